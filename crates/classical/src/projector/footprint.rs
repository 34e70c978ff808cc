//! The separable-footprint voxel projector (after the SF-TT projector of Long, Fessler & Balter,
//! "3D forward and back-projection for X-ray CT using separable footprints", IEEE TMI 2010),
//! for calibrated pinhole cameras in any pose.
//!
//! # Model
//! Voxel `j` (a uniform cube of side `Δ = (Δx, Δy, Δz)`, the unknown `g_j` inside) is seen by
//! view `v` as its *footprint*: the line integral through the cube as a function of the image
//! position. Around the voxel centre the projection is replaced by its first-order expansion,
//! so the footprint is the push-forward of the cube through the 2 × 3 Jacobian `J` of the
//! projection `(u, v)(p)` at the centre (pose, pinhole, skew and, for distorted cameras, the
//! OpenCV distortion's own Jacobian at the projected centre — see *Lens distortion* below).
//! Each cube edge `a` images to the pixel-space vector `J (Δ_a e_a)`; along the image axis `u`
//! the footprint's profile is the sum of three uniform variables of widths `|J_u Δ_a e_a|`,
//! which is approximated by a trapezoid: the convolution of two boxes, the widest edge `P`
//! and `L = sqrt(Σ w_a² − P²)` (the same variance; exact when one edge images to zero width,
//! which is the planar-ring case: the voxel edge parallel to the ring's axis has no extent
//! across it). The same holds along `v`. The footprint is the separable product of the two
//! trapezoids (SF's separability; it drops only the shear between `u` and `v`).
//!
//! The weight of pixel `(c, r)` is the footprint averaged over the pixel's area (pixels are
//! unit boxes around integer centres):
//!
//! ```text
//! w_ij = γ_j · T_u(c) · T_v(r),   T_u(c) = ∫_{c−½}^{c+½} trapezoid_u / ∫ trapezoid_u
//! γ_j  = intensity_scale · V_vox · f_x f_y |det ∂(x_d, y_d)/∂(x_n, y_n)| · s / z³
//! ```
//!
//! `γ_j` is the same total as the splat's ([`super::SplatProjector`]): the voxel's emitted
//! power per pixel area, so `Σ_i w_ij = γ_j` when the footprint lies inside the image, and a
//! smooth field projects to `intensity_scale ∫ E ds` (tested against the renderer). For a ray
//! through the footprint's flat top the weight equals `intensity_scale ×` the ray's path length
//! through the voxel (the trapezoid's height is `γ_j / (P_u P_v)`; `P` is the flat-top-plus-
//! ramp width, which is what makes the amplitude a path length), which is why a uniform ball
//! projects to its analytic chord lengths (tested).
//!
//! # Lens distortion
//! The voxel centre is projected exactly (distortion included); the footprint's widths come
//! from the local Jacobian of the distorted projection at that centre, and `γ_j` carries the
//! distortion's Jacobian determinant. The distortion's curvature across one voxel (a few
//! pixels) is neglected — far below the model's other approximations for calibrated lenses.
//!
//! # Cost
//! Each voxel touches the `N × N` pixels of a square that holds its largest footprint in the
//! view (`N` ∈ {2, 4, 8, 16, 32, 64} columns, chosen per view from the geometry, and as many
//! rows as the widest footprint along `v` needs; a voxel whose footprint would exceed them —
//! only possible with a camera inside or next to the box — is narrowed to fit, keeping its
//! total). So one projection costs voxels × views × `N × rows` simple multiply–adds plus one
//! footprint evaluation per voxel and view, whatever the voxel's image size — unlike the
//! sub-voxel splat, whose cost grows as the cube of the voxel's image size.
//!
//! # Parallelism and exactness
//! Footprints are evaluated 16 voxels of a grid row at a time, vectorised across the voxels
//! (projection, trapezoids and pixel weights; one division for `1/z` and one for the ramps'
//! `1/(2l)` and the amplitude together; the narrowing's division only in chunks that need it).
//! Forward projection scatters: each of `T` tasks (one per thread) takes every `T`-th z-slice,
//! so that uneven work is shared evenly, skips chunks of sixteen empty voxels without computing
//! their footprints, and accumulates into its own padded images (neighbouring voxels go to
//! different images, so that voxels writing the same pixels do not chain through memory; a
//! margin of `N` pixels on every side, so the inner loop has no bounds tests), and the images
//! are summed. Back projection gathers: every voxel
//! computes its footprint again and reads its pixels from a zero-padded copy of the image, so
//! z-slices are independent and no atomics or per-thread volumes are needed; the back
//! projector does the same arithmetic as the forward one.
//!
//! When a camera sees the grid's rows (its `x` axis) as vertical or horizontal lines in its
//! image, exactly (CT-style rings around that axis; see `Shared`), the voxels of a row share
//! their depth and their footprint along one image axis, which is then computed once per row
//! (sixteen rows at a time). The footprint is then separable across the whole row, and both
//! projections use it. The back projection sums the image lines under the row's shared
//! footprint with its weights into one line first, and each voxel weighs that line with its
//! weights along the other axis, `n_s + n_l` products per voxel instead of `n_s · n_l`. The
//! forward projection does the transpose: each voxel adds its weights along the other axis to
//! one line, and that line is added to the image lines under the shared footprint with its
//! weights.
//!
//! Wider footprints are stored voxel-major, so that each voxel reads its weights as one vector
//! per axis. With footprints of side 2 or 4 (voxels under about 3 pixels, where a voxel's row
//! of pixels is too short for a vector) the vector kernels work across voxels instead: the back
//! projector reads a footprint pixel of eight (AVX2) or sixteen (AVX-512) voxels with one
//! gather, weighted from the footprints' own pixel-major layout, in the same order of
//! operations as the voxel-by-voxel loop, and the forward projector reads each voxel's weights
//! from that layout too, without transposing them. Both evaluate the very same f32 weights
//! (same code, no fused multiply–add), so `⟨A x, y⟩ = ⟨x, Aᵀ y⟩` to rounding.
//!
//! The kernels are plain loops over fixed-size arrays plus the gathers; they are compiled for
//! the x86-64 baseline, AVX2 and AVX-512, and the variant is chosen at run time ([`Isa`];
//! [`FootprintProjector::with_isa`] caps it for comparisons). The back projection is the same
//! bit for bit with every variant, the forward projection up to the order in which overlapping
//! footprints are summed (both tested).

use std::ops::Range;
use std::sync::{Arc, OnceLock};

use fluidnerf_core::{Camera, Isa};
use rayon::prelude::*;

use super::camera32::{distort, CameraF32, GridF32};
use super::{check_shapes, scatter_parts, splat::validate, Grid, Projector, SparseRows, Update};
use crate::ClassicalError;

/// Footprint sides (pixels per axis) the kernels are compiled for.
pub const FOOTPRINT_SIDES: [usize; 6] = [2, 4, 8, 16, 32, 64];

/// Largest footprint side, in pixels.
pub const MAX_FOOTPRINT_SIDE: usize = 64;

/// Widest footprint (pixels) the automatic choice ([`super::ProjectorKind::Auto`]) gives to
/// this projector: what a side of [`MAX_FOOTPRINT_SIDE`] holds with the margin
/// [`FootprintProjector::new`] asks for.
pub const AUTO_FOOTPRINT_MAX_PX: f64 = (MAX_FOOTPRINT_SIDE as f64 - 1.0) / 1.02;

/// One view's camera in f32, ready for the voxel loop.
#[derive(Clone, Copy, Debug)]
struct FootView {
    cam: CameraF32,
    /// `intensity_scale · V_vox · f_x · f_y`.
    gain: f32,
    /// The voxel's edges in camera axes: `edges[a] = R (Δ_a e_a)`.
    edges: [[f32; 3]; 3],
    /// Footprint side `N` in pixels (columns; a power of two, the kernels' vector width).
    side: usize,
    /// Rows each footprint spans (at most `side`): constant per view, so the row loop has a
    /// fixed trip count.
    rows: usize,
    /// Columns each footprint spans (at most `side`). The kernels that work across a
    /// footprint's columns take all `side` of them (the ones past `cols` weigh zero); the
    /// shared-row kernels take `cols`.
    cols: usize,
    /// Which image axis the voxels of a grid row share their footprint along (see [`Shared`]).
    shared: Shared,
}

/// Views whose camera sees a grid row (the grid's `x` axis) as a vertical or a horizontal line
/// of voxels: the camera's depth and one of its coordinates do not change along the row, so
/// the voxels of a row share their projection and whole footprint along that image axis,
/// which [`FootView::rows_shared`] then computes once per row. Exact zeros in the rotation decide
/// (CT-style rings around the grid's `x` axis: the benchmark's ring, the synthetic jets').
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Shared {
    /// Every voxel has its own footprint along both axes.
    None,
    /// Camera `x` and `z` are constant along a row (the row is vertical in the image), no skew
    /// or distortion.
    U,
    /// Camera `y` and `z` are constant along a row (the row is horizontal), no distortion.
    V,
}

/// What the voxels of a grid row share along one image axis ([`FootView::rows_shared`]).
#[derive(Clone, Copy, Debug)]
struct RowShared<const N: usize> {
    /// First padded pixel along the shared axis; −1 when the row misses the padded image.
    first: f32,
    /// The pixel weights along it.
    w: [f32; N],
    /// `1 / p` of its trapezoid.
    inv_p: f32,
    /// The row's camera depth (1 behind the camera) and its inverse.
    zs: f32,
    iz: f32,
    /// The camera coordinate that stays fixed along the row (`y` when `v` is shared, `x`
    /// when `u` is).
    fixed: f32,
}

impl<const N: usize> Default for RowShared<N> {
    fn default() -> Self {
        RowShared { first: -1.0, w: [0.0; N], inv_p: 0.0, zs: 1.0, iz: 1.0, fixed: 0.0 }
    }
}

/// A chunk's footprints along the axis its voxels do not share ([`FootView::chunk_moving`]).
#[derive(Clone, Copy, Debug)]
struct Moving<const N: usize> {
    /// First padded pixel along that axis; −1 for a miss.
    first: [f32; CHUNK],
    amp: [f32; CHUNK],
    /// Pixel-major weights `w[k][q]`.
    w: [[f32; CHUNK]; N],
}

impl<const N: usize> Moving<N> {
    /// The chunk's footprints as the weighing kernels read them.
    #[inline(always)]
    fn foot(&self) -> ChunkFoot<'_> {
        ChunkFoot { first: &self.first, amp: &self.amp, w: &self.w }
    }
}

/// A chunk's moving-axis footprints, borrowed from a [`Moving`] or from kept footprints
/// ([`KeptFootprints`]): first pixels, amplitudes and at least `n_l` weights, pixel-major.
#[derive(Clone, Copy, Debug)]
struct ChunkFoot<'a> {
    first: &'a [f32; CHUNK],
    amp: &'a [f32; CHUNK],
    w: &'a [[f32; CHUNK]],
}

impl<const N: usize> Default for Moving<N> {
    fn default() -> Self {
        Moving { first: [-1.0; CHUNK], amp: [0.0; CHUNK], w: [[0.0; CHUNK]; N] }
    }
}

/// What the voxels of a grid row share along the axis that moves ([`FootView::moving_row`]):
/// the moving camera coordinate `c = start + i · step` of voxel `i`, the footprint's centre
/// `c0 + c1 c` and edge widths `|a0 + a1 c|` on that axis, and the amplitude's factors.
#[derive(Clone, Copy, Debug)]
struct MovingRow {
    start: f32,
    step: f32,
    c0: f32,
    c1: f32,
    a0: [f32; 3],
    a1: [f32; 3],
    base_s: f32,
    g0: f32,
    /// The widest trapezoid support that fits the footprint along the moving axis (its
    /// pixels − 1), as a float: converted in the loops, it kept them scalar on AVX2.
    lim: f32,
    bound: f32,
}

/// A chunk's projected footprints before they are placed ([`FootView::chunk_trapezoids`]):
/// centres, `γ` and whether in front of the camera, then ([`FootView::chunk_place`]) the first
/// pixels' offsets and the ramps' `1/(2l)` in their place; the trapezoids `(p, l)` along `u`
/// and `v`.
#[derive(Clone, Copy, Debug, Default)]
struct ChunkTrapezoids {
    u: [f32; CHUNK],
    v: [f32; CHUNK],
    gamma: [f32; CHUNK],
    front: [f32; CHUNK],
    pu: [f32; CHUNK],
    lu: [f32; CHUNK],
    pv: [f32; CHUNK],
    lv: [f32; CHUNK],
}

/// A chunk's trapezoids along the moving axis: centre (then the offset of the first pixel),
/// `γ` (then `1/(2l)`), and `(p, l)`.
#[derive(Clone, Copy, Debug, Default)]
struct MovingTrapezoids {
    off: [f32; CHUNK],
    inv: [f32; CHUNK],
    p: [f32; CHUNK],
    l: [f32; CHUNK],
}

impl MovingRow {
    /// The trapezoids of the `CHUNK` voxels from `i0`; `off` holds the centres and `inv` the
    /// `γ` until [`Self::place`].
    #[inline(always)]
    fn trapezoids(&self, i0: usize, t: &mut MovingTrapezoids) {
        let f0 = i0 as f32;
        for q in 0..CHUNK {
            let c = self.start + (f0 + Q[q]) * self.step;
            t.off[q] = self.c0 + self.c1 * c;
            let w = axes3(|a| (self.a0[a] + self.a1[a] * c).abs());
            (t.p[q], t.l[q]) = trapezoid(w);
            t.inv[q] = self.g0 * (self.base_s + c * c).sqrt();
        }
    }

    /// Whether a trapezoid of the chunk needs narrowing.
    #[inline(always)]
    fn wide(&self, t: &MovingTrapezoids) -> bool {
        (0..CHUNK).fold(false, |any, q| any | (t.p[q] + t.l[q] > self.lim))
    }

    /// Narrows the trapezoids if `wide` (which leaves those that fit unchanged, so it may be
    /// decided for more voxels than the chunk's), and places them: first pixel and amplitude
    /// into `out`, the first pixel's offset and `1/(2l)` into `t`.
    #[inline(always)]
    fn place<const N: usize>(&self, rs: &RowShared<N>, wide: bool, t: &mut MovingTrapezoids, out: &mut Moving<N>) {
        let n = N as f32;
        for q in 0..CHUNK {
            let (centre, gamma) = (t.off[q], t.inv[q]);
            let (p, l) = fit_trapezoid(t.p[q], t.l[q], self.lim, wide);
            (t.p[q], t.l[q]) = (p, l);
            let t_l = centre - 0.5 * (p + l) + 0.5 + n;
            let hit = (rs.first >= 0.0) & (t_l >= 0.0) & (t_l < self.bound);
            let first_l = if hit { floor_small(t_l) } else { -1.0 };
            out.first[q] = first_l;
            t.off[q] = (centre + n + 0.5) - first_l;
            let r = 1.0 / (p * l);
            t.inv[q] = 0.5 * p * r;
            out.amp[q] = gamma * rs.inv_p * (l * r);
        }
    }
}

/// The z-slices one forward-projection task takes: every `parts`-th from its first.
type Slices = std::iter::StepBy<Range<usize>>;

/// Voxels projected per batch.
const CHUNK: usize = 16;

/// Views per thread from which [`Projector::forward_views`] gives each view to one thread
/// instead of splitting every view over all of them.
const VIEWS_PER_THREAD: usize = 4;

/// `0, 1, …, CHUNK − 1` as f32: `(i0 + q) as f32` without a conversion per lane (exact: grids
/// are far below 2²⁴).
const Q: [f32; CHUNK] = {
    let mut q = [0f32; CHUNK];
    let mut i = 0;
    while i < CHUNK {
        q[i] = i as f32;
        i += 1;
    }
    q
};

/// Padded images each forward-projection task accumulates into: the voxel-by-voxel kernel
/// alternates between the first two by parity, the lane kernel cycles through all four.
/// Neighbouring voxels mostly hit the same pixels, and spreading them over separate images
/// breaks the read-modify-write chains through memory.
const SCATTER_IMAGES: usize = 4;

/// A batch of footprints of side `N`, structure of arrays (see [`FootView::chunk`]): the
/// padded first column and row (−1: the voxel misses), the amplitude, and the pixel weights
/// along each axis, `wu[q][k]` for pixel `k` of voxel `q` (written once per chunk, read as one
/// vector per voxel).
#[derive(Clone, Copy, Debug)]
struct Chunk<const N: usize> {
    col: [f32; CHUNK],
    row: [f32; CHUNK],
    amp: [f32; CHUNK],
    wu: [[f32; N]; CHUNK],
    wv: [[f32; N]; CHUNK],
    /// The same weights pixel-major, `wu_lanes[k][q]`, for kernels that work across voxels
    /// (written instead of `wu`, `wv` by [`FootView::chunk`] with `LANES`).
    wu_lanes: [[f32; CHUNK]; N],
    wv_lanes: [[f32; CHUNK]; N],
}

impl<const N: usize> Default for Chunk<N> {
    fn default() -> Self {
        let z = [0f32; CHUNK];
        Chunk {
            col: [-1.0; CHUNK],
            row: z,
            amp: z,
            wu: [[0.0; N]; CHUNK],
            wv: [[0.0; N]; CHUNK],
            wu_lanes: [z; N],
            wv_lanes: [z; N],
        }
    }
}

impl<const N: usize> Chunk<N> {
    /// The padded first column and row and the amplitude of entry `q`, if it hits.
    #[inline(always)]
    fn get(&self, q: usize) -> Option<(usize, usize, f32)> {
        // Whole non-negative numbers when the voxel hits.
        (self.col[q] >= 0.0).then(|| (self.col[q] as usize, self.row[q] as usize, self.amp[q]))
    }

    /// The weights of entry `q` along `u` and `v`.
    #[inline(always)]
    fn weights(&self, q: usize) -> ([f32; N], [f32; N]) {
        (self.wu[q], self.wv[q])
    }
}

/// `⌊t⌋` for `0 ≤ t < 2²²`, branch-free and vectorisable without SSE4.1 (whose `round` the
/// x86-64 baseline lacks; `f32::floor` would be a library call per element there).
#[inline(always)]
fn floor_small(t: f32) -> f32 {
    const MAGIC: f32 = 8_388_608.0; // 2²³: adding it rounds to an integer.
    let r = (t + MAGIC) - MAGIC;
    if r > t {
        r - 1.0
    } else {
        r
    }
}

/// The pixel integrals of `CHUNK` trapezoids (unit height, boxes `p ≥ l`, centred at `off`) on
/// pixels `[k, k + 1)`, `k < N`, vectorised across the voxels, given `inv = 1 / (2 l)`:
/// `store(q, k, w)` for pixel `k` of voxel `q`, the weights of a voxel summing to `p` when the
/// support lies inside.
#[inline(always)]
fn axis_weights_chunk<const N: usize>(
    off: &[f32; CHUNK],
    p: &[f32; CHUNK],
    l: &[f32; CHUNK],
    inv: &[f32; CHUNK],
    limit: usize,
    mut store: impl FnMut(usize, usize, f32),
) {
    let (mut h1, mut h2) = ([0f32; CHUNK], [0f32; CHUNK]);
    for q in 0..CHUNK {
        h1[q] = 0.5 * (p[q] + l[q]);
        h2[q] = 0.5 * (p[q] - l[q]);
    }
    let mut prev = [0f32; CHUNK];
    // The integral up to the end of pixel `k` for every voxel, then the weight of pixel `k`;
    // with `$rest`, the last pixel `k + 1` then takes what is left of the trapezoid's area
    // `p`, kept from rounding below zero.
    macro_rules! pixel {
        ($k:expr, $rest:expr) => {
            for q in 0..CHUNK {
                let (h1, h2, inv) = (h1[q], h2[q], inv[q]);
                let t = ($k + 1) as f32 - off[q];
                let a = fmin(fmax(t, -h1), -h2) + h1;
                let b = fmin(fmax(t, -h2), h2) + h2;
                let c = fmin(fmax(t, h2), h1) - h2;
                let cdf = a * a * inv + b + c - c * c * inv;
                store(q, $k, cdf - prev[q]);
                prev[q] = cdf;
                if $rest {
                    // Exactly zero when the support ends before the last pixel, as the
                    // difference of two equal integrals was (multiplicative methods divide by
                    // column sums that tiny weights would make): the overlap `h1 − t` is ≤ 0
                    // there. Where it is positive it bounds the rest of the area (the ramp is
                    // at most 1 high), so scaled by 2²⁰ it bites only on rounding. Arithmetic
                    // rather than a select, which the baseline instruction set would branch on.
                    store(q, $k + 1, fmax(fmin(p[q] - cdf, (h1 - t) * 1_048_576.0), 0.0));
                }
            }
        };
    }
    let m = N.min(limit);
    if m >= 2 {
        // The support ends inside pixel m − 1 (see `fit_trapezoid`): one integral fewer.
        for k in 0..m - 2 {
            pixel!(k, false);
        }
        pixel!(m - 2, true);
    } else {
        for k in 0..m {
            pixel!(k, false);
        }
    }
}

/// `Σ_c acc[c] · wu[c]`: in column order for sides up to 4 (the order of the lane kernels,
/// which must match), as a pairwise tree from side 8 on, whose additions vectorise (a serial
/// chain of eight or more dependent additions per voxel was the wide footprints' bottleneck).
#[inline(always)]
fn dot_columns<const N: usize>(acc: &[f32; N], wu: &[f32; N]) -> f32 {
    let mut p = [0f32; N];
    for c in 0..N {
        p[c] = acc[c] * wu[c];
    }
    if N <= 4 {
        let mut sum = 0f32;
        for c in 0..N {
            sum += p[c];
        }
        return sum;
    }
    let mut width = N;
    while width > 1 {
        width /= 2;
        for c in 0..width {
            p[c] += p[c + width];
        }
    }
    p[0]
}

/// The least first pixel of the hits among the chunks `mvs` (`f32::MAX` if none) and the
/// greatest (−1 if none: misses are −1).
#[inline(always)]
fn first_range<'a>(firsts: impl Iterator<Item = &'a [f32; CHUNK]>) -> (f32, f32) {
    let (mut lo, mut hi) = ([f32::MAX; CHUNK], [-1f32; CHUNK]);
    for first in firsts {
        for q in 0..CHUNK {
            let f = first[q];
            lo[q] = fmin(lo[q], if f >= 0.0 { f } else { f32::MAX });
            hi[q] = fmax(hi[q], f);
        }
    }
    (lo.into_iter().fold(f32::MAX, fmin), hi.into_iter().fold(-1.0, fmax))
}

/// [`first_range`] sixteen lanes at a time (the same result: minima and maxima are exact).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2")]
#[inline]
unsafe fn first_range16<'a>(firsts: impl Iterator<Item = &'a [f32; CHUNK]>) -> (f32, f32) {
    use std::arch::x86_64::*;
    const { assert!(CHUNK == 16) };
    let (mut lo, mut hi) = (_mm512_set1_ps(f32::MAX), _mm512_set1_ps(-1.0));
    for first in firsts {
        // SAFETY: `first` holds 16 values.
        let f = unsafe { _mm512_loadu_ps(first.as_ptr()) };
        let hit = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(f, _mm512_setzero_ps());
        lo = _mm512_mask_min_ps(lo, hit, lo, f);
        hi = _mm512_max_ps(hi, f);
    }
    (_mm512_reduce_min_ps(lo), _mm512_reduce_max_ps(hi))
}

/// [`first_range`] eight lanes at a time (the same result: minima and maxima are exact). The
/// compiler's own vectorisation of [`first_range`] for AVX2 mixed scalar compares and lane
/// inserts.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn first_range8<'a>(firsts: impl Iterator<Item = &'a [f32; CHUNK]>) -> (f32, f32) {
    use std::arch::x86_64::*;
    const { assert!(CHUNK == 16) };
    let (none, miss, zero) = (_mm256_set1_ps(f32::MAX), _mm256_set1_ps(-1.0), _mm256_setzero_ps());
    let (mut lo, mut hi) = ([none; 2], [miss; 2]);
    for first in firsts {
        for h in 0..2 {
            // SAFETY: `first` holds 16 values.
            let f = unsafe { _mm256_loadu_ps(first.as_ptr().add(8 * h)) };
            let hit = _mm256_cmp_ps::<_CMP_GE_OQ>(f, zero);
            lo[h] = _mm256_min_ps(lo[h], _mm256_blendv_ps(none, f, hit));
            hi[h] = _mm256_max_ps(hi[h], f);
        }
    }
    let (mut l, mut u) = ([0f32; 8], [0f32; 8]);
    // SAFETY: eight values each.
    unsafe {
        _mm256_storeu_ps(l.as_mut_ptr(), _mm256_min_ps(lo[0], lo[1]));
        _mm256_storeu_ps(u.as_mut_ptr(), _mm256_max_ps(hi[0], hi[1]));
    }
    (l.into_iter().fold(f32::MAX, fmin), u.into_iter().fold(-1.0, fmax))
}

/// The `valid ≤ CHUNK` values of `x` from `at`, zero past them: a whole chunk as one vector
/// load (a copy of a run-time length was a call to `memmove` per chunk).
#[inline(always)]
fn chunk_values(x: &[f32], at: usize, valid: usize) -> [f32; CHUNK] {
    if valid == CHUNK {
        return x[at..at + CHUNK].try_into().expect("CHUNK values");
    }
    let mut g = [0f32; CHUNK];
    g[..valid].copy_from_slice(&x[at..at + valid]);
    g
}

/// One footprint row of eight voxels: `N` vectors, vector `c` holding pixel
/// `row[at[j] + c]` of voxel `j` in lane `j` (`at` as lanes and as a vector). Sides of two and
/// four pixels load each voxel's row whole (8 or 16 bytes) and transpose the eight rows, which
/// costs a fraction of the `N` gathers it replaces on AMD's cores, where a gather of eight is
/// slow; other sides gather.
///
/// # Safety
/// The CPU must support AVX2; `row[at[j]..][..N]` must be readable for every lane `j`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn footprint_row8<const N: usize>(
    row: *const f32,
    at: &[i32; 8],
    at_v: std::arch::x86_64::__m256i,
) -> [std::arch::x86_64::__m256; N] {
    use std::arch::x86_64::*;
    // SAFETY (whole body): the caller's contract; every read below is of the N pixels of one
    // lane's row.
    unsafe {
        let p = |j: usize| row.add(at[j] as usize);
        let mut px = [_mm256_setzero_ps(); N];
        if N == 2 {
            // Lane pairs (p0, p1) of voxels j and j + 1 in one 128-bit register.
            let pair = |j: usize| {
                let lo = p(j).cast::<i64>().read_unaligned();
                let hi = p(j + 1).cast::<i64>().read_unaligned();
                _mm_castsi128_ps(_mm_set_epi64x(hi, lo))
            };
            let u0 = _mm256_set_m128(pair(4), pair(0));
            let u1 = _mm256_set_m128(pair(6), pair(2));
            px[0] = _mm256_shuffle_ps::<0b10_00_10_00>(u0, u1);
            px[1] = _mm256_shuffle_ps::<0b11_01_11_01>(u0, u1);
        } else if N == 4 {
            // Voxels j and j + 4 in the two halves, then a 4 × 4 transpose in each half.
            let a = |j: usize| _mm256_set_m128(_mm_loadu_ps(p(j + 4)), _mm_loadu_ps(p(j)));
            let (a0, a1, a2, a3) = (a(0), a(1), a(2), a(3));
            let t0 = _mm256_unpacklo_ps(a0, a1);
            let t1 = _mm256_unpackhi_ps(a0, a1);
            let t2 = _mm256_unpacklo_ps(a2, a3);
            let t3 = _mm256_unpackhi_ps(a2, a3);
            px[0] = _mm256_shuffle_ps::<0b01_00_01_00>(t0, t2);
            px[1] = _mm256_shuffle_ps::<0b11_10_11_10>(t0, t2);
            px[2] = _mm256_shuffle_ps::<0b01_00_01_00>(t1, t3);
            px[3] = _mm256_shuffle_ps::<0b11_10_11_10>(t1, t3);
        } else {
            for (c, px) in px.iter_mut().enumerate() {
                *px = _mm256_i32gather_ps::<4>(row, _mm256_add_epi32(at_v, _mm256_set1_epi32(c as i32)));
            }
        }
        px
    }
}

/// One footprint row of sixteen voxels: `N` vectors, vector `c` holding pixel
/// `row[at[j] + c]` of voxel `j` in lane `j`. Sides of two and four pixels read each voxel's
/// pixels in pairs, with 64-bit gathers of eight voxels, and split the pairs with two
/// permutes: half the elements of the `N` gathers of sixteen they replace; other sides gather.
///
/// # Safety
/// The CPU must support AVX-512F; `row[at[j]..][..N]` must be readable for every lane `j`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2")]
#[inline]
unsafe fn footprint_row16<const N: usize>(
    row: *const f32,
    at: std::arch::x86_64::__m512i,
) -> [std::arch::x86_64::__m512; N] {
    use std::arch::x86_64::*;
    // SAFETY (whole body): the caller's contract; every read below is of the N pixels of one
    // lane's row.
    unsafe {
        let mut px = [_mm512_setzero_ps(); N];
        if N == 2 || N == 4 {
            let (lo, hi) = (_mm512_castsi512_si256(at), _mm512_extracti64x4_epi64::<1>(at));
            let even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
            let odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
            for h in 0..N / 2 {
                let base = row.add(2 * h).cast::<f64>();
                let g0 = _mm512_castpd_ps(_mm512_i32gather_pd::<4>(lo, base));
                let g1 = _mm512_castpd_ps(_mm512_i32gather_pd::<4>(hi, base));
                px[2 * h] = _mm512_permutex2var_ps(g0, even, g1);
                px[2 * h + 1] = _mm512_permutex2var_ps(g0, odd, g1);
            }
        } else {
            for (c, px) in px.iter_mut().enumerate() {
                *px = _mm512_i32gather_ps::<4>(_mm512_add_epi32(at, _mm512_set1_epi32(c as i32)), row);
            }
        }
        px
    }
}

/// `dst[i] += v[i]` for the lanes of `keep` (all bits set or none) among eight entries from
/// `dst`, with AVX2. When all eight lie inside the caller's range (`full`), with a plain load,
/// add and store (the other lanes written back as they were), as masked stores are slow on
/// AMD's cores; else with masked ones.
///
/// # Safety
/// The CPU must support AVX2; the eight entries from `dst` (only the `keep` lanes unless
/// `full`) are valid and no other thread writes them.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn add_kept8(dst: *mut f32, v: std::arch::x86_64::__m256, keep: std::arch::x86_64::__m256i, full: bool) {
    use std::arch::x86_64::*;
    // SAFETY: the caller's contract above.
    unsafe {
        if full {
            // The other lanes add −0, which leaves every value as it was, bit for bit. A blend
            // of the sum with the loaded values would be the same, but the compiler turns a
            // store of such a blend back into a masked store.
            let v = _mm256_blendv_ps(_mm256_set1_ps(-0.0), v, _mm256_castsi256_ps(keep));
            _mm256_storeu_ps(dst, _mm256_add_ps(_mm256_loadu_ps(dst), v));
        } else {
            let prev = _mm256_maskload_ps(dst, keep);
            _mm256_maskstore_ps(dst, keep, _mm256_add_ps(prev, v));
        }
    }
}

/// Adds each voxel's weights times its value to its line of the forward projection's summed
/// lines ([`FootprintProjector::scatter_shared`]): `w[l][q] · values[q]` to `acc[at[q] + l]`
/// for `l < N`, skipping voxels of value zero. With SSE (every x86-64 CPU) and sides of a
/// multiple of four, each voxel adds whole vectors of four, transposed from the pixel-major
/// weights four voxels at a time; else the products are transposed through memory.
///
/// # Safety
/// For every voxel of non-zero value, `acc[at[q]..at[q] + N]` lies inside the buffer `acc`.
#[inline(always)]
unsafe fn add_to_lines<const N: usize>(acc: *mut f32, at: &[u32; CHUNK], values: &[f32; CHUNK], w: &[[f32; CHUNK]; N]) {
    #[cfg(target_arch = "x86_64")]
    if N.is_multiple_of(4) {
        use std::arch::x86_64::*;
        for qb in (0..CHUNK).step_by(4) {
            // SAFETY: `values` and `w` hold CHUNK lanes, qb + 4 ≤ CHUNK; the stores as the
            // caller's contract.
            unsafe {
                let a = _mm_loadu_ps(values.as_ptr().add(qb));
                for lb in (0..N).step_by(4) {
                    let row = |l: usize| _mm_mul_ps(_mm_loadu_ps(w[lb + l].as_ptr().add(qb)), a);
                    let (r0, r1, r2, r3) = (row(0), row(1), row(2), row(3));
                    let (t0, t1) = (_mm_unpacklo_ps(r0, r1), _mm_unpacklo_ps(r2, r3));
                    let (t2, t3) = (_mm_unpackhi_ps(r0, r1), _mm_unpackhi_ps(r2, r3));
                    let cols =
                        [_mm_movelh_ps(t0, t1), _mm_movehl_ps(t1, t0), _mm_movelh_ps(t2, t3), _mm_movehl_ps(t3, t2)];
                    for (q, col) in cols.into_iter().enumerate() {
                        if values[qb + q] != 0.0 {
                            let p = acc.add(at[qb + q] as usize + lb);
                            _mm_storeu_ps(p, _mm_add_ps(_mm_loadu_ps(p), col));
                        }
                    }
                }
            }
        }
        return;
    }
    let mut prods = [[0f32; N]; CHUNK];
    for (q, p) in prods.iter_mut().enumerate() {
        for l in 0..N {
            p[l] = values[q] * w[l][q];
        }
    }
    for q in 0..CHUNK {
        if values[q] == 0.0 {
            continue;
        }
        // SAFETY: the caller's contract.
        let line = unsafe { &mut *acc.add(at[q] as usize).cast::<[f32; N]>() };
        for l in 0..N {
            line[l] += prods[q][l];
        }
    }
}

/// The first voxels of the chunks of a grid row `row` that hold a non-zero value, into `starts`
/// (the test is branch-free, so that it vectorises).
#[inline(always)]
fn nonempty_chunks(row: &[f32], starts: &mut Vec<usize>) {
    starts.clear();
    for (c, g) in row.chunks(CHUNK).enumerate() {
        if g.iter().fold(false, |any, &g| any | (g != 0.0)) {
            starts.push(c * CHUNK);
        }
    }
}

/// The chunks of every grid row of one volume that hold a non-zero value
/// ([`Projector::forward_views`]): what each view's projection would otherwise find by
/// reading the whole volume again. Rows are numbered `k · ny + j`.
#[derive(Clone, Debug, Default)]
struct NonEmptyChunks {
    /// Row `r`'s chunk starts are `starts[ends[r - 1]..ends[r]]` (from 0 for row 0).
    ends: Vec<usize>,
    starts: Vec<usize>,
}

impl NonEmptyChunks {
    fn of(grid: &Grid, x: &[f32]) -> Self {
        let [nx, ny, _] = grid.dims;
        let slices: Vec<(Vec<usize>, Vec<usize>)> = x
            .par_chunks(nx * ny)
            .map(|slice| {
                let (mut counts, mut starts, mut row) = (Vec::with_capacity(ny), Vec::new(), Vec::new());
                for r in slice.chunks(nx) {
                    nonempty_chunks(r, &mut row);
                    counts.push(row.len());
                    starts.extend_from_slice(&row);
                }
                (counts, starts)
            })
            .collect();
        let mut out = NonEmptyChunks {
            ends: Vec::with_capacity(x.len() / nx.max(1)),
            starts: Vec::with_capacity(slices.iter().map(|s| s.1.len()).sum()),
        };
        for (counts, starts) in slices {
            for c in counts {
                out.ends.push(out.ends.last().copied().unwrap_or(0) + c);
            }
            out.starts.extend(starts);
        }
        out
    }

    fn row(&self, r: usize) -> &[usize] {
        let first = if r == 0 { 0 } else { self.ends[r - 1] };
        &self.starts[first..self.ends[r]]
    }
}

/// The non-empty chunks of row `row0 / nx` of `x`: from `known` when the caller found them
/// once for many views, else read from the row into `own`.
#[inline(always)]
fn row_chunks_of<'a>(
    known: Option<&'a NonEmptyChunks>,
    x: &[f32],
    row0: usize,
    nx: usize,
    own: &'a mut Vec<usize>,
) -> &'a [usize] {
    match known {
        Some(c) => c.row(row0 / nx),
        None => {
            nonempty_chunks(&x[row0..row0 + nx], own);
            own
        }
    }
}

/// `[f(0), f(1), f(2)]`, written out: `array::map` and `array::from_fn` were left as calls in
/// the row loops.
#[inline(always)]
fn axes3<T>(f: impl Fn(usize) -> T) -> [T; 3] {
    [f(0), f(1), f(2)]
}

#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// The trapezoid `(p, l)` approximating the sum of three uniform variables of widths `w`
/// (same variance, exact when one width is zero), `p ≥ l`.
#[inline(always)]
fn trapezoid(w: [f32; 3]) -> (f32, f32) {
    let m = fmax(fmax(w[0], w[1]), w[2]);
    let rest = fmax(w[0] * w[0] + w[1] * w[1] + w[2] * w[2] - m * m, 0.0).sqrt();
    (fmax(m, rest), fmin(m, rest))
}

/// The trapezoid `(p, l)` narrowed if needed so that its support `p + l` leaves a footprint of
/// `n` pixels (`p + l ≤ lim = n − 1`), and `l` kept above a positive floor. `lim` comes in as
/// a float, converted once outside the callers' loops: a conversion from `usize` inside them
/// kept the AVX2 forward projection's placing stage from being vectorised.
#[inline(always)]
fn fit_trapezoid(p: f32, l: f32, lim: f32, narrow: bool) -> (f32, f32) {
    let fit = if narrow { fmin(1.0, lim / (p + l)) } else { 1.0 };
    // A positive floor keeps the ramps' 1/l finite; a box of width p is the limit.
    let l = fmax(l * fit, 1e-6);
    (fmax(p * fit, l), l)
}

impl FootView {
    fn new(camera: &Camera, grid: &Grid, intensity_scale: f64) -> Self {
        let m = camera.camera_from_world().matrix3;
        let k = camera.intrinsics;
        let sp = grid.spacing();
        let sides = [sp.x, sp.y, sp.z];
        let cols = [m.x_axis, m.y_axis, m.z_axis];
        let edges = [0, 1, 2].map(|a| {
            let e = cols[a] * sides[a];
            [e.x as f32, e.y as f32, e.z as f32]
        });
        let mut view = FootView {
            cam: CameraF32::new(camera),
            gain: (intensity_scale * grid.voxel_volume() * k.fx * k.fy) as f32,
            edges,
            side: MAX_FOOTPRINT_SIDE,
            rows: MAX_FOOTPRINT_SIDE,
            cols: MAX_FOOTPRINT_SIDE,
            shared: Shared::None,
        };
        view.shared = view.sharing();
        let (su, sv) = view.support_px(grid);
        // Pixels a support of s can touch: ⌈s⌉ + 1, with a margin for the lattice's sampling.
        let need = |s: f64| ((s * 1.02 + 1.0).ceil() as usize).clamp(2, MAX_FOOTPRINT_SIDE);
        view.side = FOOTPRINT_SIDES.into_iter().find(|&n| n >= need(su.max(sv))).unwrap_or(MAX_FOOTPRINT_SIDE);
        view.rows = need(sv);
        view.cols = need(su);
        view
    }

    /// Projected centre, the three edge widths along `u` and along `v`, and `γ` of a voxel
    /// centred at camera-frame `p`; `None` behind the camera.
    #[inline(always)]
    fn project<const DISTORTED: bool>(&self, p: [f32; 3]) -> (bool, f32, f32, [f32; 3], [f32; 3], f32) {
        let [x, y, z] = p;
        let in_front = z > 1e-6;
        let zs = if in_front { z } else { 1.0 };
        let iz = 1.0 / zs;
        let (xn, yn) = (x * iz, y * iz);
        let (xd, yd, jac) = if DISTORTED { distort(&self.cam.dist, xn, yn) } else { (xn, yn, [1.0, 0.0, 0.0, 1.0]) };
        let u = self.cam.fx * xd + self.cam.skew * yd + self.cam.cx;
        let v = self.cam.fy * yd + self.cam.cy;
        let mut wu = [0f32; 3];
        let mut wv = [0f32; 3];
        for a in 0..3 {
            let e = self.edges[a];
            let dx = iz * (e[0] - xn * e[2]);
            let dy = iz * (e[1] - yn * e[2]);
            let (dxd, dyd) = if DISTORTED { (jac[0] * dx + jac[1] * dy, jac[2] * dx + jac[3] * dy) } else { (dx, dy) };
            wu[a] = (self.cam.fx * dxd + self.cam.skew * dyd).abs();
            wv[a] = (self.cam.fy * dyd).abs();
        }
        let det = if DISTORTED { (jac[0] * jac[3] - jac[1] * jac[2]).abs() } else { 1.0 };
        let s = (x * x + y * y + zs * zs).sqrt();
        let gamma = self.gain * det * s * iz * iz * iz;
        (in_front, u, v, wu, wv, gamma)
    }

    /// The footprints of `CHUNK` consecutive voxels of a row (`p = base + (i0 + q) · step`),
    /// side `N`, structure of arrays, the weights voxel-major (`wu`, `wv`) or with `LANES`
    /// pixel-major (`wu_lanes`, `wv_lanes`). Branch-free so that it vectorises across voxels;
    /// voxels whose square misses the padded image or that lie behind the camera get `tc = −1`.
    #[inline(always)]
    fn chunk<const N: usize, const DISTORTED: bool, const LANES: bool>(
        &self,
        base: [f32; 3],
        step: [f32; 3],
        i0: usize,
        out: &mut Chunk<N>,
    ) {
        if !DISTORTED {
            match self.shared {
                Shared::U => return self.chunk_shared::<N, LANES, false>(base, step, i0, out),
                Shared::V => return self.chunk_shared::<N, LANES, true>(base, step, i0, out),
                Shared::None => {}
            }
        }
        // The stages of [`Self::chunks_staged`] for one chunk, called directly: through that
        // function's loops over one chunk the general back projection ran 3–4 % slower.
        let mut t = ChunkTrapezoids::default();
        self.chunk_trapezoids::<DISTORTED>(base, step, i0, &mut t);
        let wide = self.chunk_wide::<N>(&t);
        self.chunk_place::<N>(wide, &mut t, out);
        self.chunk_weights::<N, LANES>(&t, out);
    }

    /// [`Self::chunk`] for the chunks of a row that start at the voxels `starts`, into `out`,
    /// stage by stage across the chunks ([`Self::chunks_staged`]); `scratch` holds at least as
    /// many entries as `starts`. Views that share a footprint axis and sides above 8, whose
    /// chunks are large, go chunk by chunk.
    #[inline(always)]
    fn row_chunks<const N: usize, const DISTORTED: bool, const LANES: bool>(
        &self,
        base: [f32; 3],
        step: [f32; 3],
        starts: &[usize],
        scratch: &mut [ChunkTrapezoids],
        out: &mut [Chunk<N>],
    ) {
        if N > 8 || (!DISTORTED && self.shared != Shared::None) {
            for (&i0, ch) in starts.iter().zip(out.iter_mut()) {
                self.chunk::<N, DISTORTED, LANES>(base, step, i0, ch);
            }
        } else {
            self.chunks_staged::<N, DISTORTED, LANES>(base, step, starts, scratch, out);
        }
    }

    /// The footprints of the chunks that start at the voxels `starts` of a row whose voxels do
    /// not share an axis, stage by stage across the chunks (as [`Self::row_moving`]), so that
    /// their chains of dependent operations overlap; the same arithmetic per voxel whatever the
    /// number of chunks.
    #[inline(always)]
    fn chunks_staged<const N: usize, const DISTORTED: bool, const LANES: bool>(
        &self,
        base: [f32; 3],
        step: [f32; 3],
        starts: &[usize],
        scratch: &mut [ChunkTrapezoids],
        out: &mut [Chunk<N>],
    ) {
        let mut wide = false;
        for (&i0, t) in starts.iter().zip(scratch.iter_mut()) {
            self.chunk_trapezoids::<DISTORTED>(base, step, i0, t);
            wide |= self.chunk_wide::<N>(t);
        }
        for (t, ch) in scratch.iter_mut().zip(out.iter_mut()) {
            self.chunk_place::<N>(wide, t, ch);
        }
        for (t, ch) in scratch.iter().zip(out.iter_mut()) {
            self.chunk_weights::<N, LANES>(t, ch);
        }
    }

    /// The projected centres, `γ`, and the trapezoids along `u` and `v` of the `CHUNK` voxels
    /// from `i0` of a row (`p = base + (i0 + q) · step`); `front` is 1 in front of the camera.
    #[inline(always)]
    fn chunk_trapezoids<const DISTORTED: bool>(
        &self,
        base: [f32; 3],
        step: [f32; 3],
        i0: usize,
        t: &mut ChunkTrapezoids,
    ) {
        let f0 = i0 as f32;
        for q in 0..CHUNK {
            let fi = f0 + Q[q];
            let p = [base[0] + fi * step[0], base[1] + fi * step[1], base[2] + fi * step[2]];
            let (in_front, uq, vq, wu, wv, g) = self.project::<DISTORTED>(p);
            (t.u[q], t.v[q], t.gamma[q]) = (uq, vq, g);
            t.front[q] = if in_front { 1.0 } else { 0.0 };
            (t.pu[q], t.lu[q]) = trapezoid(wu);
            (t.pv[q], t.lv[q]) = trapezoid(wv);
        }
    }

    /// Whether a trapezoid of the chunk needs narrowing (a division per axis; only next to the
    /// camera). Narrowing leaves those that fit unchanged, so it may be decided for more
    /// voxels than the chunk's.
    #[inline(always)]
    fn chunk_wide<const N: usize>(&self, t: &ChunkTrapezoids) -> bool {
        let (lim_u, lim_v) = (self.cols as f32 - 1.0, self.rows as f32 - 1.0);
        (0..CHUNK).fold(0u32, |any, q| any | u32::from((t.pu[q] + t.lu[q] > lim_u) | (t.pv[q] + t.lv[q] > lim_v))) != 0
    }

    /// Narrows the trapezoids if `wide`, and places them: first column and row (−1: the
    /// voxel's square misses the padded image, or it lies behind the camera) and amplitude
    /// into `out`; the offsets of the first pixels and the ramps' `1/(2l)` replace the centres
    /// and `γ`, `front` in `t`.
    #[inline(always)]
    fn chunk_place<const N: usize>(&self, wide: bool, t: &mut ChunkTrapezoids, out: &mut Chunk<N>) {
        let n = N as f32;
        let (wmax, hmax) = ((self.cam.width + N) as f32, (self.cam.height + N) as f32);
        let (lim_u, lim_v) = (self.cols as f32 - 1.0, self.rows as f32 - 1.0);
        for q in 0..CHUNK {
            (t.pu[q], t.lu[q]) = fit_trapezoid(t.pu[q], t.lu[q], lim_u, wide);
            (t.pv[q], t.lv[q]) = fit_trapezoid(t.pv[q], t.lv[q], lim_v, wide);
            let (pu, lu, pv, lv) = (t.pu[q], t.lu[q], t.pv[q], t.lv[q]);
            let (u, v, gamma) = (t.u[q], t.v[q], t.gamma[q]);
            // First pixel c0 = ⌊u − (p + l)/2 + ½⌋, shifted by the margin N so that every
            // square that can touch the image starts at a non-negative padded column.
            // Comparisons are false for NaN.
            let tc = u - 0.5 * (pu + lu) + 0.5 + n;
            let tr = v - 0.5 * (pv + lv) + 0.5 + n;
            let hit = (t.front[q] > 0.0) & (tc >= 0.0) & (tr >= 0.0) & (tc < wmax) & (tr < hmax);
            let (col, row) = if hit { (floor_small(tc), floor_small(tr)) } else { (-1.0, 0.0) };
            out.col[q] = col;
            out.row[q] = row;
            // u − (c0 − ½) and v − (r0 − ½).
            t.u[q] = (u + n + 0.5) - col;
            t.v[q] = (v + n + 0.5) - row;
            // The ramps' 1/(2l) and the amplitude γ/(p_u p_v) from one division (dear next to
            // the rest): all four factors lie in [1e-6, 64], so the product cannot under- or
            // overflow.
            let (puv, luv) = (pu * pv, lu * lv);
            let r = 1.0 / (puv * luv);
            t.gamma[q] = 0.5 * (puv * lv) * r;
            t.front[q] = 0.5 * (puv * lu) * r;
            out.amp[q] = gamma * luv * r;
        }
    }

    /// The pixel weights of a placed chunk ([`Self::chunk_place`]) along both axes, voxel-major
    /// or with `LANES` pixel-major: the view's `cols` and `rows` pixels, which hold every
    /// footprint ([`fit_trapezoid`]); the weights past them stay zero.
    #[inline(always)]
    fn chunk_weights<const N: usize, const LANES: bool>(&self, t: &ChunkTrapezoids, out: &mut Chunk<N>) {
        let (off_u, off_v, inv_u, inv_v) = (&t.u, &t.v, &t.gamma, &t.front);
        let (cols, rows) = (self.cols, self.rows);
        if LANES {
            axis_weights_chunk::<N>(off_u, &t.pu, &t.lu, inv_u, cols, |q, k, w| out.wu_lanes[k][q] = w);
            axis_weights_chunk::<N>(off_v, &t.pv, &t.lv, inv_v, rows, |q, k, w| out.wv_lanes[k][q] = w);
        } else {
            axis_weights_chunk::<N>(off_u, &t.pu, &t.lu, inv_u, cols, |q, k, w| out.wu[q][k] = w);
            axis_weights_chunk::<N>(off_v, &t.pv, &t.lv, inv_v, rows, |q, k, w| out.wv[q][k] = w);
        }
    }

    /// How the voxels of a grid row share their footprints in this view: exact zeros in the
    /// rotation make every voxel of a row have the same camera depth and `x` (or `y`), bit for
    /// bit.
    fn sharing(&self) -> Shared {
        let r = &self.cam.rot;
        if self.cam.distorted || r[2][0] != 0.0 {
            Shared::None
        } else if r[0][0] == 0.0 && self.cam.skew == 0.0 {
            Shared::U
        } else if r[1][0] == 0.0 {
            Shared::V
        } else {
            Shared::None
        }
    }

    /// The centre and the three edge widths of a voxel along `u` (or with `ALONG_V` along `v`)
    /// from its normalised camera coordinates and `1/z` (undistorted; as [`Self::project`]).
    #[inline(always)]
    fn along<const ALONG_V: bool>(&self, xn: f32, yn: f32, iz: f32) -> (f32, [f32; 3]) {
        if ALONG_V {
            (
                self.cam.fy * yn + self.cam.cy,
                axes3(|a| (self.cam.fy * (iz * (self.edges[a][1] - yn * self.edges[a][2]))).abs()),
            )
        } else {
            let w = axes3(|a| {
                let e = self.edges[a];
                let (dx, dy) = (iz * (e[0] - xn * e[2]), iz * (e[1] - yn * e[2]));
                (self.cam.fx * dx + self.cam.skew * dy).abs()
            });
            (self.cam.fx * xn + self.cam.skew * yn + self.cam.cx, w)
        }
    }

    /// [`Self::chunk`] for views whose grid rows share their footprint along `u` (or with
    /// `SHARED_V` along `v`), see [`Shared`]: [`Self::rows_shared`] and [`Self::chunk_moving`]
    /// laid out as a [`Chunk`].
    #[inline(always)]
    fn chunk_shared<const N: usize, const LANES: bool, const SHARED_V: bool>(
        &self,
        base: [f32; 3],
        step: [f32; 3],
        i0: usize,
        out: &mut Chunk<N>,
    ) {
        let mut rs = [RowShared::<N>::default()];
        self.rows_shared::<N, SHARED_V>(&[base; CHUNK], &mut rs);
        let rs = rs[0];
        let mut mv = Moving::<N>::default();
        self.chunk_moving::<N, SHARED_V>(&rs, base, step, i0, N, &mut mv);
        out.amp = mv.amp;
        for q in 0..CHUNK {
            let hit = mv.first[q] >= 0.0;
            (out.col[q], out.row[q]) = match (hit, SHARED_V) {
                (false, _) => (-1.0, 0.0),
                (true, false) => (rs.first, mv.first[q]),
                (true, true) => (mv.first[q], rs.first),
            };
        }
        match (LANES, SHARED_V) {
            (true, false) => {
                out.wu_lanes = rs.w.map(|w| [w; CHUNK]);
                out.wv_lanes = mv.w;
            }
            (true, true) => {
                out.wv_lanes = rs.w.map(|w| [w; CHUNK]);
                out.wu_lanes = mv.w;
            }
            (false, false) => {
                out.wu = [rs.w; CHUNK];
                out.wv = std::array::from_fn(|q| std::array::from_fn(|k| mv.w[k][q]));
            }
            (false, true) => {
                out.wv = [rs.w; CHUNK];
                out.wu = std::array::from_fn(|q| std::array::from_fn(|k| mv.w[k][q]));
            }
        }
    }

    /// What the voxels of a grid row share when the row is seen along one image axis
    /// ([`Shared`]; `u`, or with `SHARED_V` `v`): the depth, the first pixel and the weights
    /// along that axis, and `1/p` of its trapezoid, for the `CHUNK` rows whose first voxels
    /// are `bases` ([`Self::row_start`]), vectorised across the rows.
    #[inline(always)]
    fn rows_shared<const N: usize, const SHARED_V: bool>(&self, bases: &[[f32; 3]; CHUNK], out: &mut [RowShared<N>]) {
        let n = N as f32;
        let moving = if SHARED_V { 0 } else { 1 };
        let n_s = if SHARED_V { self.rows } else { self.cols };
        let lim_s = n_s as f32 - 1.0;
        let bound_s = if SHARED_V { (self.cam.height + N) as f32 } else { (self.cam.width + N) as f32 };
        let z16 = [0f32; CHUNK];
        let (mut first, mut inv_p, mut zs, mut iz, mut fixed) = (z16, z16, z16, z16, z16);
        let (mut off, mut ps, mut ls, mut inv_s) = (z16, z16, z16, z16);
        for q in 0..CHUNK {
            let base = bases[q];
            let z = base[2];
            let in_front = z > 1e-6;
            zs[q] = if in_front { z } else { 1.0 };
            iz[q] = 1.0 / zs[q];
            fixed[q] = base[1 - moving];
            let (f, i) = (fixed[q], iz[q]);
            let (centre_s, w_s) =
                if SHARED_V { self.along::<true>(0.0, f * i, i) } else { self.along::<false>(f * i, 0.0, i) };
            let (p, l) = trapezoid(w_s);
            // Narrowing leaves a trapezoid that already fits unchanged, so it does not depend
            // on the other voxels of a chunk.
            let (p, l) = fit_trapezoid(p, l, lim_s, p + l > lim_s);
            let t_s = centre_s - 0.5 * (p + l) + 0.5 + n;
            first[q] = if in_front & (t_s >= 0.0) & (t_s < bound_s) { floor_small(t_s) } else { -1.0 };
            off[q] = (centre_s + n + 0.5) - first[q];
            (ps[q], ls[q], inv_s[q], inv_p[q]) = (p, l, 0.5 / l, 1.0 / p);
        }
        let mut w = [z16; N];
        axis_weights_chunk::<N>(&off, &ps, &ls, &inv_s, n_s, |q, k, v| w[k][q] = v);
        for (q, rs) in out.iter_mut().enumerate().take(CHUNK) {
            let mut wq = [0f32; N];
            for (k, wk) in wq.iter_mut().enumerate() {
                *wk = w[k][q];
            }
            *rs = RowShared { first: first[q], w: wq, inv_p: inv_p[q], iz: iz[q], zs: zs[q], fixed: fixed[q] };
        }
    }

    /// The footprints of `CHUNK` consecutive voxels of a row (`p = base + (i0 + q) · step`)
    /// along the axis they do not share (see [`Self::rows_shared`]): first pixel (−1: the voxel
    /// misses, or the row does), amplitude, and the first `n_l ≤ N` pixel weights, pixel-major.
    /// One division per voxel, for that axis's `1/(2l)` and the amplitude together.
    #[inline(always)]
    fn chunk_moving<const N: usize, const SHARED_V: bool>(
        &self,
        rs: &RowShared<N>,
        base: [f32; 3],
        step: [f32; 3],
        i0: usize,
        n_l: usize,
        out: &mut Moving<N>,
    ) {
        let mut t = [MovingTrapezoids::default()];
        self.row_moving::<N, SHARED_V>(rs, base, step, n_l, &[i0], &mut t, std::slice::from_mut(out));
    }

    /// [`Self::chunk_moving`] for the chunks of a row that start at the voxels `starts` (lanes
    /// past the row's end are computed as if the row went on) into `out`, stage by stage
    /// across the chunks, so that the chunks' long chains of dependent operations (two square
    /// roots and a division) overlap. The same arithmetic per voxel whatever the number of
    /// chunks, so the same results bit for bit. `scratch` holds at least as many entries as
    /// `starts`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn row_moving<const N: usize, const SHARED_V: bool>(
        &self,
        rs: &RowShared<N>,
        base: [f32; 3],
        step: [f32; 3],
        n_l: usize,
        starts: &[usize],
        scratch: &mut [MovingTrapezoids],
        out: &mut [Moving<N>],
    ) {
        let row = self.moving_row::<N, SHARED_V>(rs, base, step);
        let mut wide = false;
        for (&i0, t) in starts.iter().zip(scratch.iter_mut()) {
            row.trapezoids(i0, t);
            wide |= row.wide(t);
        }
        for (t, mv) in scratch.iter_mut().zip(out.iter_mut()) {
            row.place(rs, wide, t, mv);
        }
        for (t, mv) in scratch.iter().zip(out.iter_mut()) {
            axis_weights_chunk::<N>(&t.off, &t.p, &t.l, &t.inv, n_l, |q, k, w| mv.w[k][q] = w);
        }
    }

    /// The factors of a row's moving axis (see [`MovingRow`]).
    #[inline(always)]
    fn moving_row<const N: usize, const SHARED_V: bool>(
        &self,
        rs: &RowShared<N>,
        base: [f32; 3],
        step: [f32; 3],
    ) -> MovingRow {
        let moving = if SHARED_V { 0 } else { 1 };
        let (iz, fixed) = (rs.iz, rs.fixed);
        // Along the row only the moving camera coordinate `c` changes, and the centre and the
        // three edge widths of `Self::along` are affine in it: `centre = c0 + c1 c` and
        // `w_a = |a0_a + a1_a c|` (the same quantities, with the row's factors taken once).
        let (c0, c1, a0, a1) = if SHARED_V {
            let yn = fixed * iz;
            let (f, s) = (self.cam.fx * iz, self.cam.skew * iz);
            let e = &self.edges;
            let a0 = axes3(|a| f * e[a][0] + s * (e[a][1] - yn * e[a][2]));
            (self.cam.skew * yn + self.cam.cx, f, a0, axes3(|a| -f * iz * e[a][2]))
        } else {
            let f = self.cam.fy * iz;
            let e = &self.edges;
            (self.cam.cy, f, axes3(|a| f * e[a][1]), axes3(|a| -f * iz * e[a][2]))
        };
        MovingRow {
            start: base[moving],
            step: step[moving],
            c0,
            c1,
            a0,
            a1,
            base_s: fixed * fixed + rs.zs * rs.zs,
            g0: self.gain * iz * iz * iz,
            lim: (if SHARED_V { self.cols } else { self.rows }) as f32 - 1.0,
            bound: if SHARED_V { (self.cam.width + N) as f32 } else { (self.cam.height + N) as f32 },
        }
    }

    /// Largest footprint support `p + l` along `u` and along `v` over a 9³ lattice spanning the
    /// voxel centres, in pixels (not narrowed to any side).
    fn support_px(&self, grid: &Grid) -> (f64, f64) {
        let sp = grid.spacing();
        let lo = grid.aabb.min + 0.5 * sp;
        let span = grid.aabb.size() - sp;
        let (mut largest_u, mut largest_v) = (0f32, 0f32);
        let n = 9;
        for a in 0..n {
            for b in 0..n {
                for c in 0..n {
                    let f = glam::DVec3::new(a as f64, b as f64, c as f64) / (n - 1) as f64;
                    let w = lo + f * span;
                    let w = [w.x as f32, w.y as f32, w.z as f32];
                    let r = &self.cam.rot;
                    let p = [0, 1, 2].map(|i| r[i][0] * w[0] + r[i][1] * w[1] + r[i][2] * w[2] + self.cam.trans[i]);
                    let (in_front, _, _, wu, wv, _) =
                        if self.cam.distorted { self.project::<true>(p) } else { self.project::<false>(p) };
                    if in_front {
                        let (pu, lu) = trapezoid(wu);
                        let (pv, lv) = trapezoid(wv);
                        largest_u = largest_u.max(pu + lu);
                        largest_v = largest_v.max(pv + lv);
                    }
                }
            }
        }
        (largest_u as f64, largest_v as f64)
    }

    /// Padded image size for footprints of side `N`: `(width + 2N) × (height + 2N)`.
    fn padded(&self) -> (usize, usize) {
        (self.cam.width + 2 * self.side, self.cam.height + 2 * self.side)
    }
}

/// The separable-footprint projector; see the module docs.
#[derive(Clone, Debug)]
pub struct FootprintProjector {
    grid: Grid,
    cameras: Vec<Camera>,
    views: Vec<FootView>,
    gf: GridF32,
    isa: Isa,
    kept: Option<Arc<KeptFootprints>>,
}

/// The moving-axis footprints of the views whose grid rows share a footprint axis, kept
/// between back projections ([`FootprintProjector::with_kept_footprints`]): per view (`None`
/// for a view not kept) one entry per z-slice, filled by the first back projection that reads
/// that slice.
#[derive(Debug, Default)]
struct KeptFootprints {
    views: Vec<Option<Box<[OnceLock<KeptSlice>]>>>,
}

/// One z-slice's kept footprints: each row's stretch of first pixels (`first_range`) and, for
/// each row and chunk, `2 + n_l` vectors (first pixels, amplitudes, weights).
#[derive(Debug)]
struct KeptSlice {
    ranges: Box<[(f32, f32)]>,
    data: Box<[[f32; CHUNK]]>,
}

impl KeptSlice {
    /// Row `j`'s footprints (`len` vectors); starts loading the row four ahead into L2, as the
    /// rows are read in order (without it a back projection of the 90-view ring at 64³ took
    /// 0.034–0.038 s against 0.030–0.033 s, waiting on memory).
    #[inline(always)]
    fn row(&self, j: usize, len: usize) -> &[[f32; CHUNK]] {
        #[cfg(target_arch = "x86_64")]
        if let Some(ahead) = self.data.get((j + 4) * len..(j + 5) * len) {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T1};
            for v in ahead {
                // SAFETY: a prefetch of memory inside `data` (SSE, part of x86-64).
                unsafe { _mm_prefetch::<_MM_HINT_T1>(v.as_ptr().cast()) };
            }
        }
        &self.data[j * len..][..len]
    }
}

/// Chunk `c` of a kept row ([`KeptSlice::row`]) of chunks of `stride` vectors.
#[inline(always)]
fn kept_chunk(row: &[[f32; CHUNK]], c: usize, stride: usize) -> ChunkFoot<'_> {
    let d = &row[c * stride..][..stride];
    ChunkFoot { first: &d[0], amp: &d[1], w: &d[2..] }
}

impl FootprintProjector {
    /// A projector from `grid` to the images of `cameras`, with the scene's
    /// `intensity_scale` (pixel = scale × ∫ E ds). Fails if a voxel images larger than the
    /// largest footprint (63 pixels; use more voxels or the ray projector).
    pub fn new(grid: Grid, cameras: &[Camera], intensity_scale: f64) -> Result<Self, ClassicalError> {
        validate(&grid, cameras, intensity_scale)?;
        let views: Vec<FootView> = cameras.iter().map(|c| FootView::new(c, &grid, intensity_scale)).collect();
        for (v, view) in views.iter().enumerate() {
            let (su, sv) = view.support_px(&grid);
            let px = su.max(sv);
            if px > AUTO_FOOTPRINT_MAX_PX {
                return Err(ClassicalError::invalid(
                    "projector",
                    format!(
                        "voxels image up to {px:.0} pixels wide in view {v}, more than the footprint projector's \
                         {} pixels; use more voxels or the ray projector",
                        MAX_FOOTPRINT_SIDE - 1
                    ),
                ));
            }
        }
        let gf = GridF32::new(&grid);
        Ok(FootprintProjector { grid, cameras: cameras.to_vec(), views, gf, isa: Isa::detected(), kept: None })
    }

    /// The same projector running the kernels of at most `isa` (never more than this CPU
    /// supports), for comparing the variants in tests and benchmarks.
    pub fn with_isa(mut self, isa: Isa) -> Self {
        self.isa = isa.min(Isa::detected());
        self
    }

    /// The same projector keeping, between back projections, the footprints it computes along
    /// the axis that moves along a grid row, for views whose grid rows share the other axis
    /// (rings around the grid's `x` axis), up to `budget` bytes: views in order, each whole or
    /// not at all. Back projections then read them instead of computing them again; the first
    /// one of each view computes and stores them. The results are the same bit for bit (the
    /// same values, read back). The forward projection computes its own: reading them
    /// instead made it no faster. [`Self::kept_footprint_bytes`] gives the memory: about
    /// `(2 + n) · 4` bytes per voxel and view, `n` the pixels a footprint spans along the
    /// moving axis (2–3 for voxels imaging at 1–2 px).
    pub fn with_kept_footprints(mut self, budget: u64) -> Self {
        let mut left = budget;
        let nz = self.grid.dims[2];
        let views = (0..self.views.len())
            .map(|v| {
                let bytes = self.view_kept_bytes(v);
                (bytes > 0 && bytes <= left).then(|| {
                    left -= bytes;
                    (0..nz).map(|_| OnceLock::new()).collect()
                })
            })
            .collect();
        self.kept = Some(Arc::new(KeptFootprints { views }));
        self
    }

    /// Bytes the footprints kept for `view` take once filled; 0 when its rows share no axis.
    fn view_kept_bytes(&self, view: usize) -> u64 {
        let fv = &self.views[view];
        let n_l = match fv.shared {
            Shared::None => return 0,
            Shared::V => fv.cols,
            Shared::U => fv.rows,
        };
        let [nx, ny, nz] = self.grid.dims;
        let per_row = nx.div_ceil(CHUNK) * (2 + n_l) * CHUNK * 4 + 8;
        (nz * ny * per_row) as u64
    }

    /// Views whose footprints are kept ([`Self::with_kept_footprints`]).
    pub fn kept_footprint_views(&self) -> usize {
        self.kept.as_ref().map_or(0, |k| k.views.iter().filter(|v| v.is_some()).count())
    }

    /// Bytes the kept footprints take once every kept view has been back-projected.
    pub fn kept_footprint_bytes(&self) -> u64 {
        let Some(k) = &self.kept else { return 0 };
        k.views.iter().enumerate().filter(|(_, v)| v.is_some()).map(|(v, _)| self.view_kept_bytes(v)).sum()
    }

    /// The kept moving-axis footprints of slice `k` of `view` (see [`KeptFootprints`]): for
    /// each row and chunk, `2 + n_l` vectors (first pixels, amplitudes, weights).
    fn keep_slice<const N: usize, const SHARED_V: bool>(
        &self,
        view: usize,
        k: usize,
        rss: &[RowShared<N>],
        n_l: usize,
    ) -> KeptSlice {
        let fv = &self.views[view];
        let [nx, ny, _] = self.grid.dims;
        let nc = nx.div_ceil(CHUNK);
        let stride = 2 + n_l;
        let mut data = vec![[-1f32; CHUNK]; ny * nc * stride];
        let mut ranges = vec![(-1f32, -1f32); ny];
        let mut mvs = vec![Moving::<N>::default(); nc];
        let starts: Vec<usize> = (0..nx).step_by(CHUNK).collect();
        let mut scratch = vec![MovingTrapezoids::default(); nc];
        for (j, rs) in rss.iter().enumerate() {
            if rs.first < 0.0 {
                continue;
            }
            let (base, step) = fv.cam.row_start(&self.gf, j, k, [0.0; 3]);
            fv.row_moving::<N, SHARED_V>(rs, base, step, n_l, &starts, &mut scratch, &mut mvs);
            if nx % CHUNK != 0 {
                mvs[nx / CHUNK].first[nx % CHUNK..].fill(-1.0);
            }
            ranges[j] = first_range(mvs.iter().map(|mv| &mv.first));
            for (c, mv) in mvs.iter().enumerate() {
                let d = &mut data[(j * nc + c) * stride..][..stride];
                d[0] = mv.first;
                d[1] = mv.amp;
                d[2..].copy_from_slice(&mv.w[..n_l]);
            }
        }
        KeptSlice { ranges: ranges.into_boxed_slice(), data: data.into_boxed_slice() }
    }

    /// The instruction set the kernels run with.
    pub fn isa(&self) -> Isa {
        self.isa
    }

    /// The same projector with the shared-row shortcut on (the default) or off: with it, views
    /// whose camera sees a grid row as a vertical or horizontal line of voxels (a ring around
    /// the grid's `x` axis, no distortion) compute the row's footprint along that image axis
    /// once per row instead of once per voxel, and their back projection sums the image lines
    /// under it first. Both give the same weights up to rounding; off is for comparisons in
    /// tests and benchmarks.
    pub fn with_shared_rows(mut self, on: bool) -> Self {
        for (view, camera) in self.views.iter_mut().zip(&self.cameras) {
            view.shared = if on { FootView::new(camera, &self.grid, 1.0).shared } else { Shared::None };
        }
        self
    }

    /// Views that use the shared-row shortcut ([`Self::with_shared_rows`]).
    pub fn shared_row_views(&self) -> usize {
        self.views.iter().filter(|v| v.shared != Shared::None).count()
    }

    /// Largest width of a voxel's footprint over all views, in pixels (the support of the
    /// trapezoids, measured over a lattice spanning the box): what [`crate::ProjectorConfig`]'s
    /// automatic choice looks at.
    pub fn largest_footprint_px(grid: &Grid, cameras: &[Camera]) -> f64 {
        cameras
            .iter()
            .map(|c| {
                let (su, sv) = FootView::new(c, grid, 1.0).support_px(grid);
                su.max(sv)
            })
            .fold(0.0, f64::max)
    }

    /// Side `N` of the pixel square each voxel touches in view `view`.
    pub fn footprint_side(&self, view: usize) -> usize {
        self.views[view].side
    }

    /// Computes the footprints of every chunk of z-slices `ks` of view `view` (pixel-major with
    /// `LANES`) and hands each to `visit(chunk, index of its first voxel, voxels of the chunk
    /// inside the grid row)`; indices count from the first voxel of slice `ks.start`.
    #[inline(always)]
    fn for_each_chunk<const N: usize, const DISTORTED: bool, const LANES: bool>(
        &self,
        view: usize,
        ks: Range<usize>,
        mut visit: impl FnMut(&Chunk<N>, usize, usize),
    ) {
        let fv = &self.views[view];
        let [nx, ny, _] = self.grid.dims;
        let mut ch = Chunk::<N>::default();
        for (kk, k) in ks.enumerate() {
            for j in 0..ny {
                let (base, step) = fv.cam.row_start(&self.gf, j, k, [0.0; 3]);
                let row0 = (kk * ny + j) * nx;
                for i0 in (0..nx).step_by(CHUNK) {
                    fv.chunk::<N, DISTORTED, LANES>(base, step, i0, &mut ch);
                    visit(&ch, row0 + i0, CHUNK.min(nx - i0));
                }
            }
        }
    }

    /// Forward kernel: accumulates `A_v x` of slices `ks` into the [`SCATTER_IMAGES`] padded
    /// images `img`. It keeps its own loops rather than [`Self::for_each_chunk`]'s: with the
    /// per-chunk work in a closure the AVX-512 forward projection ran 16 % slower.
    #[inline(always)]
    fn scatter<const N: usize, const DISTORTED: bool, const LANES: bool>(
        &self,
        view: usize,
        ks: Slices,
        x: &[f32],
        known: Option<&NonEmptyChunks>,
        img: &mut [f32],
    ) {
        let fv = &self.views[view];
        let (pw, ph) = fv.padded();
        let nr = fv.rows;
        let [nx, ny, _] = self.grid.dims;
        let mut chunks = vec![Chunk::<N>::default(); nx.div_ceil(CHUNK)];
        let mut own = Vec::with_capacity(chunks.len());
        let mut scratch = vec![ChunkTrapezoids::default(); chunks.len()];
        for k in ks {
            for j in 0..ny {
                let row0 = (k * ny + j) * nx;
                // Empty voxels add nothing: a chunk of them needs no footprints. Flows leave
                // most of a box dark, so this is most of the work of a projection there.
                let starts = row_chunks_of(known, x, row0, nx, &mut own);
                if starts.is_empty() {
                    continue;
                }
                let (base, step) = fv.cam.row_start(&self.gf, j, k, [0.0; 3]);
                let chunks = &mut chunks[..starts.len()];
                fv.row_chunks::<N, DISTORTED, LANES>(base, step, starts, &mut scratch, chunks);
                for (&i0, ch) in starts.iter().zip(chunks.iter()) {
                    let valid = CHUNK.min(nx - i0);
                    if LANES {
                        // Each voxel's start pixel and weighted value, vectorised across the chunk;
                        // misses and empty voxels get a zero value and are skipped.
                        let g = chunk_values(x, row0 + i0, valid);
                        let (mut at, mut a) = ([0u32; CHUNK], [0f32; CHUNK]);
                        for q in 0..CHUNK {
                            let hit = ch.col[q] >= 0.0;
                            let (row, col) = if hit { (ch.row[q], ch.col[q]) } else { (0.0, 0.0) };
                            // SAFETY: whole numbers in [0, 2³²) (`chunk`; the caller checks that the
                            // padded image has fewer than 2³² pixels), so the conversions are exact.
                            let (row, col) = unsafe { (row.to_int_unchecked::<u32>(), col.to_int_unchecked::<u32>()) };
                            at[q] = row * pw as u32 + col;
                            a[q] = if hit && g[q] != 0.0 { g[q] * ch.amp[q] } else { 0.0 };
                        }
                        let images = img.as_mut_ptr();
                        for q in 0..valid {
                            if a[q] == 0.0 {
                                continue;
                            }
                            // SAFETY: `img` holds SCATTER_IMAGES padded images.
                            let dst = unsafe { images.add((q % SCATTER_IMAGES) * pw * ph) };
                            let wu: [f32; N] = std::array::from_fn(|c| ch.wu_lanes[c][q]);
                            for r in 0..nr {
                                let s = a[q] * ch.wv_lanes[r][q];
                                // SAFETY: a voxel that hits has its N × rows square inside the
                                // padded image (`chunk`: c0 < width + N, r0 < height + N, rows ≤ N,
                                // and the padded image is (width + 2N) × (height + 2N)).
                                let line = unsafe { &mut *dst.add(at[q] as usize + r * pw).cast::<[f32; N]>() };
                                for c in 0..N {
                                    line[c] += s * wu[c];
                                }
                            }
                        }
                        continue;
                    }
                    for q in 0..valid {
                        let g = x[row0 + i0 + q];
                        let Some((col, row, amp)) = ch.get(q) else { continue };
                        if g == 0.0 {
                            continue;
                        }
                        let a = g * amp;
                        let at = row * pw + col;
                        let dst = &mut img[(q & 1) * pw * ph..][..pw * ph];
                        let (wu, wv) = ch.weights(q);
                        for (r, &wr) in wv[..nr].iter().enumerate() {
                            let s = a * wr;
                            let line: &mut [f32; N] = (&mut dst[at + r * pw..][..N]).try_into().expect("N pixels");
                            for c in 0..N {
                                line[c] += s * wu[c];
                            }
                        }
                    }
                }
            }
        }
    }

    /// Back kernel: `out += A_vᵀ y` on slices `ks` (`out` holds those slices only) from the
    /// zero-padded image `y`, and the column sums if asked.
    #[inline(always)]
    fn gather<const N: usize, const DISTORTED: bool>(
        &self,
        view: usize,
        ks: Range<usize>,
        y: &[f32],
        masks: (&[f32], &[f32]),
        out: &mut [f32],
        mut col_sums: Option<&mut [f32]>,
    ) {
        let fv = &self.views[view];
        let pw = fv.padded().0;
        let nr = fv.rows;
        let (col_mask, row_mask) = masks;
        self.for_each_chunk::<N, DISTORTED, false>(view, ks, |ch, first, valid| {
            for q in 0..valid {
                let Some((col, row, amp)) = ch.get(q) else { continue };
                let (wu, wv) = ch.weights(q);
                let at = row * pw + col;
                let mut acc = [0f32; N];
                for (r, &wr) in wv[..nr].iter().enumerate() {
                    let line: &[f32; N] = (&y[at + r * pw..][..N]).try_into().expect("N pixels");
                    for c in 0..N {
                        acc[c] += wr * line[c];
                    }
                }
                let sum = dot_columns(&acc, &wu);
                let idx = first + q;
                out[idx] += amp * sum;
                if let Some(cs) = col_sums.as_deref_mut() {
                    let cm: &[f32; N] = (&col_mask[col..][..N]).try_into().expect("N columns");
                    let rm: &[f32; N] = (&row_mask[row..][..N]).try_into().expect("N rows");
                    let (mut su, mut sv) = (0f32, 0f32);
                    for c in 0..N {
                        su += wu[c] * cm[c];
                    }
                    for r in 0..nr {
                        sv += wv[r] * rm[r];
                    }
                    cs[idx] += amp * su * sv;
                }
            }
        });
    }

    /// [`Self::gather`] eight voxels at a time in the AVX2 lanes: each footprint pixel of eight
    /// voxels is read with one gather, and the weights stay in the pixel-major layout the
    /// footprints are computed in. Every voxel's arithmetic is that of [`Self::gather`] in the
    /// same order (rows summed per column, then columns; the column sums' two masked sums
    /// likewise), so the results are identical. For small sides, where a voxel's row is too
    /// short for a vector of its own.
    ///
    /// # Safety
    /// The CPU must support AVX2, and the padded image must hold fewer than 2³¹ pixels.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn gather_lanes<const N: usize, const DISTORTED: bool>(
        &self,
        view: usize,
        ks: Range<usize>,
        y: &[f32],
        masks: (&[f32], &[f32]),
        out: &mut [f32],
        mut col_sums: Option<&mut [f32]>,
    ) {
        use std::arch::x86_64::*;
        const LANES: usize = 8;
        let fv = &self.views[view];
        let pw = fv.padded().0;
        debug_assert!(y.len() == pw * fv.padded().1 && y.len() < i32::MAX as usize);
        let nr = fv.rows;
        let pw_v = _mm256_set1_epi32(pw as i32);
        let iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        self.for_each_chunk::<N, DISTORTED, true>(view, ks, |ch, first, valid| {
            for h in (0..valid).step_by(LANES) {
                // SAFETY: every pointer below is in bounds: `h + 8 ≤ CHUNK` for the chunk's
                // arrays; a voxel that hits has its N × rows square inside the padded
                // image (see `chunk`: c0 < width + N, r0 < height + N, rows ≤ N), and
                // one that misses reads from pixel 0 onwards, inside the image too; the
                // masked load and store of `out` touch only voxels of this row.
                unsafe {
                    let col = _mm256_loadu_ps(ch.col.as_ptr().add(h));
                    let hit = _mm256_cmp_ps::<_CMP_GE_OQ>(col, _mm256_setzero_ps());
                    // First column and row, 0 for a miss.
                    let cols = _mm256_and_si256(_mm256_cvttps_epi32(col), _mm256_castps_si256(hit));
                    let rows = _mm256_and_si256(
                        _mm256_cvttps_epi32(_mm256_loadu_ps(ch.row.as_ptr().add(h))),
                        _mm256_castps_si256(hit),
                    );
                    let at = _mm256_add_epi32(_mm256_mullo_epi32(rows, pw_v), cols);
                    let mut sum = _mm256_setzero_ps();
                    let inside = _mm256_cmpgt_epi32(_mm256_set1_epi32((valid - h) as i32), iota);
                    let keep = _mm256_and_si256(inside, _mm256_castps_si256(hit));
                    let amp = _mm256_loadu_ps(ch.amp.as_ptr().add(h));
                    // Per column, the rows' weighted pixels summed in row order, then the
                    // columns: every column's sum is that of the gather's loop.
                    let mut accs = [_mm256_setzero_ps(); N];
                    let mut at_lanes = [0i32; LANES];
                    _mm256_storeu_si256(at_lanes.as_mut_ptr().cast(), at);
                    for r in 0..nr {
                        let px = footprint_row8::<N>(y.as_ptr().add(r * pw), &at_lanes, at);
                        let wr = _mm256_loadu_ps(ch.wv_lanes[r].as_ptr().add(h));
                        for c in 0..N {
                            accs[c] = _mm256_add_ps(accs[c], _mm256_mul_ps(wr, px[c]));
                        }
                    }
                    for (c, acc) in accs.iter().enumerate() {
                        let wc = _mm256_loadu_ps(ch.wu_lanes[c].as_ptr().add(h));
                        sum = _mm256_add_ps(sum, _mm256_mul_ps(*acc, wc));
                    }
                    // dst += v for the voxels that hit, inside the row: with a plain load and
                    // store (the misses written back as they were) when all eight lanes lie
                    // inside it, as masked stores are slow on AMD's cores.
                    let add_to = |dst: *mut f32, v: __m256| add_kept8(dst, v, keep, valid - h >= LANES);
                    add_to(out[first + h..].as_mut_ptr(), _mm256_mul_ps(amp, sum));
                    if let Some(cs) = col_sums.as_deref_mut() {
                        // cs += amp · (Σ_c wu · col_mask) · (Σ_r wv · row_mask); a miss reads the
                        // masks from index 0 onwards (c0 + N ≤ padded width for a hit).
                        let (mut su, mut sv) = (_mm256_setzero_ps(), _mm256_setzero_ps());
                        for c in 0..N {
                            let m = _mm256_i32gather_ps::<4>(
                                masks.0.as_ptr(),
                                _mm256_add_epi32(cols, _mm256_set1_epi32(c as i32)),
                            );
                            su = _mm256_add_ps(su, _mm256_mul_ps(_mm256_loadu_ps(ch.wu_lanes[c].as_ptr().add(h)), m));
                        }
                        for r in 0..nr {
                            let m = _mm256_i32gather_ps::<4>(
                                masks.1.as_ptr(),
                                _mm256_add_epi32(rows, _mm256_set1_epi32(r as i32)),
                            );
                            sv = _mm256_add_ps(sv, _mm256_mul_ps(_mm256_loadu_ps(ch.wv_lanes[r].as_ptr().add(h)), m));
                        }
                        add_to(cs[first + h..].as_mut_ptr(), _mm256_mul_ps(_mm256_mul_ps(amp, su), sv));
                    }
                }
            }
        });
    }

    /// [`Self::gather_lanes`] with AVX-512: one chunk of sixteen voxels per gather, the same
    /// arithmetic in the same order, column sums included.
    ///
    /// # Safety
    /// The CPU must support AVX-512F, and the padded image must hold fewer than 2³¹ pixels.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    unsafe fn gather_lanes16<const N: usize, const DISTORTED: bool>(
        &self,
        view: usize,
        ks: Range<usize>,
        y: &[f32],
        masks: (&[f32], &[f32]),
        out: &mut [f32],
        mut col_sums: Option<&mut [f32]>,
    ) {
        let fv = &self.views[view];
        debug_assert!(y.len() == fv.padded().0 * fv.padded().1 && y.len() < i32::MAX as usize);
        self.for_each_chunk::<N, DISTORTED, true>(view, ks, |ch, first, valid| {
            // SAFETY: AVX-512F is enabled here (this function's contract), and `y` is the view's
            // padded image.
            unsafe { self.lanes16_chunk(fv, ch, first, valid, y, masks, out, col_sums.as_deref_mut()) }
        });
    }

    /// One chunk of [`Self::gather_lanes16`]: `out[first..][..valid] += A_vᵀ y` of the chunk's
    /// voxels that hit, and their column sums if asked.
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `y` is the view's padded image (fewer than 2³¹ pixels).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    unsafe fn lanes16_chunk<const N: usize>(
        &self,
        fv: &FootView,
        ch: &Chunk<N>,
        first: usize,
        valid: usize,
        y: &[f32],
        masks: (&[f32], &[f32]),
        out: &mut [f32],
        col_sums: Option<&mut [f32]>,
    ) {
        use std::arch::x86_64::*;
        const { assert!(CHUNK == 16) };
        let pw = fv.padded().0;
        let pw_v = _mm512_set1_epi32(pw as i32);
        // SAFETY: as in `gather_lanes`: the chunk's arrays hold 16 entries, and every
        // gathered index lies inside the padded image (a voxel that misses reads
        // from pixel 0 onwards).
        unsafe {
            let col = _mm512_loadu_ps(ch.col.as_ptr());
            let hit = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(col, _mm512_setzero_ps());
            // First column and row, 0 for a miss.
            let cols = _mm512_maskz_mov_epi32(hit, _mm512_cvttps_epi32(col));
            let rows = _mm512_maskz_mov_epi32(hit, _mm512_cvttps_epi32(_mm512_loadu_ps(ch.row.as_ptr())));
            let at = _mm512_add_epi32(_mm512_mullo_epi32(rows, pw_v), cols);
            let plus = |v: __m512i, k: usize| _mm512_add_epi32(v, _mm512_set1_epi32(k as i32));
            Self::weigh16(
                ch,
                fv.rows,
                (first, valid, hit & ((1u32 << valid) - 1) as u16),
                out,
                col_sums,
                |r| footprint_row16::<N>(y.as_ptr().add(r * pw), at),
                |c| _mm512_i32gather_ps::<4>(plus(cols, c), masks.0.as_ptr()),
                |r| _mm512_i32gather_ps::<4>(plus(rows, r), masks.1.as_ptr()),
            );
        }
    }

    /// The arithmetic of the AVX-512 lane kernels, whatever reads the pixels: for the voxels
    /// of a chunk in `keep` (`at = (first, valid, keep)`), `out += amp · Σ_c wu_c Σ_r wv_r
    /// px(c, r)` with `px(c, r) = row(r)[c]` (rows summed per column, then columns, as
    /// [`Self::gather`] does), and with `col_sums` `amp · (Σ_c wu_c mu(c)) · (Σ_r wv_r
    /// mv(r))`, where `mu` and `mv` give the column and row masks.
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `first + valid` lies inside `out` (and `col_sums`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    unsafe fn weigh16<const N: usize>(
        ch: &Chunk<N>,
        nr: usize,
        (first, valid, keep): (usize, usize, u16),
        out: &mut [f32],
        col_sums: Option<&mut [f32]>,
        row: impl Fn(usize) -> [std::arch::x86_64::__m512; N],
        mu: impl Fn(usize) -> std::arch::x86_64::__m512,
        mv: impl Fn(usize) -> std::arch::x86_64::__m512,
    ) {
        use std::arch::x86_64::*;
        // SAFETY: the chunk's arrays hold 16 entries, and the masked loads and stores touch
        // `valid` entries from `first` on (the caller's contract).
        unsafe {
            // Per column, the rows' weighted pixels summed in row order, then the columns.
            let mut accs = [_mm512_setzero_ps(); N];
            for r in 0..nr {
                let px = row(r);
                let wr = _mm512_loadu_ps(ch.wv_lanes[r].as_ptr());
                for c in 0..N {
                    accs[c] = _mm512_add_ps(accs[c], _mm512_mul_ps(wr, px[c]));
                }
            }
            let mut sum = _mm512_setzero_ps();
            for (c, acc) in accs.iter().enumerate() {
                let wc = _mm512_loadu_ps(ch.wu_lanes[c].as_ptr());
                sum = _mm512_add_ps(sum, _mm512_mul_ps(*acc, wc));
            }
            // out += amp · sum for the voxels that hit, inside the row.
            let amp = _mm512_loadu_ps(ch.amp.as_ptr());
            let dst = out[first..][..valid].as_mut_ptr();
            let prev = _mm512_mask_loadu_ps(_mm512_setzero_ps(), keep, dst);
            _mm512_mask_storeu_ps(dst, keep, _mm512_add_ps(prev, _mm512_mul_ps(amp, sum)));
            if let Some(cs) = col_sums {
                // As in `gather_lanes`.
                let (mut su, mut sv) = (_mm512_setzero_ps(), _mm512_setzero_ps());
                for c in 0..N {
                    su = _mm512_add_ps(su, _mm512_mul_ps(_mm512_loadu_ps(ch.wu_lanes[c].as_ptr()), mu(c)));
                }
                for r in 0..nr {
                    sv = _mm512_add_ps(sv, _mm512_mul_ps(_mm512_loadu_ps(ch.wv_lanes[r].as_ptr()), mv(r)));
                }
                let dst = cs[first..][..valid].as_mut_ptr();
                let prev = _mm512_mask_loadu_ps(_mm512_setzero_ps(), keep, dst);
                _mm512_mask_storeu_ps(dst, keep, _mm512_add_ps(prev, _mm512_mul_ps(_mm512_mul_ps(amp, su), sv)));
            }
        }
    }

    /// [`FootView::rows_shared`] of every grid row of slice `k` in view `view`, sixteen rows at
    /// a time, into `out` (one entry per row).
    #[inline(always)]
    fn slice_rows_shared<const N: usize, const SHARED_V: bool>(&self, view: usize, k: usize, out: &mut [RowShared<N>]) {
        let fv = &self.views[view];
        let ny = self.grid.dims[1];
        let mut rs = [RowShared::<N>::default(); CHUNK];
        for j0 in (0..ny).step_by(CHUNK) {
            let mut bases = [[0f32; 3]; CHUNK];
            for (q, b) in bases.iter_mut().enumerate() {
                *b = fv.cam.row_start(&self.gf, (j0 + q).min(ny - 1), k, [0.0; 3]).0;
            }
            fv.rows_shared::<N, SHARED_V>(&bases, &mut rs);
            let m = CHUNK.min(ny - j0);
            out[j0..j0 + m].copy_from_slice(&rs[..m]);
        }
    }

    /// [`Self::scatter`] for views whose grid rows share a footprint axis ([`Shared`]): the
    /// transpose of [`Self::gather_rows`]. The shared axis's footprint is computed once per grid
    /// row ([`FootView::rows_shared`]) and only the other axis per chunk
    /// ([`FootView::chunk_moving`]). Each voxel adds its `n_l` weights along the moving axis to
    /// one line (`n_l` products per voxel instead of `n_s · n_l`; consecutive voxels alternate
    /// between [`SCATTER_IMAGES`] lines, so that voxels adding to the same pixel do not chain
    /// through memory), and the summed line is then added to the `n_s` image lines under the
    /// row's shared footprint with its weights, as whole vectors. The image lines are the
    /// padded image's rows when rows image horizontal (`SHARED_V`); when they image vertical
    /// they are its columns, accumulated transposed in the first image and added in place at
    /// the end.
    #[inline(always)]
    fn scatter_shared<const N: usize, const SHARED_V: bool>(
        &self,
        view: usize,
        ks: Slices,
        x: &[f32],
        known: Option<&NonEmptyChunks>,
        img: &mut [f32],
    ) {
        let fv = &self.views[view];
        let (pw, ph) = fv.padded();
        let (line_len, n_l, n_s) = if SHARED_V { (pw, fv.cols, fv.rows) } else { (ph, fv.rows, fv.cols) };
        let [nx, ny, _] = self.grid.dims;
        let mut mvs = vec![Moving::<N>::default(); nx.div_ceil(CHUNK)];
        let mut own = Vec::with_capacity(mvs.len());
        let mut scratch = vec![MovingTrapezoids::default(); mvs.len()];
        let mut rss = vec![RowShared::<N>::default(); ny];
        // The summed lines, one per voxel of a group of SCATTER_IMAGES consecutive voxels,
        // each with N + CHUNK values of slack past the line's end.
        const { assert!(SCATTER_IMAGES == 4) };
        let stride = line_len + N + CHUNK;
        let mut acc = vec![0f32; SCATTER_IMAGES * stride];
        for k in ks {
            if known.is_some_and(|c| (0..ny).all(|j| c.row(k * ny + j).is_empty())) {
                continue;
            }
            self.slice_rows_shared::<N, SHARED_V>(view, k, &mut rss);
            for (j, rs) in rss.iter().enumerate() {
                let row0 = (k * ny + j) * nx;
                if rs.first < 0.0 {
                    continue;
                }
                // Empty voxels add nothing: only the chunks with a non-zero voxel get
                // footprints.
                let starts = row_chunks_of(known, x, row0, nx, &mut own);
                if starts.is_empty() {
                    continue;
                }
                let (base, step) = fv.cam.row_start(&self.gf, j, k, [0.0; 3]);
                let across = rs.first as usize;
                let mvs = &mut mvs[..starts.len()];
                fv.row_moving::<N, SHARED_V>(rs, base, step, n_l, starts, &mut scratch, mvs);
                // The stretch of the line the row's voxels add to: lane-wise least and greatest
                // first pixel of the voxels that add something.
                let (mut lo, mut hi) = ([u32::MAX; CHUNK], [0u32; CHUNK]);
                let acc_at = acc.as_mut_ptr();
                for (&i0, mv) in starts.iter().zip(mvs.iter()) {
                    let valid = CHUNK.min(nx - i0);
                    // Each voxel's products and place in its line, vectorised across the chunk;
                    // misses and empty voxels get a zero value and are skipped.
                    let gq = chunk_values(x, row0 + i0, valid);
                    let (mut values, mut at) = ([0f32; CHUNK], [0u32; CHUNK]);
                    for q in 0..CHUNK {
                        // Selects written as masks and minima, which vectorise without branches.
                        let keep = u32::from(mv.first[q] >= 0.0).wrapping_neg();
                        let v = f32::from_bits((gq[q] * mv.amp[q]).to_bits() & keep);
                        values[q] = v;
                        // SAFETY: a whole number in [0, line_len) (`chunk_moving`), or 0.
                        let first = unsafe { fmax(mv.first[q], 0.0).to_int_unchecked::<u32>() };
                        let adds = u32::from(v != 0.0).wrapping_neg();
                        lo[q] = lo[q].min(first | !adds);
                        hi[q] = hi[q].max(first & adds);
                        at[q] = (q % SCATTER_IMAGES) as u32 * stride as u32 + first;
                    }
                    // SAFETY: a hit has `first + n_l ≤ line_len` (`chunk_moving`: first < len +
                    // N, n_l ≤ N), each line has N values of slack, and weights past `n_l` are
                    // zero; lanes past the row's end have a zero value.
                    unsafe { add_to_lines::<N>(acc_at, &at, &values, &mv.w) };
                }
                let (lo, hi) = (lo.into_iter().min().unwrap_or(u32::MAX), hi.into_iter().max().unwrap_or(0));
                let (lo, hi) = (lo as usize, hi as usize);
                if lo > hi {
                    continue;
                }
                // The lines summed and cleared, and their sum added under the shared footprint
                // (lines past its last non-zero weight add nothing), sixteen pixels at a time.
                let n_s = (0..n_s.min(N)).rev().find(|&s| rs.w[s] != 0.0).map_or(1, |s| s + 1);
                let img_at = img.as_mut_ptr();
                for c in (lo..hi + N).step_by(CHUNK) {
                    // SAFETY: `c + CHUNK ≤ line_len + N + CHUNK` = the summed lines' stride, so
                    // the four windows lie inside `acc` and apart. The image window starts
                    // inside line `across + s < pw · ph / line_len` and may run past its end by
                    // `N + CHUNK` values, into the next line or the next image, whose values
                    // it leaves as they are: the summed line is zero past `line_len` (weights
                    // past a voxel's `n_l` are zero and `first + n_l ≤ line_len`).
                    unsafe {
                        let window = |i: usize| &mut *acc_at.add(i * stride + c).cast::<[f32; CHUNK]>();
                        let (l0, l1, l2, l3) = (window(0), window(1), window(2), window(3));
                        let mut v = [0f32; CHUNK];
                        for i in 0..CHUNK {
                            v[i] = (l0[i] + l1[i]) + (l2[i] + l3[i]);
                        }
                        (*l0, *l1, *l2, *l3) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
                        for s in 0..n_s {
                            let w = rs.w[s];
                            let d = &mut *img_at.add((across + s) * line_len + c).cast::<[f32; CHUNK]>();
                            for i in 0..CHUNK {
                                d[i] += w * v[i];
                            }
                        }
                    }
                }
            }
        }
        if !SHARED_V {
            // The columns accumulated as lines: added to the second image in place.
            let (t, rest) = img.split_at_mut(pw * ph);
            for (r, row) in rest[..pw * ph].chunks_exact_mut(pw).enumerate() {
                for (c, o) in row.iter_mut().enumerate() {
                    *o += t[c * ph + r];
                }
            }
            t.fill(0.0);
        }
    }

    /// Back kernel for views whose grid rows share a footprint axis ([`Shared`]): every voxel
    /// of a grid row has the same first pixel and weights along the shared axis, so the
    /// footprint is separable across the whole row. The `n_s` image lines of the row's shared
    /// footprint are first summed with its weights into one line (as whole vectors, over the
    /// stretch the row's voxels read), and each voxel then weighs that line with its `n_l`
    /// weights along the other axis: `n_s + n_l` products per voxel instead of `n_s · n_l`.
    /// `lines` is the padded image laid out as lines: as it is when rows image horizontal
    /// (`SHARED_V`), transposed (column after column) when vertical; `masks` the padded column
    /// and row masks, each followed by 32 zeros. The same arithmetic in the same order
    /// whatever the instruction set, so the result is the same bit for bit.
    #[inline(always)]
    fn gather_rows<const N: usize, const SHARED_V: bool>(
        &self,
        view: usize,
        ks: Range<usize>,
        lines: &[f32],
        masks: (&[f32], &[f32]),
        out: &mut [f32],
        mut col_sums: Option<&mut [f32]>,
    ) {
        let fv = &self.views[view];
        let (pw, ph) = fv.padded();
        let (line_len, n_l, n_s) = if SHARED_V { (pw, fv.cols, fv.rows) } else { (ph, fv.rows, fv.cols) };
        let (m_along, m_across) = if SHARED_V { masks } else { (masks.1, masks.0) };
        let [nx, ny, _] = self.grid.dims;
        // 32 more, for the vector kernel's window.
        let mut acc = vec![0f32; line_len + 32];
        let mut mvs = vec![Moving::<N>::default(); nx.div_ceil(CHUNK)];
        let starts: Vec<usize> = (0..nx).step_by(CHUNK).collect();
        let mut scratch = vec![MovingTrapezoids::default(); mvs.len()];
        let mut rss = vec![RowShared::<N>::default(); ny];
        let nc = nx.div_ceil(CHUNK);
        let stride = 2 + n_l;
        for (kk, k) in ks.enumerate() {
            self.slice_rows_shared::<N, SHARED_V>(view, k, &mut rss);
            let kept = self
                .kept
                .as_ref()
                .and_then(|kf| kf.views[view].as_ref())
                .map(|slices| slices[k].get_or_init(|| self.keep_slice::<N, SHARED_V>(view, k, &rss, n_l)));
            for (j, rs) in rss.iter().enumerate() {
                let (base, step) = fv.cam.row_start(&self.gf, j, k, [0.0; 3]);
                if rs.first < 0.0 {
                    continue;
                }
                let across = rs.first as usize;
                // The mask under the shared footprint, for the column sums only.
                let mut m_s = 0f32;
                if col_sums.is_some() {
                    for s in 0..n_s {
                        m_s += rs.w[s] * m_across[across + s];
                    }
                }
                // Every chunk's footprints, and the stretch of the line they read (lane-wise
                // minimum and maximum first pixel of the hits; misses are −1).
                let row_kept = kept.map(|ks| ks.row(j, nc * stride));
                if kept.is_none() {
                    fv.row_moving::<N, SHARED_V>(rs, base, step, n_l, &starts, &mut scratch, &mut mvs);
                    if nx % CHUNK != 0 {
                        // The short last chunk: lanes past the row are not voxels.
                        mvs[nx / CHUNK].first[nx % CHUNK..].fill(-1.0);
                    }
                }
                let foot = |c: usize| match row_kept {
                    Some(row) => kept_chunk(row, c, stride),
                    None => mvs[c].foot(),
                };
                let (lo, hi) = match kept {
                    Some(ks) => ks.ranges[j],
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX-512F is available (`isa`).
                    None if self.isa == Isa::Avx512 => unsafe { first_range16(mvs.iter().map(|mv| &mv.first)) },
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 is available (`isa`).
                    None if self.isa == Isa::Avx2 => unsafe { first_range8(mvs.iter().map(|mv| &mv.first)) },
                    None => first_range(mvs.iter().map(|mv| &mv.first)),
                };
                if hi < 0.0 {
                    continue;
                }
                // The shared footprint's lines summed over [lo, hi + n_l): every hit has
                // `first + n_l ≤ line_len` (see `chunk_moving`: first < len + N, n_l ≤ N).
                // Lines past the footprint's last non-zero weight add nothing.
                let (lo, hi) = (lo as usize, hi as usize + n_l);
                let n_s = (0..n_s.min(N)).rev().find(|&s| rs.w[s] != 0.0).map_or(1, |s| s + 1);
                let (lines_at, acc_at) = (lines.as_ptr(), acc.as_mut_ptr());
                for c in (lo..hi).step_by(CHUNK) {
                    // SAFETY: `c < hi ≤ line_len`, so the window lies inside `acc` (32 values of
                    // slack) and the image windows inside `lines`, which holds CHUNK values past
                    // its last line. A window running past its line's end reads the next line
                    // into `acc` past `hi`, where no voxel reads with a non-zero weight.
                    unsafe {
                        let line = |s: usize| &*lines_at.add((across + s) * line_len + c).cast::<[f32; CHUNK]>();
                        let mut v = [0f32; CHUNK];
                        let l0 = line(0);
                        for i in 0..CHUNK {
                            v[i] = rs.w[0] * l0[i];
                        }
                        for s in 1..n_s {
                            let (w, ls) = (rs.w[s], line(s));
                            for i in 0..CHUNK {
                                v[i] += w * ls[i];
                            }
                        }
                        *acc_at.add(c).cast::<[f32; CHUNK]>() = v;
                    }
                }
                let row0 = (kk * ny + j) * nx;
                for c in 0..nc {
                    let mv = foot(c);
                    let at = (row0 + c * CHUNK, CHUNK.min(nx - c * CHUNK));
                    #[cfg(target_arch = "x86_64")]
                    {
                        let line = SummedLine { acc: &acc, m_along, m_s, n_l };
                        match self.isa {
                            // SAFETY: AVX-512F is available (`isa`); `acc` and the masks hold
                            // 32 values past their padded extent, and `at` lies inside `out`
                            // and `col_sums`.
                            Isa::Avx512 => {
                                if unsafe {
                                    Self::weigh_rows16::<SHARED_V>(mv, &line, at, out, col_sums.as_deref_mut())
                                } {
                                    continue;
                                }
                            }
                            // SAFETY: AVX2 is available (`isa`); every hit's pixels lie inside
                            // `acc` and the mask, and `at` inside `out` and `col_sums`.
                            Isa::Avx2 => {
                                unsafe { Self::weigh_rows8::<SHARED_V>(mv, &line, at, out, col_sums.as_deref_mut()) };
                                continue;
                            }
                            Isa::Baseline => {}
                        }
                    }
                    for q in 0..at.1 {
                        if mv.first[q] < 0.0 {
                            continue;
                        }
                        let first = mv.first[q] as usize;
                        let mut sum = 0f32;
                        for l in 0..n_l {
                            sum += mv.w[l][q] * acc[first + l];
                        }
                        let idx = at.0 + q;
                        let amp = mv.amp[q];
                        out[idx] += amp * sum;
                        if let Some(cs) = col_sums.as_deref_mut() {
                            let mut m_l = 0f32;
                            for l in 0..n_l {
                                m_l += mv.w[l][q] * m_along[first + l];
                            }
                            let (su, sv) = if SHARED_V { (m_l, m_s) } else { (m_s, m_l) };
                            cs[idx] += amp * su * sv;
                        }
                    }
                }
            }
        }
    }

    /// The per-voxel part of [`Self::gather_rows`] for one chunk, sixteen voxels at a time when
    /// they read within 32 pixels of each other (else it returns `false` and does nothing):
    /// each weight's pixels come from the summed line by one permutation. The arithmetic and
    /// its order are the scalar loop's.
    ///
    /// # Safety
    /// The CPU must support AVX-512F; `acc` and `m_along` hold 32 values past any voxel's
    /// first pixel, and `at.0 + at.1` lies inside `out` (and `col_sums`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    #[inline]
    unsafe fn weigh_rows16<const SHARED_V: bool>(
        mv: ChunkFoot<'_>,
        &SummedLine { acc, m_along, m_s, n_l }: &SummedLine<'_>,
        (first, valid): (usize, usize),
        out: &mut [f32],
        col_sums: Option<&mut [f32]>,
    ) -> bool {
        use std::arch::x86_64::*;
        const { assert!(CHUNK == 16) };
        // SAFETY: the chunk's arrays hold 16 entries; the window [lo, lo + 32) is checked
        // against both buffers; the masked loads and stores touch `valid` entries from `first`.
        unsafe {
            let f = _mm512_loadu_ps(mv.first.as_ptr());
            let keep = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(f, _mm512_setzero_ps()) & ((1u32 << valid) - 1) as u16;
            if keep == 0 {
                return true;
            }
            let fi = _mm512_cvttps_epi32(f);
            // The window starts at the hits' least first pixel. Along a row the footprints
            // move one way, so when both ends of the chunk hit, the lesser of their first
            // pixels is it (checked against every lane; a reduction otherwise).
            let mut lo = if keep == u16::MAX {
                let last = _mm_extract_epi32::<3>(_mm512_extracti32x4_epi32::<3>(fi));
                _mm512_cvtsi512_si32(fi).min(last)
            } else {
                _mm512_mask_reduce_min_epi32(keep, fi)
            };
            if _mm512_mask_cmplt_epi32_mask(keep, fi, _mm512_set1_epi32(lo)) != 0 {
                lo = _mm512_mask_reduce_min_epi32(keep, fi);
            }
            let off = _mm512_maskz_sub_epi32(keep, fi, _mm512_set1_epi32(lo));
            let lo = lo as usize;
            if _mm512_mask_cmpgt_epi32_mask(keep, off, _mm512_set1_epi32(32 - n_l as i32)) != 0
                || lo + 32 > acc.len().min(m_along.len())
            {
                return false;
            }
            let pick = |p: *const f32, l: usize| {
                let idx = _mm512_add_epi32(off, _mm512_set1_epi32(l as i32));
                _mm512_permutex2var_ps(_mm512_loadu_ps(p), idx, _mm512_loadu_ps(p.add(16)))
            };
            let a = acc.as_ptr().add(lo);
            let mut sum = _mm512_setzero_ps();
            for (l, w) in mv.w[..n_l].iter().enumerate() {
                sum = _mm512_add_ps(sum, _mm512_mul_ps(_mm512_loadu_ps(w.as_ptr()), pick(a, l)));
            }
            let amp = _mm512_loadu_ps(mv.amp.as_ptr());
            let dst = out[first..][..valid].as_mut_ptr();
            let prev = _mm512_mask_loadu_ps(_mm512_setzero_ps(), keep, dst);
            _mm512_mask_storeu_ps(dst, keep, _mm512_add_ps(prev, _mm512_mul_ps(amp, sum)));
            if let Some(cs) = col_sums {
                let m = m_along.as_ptr().add(lo);
                let mut m_l = _mm512_setzero_ps();
                for (l, w) in mv.w[..n_l].iter().enumerate() {
                    m_l = _mm512_add_ps(m_l, _mm512_mul_ps(_mm512_loadu_ps(w.as_ptr()), pick(m, l)));
                }
                let m_s = _mm512_set1_ps(m_s);
                let (su, sv) = if SHARED_V { (m_l, m_s) } else { (m_s, m_l) };
                let dst = cs[first..][..valid].as_mut_ptr();
                let prev = _mm512_mask_loadu_ps(_mm512_setzero_ps(), keep, dst);
                _mm512_mask_storeu_ps(dst, keep, _mm512_add_ps(prev, _mm512_mul_ps(_mm512_mul_ps(amp, su), sv)));
            }
            true
        }
    }

    /// The per-voxel part of [`Self::gather_rows`] for one chunk with AVX2, eight voxels at a
    /// time. When the eight read within a window of 8 (or 16) pixels, as they do wherever a
    /// voxel images at a pixel or two, each weight's pixels come from the summed line by one
    /// (or two) permutations of a window that moves with the weight; else they are gathered.
    /// Full halves of a chunk are read and written with plain loads and stores (the lanes that
    /// miss written back as they were), since masked stores are slow on AMD's cores. The
    /// arithmetic and its order are the scalar loop's.
    ///
    /// # Safety
    /// The CPU must support AVX2; every hit's first pixel plus `n_l` lies inside `acc` and
    /// `m_along`, and `at.0 + at.1` inside `out` (and `col_sums`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn weigh_rows8<const SHARED_V: bool>(
        mv: ChunkFoot<'_>,
        &SummedLine { acc, m_along, m_s, n_l }: &SummedLine<'_>,
        (first, valid): (usize, usize),
        out: &mut [f32],
        mut col_sums: Option<&mut [f32]>,
    ) {
        use std::arch::x86_64::*;
        const { assert!(CHUNK == 16) };
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let len = acc.len().min(m_along.len());
        for h in 0..2 {
            let q0 = 8 * h;
            if q0 >= valid {
                break;
            }
            // SAFETY: the chunk's arrays hold 16 entries; windows are read only when they lie
            // inside both buffers (checked), gathers only at the lanes that hit (whose pixels
            // lie inside the buffers), and the stores only the `valid` entries from `first`.
            unsafe {
                let f = _mm256_loadu_ps(mv.first.as_ptr().add(q0));
                let inside = _mm256_cmpgt_epi32(_mm256_set1_epi32((valid - q0) as i32), lane);
                let keep =
                    _mm256_and_si256(_mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(f, _mm256_setzero_ps())), inside);
                if _mm256_testz_si256(keep, keep) != 0 {
                    continue;
                }
                let fi = _mm256_and_si256(_mm256_cvttps_epi32(f), keep);
                let keep_ps = _mm256_castsi256_ps(keep);
                // The least first pixel of the hits, and each hit's offset from it.
                let m = _mm256_blendv_epi8(_mm256_set1_epi32(i32::MAX), fi, keep);
                let m = _mm256_min_epi32(m, _mm256_permute2x128_si256::<1>(m, m));
                let m = _mm256_min_epi32(m, _mm256_shuffle_epi32::<0b0100_1110>(m));
                let m = _mm256_min_epi32(m, _mm256_shuffle_epi32::<0b1011_0001>(m));
                let lo = _mm256_cvtsi256_si32(m) as usize;
                let off = _mm256_and_si256(_mm256_sub_epi32(fi, _mm256_set1_epi32(lo as i32)), keep);
                let past = |w: i32| _mm256_testz_si256(_mm256_cmpgt_epi32(off, _mm256_set1_epi32(w)), keep) == 0;
                let window = if past(7) || lo + n_l + 8 > len {
                    if past(15) || lo + n_l + 16 > len {
                        0
                    } else {
                        16
                    }
                } else {
                    8
                };
                let upper = _mm256_castsi256_ps(_mm256_cmpgt_epi32(off, _mm256_set1_epi32(7)));
                let dot = |p: *const f32| {
                    let mut sum = _mm256_setzero_ps();
                    let ws = mv.w[..n_l].iter().enumerate();
                    match window {
                        8 => {
                            for (l, w) in ws {
                                let g = _mm256_permutevar8x32_ps(_mm256_loadu_ps(p.add(lo + l)), off);
                                sum = _mm256_add_ps(sum, _mm256_mul_ps(_mm256_loadu_ps(w.as_ptr().add(q0)), g));
                            }
                        }
                        16 => {
                            for (l, w) in ws {
                                let a = _mm256_permutevar8x32_ps(_mm256_loadu_ps(p.add(lo + l)), off);
                                let b = _mm256_permutevar8x32_ps(_mm256_loadu_ps(p.add(lo + l + 8)), off);
                                let g = _mm256_blendv_ps(a, b, upper);
                                sum = _mm256_add_ps(sum, _mm256_mul_ps(_mm256_loadu_ps(w.as_ptr().add(q0)), g));
                            }
                        }
                        _ => {
                            for (l, w) in ws {
                                let idx = _mm256_add_epi32(fi, _mm256_set1_epi32(l as i32));
                                let g = _mm256_mask_i32gather_ps::<4>(_mm256_setzero_ps(), p, idx, keep_ps);
                                sum = _mm256_add_ps(sum, _mm256_mul_ps(_mm256_loadu_ps(w.as_ptr().add(q0)), g));
                            }
                        }
                    }
                    sum
                };
                // Adds `v` to the hits' entries of `dst` (eight from `first + q0`).
                let add_to = |dst: *mut f32, v: __m256| add_kept8(dst, v, keep, valid - q0 >= 8);
                let amp = _mm256_loadu_ps(mv.amp.as_ptr().add(q0));
                add_to(out.as_mut_ptr().add(first + q0), _mm256_mul_ps(amp, dot(acc.as_ptr())));
                if let Some(cs) = col_sums.as_deref_mut() {
                    let m_l = dot(m_along.as_ptr());
                    let m_s = _mm256_set1_ps(m_s);
                    let (su, sv) = if SHARED_V { (m_l, m_s) } else { (m_s, m_l) };
                    add_to(cs.as_mut_ptr().add(first + q0), _mm256_mul_ps(_mm256_mul_ps(amp, su), sv));
                }
            }
        }
    }

    /// The rows of `A_v` (see [`Projector::rows`]), built in parallel: each thread takes a
    /// contiguous range of z-slices, counts its entries per pixel, and after the counts are
    /// laid out (pixel by pixel, the threads' ranges in slice order) writes them into its own
    /// slots. The entries of a row come in voxel order, as one pass over the grid would give.
    fn rows_impl<const N: usize, const DISTORTED: bool>(&self, view: usize) -> SparseRows {
        let fv = &self.views[view];
        let pixels = fv.cam.width * fv.cam.height;
        let nz = self.grid.dims[2];
        let parts = rayon::current_num_threads().clamp(1, nz.max(1));
        let ranges: Vec<Range<usize>> = (0..parts).map(|t| t * nz / parts..(t + 1) * nz / parts).collect();
        let counts: Vec<Vec<u32>> = ranges
            .par_iter()
            .map(|ks| {
                let mut c = vec![0u32; pixels];
                kernels::rows_count::<N, DISTORTED>(self, view, ks.clone(), &mut c);
                c
            })
            .collect();
        // Row `pix` holds part 0's entries, then part 1's, …: `next[t][pix]` is part t's first.
        let mut ptr = vec![0u64; pixels + 1];
        let mut next = vec![vec![0u64; pixels]; parts];
        let mut at = 0u64;
        for pix in 0..pixels {
            ptr[pix] = at;
            for (t, c) in counts.iter().enumerate() {
                next[t][pix] = at;
                at += c[pix] as u64;
            }
        }
        ptr[pixels] = at;
        drop(counts);
        let nnz = at as usize;
        let mut cols = vec![0u32; nnz];
        let mut vals = vec![0f32; nnz];
        let slots = Slots { cols: cols.as_mut_ptr(), vals: vals.as_mut_ptr(), len: nnz };
        ranges.par_iter().zip(next.par_iter_mut()).for_each(|(ks, next)| {
            // SAFETY: part t writes only the slots from `next[t][pix]` on, as many as it
            // counted for `pix`, which no other part's slots overlap, all below `nnz`; the
            // pass visits the same entries as the count did (the same code on the same view).
            unsafe { kernels::rows_fill::<N, DISTORTED>(self, view, ks.clone(), next, slots) };
        });
        SparseRows { ptr, cols, vals }
    }

    /// Hands every entry of the rows of `A_v` that the voxels of slices `ks` give to
    /// `emit(pixel, voxel, weight)`: every in-image footprint pixel with a positive weight, in
    /// voxel order.
    #[inline(always)]
    fn rows_part<const N: usize, const DISTORTED: bool>(
        &self,
        view: usize,
        ks: Range<usize>,
        mut emit: impl FnMut(usize, u32, f32),
    ) {
        let fv = &self.views[view];
        let (w, h) = (fv.cam.width, fv.cam.height);
        let [nx, ny, _] = self.grid.dims;
        let first_voxel = ks.start * nx * ny;
        self.for_each_chunk::<N, DISTORTED, false>(view, ks, |ch, first, valid| {
            for q in 0..valid {
                let Some((col, row, amp)) = ch.get(q) else { continue };
                let (wu, wv) = ch.weights(q);
                let voxel = (first_voxel + first + q) as u32;
                for (r, &wr) in wv[..fv.rows].iter().enumerate() {
                    let Some(pr) = (row + r).checked_sub(N).filter(|&pr| pr < h) else { continue };
                    for (c, &wc) in wu.iter().enumerate() {
                        let wgt = amp * wr * wc;
                        if let Some(pc) = (col + c).checked_sub(N).filter(|&pc| pc < w && wgt > 0.0) {
                            emit(pr * w + pc, voxel, wgt);
                        }
                    }
                }
            }
        });
    }
}

/// Where [`FootprintProjector::rows_impl`]'s threads write their entries.
#[derive(Clone, Copy)]
struct Slots {
    cols: *mut u32,
    vals: *mut f32,
    len: usize,
}

// SAFETY: the threads that share `Slots` write disjoint slots (see `rows_impl`).
unsafe impl Send for Slots {}
// SAFETY: as above.
unsafe impl Sync for Slots {}

/// Runs `$body` with `N` bound to the view's footprint side and `D` to its distortion flag,
/// one monomorphised kernel per side (the kernels choose baseline or AVX2 code themselves).
macro_rules! dispatch {
    ($side:expr, $distorted:expr, |$n:ident, $d:ident| $call:expr) => {
        match ($side, $distorted) {
            (2, false) => {
                const $n: usize = 2;
                const $d: bool = false;
                $call
            }
            (4, false) => {
                const $n: usize = 4;
                const $d: bool = false;
                $call
            }
            (8, false) => {
                const $n: usize = 8;
                const $d: bool = false;
                $call
            }
            (16, false) => {
                const $n: usize = 16;
                const $d: bool = false;
                $call
            }
            (32, false) => {
                const $n: usize = 32;
                const $d: bool = false;
                $call
            }
            (_, false) => {
                const $n: usize = 64;
                const $d: bool = false;
                $call
            }
            (2, true) => {
                const $n: usize = 2;
                const $d: bool = true;
                $call
            }
            (4, true) => {
                const $n: usize = 4;
                const $d: bool = true;
                $call
            }
            (8, true) => {
                const $n: usize = 8;
                const $d: bool = true;
                $call
            }
            (16, true) => {
                const $n: usize = 16;
                const $d: bool = true;
                $call
            }
            (32, true) => {
                const $n: usize = 32;
                const $d: bool = true;
                $call
            }
            (_, true) => {
                const $n: usize = 64;
                const $d: bool = true;
                $call
            }
        }
    };
}

/// Largest footprint side for which the AVX2 kernels keep the weights pixel-major, as the
/// footprints are computed: back projection reads eight voxels per gather
/// ([`FootprintProjector::gather_lanes`]) and forward projection reads each voxel's weights from
/// the lanes, saving the transposition. Wider footprints read each voxel's rows as vectors of
/// their own, which is cheaper than gathers.
const LANE_GATHER_MAX_SIDE: usize = 4;

/// The two kernels behind the runtime CPU dispatch: the same code compiled for the baseline,
/// for AVX2 and for AVX-512 (wider vectors, identical results: no fused multiply–adds are
/// formed). AVX-512 evaluates a whole chunk of sixteen footprints per instruction.
mod kernels {
    use super::*;

    /// Defines `avx512::<N, D>` and `avx2::<N, D>`: `$body` compiled for each instruction set.
    macro_rules! variants {
        (fn($($arg:ident: $ty:ty),* $(,)?) $body:block) => {
            #[target_feature(enable = "avx512f,avx2")]
            unsafe fn avx512<const N: usize, const D: bool>($($arg: $ty),*) $body
            #[target_feature(enable = "avx2")]
            unsafe fn avx2<const N: usize, const D: bool>($($arg: $ty),*) $body
        };
    }

    pub(super) fn scatter<const N: usize, const D: bool>(
        p: &FootprintProjector,
        view: usize,
        ks: Slices,
        x: &[f32],
        known: Option<&NonEmptyChunks>,
        img: &mut [f32],
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            variants!(fn(
                p: &FootprintProjector,
                view: usize,
                ks: Slices,
                x: &[f32],
                known: Option<&NonEmptyChunks>,
                img: &mut [f32],
            ) {
                let shared = p.views[view].shared;
                if shared == Shared::V && !D {
                    p.scatter_shared::<N, true>(view, ks, x, known, img)
                } else if shared == Shared::U && !D {
                    p.scatter_shared::<N, false>(view, ks, x, known, img)
                } else if N <= LANE_GATHER_MAX_SIDE && img.len() / SCATTER_IMAGES < u32::MAX as usize {
                    p.scatter::<N, D, true>(view, ks, x, known, img)
                } else {
                    p.scatter::<N, D, false>(view, ks, x, known, img)
                }
            });
            match p.isa {
                // SAFETY: `p.isa` never exceeds what `Isa::detected` found on this CPU.
                Isa::Avx512 => return unsafe { avx512::<N, D>(p, view, ks, x, known, img) },
                // SAFETY: as above.
                Isa::Avx2 => return unsafe { avx2::<N, D>(p, view, ks, x, known, img) },
                Isa::Baseline => {}
            }
        }
        match p.views[view].shared {
            Shared::V if !D => p.scatter_shared::<N, true>(view, ks, x, known, img),
            Shared::U if !D => p.scatter_shared::<N, false>(view, ks, x, known, img),
            _ => p.scatter::<N, D, false>(view, ks, x, known, img),
        }
    }

    /// [`FootprintProjector::gather_rows`], rows horizontal with `V`.
    pub(super) fn gather_rows<const N: usize, const V: bool>(
        p: &FootprintProjector,
        view: usize,
        ks: Range<usize>,
        lines: &[f32],
        masks: (&[f32], &[f32]),
        out: &mut [f32],
        col_sums: Option<&mut [f32]>,
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            variants!(fn(
                p: &FootprintProjector,
                view: usize,
                ks: Range<usize>,
                lines: &[f32],
                masks: (&[f32], &[f32]),
                out: &mut [f32],
                col_sums: Option<&mut [f32]>,
            ) {
                p.gather_rows::<N, D>(view, ks, lines, masks, out, col_sums)
            });
            match p.isa {
                // SAFETY: `p.isa` never exceeds what `Isa::detected` found on this CPU.
                Isa::Avx512 => return unsafe { avx512::<N, V>(p, view, ks, lines, masks, out, col_sums) },
                // SAFETY: as above.
                Isa::Avx2 => return unsafe { avx2::<N, V>(p, view, ks, lines, masks, out, col_sums) },
                Isa::Baseline => {}
            }
        }
        p.gather_rows::<N, V>(view, ks, lines, masks, out, col_sums)
    }

    /// Counts, per pixel, the entries of the rows of `A_v` that slices `ks` give
    /// ([`FootprintProjector::rows_part`]).
    pub(super) fn rows_count<const N: usize, const D: bool>(
        p: &FootprintProjector,
        view: usize,
        ks: Range<usize>,
        counts: &mut [u32],
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            variants!(fn(p: &FootprintProjector, view: usize, ks: Range<usize>, counts: &mut [u32]) {
                p.rows_part::<N, D>(view, ks, |pix, _, _| counts[pix] += 1)
            });
            match p.isa {
                // SAFETY: `p.isa` never exceeds what `Isa::detected` found on this CPU.
                Isa::Avx512 => return unsafe { avx512::<N, D>(p, view, ks, counts) },
                // SAFETY: as above.
                Isa::Avx2 => return unsafe { avx2::<N, D>(p, view, ks, counts) },
                Isa::Baseline => {}
            }
        }
        p.rows_part::<N, D>(view, ks, |pix, _, _| counts[pix] += 1)
    }

    /// Writes the entries that slices `ks` give into `slots`, each pixel's from `next[pixel]`
    /// on (advanced past them).
    ///
    /// # Safety
    /// The slots from `next[pixel]`, as many as slices `ks` give entries to `pixel`
    /// ([`rows_count`]), lie below `slots.len` and no other thread writes them.
    pub(super) unsafe fn rows_fill<const N: usize, const D: bool>(
        p: &FootprintProjector,
        view: usize,
        ks: Range<usize>,
        next: &mut [u64],
        slots: Slots,
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            variants!(fn(p: &FootprintProjector, view: usize, ks: Range<usize>, next: &mut [u64], slots: Slots) {
                // SAFETY: the caller's contract.
                unsafe { fill::<N, D>(p, view, ks, next, slots) }
            });
            match p.isa {
                // SAFETY: `p.isa` never exceeds what `Isa::detected` found on this CPU; the
                // slots as the caller's contract.
                Isa::Avx512 => return unsafe { avx512::<N, D>(p, view, ks, next, slots) },
                // SAFETY: as above.
                Isa::Avx2 => return unsafe { avx2::<N, D>(p, view, ks, next, slots) },
                Isa::Baseline => {}
            }
        }
        // SAFETY: the caller's contract.
        unsafe { fill::<N, D>(p, view, ks, next, slots) }
    }

    /// The body of [`rows_fill`].
    ///
    /// # Safety
    /// As [`rows_fill`].
    #[inline(always)]
    unsafe fn fill<const N: usize, const D: bool>(
        p: &FootprintProjector,
        view: usize,
        ks: Range<usize>,
        next: &mut [u64],
        slots: Slots,
    ) {
        p.rows_part::<N, D>(view, ks, |pix, voxel, wgt| {
            let at = next[pix] as usize;
            debug_assert!(at < slots.len);
            // SAFETY: `at` is one of this thread's slots (the caller's contract).
            unsafe {
                *slots.cols.add(at) = voxel;
                *slots.vals.add(at) = wgt;
            }
            next[pix] += 1;
        })
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn gather<const N: usize, const D: bool>(
        p: &FootprintProjector,
        view: usize,
        ks: Range<usize>,
        y: &[f32],
        masks: (&[f32], &[f32]),
        out: &mut [f32],
        col_sums: Option<&mut [f32]>,
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            variants!(fn(
                p: &FootprintProjector,
                view: usize,
                ks: Range<usize>,
                y: &[f32],
                masks: (&[f32], &[f32]),
                out: &mut [f32],
                col_sums: Option<&mut [f32]>,
            ) {
                p.gather::<N, D>(view, ks, y, masks, out, col_sums)
            });
            let lanes = N <= LANE_GATHER_MAX_SIDE && y.len() < i32::MAX as usize;
            // SAFETY (all four calls): `p.isa` never exceeds what `Isa::detected` found on this
            // CPU, and the lane kernels get images of fewer than 2³¹ pixels.
            match (p.isa, lanes) {
                (Isa::Avx512, true) => return unsafe { p.gather_lanes16::<N, D>(view, ks, y, masks, out, col_sums) },
                (Isa::Avx512, false) => return unsafe { avx512::<N, D>(p, view, ks, y, masks, out, col_sums) },
                (Isa::Avx2, true) => return unsafe { p.gather_lanes::<N, D>(view, ks, y, masks, out, col_sums) },
                (Isa::Avx2, false) => return unsafe { avx2::<N, D>(p, view, ks, y, masks, out, col_sums) },
                (Isa::Baseline, _) => {}
            }
        }
        p.gather::<N, D>(view, ks, y, masks, out, col_sums)
    }
}

/// A grid row's summed image line and what the per-voxel weighing of
/// [`FootprintProjector::gather_rows`] reads with it: the line `acc`, the image mask along it
/// `m_along` and across it summed under the shared footprint `m_s`, and the moving footprint's
/// pixel count `n_l`.
#[cfg(target_arch = "x86_64")]
struct SummedLine<'a> {
    acc: &'a [f32],
    m_along: &'a [f32],
    m_s: f32,
    n_l: usize,
}

/// A view's image as the back projection reads it ([`FootprintProjector::back_image`]).
struct BackImage {
    /// The image with a margin of the footprint side on every side, transposed when the
    /// view's grid rows image as columns, and followed by [`CHUNK`] zeros for the shared-row
    /// kernel's vector reads.
    padded: Vec<f32>,
    /// 1 on the image's columns and rows, 0 on the margins, with 32 trailing zeros for the
    /// shared-row kernel's vector window.
    col_mask: Vec<f32>,
    row_mask: Vec<f32>,
}

impl FootprintProjector {
    /// The z-slices of a back projection's task: enough tasks to balance the threads, few
    /// enough to keep the overhead small and a slab in cache.
    fn slices_per_task(&self) -> usize {
        self.grid.dims[2].div_ceil(8 * scatter_parts()).max(1)
    }

    /// View `view`'s image `y` padded (and transposed) for [`Self::back_slab`].
    fn back_image(&self, view: usize, y: &[f32]) -> BackImage {
        let fv = &self.views[view];
        let (pw, ph) = fv.padded();
        let (w, h, n) = (fv.cam.width, fv.cam.height, fv.side);
        let mut padded = vec![0f32; pw * ph + CHUNK];
        for (r, row) in y.chunks_exact(w).enumerate() {
            padded[(r + n) * pw + n..][..w].copy_from_slice(row);
        }
        let col_mask: Vec<f32> = (0..pw + 32).map(|c| if (n..n + w).contains(&c) { 1.0 } else { 0.0 }).collect();
        let row_mask: Vec<f32> = (0..ph + 32).map(|r| if (n..n + h).contains(&r) { 1.0 } else { 0.0 }).collect();
        // Rows that share a footprint axis read along image lines: rows (the padded image as it
        // is) when they image horizontal, columns (the image transposed) when vertical.
        if fv.shared == Shared::U {
            let mut t = vec![0f32; pw * ph + CHUNK];
            for (r, row) in padded[..pw * ph].chunks_exact(pw).enumerate() {
                for (c, &v) in row.iter().enumerate() {
                    t[c * ph + r] = v;
                }
            }
            padded = t;
        }
        BackImage { padded, col_mask, row_mask }
    }

    /// Adds view `view`'s back projection of `im` to the z-slices `ks` (`o`, and `c` the
    /// column sums, hold those slices).
    fn back_slab(&self, view: usize, im: &BackImage, ks: Range<usize>, o: &mut [f32], c: Option<&mut [f32]>) {
        let fv = &self.views[view];
        let (pw, ph) = fv.padded();
        let padded = &im.padded[..];
        let rows_masks = (&im.col_mask[..], &im.row_mask[..]);
        let masks = (&im.col_mask[..pw], &im.row_mask[..ph]);
        match fv.shared {
            Shared::V => dispatch!(fv.side, false, |N, _D| kernels::gather_rows::<N, true>(
                self, view, ks, padded, rows_masks, o, c
            )),
            Shared::U => dispatch!(fv.side, false, |N, _D| kernels::gather_rows::<N, false>(
                self, view, ks, padded, rows_masks, o, c
            )),
            Shared::None => {
                dispatch!(fv.side, fv.cam.distorted, |N, D| kernels::gather::<N, D>(
                    self,
                    view,
                    ks,
                    &padded[..pw * ph],
                    masks,
                    o,
                    c
                ))
            }
        }
    }
}

impl FootprintProjector {
    /// [`Projector::forward`], with the volume's non-empty chunks found beforehand or not; with
    /// `serial` on the calling thread alone (the caller runs views in parallel), else split
    /// over the threads by z-slices.
    fn forward_known(&self, view: usize, x: &[f32], known: Option<&NonEmptyChunks>, out: &mut [f32], serial: bool) {
        let fv = &self.views[view];
        let (pw, ph) = fv.padded();
        let (w, n) = (fv.cam.width, fv.side);
        let nz = self.grid.dims[2];
        // Interleaved slices, so that the threads share the work evenly when it is uneven
        // (chunks of empty voxels are skipped, and a flow fills part of the box).
        let parts = if serial { 1 } else { scatter_parts().clamp(1, nz) };
        let scatter = |first: usize| {
            let ks = (first..nz).step_by(parts);
            let mut img = vec![0f32; SCATTER_IMAGES * pw * ph];
            dispatch!(fv.side, fv.cam.distorted, |N, D| kernels::scatter::<N, D>(self, view, ks, x, known, &mut img));
            img
        };
        let partials: Vec<Vec<f32>> =
            if parts == 1 { vec![scatter(0)] } else { (0..parts).into_par_iter().map(scatter).collect() };
        let sum_row = |(r, row): (usize, &mut [f32])| {
            let at = (r + n) * pw + n;
            row.fill(0.0);
            for p in &partials {
                for (o, (&a, &b)) in row.iter_mut().zip(p[at..at + w].iter().zip(&p[pw * ph + at..][..w])) {
                    *o += a + b;
                }
                for (o, (&a, &b)) in
                    row.iter_mut().zip(p[2 * pw * ph + at..][..w].iter().zip(&p[3 * pw * ph + at..][..w]))
                {
                    *o += a + b;
                }
            }
        };
        if serial {
            out.chunks_mut(w).enumerate().for_each(sum_row);
        } else {
            out.par_chunks_mut(w).enumerate().for_each(sum_row);
        }
    }
}

impl Projector for FootprintProjector {
    fn grid(&self) -> &Grid {
        &self.grid
    }

    fn cameras(&self) -> &[Camera] {
        &self.cameras
    }

    fn forward(&self, view: usize, x: &[f32], out: &mut [f32]) {
        check_shapes(self, view, x.len(), out.len());
        self.forward_known(view, x, None, out, false);
    }

    /// Which chunks of the volume hold anything is found once instead of once per view: for a
    /// flow that fills part of the box, reading the whole volume again for each view was a
    /// sixth of a projection's time.
    fn forward_views(&self, views: &[usize], x: &[f32], outs: &mut [&mut [f32]]) {
        assert_eq!(views.len(), outs.len(), "one image per view");
        for (&v, out) in views.iter().zip(outs.iter()) {
            check_shapes(self, v, x.len(), out.len());
        }
        let known = NonEmptyChunks::of(&self.grid, x);
        // With enough views for every thread to take several, each view runs on one thread:
        // the threads then meet once, not twice per view, and no view's image is split.
        if views.len() >= VIEWS_PER_THREAD * rayon::current_num_threads() {
            views
                .par_iter()
                .zip(outs.par_iter_mut())
                .for_each(|(&v, out)| self.forward_known(v, x, Some(&known), out, true));
        } else {
            for (&v, out) in views.iter().zip(outs.iter_mut()) {
                self.forward_known(v, x, Some(&known), out, false);
            }
        }
    }

    fn back_add(&self, view: usize, y: &[f32], out: &mut [f32], col_sums: Option<&mut [f32]>) {
        self.back_add_views(&[view], &[y], out, col_sums);
    }

    /// Each task zeroes its slab of `b` and `c`, back-projects into it and updates its slab of
    /// `x` while the three are in cache: one pass over the grid instead of four.
    fn back_update(&self, view: usize, y: &[f32], x: &mut [f32], scratch: (&mut [f32], &mut [f32]), update: &Update) {
        check_shapes(self, view, x.len(), y.len());
        let (b, c) = scratch;
        assert!(b.len() == x.len() && c.len() == x.len(), "back_update: scratch of the wrong length");
        let im = self.back_image(view, y);
        let slab = self.grid.dims[0] * self.grid.dims[1];
        let per = self.slices_per_task();
        x.par_chunks_mut(per * slab)
            .zip(b.par_chunks_mut(per * slab).zip(c.par_chunks_mut(per * slab)))
            .enumerate()
            .for_each(|(t, (xs, (bs, cs)))| {
                bs.fill(0.0);
                cs.fill(0.0);
                self.back_slab(view, &im, t * per..t * per + xs.len() / slab, bs, Some(cs));
                update(t * per * slab, xs, bs, cs);
            });
    }

    /// One pass over the grid for all the views: each task takes a slab of z-slices and adds
    /// every view's back projection to it in turn, so the slab stays in cache across the views
    /// and the threads meet once, not once per view.
    fn back_add_views(&self, views: &[usize], ys: &[&[f32]], out: &mut [f32], col_sums: Option<&mut [f32]>) {
        assert_eq!(views.len(), ys.len(), "one image per view");
        for (&v, y) in views.iter().zip(ys) {
            check_shapes(self, v, out.len(), y.len());
        }
        let images: Vec<BackImage> = if views.len() == 1 {
            vec![self.back_image(views[0], ys[0])]
        } else {
            views.par_iter().zip(ys).map(|(&v, y)| self.back_image(v, y)).collect()
        };
        let slab = self.grid.dims[0] * self.grid.dims[1];
        let per = self.slices_per_task();
        let task = |t: usize, o: &mut [f32], mut c: Option<&mut [f32]>| {
            let ks = t * per..(t * per + o.len() / slab);
            for (&view, im) in views.iter().zip(&images) {
                self.back_slab(view, im, ks.clone(), o, c.as_deref_mut());
            }
        };
        match col_sums {
            None => out.par_chunks_mut(per * slab).enumerate().for_each(|(t, o)| task(t, o, None)),
            Some(cs) => {
                assert_eq!(cs.len(), out.len(), "column-sum buffer has the wrong length");
                out.par_chunks_mut(per * slab)
                    .zip(cs.par_chunks_mut(per * slab))
                    .enumerate()
                    .for_each(|(t, (o, c))| task(t, o, Some(c)))
            }
        }
    }

    fn rows(&self, view: usize) -> SparseRows {
        let fv = &self.views[view];
        dispatch!(fv.side, fv.cam.distorted, |N, D| self.rows_impl::<N, D>(view))
    }

    fn rows_bytes_estimate(&self, view: usize) -> usize {
        // A footprint of side N covers about (N/2 + 1)² pixels with a positive weight.
        let n = self.views[view].side / 2 + 1;
        self.grid.len() * 8 * n * n + (self.view_len(view) + 1) * 8
    }

    fn bytes(&self) -> usize {
        std::mem::size_of::<FootView>() * self.views.len() + self.kept_footprint_bytes() as usize
    }

    fn scratch_bytes(&self, view: usize) -> usize {
        let (pw, ph) = self.views[view].padded();
        (SCATTER_IMAGES * scatter_parts() + 1) * pw * ph * 4
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The vectorised ranges of first pixels equal the scalar one on rows of hits and misses,
    /// rows of misses only, and no chunks at all.
    #[test]
    fn first_ranges_agree_across_instruction_sets() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for (chunks, miss_rate) in [(0, 0.5), (1, 0.0), (1, 1.0), (3, 0.5), (8, 0.9), (8, 1.0), (5, 0.1)] {
            let rows: Vec<[f32; CHUNK]> = (0..chunks)
                .map(|_| {
                    std::array::from_fn(
                        |_| if rng.random_bool(miss_rate) { -1.0 } else { rng.random_range(0..300) as f32 },
                    )
                })
                .collect();
            let scalar = first_range(rows.iter());
            let hits: Vec<f32> = rows.iter().flatten().copied().filter(|&f| f >= 0.0).collect();
            let lo = hits.iter().copied().fold(f32::MAX, f32::min);
            let hi = hits.iter().copied().fold(-1.0, f32::max);
            assert_eq!(scalar, (lo, hi), "{chunks} chunks, miss rate {miss_rate}");
            #[cfg(target_arch = "x86_64")]
            {
                if Isa::detected() >= Isa::Avx2 {
                    // SAFETY: AVX2 was detected.
                    assert_eq!(unsafe { first_range8(rows.iter()) }, scalar, "AVX2, {chunks} chunks");
                }
                if Isa::detected() >= Isa::Avx512 {
                    // SAFETY: AVX-512F was detected.
                    assert_eq!(unsafe { first_range16(rows.iter()) }, scalar, "AVX-512, {chunks} chunks");
                }
            }
        }
    }
}
