//! SART-TV: SART sweeps alternated with total-variation descent, in the style of ASD-POCS
//! (Sidky & Pan 2008), an edge-preserving regulariser for few views.
//!
//! Each iteration: one SART sweep (Eq. 2.27, with non-negativity), giving the data step
//! `d = ‖g_after − g_before‖₂`; then `tv_steps` steps of steepest descent on the isotropic
//! total variation
//!
//! ```text
//! TV(g) = Σ_m sqrt((g_m − g_{m−x})² + (g_m − g_{m−y})² + (g_m − g_{m−z})² + ε²)
//! g ← max(0, g − tv_weight · d · ∇TV / ‖∇TV‖)
//! ```
//!
//! (backward differences, zero across the grid's faces, ε = 10⁻⁴ × the largest voxel). Tying
//! the TV step to `d` keeps the two in balance as the iteration converges. Defaults:
//! `tv_weight` 0.2 and 20 steps (ASD-POCS's α and N_grad), SART μ = 1, at most 50 iterations,
//! plateau rule on. `tv_weight = 0` is plain SART.

use std::ops::ControlFlow;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{drive, sart::SartSweep, IterState, Problem, Report, Stopping};
use crate::{Grid, SolveError};

/// Parameters of [`sart_tv`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TvParams {
    /// SART relaxation μ. Default 1.
    pub relaxation: f64,
    /// TV step per descent step, as a fraction of the SART step's size. Default 0.2.
    pub tv_weight: f64,
    /// TV descent steps per iteration. Default 20.
    pub tv_steps: usize,
    /// Default: at most 50 iterations, plateau rule on.
    pub stopping: Stopping,
}

impl Default for TvParams {
    fn default() -> Self {
        TvParams { relaxation: 1.0, tv_weight: 0.2, tv_steps: 20, stopping: Stopping::with_cap(50) }
    }
}

/// `grad = ∇TV(g)` with the norms of the backward differences in `norms` (both
/// [`Grid::len`]).
pub(crate) fn tv_gradient(grid: &Grid, g: &[f32], norms: &mut [f32], grad: &mut [f32]) {
    let [nx, ny, _] = grid.dims;
    let slab = nx * ny;
    let peak = g.par_iter().cloned().reduce(|| 0.0, f32::max);
    let eps2 = (1e-4 * peak).powi(2).max(f32::MIN_POSITIVE);
    let diffs = |m: usize| -> [f32; 3] {
        let (i, j, k) = (m % nx, (m / nx) % ny, m / slab);
        let v = g[m];
        [
            if i > 0 { v - g[m - 1] } else { 0.0 },
            if j > 0 { v - g[m - nx] } else { 0.0 },
            if k > 0 { v - g[m - slab] } else { 0.0 },
        ]
    };
    norms.par_iter_mut().enumerate().for_each(|(m, n)| {
        let d = diffs(m);
        *n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + eps2).sqrt();
    });
    let len = g.len();
    grad.par_iter_mut().enumerate().for_each(|(m, out)| {
        let d = diffs(m);
        let mut s = (d[0] + d[1] + d[2]) / norms[m];
        let (i, j) = (m % nx, (m / nx) % ny);
        if i + 1 < nx {
            s -= diffs(m + 1)[0] / norms[m + 1];
        }
        if j + 1 < ny {
            s -= diffs(m + nx)[1] / norms[m + nx];
        }
        if m + slab < len {
            s -= diffs(m + slab)[2] / norms[m + slab];
        }
        *out = s;
    });
}

/// Total variation of `g` as defined in the module docs (with ε = 0).
pub fn total_variation(grid: &Grid, g: &[f32]) -> f64 {
    let [nx, ny, _] = grid.dims;
    let slab = nx * ny;
    (0..g.len())
        .into_par_iter()
        .map(|m| {
            let (i, j, k) = (m % nx, (m / nx) % ny, m / slab);
            let v = g[m];
            let dx = if i > 0 { v - g[m - 1] } else { 0.0 };
            let dy = if j > 0 { v - g[m - nx] } else { 0.0 };
            let dz = if k > 0 { v - g[m - slab] } else { 0.0 };
            ((dx * dx + dy * dy + dz * dz) as f64).sqrt()
        })
        .sum()
}

/// SART-TV; see the module docs. `init` replaces the zero start.
pub fn sart_tv(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &TvParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let grid = *problem.projector.grid();
    let n = grid.len();
    let x = problem.start(init, || vec![0f32; n]);
    let mut sweep = SartSweep::new(problem, params.relaxation);
    let mut before = vec![0f32; n];
    let mut norms = vec![0f32; n];
    let mut grad = vec![0f32; n];
    let weight = params.tv_weight;
    drive(
        "SART-TV",
        problem,
        &params.stopping,
        x,
        |x, _| {
            before.copy_from_slice(x);
            let ss = sweep.run(problem, x);
            let d: f64 =
                x.par_iter().zip(before.par_iter()).map(|(&a, &b)| ((a - b) as f64).powi(2)).sum::<f64>().sqrt();
            if weight > 0.0 && d > 0.0 {
                for _ in 0..params.tv_steps {
                    tv_gradient(&grid, x, &mut norms, &mut grad);
                    let gn: f64 = grad.par_iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
                    if gn == 0.0 {
                        break;
                    }
                    let step = (weight * d / gn) as f32;
                    x.par_iter_mut().zip(grad.par_iter()).for_each(|(g, &dg)| *g = (*g - step * dg).max(0.0));
                    problem.project_feasible(x);
                }
            }
            ss
        },
        on_iter,
    )
}
