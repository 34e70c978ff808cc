//! SART with second-order Tikhonov regularisation: a smoothness prior for noisy or few views
//! (dissertation §2.4.1, Eq. 2.34–2.35, after Tikhonov 1963 and the review of emission
//! tomography by Grauer et al., its ref. [1]; §4.1 cites Liu et al., ref. [180], who compared
//! Tikhonov with ART, Landweber and truncated SVD for chemiluminescence tomography).
//!
//! The problem is Eq. 2.35 with `L_Tik` the discrete Laplacian ∇² ([`laplacian`]):
//!
//! ```text
//! g_Tik = argmin_{g ≥ 0} ‖p − A g‖² + λ ‖∇² g‖²                                  (2.35)
//! ```
//!
//! solved by forward–backward splitting in SART's metric. Each iteration is one SART sweep
//! (Eq. 2.27, views in the multilevel order, non-negativity after every view), which handles
//! the data term, followed by one gradient step on the penalty:
//!
//! ```text
//! g ← max(0, g − μ λ Lᵀ L g)        (L = ∇² with unit voxel spacing, so Lᵀ L = L²)
//! ```
//!
//! - **Units.** SART's update is normalised by row and column sums, so its step is in the
//!   units of `g` whatever the imaging scale; with `L` taken in voxel units (spacing 1) the
//!   weight λ is dimensionless and acts at the scale of voxels, where noise and the streaks
//!   of few views live, for any box size.
//! - **Boundaries.** `L` is the graph Laplacian of the voxel grid (reflecting, Neumann
//!   faces): `(L g)_m = Σ_{n ∈ neighbours(m)} (g_n − g_m)` over the up to six face
//!   neighbours. It is symmetric and negative semi-definite, and constants are its null space,
//!   so the penalty smooths without pulling the field towards zero at the box faces (a jet
//!   crosses its inflow face).
//! - **Stability.** The eigenvalues of `Lᵀ L` lie in `[0, 144]` (twice the largest degree,
//!   squared), so the explicit step is split into `⌈144 μ λ⌉` equal sub-steps of at most
//!   `1/144`: every sub-step damps every mode without flipping its sign, for any λ.
//! - **Balance.** One sweep is an incremental gradient pass over `Σ_v f_v + λ ‖L g‖²`, where
//!   `f_v` is view `v`'s data misfit in SART's row- and column-normalised metric; so λ weighs
//!   the penalty against the data of one iteration, and more views mean relatively less
//!   smoothing, as more data should.
//! - Defaults: λ = 0.003, μ = 1, zero start, at most 50 iterations, plateau rule on. An
//!   iteration with λ = 0.003 damps the checkerboard mode by 1 − 0.003 × 144 ≈ 0.57 and a
//!   wavelength of four voxels by about 1 %: it removes noise at the voxel scale and leaves
//!   what the data resolve to the data term. The best λ depends on the noise, the views and
//!   how many voxels the field's features span; measured (NRMSE, λ = 0.003 against SART):
//!   - the `demo` jet (15 views of 96² px, 64³ voxels, 40 iterations): 0.204 vs 0.177
//!     without noise, 0.216 vs 0.201 with 2.5 % image noise, 0.247 vs 0.256 with 5 %, 0.326
//!     vs 0.381 with 10 % (there λ = 0.01 gives 0.310); so a smoothness prior pays off on
//!     this sharp-edged, multi-scale field only from about 5 % noise;
//!   - two Gaussian blobs (24³ voxels, 8 views of 48² px, `tests/classical/tikhonov.rs`) with 5 %
//!     noise: 0.437 vs 0.575 (0.30 at SART's best iteration); λ = 0.1 gives 0.185.
//!
//!   An L-curve (Hansen 1992), as §2.4.1 suggests, picks λ for a given experiment. `λ = 0`
//!   is plain SART.

use std::ops::ControlFlow;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{drive, sart::SartSweep, IterState, Problem, Report, Stopping};
use crate::{Grid, SolveError};

/// Upper bound of the spectrum of `Lᵀ L` for the graph Laplacian of a 3D grid: `(2 × 6)²`.
const LTL_SPECTRAL_BOUND: f64 = 144.0;

/// Parameters of [`sart_tikhonov`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TikhonovParams {
    /// SART relaxation μ (Eq. 2.27), in (0, 2). Default 1.
    pub relaxation: f64,
    /// Weight λ of the penalty `‖∇² g‖²` (Eq. 2.35), in voxel units; at most 10. Default 0.003.
    pub weight: f64,
    /// Default: at most 50 iterations, plateau rule on.
    pub stopping: Stopping,
}

impl Default for TikhonovParams {
    fn default() -> Self {
        TikhonovParams { relaxation: 1.0, weight: 0.003, stopping: Stopping::with_cap(50) }
    }
}

/// The graph Laplacian of the grid with unit spacing (see the module docs):
/// `out[m] = Σ_{n ∈ face neighbours of m} (g[n] − g[m])`. In the interior this is the
/// 7-point stencil `g[m±x] + g[m±y] + g[m±z] − 6 g[m]`; at the faces missing neighbours count
/// as equal to `g[m]` (zero flux). `g` and `out` have [`Grid::len`] elements, x fastest.
pub fn laplacian(grid: &Grid, g: &[f32], out: &mut [f32]) {
    let [nx, ny, nz] = grid.dims;
    assert_eq!(g.len(), grid.len(), "laplacian: input has the wrong length");
    assert_eq!(out.len(), grid.len(), "laplacian: output has the wrong length");
    let slab = nx * ny;
    out.par_chunks_mut(nx).enumerate().for_each(|(row, out_row)| {
        let (j, k) = (row % ny, row / ny);
        let base = row * nx;
        let centre = &g[base..base + nx];
        // Neighbouring rows in y and z; a missing one is the row itself (zero flux).
        let ym = if j > 0 { &g[base - nx..base] } else { centre };
        let yp = if j + 1 < ny { &g[base + nx..base + 2 * nx] } else { centre };
        let zm = if k > 0 { &g[base - slab..base - slab + nx] } else { centre };
        let zp = if k + 1 < nz { &g[base + slab..base + slab + nx] } else { centre };
        for i in 0..nx {
            let v = centre[i];
            let xm = if i > 0 { centre[i - 1] } else { v };
            let xp = if i + 1 < nx { centre[i + 1] } else { v };
            out_row[i] = (xm + xp + ym[i] + yp[i] + zm[i] + zp[i]) - 6.0 * v;
        }
    });
}

/// `‖∇² g‖₂²` with the [`laplacian`] of the grid: the penalty of Eq. 2.35 without λ.
pub fn laplacian_norm2(grid: &Grid, g: &[f32]) -> f64 {
    let mut lg = vec![0f32; g.len()];
    laplacian(grid, g, &mut lg);
    lg.par_iter().map(|&v| (v as f64) * (v as f64)).sum()
}

/// One explicit step `g ← max(0, g − step · L² g)` (split into stable sub-steps), with `lg` as
/// scratch ([`Grid::len`] values).
fn penalty_step(problem: &Problem, grid: &Grid, step: f64, x: &mut [f32], lg: &mut [f32]) {
    if step <= 0.0 {
        return;
    }
    let substeps = (step * LTL_SPECTRAL_BOUND).ceil().max(1.0) as usize;
    let h = (step / substeps as f64) as f32;
    let [nx, ny, nz] = grid.dims;
    let slab = nx * ny;
    for _ in 0..substeps {
        laplacian(grid, x, lg);
        // g −= h · L (L g), fused: the second Laplacian is evaluated row by row from `lg`.
        let lg = &*lg;
        x.par_chunks_mut(nx).enumerate().for_each(|(row, x_row)| {
            let (j, k) = (row % ny, row / ny);
            let base = row * nx;
            let centre = &lg[base..base + nx];
            let ym = if j > 0 { &lg[base - nx..base] } else { centre };
            let yp = if j + 1 < ny { &lg[base + nx..base + 2 * nx] } else { centre };
            let zm = if k > 0 { &lg[base - slab..base - slab + nx] } else { centre };
            let zp = if k + 1 < nz { &lg[base + slab..base + slab + nx] } else { centre };
            for i in 0..nx {
                let v = centre[i];
                let xm = if i > 0 { centre[i - 1] } else { v };
                let xp = if i + 1 < nx { centre[i + 1] } else { v };
                let llg = (xm + xp + ym[i] + yp[i] + zm[i] + zp[i]) - 6.0 * v;
                x_row[i] = (x_row[i] - h * llg).max(0.0);
            }
        });
        problem.project_feasible(x);
    }
}

/// SART with second-order Tikhonov regularisation (Eq. 2.35); see the module docs. `init`
/// replaces the zero start.
pub fn sart_tikhonov(
    problem: &Problem,
    init: Option<&[f32]>,
    params: &TikhonovParams,
    on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    if !(params.weight >= 0.0 && params.weight.is_finite()) {
        return Err(crate::ClassicalError::invalid(
            "Tikhonov weight",
            format!("must be ≥ 0, got {}", fluidnerf_core::num(params.weight)),
        ));
    }
    let grid = *problem.projector.grid();
    let n = grid.len();
    let x = problem.start(init, || vec![0f32; n]);
    let mut sweep = SartSweep::new(problem, params.relaxation);
    let mut lg = vec![0f32; n];
    let step = params.relaxation * params.weight;
    drive(
        "SART-Tikhonov",
        problem,
        &params.stopping,
        x,
        |x, _| {
            let ss = sweep.run(problem, x);
            penalty_step(problem, &grid, step, x, &mut lg);
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

    fn grid(dims: [usize; 3]) -> Grid {
        Grid::new(dims, Aabb::new(DVec3::ZERO, DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64)))
    }

    /// A quadratic `a i² + b j² + c k²` (plus linear terms) has the constant Laplacian
    /// `2 (a + b + c)` at every interior voxel.
    #[test]
    fn laplacian_of_a_quadratic_is_constant_inside() {
        let g = grid([9, 7, 6]);
        let [nx, ny, nz] = g.dims;
        let (a, b, c) = (0.5f32, -1.25f32, 2.0f32);
        let f = |i: usize, j: usize, k: usize| {
            let (x, y, z) = (i as f32, j as f32, k as f32);
            a * x * x + b * y * y + c * z * z + 0.3 * x - 0.7 * y + 1.1 * z + 4.0
        };
        let mut values = vec![0f32; g.len()];
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    values[(k * ny + j) * nx + i] = f(i, j, k);
                }
            }
        }
        let mut lap = vec![0f32; g.len()];
        laplacian(&g, &values, &mut lap);
        let expected = 2.0 * (a + b + c);
        for k in 1..nz - 1 {
            for j in 1..ny - 1 {
                for i in 1..nx - 1 {
                    let got = lap[(k * ny + j) * nx + i];
                    assert!((got - expected).abs() < 1e-3, "({i}, {j}, {k}): {got} vs {expected}");
                }
            }
        }
        // Constants are the null space, at the faces too.
        laplacian(&g, &vec![3.5; g.len()], &mut lap);
        assert!(lap.iter().all(|&v| v == 0.0));
    }

    /// ⟨L x, y⟩ = ⟨x, L y⟩ and ⟨L x, x⟩ ≤ 0 on random vectors, faces included.
    #[test]
    fn laplacian_is_self_adjoint_and_negative_semidefinite() {
        let g = grid([6, 5, 4]);
        let mut s = 12345u64;
        let mut rand = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 40) as f32 / (1u64 << 24) as f32) - 0.5
        };
        let x: Vec<f32> = (0..g.len()).map(|_| rand()).collect();
        let y: Vec<f32> = (0..g.len()).map(|_| rand()).collect();
        let (mut lx, mut ly) = (vec![0f32; g.len()], vec![0f32; g.len()]);
        laplacian(&g, &x, &mut lx);
        laplacian(&g, &y, &mut ly);
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(&p, &q)| p as f64 * q as f64).sum::<f64>();
        let (lxy, xly) = (dot(&lx, &y), dot(&x, &ly));
        assert!((lxy - xly).abs() < 1e-9 * (1.0 + lxy.abs()) + 1e-5, "{lxy} vs {xly}");
        assert!(dot(&lx, &x) <= 0.0);
    }

    /// One view that sees nothing: the SART sweep leaves the volume alone, so an iteration is
    /// the penalty step alone.
    fn blind(voxels: usize) -> crate::solve::dense::Dense {
        crate::solve::dense::Dense::new(voxels, vec![vec![vec![0.0; voxels]]])
    }

    fn smooth(init: &[f32], relaxation: f64, weight: f64) -> Vec<f32> {
        let dense = blind(init.len());
        let images = dense.images(&[&[0.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let params = TikhonovParams { relaxation, weight, stopping: Stopping { max_iterations: 1, plateau: None } };
        sart_tikhonov(&problem, Some(init), &params, |_| ControlFlow::Continue(())).expect("runs").volume
    }

    /// On a row of three voxels a spike (0, 1, 0) has `L g = (1, −2, 1)` and
    /// `L² g = (−3, 6, −3)`: a step of μλ = 0.005 (one sub-step) gives (0.015, 0.97, 0.015),
    /// whichever of μ and λ carries it; an edge (1, 0, 0), `L² g = (2, −3, 1)`, would take its
    /// last voxel below zero, where it is clamped.
    #[test]
    fn a_tikhonov_step_subtracts_the_relaxed_weighted_bilaplacian() {
        let spike = [0.0, 1.0, 0.0];
        crate::solve::dense::assert_close(&smooth(&spike, 1.0, 0.005), &[0.015, 0.97, 0.015], 1e-6);
        crate::solve::dense::assert_close(&smooth(&spike, 0.5, 0.01), &[0.015, 0.97, 0.015], 1e-6);
        crate::solve::dense::assert_close(&smooth(&[1.0, 0.0, 0.0], 1.0, 0.005), &[0.99, 0.015, 0.0], 1e-6);
        assert_eq!(smooth(&spike, 1.0, 0.0), spike, "λ = 0 is plain SART");
    }

    /// A step of 0.1 is taken in ⌈144 × 0.1⌉ = 15 equal sub-steps, each stable.
    #[test]
    fn a_large_tikhonov_step_is_split_into_stable_sub_steps() {
        let g = grid([3, 1, 1]);
        let mut want = vec![0.0f32, 1.0, 0.0];
        let (mut lg, mut llg) = (vec![0f32; 3], vec![0f32; 3]);
        let h = (0.1 / 15.0) as f32;
        for _ in 0..15 {
            laplacian(&g, &want, &mut lg);
            laplacian(&g, &lg, &mut llg);
            for (w, l) in want.iter_mut().zip(&llg) {
                *w = (*w - h * l).max(0.0);
            }
        }
        crate::solve::dense::assert_close(&smooth(&[0.0, 1.0, 0.0], 1.0, 0.1), &want, 1e-6);
    }

    /// A weight that is negative or not a number is refused.
    #[test]
    fn a_negative_or_nan_weight_is_refused() {
        let dense = blind(2);
        let images = dense.images(&[&[0.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        for weight in [-0.1, f64::NAN, f64::INFINITY] {
            let params = TikhonovParams { weight, ..Default::default() };
            assert!(sart_tikhonov(&problem, None, &params, |_| ControlFlow::Continue(())).is_err(), "{weight}");
        }
    }

    /// The checkerboard is the top of the spectrum: L² of it is 144 times it, inside.
    #[test]
    fn checkerboard_reaches_the_spectral_bound() {
        let g = grid([6, 6, 6]);
        let n = g.len();
        let x: Vec<f32> = (0..n).map(|m| if (m % 6 + (m / 6) % 6 + m / 36) % 2 == 0 { 1.0 } else { -1.0 }).collect();
        let (mut lx, mut llx) = (vec![0f32; n], vec![0f32; n]);
        laplacian(&g, &x, &mut lx);
        laplacian(&g, &lx, &mut llx);
        let centre = (3 * 6 + 3) * 6 + 3;
        assert_eq!(llx[centre], LTL_SPECTRAL_BOUND as f32 * x[centre]);
    }
}
