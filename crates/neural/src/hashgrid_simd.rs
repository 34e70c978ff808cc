//! The hash-grid encoding eight points at a time with AVX2 and FMA (selected at run time;
//! [`crate::hashgrid`] falls back to its scalar loop elsewhere and for the last rows): the
//! forward pass, and the backward pass's weights and indices ([`level_backward`]).
//!
//! Per point and level it computes what the scalar loop does — clamp, cell, trilinear weights
//! multiplied in axis order, the dense vertex index or the spatial hash — in eight lanes, and
//! gathers the `F` features of each corner with `vgatherdps`. Batches are prepared [`AHEAD`]
//! batches before they are used, their table entries fetched into the cache meanwhile: the
//! hashed levels' tables (and their gradients) are larger than a core's cache, and a gather or
//! an addition would otherwise wait on each entry in turn. The features are accumulated with
//! fused multiply–adds, so results differ from the scalar loop by rounding only (tested), and a
//! NaN coordinate reads as 0 instead of propagating.

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

/// Whether the kernel runs: the CPU has AVX2 and FMA (cached by the standard library) and
/// [`crate::hashgrid::set_vectorised`] has not turned it off.
#[inline]
pub(crate) fn available() -> bool {
    super::hashgrid::VECTORISED.load(std::sync::atomic::Ordering::Relaxed)
        && is_x86_feature_detected!("avx2")
        && is_x86_feature_detected!("fma")
}

/// Writes the level's features of the first `8 ⌊n / 8⌋` rows of `inputs` (`n × D`) into
/// `feats` and returns how many rows it did.
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`available`]). `args.table` must hold every entry a vertex
/// of the level can index: `(res + 1)^D'` vertices (D' = 3 spatial axes, plus `res_t + 1` time
/// vertices for D = 4) for a dense level, `mask + 1` for a hashed one, `F` values each.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn level_forward<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    feats: &mut [f32],
) -> usize {
    let n = inputs.len() / D;
    let full = n / 8 * 8;
    assert!(feats.len() >= n * args.row_len && args.column + F <= args.row_len);
    let zero = _mm256_setzero_ps();
    let table = args.table.as_ptr();
    let mut out = [[0.0f32; 8]; F];
    let mask = _mm256_set1_epi32(args.mask as i32);
    // Gathers the features of the batch of eight rows from `$base`, whose corners' weights and
    // entries (`F` values per entry) `$corner => $wa` gives; `$idle` as [`skipped`] takes it.
    macro_rules! gather_batch {
        ($base:expr, $idle:expr, $corner:ident => $wa:expr) => {{
            let base = $base;
            if F == 2 {
                // Both features of a vertex in one 64-bit element: four points per gather, with
                // their weights duplicated to match, accumulated in the rows' own layout.
                let (mut lo, mut hi) = (zero, zero);
                let dup_lo = _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3);
                let dup_hi = _mm256_setr_epi32(4, 4, 5, 5, 6, 6, 7, 7);
                for $corner in 0..1usize << D {
                    if skipped::<D>($corner, $idle) {
                        continue;
                    }
                    let (wc, at): (__m256, __m256i) = $wa;
                    let pairs = table as *const i64;
                    // SAFETY: `at / 2` is a vertex index or masked hash below the level's
                    // entries, and its pair of floats starts at float `at`, byte `4 · at` (the
                    // caller's contract).
                    let (v_lo, v_hi) = unsafe {
                        (
                            _mm256_i32gather_epi64::<4>(pairs, _mm256_castsi256_si128(at)),
                            _mm256_i32gather_epi64::<4>(pairs, _mm256_extracti128_si256::<1>(at)),
                        )
                    };
                    lo = _mm256_fmadd_ps(_mm256_permutevar8x32_ps(wc, dup_lo), _mm256_castsi256_ps(v_lo), lo);
                    hi = _mm256_fmadd_ps(_mm256_permutevar8x32_ps(wc, dup_hi), _mm256_castsi256_ps(v_hi), hi);
                }
                let mut pair = [[0.0f32; 8]; 2];
                // SAFETY: each array holds eight floats.
                unsafe {
                    _mm256_storeu_ps(pair[0].as_mut_ptr(), lo);
                    _mm256_storeu_ps(pair[1].as_mut_ptr(), hi);
                }
                for j in 0..8 {
                    let row = (base + j) * args.row_len + args.column;
                    let src = &pair[j / 4][2 * (j % 4)..2 * (j % 4) + 2];
                    feats[row..row + 2].copy_from_slice(src);
                }
            } else {
                let mut acc = [zero; F];
                for $corner in 0..1usize << D {
                    if skipped::<D>($corner, $idle) {
                        continue;
                    }
                    let (wc, at): (__m256, __m256i) = $wa;
                    for (k, acc) in acc.iter_mut().enumerate() {
                        // SAFETY: `at / F` is a vertex index or masked hash below the level's
                        // entries, so `at + k` is inside the table (the caller's contract).
                        let v = unsafe { _mm256_i32gather_ps::<4>(table.add(k), at) };
                        *acc = _mm256_fmadd_ps(wc, v, *acc);
                    }
                }
                for k in 0..F {
                    // SAFETY: `out[k]` holds eight floats.
                    unsafe { _mm256_storeu_ps(out[k].as_mut_ptr(), acc[k]) };
                }
                for j in 0..8 {
                    let row = (base + j) * args.row_len + args.column;
                    for k in 0..F {
                        feats[row + k] = out[k][j];
                    }
                }
            }
        }};
    }
    let times_f = _mm256_set1_epi32(F as i32);
    if !args.fetch_ahead {
        // Points in spatial order: their entries are mostly in the cache already, and the
        // corners are computed where they are used.
        for base in (0..full).step_by(8) {
            let (w, part) = axes::<D, DENSE>(args, &inputs[base * D..(base + 8) * D]);
            let idle = idle_time_corners::<D>(&w);
            gather_batch!(base, idle, corner => {
                let (wc, idx) = corner_of::<D, DENSE>(&w, &part, corner, mask);
                (wc, _mm256_mullo_epi32(idx, times_f))
            });
        }
        return full;
    }
    // Batches of eight points are prepared AHEAD batches before they gather: their corners'
    // weights and entries computed, the entries fetched into the cache (the tables are larger
    // than the cache, and the gathers would otherwise wait on them in turn).
    let batches = full / 8;
    let mut ring = [Corners::EMPTY; AHEAD + 1];
    for b in 0..batches.min(AHEAD) {
        ring[b].prepare::<D, F, DENSE>(args, &inputs[b * 8 * D..(b + 1) * 8 * D], mask, Some(table));
    }
    for b in 0..batches {
        if b + AHEAD < batches {
            let points = &inputs[(b + AHEAD) * 8 * D..(b + AHEAD + 1) * 8 * D];
            ring[(b + AHEAD) % (AHEAD + 1)].prepare::<D, F, DENSE>(args, points, mask, Some(table));
        }
        let c = &ring[b % (AHEAD + 1)];
        gather_batch!(b * 8, c.idle, corner => (c.weight[corner], c.entry[corner]));
    }
    full
}

/// Per axis, for the eight points in `points` (`8 × D`, row by row): the weights of the lower
/// and upper vertex, and their contributions to the vertex index (dense: coordinate × stride)
/// or hash (coordinate × prime) — what the scalar loop computes per point.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn axes<const D: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    points: &[f32],
) -> ([[__m256; 2]; 4], [[__m256i; 2]; 4]) {
    // Coordinate `a` of point `j` at `lanes[a][j]`.
    let mut lanes = [[0.0f32; 8]; 4];
    for (j, x) in points.chunks_exact(D).take(8).enumerate() {
        for a in 0..D {
            lanes[a][j] = x[a];
        }
    }
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let mut w = [[zero; 2]; 4];
    let mut part = [[_mm256_setzero_si256(); 2]; 4];
    for a in 0..D {
        let (scale, r) = if a < 3 { (1.0, args.res) } else { (args.inv_span, args.res_t) };
        // SAFETY: `lanes[a]` holds eight floats.
        let u = unsafe { _mm256_loadu_ps(lanes[a].as_ptr()) };
        // max(u, 0) returns 0 for a NaN u; then min(·, 1) (or min(·, r) on an exact time axis).
        let p = if a == 3 && args.time_exact {
            _mm256_min_ps(_mm256_max_ps(u, zero), _mm256_set1_ps(r as f32))
        } else {
            let u = _mm256_mul_ps(u, _mm256_set1_ps(scale));
            let u = _mm256_min_ps(_mm256_max_ps(u, zero), one);
            _mm256_mul_ps(u, _mm256_set1_ps(r as f32))
        };
        let c = _mm256_min_epi32(_mm256_cvttps_epi32(p), _mm256_set1_epi32(r.saturating_sub(1) as i32));
        let t = _mm256_sub_ps(p, _mm256_cvtepi32_ps(c));
        w[a] = [_mm256_sub_ps(one, t), t];
        let c1 = _mm256_add_epi32(c, _mm256_set1_epi32(1));
        let k = if DENSE { args.stride[a] as u32 } else { PRIMES[a] };
        let k = _mm256_set1_epi32(k as i32);
        part[a] = [_mm256_mullo_epi32(c, k), _mm256_mullo_epi32(c1, k)];
    }
    (w, part)
}

/// Scatters the level's gradient of the first `8 ⌊n / 8⌋` rows: `dfeats` (`n × row_len`) holds
/// ∂L/∂features, and each corner's `F` entries of `gtable` (the level's slice of the gradient,
/// laid out like its table) receive weight × ∂L/∂feature. Returns how many rows it did.
///
/// The weights and indices are computed eight points at a time; the additions run point by
/// point, corner by corner, each a product rounded once and then added — the scalar loop's
/// order and arithmetic, so the gradient is bit-identical to it (tested).
///
/// # Safety
/// As [`level_forward`], with `gtable` in place of the table: it must hold every entry a vertex
/// of the level can index, `F` values each.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn level_backward<const D: usize, const F: usize, const DENSE: bool>(
    args: &LevelArgs<'_>,
    inputs: &[f32],
    dfeats: &[f32],
    gtable: &mut [f32],
) -> usize {
    let n = inputs.len() / D;
    let full = n / 8 * 8;
    assert!(dfeats.len() >= n * args.row_len && args.column + F <= args.row_len);
    let g = gtable.as_mut_ptr();
    let mut d = [[0.0f32; 8]; F];
    // Batches of eight points are prepared AHEAD batches before their additions: their
    // corners' weights and entries computed with the products weight × ∂L/∂feature, and the
    // entries fetched into the cache (the gradient table is larger than the cache, and the
    // additions would otherwise wait on its entries in turn).
    let batches = full / 8;
    let fetch = args.fetch_ahead.then_some(g as *const f32);
    let mut ring = [Corners::EMPTY; AHEAD + 1];
    let mut prod = [[[[0.0f32; 8]; F]; 16]; AHEAD + 1];
    let mask = _mm256_set1_epi32(args.mask as i32);
    for b in 0..batches + AHEAD {
        if b < batches {
            let base = b * 8;
            for j in 0..8 {
                let row = (base + j) * args.row_len + args.column;
                for k in 0..F {
                    d[k][j] = dfeats[row + k];
                }
            }
            let mut dv = [_mm256_setzero_ps(); F];
            for k in 0..F {
                // SAFETY: `d[k]` holds eight floats.
                dv[k] = unsafe { _mm256_loadu_ps(d[k].as_ptr()) };
            }
            let slot = b % (AHEAD + 1);
            let c = &mut ring[slot];
            c.prepare::<D, F, DENSE>(args, &inputs[base * D..(base + 8) * D], mask, fetch);
            for corner in 0..1usize << D {
                if skipped::<D>(corner, c.idle) {
                    continue;
                }
                for k in 0..F {
                    // SAFETY: each product holds eight floats.
                    unsafe {
                        _mm256_storeu_ps(prod[slot][corner][k].as_mut_ptr(), _mm256_mul_ps(c.weight[corner], dv[k]))
                    };
                }
            }
        }
        if b >= AHEAD {
            let slot = (b - AHEAD) % (AHEAD + 1);
            // SAFETY: the entries are inside `gtable` (the caller's contract).
            unsafe { add_batch::<D, F>(g, &ring[slot], &prod[slot]) };
        }
    }
    full
}

/// How many batches of eight points ahead the encoding fetches table entries into the cache.
const AHEAD: usize = 2;

/// One batch of eight points at one level: every corner's trilinear weights and table entry
/// (its first value's index, `F` values per entry), and which corners are idle.
#[derive(Clone, Copy)]
struct Corners {
    weight: [__m256; 16],
    entry: [__m256i; 16],
    idle: (bool, bool),
}

impl Corners {
    /// Zero weights and entries: a ring's slots before their first batch.
    // SAFETY: all-zero bits are a valid `__m256` and `__m256i` (eight 0.0 floats, eight zeros).
    const EMPTY: Corners = Corners {
        weight: [unsafe { std::mem::zeroed() }; 16],
        entry: [unsafe { std::mem::zeroed() }; 16],
        idle: (false, false),
    };

    /// Computes the corners of the eight points `points` (`8 × D`) and fetches their entries of
    /// `table` (the level's table or its gradient) into the cache.
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    fn prepare<const D: usize, const F: usize, const DENSE: bool>(
        &mut self,
        args: &LevelArgs<'_>,
        points: &[f32],
        mask: __m256i,
        table: Option<*const f32>,
    ) {
        let (w, part) = axes::<D, DENSE>(args, points);
        self.idle = idle_time_corners::<D>(&w);
        let mut at = [0u32; 8];
        for corner in 0..1usize << D {
            if skipped::<D>(corner, self.idle) {
                continue;
            }
            let (wc, idx) = corner_of::<D, DENSE>(&w, &part, corner, mask);
            let idx = _mm256_mullo_epi32(idx, _mm256_set1_epi32(F as i32));
            self.weight[corner] = wc;
            self.entry[corner] = idx;
            if let Some(table) = table {
                // SAFETY: `at` holds eight values.
                unsafe { _mm256_storeu_si256(at.as_mut_ptr() as *mut __m256i, idx) };
                for &e in &at {
                    // A prefetch reads nothing; the address is an entry of the table.
                    _mm_prefetch::<_MM_HINT_T0>(table.wrapping_add(e as usize) as *const i8);
                }
            }
        }
    }
}

/// Adds one batch's products into the gradient table at `g`: point by point, corner by
/// corner, each product added once (the scalar loop's order).
///
/// # Safety
/// Every entry of `c` and the `F` values from it must lie inside the table at `g`.
#[inline(always)]
unsafe fn add_batch<const D: usize, const F: usize>(g: *mut f32, c: &Corners, prod: &[[[f32; 8]; F]; 16]) {
    let mut at = [[0u32; 8]; 16];
    for (corner, at) in at.iter_mut().enumerate().take(1 << D) {
        if !skipped::<D>(corner, c.idle) {
            // SAFETY: `at` holds eight values.
            unsafe { _mm256_storeu_si256(at.as_mut_ptr() as *mut __m256i, c.entry[corner]) };
        }
    }
    for j in 0..8 {
        for corner in 0..1usize << D {
            if skipped::<D>(corner, c.idle) {
                continue;
            }
            let e = at[corner][j] as usize;
            for k in 0..F {
                // SAFETY: inside the table (the caller's contract).
                unsafe { *g.add(e + k) += prod[corner][k][j] };
            }
        }
    }
}

/// For a 4D level: whether every one of the eight points has time weight exactly 0 at the
/// upper time vertex (`.0`: the corners with bit 3 set contribute nothing) or at the lower one
/// (`.1`). Points on a frame's time vertex — every training sample of a space–time grid — skip
/// half the corners; a zero weight adds exactly nothing, so skipping changes no result.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn idle_time_corners<const D: usize>(w: &[[__m256; 2]; 4]) -> (bool, bool) {
    if D < 4 {
        return (false, false);
    }
    let zero = _mm256_setzero_ps();
    let all_zero = |v: __m256| _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(v, zero)) == 0xFF;
    (all_zero(w[3][1]), all_zero(w[3][0]))
}

/// Whether `corner` is one [`idle_time_corners`] found idle.
#[inline(always)]
fn skipped<const D: usize>(corner: usize, idle: (bool, bool)) -> bool {
    D == 4 && if (corner >> 3) & 1 == 1 { idle.0 } else { idle.1 }
}

/// The trilinear weight and the table entry of vertex `corner` (bit `a` = upper along axis `a`)
/// for eight points: weights multiplied in axis order, indices summed (dense) or hashed.
#[target_feature(enable = "avx2,fma")]
#[inline]
fn corner_of<const D: usize, const DENSE: bool>(
    w: &[[__m256; 2]; 4],
    part: &[[__m256i; 2]; 4],
    corner: usize,
    mask: __m256i,
) -> (__m256, __m256i) {
    let mut wc = _mm256_set1_ps(1.0);
    let mut key = _mm256_setzero_si256();
    for a in 0..D {
        let bit = (corner >> a) & 1;
        wc = _mm256_mul_ps(wc, w[a][bit]);
        key = if DENSE { _mm256_add_epi32(key, part[a][bit]) } else { _mm256_xor_si256(key, part[a][bit]) };
    }
    (wc, if DENSE { key } else { _mm256_and_si256(key, mask) })
}
