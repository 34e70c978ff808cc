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
