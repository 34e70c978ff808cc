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
//! the TV step to `d` keeps the two in balance as the iteration converges. Inside a support
//! (a visual hull) the step is also shrunk whenever the TV steps changed the volume more than
//! the SART sweep did, as ASD-POCS does ([`TvStepRule`]). Defaults: `tv_weight` 0.2 and 20
//! steps (ASD-POCS's α and N_grad), SART μ = 1, at most 50 iterations, plateau rule on.
//! `tv_weight = 0` is plain SART.

use std::ops::ControlFlow;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{drive, sart::SartSweep, IterState, Problem, Report, Stopping};
use crate::{Grid, SolveError};

/// Parameters of [`sart_tv`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TvParams {
    /// SART relaxation μ, in (0, 2). Default 1.
    pub relaxation: f64,
    /// TV step per descent step, as a fraction of the SART step's size; at most 1 (0: plain
    /// SART). Default 0.2.
    pub tv_weight: f64,
    /// TV descent steps per iteration; at most 1000 (0: plain SART). Default 20.
    pub tv_steps: usize,
    /// Default: at most 50 iterations, plateau rule on.
    pub stopping: Stopping,
    /// How the TV step's length follows the SART step's. Default [`TvStepRule::Auto`]; a
    /// configuration that names none ran [`TvStepRule::Data`], and keeps it.
    #[serde(default = "TvStepRule::before_the_rule")]
    pub step_rule: TvStepRule,
}

/// How the length of SART-TV's descent steps is set ([`TvParams::step_rule`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TvStepRule {
    /// [`TvStepRule::Balanced`] when the problem holds voxels at zero outside a support (a
    /// visual hull), [`TvStepRule::Data`] otherwise: chosen on the synthetic jet, where the
    /// data rule is the better one without a hull and smooths a hull's voxels far too hard
    /// (docs/claims.md).
    #[default]
    Auto,
    /// `tv_weight · d` in every iteration, `d` that iteration's SART step.
    Data,
    /// `tv_weight · d` times a factor that starts at 1 and shrinks by 0.95 after every
    /// iteration whose TV steps changed the volume by more than 0.95 of its SART step: the
    /// balance of ASD-POCS (Sidky & Pan 2008), so that the TV steps do not outweigh the data's
    /// however few voxels they move.
    Balanced,
}

impl TvStepRule {
    fn before_the_rule() -> Self {
        TvStepRule::Data
    }

    /// The rule that applies to a problem with (`true`) or without a support.
    pub fn resolve(self, support: bool) -> TvStepRule {
        match self {
            TvStepRule::Auto if support => TvStepRule::Balanced,
            TvStepRule::Auto => TvStepRule::Data,
            rule => rule,
        }
    }

    /// The name in configurations and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            TvStepRule::Auto => "auto",
            TvStepRule::Data => "data",
            TvStepRule::Balanced => "balanced",
        }
    }
}

impl Default for TvParams {
    fn default() -> Self {
        TvParams {
            relaxation: 1.0,
            tv_weight: 0.2,
            tv_steps: 20,
            stopping: Stopping::with_cap(50),
            step_rule: TvStepRule::Auto,
        }
    }
}

/// Compiles `$body` (plain loops over slices that LLVM vectorises) for AVX-512, for AVX2 and
/// for the baseline, and runs the one [`crate::Isa::detected`] names, as the projectors do. No fused
/// multiply–adds are formed and division and square root are exact, so every version gives the
/// same bits.
macro_rules! dispatched {
    ($(#[$meta:meta])* fn $name:ident($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$meta])*
        fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn body($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx2")]
                unsafe fn avx512($($arg: $ty),*) $(-> $ret)? {
                    body($($arg),*)
                }
                #[target_feature(enable = "avx2")]
                unsafe fn avx2($($arg: $ty),*) $(-> $ret)? {
                    body($($arg),*)
                }
                match crate::Isa::detected() {
                    // SAFETY: the CPU has AVX-512F and AVX2 (`Isa::detected`).
                    crate::Isa::Avx512 => return unsafe { avx512($($arg),*) },
                    // SAFETY: the CPU has AVX2 (`Isa::detected`).
                    crate::Isa::Avx2 => return unsafe { avx2($($arg),*) },
                    crate::Isa::Baseline => {}
                }
            }
            body($($arg),*)
        }
    };
}

/// A grid row `c` along `x` and the rows before it along `y` and `z` (`ym`, `zm`, each `None`
/// across the grid's face, where the difference is zero).
#[derive(Clone, Copy)]
struct Rows<'a> {
    c: &'a [f32],
    ym: Option<&'a [f32]>,
    zm: Option<&'a [f32]>,
}

dispatched! {
    /// The norms of the backward differences along a row (see [`Rows`]).
    fn row_norms(r: Rows<'_>, eps2: f32, out: &mut [f32]) {
        let n = r.c.len();
        let (has_y, has_z) = (r.ym.is_some(), r.zm.is_some());
        let (ym, zm) = (r.ym.unwrap_or(r.c), r.zm.unwrap_or(r.c));
        let (ym, zm, out) = (&ym[..n], &zm[..n], &mut out[..n]);
        for i in 0..n {
            let v = r.c[i];
            let dx = if i > 0 { v - r.c[i - 1] } else { 0.0 };
            let dy = if has_y { v - ym[i] } else { 0.0 };
            let dz = if has_z { v - zm[i] } else { 0.0 };
            out[i] = (dx * dx + dy * dy + dz * dz + eps2).sqrt();
        }
    }
}

dispatched! {
    /// `∇TV` along a row (see [`Rows`]) from the norms of its differences `cn` and of the rows
    /// after it along `y` and `z` (`yp`, `zp`: the rows and their norms).
    fn row_gradient(
        r: Rows<'_>,
        cn: &[f32],
        yp: Option<(&[f32], &[f32])>,
        zp: Option<(&[f32], &[f32])>,
        out: &mut [f32],
    ) {
        let n = r.c.len();
        let (has_y, has_z, next_y, next_z) = (r.ym.is_some(), r.zm.is_some(), yp.is_some(), zp.is_some());
        let (ym, zm) = (r.ym.unwrap_or(r.c), r.zm.unwrap_or(r.c));
        let ((yv, yn), (zv, zn)) = (yp.unwrap_or((r.c, cn)), zp.unwrap_or((r.c, cn)));
        let (c, ym, zm, cn, out) = (r.c, &ym[..n], &zm[..n], &cn[..n], &mut out[..n]);
        let (yv, yn, zv, zn) = (&yv[..n], &yn[..n], &zv[..n], &zn[..n]);
        for i in 0..n {
            let v = c[i];
            let dx = if i > 0 { v - c[i - 1] } else { 0.0 };
            let dy = if has_y { v - ym[i] } else { 0.0 };
            let dz = if has_z { v - zm[i] } else { 0.0 };
            let mut s = (dx + dy + dz) / cn[i];
            if i + 1 < n {
                s -= (c[i + 1] - v) / cn[i + 1];
            }
            if next_y {
                s -= (yv[i] - v) / yn[i];
            }
            if next_z {
                s -= (zv[i] - v) / zn[i];
            }
            out[i] = s;
        }
    }
}

/// `grad = ∇TV(g)` ([`Grid::len`] values), and `‖∇TV‖₂²`. Row by row (each grid row along
/// `x` is contiguous, its neighbours along `y` and `z` are whole rows), vectorised along the
/// row with the CPU's widest instructions; the per-voxel arithmetic is that of the definition,
/// in the same order. Each task takes a band of z-slices and keeps the norms of the
/// differences of two slices at a time (the slice and the next, which the gradient reads),
/// so they stay in cache and the grid is read once and written once. The squared norm is
/// summed per row in f64 and the rows' sums in row order, so it does not depend on the
/// threads.
pub(crate) fn tv_gradient(grid: &Grid, g: &[f32], grad: &mut [f32]) -> f64 {
    let [nx, ny, nz] = grid.dims;
    let slab = nx * ny;
    let len = g.len();
    assert!(grad.len() == len, "tv_gradient: a gradient buffer of the wrong length");
    if len == 0 {
        return 0.0;
    }
    let peak = g.par_chunks(slab.max(1)).map(|c| c.iter().cloned().fold(0.0, f32::max)).reduce(|| 0.0, f32::max);
    let eps2 = (1e-4 * peak).powi(2).max(f32::MIN_POSITIVE);
    let rows = |row: usize| -> Rows<'_> {
        let (j, base) = (row % ny, row * nx);
        Rows {
            c: &g[base..base + nx],
            ym: (j > 0).then(|| &g[base - nx..base]),
            zm: (base >= slab).then(|| &g[base - slab..base - slab + nx]),
        }
    };
    // The norms of slice `k`'s rows.
    let slice_norms = |k: usize, out: &mut [f32]| {
        for (j, o) in out.chunks_exact_mut(nx).enumerate() {
            row_norms(rows(k * ny + j), eps2, o);
        }
    };
    // A few bands per thread, to balance; each computes the norms of the slice after it again.
    let per = nz.div_ceil(4 * rayon::current_num_threads()).max(1);
    let mut row_sums = vec![0f64; nz * ny];
    grad.par_chunks_mut(per * slab).zip(row_sums.par_chunks_mut(per * ny)).enumerate().for_each(|(b, (band, sums))| {
        let k0 = b * per;
        let (mut cur, mut next) = (vec![0f32; slab], vec![0f32; slab]);
        slice_norms(k0, &mut cur);
        for (kk, (out, sums)) in band.chunks_exact_mut(slab).zip(sums.chunks_exact_mut(ny)).enumerate() {
            let k = k0 + kk;
            if k + 1 < nz {
                slice_norms(k + 1, &mut next);
            }
            for (j, (out, sum)) in out.chunks_exact_mut(nx).zip(sums.iter_mut()).enumerate() {
                let base = (k * ny + j) * nx;
                let yp = (j + 1 < ny).then(|| (&g[base + nx..base + 2 * nx], &cur[(j + 1) * nx..(j + 2) * nx]));
                let zp = (k + 1 < nz).then(|| (&g[base + slab..base + slab + nx], &next[j * nx..(j + 1) * nx]));
                row_gradient(rows(k * ny + j), &cur[j * nx..(j + 1) * nx], yp, zp, out);
                *sum = out.iter().map(|&s| (s as f64) * (s as f64)).sum::<f64>();
            }
            std::mem::swap(&mut cur, &mut next);
        }
    });
    row_sums.iter().sum()
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

/// `‖a − b‖₂`, summed in f64.
fn distance(a: &[f32], b: &[f32]) -> f64 {
    a.par_iter().zip(b.par_iter()).map(|(&a, &b)| ((a - b) as f64).powi(2)).sum::<f64>().sqrt()
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
    let mut grad = vec![0f32; n];
    let weight = params.tv_weight;
    let rule = params.step_rule.resolve(problem.support.is_some());
    // The balanced rule's factor on the step.
    let mut balance = 1.0f64;
    drive(
        "SART-TV",
        problem,
        &params.stopping,
        x,
        |x, _| {
            before.copy_from_slice(x);
            let ss = sweep.run(problem, x);
            let d = distance(x, &before);
            if weight > 0.0 && d > 0.0 {
                if rule == TvStepRule::Balanced {
                    before.copy_from_slice(x);
                }
                let length = balance * weight * d;
                for _ in 0..params.tv_steps {
                    let gn = tv_gradient(&grid, x, &mut grad).sqrt();
                    if gn == 0.0 {
                        break;
                    }
                    let step = (length / gn) as f32;
                    // The descent step and the feasible set (non-negative, zero outside the
                    // support) in one pass.
                    let grad = &grad;
                    match problem.support {
                        Some(keep) => x.par_chunks_mut(4096).enumerate().for_each(|(c, xs)| {
                            let at = c * 4096;
                            for ((g, &dg), &keep) in xs.iter_mut().zip(&grad[at..]).zip(&keep[at..]) {
                                *g = if keep { (*g - step * dg).max(0.0) } else { 0.0 };
                            }
                        }),
                        None => x.par_chunks_mut(4096).zip(grad.par_chunks(4096)).for_each(|(xs, gs)| {
                            for (g, &dg) in xs.iter_mut().zip(gs) {
                                *g = (*g - step * dg).max(0.0);
                            }
                        }),
                    }
                }
                if rule == TvStepRule::Balanced && distance(x, &before) > 0.95 * d {
                    balance *= 0.95;
                }
            }
            ss
        },
        on_iter,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::Aabb;
    use glam::DVec3;
    use rand::{Rng, SeedableRng};

    /// The gradient as the definition reads, voxel by voxel with its own index arithmetic (the
    /// implementation before the row-by-row one), and `‖∇TV‖₂²` summed in f64.
    fn reference(grid: &Grid, g: &[f32]) -> (Vec<f32>, f64) {
        let [nx, ny, _] = grid.dims;
        let slab = nx * ny;
        let peak = g.iter().cloned().fold(0.0, f32::max);
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
        let norms: Vec<f32> = (0..g.len())
            .map(|m| {
                let d = diffs(m);
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + eps2).sqrt()
            })
            .collect();
        let grad: Vec<f32> = (0..g.len())
            .map(|m| {
                let d = diffs(m);
                let mut s = (d[0] + d[1] + d[2]) / norms[m];
                let (i, j) = (m % nx, (m / nx) % ny);
                if i + 1 < nx {
                    s -= diffs(m + 1)[0] / norms[m + 1];
                }
                if j + 1 < ny {
                    s -= diffs(m + nx)[1] / norms[m + nx];
                }
                if m + slab < g.len() {
                    s -= diffs(m + slab)[2] / norms[m + slab];
                }
                s
            })
            .collect();
        let n2 = grad.iter().map(|&v| (v as f64) * (v as f64)).sum();
        (grad, n2)
    }

    /// The row-by-row gradient is the definition's bit for bit, on grids of odd shapes (one
    /// voxel thick along each axis in turn) with flat, empty and random regions.
    #[test]
    fn tv_gradient_matches_the_definition_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for dims in [[7, 5, 3], [1, 6, 4], [9, 1, 5], [4, 3, 1], [33, 17, 9], [20, 11, 41]] {
            let grid = Grid::new(dims, Aabb::cube(DVec3::ZERO, 1.0));
            let g: Vec<f32> = (0..grid.len())
                .map(|m| match m % 5 {
                    0 => 0.0,
                    1 => 0.5,
                    _ => rng.random_range(0.0..2.0),
                })
                .collect();
            let (want, want_n2) = reference(&grid, &g);
            let mut grad = vec![0f32; grid.len()];
            let n2 = tv_gradient(&grid, &g, &mut grad);
            for (m, (a, b)) in grad.iter().zip(&want).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{dims:?} voxel {m}: {a} vs {b}");
            }
            assert!((n2 - want_n2).abs() <= 1e-12 * want_n2, "{dims:?}: {n2} vs {want_n2}");
        }
    }

    /// Isotropic TV by hand: an edge across a row counts its height once, a corner voxel whose
    /// differences along `x` and `y` are both 1 counts √2.
    #[test]
    fn total_variation_of_an_edge_and_a_corner() {
        let row = Grid::new([4, 1, 1], Aabb::cube(DVec3::ZERO, 1.0));
        assert_eq!(total_variation(&row, &[0.0, 0.0, 1.5, 1.5]), 1.5);
        assert_eq!(total_variation(&row, &[2.0, 0.0, 2.0, 2.0]), 4.0);
        let square = Grid::new([2, 2, 1], Aabb::cube(DVec3::ZERO, 1.0));
        assert_eq!(total_variation(&square, &[0.0, 1.0, 1.0, 1.0]), 2.0);
        assert!((total_variation(&square, &[0.0, 0.0, 0.0, 1.0]) - 2f64.sqrt()).abs() < 1e-7);
        let column = Grid::new([1, 1, 3], Aabb::cube(DVec3::ZERO, 1.0));
        assert_eq!(total_variation(&column, &[1.0, 3.0, 3.0]), 2.0);
    }

    /// An identity projector: SART with μ = 1 lands on the data in one sweep, so an
    /// iteration's SART step is known and the TV steps can be measured against it.
    fn identity(voxels: usize) -> crate::solve::dense::Dense {
        let rows = (0..voxels).map(|i| (0..voxels).map(|j| if i == j { 1.0 } else { 0.0 }).collect()).collect();
        crate::solve::dense::Dense::new(voxels, vec![rows])
    }

    fn params(tv_weight: f64, tv_steps: usize, step_rule: TvStepRule, iterations: usize) -> TvParams {
        TvParams {
            relaxation: 1.0,
            tv_weight,
            tv_steps,
            stopping: Stopping { max_iterations: iterations, plateau: None },
            step_rule,
        }
    }

    /// One TV step moves the volume by `tv_weight × d` (d the SART step's length), down the
    /// TV gradient, and lowers the TV; zero weight or zero steps is plain SART.
    #[test]
    fn a_tv_step_has_the_weighted_length_of_the_sart_step() {
        let dense = identity(4);
        let data = [1.0, 3.0, 1.0, 3.0];
        let images = dense.images(&[&data]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let init = [1.0f32; 4];
        let go = |_: &IterState| ControlFlow::Continue(());
        let d = distance(&data, &init);
        for rule in [TvStepRule::Data, TvStepRule::Balanced] {
            let x = sart_tv(&problem, Some(&init), &params(0.3, 1, rule, 1), go).expect("runs").volume;
            assert!((distance(&x, &data) - 0.3 * d).abs() < 1e-5 * d, "{rule:?}: {x:?}");
            let mut grad = vec![0f32; 4];
            let gn = tv_gradient(problem.projector.grid(), &data, &mut grad).sqrt();
            for ((xi, pi), gi) in x.iter().zip(&data).zip(&grad) {
                let want = pi - (0.3 * d / gn) as f32 * gi;
                assert!((xi - want).abs() < 1e-5, "{rule:?}: {x:?}");
            }
            let grid = problem.projector.grid();
            assert!(total_variation(grid, &x) < total_variation(grid, &data));
            for plain in [params(0.0, 1, rule, 1), params(0.3, 0, rule, 1)] {
                assert_eq!(sart_tv(&problem, Some(&init), &plain, go).expect("runs").volume, data);
            }
        }
        // Three steps go no farther than three times the length.
        let x = sart_tv(&problem, Some(&init), &params(0.3, 3, TvStepRule::Data, 1), go).expect("runs").volume;
        let moved = distance(&x, &data);
        assert!(moved > 0.0 && moved <= 0.9 * d + 1e-5, "{moved} against {d}");
    }

    /// The balanced rule shrinks the step by 0.95 after an iteration whose TV steps moved the
    /// volume more than 0.95 of its SART step, and only then; the data rule never does.
    #[test]
    fn the_balanced_rule_shrinks_the_step_after_tv_outweighs_the_data() {
        let dense = identity(4);
        let data = [1.0, 3.0, 1.0, 3.0];
        let images = dense.images(&[&data]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        for (rule, weight, shrink) in
            [(TvStepRule::Balanced, 0.97, 0.95), (TvStepRule::Balanced, 0.5, 1.0), (TvStepRule::Data, 0.97, 1.0)]
        {
            let mut first = Vec::new();
            let x = sart_tv(&problem, Some(&[1.0; 4]), &params(weight, 1, rule, 2), |s: &IterState| {
                if s.iteration == 1 {
                    first = s.volume.to_vec();
                }
                ControlFlow::Continue(())
            })
            .expect("runs")
            .volume;
            // The second sweep lands on the data again, from where the first iteration left.
            let d = distance(&data, &first);
            let moved = distance(&x, &data);
            assert!((moved - shrink * weight * d).abs() < 1e-4 * d, "{rule:?} {weight}: {moved} against {d}");
        }
    }

    /// A flat volume has no TV gradient: the descent stops instead of dividing by zero.
    #[test]
    fn a_flat_volume_stays_flat() {
        let dense = identity(3);
        let images = dense.images(&[&[2.0, 2.0, 2.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let x = sart_tv(&problem, Some(&[1.0; 3]), &params(0.3, 5, TvStepRule::Data, 1), |_| ControlFlow::Continue(()))
            .expect("runs")
            .volume;
        assert_eq!(x, [2.0; 3]);
    }

    /// Inside a support the TV step moves the voxels inside it and keeps those outside at
    /// zero: from SART's (0, 4, 4, 0) the step down the gradient (−1, 1, 1, −1) / 2 of length
    /// 0.3 × ‖(0, 4, 4, 0)‖ would raise the last voxel too, but it lies outside.
    #[test]
    fn tv_steps_keep_the_support_and_non_negativity() {
        let dense = identity(4);
        let data = [0.0, 4.0, 4.0, 0.1];
        let images = dense.images(&[&data]);
        let support = [true, true, true, false];
        let problem = Problem::new(&dense, &images).expect("consistent").with_support(&support);
        let x = sart_tv(&problem, Some(&[0.0; 4]), &params(0.3, 1, TvStepRule::Data, 1), |_| ControlFlow::Continue(()))
            .expect("runs")
            .volume;
        let h = 0.3 * 32f32.sqrt() / 2.0;
        crate::solve::dense::assert_close(&x, &[h, 4.0 - h, 4.0 - h, 0.0], 1e-4);
    }

    /// A configuration that names no step rule ran the data rule and keeps it; a new one
    /// takes `auto`, which is the balanced rule inside a support only.
    #[test]
    fn a_configuration_without_a_step_rule_keeps_the_data_rule() {
        let old: TvParams = serde_json::from_str(r#"{"tv_weight": 0.2}"#).expect("reads");
        assert_eq!(old.step_rule, TvStepRule::Data);
        let new: TvParams = serde_json::from_str(&serde_json::to_string(&TvParams::default()).unwrap()).unwrap();
        assert_eq!(new.step_rule, TvStepRule::Auto);
        assert!(serde_json::to_string(&TvParams::default()).unwrap().contains(r#""step_rule":"auto""#));
        assert_eq!(TvStepRule::Auto.resolve(true), TvStepRule::Balanced);
        assert_eq!(TvStepRule::Auto.resolve(false), TvStepRule::Data);
        assert_eq!(TvStepRule::Data.resolve(true), TvStepRule::Data);
        for rule in [TvStepRule::Auto, TvStepRule::Data, TvStepRule::Balanced] {
            assert_eq!(serde_json::to_string(&rule).unwrap(), format!("\"{}\"", rule.name()));
        }
    }
}
