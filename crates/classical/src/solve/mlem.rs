//! Simultaneous multiplicative methods: MLEM (Eq. 2.33) and SMART (Eq. 2.28).
//!
//! ```text
//! MLEM:  g_j ← g_j / (Σ_i w_ij) · Σ_i w_ij p_i / Σ_j w_ij g_j                          (2.33)
//! SMART: g_j ← g_j Π_{i∈Υ_j} (p_i / Σ_j w_ij g_j)^(μ/N_j · w_ij / w_i,max)              (2.28)
//! ```
//!
//! Sums and products run over the rows of all views (one update per iteration). Υ_j is the
//! set of rows (pixel rays) with `w_ij > 0` and `N_j` its size; `w_i,max` is row i's largest
//! weight. Both start from one on every voxel some view sees and zero elsewhere, and never go
//! negative. SMART floors its ratio like MART (`(p + ε)/(q + ε)`, ε = 10⁻⁶ × the largest pixel);
//! MLEM skips rays with no predicted intensity. Defaults: SMART μ = 1; at most 100 iterations,
//! plateau rule on.

use std::ops::ControlFlow;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{art::unity_start, drive, ratio_floor, total_column_sums, IterState, Problem, Report, Stopping};
use crate::SolveError;

/// Parameters of [`mlem`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MlemParams {
    /// Default: at most 100 iterations, plateau rule on.
    pub stopping: Stopping,
}

impl Default for MlemParams {
    fn default() -> Self {
        MlemParams { stopping: Stopping::with_cap(100) }
    }
}

/// Parameters of [`smart`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SmartParams {
    /// Relaxation μ of Eq. 2.28, in (0, 1]. Default 1.
    pub relaxation: f64,
    /// Default: at most 100 iterations, plateau rule on.
    pub stopping: Stopping,
}

impl Default for SmartParams {
    fn default() -> Self {
        SmartParams { relaxation: 1.0, stopping: Stopping::with_cap(100) }
    }
}

/// MLEM (Eq. 2.33); see the module docs. `init` replaces the unity start.
pub fn mlem(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &MlemParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let p = problem.projector;
    let col_sums = total_column_sums(problem);
    let x = problem.start(init, || col_sums.iter().map(|&c| if c > 0.0 { 1.0 } else { 0.0 }).collect());
    // Every view's ratio image, back-projected together in one pass over the grid.
    let views: Vec<usize> = (0..p.n_views()).collect();
    let mut qs: Vec<Vec<f32>> = views.iter().map(|&v| vec![0f32; p.view_len(v)]).collect();
    let mut acc = vec![0f32; p.grid().len()];
    drive(
        "MLEM",
        problem,
        &params.stopping,
        x,
        |x, _| {
            let mut ss = 0f64;
            acc.par_iter_mut().for_each(|a| *a = 0.0);
            for (v, q) in qs.iter_mut().enumerate() {
                p.forward(v, x, q);
                for (qi, &pi) in q.iter_mut().zip(&problem.images[v].data) {
                    let res = pi - *qi;
                    ss += res as f64 * res as f64;
                    *qi = if *qi > 0.0 { pi.max(0.0) / *qi } else { 0.0 };
                }
            }
            let ys: Vec<&[f32]> = qs.iter().map(Vec::as_slice).collect();
            p.back_add_views(&views, &ys, &mut acc, None);
            x.par_iter_mut().zip(acc.par_iter().zip(col_sums.par_iter())).for_each(|(g, (&a, &c))| {
                *g = if c > 0.0 { *g * a / c } else { 0.0 };
            });
            problem.project_feasible(x);
            ss
        },
        on_iter,
    )
}

/// SMART (Eq. 2.28); see the module docs. `init` replaces the unity start.
pub fn smart(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &SmartParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let p = problem.projector;
    let n = p.grid().len();
    // N_j and w_i,max come from each view's rows, built once and dropped.
    let mut rays_per_voxel = vec![0f32; n];
    let mut inv_row_max: Vec<Vec<f32>> = Vec::with_capacity(p.n_views());
    for v in 0..p.n_views() {
        let rows = p.rows(v);
        for &j in &rows.cols {
            rays_per_voxel[j as usize] += 1.0;
        }
        inv_row_max.push(rows.row_max().into_iter().map(|m| if m > 0.0 { 1.0 / m } else { 0.0 }).collect());
    }
    let x = problem.start(init, || unity_start(problem));
    let eps = ratio_floor(problem);
    let mu = params.relaxation as f32;
    let views: Vec<usize> = (0..p.n_views()).collect();
    let mut qs: Vec<Vec<f32>> = views.iter().map(|&v| vec![0f32; p.view_len(v)]).collect();
    let mut acc = vec![0f32; n];
    drive(
        "SMART",
        problem,
        &params.stopping,
        x,
        |x, _| {
            let mut ss = 0f64;
            acc.par_iter_mut().for_each(|a| *a = 0.0);
            for (v, q) in qs.iter_mut().enumerate() {
                p.forward(v, x, q);
                for ((qi, &pi), &inv) in q.iter_mut().zip(&problem.images[v].data).zip(&inv_row_max[v]) {
                    let res = pi - *qi;
                    ss += res as f64 * res as f64;
                    *qi = ((pi.max(0.0) + eps) / (*qi + eps)).ln() * inv;
                }
            }
            let ys: Vec<&[f32]> = qs.iter().map(Vec::as_slice).collect();
            p.back_add_views(&views, &ys, &mut acc, None);
            x.par_iter_mut().zip(acc.par_iter().zip(rays_per_voxel.par_iter())).for_each(|(g, (&a, &nj))| {
                if nj > 0.0 {
                    *g *= (mu * a / nj).exp();
                }
            });
            problem.project_feasible(x);
            ss
        },
        on_iter,
    )
}

#[cfg(test)]
mod tests {
    use super::super::dense::{assert_close, Dense};
    use super::*;

    fn go(_: &IterState) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }

    fn capped(iterations: usize) -> Stopping {
        Stopping { max_iterations: iterations, plateau: None }
    }

    fn problem_of<'a>(dense: &'a Dense, images: &'a [fluidnerf_core::Image]) -> Problem<'a> {
        Problem::new(dense, images).expect("consistent")
    }

    /// `A = [[1, 0], [1, 1]]`, `p = (1, 3)` from the unity start: ratios `p / Ag = (1, 1.5)`,
    /// back-projected (2.5, 1.5) over column sums (2, 1): `g = (1.25, 1.5)`. The solution
    /// (1, 2) is a fixed point.
    #[test]
    fn an_mlem_step_multiplies_by_the_normalised_back_projected_ratio() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 0.0], vec![1.0, 1.0]]]);
        let images = dense.images(&[&[1.0, 3.0]]);
        let problem = problem_of(&dense, &images);
        let params = MlemParams { stopping: capped(1) };
        let r = mlem(&problem, None, &params, go).expect("runs");
        assert_close(&r.volume, &[1.25, 1.5], 1e-6);
        assert!((r.residual_history[0] - 0.1f64.sqrt()).abs() < 1e-7, "{:?}", r.residual_history);
        let r = mlem(&problem, Some(&[1.0, 2.0]), &MlemParams { stopping: capped(5) }, go).expect("runs");
        assert_close(&r.volume, &[1.0, 2.0], 1e-6);
    }

    /// A ray predicted dark is skipped (no division by zero), a negative pixel counts as zero,
    /// and a voxel no view sees starts, and stays, at zero.
    #[test]
    fn mlem_skips_dark_predictions_and_negative_pixels() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 0.0, 0.0], vec![1.0, 1.0, 0.0]]]);
        let images = dense.images(&[&[1.0, 3.0]]);
        let problem = problem_of(&dense, &images);
        // From (0, 1): ratios (skipped, 3), back-projected (3, 3) over (2, 1).
        let r = mlem(&problem, Some(&[0.0, 1.0, 0.0]), &MlemParams { stopping: capped(1) }, go).expect("runs");
        assert_close(&r.volume, &[0.0, 3.0, 0.0], 1e-6);
        let r = mlem(&problem, None, &MlemParams { stopping: capped(0) }, go).expect("runs");
        assert_eq!(r.volume, [1.0, 1.0, 0.0]);
        let r = mlem(&problem, Some(&[1.0, 1.0, 5.0]), &MlemParams { stopping: capped(1) }, go).expect("runs");
        assert_eq!(r.volume[2], 0.0);
        let images = dense.images(&[&[-1.0, 3.0]]);
        let problem = problem_of(&dense, &images);
        // Ratios (0, 1.5), back-projected (1.5, 1.5) over (2, 1).
        let r = mlem(&problem, None, &MlemParams { stopping: capped(1) }, go).expect("runs");
        assert_close(&r.volume, &[0.75, 1.5, 0.0], 1e-6);
    }

    /// `A = [[2, 0], [1, 1]]`, `p = (4, 3)` from the unity start (prediction (2, 2)): the log
    /// ratios (ln 2, ln 1.5) over the rows' largest weights (2, 1), back-projected
    /// (ln 2 + ln 1.5, ln 1.5) over the rays per voxel (2, 1), exponentiated: (√3, 1.5) for
    /// μ = 1, their square roots for μ = 1/2.
    #[test]
    fn a_smart_step_is_the_geometric_mean_of_the_relative_ratios() {
        let dense = Dense::new(2, vec![vec![vec![2.0, 0.0], vec![1.0, 1.0]]]);
        let images = dense.images(&[&[4.0, 3.0]]);
        let problem = problem_of(&dense, &images);
        let r = smart(&problem, None, &SmartParams { relaxation: 1.0, stopping: capped(1) }, go).expect("runs");
        assert_close(&r.volume, &[3f32.sqrt(), 1.5], 1e-5);
        let r = smart(&problem, None, &SmartParams { relaxation: 0.5, stopping: capped(1) }, go).expect("runs");
        assert_close(&r.volume, &[3f32.powf(0.25), 1.5f32.sqrt()], 1e-5);
        // The solution (2, 1) is a fixed point.
        let r = smart(&problem, Some(&[2.0, 1.0]), &SmartParams { relaxation: 1.0, stopping: capped(5) }, go)
            .expect("runs");
        assert_close(&r.volume, &[2.0, 1.0], 1e-5);
    }

    /// SMART starts from one where a view sees the voxel, zero elsewhere, and stays there.
    #[test]
    fn smart_starts_at_one_where_a_view_sees_the_voxel() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 0.0, 0.0]], vec![vec![0.0, 2.0, 0.0]]]);
        let images = dense.images(&[&[1.0], &[2.0]]);
        let problem = problem_of(&dense, &images);
        let r = smart(&problem, None, &SmartParams { relaxation: 1.0, stopping: capped(0) }, go).expect("runs");
        assert_eq!(r.volume, [1.0, 1.0, 0.0]);
        let r = smart(&problem, None, &SmartParams { relaxation: 1.0, stopping: capped(3) }, go).expect("runs");
        assert_close(&r.volume, &[1.0, 1.0, 0.0], 1e-5);
    }
}
