//! Row-action methods: ART (Kaczmarz, Eq. 2.21) and MART (Eq. 2.25).
//!
//! ```text
//! ART:  g_j ← max(0, g_j + μ w_ij (p_i − Σ_j w_ij g_j) / Σ_j w_ij²)          (2.21)
//! MART: g_j ← g_j (p_i / Σ_j w_ij g_j)^(μ w_ij / w_i,max)                     (2.25)
//! ```
//!
//! One row (pixel ray) at a time. Random order beats sequential order (dissertation §2.3.1):
//! every iteration visits the views in a shuffled order and, within each view, its rows in a
//! shuffled order, from a seeded ChaCha8 generator; a fully random order over all rows would
//! need the whole matrix at once. A view's rows ([`crate::Projector::rows`], built on both
//! cores, with the voxels outside the support left out) are kept for the next iterations while
//! all kept rows fit in `row_cache_mib`; the views that do not fit are built again each time
//! they come up. Building the rows is most of an iteration's work when they are not kept
//! (`docs/performance.md`); keeping them changes no result, only the time. Row actions are
//! sequential, so they run on one core.
//!
//! ART starts from zero. MART starts from one on every voxel some view sees and zero elsewhere
//! (the usual unity start); its ratio is floored, `(p_i + ε)/(q_i + ε)` with ε = 10⁻⁶ × the
//! largest pixel, so that dark pixels drive voxels towards zero without dividing by zero.
//! Voxels outside the support are left out of the rows. ART then divides a row's residual by
//! the squared norm of the whole row, inside the support and out, not of its entries in the
//! support alone: a ray that only grazes the support (a few voxels at its edge, where most of the
//! ray's weight was carved away) would otherwise move them by its residual over a tiny norm. With
//! images that the support does not fit exactly (pixels just below the hull's threshold, rays
//! blurred over several voxels) those steps made ART diverge inside a visual hull: on a scene
//! of two blobs seen by 8 cameras the relative residual rose above 1 and the volume NRMSE went
//! from 0.20 to 0.89. Each row's step is thereby relaxed by the fraction of its weight inside the
//! support, a row-wise relaxation in (0, μ], under which Kaczmarz's iteration still converges for
//! consistent data.

use std::ops::ControlFlow;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{drive, ratio_floor, total_column_sums, IterState, Problem, Report, Stopping};
use crate::{SolveError, SparseRows};

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
    /// MiB of views' rows kept between iterations (see the module docs); 0 builds every
    /// view's rows again each iteration. Default [`ROW_CACHE_MIB`].
    pub row_cache_mib: u64,
}

impl Default for ArtParams {
    fn default() -> Self {
        ArtParams { relaxation: 1.0, seed: 0, stopping: Stopping::with_cap(20), row_cache_mib: ROW_CACHE_MIB }
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
    /// MiB of views' rows kept between iterations (see the module docs); 0 builds every
    /// view's rows again each iteration. Default [`ROW_CACHE_MIB`].
    pub row_cache_mib: u64,
}

impl Default for MartParams {
    fn default() -> Self {
        MartParams { relaxation: 1.0, seed: 0, stopping: Stopping::with_cap(20), row_cache_mib: ROW_CACHE_MIB }
    }
}

/// Default of `row_cache_mib`: 1 GiB holds the rows of 15 views of 128² px at 64³ (18 MB per
/// view) and at 128³ (63 MB per view).
pub const ROW_CACHE_MIB: u64 = 1024;

/// A view's rows with the support applied and, when it removed entries, each whole row's
/// squared norm (see the module docs).
type Rows = (SparseRows, Option<Vec<[f32; 2]>>);

/// The views' rows with the support applied, kept while they fit in the budget.
struct RowCache {
    views: Vec<Option<Rows>>,
    bytes: usize,
    budget: usize,
}

impl RowCache {
    fn new(views: usize, budget_mib: u64) -> Self {
        let budget = usize::try_from(budget_mib.saturating_mul(1 << 20)).unwrap_or(usize::MAX);
        RowCache { views: vec![None; views], bytes: 0, budget }
    }

    /// `f` of view `v`'s rows: the kept ones, or built now (and kept if they fit).
    fn with_rows<R>(&mut self, problem: &Problem, v: usize, f: impl FnOnce(&Rows) -> R) -> R {
        if let Some(rows) = &self.views[v] {
            return f(rows);
        }
        let rows = problem.projector.rows(v);
        let rows = match problem.support {
            None => (rows, None),
            Some(s) => {
                let norms = (0..rows.n_rows())
                    .map(|i| {
                        let w = rows.row(i).1;
                        [w.iter().map(|w| w * w).sum(), w.iter().fold(0f32, |m, &v| m.max(v))]
                    })
                    .collect();
                (rows.restricted(s), Some(norms))
            }
        };
        let out = f(&rows);
        let bytes = rows.0.bytes() + rows.1.as_ref().map_or(0, |n| 8 * n.len());
        if self.bytes + bytes <= self.budget {
            self.bytes += bytes;
            self.views[v] = Some(rows);
        }
        out
    }
}

/// Visits every row of every view in a seeded random order:
/// `act(pixel value, voxel indices, weights, whole row's squared norm if the support cut it)
/// -> residual`; returns the sum of squared residuals.
fn row_sweep(
    problem: &Problem,
    rng: &mut ChaCha8Rng,
    cache: &mut RowCache,
    mut act: impl FnMut(f32, &[u32], &[f32], Option<[f32; 2]>) -> f32,
) -> f64 {
    let mut views: Vec<usize> = (0..problem.projector.n_views()).collect();
    views.shuffle(rng);
    let mut ss = 0f64;
    let mut order: Vec<u32> = Vec::new();
    for v in views {
        let data = &problem.images[v].data;
        cache.with_rows(problem, v, |(rows, whole)| {
            order.clear();
            order.extend(0..rows.n_rows() as u32);
            order.shuffle(rng);
            for &i in &order {
                let (c, w) = rows.row(i as usize);
                let whole = whole.as_ref().map(|n| n[i as usize]);
                let r = if c.is_empty() { data[i as usize] } else { act(data[i as usize], c, w, whole) };
                ss += r as f64 * r as f64;
            }
        });
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
    let mut cache = RowCache::new(problem.projector.n_views(), params.row_cache_mib);
    drive(
        "ART",
        problem,
        &params.stopping,
        x,
        |x, _| {
            row_sweep(problem, &mut rng, &mut cache, |p, cols, w, whole| {
                let (mut q, mut norm2) = (0f32, 0f32);
                for (&j, &wij) in cols.iter().zip(w) {
                    q += wij * x[j as usize];
                    norm2 += wij * wij;
                }
                // The whole row's norm inside a support (the module docs).
                let norm2 = whole.map_or(norm2, |[n, _]| n.max(norm2));
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
    let mut cache = RowCache::new(problem.projector.n_views(), params.row_cache_mib);
    drive(
        "MART",
        problem,
        &params.stopping,
        x,
        |x, _| {
            row_sweep(problem, &mut rng, &mut cache, |p, cols, w, whole| {
                let (mut q, mut wmax) = (0f32, 0f32);
                for (&j, &wij) in cols.iter().zip(w) {
                    q += wij * x[j as usize];
                    wmax = wmax.max(wij);
                }
                let wmax = whole.map_or(wmax, |[_, m]| m.max(wmax));
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

#[cfg(test)]
mod tests {
    use super::super::dense::{assert_close, Dense};
    use super::*;

    fn no_plateau(iterations: usize) -> Stopping {
        Stopping { max_iterations: iterations, plateau: None }
    }

    fn art_params(relaxation: f64, iterations: usize) -> ArtParams {
        ArtParams { relaxation, stopping: no_plateau(iterations), ..Default::default() }
    }

    fn mart_params(relaxation: f64, iterations: usize) -> MartParams {
        MartParams { relaxation, stopping: no_plateau(iterations), ..Default::default() }
    }

    fn go(_: &IterState) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }

    /// One row `g₀ + 2 g₁ = 5` from zero: Kaczmarz projects onto the row's hyperplane, to
    /// `μ · 5 / 5 · (1, 2)`; the residual of the first iteration is measured before the step.
    #[test]
    fn an_art_step_moves_along_the_row_by_the_relaxed_residual() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 2.0]]]);
        let images = dense.images(&[&[5.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = art(&problem, None, &art_params(1.0, 2), go).expect("runs");
        assert_close(&r.volume, &[1.0, 2.0], 1e-6);
        assert_eq!(r.residual_history[0], 1.0);
        assert!(r.residual_history[1] < 1e-6, "{:?}", r.residual_history);
        let r = art(&problem, None, &art_params(0.5, 1), go).expect("runs");
        assert_close(&r.volume, &[0.5, 1.0], 1e-6);
    }

    /// From (2, 1) towards `g₀ + 3 g₁ = 0`: the step −0.5 · (1, 3) takes `g₁` below zero,
    /// where it is clamped.
    #[test]
    fn art_clamps_a_voxel_the_step_takes_below_zero() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 3.0]]]);
        let images = dense.images(&[&[0.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = art(&problem, Some(&[2.0, 1.0]), &art_params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[1.5, 0.0], 1e-6);
    }

    /// Inside a support the residual is divided by the whole row's squared norm (5), not by
    /// that of its entries in the support (1): `g₀` moves by 5 / 5, not by 5.
    #[test]
    fn inside_a_support_art_divides_by_the_whole_rows_norm() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 2.0]]]);
        let images = dense.images(&[&[5.0]]);
        let support = [true, false];
        let problem = Problem::new(&dense, &images).expect("consistent").with_support(&support);
        let r = art(&problem, None, &art_params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[1.0, 0.0], 1e-6);
    }

    /// Rows of several views: ART converges to the solution of a consistent square system
    /// whatever the order it draws, with the rows kept or not.
    #[test]
    fn art_solves_a_consistent_system_of_several_views() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 1.0, 0.0], vec![0.0, 1.0, 1.0]], vec![vec![1.0, 0.0, 2.0]]]);
        // Solution (1, 2, 3).
        let images = dense.images(&[&[3.0, 5.0], &[7.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        for row_cache_mib in [0, 1] {
            let params = ArtParams { row_cache_mib, ..art_params(1.0, 200) };
            let r = art(&problem, None, &params, go).expect("runs");
            assert_close(&r.volume, &[1.0, 2.0, 3.0], 1e-3);
        }
    }

    /// One row `g₀ + 2 g₁ = 6` from the unity start (prediction 3): MART multiplies each voxel
    /// by the ratio 2 to the power `μ w_ij / w_max`, giving (√2, 2) for μ = 1.
    #[test]
    fn a_mart_step_multiplies_by_the_ratio_to_the_relative_weight() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 2.0]]]);
        let images = dense.images(&[&[6.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = mart(&problem, None, &mart_params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[2f32.sqrt(), 2.0], 1e-5);
        assert!((r.residual_history[0] - 0.5).abs() < 1e-9, "{:?}", r.residual_history);
        let r = mart(&problem, None, &mart_params(0.5, 1), go).expect("runs");
        assert_close(&r.volume, &[2f32.powf(0.25), 2f32.sqrt()], 1e-5);
    }

    /// MART starts from one where some view sees the voxel and zero elsewhere, and a voxel
    /// at zero stays there.
    #[test]
    fn mart_starts_at_one_where_a_view_sees_the_voxel() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 0.0, 0.0]], vec![vec![0.0, 2.0, 0.0]]]);
        let images = dense.images(&[&[1.0], &[2.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = mart(&problem, None, &mart_params(1.0, 0), go).expect("runs");
        assert_eq!(r.volume, [1.0, 1.0, 0.0]);
        let r = mart(&problem, None, &mart_params(1.0, 3), go).expect("runs");
        assert_close(&r.volume, &[1.0, 1.0, 0.0], 1e-5);
    }

    /// Inside a support MART's exponent is relative to the whole row's largest weight (2), not
    /// to the largest in the support (1): `g₀` is multiplied by 6^(1/2), not by 6.
    #[test]
    fn inside_a_support_mart_scales_by_the_whole_rows_largest_weight() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 2.0]]]);
        let images = dense.images(&[&[6.0]]);
        let support = [true, false];
        let problem = Problem::new(&dense, &images).expect("consistent").with_support(&support);
        let r = mart(&problem, None, &mart_params(1.0, 1), go).expect("runs");
        assert_close(&r.volume, &[6f32.sqrt(), 0.0], 1e-5);
    }

    /// A dark pixel drives its voxels towards zero, finite and non-negative, with the ratio
    /// floored relative to the brightest pixel.
    #[test]
    fn a_dark_pixel_drives_mart_towards_zero_without_dividing_by_zero() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 1.0]], vec![vec![0.0, 1.0]]]);
        let images = dense.images(&[&[0.0], &[1.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let r = mart(&problem, None, &mart_params(1.0, 1), go).expect("runs");
        assert!(r.volume.iter().all(|v| v.is_finite() && *v >= 0.0), "{:?}", r.volume);
        // The first row seen sets `g₀` to 1e-6 / (2 + 1e-6) or so; nothing raises it again.
        assert!(r.volume[0] < 1e-5, "{:?}", r.volume);
    }
}
