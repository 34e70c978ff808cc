//! SART, simultaneous ART (Andersen & Kak 1984), view by view (Eq. 2.27):
//!
//! ```text
//! g_j⁽ᵏ⁺¹⁾ = g_j⁽ᵏ⁾ + μ / (Σ_{i∈view} w_ij) · Σ_{i∈view} w_ij (p_i − Σ_j w_ij g_j⁽ᵏ⁾) / Σ_j w_ij
//! ```
//!
//! Views in the multilevel access order ([`super::multilevel_order`]); non-negativity after
//! every view; zero start. Defaults: μ = 1, at most 50 iterations, plateau rule on.

use std::ops::ControlFlow;

use serde::{Deserialize, Serialize};

use super::{drive, multilevel_order, IterState, Problem, Report, Stopping};
use crate::SolveError;

/// Parameters of [`sart`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SartParams {
    /// Relaxation μ of Eq. 2.27, in (0, 2). Default 1.
    pub relaxation: f64,
    /// Default: at most 50 iterations, plateau rule on.
    pub stopping: Stopping,
}

impl Default for SartParams {
    fn default() -> Self {
        SartParams { relaxation: 1.0, stopping: Stopping::with_cap(50) }
    }
}

/// Reusable state of a SART sweep (shared with SART-TV).
pub(crate) struct SartSweep {
    order: Vec<usize>,
    row_sums: Vec<Vec<f32>>,
    q: Vec<f32>,
    back: Vec<f32>,
    cols: Vec<f32>,
    mu: f32,
}

impl SartSweep {
    pub(crate) fn new(problem: &Problem, relaxation: f64) -> Self {
        let p = problem.projector;
        let n = p.grid().len();
        let ones = vec![1f32; n];
        let row_sums = (0..p.n_views())
            .map(|v| {
                let mut rs = vec![0f32; p.view_len(v)];
                p.forward(v, &ones, &mut rs);
                rs
            })
            .collect();
        SartSweep {
            order: multilevel_order(p.cameras(), p.grid().aabb.centre()),
            row_sums,
            q: vec![0f32; problem.max_view_len()],
            back: vec![0f32; n],
            cols: vec![0f32; n],
            mu: relaxation as f32,
        }
    }

    /// One sweep over all views; returns the sum of squared residuals.
    pub(crate) fn run(&mut self, problem: &Problem, x: &mut [f32]) -> f64 {
        let p = problem.projector;
        let mut ss = 0f64;
        for &v in &self.order {
            let m = p.view_len(v);
            let q = &mut self.q[..m];
            p.forward(v, x, q);
            for ((qi, &pi), &rs) in q.iter_mut().zip(&problem.images[v].data).zip(&self.row_sums[v]) {
                let res = pi - *qi;
                ss += res as f64 * res as f64;
                *qi = if rs > 0.0 { res / rs } else { 0.0 };
            }
            let mu = self.mu;
            // The step and the feasible set, each stretch while its back projection is fresh.
            p.back_update(v, q, x, (&mut self.back, &mut self.cols), &|at, xs, bs, cs| {
                for (g, (&b, &c)) in xs.iter_mut().zip(bs.iter().zip(cs)) {
                    if c > 0.0 {
                        *g = (*g + mu * b / c).max(0.0);
                    }
                }
                problem.project_feasible_at(at, xs);
            });
        }
        ss
    }
}

/// SART (Eq. 2.27); see the module docs. `init` replaces the zero start.
pub fn sart(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &SartParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let x = problem.start(init, || vec![0f32; problem.projector.grid().len()]);
    let mut sweep = SartSweep::new(problem, params.relaxation);
    drive("SART", problem, &params.stopping, x, |x, _| sweep.run(problem, x), on_iter)
}

#[cfg(test)]
mod tests {
    use super::super::dense::{assert_close, Dense};
    use super::*;

    fn params(relaxation: f64, iterations: usize) -> SartParams {
        SartParams { relaxation, stopping: Stopping { max_iterations: iterations, plateau: None } }
    }

    fn go(_: &IterState) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }

    /// `A = [[1, 0], [1, 1]]`, `p = (1, 3)` from zero: residuals over row sums (1/1, 3/2),
    /// back-projected (2.5, 1.5) over column sums (2, 1): the step is μ · (1.25, 1.5). A pixel
    /// no voxel reaches (the third) changes nothing but the residual.
    #[test]
    fn a_sart_step_is_the_row_and_column_normalised_back_projection() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 0.0], vec![1.0, 1.0], vec![0.0, 0.0]]]);
        let images = dense.images(&[&[1.0, 3.0, 1.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = sart(&problem, None, &params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[1.25, 1.5], 1e-6);
        assert_eq!(r.residual_history, vec![1.0]);
        let r = sart(&problem, None, &params(0.5, 1), go).expect("runs");
        assert_close(&r.volume, &[0.625, 0.75], 1e-6);
    }

    /// A step that takes a voxel below zero is clamped; a voxel no ray crosses keeps its value.
    #[test]
    fn sart_clamps_below_zero_and_leaves_unseen_voxels_alone() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 0.0, 0.0], vec![1.0, 1.0, 0.0]]]);
        let images = dense.images(&[&[0.0, 0.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        // Prediction (1, 2); steps (−1/1 − 2/2) / 2 = −1 and −1: both land at zero or below.
        let r = sart(&problem, Some(&[1.0, 1.0, 3.0]), &params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[0.0, 0.0, 3.0], 1e-6);
        // From (1, 3): prediction (1, 4), ratios (−1, −2), back-projected (−3, −2) over column
        // sums (2, 1): `g₀ = 1 − 1.5` is clamped, `g₁ = 3 − 2`.
        let r = sart(&problem, Some(&[1.0, 3.0, 3.0]), &params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[0.0, 1.0, 3.0], 1e-6);
    }

    /// Views one after the other: each sees the volume the previous one left.
    #[test]
    fn sart_updates_after_each_view() {
        // View 0: g₀ + g₁ = 4; view 1: g₁ = 3. From zero, view 0 gives (2, 2) (row sum 2,
        // column sums 1), then view 1 moves g₁ by 3 − 2 = 1: (2, 3).
        let dense = Dense::new(2, vec![vec![vec![1.0, 1.0]], vec![vec![0.0, 1.0]]]);
        let images = dense.images(&[&[4.0], &[3.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = sart(&problem, None, &params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[2.0, 3.0], 1e-6);
        // The residual of view 1 was measured on (2, 2): (4² + 1²) / (4² + 3²).
        assert!((r.residual_history[0] - (17.0f64 / 25.0).sqrt()).abs() < 1e-7, "{:?}", r.residual_history);
    }
}
