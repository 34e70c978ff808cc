//! Inference of the ReLU MLPs of width 64 (the grid fields' decoders) with every layer of a
//! tile of six rows kept in registers: the tile's activations never leave L1, and no pass over
//! a whole chunk adds the bias or applies the ReLU. Used by [`Mlp::infer`] when the CPU has
//! AVX2 and FMA (AVX-512 where it has it); the products are the same as the GEMMs', summed in
//! another order, so the outputs agree with the GEMM path to rounding (tested).
//!
//! Each layer's tile is `6 × 64` accumulators, started from the bias and updated by one
//! fused multiply–add per input feature and column: with AVX-512 four vectors per row (24
//! registers), with AVX2 one block of 16 columns at a time (12 registers). The input
//! features are broadcast from the previous layer's tile.

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
    assert!(fits(mlp), "infer64 on a network it is not written for");
    assert!(Kernel::detect().is_some_and(|k| k == kernel || kernel == Kernel::Avx2), "{kernel:?} on this CPU");
    let (n, din) = (pre_out.len(), mlp.in_dim);
    assert_eq!(x.len(), n * din, "infer64: input is not {n}×{din}");
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
