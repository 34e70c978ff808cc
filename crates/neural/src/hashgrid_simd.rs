//! The hash-grid encoding eight points at a time with AVX2 and FMA, or sixteen with AVX-512
//! (selected at run time; [`crate::hashgrid`] falls back to its scalar loop elsewhere and for
//! the last rows): the forward pass, and the backward pass's weights and indices
//! ([`level_backward`]).
//!
//! Per point and level it computes what the scalar loop does — clamp, cell, trilinear weights
//! multiplied in axis order, the dense vertex index or the spatial hash — in eight or sixteen
//! lanes, and gathers the `F` features of each corner with vector gathers. Batches are prepared
//! [`AHEAD`] batches before they are used, their table entries fetched into the cache
//! meanwhile: the hashed levels' tables (and their gradients) are larger than a core's cache,
//! and a gather or an addition would otherwise wait on each entry in turn. The features are
//! accumulated with fused multiply–adds, so results differ from the scalar loop by rounding
//! only (tested), and a NaN coordinate reads as 0 instead of propagating.
//!
//! Both widths run one generic kernel over [`Lanes`], whose operations are inlined into each
//! width's `#[target_feature]` entry point. Sixteen lanes are taken on CPUs with AVX-512
//! ([`wide`]; measured faster on Intel's Sapphire Rapids and AMD's Zen 4); the first rows go
//! sixteen at a time, then
//! eight, then the scalar loop, in row order, so the gradient's additions keep the scalar
//! loop's order at either width.

use std::arch::x86_64::*;

use super::hashgrid::PRIMES;

/// What one level's forward pass needs.
pub(crate) struct LevelArgs<'a> {
    pub res: u32,
    pub res_t: u32,
    pub inv_span: f32,
    /// The time axis has one cell per time unit (`res_t = time_span`): the time coordinate is
    /// then clamped to `[0, res_t]` and used as it is, so a whole `t'` lands exactly on a
    /// vertex (the scalar loop does the same).
    pub time_exact: bool,
    /// Vertex-index strides of a dense level.
    pub stride: [usize; 4],
    /// `entries − 1` of a hashed level.
    pub mask: usize,
    /// The level's table, `entries × F`.
    pub table: &'a [f32],
    /// The level's first feature column in a row of `feats`.
    pub column: usize,
    /// Features per row (`L · F`).
    pub row_len: usize,
    /// Whether the table entries of batches ahead are fetched into the cache: for points in
    /// random order (training samples of random rays), not for points that follow each other
    /// in space (a grid, a ray marched in order), whose entries the cache already holds.
    pub fetch_ahead: bool,
}

/// Whether the kernels run: the CPU has AVX2 and FMA (cached by the standard library) and
/// [`crate::hashgrid::set_vectorised`] has not turned them off.
#[inline]
pub(crate) fn available() -> bool {
    super::hashgrid::VECTORISED.load(std::sync::atomic::Ordering::Relaxed)
        && is_x86_feature_detected!("avx2")
        && is_x86_feature_detected!("fma")
}

#[cfg(test)]
thread_local! {
    /// Tests of the eight-lane kernels on a CPU that takes sixteen.
    pub(crate) static NARROW: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether the kernels take sixteen points at a time: on CPUs with AVX-512, where the training
/// step measured faster with them, on Intel's Sapphire Rapids and on AMD's Zen 4, which splits
/// 512-bit operations in two (docs/training-engine.md). A rule by instruction set, like the
/// decoder's bfloat16 rule: the same rows take the same path on every run of a machine.
fn wide() -> bool {
    #[cfg(test)]
    if NARROW.with(|n| n.get()) {
        return false;
    }
    is_x86_feature_detected!("avx512f")
}

/// Writes the level's features of the first rows of `inputs` (`n × D`) into `feats`, whole
/// groups of sixteen or eight, and returns how many rows it did.
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`available`]). `args.table` must hold every entry a vertex
/// of the level can index: `(res + 1)^D'` vertices (D' = 3 spatial axes, plus `res_t + 1` time
/// vertices for D = 4) for a dense level, `mask + 1` for a hashed one, `F` values each.
pub(crate) unsafe fn level_forward<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    feats: &mut [f32],
) -> usize {
    let mut done = 0;
    if wide() {
        // SAFETY: `wide` found AVX-512; the table as the caller promised.
        done = unsafe { forward_512::<D, F, DENSE>(args, inputs, feats) };
    }
    let (rest, rest_feats) = (&inputs[done * D..], &mut feats[done * args.row_len..]);
    // SAFETY: AVX2 and FMA as the caller promised; the same table.
    done + unsafe { forward_256::<D, F, DENSE>(args, rest, rest_feats) }
}

/// Scatters the level's gradient of the first rows, whole groups of sixteen or eight:
/// `dfeats` (`n × row_len`) holds ∂L/∂features, and each corner's `F` entries of `gtable`
/// (the level's slice of the gradient, laid out like its table) receive weight ×
/// ∂L/∂feature. Returns how many rows it did.
///
/// The weights and indices are computed a vector of points at a time; the additions run
/// point by point, corner by corner, each a product rounded once and then added — the scalar
/// loop's order and arithmetic, so the gradient is bit-identical to it (tested).
///
/// # Safety
/// As [`level_forward`], with `gtable` in place of the table: it must hold every entry a vertex
/// of the level can index, `F` values each.
pub(crate) unsafe fn level_backward<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    dfeats: &[f32],
    gtable: &mut [f32],
) -> usize {
    let mut done = 0;
    if wide() {
        // SAFETY: `wide` found AVX-512; the gradient table as the caller promised.
        done = unsafe { backward_512::<D, F, DENSE>(args, inputs, dfeats, gtable) };
    }
    let (rest, rest_d) = (&inputs[done * D..], &dfeats[done * args.row_len..]);
    // SAFETY: AVX2 and FMA as the caller promised; the same gradient table.
    done + unsafe { backward_256::<D, F, DENSE>(args, rest, rest_d, gtable) }
}

#[target_feature(enable = "avx2,fma")]
unsafe fn forward_256<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    feats: &mut [f32],
) -> usize {
    // SAFETY: the features are enabled here; the table as `level_forward` requires.
    unsafe { forward::<Avx2, D, F, DENSE>(args, inputs, feats) }
}

#[target_feature(enable = "avx2,fma,avx512f")]
unsafe fn forward_512<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    feats: &mut [f32],
) -> usize {
    // SAFETY: the features are enabled here; the table as `level_forward` requires.
    unsafe { forward::<Avx512, D, F, DENSE>(args, inputs, feats) }
}

#[target_feature(enable = "avx2,fma")]
unsafe fn backward_256<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    dfeats: &[f32],
    gtable: &mut [f32],
) -> usize {
    // SAFETY: the features are enabled here; the table as `level_backward` requires.
    unsafe { backward::<Avx2, D, F, DENSE>(args, inputs, dfeats, gtable) }
}

#[target_feature(enable = "avx2,fma,avx512f")]
unsafe fn backward_512<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    dfeats: &[f32],
    gtable: &mut [f32],
) -> usize {
    // SAFETY: the features are enabled here; the table as `level_backward` requires.
    unsafe { backward::<Avx512, D, F, DENSE>(args, inputs, dfeats, gtable) }
}

/// The most lanes a [`Lanes`] has: the size of the kernels' scratch rows.
const MAX_LANES: usize = 16;

/// The vector operations of the kernels at one register width: eight lanes ([`Avx2`]) or
/// sixteen ([`Avx512`]).
///
/// # Safety
/// Every method requires the width's CPU features. They are `#[inline(always)]` and called
/// only from the kernels, themselves inlined into the width's `#[target_feature]` entry
/// points, where the intrinsics are inlined too.
trait Lanes {
    /// Points per vector.
    const N: usize;
    /// `N` floats.
    type F: Copy;
    /// `N` 32-bit integers.
    type I: Copy;
    unsafe fn splat(x: f32) -> Self::F;
    unsafe fn splat_i(x: i32) -> Self::I;
    /// `N` floats from `p`.
    unsafe fn load(p: *const f32) -> Self::F;
    unsafe fn store(p: *mut f32, v: Self::F);
    unsafe fn store_i(p: *mut u32, v: Self::I);
    unsafe fn sub(a: Self::F, b: Self::F) -> Self::F;
    unsafe fn mul(a: Self::F, b: Self::F) -> Self::F;
    /// `a · b + c`, rounded once.
    unsafe fn fmadd(a: Self::F, b: Self::F, c: Self::F) -> Self::F;
    /// `max(a, b)`, `b` where `a` is NaN.
    unsafe fn max(a: Self::F, b: Self::F) -> Self::F;
    unsafe fn min(a: Self::F, b: Self::F) -> Self::F;
    /// Truncated to integers.
    unsafe fn trunc(a: Self::F) -> Self::I;
    unsafe fn to_f(a: Self::I) -> Self::F;
    unsafe fn min_i(a: Self::I, b: Self::I) -> Self::I;
    unsafe fn add_i(a: Self::I, b: Self::I) -> Self::I;
    /// The low 32 bits of `a · b`.
    unsafe fn mul_i(a: Self::I, b: Self::I) -> Self::I;
    unsafe fn xor_i(a: Self::I, b: Self::I) -> Self::I;
    unsafe fn and_i(a: Self::I, b: Self::I) -> Self::I;
    /// Whether every lane is exactly 0.
    unsafe fn all_zero(a: Self::F) -> bool;
    /// `table[at[i]]` per lane.
    unsafe fn gather(table: *const f32, at: Self::I) -> Self::F;
    /// For `F = 2`: adds `w[i] · (table[at[i]], table[at[i] + 1])` to the rows' layout of the
    /// pairs, points `0 .. N/2` in `acc[0]` and the rest in `acc[1]`.
    unsafe fn fmadd_pairs(table: *const f32, w: Self::F, at: Self::I, acc: &mut [Self::F; 2]);
    /// `w` with each lane doubled, in the layout of [`Lanes::fmadd_pairs`]'s sums.
    unsafe fn dup_pairs(w: Self::F) -> [Self::F; 2];
}

/// Eight lanes: AVX2 and FMA.
struct Avx2;

impl Lanes for Avx2 {
    const N: usize = 8;
    type F = __m256;
    type I = __m256i;
    #[inline(always)]
    unsafe fn splat(x: f32) -> __m256 {
        unsafe { _mm256_set1_ps(x) }
    }
    #[inline(always)]
    unsafe fn splat_i(x: i32) -> __m256i {
        unsafe { _mm256_set1_epi32(x) }
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> __m256 {
        unsafe { _mm256_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: __m256) {
        unsafe { _mm256_storeu_ps(p, v) }
    }
    #[inline(always)]
    unsafe fn store_i(p: *mut u32, v: __m256i) {
        unsafe { _mm256_storeu_si256(p.cast(), v) }
    }
    #[inline(always)]
    unsafe fn sub(a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_sub_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn mul(a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_mul_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn fmadd(a: __m256, b: __m256, c: __m256) -> __m256 {
        unsafe { _mm256_fmadd_ps(a, b, c) }
    }
    #[inline(always)]
    unsafe fn max(a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_max_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn min(a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_min_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn trunc(a: __m256) -> __m256i {
        unsafe { _mm256_cvttps_epi32(a) }
    }
    #[inline(always)]
    unsafe fn to_f(a: __m256i) -> __m256 {
        unsafe { _mm256_cvtepi32_ps(a) }
    }
    #[inline(always)]
    unsafe fn min_i(a: __m256i, b: __m256i) -> __m256i {
        unsafe { _mm256_min_epi32(a, b) }
    }
    #[inline(always)]
    unsafe fn add_i(a: __m256i, b: __m256i) -> __m256i {
        unsafe { _mm256_add_epi32(a, b) }
    }
    #[inline(always)]
    unsafe fn mul_i(a: __m256i, b: __m256i) -> __m256i {
        unsafe { _mm256_mullo_epi32(a, b) }
    }
    #[inline(always)]
    unsafe fn xor_i(a: __m256i, b: __m256i) -> __m256i {
        unsafe { _mm256_xor_si256(a, b) }
    }
    #[inline(always)]
    unsafe fn and_i(a: __m256i, b: __m256i) -> __m256i {
        unsafe { _mm256_and_si256(a, b) }
    }
    #[inline(always)]
    unsafe fn all_zero(a: __m256) -> bool {
        unsafe { _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(a, _mm256_setzero_ps())) == 0xFF }
    }
    #[inline(always)]
    unsafe fn gather(table: *const f32, at: __m256i) -> __m256 {
        unsafe { _mm256_i32gather_ps::<4>(table, at) }
    }
    #[inline(always)]
    unsafe fn fmadd_pairs(table: *const f32, w: __m256, at: __m256i, acc: &mut [__m256; 2]) {
        // Both features of a vertex in one 64-bit element: four points per gather, with their
        // weights duplicated to match.
        unsafe {
            let pairs = table as *const i64;
            let lo = _mm256_i32gather_epi64::<4>(pairs, _mm256_castsi256_si128(at));
            let hi = _mm256_i32gather_epi64::<4>(pairs, _mm256_extracti128_si256::<1>(at));
            let [w_lo, w_hi] = Self::dup_pairs(w);
            acc[0] = _mm256_fmadd_ps(w_lo, _mm256_castsi256_ps(lo), acc[0]);
            acc[1] = _mm256_fmadd_ps(w_hi, _mm256_castsi256_ps(hi), acc[1]);
        }
    }
    #[inline(always)]
    unsafe fn dup_pairs(w: __m256) -> [__m256; 2] {
        unsafe {
            let dup_lo = _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3);
            let dup_hi = _mm256_setr_epi32(4, 4, 5, 5, 6, 6, 7, 7);
            [_mm256_permutevar8x32_ps(w, dup_lo), _mm256_permutevar8x32_ps(w, dup_hi)]
        }
    }
}

/// Sixteen lanes: AVX-512 Foundation.
struct Avx512;

impl Lanes for Avx512 {
    const N: usize = 16;
    type F = __m512;
    type I = __m512i;
    #[inline(always)]
    unsafe fn splat(x: f32) -> __m512 {
        unsafe { _mm512_set1_ps(x) }
    }
    #[inline(always)]
    unsafe fn splat_i(x: i32) -> __m512i {
        unsafe { _mm512_set1_epi32(x) }
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> __m512 {
        unsafe { _mm512_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: __m512) {
        unsafe { _mm512_storeu_ps(p, v) }
    }
    #[inline(always)]
    unsafe fn store_i(p: *mut u32, v: __m512i) {
        unsafe { _mm512_storeu_si512(p.cast(), v) }
    }
    #[inline(always)]
    unsafe fn sub(a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_sub_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn mul(a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_mul_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn fmadd(a: __m512, b: __m512, c: __m512) -> __m512 {
        unsafe { _mm512_fmadd_ps(a, b, c) }
    }
    #[inline(always)]
    unsafe fn max(a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_max_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn min(a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_min_ps(a, b) }
    }
    #[inline(always)]
    unsafe fn trunc(a: __m512) -> __m512i {
        unsafe { _mm512_cvttps_epi32(a) }
    }
    #[inline(always)]
    unsafe fn to_f(a: __m512i) -> __m512 {
        unsafe { _mm512_cvtepi32_ps(a) }
    }
    #[inline(always)]
    unsafe fn min_i(a: __m512i, b: __m512i) -> __m512i {
        unsafe { _mm512_min_epi32(a, b) }
    }
    #[inline(always)]
    unsafe fn add_i(a: __m512i, b: __m512i) -> __m512i {
        unsafe { _mm512_add_epi32(a, b) }
    }
    #[inline(always)]
    unsafe fn mul_i(a: __m512i, b: __m512i) -> __m512i {
        unsafe { _mm512_mullo_epi32(a, b) }
    }
    #[inline(always)]
    unsafe fn xor_i(a: __m512i, b: __m512i) -> __m512i {
        unsafe { _mm512_xor_si512(a, b) }
    }
    #[inline(always)]
    unsafe fn and_i(a: __m512i, b: __m512i) -> __m512i {
        unsafe { _mm512_and_si512(a, b) }
    }
    #[inline(always)]
    unsafe fn all_zero(a: __m512) -> bool {
        unsafe { _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(a, _mm512_setzero_ps()) == 0xFFFF }
    }
    #[inline(always)]
    unsafe fn gather(table: *const f32, at: __m512i) -> __m512 {
        unsafe { _mm512_i32gather_ps::<4>(at, table) }
    }
    #[inline(always)]
    unsafe fn fmadd_pairs(table: *const f32, w: __m512, at: __m512i, acc: &mut [__m512; 2]) {
        // Both features of a vertex in one 64-bit element: eight points per gather, with
        // their weights duplicated to match.
        unsafe {
            let pairs = table as *const i64;
            let lo = _mm512_i32gather_epi64::<4>(_mm512_castsi512_si256(at), pairs);
            let hi = _mm512_i32gather_epi64::<4>(_mm512_extracti64x4_epi64::<1>(at), pairs);
            let [w_lo, w_hi] = Self::dup_pairs(w);
            acc[0] = _mm512_fmadd_ps(w_lo, _mm512_castsi512_ps(lo), acc[0]);
            acc[1] = _mm512_fmadd_ps(w_hi, _mm512_castsi512_ps(hi), acc[1]);
        }
    }
    #[inline(always)]
    unsafe fn dup_pairs(w: __m512) -> [__m512; 2] {
        unsafe {
            let dup_lo = _mm512_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7);
            let dup_hi = _mm512_setr_epi32(8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13, 13, 14, 14, 15, 15);
            [_mm512_permutexvar_ps(dup_lo, w), _mm512_permutexvar_ps(dup_hi, w)]
        }
    }
}

/// The forward pass at width `V` over the first `N ⌊n / N⌋` rows; returns how many it did.
///
/// # Safety
/// The width's features; the table as [`level_forward`] requires.
#[inline(always)]
unsafe fn forward<V: Lanes, const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    feats: &mut [f32],
) -> usize {
    let n = inputs.len() / D;
    let full = n / V::N * V::N;
    assert!(feats.len() >= n * args.row_len && args.column + F <= args.row_len);
    let table = args.table.as_ptr();
    let batches = full / V::N;
    let points = |b: usize| &inputs[b * V::N * D..(b + 1) * V::N * D];
    if !args.fetch_ahead {
        // Points in spatial order: their entries are mostly in the cache already.
        // SAFETY: the width's features, as the caller promised.
        let mut c = unsafe { Corners::<V>::empty() };
        for b in 0..batches {
            // SAFETY: the width's features, as the caller promised.
            unsafe {
                c.prepare::<D, F, DENSE>(args, points(b), None);
                gather_batch::<V, D, F>(args, table, &c, b * V::N, feats);
            }
        }
        return full;
    }
    // Batches of points are prepared AHEAD batches before they gather: their corners' weights
    // and entries computed, the entries fetched into the cache (the tables are larger than the
    // cache, and the gathers would otherwise wait on them in turn).
    // SAFETY (whole block): the width's features, as the caller promised; the entries lie in
    // the table.
    unsafe {
        let mut ring = [Corners::<V>::empty(); AHEAD + 1];
        for b in 0..batches.min(AHEAD) {
            ring[b].prepare::<D, F, DENSE>(args, points(b), Some(table));
        }
        for b in 0..batches {
            if b + AHEAD < batches {
                ring[(b + AHEAD) % (AHEAD + 1)].prepare::<D, F, DENSE>(args, points(b + AHEAD), Some(table));
            }
            gather_batch::<V, D, F>(args, table, &ring[b % (AHEAD + 1)], b * V::N, feats);
        }
    }
    full
}

/// Gathers the features of the batch of `N` rows from `base`, whose corners `c` gives, into
/// `feats`.
///
/// # Safety
/// The width's features; the entries of `c` lie in the table at `table`, `F` values each.
#[inline(always)]
unsafe fn gather_batch<V: Lanes, const D: usize, const F: usize>(
    args: &LevelArgs<'_>,
    table: *const f32,
    c: &Corners<V>,
    base: usize,
    feats: &mut [f32],
) {
    let mut out = [[0.0f32; MAX_LANES]; F];
    // SAFETY (whole body): the caller's contract; `out` rows hold MAX_LANES ≥ N floats.
    unsafe {
        if F == 2 {
            // Accumulated in the rows' own layout: (feature 0, feature 1) per point.
            let mut acc = [V::splat(0.0); 2];
            for corner in 0..1usize << D {
                if !skipped::<D>(corner, c.idle) {
                    V::fmadd_pairs(table, c.weight[corner], c.entry[corner], &mut acc);
                }
            }
            V::store(out[0].as_mut_ptr(), acc[0]);
            V::store(out[1].as_mut_ptr(), acc[1]);
            let half = V::N / 2;
            for j in 0..V::N {
                let row = (base + j) * args.row_len + args.column;
                let src = &out[j / half][2 * (j % half)..2 * (j % half) + 2];
                feats[row..row + 2].copy_from_slice(src);
            }
        } else {
            let mut acc = [V::splat(0.0); F];
            for corner in 0..1usize << D {
                if skipped::<D>(corner, c.idle) {
                    continue;
                }
                for (k, acc) in acc.iter_mut().enumerate() {
                    let v = V::gather(table.add(k), c.entry[corner]);
                    *acc = V::fmadd(c.weight[corner], v, *acc);
                }
            }
            for k in 0..F {
                V::store(out[k].as_mut_ptr(), acc[k]);
            }
            for j in 0..V::N {
                let row = (base + j) * args.row_len + args.column;
                for k in 0..F {
                    feats[row + k] = out[k][j];
                }
            }
        }
    }
}

/// Per axis, for the `N` points in `points` (`N × D`, row by row): the weights of the lower
/// and upper vertex, and their contributions to the vertex index (dense: coordinate × stride)
/// or hash (coordinate × prime) — what the scalar loop computes per point.
///
/// # Safety
/// The width's features.
#[inline(always)]
#[allow(clippy::type_complexity)]
unsafe fn axes<V: Lanes, const D: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    points: &[f32],
) -> ([[V::F; 2]; 4], [[V::I; 2]; 4]) {
    // Coordinate `a` of point `j` at `lanes[a][j]`.
    let mut lanes = [[0.0f32; MAX_LANES]; 4];
    for (j, x) in points.chunks_exact(D).take(V::N).enumerate() {
        for a in 0..D {
            lanes[a][j] = x[a];
        }
    }
    // SAFETY (whole body): the width's features; `lanes[a]` holds MAX_LANES ≥ N floats.
    unsafe {
        let zero = V::splat(0.0);
        let one = V::splat(1.0);
        let mut w = [[zero; 2]; 4];
        let mut part = [[V::splat_i(0); 2]; 4];
        for a in 0..D {
            let (scale, r) = if a < 3 { (1.0, args.res) } else { (args.inv_span, args.res_t) };
            let u = V::load(lanes[a].as_ptr());
            // max(u, 0) returns 0 for a NaN u; then min(·, 1) (or min(·, r) on an exact time
            // axis).
            let p = if a == 3 && args.time_exact {
                V::min(V::max(u, zero), V::splat(r as f32))
            } else {
                let u = V::mul(u, V::splat(scale));
                V::mul(V::min(V::max(u, zero), one), V::splat(r as f32))
            };
            let c = V::min_i(V::trunc(p), V::splat_i(r.saturating_sub(1) as i32));
            let t = V::sub(p, V::to_f(c));
            w[a] = [V::sub(one, t), t];
            let c1 = V::add_i(c, V::splat_i(1));
            let k = V::splat_i(if DENSE { args.stride[a] as u32 } else { PRIMES[a] } as i32);
            part[a] = [V::mul_i(c, k), V::mul_i(c1, k)];
        }
        (w, part)
    }
}

/// The backward pass at width `V` over the first `N ⌊n / N⌋` rows; returns how many it did.
///
/// # Safety
/// The width's features; the gradient table as [`level_backward`] requires.
#[inline(always)]
unsafe fn backward<V: Lanes, const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    dfeats: &[f32],
    gtable: &mut [f32],
) -> usize {
    let n = inputs.len() / D;
    let full = n / V::N * V::N;
    assert!(dfeats.len() >= n * args.row_len && args.column + F <= args.row_len);
    let g = gtable.as_mut_ptr();
    // ∂L/∂features of the batch's points, point by point (`F` values each).
    let mut d = [0.0f32; MAX_LANES * 8];
    let mut dk = [0.0f32; MAX_LANES];
    // Batches of points are prepared AHEAD batches before their additions: their corners'
    // weights and entries computed with the products weight × ∂L/∂feature, and the entries
    // fetched into the cache (the gradient table is larger than the cache, and the additions
    // would otherwise wait on its entries in turn).
    let batches = full / V::N;
    let fetch = args.fetch_ahead.then_some(g as *const f32);
    // SAFETY (whole block): the width's features, as the caller promised; `d`, `dk` and the
    // products hold N · F floats (N ≤ MAX_LANES, F ≤ 8); the entries lie in the gradient table.
    unsafe {
        let mut ring = [Corners::<V>::empty(); AHEAD + 1];
        // Per corner, the products point by point (`F` values each), as they are added.
        let mut prod = [[[0.0f32; MAX_LANES * 8]; 16]; AHEAD + 1];
        for b in 0..batches + AHEAD {
            if b < batches {
                let base = b * V::N;
                for j in 0..V::N {
                    let row = (base + j) * args.row_len + args.column;
                    d[j * F..(j + 1) * F].copy_from_slice(&dfeats[row..row + F]);
                }
                let slot = b % (AHEAD + 1);
                let points = &inputs[base * D..(base + V::N) * D];
                ring[slot].prepare::<D, F, DENSE>(args, points, fetch);
                let c = &ring[slot];
                for corner in 0..1usize << D {
                    if skipped::<D>(corner, c.idle) {
                        continue;
                    }
                    let w = c.weight[corner];
                    let out = prod[slot][corner].as_mut_ptr();
                    if F == 2 {
                        // The point-major pairs are the rows' layout of `fmadd_pairs`.
                        let [w_lo, w_hi] = V::dup_pairs(w);
                        V::store(out, V::mul(w_lo, V::load(d.as_ptr())));
                        V::store(out.add(V::N), V::mul(w_hi, V::load(d.as_ptr().add(V::N))));
                    } else {
                        for k in 0..F {
                            for j in 0..V::N {
                                dk[j] = d[j * F + k];
                            }
                            V::store(dk.as_mut_ptr(), V::mul(w, V::load(dk.as_ptr())));
                            for j in 0..V::N {
                                *out.add(j * F + k) = dk[j];
                            }
                        }
                    }
                }
            }
            if b >= AHEAD {
                let slot = (b - AHEAD) % (AHEAD + 1);
                add_batch::<V, D, F>(g, &ring[slot], &prod[slot]);
            }
        }
    }
    full
}

/// How many batches of points ahead the encoding fetches table entries into the cache.
const AHEAD: usize = 2;

/// One batch of `N` points at one level: every corner's trilinear weights and table entry
/// (its first value's index, `F` values per entry), and which corners are idle.
struct Corners<V: Lanes> {
    weight: [V::F; 16],
    entry: [V::I; 16],
    idle: (bool, bool),
}

impl<V: Lanes> Clone for Corners<V> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<V: Lanes> Copy for Corners<V> {}

impl<V: Lanes> Corners<V> {
    /// Zero weights and entries: a ring's slots before their first batch.
    ///
    /// # Safety
    /// The width's features.
    #[inline(always)]
    unsafe fn empty() -> Self {
        // SAFETY: the width's features, as the caller promised.
        unsafe { Corners { weight: [V::splat(0.0); 16], entry: [V::splat_i(0); 16], idle: (false, false) } }
    }

    /// The corners of the `N` points `points` (`N × D`), their entries of `table` (the level's
    /// table or its gradient) fetched into the cache when it is given.
    ///
    /// # Safety
    /// The width's features.
    #[inline(always)]
    unsafe fn prepare<const D: usize, const F: usize, const DENSE: bool>(
        &mut self,
        args: &LevelArgs<'_>,
        points: &[f32],
        table: Option<*const f32>,
    ) {
        let c = self;
        // SAFETY (whole body): the width's features, as the caller promised; `at` holds
        // MAX_LANES ≥ N values.
        unsafe {
            let (w, part) = axes::<V, D, DENSE>(args, points);
            c.idle = idle_time_corners::<V, D>(&w);
            let mask = V::splat_i(args.mask as i32);
            let mut at = [0u32; MAX_LANES];
            for corner in 0..1usize << D {
                if skipped::<D>(corner, c.idle) {
                    continue;
                }
                let (wc, idx) = corner_of::<V, D, DENSE>(&w, &part, corner, mask);
                let idx = V::mul_i(idx, V::splat_i(F as i32));
                c.weight[corner] = wc;
                c.entry[corner] = idx;
                // Only the corners at the lower x vertex: the upper one's entry follows it in
                // the table (dense levels: index + 1; hashed: x's prime is 1, so the hash
                // differs in its lowest bits), in the same cache line for most points.
                if let Some(table) = table.filter(|_| corner & 1 == 0) {
                    V::store_i(at.as_mut_ptr(), idx);
                    for &e in &at[..V::N] {
                        // A prefetch reads nothing; the address is an entry of the table.
                        _mm_prefetch::<_MM_HINT_T0>(table.wrapping_add(e as usize) as *const i8);
                    }
                }
            }
        }
    }
}

/// Adds one batch's products into the gradient table at `g`: point by point, corner by
/// corner, each product added once (the scalar loop's order).
///
/// # Safety
/// The width's features. Every entry of `c` and the `F` values from it must lie inside the
/// table at `g`.
#[inline(always)]
unsafe fn add_batch<V: Lanes, const D: usize, const F: usize>(
    g: *mut f32,
    c: &Corners<V>,
    prod: &[[f32; MAX_LANES * 8]; 16],
) {
    let mut at = [[0u32; MAX_LANES]; 16];
    for (corner, at) in at.iter_mut().enumerate().take(1 << D) {
        if !skipped::<D>(corner, c.idle) {
            // SAFETY: the width's features; `at` holds MAX_LANES ≥ N values.
            unsafe { V::store_i(at.as_mut_ptr(), c.entry[corner]) };
        }
    }
    for j in 0..V::N {
        for corner in 0..1usize << D {
            if skipped::<D>(corner, c.idle) {
                continue;
            }
            let e = at[corner][j] as usize;
            for k in 0..F {
                // SAFETY: inside the table (the caller's contract).
                unsafe { *g.add(e + k) += prod[corner][j * F + k] };
            }
        }
    }
}

/// For a 4D level: whether every one of the batch's points has time weight exactly 0 at the
/// upper time vertex (`.0`: the corners with bit 3 set contribute nothing) or at the lower one
/// (`.1`). Points on a frame's time vertex — every training sample of a space–time grid — skip
/// half the corners; a zero weight adds exactly nothing, so skipping changes no result.
///
/// # Safety
/// The width's features.
#[inline(always)]
unsafe fn idle_time_corners<V: Lanes, const D: usize>(w: &[[V::F; 2]; 4]) -> (bool, bool) {
    if D < 4 {
        return (false, false);
    }
    // SAFETY: the width's features, as the caller promised.
    unsafe { (V::all_zero(w[3][1]), V::all_zero(w[3][0])) }
}

/// Whether `corner` is one [`idle_time_corners`] found idle.
#[inline(always)]
fn skipped<const D: usize>(corner: usize, idle: (bool, bool)) -> bool {
    D == 4 && if (corner >> 3) & 1 == 1 { idle.0 } else { idle.1 }
}

/// The trilinear weight and the table entry of vertex `corner` (bit `a` = upper along axis `a`)
/// for the batch's points: weights multiplied in axis order, indices summed (dense) or hashed.
///
/// # Safety
/// The width's features.
#[inline(always)]
unsafe fn corner_of<V: Lanes, const D: usize, const DENSE: bool>(
    w: &[[V::F; 2]; 4],
    part: &[[V::I; 2]; 4],
    corner: usize,
    mask: V::I,
) -> (V::F, V::I) {
    // SAFETY (whole body): the width's features, as the caller promised.
    unsafe {
        let mut wc = V::splat(1.0);
        let mut key = V::splat_i(0);
        for a in 0..D {
            let bit = (corner >> a) & 1;
            wc = V::mul(wc, w[a][bit]);
            key = if DENSE { V::add_i(key, part[a][bit]) } else { V::xor_i(key, part[a][bit]) };
        }
        (wc, if DENSE { key } else { V::and_i(key, mask) })
    }
}
