//! The ReLU MLPs of width 64 (the grid fields' decoders) in f32, a tile of six rows at a time
//! through every layer in registers: the tile's activations never leave L1, and no pass over
//! a whole chunk adds the bias, applies the ReLU or its mask. Used by [`Mlp::infer`], and by
//! training's [`Mlp::forward`] and [`Mlp::backward`] where the decoder's products are f32, when
//! the CPU has AVX2 and FMA (AVX-512 where it has it); the products are the same as the GEMMs',
//! summed in another order, so the results agree with the GEMM path to rounding (tested).
//!
//! Each layer's tile is `6 × 64` accumulators, started from the bias and updated by one
//! fused multiply–add per input feature and column: with AVX-512 four vectors per row (24
//! registers), with AVX2 one block of 16 columns at a time (12 registers). The input
//! features are broadcast from the previous layer's tile. The forward pass keeps each
//! layer's tile in the tape as well; the backward pass takes a tile of `∂z` down the layers
//! the same way through the transposed weights (`∂z_{l−1} = ∂z_l W_lᵀ` through layer `l − 1`'s
//! ReLU, `∂x = ∂z_0 W_0ᵀ`); the weight gradients, sums over all the chunk's rows, keep blocks
//! of six of their rows in registers while passes of 64 rows go by.

use std::ops::Range;

use super::Mlp;

/// The width the kernels are written for.
const WIDTH: usize = 64;
/// Rows per tile.
const ROWS: usize = 6;

/// Which kernel the running CPU takes, if any.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kernel {
    Avx512,
    Avx2,
}

impl Kernel {
    /// The best kernel the running CPU supports.
    pub(super) fn detect() -> Option<Kernel> {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Some(Kernel::Avx512);
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Some(Kernel::Avx2);
            }
        }
        None
    }
}

/// Whether `mlp` has the shape these kernels (and the bfloat16 passes) are written for:
/// ReLU layers of width 64 on at most 64 inputs, without a skip connection.
pub(super) fn fits(mlp: &Mlp) -> bool {
    mlp.width == WIDTH
        && mlp.in_dim <= WIDTH
        && mlp.activation == super::Activation::Relu
        && mlp.skip.is_none()
        && !mlp.layers.is_empty()
}

/// The output's pre-activation of `mlp` for the `n = pre_out.len()` rows of `x` (`n × in_dim`),
/// with `kernel`. Requires [`fits`] and a `kernel` the CPU supports ([`Kernel::detect`]).
pub(super) fn infer(mlp: &Mlp, params: &[f32], x: &[f32], pre_out: &mut [f32], kernel: Kernel) {
    tiles(mlp, params, x, None, pre_out, kernel);
}

/// [`infer`] that also keeps every layer's activations, as training's forward pass does:
/// layer `l`'s rows of 64 into `acts[l · stride ..]`. The outputs are [`infer`]'s bit for bit.
/// Requires [`fits`] and a `kernel` the CPU supports ([`Kernel::detect`]).
pub(super) fn forward(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    acts: &mut [f32],
    stride: usize,
    pre_out: &mut [f32],
    kernel: Kernel,
) {
    let n = pre_out.len();
    assert!(
        stride >= n * WIDTH && acts.len() >= (mlp.layers.len() - 1) * stride + n * WIDTH,
        "tile64::forward: acts too short"
    );
    tiles(mlp, params, x, Some((acts, stride)), pre_out, kernel);
}

/// The tiles of [`infer`] and [`forward`].
fn tiles(
    mlp: &Mlp,
    params: &[f32],
    x: &[f32],
    mut acts: Option<(&mut [f32], usize)>,
    pre_out: &mut [f32],
    kernel: Kernel,
) {
    assert!(fits(mlp), "tile64 on a network it is not written for");
    assert!(Kernel::detect().is_some_and(|k| k == kernel || kernel == Kernel::Avx2), "{kernel:?} on this CPU");
    let (n, din) = (pre_out.len(), mlp.in_dim);
    assert_eq!(x.len(), n * din, "tile64: input is not {n}×{din}");
    let w_out: &[f32; WIDTH] = params[mlp.out_weight.clone()].try_into().expect("64 output weights");
    let b_out = params[mlp.out_bias];
    // The last tile's rows, padded with zeros to a whole tile.
    let mut tail = [0f32; ROWS * WIDTH];
    let mut tiles = [[[0f32; WIDTH]; ROWS]; 2];
    for r0 in (0..n).step_by(ROWS) {
        let rows = ROWS.min(n - r0);
        let input: &[f32] = if rows == ROWS {
            &x[r0 * din..(r0 + ROWS) * din]
        } else {
            tail[..rows * din].copy_from_slice(&x[r0 * din..(r0 + rows) * din]);
            tail[rows * din..ROWS * din].fill(0.0);
            &tail[..ROWS * din]
        };
        let [a, b] = &mut tiles;
        let (mut prev, mut cur) = (a, b);
        for (l, layer) in mlp.layers.iter().enumerate() {
            let (w, bias) = (&params[layer.weight.clone()], &params[layer.bias.clone()]);
            let (inp, k) = if l == 0 { (input, din) } else { (prev.as_flattened(), WIDTH) };
            match kernel {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: the CPU supports the kernel (asserted above); `inp` holds ROWS rows of
                // `k` features, `w` `k × 64` weights and `bias` 64.
                Kernel::Avx512 => unsafe { layer_avx512(inp, k, w, bias, cur) },
                #[cfg(target_arch = "x86_64")]
                // SAFETY: as above.
                Kernel::Avx2 => unsafe { layer_avx2(inp, k, w, bias, cur) },
                #[cfg(not(target_arch = "x86_64"))]
                _ => unreachable!("no kernel is detected off x86-64"),
            }
            if let Some((a, stride)) = &mut acts {
                let at = l * *stride + r0 * WIDTH;
                a[at..at + rows * WIDTH].copy_from_slice(&cur.as_flattened()[..rows * WIDTH]);
            }
            std::mem::swap(&mut prev, &mut cur);
        }
        let dst = &mut pre_out[r0..r0 + rows];
        match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU supports the kernel (asserted above).
            Kernel::Avx512 => unsafe { output_avx512(prev, w_out, b_out, dst) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above.
            Kernel::Avx2 => unsafe { output_avx2(prev, w_out, b_out, dst) },
            #[cfg(not(target_arch = "x86_64"))]
            _ => unreachable!("no kernel is detected off x86-64"),
        }
    }
}

/// Scratch of [`backward`]: every layer's weights transposed, and every layer's `∂z`.
#[derive(Debug, Default)]
pub(super) struct Scratch {
    /// Layer `l`'s `Wᵀ` as `64 × c_l` (`c_l` = its fan-in rounded up to 16, zeros past it),
    /// one layer after another.
    wt: Vec<f32>,
    /// Layer `l`'s `∂L/∂z` for the chunk's rows, `n × 64`, one layer after another.
    dz: Vec<f32>,
    /// Layer `l`'s bias gradient over the chunk.
    db: Vec<[f32; WIDTH]>,
}

/// `$f::<N>($args)` for `N = $n`, one of the listed constants, else 1.
macro_rules! by_const {
    ($n:expr, [$($c:literal),*], $f:ident $args:tt) => {
        match $n {
            $($c => $f::<$c> $args,)*
            _ => $f::<1> $args,
        }
    };
}

/// Fan-in rounded up to whole blocks of 16 columns.
fn blocks(k: usize) -> usize {
    k.div_ceil(16)
}

/// What [`backward`] reads: the network and its parameters, the forward pass's inputs `x` and
/// activations (`acts`, layer `l` at `l · stride`), and `g = ∂L/∂(output pre-activation)` for
/// its `n = g.len()` rows.
pub(super) struct Pass<'a> {
    pub mlp: &'a Mlp,
    pub params: &'a [f32],
    pub x: &'a [f32],
    pub acts: &'a [f32],
    pub stride: usize,
    pub g: &'a [f32],
}

/// The backward pass after [`forward`] over the same rows: adds the gradients into `grads` and
/// writes `∂L/∂x` into `d_x`. Each tile of six rows goes down the network in registers (`∂z` of
/// a layer from the one above it, its ReLU mask and bias sums); the weight gradients `inputᵀ ·
/// ∂z`, long sums over the chunk's rows, follow ([`rank_avx512`], [`rank_avx2`]). Requires
/// [`fits`] and a `kernel` the CPU supports.
pub(super) fn backward(pass: Pass<'_>, s: &mut Scratch, grads: &mut [f32], d_x: Option<&mut [f32]>, kernel: Kernel) {
    assert!(fits(pass.mlp), "tile64 on a network it is not written for");
    assert!(Kernel::detect().is_some_and(|k| k == kernel || kernel == Kernel::Avx2), "{kernel:?} on this CPU");
    // The whole pass compiled for the kernel's instruction set, so that the loops between the
    // products (the output's gradient, the bias sums) are vectorised too.
    macro_rules! compiled_for {
        ($name:ident, $features:literal, $kernel:expr) => {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = $features)]
            unsafe fn $name(pass: Pass<'_>, s: &mut Scratch, grads: &mut [f32], d_x: Option<&mut [f32]>) {
                backward_tiles(pass, s, grads, d_x, $kernel)
            }
        };
    }
    compiled_for!(wide, "avx512f", Kernel::Avx512);
    compiled_for!(narrow, "avx2,fma", Kernel::Avx2);
    match kernel {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU supports the kernel (asserted above).
        Kernel::Avx512 => unsafe { wide(pass, s, grads, d_x) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Kernel::Avx2 => unsafe { narrow(pass, s, grads, d_x) },
        #[cfg(not(target_arch = "x86_64"))]
        _ => unreachable!("no kernel is detected off x86-64"),
    }
}

/// The body of [`backward`], for a `kernel` the CPU supports.
#[inline(always)]
fn backward_tiles(pass: Pass<'_>, s: &mut Scratch, grads: &mut [f32], d_x: Option<&mut [f32]>, kernel: Kernel) {
    let Pass { mlp, params, x, acts, stride, g } = pass;
    let (n, din, depth) = (g.len(), mlp.in_dim, mlp.layers.len());
    assert_eq!(x.len(), n * din, "tile64::backward: input is not {n}×{din}");
    assert!(stride >= n * WIDTH && acts.len() >= (depth - 1) * stride + n * WIDTH, "tile64::backward: acts too short");
    // Every layer's Wᵀ, 64 rows of its fan-in's blocks.
    let fan_in = |l: usize| if l == 0 { din } else { WIDTH };
    let wt_off = |l: usize| if l == 0 { 0 } else { WIDTH * 16 * blocks(din) + (l - 1) * WIDTH * WIDTH };
    s.wt.clear();
    s.wt.resize(wt_off(depth), 0.0);
    for (l, layer) in mlp.layers.iter().enumerate() {
        let (w, k, c) = (&params[layer.weight.clone()], fan_in(l), 16 * blocks(fan_in(l)));
        let wt = &mut s.wt[wt_off(l)..wt_off(l + 1)];
        for (kk, row) in w.chunks_exact(WIDTH).enumerate().take(k) {
            for (j, &v) in row.iter().enumerate() {
                wt[j * c + kk] = v;
            }
        }
    }
    s.dz.resize(depth * n * WIDTH, 0.0);
    let w_out: &[f32; WIDTH] = params[mlp.out_weight.clone()].try_into().expect("64 output weights");
    let mut d_w_out = [0f32; WIDTH];
    let db = &mut s.db;
    db.clear();
    db.resize(depth, [0f32; WIDTH]);
    let mut d_x = d_x;
    // The last tile's ∂z padded with zeros to a whole tile, and ∂x of a tile.
    let mut tail = [0f32; ROWS * WIDTH];
    let mut dx_tile = [0f32; ROWS * WIDTH];
    let last = depth - 1;
    for r0 in (0..n).step_by(ROWS) {
        let rows = ROWS.min(n - r0);
        // A layer's activations for the tile's rows.
        let act = |l: usize| &acts[l * stride + r0 * WIDTH..][..rows * WIDTH];
        // The last layer's ∂z: ∂L/∂a = g w_outᵀ, through its ReLU.
        {
            let a = act(last);
            let dz = &mut s.dz[(last * n + r0) * WIDTH..][..rows * WIDTH];
            for r in 0..rows {
                let gr = g[r0 + r];
                let (a, dz) = (&a[r * WIDTH..(r + 1) * WIDTH], &mut dz[r * WIDTH..(r + 1) * WIDTH]);
                for j in 0..WIDTH {
                    d_w_out[j] += gr * a[j];
                    let v = if a[j] > 0.0 { gr * w_out[j] } else { 0.0 };
                    dz[j] = v;
                }
                for (b, &v) in db[last].iter_mut().zip(dz.iter()) {
                    *b += v;
                }
            }
        }
        // Down the layers: ∂z of layer l − 1 = (∂z_l W_lᵀ) through layer l − 1's ReLU, and
        // ∂x = ∂z_0 W_0ᵀ.
        for l in (0..depth).rev() {
            if l == 0 && d_x.is_none() {
                break;
            }
            let (below, here) = s.dz.split_at_mut(l * n * WIDTH);
            let here = &here[r0 * WIDTH..];
            let inp: &[f32] = if rows == ROWS {
                &here[..ROWS * WIDTH]
            } else {
                tail[..rows * WIDTH].copy_from_slice(&here[..rows * WIDTH]);
                tail[rows * WIDTH..].fill(0.0);
                &tail
            };
            let wt = &s.wt[wt_off(l)..wt_off(l + 1)];
            let nb = blocks(fan_in(l));
            let (mask, out): (Option<&[f32]>, &mut [f32]) = if l > 0 {
                (Some(act(l - 1)), &mut below[((l - 1) * n + r0) * WIDTH..][..rows * WIDTH])
            } else {
                (None, &mut dx_tile[..rows * WIDTH])
            };
            match kernel {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: the CPU supports the kernel (asserted above); `inp` holds a tile of
                // rows of 64, `wt` 64 rows of 16 nb columns, `mask` and `out` `rows` rows of 64.
                Kernel::Avx512 => unsafe { by_const!(nb, [4, 3, 2], back_avx512(inp, wt, mask, out)) },
                #[cfg(target_arch = "x86_64")]
                // SAFETY: as above.
                Kernel::Avx2 => unsafe { by_const!(nb, [4, 3, 2], back_avx2(inp, wt, mask, out)) },
                #[cfg(not(target_arch = "x86_64"))]
                _ => unreachable!("no kernel is detected off x86-64"),
            }
            if l > 0 {
                for row in out.chunks_exact(WIDTH) {
                    for (b, &v) in db[l - 1].iter_mut().zip(row) {
                        *b += v;
                    }
                }
            } else if let Some(dx) = d_x.as_deref_mut() {
                for (r, row) in out.chunks_exact(WIDTH).enumerate() {
                    dx[(r0 + r) * din..(r0 + r + 1) * din].copy_from_slice(&row[..din]);
                }
            }
        }
    }
    for (gw, v) in grads[mlp.out_weight.clone()].iter_mut().zip(&d_w_out) {
        *gw += v;
    }
    for (l, layer) in mlp.layers.iter().enumerate() {
        for (gb, v) in grads[layer.bias.clone()].iter_mut().zip(&db[l]) {
            *gb += v;
        }
        // ∂L/∂W = inputᵀ · ∂z, summed over the chunk's rows.
        let (inp, k) = if l == 0 { (x, din) } else { (&acts[(l - 1) * stride..(l - 1) * stride + n * WIDTH], WIDTH) };
        let dz = &s.dz[l * n * WIDTH..(l + 1) * n * WIDTH];
        let dw = &mut grads[layer.weight.clone()];
        match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU supports the kernel (asserted by `backward`); `inp` holds n rows of
            // k, `dz` n rows of 64 and `dw` k rows of 64.
            Kernel::Avx512 => unsafe { rank_avx512(inp, k, dz, &mut dw[..k * WIDTH]) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above.
            Kernel::Avx2 => unsafe { rank_avx2(inp, k, dz, &mut dw[..k * WIDTH]) },
            #[cfg(not(target_arch = "x86_64"))]
            _ => unreachable!("no kernel is detected off x86-64"),
        }
    }
}

/// Rows of the chunk per pass of [`rank_avx512`] and [`rank_avx2`]: their `∂z` and inputs
/// (16 KB each at most) stay in L1 while every block of the weight gradient passes over them.
const RANK_ROWS: usize = 64;

/// The blocks of the weight gradient's kernels: `block(kb, k0, c, rows)` for every block of
/// `kb ≤ 6` rows of `dw` from `k0` and `group` columns from `c`, over passes of [`RANK_ROWS`] of
/// the chunk's `n` rows.
#[inline(always)]
fn rank_blocks(n: usize, k_n: usize, group: usize, mut block: impl FnMut(usize, usize, usize, Range<usize>)) {
    for p0 in (0..n).step_by(RANK_ROWS) {
        let rows = p0..(p0 + RANK_ROWS).min(n);
        for c in (0..WIDTH).step_by(group) {
            let mut k0 = 0;
            while k0 < k_n {
                let kb = (k_n - k0).min(6);
                block(kb, k0, c, rows.clone());
                k0 += kb;
            }
        }
    }
}

/// `dw[k][j] += Σ_p inp[p][k] · dz[p][j]` over the rows `p` of the chunk (`inp` rows of `k_n`,
/// `dz` and `dw` rows of 64) with AVX-512: blocks of six rows of `dw` held in 24 registers
/// while a pass of [`RANK_ROWS`] rows goes by.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn rank_avx512(inp: &[f32], k_n: usize, dz: &[f32], dw: &mut [f32]) {
    use std::arch::x86_64::*;
    let n = dz.len() / WIDTH;
    assert!(inp.len() >= n * k_n && dw.len() >= k_n * WIDTH);
    /// Rows `k0 .. k0 + KB` of `dw`, over the rows `ps` of the chunk.
    #[inline(always)]
    unsafe fn block<const KB: usize>(inp: &[f32], k_n: usize, k0: usize, dz: &[f32], ps: Range<usize>, dw: &mut [f32]) {
        // SAFETY (whole body): the caller bounds `ps` by the chunk's rows and `k0 + KB` by
        // `k_n`; loads and stores are unaligned.
        unsafe {
            let d0 = dw.as_mut_ptr().add(k0 * WIDTH);
            let mut acc: [[__m512; 4]; KB] =
                std::array::from_fn(|kk| std::array::from_fn(|v| _mm512_loadu_ps(d0.add(kk * WIDTH + 16 * v))));
            for p in ps {
                let zp = dz.as_ptr().add(p * WIDTH);
                let z: [__m512; 4] = std::array::from_fn(|v| _mm512_loadu_ps(zp.add(16 * v)));
                for (kk, acc) in acc.iter_mut().enumerate() {
                    let a = _mm512_set1_ps(*inp.get_unchecked(p * k_n + k0 + kk));
                    for (acc, &z) in acc.iter_mut().zip(&z) {
                        *acc = _mm512_fmadd_ps(a, z, *acc);
                    }
                }
            }
            for (kk, acc) in acc.iter().enumerate() {
                for (v, &acc) in acc.iter().enumerate() {
                    _mm512_storeu_ps(d0.add(kk * WIDTH + 16 * v), acc);
                }
            }
        }
    }
    rank_blocks(n, k_n, WIDTH, |kb, k0, _, rows| {
        // SAFETY: `rows` lies in the chunk and `k0 + kb ≤ k_n`; AVX-512F is enabled here.
        unsafe { by_const!(kb, [6, 5, 4, 3, 2], block(inp, k_n, k0, dz, rows, dw)) }
    });
}

/// [`rank_avx512`] with AVX2 and FMA: blocks of six rows of `dw` and 16 of its columns.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn rank_avx2(inp: &[f32], k_n: usize, dz: &[f32], dw: &mut [f32]) {
    use std::arch::x86_64::*;
    let n = dz.len() / WIDTH;
    assert!(inp.len() >= n * k_n && dw.len() >= k_n * WIDTH);
    /// Rows `k0 .. k0 + KB` and columns `c .. c + 16` of `dw`, over the rows `ps`.
    #[inline(always)]
    unsafe fn block<const KB: usize>(
        inp: &[f32],
        k_n: usize,
        k0: usize,
        c: usize,
        dz: &[f32],
        ps: Range<usize>,
        dw: &mut [f32],
    ) {
        // SAFETY (whole body): the caller bounds `ps`, `k0 + KB` and `c + 16`; loads and stores
        // are unaligned.
        unsafe {
            let d0 = dw.as_mut_ptr().add(k0 * WIDTH + c);
            let mut acc: [[__m256; 2]; KB] =
                std::array::from_fn(|kk| std::array::from_fn(|v| _mm256_loadu_ps(d0.add(kk * WIDTH + 8 * v))));
            for p in ps {
                let zp = dz.as_ptr().add(p * WIDTH + c);
                let z = [_mm256_loadu_ps(zp), _mm256_loadu_ps(zp.add(8))];
                for (kk, acc) in acc.iter_mut().enumerate() {
                    let a = _mm256_set1_ps(*inp.get_unchecked(p * k_n + k0 + kk));
                    for (acc, &z) in acc.iter_mut().zip(&z) {
                        *acc = _mm256_fmadd_ps(a, z, *acc);
                    }
                }
            }
            for (kk, acc) in acc.iter().enumerate() {
                for (v, &acc) in acc.iter().enumerate() {
                    _mm256_storeu_ps(d0.add(kk * WIDTH + 8 * v), acc);
                }
            }
        }
    }
    rank_blocks(n, k_n, 16, |kb, k0, c, rows| {
        // SAFETY: `rows` lies in the chunk, `k0 + kb ≤ k_n`, `c + 16 ≤ 64`; AVX2 and FMA are
        // enabled here.
        unsafe { by_const!(kb, [6, 5, 4, 3, 2], block(inp, k_n, k0, c, dz, rows, dw)) }
    });
}

/// `out[r][c] = Σ_j inp[r][j] · wt[j][c]` for the `16 nb` columns of `wt` (64 rows of `16 nb`),
/// kept where `mask[r][c] > 0` when a mask is given, with AVX-512: `inp` a whole tile of rows
/// of 64, `out` (and `mask`) its first `out.len() / 64` rows, of 64 values each.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn back_avx512<const NB: usize>(inp: &[f32], wt: &[f32], mask: Option<&[f32]>, out: &mut [f32]) {
    let nb = NB;
    use std::arch::x86_64::*;
    let rows = out.len() / WIDTH;
    assert!((1..=4).contains(&nb) && wt.len() >= WIDTH * 16 * nb && inp.len() >= ROWS * WIDTH && rows <= ROWS);
    assert!(mask.is_none_or(|m| m.len() >= out.len()));
    let c = 16 * nb;
    // SAFETY: the lengths are asserted just above; loads and stores are unaligned.
    unsafe {
        let mut acc = [[_mm512_setzero_ps(); NB]; ROWS];
        for j in 0..WIDTH {
            let wp = wt.as_ptr().add(j * c);
            let wv: [__m512; NB] = std::array::from_fn(|v| _mm512_loadu_ps(wp.add(16 * v)));
            for (r, acc) in acc.iter_mut().enumerate() {
                let a = _mm512_set1_ps(*inp.get_unchecked(r * WIDTH + j));
                for (acc, &wv) in acc.iter_mut().zip(&wv) {
                    *acc = _mm512_fmadd_ps(a, wv, *acc);
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (r, acc) in acc.iter().enumerate().take(rows) {
            for (v, &acc) in acc.iter().enumerate() {
                let at = r * WIDTH + 16 * v;
                let kept = match mask {
                    Some(m) => _mm512_maskz_mov_ps(
                        _mm512_cmp_ps_mask::<_CMP_GT_OQ>(_mm512_loadu_ps(m.as_ptr().add(at)), zero),
                        acc,
                    ),
                    None => acc,
                };
                _mm512_storeu_ps(out.as_mut_ptr().add(at), kept);
            }
        }
    }
}

/// [`back_avx512`] with AVX2 and FMA, 16 columns at a time.
///
/// # Safety
/// The CPU must support AVX2 and FMA; the lengths as for [`back_avx512`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn back_avx2<const NB: usize>(inp: &[f32], wt: &[f32], mask: Option<&[f32]>, out: &mut [f32]) {
    let nb = NB;
    use std::arch::x86_64::*;
    let rows = out.len() / WIDTH;
    assert!((1..=4).contains(&nb) && wt.len() >= WIDTH * 16 * nb && inp.len() >= ROWS * WIDTH && rows <= ROWS);
    assert!(mask.is_none_or(|m| m.len() >= out.len()));
    let cols = 16 * nb;
    // SAFETY: the lengths are asserted just above; loads and stores are unaligned.
    unsafe {
        let zero = _mm256_setzero_ps();
        for c in (0..cols).step_by(16) {
            let mut acc = [[zero; 2]; ROWS];
            for j in 0..WIDTH {
                let wp = wt.as_ptr().add(j * cols + c);
                let wv = [_mm256_loadu_ps(wp), _mm256_loadu_ps(wp.add(8))];
                for (r, acc) in acc.iter_mut().enumerate() {
                    let a = _mm256_set1_ps(*inp.get_unchecked(r * WIDTH + j));
                    for (acc, &wv) in acc.iter_mut().zip(&wv) {
                        *acc = _mm256_fmadd_ps(a, wv, *acc);
                    }
                }
            }
            for (r, acc) in acc.iter().enumerate().take(rows) {
                for (v, &acc) in acc.iter().enumerate() {
                    let at = r * WIDTH + c + 8 * v;
                    let kept = match mask {
                        Some(m) => {
                            _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(_mm256_loadu_ps(m.as_ptr().add(at)), zero), acc)
                        }
                        None => acc,
                    };
                    _mm256_storeu_ps(out.as_mut_ptr().add(at), kept);
                }
            }
        }
    }
}

/// The output's pre-activation of the tile's first `dst.len()` rows with AVX-512:
/// `b_out + h · w_out`.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn output_avx512(h: &[[f32; WIDTH]; ROWS], w_out: &[f32; WIDTH], b_out: f32, dst: &mut [f32]) {
    use std::arch::x86_64::*;
    // SAFETY: every pointer reads 16 values inside a 64-value array.
    unsafe {
        let w = [0, 1, 2, 3].map(|v| _mm512_loadu_ps(w_out.as_ptr().add(16 * v)));
        for (o, h) in dst.iter_mut().zip(h) {
            let mut s = _mm512_mul_ps(_mm512_loadu_ps(h.as_ptr()), w[0]);
            for (v, &w) in w.iter().enumerate().skip(1) {
                s = _mm512_fmadd_ps(_mm512_loadu_ps(h.as_ptr().add(16 * v)), w, s);
            }
            *o = b_out + _mm512_reduce_add_ps(s);
        }
    }
}

/// [`output_avx512`] with AVX2 and FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn output_avx2(h: &[[f32; WIDTH]; ROWS], w_out: &[f32; WIDTH], b_out: f32, dst: &mut [f32]) {
    use std::arch::x86_64::*;
    // SAFETY: every pointer reads 8 values inside a 64-value array.
    unsafe {
        for (o, h) in dst.iter_mut().zip(h) {
            let mut s = _mm256_mul_ps(_mm256_loadu_ps(h.as_ptr()), _mm256_loadu_ps(w_out.as_ptr()));
            for v in (8..WIDTH).step_by(8) {
                s = _mm256_fmadd_ps(_mm256_loadu_ps(h.as_ptr().add(v)), _mm256_loadu_ps(w_out.as_ptr().add(v)), s);
            }
            let q = _mm_add_ps(_mm256_castps256_ps128(s), _mm256_extractf128_ps::<1>(s));
            let q = _mm_add_ps(q, _mm_movehl_ps(q, q));
            let q = _mm_add_ss(q, _mm_movehdup_ps(q));
            *o = b_out + _mm_cvtss_f32(q);
        }
    }
}

/// One ReLU layer of a tile with AVX-512: `out[r] = max(0, bias + Σ_k inp[r·k_n + k] · w[k])`.
///
/// # Safety
/// The CPU must support AVX-512F; `inp` holds `ROWS × k_n` values, `w` `k_n × 64` and `bias` 64.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn layer_avx512(inp: &[f32], k_n: usize, w: &[f32], bias: &[f32], out: &mut [[f32; WIDTH]; ROWS]) {
    use std::arch::x86_64::*;
    assert!(inp.len() >= ROWS * k_n && w.len() >= k_n * WIDTH && bias.len() >= WIDTH);
    // SAFETY: the lengths are asserted just above; loads and stores are unaligned.
    unsafe {
        let b = [0, 1, 2, 3].map(|v| _mm512_loadu_ps(bias.as_ptr().add(16 * v)));
        let mut acc = [b; ROWS];
        for k in 0..k_n {
            let wp = w.as_ptr().add(k * WIDTH);
            let wv = [0, 1, 2, 3].map(|v| _mm512_loadu_ps(wp.add(16 * v)));
            for (r, acc) in acc.iter_mut().enumerate() {
                let a = _mm512_set1_ps(*inp.get_unchecked(r * k_n + k));
                for (acc, &wv) in acc.iter_mut().zip(&wv) {
                    *acc = _mm512_fmadd_ps(a, wv, *acc);
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (o, acc) in out.iter_mut().zip(&acc) {
            for (v, &acc) in acc.iter().enumerate() {
                _mm512_storeu_ps(o.as_mut_ptr().add(16 * v), _mm512_max_ps(acc, zero));
            }
        }
    }
}

/// [`layer_avx512`] with AVX2 and FMA, 16 columns at a time.
///
/// # Safety
/// The CPU must support AVX2 and FMA; the lengths as for [`layer_avx512`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn layer_avx2(inp: &[f32], k_n: usize, w: &[f32], bias: &[f32], out: &mut [[f32; WIDTH]; ROWS]) {
    use std::arch::x86_64::*;
    assert!(inp.len() >= ROWS * k_n && w.len() >= k_n * WIDTH && bias.len() >= WIDTH);
    // SAFETY: the lengths are asserted just above; loads and stores are unaligned.
    unsafe {
        let zero = _mm256_setzero_ps();
        for c in (0..WIDTH).step_by(16) {
            let b = [0, 8].map(|v| _mm256_loadu_ps(bias.as_ptr().add(c + v)));
            let mut acc = [b; ROWS];
            for k in 0..k_n {
                let wp = w.as_ptr().add(k * WIDTH + c);
                let wv = [_mm256_loadu_ps(wp), _mm256_loadu_ps(wp.add(8))];
                for (r, acc) in acc.iter_mut().enumerate() {
                    let a = _mm256_set1_ps(*inp.get_unchecked(r * k_n + k));
                    for (acc, &wv) in acc.iter_mut().zip(&wv) {
                        *acc = _mm256_fmadd_ps(a, wv, *acc);
                    }
                }
            }
            for (o, acc) in out.iter_mut().zip(&acc) {
                for (v, &acc) in acc.iter().enumerate() {
                    _mm256_storeu_ps(o.as_mut_ptr().add(c + 8 * v), _mm256_max_ps(acc, zero));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::super::{Activation, Mlp, MlpTape, OutputActivation};
    use super::{fits, infer, Kernel};

    /// Every kernel the CPU has gives the GEMM path's outputs up to the order of the sums, for
    /// one to three layers, 3 to 64 inputs and row counts that leave every size of last tile;
    /// the ReLUs cut (about half the hidden units are off), so a wrong mask would show.
    #[test]
    fn the_fused_layers_match_the_gemms() {
        let Some(best) = Kernel::detect() else { return };
        let kernels = if best == Kernel::Avx512 { vec![Kernel::Avx512, Kernel::Avx2] } else { vec![Kernel::Avx2] };
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        for (depth, in_dim) in [(1, 3), (2, 16), (3, 32), (2, 64)] {
            let mlp = Mlp::new(in_dim, 64, depth, Activation::Relu, OutputActivation::Softplus, false);
            assert!(fits(&mlp));
            let params: Vec<f32> = (0..mlp.num_params()).map(|_| rng.random_range(-0.4f32..0.4)).collect();
            for n in [1, 5, 6, 7, 13, 100, 1025] {
                let x: Vec<f32> = (0..n * in_dim).map(|_| rng.random_range(-1f32..1.0)).collect();
                let mut want = vec![0f32; n];
                mlp.infer_gemm(&params, &x, &mut want, &mut MlpTape::default());
                let scale = want.iter().fold(0f32, |m, v| m.max(v.abs()));
                assert!(scale > 0.1, "depth {depth}: outputs {scale}");
                for &k in &kernels {
                    let mut got = vec![f32::NAN; n];
                    infer(&mlp, &params, &x, &mut got, k);
                    for (r, (g, w)) in got.iter().zip(&want).enumerate() {
                        assert!(
                            (g - w).abs() <= 1e-5 * scale,
                            "{k:?}, depth {depth}, {in_dim} inputs, row {r} of {n}: {g} vs {w}"
                        );
                    }
                }
            }
        }
    }

    /// Training's f32 passes in tiles give what the GEMMs give, to the order of the sums: every
    /// layer's activations and the output of [`super::forward`], and every gradient and `∂x` of
    /// [`super::backward`], for every kernel the CPU has, one to three layers, inputs narrower
    /// than a block of 16 and wider, and every size of last tile; the forward pass's outputs
    /// are [`infer`]'s bit for bit.
    #[test]
    fn training_passes_in_tiles_match_the_gemms() {
        let Some(best) = Kernel::detect() else { return };
        let kernels = if best == Kernel::Avx512 { vec![Kernel::Avx512, Kernel::Avx2] } else { vec![Kernel::Avx2] };
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        for (depth, in_dim) in [(1, 3), (1, 5), (2, 16), (3, 42), (2, 64)] {
            let mlp = Mlp::new(in_dim, 64, depth, Activation::Relu, OutputActivation::Softplus, false);
            let params: Vec<f32> = (0..mlp.num_params()).map(|_| rng.random_range(-0.4f32..0.4)).collect();
            for n in [1, 5, 6, 7, 13, 100, 1025] {
                let x: Vec<f32> = (0..n * in_dim).map(|_| rng.random_range(-1f32..1.0)).collect();
                let d_out: Vec<f32> = (0..n).map(|_| rng.random_range(-1f32..1.0)).collect();
                // The GEMM passes.
                let mut tape = MlpTape::default();
                mlp.reserve(&mut tape, n);
                let stride = tape.cap * 64;
                mlp.forward_f32(&params, &x, &mut tape, stride);
                let (want_acts, want_pre) = (tape.acts.clone(), tape.pre_out[..n].to_vec());
                let g: Vec<f32> = want_pre.iter().zip(&d_out).map(|(&z, &d)| d * crate::kernels::sigmoid(z)).collect();
                tape.pre_out[..n].copy_from_slice(&g);
                let (mut want_grads, mut want_dx) = (vec![0f32; mlp.num_params()], vec![0f32; n * in_dim]);
                mlp.backward_gemm(&params, &x, &mut tape, &mut want_grads, Some(&mut want_dx));
                let scale = |v: &[f32]| v.iter().fold(0f32, |m, v| m.max(v.abs()));
                let close = |got: &[f32], want: &[f32], what: &str| {
                    let tol = 1e-5 * scale(want).max(1e-3);
                    for (i, (a, b)) in got.iter().zip(want).enumerate() {
                        assert!(
                            (a - b).abs() <= tol,
                            "{what} [{i}], depth {depth}, {in_dim} inputs, {n} rows: {a} vs {b}"
                        );
                    }
                };
                // One row may leave most units cut; a tile's worth cannot.
                assert!(
                    n < 6 || scale(&want_dx) > 0.01 && scale(&want_grads) > 0.01,
                    "depth {depth}, {n} rows: gradients vanish ({} and {})",
                    scale(&want_dx),
                    scale(&want_grads)
                );
                for &k in &kernels {
                    let what = format!("{k:?}");
                    let mut acts = vec![f32::NAN; depth * stride];
                    let mut pre = vec![f32::NAN; n];
                    super::forward(&mlp, &params, &x, &mut acts, stride, &mut pre, k);
                    for l in 0..depth {
                        let r = l * stride..l * stride + n * 64;
                        close(&acts[r.clone()], &want_acts[r], &format!("{what} activations of layer {l}"));
                    }
                    close(&pre, &want_pre, &format!("{what} output"));
                    let mut inferred = vec![f32::NAN; n];
                    infer(&mlp, &params, &x, &mut inferred, k);
                    assert_eq!(inferred, pre, "{what}: inference and the forward pass differ");
                    let (mut grads, mut dx) = (vec![0f32; mlp.num_params()], vec![f32::NAN; n * in_dim]);
                    let mut s = super::Scratch::default();
                    let pass = super::Pass { mlp: &mlp, params: &params, x: &x, acts: &want_acts, stride, g: &g };
                    super::backward(pass, &mut s, &mut grads, Some(&mut dx), k);
                    close(&dx, &want_dx, &format!("{what} ∂x"));
                    for (name, _, r) in mlp.tensors("", 0) {
                        if name == "output.bias" {
                            // Added by `Mlp::backward` before either path.
                            continue;
                        }
                        close(&grads[r.clone()], &want_grads[r], &format!("{what} ∂{name}"));
                    }
                }
            }
        }
    }

    /// `Mlp::infer` takes the fused layers only for the shapes they are written for: the
    /// faithful network's 256-wide layers and a skip connection keep the GEMMs, with the same
    /// outputs either way.
    #[test]
    fn other_shapes_keep_the_gemms() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(8);
        for (width, skip) in [(256, false), (64, true), (32, false)] {
            let mlp = Mlp::new(6, width, 4, Activation::Relu, OutputActivation::Relu, skip);
            assert!(!fits(&mlp), "width {width}, skip {skip}");
            let params: Vec<f32> = (0..mlp.num_params()).map(|_| rng.random_range(-0.3f32..0.3)).collect();
            let x: Vec<f32> = (0..20 * 6).map(|_| rng.random_range(-1f32..1.0)).collect();
            let (mut a, mut b) = (vec![0f32; 20], vec![0f32; 20]);
            mlp.infer(&params, &x, &mut a, &mut MlpTape::default());
            mlp.infer_gemm(&params, &x, &mut b, &mut MlpTape::default());
            b.iter_mut().for_each(|o| *o = o.max(0.0));
            assert_eq!(a, b);
        }
    }
}
