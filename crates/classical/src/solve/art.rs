//! Row-action methods: ART (Kaczmarz, Eq. 2.21) and MART (Eq. 2.25).
//!
//! ```text
//! ART:  g_j ← max(0, g_j + μ w_ij (p_i − Σ_j w_ij g_j) / Σ_j w_ij²)          (2.21)
//! MART: g_j ← g_j (p_i / Σ_j w_ij g_j)^(μ w_ij / w_i,max)                     (2.25)
//! ```
//!
//! One row (pixel ray) at a time. Random order beats sequential order (dissertation §2.3.1):
//! every iteration visits the views in a shuffled order and, within each view, its rows in a
//! shuffled order, from a seeded ChaCha8 generator. Only the current view's rows are held
//! ([`crate::Projector::rows`]); a fully random order over all rows would hold the whole
//! matrix. Row actions are sequential, so these two run on one core.
//!
//! ART starts from zero. MART starts from one on every voxel some view sees and zero elsewhere
//! (the usual unity start); its ratio is floored, `(p_i + ε)/(q_i + ε)` with ε = 10⁻⁶ × the
//! largest pixel, so that dark pixels drive voxels towards zero without dividing by zero.
//! Voxels outside the support are left out of the rows.

use std::ops::ControlFlow;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{drive, ratio_floor, total_column_sums, IterState, Problem, Report, Stopping};
use crate::SolveError;

/// Parameters of [`art`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ArtParams {
    /// Relaxation μ of Eq. 2.21, in (0, 2). Default 1 (Kaczmarz).
    pub relaxation: f64,
    /// Seed of the row order. Default 0.
    pub seed: u64,
    /// Default: at most 20 iterations, plateau rule on.
    pub stopping: Stopping,
}

impl Default for ArtParams {
    fn default() -> Self {
        ArtParams { relaxation: 1.0, seed: 0, stopping: Stopping::with_cap(20) }
    }
}

/// Parameters of [`mart`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MartParams {
    /// Relaxation μ of Eq. 2.25, in (0, 1]. Default 1.
    pub relaxation: f64,
    /// Seed of the row order. Default 0.
    pub seed: u64,
    /// Default: at most 20 iterations, plateau rule on.
    pub stopping: Stopping,
}

impl Default for MartParams {
    fn default() -> Self {
        MartParams { relaxation: 1.0, seed: 0, stopping: Stopping::with_cap(20) }
    }
}

/// Visits every row of every view in a seeded random order:
/// `act(pixel value, voxel indices, weights) -> residual`; returns the sum of squared residuals.
fn row_sweep(problem: &Problem, rng: &mut ChaCha8Rng, mut act: impl FnMut(f32, &[u32], &[f32]) -> f32) -> f64 {
    let p = problem.projector;
    let mut views: Vec<usize> = (0..p.n_views()).collect();
    views.shuffle(rng);
    let mut ss = 0f64;
    let mut cols: Vec<u32> = Vec::new();
    let mut vals: Vec<f32> = Vec::new();
    for v in views {
        let rows = p.rows(v);
        let mut order: Vec<u32> = (0..rows.n_rows() as u32).collect();
        order.shuffle(rng);
        let data = &problem.images[v].data;
        for i in order {
            let (c, w) = rows.row(i as usize);
            let (c, w) = match problem.support {
                None => (c, w),
                Some(s) => {
                    cols.clear();
                    vals.clear();
                    for (&j, &wij) in c.iter().zip(w) {
                        if s[j as usize] {
                            cols.push(j);
                            vals.push(wij);
                        }
                    }
                    (&cols[..], &vals[..])
                }
            };
            let r = if c.is_empty() { data[i as usize] } else { act(data[i as usize], c, w) };
            ss += r as f64 * r as f64;
        }
    }
    ss
}

/// ART (Eq. 2.21); see the module docs. `init` replaces the zero start.
pub fn art(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &ArtParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let x = problem.start(init, || vec![0f32; problem.projector.grid().len()]);
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let mu = params.relaxation as f32;
    drive(
        "ART",
        problem,
        &params.stopping,
        x,
        |x, _| {
            row_sweep(problem, &mut rng, |p, cols, w| {
                let (mut q, mut norm2) = (0f32, 0f32);
                for (&j, &wij) in cols.iter().zip(w) {
                    q += wij * x[j as usize];
                    norm2 += wij * wij;
                }
                let r = p - q;
                if norm2 > 0.0 {
                    let step = mu * r / norm2;
                    for (&j, &wij) in cols.iter().zip(w) {
                        let g = &mut x[j as usize];
                        *g = (*g + step * wij).max(0.0);
                    }
                }
                r
            })
        },
        on_iter,
    )
}

/// The unity start of the multiplicative methods: one where some view sees the voxel.
pub(crate) fn unity_start(problem: &Problem) -> Vec<f32> {
    total_column_sums(problem).into_iter().map(|c| if c > 0.0 { 1.0 } else { 0.0 }).collect()
}

/// MART (Eq. 2.25); see the module docs. `init` replaces the unity start.
pub fn mart(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &MartParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let x = problem.start(init, || unity_start(problem));
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let mu = params.relaxation as f32;
    let eps = ratio_floor(problem);
    drive(
        "MART",
        problem,
        &params.stopping,
        x,
        |x, _| {
            row_sweep(problem, &mut rng, |p, cols, w| {
                let (mut q, mut wmax) = (0f32, 0f32);
                for (&j, &wij) in cols.iter().zip(w) {
                    q += wij * x[j as usize];
                    wmax = wmax.max(wij);
                }
                if wmax > 0.0 {
                    let log_ratio = ((p.max(0.0) + eps) / (q + eps)).ln();
                    let k = mu * log_ratio / wmax;
                    for (&j, &wij) in cols.iter().zip(w) {
                        x[j as usize] *= (k * wij).exp();
                    }
                }
                p - q
            })
        },
        on_iter,
    )
}
