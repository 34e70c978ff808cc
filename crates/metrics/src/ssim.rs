//! Structural similarity (SSIM), dissertation Eq. 6.19, in two forms:
//!
//! - **global** ([`ssim_global`]): Eq. 6.19 evaluated once with the means, variances and
//!   covariance of the whole arrays (one window covering everything);
//! - **windowed** ([`ssim_2d`], [`ssim_3d`]): Eq. 6.19 evaluated in a window around every
//!   voxel whose window lies inside the array, then averaged (mean SSIM, Wang et al. 2004).
//!   This reproduces `skimage.metrics.structural_similarity` (scikit-image 0.26) with its
//!   defaults: a 7-wide uniform window (or, with [`SsimWindow::Gaussian`], a Gaussian of
//!   σ = 1.5 truncated at 3.5 σ, i.e. 11 taps, as `gaussian_weights=True`), K₁ = 0.01,
//!   K₂ = 0.03, sample covariance (`N/(N−1)` with `N` the window's voxel count), mean over the
//!   interior where the window fits (skimage crops `(win − 1)/2` from every side).
//!
//! ```text
//! SSIM = (2 μ_E μ_Ê + c₁)(2 σ_EÊ + c₂) / ((μ_E² + μ_Ê² + c₁)(σ_E² + σ_Ê² + c₂)),
//! c₁ = (K₁ R)², c₂ = (K₂ R)²,  R the data range.
//! ```
//!
//! The dissertation does not give its constants; we use Wang's K₁, K₂ above with `R` the
//! truth's value range by default ([`crate::data_range_of`]).
//!
//! Arrays are f32, x fastest (`data[(k * ny + j) * nx + i]`, as [`fluidnerf_core::Volume`];
//! images row-major, as [`fluidnerf_core::Image`]); statistics accumulate in f64.
//!
//! Speed: the five local moments (E, Ê, E², Ê², EÊ) are filtered separably. The uniform window
//! uses running sums along every axis (cost independent of the window size); the Gaussian window
//! uses direct taps. 3D work is split over output z-slabs with rayon, each slab holding only a
//! few planes of f64 moments.

use fluidnerf_core::num;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{data_range_of, data_range_problem, MetricsError};

/// The window of the local statistics.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub enum SsimWindow {
    /// A cube (square in 2D) of `size` voxels per side with equal weights; `size` must be odd.
    /// skimage's default, with size 7.
    Uniform { size: usize },
    /// A separable Gaussian of standard deviation `sigma` voxels, truncated at 3.5 σ (11 taps
    /// for σ = 1.5), as skimage's `gaussian_weights=True`.
    Gaussian { sigma: f64 },
}

impl SsimWindow {
    /// Number of taps along one axis.
    pub fn size(&self) -> usize {
        match *self {
            SsimWindow::Uniform { size } => size,
            // scipy.ndimage: radius = int(truncate * sigma + 0.5).
            SsimWindow::Gaussian { sigma } => 2 * ((3.5 * sigma + 0.5) as usize) + 1,
        }
    }
}

/// Parameters of the windowed SSIM. The defaults are skimage's.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SsimParams {
    /// Default: uniform, 7 wide.
    pub window: SsimWindow,
    /// Luminance constant, c₁ = (K₁ R)². Default 0.01.
    pub k1: f64,
    /// Contrast constant, c₂ = (K₂ R)². Default 0.03.
    pub k2: f64,
    /// The data range R. Default (`None`): the reference's (second argument's) `max − min`.
    pub data_range: Option<f64>,
    /// Normalise (co)variances by `N − 1` (sample) instead of `N`. Default true, as skimage.
    pub sample_covariance: bool,
}

impl Default for SsimParams {
    fn default() -> Self {
        SsimParams {
            window: SsimWindow::Uniform { size: 7 },
            k1: 0.01,
            k2: 0.03,
            data_range: None,
            sample_covariance: true,
        }
    }
}

impl SsimParams {
    /// skimage's `gaussian_weights=True` (σ = 1.5, 11 taps).
    pub fn gaussian() -> Self {
        SsimParams { window: SsimWindow::Gaussian { sigma: 1.5 }, ..Default::default() }
    }

    /// Refuses parameters no SSIM can be computed with: an even or empty window, a 1-voxel one
    /// with sample (co)variances, a σ or constant out of range, and a data range whose
    /// constants `(K R)²` vanish in f64 or beyond any two f32 values' difference
    /// ([`data_range_problem`]).
    pub fn validate(&self) -> Result<(), MetricsError> {
        match self.window {
            SsimWindow::Uniform { size } if size == 0 || size % 2 == 0 => {
                return Err(MetricsError::invalid("SSIM window size", format!("must be odd and positive, got {size}")))
            }
            SsimWindow::Uniform { size: 1 } if self.sample_covariance => {
                return Err(MetricsError::invalid(
                    "SSIM window size",
                    "must be at least 3 with sample (co)variances: a 1-voxel window has none (N - 1 = 0)",
                ))
            }
            SsimWindow::Gaussian { sigma } if !(sigma > 0.0 && sigma.is_finite()) => {
                return Err(MetricsError::invalid(
                    "SSIM Gaussian sigma",
                    format!("must be positive, got {}", num(sigma)),
                ))
            }
            _ => {}
        }
        if !(self.k1 >= 0.0 && self.k2 >= 0.0) {
            return Err(MetricsError::invalid(
                "SSIM constants",
                format!("K1 {} and K2 {} must be >= 0", num(self.k1), num(self.k2)),
            ));
        }
        if let Some(why) = self.data_range.and_then(|r| data_range_problem(r, [self.k1, self.k2])) {
            return Err(MetricsError::invalid("SSIM data range", why));
        }
        Ok(())
    }
}

/// Global SSIM, Eq. 6.19 over the whole arrays as a single window: μ the means, σ² the
/// (population) variances, σ_EÊ the covariance, c₁ = (0.01 R)², c₂ = (0.03 R)² with
/// `R = data_range`. Symmetric in its arguments; 1 for identical inputs. Panics if the lengths
/// differ, the slices are empty or `data_range` is not positive; a range [`data_range_problem`]
/// refuses (with the default K's) gives NaN or a meaningless score.
pub fn ssim_global(a: &[f32], b: &[f32], data_range: f64) -> f64 {
    assert_eq!(a.len(), b.len(), "ssim_global: inputs differ in length");
    assert!(!a.is_empty(), "ssim_global: empty inputs");
    assert!(data_range > 0.0, "ssim_global: data_range must be positive, got {data_range}");
    let n = a.len() as f64;
    let (sa, sb) = a.iter().zip(b).fold((0f64, 0f64), |(sa, sb), (&x, &y)| (sa + x as f64, sb + y as f64));
    let (ma, mb) = (sa / n, sb / n);
    // Second pass about the means: no cancellation for large offsets.
    let (vaa, vbb, vab) = a.iter().zip(b).fold((0f64, 0f64, 0f64), |(vaa, vbb, vab), (&x, &y)| {
        let (dx, dy) = (x as f64 - ma, y as f64 - mb);
        (vaa + dx * dx, vbb + dy * dy, vab + dx * dy)
    });
    let (va, vb, cov) = (vaa / n, vbb / n, vab / n);
    let c1 = (0.01 * data_range).powi(2);
    let c2 = (0.03 * data_range).powi(2);
    (2.0 * ma * mb + c1) * (2.0 * cov + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
}

/// Mean windowed SSIM of two `width × height` row-major images (`a` the estimate, `b` the
/// reference), as `skimage.metrics.structural_similarity(a, b, data_range=R)` with the
/// parameters' window. Errors if a side is shorter than the window or a parameter is invalid;
/// panics if a slice's length is not `width * height`.
pub fn ssim_2d(a: &[f32], b: &[f32], width: usize, height: usize, params: &SsimParams) -> Result<f64, MetricsError> {
    assert_eq!(a.len(), width * height, "ssim_2d: a is not {width}x{height}");
    assert_eq!(b.len(), width * height, "ssim_2d: b is not {width}x{height}");
    windowed(a, b, [width, height, 1], 2, params)
}

/// Mean windowed SSIM of two `nx × ny × nz` volumes (x fastest; `a` the estimate, `b` the
/// reference), as `skimage.metrics.structural_similarity` on the `(nz, ny, nx)` arrays.
/// Errors if a side is shorter than the window or a parameter is invalid; panics if a slice's
/// length is not `nx * ny * nz`.
pub fn ssim_3d(a: &[f32], b: &[f32], dims: [usize; 3], params: &SsimParams) -> Result<f64, MetricsError> {
    let n = dims[0] * dims[1] * dims[2];
    assert_eq!(a.len(), n, "ssim_3d: a does not match dims {dims:?}");
    assert_eq!(b.len(), n, "ssim_3d: b does not match dims {dims:?}");
    windowed(a, b, dims, 3, params)
}

/// Filter taps along one axis.
enum Taps {
    /// `n` equal taps, applied as running sums (unnormalised; scaled once at the end).
    Box(usize),
    /// Explicit normalised weights.
    Weights(Vec<f64>),
}

impl Taps {
    fn len(&self) -> usize {
        match self {
            Taps::Box(n) => *n,
            Taps::Weights(w) => w.len(),
        }
    }

    /// The factor that turns this axis' output into a weighted mean.
    fn norm(&self) -> f64 {
        match self {
            Taps::Box(n) => 1.0 / *n as f64,
            Taps::Weights(_) => 1.0,
        }
    }
}

/// scipy.ndimage's `_gaussian_kernel1d` (order 0): exp(−x²/2σ²) for |x| ≤ radius, normalised.
fn gaussian_taps(sigma: f64, size: usize) -> Vec<f64> {
    let r = (size / 2) as f64;
    let mut w: Vec<f64> = (0..size).map(|i| (-0.5 * ((i as f64 - r) / sigma).powi(2)).exp()).collect();
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= s);
    w
}

/// The five local moments of the pair, one f64 plane (or row) each.
struct Moments {
    m: [Vec<f64>; 5],
}

impl Moments {
    fn zeros(n: usize) -> Self {
        Moments { m: std::array::from_fn(|_| vec![0.0; n]) }
    }

    fn clear(&mut self) {
        self.m.iter_mut().for_each(|v| v.fill(0.0));
    }

    /// Adds `c ×` the moments of the pair `(a, b)` element-wise.
    fn add(&mut self, a: &[f32], b: &[f32], c: f64) {
        let [m0, m1, m2, m3, m4] = &mut self.m;
        for (i, (&x, &y)) in a.iter().zip(b).enumerate() {
            let (x, y) = (x as f64, y as f64);
            let (cx, cy) = (c * x, c * y);
            m0[i] += cx;
            m1[i] += cy;
            m2[i] += cx * x;
            m3[i] += cy * y;
            m4[i] += cx * y;
        }
    }
}

/// Filters `src` (rows of `row_len` values) along the row index with `taps`, keeping only the
/// rows whose window fits: `dst` has `rows − taps + 1` rows.
fn filter_rows(src: &[f64], dst: &mut [f64], row_len: usize, taps: &Taps) {
    let rows_in = src.len() / row_len;
    let rows_out = dst.len() / row_len;
    debug_assert_eq!(rows_out, rows_in + 1 - taps.len());
    match taps {
        Taps::Box(n) => {
            let (first, _) = dst.split_at_mut(row_len);
            first.fill(0.0);
            for r in 0..*n {
                for (d, &s) in first.iter_mut().zip(&src[r * row_len..(r + 1) * row_len]) {
                    *d += s;
                }
            }
            for ro in 1..rows_out {
                let (done, rest) = dst.split_at_mut(ro * row_len);
                let prev = &done[(ro - 1) * row_len..];
                let cur = &mut rest[..row_len];
                let add = &src[(ro + n - 1) * row_len..(ro + n) * row_len];
                let sub = &src[(ro - 1) * row_len..ro * row_len];
                for i in 0..row_len {
                    cur[i] = prev[i] + add[i] - sub[i];
                }
            }
        }
        Taps::Weights(w) => {
            for ro in 0..rows_out {
                let cur = &mut dst[ro * row_len..(ro + 1) * row_len];
                cur.fill(0.0);
                for (t, &wt) in w.iter().enumerate() {
                    let s = &src[(ro + t) * row_len..(ro + t + 1) * row_len];
                    for (d, &v) in cur.iter_mut().zip(s) {
                        *d += wt * v;
                    }
                }
            }
        }
    }
}

/// Filters one contiguous line with `taps`, keeping the `src.len() − taps + 1` outputs whose
/// window fits.
fn filter_line(src: &[f64], dst: &mut [f64], taps: &Taps) {
    debug_assert_eq!(dst.len(), src.len() + 1 - taps.len());
    match taps {
        Taps::Box(n) => {
            let mut acc: f64 = src[..*n].iter().sum();
            dst[0] = acc;
            for i in 1..dst.len() {
                acc += src[i + n - 1] - src[i - 1];
                dst[i] = acc;
            }
        }
        Taps::Weights(w) => {
            for (d, win) in dst.iter_mut().zip(src.windows(w.len())) {
                *d = win.iter().zip(w).map(|(v, wt)| v * wt).sum();
            }
        }
    }
}

/// Constants of the SSIM formula.
#[derive(Clone, Copy)]
struct Consts {
    c1: f64,
    c2: f64,
    /// Turns the filtered sums into means.
    mean_norm: f64,
    /// N/(N−1) or 1.
    cov_norm: f64,
}

impl Consts {
    #[inline]
    fn ssim(&self, sx: f64, sy: f64, sxx: f64, syy: f64, sxy: f64) -> f64 {
        let (ux, uy) = (sx * self.mean_norm, sy * self.mean_norm);
        let vx = self.cov_norm * (sxx * self.mean_norm - ux * ux);
        let vy = self.cov_norm * (syy * self.mean_norm - uy * uy);
        let vxy = self.cov_norm * (sxy * self.mean_norm - ux * uy);
        (2.0 * ux * uy + self.c1) * (2.0 * vxy + self.c2) / ((ux * ux + uy * uy + self.c1) * (vx + vy + self.c2))
    }
}

fn windowed(a: &[f32], b: &[f32], dims: [usize; 3], ndim: u32, params: &SsimParams) -> Result<f64, MetricsError> {
    params.validate()?;
    let win = params.window.size();
    let wins = [win, win, if ndim == 3 { win } else { 1 }];
    if (0..3).any(|ax| dims[ax] < wins[ax]) {
        let shown = &dims[..ndim as usize];
        return Err(MetricsError::TooSmall { dims: shown.to_vec(), window: win });
    }
    let range = params.data_range.unwrap_or_else(|| data_range_of(b));
    let np = (win as f64).powi(ndim as i32);
    let make = |n: usize| match params.window {
        SsimWindow::Uniform { .. } => Taps::Box(n),
        SsimWindow::Gaussian { sigma } if n > 1 => Taps::Weights(gaussian_taps(sigma, n)),
        SsimWindow::Gaussian { .. } => Taps::Weights(vec![1.0]),
    };
    let taps = [make(wins[0]), make(wins[1]), make(wins[2])];
    let consts = Consts {
        c1: (params.k1 * range).powi(2),
        c2: (params.k2 * range).powi(2),
        mean_norm: taps.iter().map(Taps::norm).product(),
        cov_norm: if params.sample_covariance { np / (np - 1.0) } else { 1.0 },
    };
    let [nx, ny, nz] = dims;
    let out = [nx + 1 - wins[0], ny + 1 - wins[1], nz + 1 - wins[2]];
    // Slabs of output z-slices: enough to keep both cores busy, long enough that refilling the
    // running z-window at each slab's start stays cheap.
    let slab = out[2].div_ceil(4 * rayon::current_num_threads()).max(8);
    let starts: Vec<usize> = (0..out[2]).step_by(slab).collect();
    let sum: f64 =
        starts.par_iter().map(|&k0| slab_sum(a, b, dims, out, &taps, consts, k0..(k0 + slab).min(out[2]))).sum();
    Ok(sum / (out[0] * out[1] * out[2]) as f64)
}

/// Sum of the SSIM map over output z-slices `ks`.
fn slab_sum(
    a: &[f32],
    b: &[f32],
    dims: [usize; 3],
    out: [usize; 3],
    taps: &[Taps; 3],
    c: Consts,
    ks: std::ops::Range<usize>,
) -> f64 {
    let [nx, ny, _] = dims;
    let plane = nx * ny;
    let mut zsum = Moments::zeros(plane);
    let mut ysum = Moments::zeros(nx * out[1]);
    let mut xrow = Moments::zeros(out[0]);
    let slice = |k: usize| (&a[k * plane..(k + 1) * plane], &b[k * plane..(k + 1) * plane]);
    let mut total = 0.0;
    for k in ks.clone() {
        match &taps[2] {
            Taps::Box(n) if k > ks.start => {
                let (pa, pb) = slice(k + n - 1);
                zsum.add(pa, pb, 1.0);
                let (pa, pb) = slice(k - 1);
                zsum.add(pa, pb, -1.0);
            }
            Taps::Box(n) => {
                zsum.clear();
                for t in 0..*n {
                    let (pa, pb) = slice(k + t);
                    zsum.add(pa, pb, 1.0);
                }
            }
            Taps::Weights(w) => {
                zsum.clear();
                for (t, &wt) in w.iter().enumerate() {
                    let (pa, pb) = slice(k + t);
                    zsum.add(pa, pb, wt);
                }
            }
        }
        for q in 0..5 {
            filter_rows(&zsum.m[q], &mut ysum.m[q], nx, &taps[1]);
        }
        for jo in 0..out[1] {
            for q in 0..5 {
                filter_line(&ysum.m[q][jo * nx..(jo + 1) * nx], &mut xrow.m[q], &taps[0]);
            }
            let [m0, m1, m2, m3, m4] = &xrow.m;
            for i in 0..out[0] {
                total += c.ssim(m0[i], m1[i], m2[i], m3[i], m4[i]);
            }
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn field(dims: [usize; 3], seed: u32) -> Vec<f32> {
        let mut s = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        (0..dims[0] * dims[1] * dims[2])
            .map(|i| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (i % 7) as f32 * 0.1 + (s % 1000) as f32 * 1e-3
            })
            .collect()
    }

    /// Direct evaluation of skimage's algorithm: every window, explicit weights.
    fn reference(a: &[f32], b: &[f32], dims: [usize; 3], ndim: u32, params: &SsimParams) -> f64 {
        let w = params.window.size();
        let wins = [w, w, if ndim == 3 { w } else { 1 }];
        let taps1 = match params.window {
            SsimWindow::Uniform { size } => vec![1.0 / size as f64; size],
            SsimWindow::Gaussian { sigma } => gaussian_taps(sigma, w),
        };
        let wt = |ax: usize, t: usize| if wins[ax] == 1 { 1.0 } else { taps1[t] };
        let range = params.data_range.unwrap_or_else(|| data_range_of(b));
        let np = (w as f64).powi(ndim as i32);
        let cov = if params.sample_covariance { np / (np - 1.0) } else { 1.0 };
        let (c1, c2) = ((params.k1 * range).powi(2), (params.k2 * range).powi(2));
        let [nx, ny, nz] = dims;
        let (mut total, mut count) = (0.0, 0usize);
        for k in 0..=nz - wins[2] {
            for j in 0..=ny - wins[1] {
                for i in 0..=nx - wins[0] {
                    let mut m = [0f64; 5];
                    for tz in 0..wins[2] {
                        for ty in 0..wins[1] {
                            for tx in 0..wins[0] {
                                let idx = ((k + tz) * ny + j + ty) * nx + i + tx;
                                let c = wt(0, tx) * wt(1, ty) * wt(2, tz);
                                let (x, y) = (a[idx] as f64, b[idx] as f64);
                                m = [m[0] + c * x, m[1] + c * y, m[2] + c * x * x, m[3] + c * y * y, m[4] + c * x * y];
                            }
                        }
                    }
                    let vx = cov * (m[2] - m[0] * m[0]);
                    let vy = cov * (m[3] - m[1] * m[1]);
                    let vxy = cov * (m[4] - m[0] * m[1]);
                    total += (2.0 * m[0] * m[1] + c1) * (2.0 * vxy + c2)
                        / ((m[0] * m[0] + m[1] * m[1] + c1) * (vx + vy + c2));
                    count += 1;
                }
            }
        }
        total / count as f64
    }

    #[test]
    fn identical_inputs_score_one() {
        let dims = [12, 10, 9];
        let a = field(dims, 1);
        for p in [SsimParams::default(), SsimParams { window: SsimWindow::Uniform { size: 3 }, ..Default::default() }] {
            assert_relative_eq!(ssim_3d(&a, &a, dims, &p).expect("fits"), 1.0, epsilon = 1e-12);
            assert_relative_eq!(ssim_2d(&a[..120], &a[..120], 12, 10, &p).expect("fits"), 1.0, epsilon = 1e-12);
        }
        let big = [24, 13, 12];
        let g = field(big, 3);
        assert_relative_eq!(ssim_3d(&g, &g, big, &SsimParams::gaussian()).expect("fits"), 1.0, epsilon = 1e-12);
        assert_relative_eq!(ssim_global(&a, &a, 1.0), 1.0, epsilon = 1e-12);
    }

    /// A data range whose constants (K R)² multiply to less than the smallest f64 scored
    /// identical flat arrays NaN (0/0); it is refused naming the range, as one wider than any
    /// two f32 values differ by is. Ranges down to the smallest difference of two f32 values are
    /// computed.
    #[test]
    fn a_data_range_whose_constants_vanish_is_refused() {
        // Zero throughout: the windows' (co)variances are exactly 0, so SSIM is c₁c₂ / c₁c₂ there.
        let flat = vec![0.0f32; 64];
        for (r, says) in [
            (1e-300, "1e-300 is so small that"),
            (1e-80, "1e-80 is so small that"),
            (1e39, "1e39 is more than any two float32 values differ by"),
            (1e300, "1e300 is more than any two float32 values differ by"),
        ] {
            let p = SsimParams { data_range: Some(r), ..Default::default() };
            let e = ssim_2d(&flat, &flat, 8, 8, &p).expect_err("refused").to_string();
            assert!(e.starts_with(&format!("invalid SSIM data range: {says}")), "{e}");
        }
        // The unguarded global SSIM of such a range is what the refusal keeps from a report.
        assert!(ssim_global(&flat, &flat, 1e-300).is_nan());
        let smallest = f64::from(f32::from_bits(1));
        for r in [smallest, 1e-50, 1.0, 2.0 * f64::from(f32::MAX)] {
            let p = SsimParams { data_range: Some(r), ..Default::default() };
            assert_relative_eq!(ssim_2d(&flat, &flat, 8, 8, &p).expect("computed"), 1.0, epsilon = 1e-12);
            assert_relative_eq!(ssim_global(&flat, &flat, r), 1.0, epsilon = 1e-12);
        }
        // Constants set to 0 on purpose (K = 0) are not vanished ones.
        assert!(data_range_problem(1e-300, [0.0, 0.0]).is_none());
    }

    #[test]
    fn fast_path_matches_direct_windows() {
        let dims = [23, 17, 30];
        let (a, b) = (field(dims, 1), field(dims, 2));
        for p in [
            SsimParams::default(),
            SsimParams::gaussian(),
            SsimParams { sample_covariance: false, ..Default::default() },
        ] {
            let fast = ssim_3d(&a, &b, dims, &p).expect("fits");
            assert_relative_eq!(fast, reference(&a, &b, dims, 3, &p), epsilon = 1e-12);
            let plane = &a[..23 * 17];
            let fast = ssim_2d(plane, &b[..23 * 17], 23, 17, &p).expect("fits");
            assert_relative_eq!(fast, reference(plane, &b[..23 * 17], [23, 17, 1], 2, &p), epsilon = 1e-12);
        }
    }

    #[test]
    fn global_by_hand() {
        // a = [0, 1], b = [1, 1]: μa = ½, μb = 1, σa² = ¼, σb² = 0, σab = 0.
        let (c1, c2) = (1e-4, 9e-4);
        let want = (2.0 * 0.5 + c1) * c2 / ((0.25 + 1.0 + c1) * (0.25 + c2));
        assert_relative_eq!(ssim_global(&[0.0, 1.0], &[1.0, 1.0], 1.0), want, epsilon = 1e-12);
        // Anti-correlated inputs score below zero in the structure term.
        assert!(ssim_global(&[0.0, 1.0, 0.0, 1.0], &[1.0, 0.0, 1.0, 0.0], 1.0) < 0.0);
    }

    #[test]
    fn rejects_windows_larger_than_the_array() {
        let a = vec![0f32; 6 * 8];
        assert!(matches!(ssim_2d(&a, &a, 6, 8, &SsimParams::default()), Err(MetricsError::TooSmall { .. })));
        let even = SsimParams { window: SsimWindow::Uniform { size: 4 }, ..Default::default() };
        assert!(ssim_2d(&a, &a, 6, 8, &even).is_err());
    }

    #[test]
    fn a_one_voxel_window_needs_population_covariance() {
        let (a, b) = (field([5, 5, 5], 1), field([5, 5, 5], 2));
        let one = SsimParams { window: SsimWindow::Uniform { size: 1 }, ..Default::default() };
        let e = ssim_3d(&a, &b, [5, 5, 5], &one).unwrap_err().to_string();
        assert!(e.contains("at least 3"), "{e}");
        // Without the N - 1 correction it is defined: the mean luminance term of each voxel.
        let population = SsimParams { sample_covariance: false, data_range: Some(1.0), ..one };
        let c1 = 1e-4;
        let want = a
            .iter()
            .zip(&b)
            .map(|(&x, &y)| (x as f64, y as f64))
            .map(|(x, y)| (2.0 * x * y + c1) / (x * x + y * y + c1));
        let want = want.sum::<f64>() / a.len() as f64;
        assert_relative_eq!(ssim_3d(&a, &b, [5, 5, 5], &population).unwrap(), want, epsilon = 1e-9);
    }
}
