//! The hash grid's decoder (a ReLU network of width 64 without a skip) with its products in
//! bfloat16, on CPUs with AVX-512 BF16 where it pays ([`bf16_pays`]).
//!
//! `vdpbf16ps` multiplies pairs of bfloat16 values and adds both products to one f32 lane: 32
//! multiply–adds per instruction where an f32 FMA does 16. Every matrix product of the
//! decoder takes its operands rounded to bfloat16 (8 bits of mantissa) and accumulates in
//! f32, as mixed-precision training does on GPUs; the biases, activations, ReLU masks, the
//! output layer, the gradients' sums and Adam stay in f32.
//!
//! Layouts (`u16` holds a bfloat16, "pairs" are two values one `vdpbf16ps` lane takes):
//! - a product `out[p][:] = Σ_k in[p][k] W[k][:]` takes `in`'s rows in bfloat16 (the pair
//!   `(in[p][2k'], in[p][2k' + 1])` broadcast) and `W` packed as `[k'][j][2]`;
//! - a weight gradient `dW[k][j] = Σ_p in[p][k] dz[p][j]` pairs consecutive rows: `in` packed
//!   as `[p'][k][2]` gives the lanes over `k`, `dz` packed as `[p'][j][2]` the broadcast pair,
//!   so it accumulates `dWᵀ` (rows `j`, lanes `k`) over the chunk and adds it transposed.
//!
//! Rows are handled `P` at a time in the products (forward and `∂z Wᵀ`) and in blocks of
//! [`BLOCK`] for the gradients; the last tile or block is padded with zero rows.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::Mlp;

/// The width the passes are written for.
const WIDTH: usize = 64;
/// Rows per tile of the products: 6 rows × 4 vectors of accumulators.
const P: usize = 6;
/// Rows per block of the backward pass (even: its rows are paired).
const BLOCK: usize = 48;

/// Whether the running CPU has AVX-512 with BF16.
pub(super) fn cpu_has_bf16() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the products pay here: AMD's Zen 4 and Zen 5 execute `vdpbf16ps` at twice the
/// multiply–adds of an f32 FMA, where Intel's cores (Sapphire Rapids measured) execute it on
/// one port against FMAs on two, the same multiply–adds, so the conversions to bfloat16 made
/// the step slower there (7.0 s against 6.5 s in f32 for 150 iterations of the demo scene).
/// Intel's CPUs with AMX take the products on its tiles instead ([`super::amx`]). A rule by
/// vendor and instruction set rather than a timing at start-up, so that a configuration gives
/// the same arithmetic on every run of a machine. Read once: `cpuid` traps to the hypervisor
/// in a virtual machine, and inference asks for every chunk of points.
pub(super) fn bf16_pays() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static PAYS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *PAYS.get_or_init(|| {
            // CPUID leaf 0 (the vendor) exists on every x86-64 CPU.
            let id = std::arch::x86_64::__cpuid(0);
            let amd = (id.ebx, id.edx, id.ecx) == (0x6874_7541, 0x6974_6e65, 0x444d_4163); // "AuthenticAMD"
            (amd && cpu_has_bf16()) || amx_ready()
        })
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the products run on AMX tiles ([`super::amx`]): where the CPU and the kernel allow.
fn amx_ready() -> bool {
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    {
        super::amx::ready()
    }
    #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
    {
        false
    }
}

#[cfg(test)]
thread_local! {
    /// Tests of the AVX-512 kernels on a CPU that has AMX.
    static WITHOUT_AMX: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Whether this pass takes the AMX products.
fn use_amx() -> bool {
    #[cfg(test)]
    if WITHOUT_AMX.with(|w| w.get()) {
        return false;
    }
    amx_ready()
}

/// Whether `mlp`'s shape is the one these passes are written for.
pub(super) fn fits(mlp: &Mlp) -> bool {
    super::tile64::fits(mlp)
}

/// `k` rounded up to whole vectors of 16.
fn padded(k: usize) -> usize {
    k.div_ceil(16) * 16
}

/// Scratch of the passes, kept in the tape between calls.
#[derive(Debug, Default)]
pub(super) struct Scratch {
    /// Every layer's weights packed for the forward products, `[k'][64][2]`.
    w_fwd: Vec<u16>,
    /// Every layer's `Wᵀ` packed for `∂z Wᵀ`, `[j'][k][2]` (`k` padded to 16).
    w_bwd: Vec<u16>,
    /// `dWᵀ` of every layer, accumulated over the chunk (`64 × k_pad` each).
    dwt: Vec<f32>,
    /// The bias gradients of every layer.
    db: Vec<f32>,
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::*;

    /// Sixteen f32 to bfloat16 (round to nearest even).
    #[inline(always)]
    unsafe fn bf16x16(v: __m512) -> __m256i {
        // SAFETY: __m256bh and __m256i are both 256 bits of plain data.
        unsafe { std::mem::transmute::<__m256bh, __m256i>(_mm512_cvtneps_pbh(v)) }
    }

    /// The index that interleaves the low and high halves of a vector of 32 words.
    #[inline(always)]
    pub(super) unsafe fn interleave_index() -> __m512i {
        let idx: [i16; 32] = std::array::from_fn(|i| ((i / 2) + 16 * (i % 2)) as i16);
        // SAFETY: `idx` holds 64 bytes.
        unsafe { _mm512_loadu_si512(idx.as_ptr().cast()) }
    }

    /// `dst[c][2]` for `c < len` (a multiple of 16) = `(a[c], b[c])` in bfloat16.
    #[inline(always)]
    pub(super) unsafe fn pair_rows(a: &[f32], b: &[f32], len: usize, dst: &mut [u16], idx: __m512i) {
        debug_assert!(a.len() >= len && b.len() >= len && dst.len() >= 2 * len && len.is_multiple_of(16));
        for c in (0..len).step_by(16) {
            // SAFETY: c + 16 ≤ len, inside `a`, `b` and (doubled) `dst`.
            unsafe {
                let lo = bf16x16(_mm512_loadu_ps(a.as_ptr().add(c)));
                let hi = bf16x16(_mm512_loadu_ps(b.as_ptr().add(c)));
                let both = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(lo), hi);
                _mm512_storeu_si512(dst.as_mut_ptr().add(2 * c).cast(), _mm512_permutexvar_epi16(idx, both));
            }
        }
    }

    /// `dst[j][q] = src[q][j]` for the 64 columns `j` of `src` (rows of 64 units) and `q <
    /// all` (a multiple of 8, at most 24; `dst` rows of 24), zero for `q ≥ pairs`: sixteen
    /// rows of a column gathered at once. For the AMX passes.
    #[cfg(target_os = "linux")]
    #[inline(always)]
    pub(super) unsafe fn transpose_pairs(src: &[u32], pairs: usize, all: usize, dst: &mut [u32]) {
        const ROW: usize = BLOCK / 2;
        debug_assert!(pairs <= all && all <= ROW && all.is_multiple_of(8));
        debug_assert!(src.len() >= pairs * WIDTH && dst.len() >= WIDTH * ROW);
        // SAFETY (whole body): the gathers read rows q < pairs of `src` (masked), the stores
        // write q < all ≤ 24 of each row of `dst`.
        unsafe {
            let rows = _mm512_mullo_epi32(
                _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15),
                _mm512_set1_epi32(WIDTH as i32),
            );
            let zero = _mm512_setzero_si512();
            let (sp, dp) = (src.as_ptr(), dst.as_mut_ptr());
            for q0 in (0..all).step_by(16) {
                let valid = pairs.saturating_sub(q0).min(16);
                let read: __mmask16 = if valid == 16 { 0xffff } else { (1u16 << valid) - 1 };
                let write: __mmask16 = if all - q0 >= 16 { 0xffff } else { 0x00ff };
                let base = sp.add(q0 * WIDTH).cast::<i32>();
                for j in 0..WIDTH {
                    let idx = _mm512_add_epi32(rows, _mm512_set1_epi32(j as i32));
                    let v = _mm512_mask_i32gather_epi32::<4>(zero, read, idx, base);
                    _mm512_mask_storeu_epi32(dp.add(j * ROW + q0).cast(), write, v);
                }
            }
        }
    }

    /// A row of `len` (a multiple of 16) f32 to bfloat16.
    #[inline(always)]
    pub(super) unsafe fn row_bf16(a: &[f32], len: usize, dst: &mut [u16]) {
        debug_assert!(a.len() >= len && dst.len() >= len && len.is_multiple_of(16));
        for c in (0..len).step_by(16) {
            // SAFETY: c + 16 ≤ len, inside `a` and `dst`.
            unsafe { _mm256_storeu_si256(dst.as_mut_ptr().add(c).cast(), bf16x16(_mm512_loadu_ps(a.as_ptr().add(c)))) };
        }
    }

    /// The pair at `p` (two bfloat16) broadcast to every lane.
    #[inline(always)]
    unsafe fn pair(p: *const u16) -> __m512bh {
        // SAFETY: the caller points at two readable u16; the casts reinterpret plain bits.
        unsafe { std::mem::transmute::<__m512i, __m512bh>(_mm512_set1_epi32(p.cast::<i32>().read_unaligned())) }
    }

    #[inline(always)]
    unsafe fn load_bh(p: *const u16) -> __m512bh {
        // SAFETY: the caller points at 32 readable u16.
        unsafe { std::mem::transmute::<__m512i, __m512bh>(_mm512_loadu_si512(p.cast())) }
    }

    /// `out[p][c·16 ..] = [relu](bias + Σ_k' in[p][k'] · w[k'])` for `P` rows and `NC` vectors
    /// of columns: `inp` is `P` rows of `k_pad` bfloat16 (row stride `k_pad`), `w` is
    /// `[k_pad / 2][16 NC][2]`. Writes `rows ≤ P` rows of f32 to `out` (row stride `os`) and,
    /// with `outb`, in bfloat16 too (row stride 16 NC).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) unsafe fn product<const NC: usize, const RELU: bool>(
        inp: &[u16],
        k_pad: usize,
        w: &[u16],
        bias: Option<&[f32]>,
        rows: usize,
        out: &mut [f32],
        os: usize,
        outb: Option<&mut [u16]>,
    ) {
        debug_assert!(inp.len() >= P * k_pad && w.len() >= k_pad * 16 * NC && rows <= P);
        debug_assert!(out.len() >= (rows.max(1) - 1) * os + 16 * NC);
        // SAFETY (whole body): the asserts above bound every pointer below.
        unsafe {
            let mut acc = [[_mm512_setzero_ps(); NC]; P];
            if let Some(b) = bias {
                for a in &mut acc {
                    for (c, v) in a.iter_mut().enumerate() {
                        *v = _mm512_loadu_ps(b.as_ptr().add(16 * c));
                    }
                }
            }
            let (ip, wp) = (inp.as_ptr(), w.as_ptr());
            for k2 in 0..k_pad / 2 {
                let mut wv = [load_bh(wp); NC];
                for (c, v) in wv.iter_mut().enumerate() {
                    *v = load_bh(wp.add((k2 * 16 * NC + 16 * c) * 2));
                }
                for (p, a) in acc.iter_mut().enumerate() {
                    let x = pair(ip.add(p * k_pad + 2 * k2));
                    for c in 0..NC {
                        a[c] = _mm512_dpbf16_ps(a[c], wv[c], x);
                    }
                }
            }
            let zero = _mm512_setzero_ps();
            let mut outb = outb;
            for (p, a) in acc.iter().enumerate().take(rows) {
                for (c, &v) in a.iter().enumerate() {
                    let v = if RELU { _mm512_max_ps(v, zero) } else { v };
                    _mm512_storeu_ps(out.as_mut_ptr().add(p * os + 16 * c), v);
                    if let Some(ob) = outb.as_deref_mut() {
                        _mm256_storeu_si256(ob.as_mut_ptr().add(p * 16 * NC + 16 * c).cast(), bf16x16(v));
                    }
                }
            }
        }
    }

    /// `dwt[j][k] += Σ_p' dz[p'][j][2] · inp[p'][k][2]` over `pairs` row pairs: `dwt` is
    /// `64 × k_pad`, `inp` `[pairs][k_pad][2]`, `dz` `[pairs][64][2]`.
    #[inline(always)]
    pub(super) unsafe fn rank<const NK: usize>(dwt: &mut [f32], inp: &[u16], dz: &[u16], pairs: usize) {
        let k_pad = 16 * NK;
        debug_assert!(dwt.len() >= WIDTH * k_pad && inp.len() >= pairs * 2 * k_pad && dz.len() >= pairs * 2 * WIDTH);
        const R: usize = 4;
        // SAFETY (whole body): the assert above bounds every pointer below.
        unsafe {
            let (ip, dp, op) = (inp.as_ptr(), dz.as_ptr(), dwt.as_mut_ptr());
            for j0 in (0..WIDTH).step_by(R) {
                let mut acc = [[_mm512_setzero_ps(); NK]; R];
                for (r, a) in acc.iter_mut().enumerate() {
                    for (c, v) in a.iter_mut().enumerate() {
                        *v = _mm512_loadu_ps(op.add((j0 + r) * k_pad + 16 * c));
                    }
                }
                for q in 0..pairs {
                    let mut hv = [load_bh(ip); NK];
                    for (c, v) in hv.iter_mut().enumerate() {
                        *v = load_bh(ip.add((q * k_pad + 16 * c) * 2));
                    }
                    for (r, a) in acc.iter_mut().enumerate() {
                        let d = pair(dp.add((q * WIDTH + j0 + r) * 2));
                        for c in 0..NK {
                            a[c] = _mm512_dpbf16_ps(a[c], hv[c], d);
                        }
                    }
                }
                for (r, a) in acc.iter().enumerate() {
                    for (c, &v) in a.iter().enumerate() {
                        _mm512_storeu_ps(op.add((j0 + r) * k_pad + 16 * c), v);
                    }
                }
            }
        }
    }

    /// `max(a, 0)` of a row of 64 in bfloat16: [`row_bf16`] of the row's ReLU.
    pub(super) unsafe fn relu_row_bf16(a: &[f32], dst: &mut [u16]) {
        debug_assert!(a.len() >= WIDTH && dst.len() >= WIDTH);
        // SAFETY: both hold 64 values.
        unsafe {
            let zero = _mm512_setzero_ps();
            for c in (0..WIDTH).step_by(16) {
                let v = _mm512_max_ps(_mm512_loadu_ps(a.as_ptr().add(c)), zero);
                _mm256_storeu_si256(dst.as_mut_ptr().add(c).cast(), bf16x16(v));
            }
        }
    }

    /// `Σ_j h[j] w[j]` over 64 values, of `max(h[j], 0)` with `RELU`.
    #[inline(always)]
    pub(super) unsafe fn dot64<const RELU: bool>(h: &[f32], w: &[f32]) -> f32 {
        debug_assert!(h.len() >= WIDTH && w.len() >= WIDTH);
        // SAFETY: both hold 64 values.
        unsafe {
            let (hp, wp, zero) = (h.as_ptr(), w.as_ptr(), _mm512_setzero_ps());
            let at = |c: usize| {
                let v = _mm512_loadu_ps(hp.add(16 * c));
                if RELU {
                    _mm512_max_ps(v, zero)
                } else {
                    v
                }
            };
            let mut acc = _mm512_mul_ps(at(0), _mm512_loadu_ps(wp));
            for c in 1..WIDTH / 16 {
                acc = _mm512_fmadd_ps(at(c), _mm512_loadu_ps(wp.add(16 * c)), acc);
            }
            _mm512_reduce_add_ps(acc)
        }
    }

    /// `d[p] = d[p] [a[p] > 0]` for `rows` rows of 64 (`d` and `a` row stride 64), adding
    /// every row into `db`.
    #[inline(always)]
    pub(super) unsafe fn relu_mask(d: &mut [f32], a: &[f32], rows: usize, db: &mut [f32]) {
        debug_assert!(d.len() >= rows * WIDTH && a.len() >= rows * WIDTH && db.len() >= WIDTH);
        // SAFETY: the assert bounds every pointer.
        unsafe {
            let (dp, ap) = (d.as_mut_ptr(), a.as_ptr());
            let zero = _mm512_setzero_ps();
            let mut acc = [zero; WIDTH / 16];
            for (c, v) in acc.iter_mut().enumerate() {
                *v = _mm512_loadu_ps(db.as_ptr().add(16 * c));
            }
            for p in 0..rows {
                for (c, v) in acc.iter_mut().enumerate() {
                    let o = p * WIDTH + 16 * c;
                    let m = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(_mm512_loadu_ps(ap.add(o)), zero);
                    let x = _mm512_maskz_mov_ps(m, _mm512_loadu_ps(dp.add(o)));
                    _mm512_storeu_ps(dp.add(o), x);
                    *v = _mm512_add_ps(*v, x);
                }
            }
            for (c, v) in acc.iter().enumerate() {
                _mm512_storeu_ps(db.as_mut_ptr().add(16 * c), *v);
            }
        }
    }

    /// The output layer's backward pass for `rows` rows: `d[p] = g[p] w` (rows of 64) and
    /// `dw += Σ_p g[p] h[p]`; rows from `g.len()` on get `d = 0`.
    #[inline(always)]
    pub(super) unsafe fn output_backward(g: &[f32], h: &[f32], w: &[f32], rows: usize, d: &mut [f32], dw: &mut [f32]) {
        debug_assert!(h.len() >= g.len() * WIDTH && w.len() >= WIDTH && d.len() >= rows * WIDTH && dw.len() >= WIDTH);
        // SAFETY: the assert bounds every pointer.
        unsafe {
            let (hp, dp) = (h.as_ptr(), d.as_mut_ptr());
            let mut wv = [_mm512_setzero_ps(); WIDTH / 16];
            let mut acc = wv;
            for c in 0..WIDTH / 16 {
                wv[c] = _mm512_loadu_ps(w.as_ptr().add(16 * c));
                acc[c] = _mm512_loadu_ps(dw.as_ptr().add(16 * c));
            }
            for p in 0..rows {
                let gp = _mm512_set1_ps(g.get(p).copied().unwrap_or(0.0));
                for c in 0..WIDTH / 16 {
                    _mm512_storeu_ps(dp.add(p * WIDTH + 16 * c), _mm512_mul_ps(gp, wv[c]));
                    if p < g.len() {
                        acc[c] = _mm512_fmadd_ps(gp, _mm512_loadu_ps(hp.add(p * WIDTH + 16 * c)), acc[c]);
                    }
                }
            }
            for (c, v) in acc.iter().enumerate() {
                _mm512_storeu_ps(dw.as_mut_ptr().add(16 * c), *v);
            }
        }
    }

    /// Packs `w` (`k × 64` row-major f32) for the forward products: `[k_pad / 2][64][2]`.
    #[inline(always)]
    pub(super) unsafe fn pack_forward(w: &[f32], k: usize, dst: &mut [u16], idx: __m512i) {
        let zero = [0f32; WIDTH];
        for k2 in 0..padded(k) / 2 {
            let row = |r: usize| if r < k { &w[r * WIDTH..(r + 1) * WIDTH] } else { &zero[..] };
            // SAFETY: rows of 64, `dst` holds k_pad / 2 blocks of 128.
            unsafe { pair_rows(row(2 * k2), row(2 * k2 + 1), WIDTH, &mut dst[k2 * 2 * WIDTH..], idx) };
        }
    }

    /// Packs `Wᵀ` of `w` (`k × 64`) for `∂z Wᵀ`: `[32][k_pad][2]`, with `t` as scratch.
    #[inline(always)]
    pub(super) unsafe fn pack_backward(w: &[f32], k: usize, dst: &mut [u16], t: &mut [f32; 2 * WIDTH], idx: __m512i) {
        let kp = padded(k);
        for j2 in 0..WIDTH / 2 {
            t.fill(0.0);
            for i in 0..k {
                t[i] = w[i * WIDTH + 2 * j2];
                t[WIDTH + i] = w[i * WIDTH + 2 * j2 + 1];
            }
            let (a, b) = t.split_at(WIDTH);
            // SAFETY: kp ≤ 64 values of each, `dst` holds 32 blocks of 2 kp.
            unsafe { pair_rows(a, b, kp, &mut dst[j2 * 2 * kp..], idx) };
        }
    }
}

/// Packs every layer's weights into `dst`, one block after another: for the forward products,
/// or transposed for `∂z Wᵀ`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn pack(mlp: &Mlp, params: &[f32], dst: &mut Vec<u16>, transposed: bool) {
    let k0 = padded(mlp.in_dim);
    let sizes = |l: usize| if l == 0 { k0 } else { WIDTH };
    dst.resize((0..mlp.layers.len()).map(|l| sizes(l) * WIDTH).sum(), 0);
    // SAFETY: AVX-512 BW is enabled on this function.
    let idx = unsafe { x86::interleave_index() };
    let mut t = [0f32; 2 * WIDTH];
    let mut off = 0;
    for (l, layer) in mlp.layers.iter().enumerate() {
        let (w, k) = (&params[layer.weight.clone()], layer.fan_in);
        let block = &mut dst[off..off + sizes(l) * WIDTH];
        // SAFETY: each block holds `padded(k) × 64` values; AVX-512 BW and BF16 are enabled.
        unsafe {
            if transposed {
                x86::pack_backward(w, k, block, &mut t, idx);
            } else {
                x86::pack_forward(w, k, block, idx);
            }
        }
        off += sizes(l) * WIDTH;
    }
}

/// The rows `rows` of `x` (rows of `k0` values) in bfloat16 into `xin`, each padded with
/// zeros to `padded(k0)` values.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn input_rows(x: &[f32], k0: usize, rows: std::ops::Range<usize>, xin: &mut [u16]) {
    let kp0 = padded(k0);
    let mut row = [0f32; WIDTH];
    for (p, r) in rows.enumerate() {
        let src = &x[r * k0..(r + 1) * k0];
        let src = if k0 == kp0 {
            src
        } else {
            row[..k0].copy_from_slice(src);
            &row[..kp0]
        };
        // SAFETY: kp0 ≤ 64 values; the features are enabled here.
        unsafe { x86::row_bf16(src, kp0, &mut xin[p * kp0..]) };
    }
}

/// The forward pass: every layer's activations into `acts` (`D × stride`, rows of 64) and the
/// output's pre-activation into `pre_out`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn forward_v4(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    acts: &mut [f32],
    stride: usize,
    pre_out: &mut [f32],
    s: &mut Scratch,
) {
    // SAFETY: the target features are enabled on this function.
    unsafe { tiles_v4(mlp, params, x, Some((acts, stride)), pre_out, s) }
}

/// Inference with the products of [`forward_v4`], one tile of `P` rows at a time kept in L1:
/// the output's pre-activation of the `n = pre_out.len()` rows of `x`, equal bit for bit to
/// what [`forward_v4`] computes for them (the same products, summed in the same order).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn infer_v4(mlp: &Mlp, params: &[f32], x: &[f32], pre_out: &mut [f32], s: &mut Scratch) {
    // SAFETY: the target features are enabled on this function.
    unsafe { tiles_v4(mlp, params, x, None, pre_out, s) }
}

/// The products of the forward pass, `P` rows at a time through every layer: each layer's
/// activations into `acts` (`D × stride`, rows of 64) when given, else into one tile kept in
/// L1, and the output's pre-activation into `pre_out`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn tiles_v4(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    mut acts: Option<(&mut [f32], usize)>,
    pre_out: &mut [f32],
    s: &mut Scratch,
) {
    let n = pre_out.len();
    let (k0, kp0) = (mlp.in_dim, padded(mlp.in_dim));
    // SAFETY: the target features are enabled on this function.
    unsafe { pack(mlp, params, &mut s.w_fwd, false) };
    let depth = mlp.layers.len();
    let mut xin = [0u16; P * WIDTH];
    let (mut hb, mut nb) = ([0u16; P * WIDTH], [0u16; P * WIDTH]);
    let mut tile = [0f32; P * WIDTH];
    let (w_out, b_out) = (&params[mlp.out_weight.clone()], params[mlp.out_bias]);
    let mut r = 0;
    while r < n {
        let rows = (n - r).min(P);
        if rows < P {
            xin.fill(0);
        }
        // SAFETY: the features are enabled here.
        unsafe { input_rows(x, k0, r..r + rows, &mut xin) };
        let mut off = 0;
        for (l, layer) in mlp.layers.iter().enumerate() {
            let (k_pad, inp): (usize, &[u16]) = if l == 0 { (kp0, &xin) } else { (WIDTH, &hb) };
            let n_w = k_pad * WIDTH;
            let out: &mut [f32] = match &mut acts {
                Some((a, stride)) => &mut a[l * *stride + r * WIDTH..l * *stride + (r + rows) * WIDTH],
                None => &mut tile[..],
            };
            // SAFETY: `inp` holds P rows of k_pad, the packed weights k_pad × 64, `out` at least
            // `rows` rows of 64; the features are enabled here.
            unsafe {
                x86::product::<4, true>(
                    inp,
                    k_pad,
                    &s.w_fwd[off..off + n_w],
                    Some(&params[layer.bias.clone()]),
                    rows,
                    out,
                    WIDTH,
                    (l + 1 < depth).then_some(&mut nb[..]),
                )
            };
            if l + 1 == depth {
                for (p, o) in pre_out[r..r + rows].iter_mut().enumerate() {
                    // SAFETY: rows of 64; features enabled.
                    *o = b_out + unsafe { x86::dot64::<false>(&out[p * WIDTH..], w_out) };
                }
            }
            std::mem::swap(&mut hb, &mut nb);
            off += n_w;
        }
        r += rows;
    }
}

/// [`tiles_v4`] with the products on AMX tiles, 16 rows at a time: each layer's activations
/// into `acts` (`D × stride`, rows of 64) when given (the forward pass of training), else into
/// one tile of 16 rows kept in L1 (inference), and the output's pre-activation into `pre_out`.
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn tiles_amx(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    mut acts: Option<(&mut [f32], usize)>,
    pre_out: &mut [f32],
    s: &mut Scratch,
) {
    use super::amx::{self, ROWS};
    let n = pre_out.len();
    let (k0, kp0) = (mlp.in_dim, padded(mlp.in_dim));
    // SAFETY: the target features are enabled on this function.
    unsafe { pack(mlp, params, &mut s.w_fwd, false) };
    let depth = mlp.layers.len();
    let mut xin = [0u16; ROWS * WIDTH];
    let mut hb = [0u16; ROWS * WIDTH];
    let mut sums = [0f32; ROWS * WIDTH];
    let (w_out, b_out) = (&params[mlp.out_weight.clone()], params[mlp.out_bias]);
    // SAFETY: the caller checked AMX (`use_amx`).
    unsafe { amx::configure() };
    let mut r = 0;
    while r < n {
        // Rows past `rows` in the last block hold zeros or an earlier block's values; each
        // output row depends on its own input row only, and those are not written.
        let rows = (n - r).min(ROWS);
        if rows < ROWS {
            xin.fill(0);
        }
        // SAFETY: the features are enabled here.
        unsafe { input_rows(x, k0, r..r + rows, &mut xin) };
        let mut off = 0;
        for l in 0..depth {
            let layer = &mlp.layers[l];
            let (k_pad, inp): (usize, &[u16]) = if l == 0 { (kp0, &xin) } else { (WIDTH, &hb) };
            let n_w = k_pad * WIDTH;
            // SAFETY: `inp` holds 16 rows of k_pad, the packed weights k_pad × 64, `sums` 16
            // rows of 64; the tiles are configured.
            unsafe {
                amx::product::<4>(inp, k_pad, &s.w_fwd[off..off + n_w], Some(&params[layer.bias.clone()]), &mut sums)
            };
            let mut out =
                acts.as_mut().map(|(a, stride)| &mut a[l * *stride + r * WIDTH..l * *stride + (r + rows) * WIDTH]);
            // The ReLU; the next layer's input in bfloat16, or the output's product after the
            // last layer (whose activations need no bfloat16 copy).
            let last = l + 1 == depth;
            for p in 0..rows {
                let sum = &sums[p * WIDTH..(p + 1) * WIDTH];
                match out.as_deref_mut() {
                    Some(out) => {
                        let o = &mut out[p * WIDTH..(p + 1) * WIDTH];
                        for (o, &v) in o.iter_mut().zip(sum) {
                            *o = v.max(0.0);
                        }
                        // SAFETY: rows of 64; features enabled.
                        unsafe {
                            if last {
                                pre_out[r + p] = b_out + x86::dot64::<false>(o, w_out);
                            } else {
                                x86::row_bf16(o, WIDTH, &mut hb[p * WIDTH..]);
                            }
                        }
                    }
                    // Inference keeps no activations: the ReLU is applied on the way.
                    // SAFETY: rows of 64; features enabled.
                    None => unsafe {
                        if last {
                            pre_out[r + p] = b_out + x86::dot64::<true>(sum, w_out);
                        } else {
                            x86::relu_row_bf16(sum, &mut hb[p * WIDTH..]);
                        }
                    },
                }
            }
            off += n_w;
        }
        r += rows;
    }
    // SAFETY: configured above.
    unsafe { amx::release() };
}

/// The backward pass after [`forward_v4`] on the same rows, given `g = ∂L/∂(output
/// pre-activation)`: adds the gradients into `grads` and writes `∂L/∂x` into `d_x`.
#[allow(clippy::too_many_arguments)]
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
unsafe fn backward_v4(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    acts: &[f32],
    stride: usize,
    g: &[f32],
    s: &mut Scratch,
    grads: &mut [f32],
    d_x: Option<&mut [f32]>,
    amx: bool,
) {
    let n = g.len();
    let depth = mlp.layers.len();
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    let mut sums = [0f32; 16 * WIDTH];
    if amx {
        #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
        // SAFETY: the caller checked AMX (`use_amx`).
        unsafe {
            super::amx::configure()
        };
    }
    let (k0, kp0) = (mlp.in_dim, padded(mlp.in_dim));
    // SAFETY: the target features are enabled on this function.
    unsafe { pack(mlp, params, &mut s.w_bwd, true) };
    let k_of = |l: usize| if l == 0 { kp0 } else { WIDTH };
    let w_off = |l: usize| if l == 0 { 0 } else { kp0 * WIDTH + (l - 1) * WIDTH * WIDTH };
    let total: usize = (0..depth).map(|l| k_of(l) * WIDTH).sum();
    s.dwt.clear();
    s.dwt.resize(total, 0.0);
    s.db.clear();
    s.db.resize(depth * WIDTH, 0.0);
    // SAFETY: AVX-512 BW is enabled here.
    let idx = unsafe { x86::interleave_index() };
    let w_out = &params[mlp.out_weight.clone()];
    let mut d_out_w = [0f32; WIDTH];
    let mut da = [0f32; BLOCK * WIDTH];
    let mut next = [0f32; BLOCK * WIDTH];
    let mut dzb = [0u16; (BLOCK + P) * WIDTH];
    // Pairs of bfloat16 are read as 32-bit units below: storage of u32.
    let mut dzp_store = [0u32; BLOCK * WIDTH / 2];
    let dzp: &mut [u16] = bytemuck::cast_slice_mut(&mut dzp_store[..]);
    let mut inp = [0u16; BLOCK * WIDTH];
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    let mut dzt_store = [0u32; WIDTH * BLOCK / 2];
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    let dzt: &mut [u16] = bytemuck::cast_slice_mut(&mut dzt_store[..]);
    let mut o_tmp = [0f32; P * WIDTH];
    let zero = [0f32; WIDTH];
    let mut xrow = [[0f32; WIDTH]; 2];
    let mut d_x = d_x;
    let mut r = 0;
    while r < n {
        let b = (n - r).min(BLOCK);
        let b2 = b.div_ceil(2) * 2;
        let last = (depth - 1) * stride;
        let h = &acts[last + r * WIDTH..last + (r + b) * WIDTH];
        // SAFETY: `g[r..r + b]` with b rows of 64 in `h`, b2 ≤ BLOCK rows in `da`; features
        // enabled.
        unsafe { x86::output_backward(&g[r..r + b], h, w_out, b2, &mut da, &mut d_out_w) };
        for l in (0..depth).rev() {
            // ∂z = ∂a [a > 0], ∂b += Σ ∂z.
            let db = &mut s.db[l * WIDTH..(l + 1) * WIDTH];
            let a = &acts[l * stride + r * WIDTH..l * stride + (r + b) * WIDTH];
            // SAFETY: `da` and `a` hold b rows of 64; features enabled.
            unsafe { x86::relu_mask(&mut da, a, b, db) };
            // ∂W: the rows of ∂z and of the layer's input paired.
            let k_pad = k_of(l);
            for q in 0..b2 / 2 {
                let (p0, p1) = (2 * q, 2 * q + 1);
                // SAFETY: rows of 64 and blocks of 128 inside the buffers; features enabled.
                unsafe {
                    x86::pair_rows(&da[p0 * WIDTH..], &da[p1 * WIDTH..], WIDTH, &mut dzp[q * 2 * WIDTH..], idx);
                    if l == 0 && k0 == kp0 {
                        let row = |p: usize| if p < b { &x[(r + p) * k0..(r + p + 1) * k0] } else { &zero[..k0] };
                        x86::pair_rows(row(p0), row(p1), kp0, &mut inp[q * 2 * kp0..], idx);
                    } else if l == 0 {
                        for (t, p) in [p0, p1].into_iter().enumerate() {
                            xrow[t][..kp0].fill(0.0);
                            if p < b {
                                xrow[t][..k0].copy_from_slice(&x[(r + p) * k0..(r + p + 1) * k0]);
                            }
                        }
                        x86::pair_rows(&xrow[0], &xrow[1], kp0, &mut inp[q * 2 * kp0..], idx);
                    } else {
                        let below = (l - 1) * stride;
                        let row = |p: usize| {
                            if p < b {
                                &acts[below + (r + p) * WIDTH..below + (r + p + 1) * WIDTH]
                            } else {
                                &zero[..]
                            }
                        };
                        x86::pair_rows(row(p0), row(p1), WIDTH, &mut inp[q * 2 * WIDTH..], idx);
                    }
                }
            }
            let dwt = &mut s.dwt[w_off(l)..w_off(l) + k_pad * WIDTH];
            #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
            if amx {
                // The pairs of ∂z rows transposed (a pair is one 32-bit unit): the tiles' A
                // operand, rows j of p_len / 2 pairs, zero past the block's pairs.
                let p_len = b.div_ceil(16) * 16;
                let (pairs, all) = (b2 / 2, p_len / 2);
                let src: &[u32] = bytemuck::cast_slice(&dzp[..]);
                let dst: &mut [u32] = bytemuck::cast_slice_mut(&mut dzt[..]);
                // SAFETY: `src` holds 24 pairs of rows of 64 units and `dst` 64 rows of 24;
                // `all` ≤ 24 and `pairs` ≤ `all`; features enabled.
                unsafe { x86::transpose_pairs(src, pairs, all, dst) };
                // SAFETY: `dwt` is 64 × k_pad, `dzt` 64 × 48, `inp` holds p_len / 2 pairs of
                // rows of k_pad (those past b2 / 2 meet zeros); the tiles are configured.
                unsafe {
                    match k_pad {
                        16 => super::amx::rank::<1>(dwt, dzt, &inp, p_len),
                        32 => super::amx::rank::<2>(dwt, dzt, &inp, p_len),
                        48 => super::amx::rank::<3>(dwt, dzt, &inp, p_len),
                        _ => super::amx::rank::<4>(dwt, dzt, &inp, p_len),
                    }
                }
            }
            // SAFETY: `dwt` is 64 × k_pad, `inp` and `dzp` hold b2 / 2 pairs; features enabled.
            if !amx {
                unsafe {
                    match k_pad {
                        16 => x86::rank::<1>(dwt, &inp, dzp, b2 / 2),
                        32 => x86::rank::<2>(dwt, &inp, dzp, b2 / 2),
                        48 => x86::rank::<3>(dwt, &inp, dzp, b2 / 2),
                        _ => x86::rank::<4>(dwt, &inp, dzp, b2 / 2),
                    }
                }
            }
            // ∂(layer input) = ∂z Wᵀ.
            if l > 0 || d_x.is_some() {
                for p in 0..b {
                    // SAFETY: a row of 64; features enabled.
                    unsafe { x86::row_bf16(&da[p * WIDTH..], WIDTH, &mut dzb[p * WIDTH..]) };
                }
                let wb = &s.w_bwd[w_off(l)..w_off(l) + k_pad * WIDTH];
                #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
                if amx {
                    use super::amx::{self, ROWS};
                    let mut q = 0;
                    while q < b {
                        let rows = (b - q).min(ROWS);
                        // Rows past `b` hold an earlier block's values; their sums are not read.
                        let tile = &dzb[q * WIDTH..(q + ROWS) * WIDTH];
                        // SAFETY: the tile holds 16 rows of 64 (q + 16 ≤ BLOCK), `wb` is
                        // [32][k_pad][2], `sums` 16 rows of 64; the tiles are configured.
                        unsafe {
                            match k_pad {
                                64 => amx::product::<4>(tile, WIDTH, wb, None, &mut sums),
                                48 => amx::product::<3>(tile, WIDTH, wb, None, &mut sums),
                                32 => amx::product::<2>(tile, WIDTH, wb, None, &mut sums),
                                _ => amx::product::<1>(tile, WIDTH, wb, None, &mut sums),
                            }
                        }
                        for p in 0..rows {
                            let src = &sums[p * WIDTH..];
                            if l > 0 {
                                next[(q + p) * WIDTH..(q + p + 1) * WIDTH].copy_from_slice(&src[..WIDTH]);
                            } else {
                                let dx = d_x.as_deref_mut().expect("d_x wanted");
                                dx[(r + q + p) * k0..(r + q + p + 1) * k0].copy_from_slice(&src[..k0]);
                            }
                        }
                        q += rows;
                    }
                    if l > 0 {
                        next[b * WIDTH..b2 * WIDTH].fill(0.0);
                        std::mem::swap(&mut da, &mut next);
                    }
                    continue;
                }
                let direct = l > 0 || k0 == kp0;
                let mut q = 0;
                while q < b {
                    let rows = (b - q).min(P);
                    let tile = &dzb[q * WIDTH..(q + P) * WIDTH];
                    let (o, os): (&mut [f32], usize) = if l > 0 {
                        (&mut next[q * WIDTH..], WIDTH)
                    } else if direct {
                        let dx = d_x.as_deref_mut().expect("d_x wanted");
                        (&mut dx[(r + q) * k0..], k0)
                    } else {
                        (&mut o_tmp[..], WIDTH)
                    };
                    // SAFETY: the tile holds P rows of 64 (`dzb` has P rows to spare), `wb` is
                    // [32][k_pad][2], `o` holds `rows` rows of stride `os` ≥ k_pad; features
                    // enabled.
                    unsafe {
                        match k_pad {
                            64 => x86::product::<4, false>(tile, WIDTH, wb, None, rows, o, os, None),
                            48 => x86::product::<3, false>(tile, WIDTH, wb, None, rows, o, os, None),
                            32 => x86::product::<2, false>(tile, WIDTH, wb, None, rows, o, os, None),
                            _ => x86::product::<1, false>(tile, WIDTH, wb, None, rows, o, os, None),
                        }
                    }
                    if !direct {
                        let dx = d_x.as_deref_mut().expect("d_x wanted");
                        for p in 0..rows {
                            dx[(r + q + p) * k0..(r + q + p + 1) * k0]
                                .copy_from_slice(&o_tmp[p * WIDTH..p * WIDTH + k0]);
                        }
                    }
                    q += rows;
                }
                if l > 0 {
                    next[b * WIDTH..b2 * WIDTH].fill(0.0);
                    std::mem::swap(&mut da, &mut next);
                }
            }
        }
        r += b;
    }
    if amx {
        #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
        // SAFETY: configured above.
        unsafe {
            super::amx::release()
        };
    }
    for (j, v) in d_out_w.iter().enumerate() {
        grads[mlp.out_weight.start + j] += v;
    }
    for (l, layer) in mlp.layers.iter().enumerate() {
        let k_pad = k_of(l);
        let dwt = &s.dwt[w_off(l)..w_off(l) + k_pad * WIDTH];
        let gw = &mut grads[layer.weight.clone()];
        for k in 0..layer.fan_in {
            for j in 0..WIDTH {
                gw[k * WIDTH + j] += dwt[j * k_pad + k];
            }
        }
        for (gb, v) in grads[layer.bias.clone()].iter_mut().zip(&s.db[l * WIDTH..(l + 1) * WIDTH]) {
            *gb += v;
        }
    }
}

/// Forward pass of `mlp` over `x` (`n × in_dim`): every layer's activations into `acts`
/// (`D × stride`, rows of 64) and the output's pre-activation into `pre_out` (the caller
/// applies the output activation). Requires [`cpu_has_bf16`] and [`fits`].
pub(super) fn forward(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    acts: &mut [f32],
    stride: usize,
    pre_out: &mut [f32],
    s: &mut Scratch,
) {
    assert!(cpu_has_bf16() && fits(mlp), "bf16::forward on an unfit network or CPU");
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    if use_amx() {
        // SAFETY: the CPU features and AMX were checked just above.
        unsafe { tiles_amx(mlp, params, x, Some((acts, stride)), pre_out, s) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU features were checked just above.
    unsafe {
        forward_v4(mlp, params, x, acts, stride, pre_out, s)
    };
}

/// Inference with the products of [`forward`], on AMX tiles where training takes them there and
/// on AVX-512 BF16 elsewhere: the output's pre-activation of `n = pre_out.len()` rows of `x`
/// (the caller applies the output activation), equal bit for bit to [`forward`]'s on the same
/// path. Requires [`cpu_has_bf16`] and [`fits`].
pub(super) fn infer(mlp: &Mlp, params: &[f32], x: &[f32], pre_out: &mut [f32], s: &mut Scratch) {
    assert!(cpu_has_bf16() && fits(mlp), "bf16::infer on an unfit network or CPU");
    assert_eq!(x.len(), pre_out.len() * mlp.in_dim, "bf16::infer: input is not {}×{}", pre_out.len(), mlp.in_dim);
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    if use_amx() {
        // SAFETY: the CPU features and AMX were checked just above.
        unsafe { tiles_amx(mlp, params, x, None, pre_out, s) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU features were checked just above.
    unsafe {
        infer_v4(mlp, params, x, pre_out, s)
    };
}

/// Whether inference takes the bfloat16 products of a network trained with them: wherever
/// training takes them ([`bf16_pays`]), on AVX-512 BF16 (AMD's Zen 4 and Zen 5) or on AMX
/// tiles (Intel), as training does.
pub(super) fn infer_pays() -> bool {
    cpu_has_bf16() && bf16_pays()
}

/// Backward pass after [`forward`] with `acts`. Requires [`cpu_has_bf16`] and [`fits`].
#[allow(clippy::too_many_arguments)]
pub(super) fn backward(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    acts: &[f32],
    stride: usize,
    g: &[f32],
    s: &mut Scratch,
    grads: &mut [f32],
    d_x: Option<&mut [f32]>,
) {
    assert!(cpu_has_bf16() && fits(mlp), "bf16::backward on an unfit network or CPU");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU features were checked just above.
    unsafe {
        backward_v4(mlp, params, x, acts, stride, g, s, grads, d_x, use_amx())
    };
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::super::{Activation, Mlp, MlpTape, OutputActivation};
    use crate::kernels;

    fn relative(a: &[f32], b: &[f32]) -> f64 {
        let d: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum();
        let n: f64 = b.iter().map(|y| f64::from(*y).powi(2)).sum();
        (d / n).sqrt()
    }

    /// `v` rounded to bfloat16 (nearest, ties to even), as `vcvtneps2bf16` does.
    fn bf(v: f32) -> f32 {
        let b = v.to_bits();
        f32::from_bits((b + 0x7fff + ((b >> 16) & 1)) & 0xffff_0000)
    }

    /// The passes written out in scalar f32 with every product's operands rounded to
    /// bfloat16: (outputs, parameter gradient, input gradient).
    fn emulated(m: &Mlp, params: &[f32], x: &[f32], d_out: &[f32], n: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let w = 64;
        let mut acts: Vec<Vec<f32>> = Vec::new();
        for (l, layer) in m.layers.iter().enumerate() {
            let (inp, k) = if l == 0 { (x, m.in_dim) } else { (&acts[l - 1][..], w) };
            let (wt, b) = (&params[layer.weight.clone()], &params[layer.bias.clone()]);
            let mut h = vec![0f32; n * w];
            for p in 0..n {
                for j in 0..w {
                    let z = (0..k).fold(b[j], |s, i| s + bf(inp[p * k + i]) * bf(wt[i * w + j]));
                    h[p * w + j] = z.max(0.0);
                }
            }
            acts.push(h);
        }
        let last = acts.last().expect("a layer");
        let w_out = &params[m.out_weight.clone()];
        let pre: Vec<f32> =
            (0..n).map(|p| params[m.out_bias] + (0..w).map(|j| last[p * w + j] * w_out[j]).sum::<f32>()).collect();
        let out: Vec<f32> = pre.iter().map(|&z| kernels::softplus(z)).collect();
        let g: Vec<f32> = pre.iter().zip(d_out).map(|(&z, &d)| d * kernels::sigmoid(z)).collect();
        let mut grads = vec![0f32; m.num_params()];
        grads[m.out_bias] = g.iter().sum();
        let mut da = vec![0f32; n * w];
        for p in 0..n {
            for j in 0..w {
                da[p * w + j] = g[p] * w_out[j];
                grads[m.out_weight.start + j] += g[p] * last[p * w + j];
            }
        }
        let mut dx = vec![0f32; n * m.in_dim];
        for (l, layer) in m.layers.iter().enumerate().rev() {
            for (d, a) in da.iter_mut().zip(&acts[l]) {
                *d = if *a > 0.0 { *d } else { 0.0 };
            }
            for p in 0..n {
                for j in 0..w {
                    grads[layer.bias.start + j] += da[p * w + j];
                }
            }
            let (inp, k) = if l == 0 { (x, m.in_dim) } else { (&acts[l - 1][..], w) };
            let wt = &params[layer.weight.clone()];
            for i in 0..k {
                for j in 0..w {
                    grads[layer.weight.start + i * w + j] +=
                        (0..n).map(|p| bf(inp[p * k + i]) * bf(da[p * w + j])).sum::<f32>();
                }
            }
            let mut below = vec![0f32; n * k];
            for p in 0..n {
                for i in 0..k {
                    below[p * k + i] = (0..w).map(|j| bf(da[p * w + j]) * bf(wt[i * w + j])).sum();
                }
            }
            if l == 0 {
                dx = below;
            } else {
                da = below;
            }
        }
        (out, grads, dx)
    }

    /// The vectorised passes against the same arithmetic written out in scalar code (every
    /// product's operands rounded to bfloat16, sums in f32): equal up to the order of the
    /// sums. Row counts that fill no whole tile or block, inputs narrower than a vector and
    /// depths 1–3. Against the f32 passes the output differs by bfloat16's rounding only
    /// (the gradients also by the few ReLU units that rounding moves across zero). On a CPU
    /// without AVX-512 BF16 the request falls back to f32, bit for bit; on one where it does not
    /// pay the request gives f32 and the kernels are still tested.
    #[test]
    fn bfloat16_products_compute_the_rounded_arithmetic() {
        for (in_dim, depth, n) in [(16, 2, 101), (18, 1, 7), (32, 3, 200)] {
            let f32_net = Mlp::new(in_dim, 64, depth, Activation::Relu, OutputActivation::Softplus, false);
            assert_eq!(f32_net.clone().with_bf16_products(true).bf16_products(), super::bf16_pays());
            // The kernels wherever the CPU has them, whether or not they pay.
            let bf16_net = f32_net.clone().with_bf16_kernels();
            assert_eq!(bf16_net.bf16_products(), super::cpu_has_bf16());
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
            let mut params = vec![0.0; f32_net.num_params()];
            f32_net.init(&mut params, &mut rng);
            for layer in &f32_net.layers {
                for b in &mut params[layer.bias.clone()] {
                    *b = rng.random_range(-0.5..0.5);
                }
            }
            let x: Vec<f32> = (0..n * in_dim).map(|_| rng.random_range(-1.0..1.0)).collect();
            let d_out: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let run = |m: &Mlp| {
                let mut tape = MlpTape::default();
                let mut out = vec![0.0; n];
                m.forward(&params, &x, &mut out, &mut tape);
                let mut grads = vec![0.0; m.num_params()];
                let mut dx = vec![0.0; n * in_dim];
                m.backward(&params, &x, &mut tape, &d_out, &mut grads, Some(&mut dx));
                (out, grads, dx)
            };
            let (out, _, _) = run(&f32_net);
            if !bf16_net.bf16_products() {
                assert_eq!(run(&f32_net), run(&bf16_net), "the f32 fallback");
                continue;
            }
            let (out_e, grads_e, dx_e) = emulated(&bf16_net, &params, &x, &d_out, n);
            // The AMX tiles where the CPU has them, and the AVX-512 kernels.
            let kernels: &[bool] = if super::amx_ready() { &[false, true] } else { &[true] };
            for &without_amx in kernels {
                super::WITHOUT_AMX.with(|w| w.set(without_amx));
                let (out_b, grads_b, dx_b) = run(&bf16_net);
                super::WITHOUT_AMX.with(|w| w.set(false));
                let case = format!("{in_dim} inputs, depth {depth}, {n} rows, AMX {}", !without_amx);
                let e = relative(&out_b, &out);
                assert!(e > 1e-5 && e < 5e-3, "output against f32 ({case}): relative error {e:e}");
                for (what, a, b) in
                    [("output", &out_b, &out_e), ("gradient", &grads_b, &grads_e), ("input gradient", &dx_b, &dx_e)]
                {
                    let e = relative(a, b);
                    assert!(e < 1e-5, "{what} against the scalar bfloat16 arithmetic ({case}): relative error {e:e}");
                }
            }
        }
    }

    /// Inference takes the training pass's products: its output's pre-activation equals the
    /// forward pass's bit for bit, for every size of last tile and depths 1–3, and `Mlp::infer`
    /// takes it for a network trained in bfloat16 where it pays.
    #[test]
    fn inference_computes_what_training_did() {
        if !super::cpu_has_bf16() {
            return;
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (in_dim, depth) in [(16, 2), (18, 1), (32, 3)] {
            let net =
                Mlp::new(in_dim, 64, depth, Activation::Relu, OutputActivation::Softplus, false).with_bf16_kernels();
            let mut params = vec![0.0; net.num_params()];
            net.init(&mut params, &mut rng);
            for layer in &net.layers {
                for b in &mut params[layer.bias.clone()] {
                    *b = rng.random_range(-0.5..0.5);
                }
            }
            for n in [1, 5, 6, 7, 13, 101] {
                let x: Vec<f32> = (0..n * in_dim).map(|_| rng.random_range(-1.0..1.0)).collect();
                let (mut want, mut got) = (vec![0.0; n], vec![f32::NAN; n]);
                let mut acts = vec![0.0; depth * n * 64];
                let mut s = super::Scratch::default();
                // Both paths where the CPU has AMX (the tiles' and AVX-512 BF16's), the latter
                // alone elsewhere.
                for without_amx in [true, false] {
                    super::WITHOUT_AMX.with(|w| w.set(without_amx));
                    super::forward(&net, &params, &x, &mut acts, n * 64, &mut want, &mut s);
                    got.fill(f32::NAN);
                    super::infer(&net, &params, &x, &mut got, &mut s);
                    super::WITHOUT_AMX.with(|w| w.set(false));
                    let path = if without_amx || !super::use_amx() { "AVX-512 BF16" } else { "AMX" };
                    assert_eq!(got, want, "{path}: {in_dim} inputs, depth {depth}, {n} rows");
                }
                if super::infer_pays() {
                    let mut out = vec![0.0; n];
                    net.infer(&params, &x, &mut out, &mut MlpTape::default());
                    let soft: Vec<f32> = want.iter().map(|&z| kernels::softplus(z)).collect();
                    assert_eq!(out, soft, "Mlp::infer, {in_dim} inputs, depth {depth}, {n} rows");
                }
            }
        }
    }
}
