//! ASART, adaptive simultaneous ART (Wan et al. 2006), the dissertation's baseline
//! (Eq. 2.29–2.30, §6.4.1).
//!
//! ```text
//! g_j⁽⁰⁾   = Σ_i w_ij p_i / Σ_i w_ij                                            (2.29)
//! g_j⁽ᵏ⁺¹⁾ = g_j⁽ᵏ⁾ + (μ/4) Σ_{i ∈ view} (w_ij g_j⁽ᵏ⁾ / Σ_j w_ij g_j⁽ᵏ⁾) [p_i − Σ_j w_ij g_j⁽ᵏ⁾]   (2.30)
//! ```
//!
//! - View by view, views in the multilevel access order ([`super::multilevel_order`]).
//! - The adaptive relaxation is the factor `w_ij g_j / Σ_j w_ij g_j`: each pixel's residual is
//!   shared among the voxels on its ray in proportion to what they contribute to it.
//! - Column-sum substitution: the dissertation's bilinear weights sum to 1 over a voxel's four
//!   pixels, so Eq. 2.30 has no column-sum normalisation. Our weights carry the imaging scale
//!   (`w_ij = γ_j b_ij`, see [`crate::SplatProjector`]), so the update is divided by the voxel's
//!   column sum in the view, `Σ_{i∈view} w_ij`; with the splat this is exactly Eq. 2.30 on the
//!   bilinear weights, and it keeps the update independent of units for any projector.
//! - Eq. 2.29 yields values in pixel units; the start is that volume times the one scalar that
//!   best fits its projections to the data (least squares), so the iteration starts at the
//!   right magnitude whatever the imaging scale.
//! - Non-negativity after every view; zero outside the support.
//! - Defaults: μ = 0.5, at most 250 iterations, stop when the residual (sliding mean of 4)
//!   varies by less than 2 % over 20 iterations.

use std::ops::ControlFlow;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{drive, multilevel_order, IterState, Plateau, Problem, Report, Stopping};
use crate::SolveError;

/// Parameters of [`asart`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AsartParams {
    /// Relaxation μ of Eq. 2.30, in (0, 2). Default 0.5 (the dissertation's).
    pub relaxation: f64,
    /// Default: at most 250 iterations, plateau rule on (20 iterations, mean of 4, 2 %).
    pub stopping: Stopping,
}

impl Default for AsartParams {
    fn default() -> Self {
        AsartParams { relaxation: 0.5, stopping: Stopping { max_iterations: 250, plateau: Some(Plateau::default()) } }
    }
}

/// The start of Eq. 2.29, rescaled to fit the data (see the module docs).
pub(crate) fn asart_start(problem: &Problem) -> Vec<f32> {
    let p = problem.projector;
    let n = p.grid().len();
    let mut num = vec![0f32; n];
    let mut den = vec![0f32; n];
    for v in 0..p.n_views() {
        p.back_add(v, &problem.images[v].data, &mut num, Some(&mut den));
    }
    let mut x: Vec<f32> = num.iter().zip(&den).map(|(&a, &b)| if b > 0.0 { a / b } else { 0.0 }).collect();
    problem.project_feasible(&mut x);
    let mut q = vec![0f32; problem.max_view_len()];
    let (mut pq, mut qq) = (0f64, 0f64);
    for v in 0..p.n_views() {
        let q = &mut q[..p.view_len(v)];
        p.forward(v, &x, q);
        for (&a, &b) in problem.images[v].data.iter().zip(q.iter()) {
            pq += a as f64 * b as f64;
            qq += b as f64 * b as f64;
        }
    }
    if qq > 0.0 {
        let s = (pq / qq) as f32;
        x.par_iter_mut().for_each(|v| *v *= s);
    }
    x
}

/// ASART (Eq. 2.29–2.30); see the module docs. `init` replaces the Eq. 2.29 start.
pub fn asart(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &AsartParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let p = problem.projector;
    let n = p.grid().len();
    let order = multilevel_order(p.cameras(), p.grid().aabb.centre());
    let x = problem.start(init, || asart_start(problem));
    let mu4 = (params.relaxation / 4.0) as f32;
    let mut q = vec![0f32; problem.max_view_len()];
    let mut ratio = q.clone();
    let mut back = vec![0f32; n];
    let mut cols = vec![0f32; n];
    drive(
        "ASART",
        problem,
        &params.stopping,
        x,
        |x, _| {
            let mut ss = 0f64;
            for &v in &order {
                let m = p.view_len(v);
                let (q, ratio) = (&mut q[..m], &mut ratio[..m]);
                p.forward(v, x, q);
                for ((r, &qi), &pi) in ratio.iter_mut().zip(q.iter()).zip(&problem.images[v].data) {
                    let res = pi - qi;
                    ss += res as f64 * res as f64;
                    *r = if qi > 0.0 { res / qi } else { 0.0 };
                }
                // The step and the feasible set, each stretch while its back projection is
                // fresh.
                p.back_update(v, ratio, x, (&mut back, &mut cols), &|at, xs, bs, cs| {
                    for (g, (&b, &c)) in xs.iter_mut().zip(bs.iter().zip(cs)) {
                        if c > 0.0 {
                            *g = (*g + mu4 * *g * b / c).max(0.0);
                        }
                    }
                    problem.project_feasible_at(at, xs);
                });
            }
            ss
        },
        on_iter,
    )
}

#[cfg(test)]
mod tests {
    use super::super::dense::{assert_close, Dense};
    use super::*;

    fn params(relaxation: f64, iterations: usize) -> AsartParams {
        AsartParams { relaxation, stopping: Stopping { max_iterations: iterations, plateau: None } }
    }

    fn go(_: &IterState) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }

    /// `A = [[1, 0], [1, 1]]`, `p = (1, 3)`: Eq. 2.29 gives `Aᵀp / Aᵀ1 = (4/2, 3/1) = (2, 3)`,
    /// whose projection (2, 5) is fitted to the data by the factor `⟨p, q⟩ / ⟨q, q⟩ = 17/29`.
    #[test]
    fn the_start_is_the_normalised_back_projection_fitted_to_the_data() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 0.0], vec![1.0, 1.0]]]);
        let images = dense.images(&[&[1.0, 3.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = asart(&problem, None, &params(0.5, 0), go).expect("runs");
        assert_close(&r.volume, &[34.0 / 29.0, 51.0 / 29.0], 1e-6);
    }

    /// From (2, 0.5): the prediction (2, 2.5) leaves residuals (−1, 0.5), ratios (−0.5, 0.2),
    /// back-projected (−0.3, 0.2) over column sums (2, 1); the update
    /// `g + μ/4 · g · Aᵀratio / Aᵀ1` is `(2 − μ/4 · 0.3, 0.5 + μ/4 · 0.1)`.
    #[test]
    fn an_asart_step_shares_each_residual_in_proportion_to_the_voxels_share() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 0.0], vec![1.0, 1.0]]]);
        let images = dense.images(&[&[1.0, 3.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = asart(&problem, Some(&[2.0, 0.5]), &params(0.5, 1), go).expect("runs");
        assert_close(&r.volume, &[1.9625, 0.5125], 1e-6);
        assert!((r.residual_history[0] - 0.125f64.sqrt()).abs() < 1e-7, "{:?}", r.residual_history);
        let r = asart(&problem, Some(&[2.0, 0.5]), &params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[1.925, 0.525], 1e-6);
    }

    /// A voxel at zero contributes nothing, so it takes no share of the residual; a pixel
    /// predicted dark passes nothing back.
    #[test]
    fn asart_leaves_a_voxel_at_zero_at_zero() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 0.0], vec![1.0, 1.0]]]);
        let images = dense.images(&[&[1.0, 3.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        // Prediction (0, 1), ratios (0, 2): `g₁ = 1 + 0.125 · 2 / 1`.
        let r = asart(&problem, Some(&[0.0, 1.0]), &params(0.5, 1), go).expect("runs");
        assert_close(&r.volume, &[0.0, 1.25], 1e-6);
    }

    /// A voxel no ray crosses has no column sum to divide by: it keeps its value.
    #[test]
    fn asart_leaves_a_voxel_no_ray_crosses_alone() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 0.0, 0.0], vec![1.0, 1.0, 0.0]]]);
        let images = dense.images(&[&[1.0, 3.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = asart(&problem, Some(&[2.0, 0.5, 4.0]), &params(0.5, 1), go).expect("runs");
        assert_close(&r.volume, &[1.9625, 0.5125, 4.0], 1e-6);
    }

    /// On consistent data ASART converges to the solution, with the views in turn.
    #[test]
    fn asart_solves_a_consistent_system_of_two_views() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 1.0, 0.0], vec![0.0, 1.0, 1.0]], vec![vec![1.0, 0.0, 2.0]]]);
        let images = dense.images(&[&[3.0, 5.0], &[7.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = asart(&problem, None, &params(1.0, 2000), go).expect("runs");
        assert_close(&r.volume, &[1.0, 2.0, 3.0], 1e-3);
    }
}
