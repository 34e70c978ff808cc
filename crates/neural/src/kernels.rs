//! Low-level f32 kernels of the training engine: a safe wrapper around the `gemm` crates for
//! dense row-major matrices, and the elementwise passes (bias, activations and their
//! derivatives fused with bias-gradient reductions, fast `exp`).
//!
//! # Layout
//! Every matrix is dense and row-major: element `(i, j)` of an `r × c` matrix is at
//! `i * c + j`. A transposed operand is the same storage read with swapped strides, so no
//! transposition is ever materialised.
//!
//! # CPU dispatch
//! The `gemm-f32` crate picks AVX-512 / AVX2+FMA / SSE kernels at run time (its `x86-v4` feature
//! enables the AVX-512 ones). The elementwise kernels here do the same with
//! [`multiversion!`]: each is compiled three times (AVX-512, AVX2+FMA, baseline) and the best
//! one the running CPU supports is chosen on each call (a cached feature test, a few ns). A
//! plain `cargo build --release` therefore runs at full speed without `-C target-cpu=native`
//! and the binary still runs on any x86-64.

/// Defines `pub(crate) fn $name(..)` whose body is compiled for AVX-512, AVX2+FMA and the
/// baseline target, dispatching at run time. The body must be plain scalar loops that LLVM can
/// vectorise (no `mul_add`: without FMA it becomes a libm call).
macro_rules! multiversion {
    ($(#[$meta:meta])* fn $name:ident($($arg:ident : $ty:ty),* $(,)?) $body:block) => {
        $(#[$meta])*
        pub(crate) fn $name($($arg: $ty),*) {
            #[inline(always)]
            fn body($($arg: $ty),*) $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx2,fma")]
                unsafe fn v4($($arg: $ty),*) {
                    body($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                unsafe fn v3($($arg: $ty),*) {
                    body($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx512f")
                    && std::arch::is_x86_feature_detected!("avx512vl")
                    && std::arch::is_x86_feature_detected!("avx512dq")
                {
                    // SAFETY: the required CPU features were detected just above.
                    return unsafe { v4($($arg),*) };
                }
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: the required CPU features were detected just above.
                    return unsafe { v3($($arg),*) };
                }
            }
            body($($arg),*)
        }
    };
}
pub(crate) use multiversion;

/// Which operand of [`matmul`] is read transposed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Op {
    /// As stored: `r × c` row-major.
    N,
    /// Transposed: stored `c × r` row-major, read as `r × c`.
    T,
}

/// `dst (m × n) = [dst +] op(lhs) (m × k) · op(rhs) (k × n)`, all dense row-major, single
/// threaded (callers parallelise over chunks of rows).
pub(crate) fn matmul(
    dst: &mut [f32],
    m: usize,
    n: usize,
    k: usize,
    lhs: &[f32],
    lhs_op: Op,
    rhs: &[f32],
    rhs_op: Op,
    accumulate: bool,
) {
    assert!(dst.len() >= m * n, "matmul: dst holds {} < {m}×{n}", dst.len());
    assert!(lhs.len() >= m * k, "matmul: lhs holds {} < {m}×{k}", lhs.len());
    assert!(rhs.len() >= k * n, "matmul: rhs holds {} < {k}×{n}", rhs.len());
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            dst[..m * n].fill(0.0);
        }
        return;
    }
    // (column stride, row stride) of each operand as gemm wants them.
    let (lhs_cs, lhs_rs) = match lhs_op {
        Op::N => (1, k as isize),
        Op::T => (m as isize, 1),
    };
    let (rhs_cs, rhs_rs) = match rhs_op {
        Op::N => (1, n as isize),
        Op::T => (k as isize, 1),
    };
    let (dst_cs, dst_rs) = (1, n as isize);
    // gemm's microkernels prefer a column-major destination: a row-major product is computed
    // as its transpose, `dstᵀ = op(rhs)ᵀ · op(lhs)ᵀ` (the rule of the `gemm` crate's front end,
    // whose other cases, negative strides, never arise here).
    let (m, n, dst_cs, dst_rs, lhs, lhs_cs, lhs_rs, rhs, rhs_cs, rhs_rs) = if dst_cs < dst_rs {
        (n, m, dst_rs, dst_cs, rhs, rhs_rs, rhs_cs, lhs, lhs_rs, lhs_cs)
    } else {
        (m, n, dst_cs, dst_rs, lhs, lhs_cs, lhs_rs, rhs, rhs_cs, rhs_rs)
    };
    // SAFETY: the asserts above guarantee every element addressed by the strides lies inside
    // the slices; `dst` is exclusively borrowed and cannot alias `lhs` or `rhs`.
    unsafe {
        gemm_f32::gemm::f32::get_gemm_fn()(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            dst_cs,
            dst_rs,
            accumulate,
            lhs.as_ptr(),
            lhs_cs,
            lhs_rs,
            rhs.as_ptr(),
            rhs_cs,
            rhs_rs,
            1.0,
            1.0,
            false,
            false,
            false,
            gemm_common::Parallelism::None,
        );
    }
}

/// `e^x` to about 2 ulp for |x| < 87, vectorisable (Cody–Waite range reduction
/// `x = k ln 2 + r`, a degree-6 polynomial for `e^r`, `2^k` built in the exponent bits).
/// Saturates to 0 below −87 and to `f32::MAX`-ish above 88.
#[inline(always)]
pub(crate) fn fast_exp(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    let k = (x * std::f32::consts::LOG2_E).round();
    // ln 2 split in a part exact in f32 and a small correction (Cody–Waite).
    let r = x - k * 0.693_145_75 - k * 1.428_606_8e-6;
    let p = 1.0
        + r * (1.0 + r * (0.5 + r * (0.166_666_67 + r * (0.041_666_668 + r * (0.008_333_334 + r * 0.001_388_889)))));
    let bits = ((k as i32 + 127) as u32) << 23;
    p * f32::from_bits(bits)
}

/// Logistic sigmoid `1 / (1 + e^{−x})`.
#[inline(always)]
pub(crate) fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + fast_exp(-x))
}

/// Softplus `ln(1 + e^x)`, computed stably as `max(x, 0) + ln(1 + e^{−|x|})`, in branch-free
/// arithmetic that vectorises (libm's `expf` and `log1pf` do not): [`fast_exp`], then
/// `ln(1 + y) = 2 atanh(s)` with `s = y / (2 + y) ∈ [0, 1/3]`, whose odd series to `s¹⁵`
/// leaves a relative error under 2e-9, small arguments included. Within 4e-7 of the exact
/// value relative (tested).
#[inline(always)]
pub(crate) fn softplus(x: f32) -> f32 {
    let y = fast_exp(-x.abs());
    let s = y / (2.0 + y);
    let q = s * s;
    let series = 1.0
        + q * (1.0 / 3.0
            + q * (1.0 / 5.0
                + q * (1.0 / 7.0 + q * (1.0 / 9.0 + q * (1.0 / 11.0 + q * (1.0 / 13.0 + q * (1.0 / 15.0)))))));
    x.max(0.0) + 2.0 * s * series
}

multiversion! {
    /// `z = softplus(z)` in place.
    fn softplus_inplace(z: &mut [f32]) {
        for v in z.iter_mut() {
            *v = softplus(*v);
        }
    }
}

multiversion! {
    /// `out = softplus(z)` elementwise.
    fn softplus_into(z: &[f32], out: &mut [f32]) {
        for (o, &v) in out.iter_mut().zip(z) {
            *o = softplus(v);
        }
    }
}

/// The `x` with `softplus(x) = e` (> 0), computed without overflow.
pub(crate) fn inverse_softplus(e: f32) -> f32 {
    if e > 20.0 {
        e + (-(-e).exp()).ln_1p()
    } else {
        e.exp_m1().ln()
    }
}

multiversion! {
    /// Each of the `rows` rows of `dst` (`rows × bias.len()`) is set to `bias`.
    fn fill_rows(dst: &mut [f32], bias: &[f32]) {
        for row in dst.chunks_exact_mut(bias.len()) {
            row.copy_from_slice(bias);
        }
    }
}

multiversion! {
    /// `a = max(z, 0)` in place.
    fn relu_inplace(z: &mut [f32]) {
        for v in z.iter_mut() {
            *v = v.max(0.0);
        }
    }
}

multiversion! {
    /// Swish `a = z σ(z)`.
    fn swish(z: &[f32], a: &mut [f32]) {
        for (a, &z) in a.iter_mut().zip(z) {
            *a = z * sigmoid(z);
        }
    }
}

multiversion! {
    /// Swish in place, `z ← z σ(z)`.
    fn swish_inplace(z: &mut [f32]) {
        for v in z.iter_mut() {
            *v *= sigmoid(*v);
        }
    }
}

/// The layer width whose bias gradient [`relu_backward`] keeps in registers (the fast field's
/// decoder).
const RELU_BLOCK: usize = 64;

multiversion! {
    /// ReLU backward fused with the bias gradient: `dz = da · [a > 0]` in place over
    /// `da` (`rows × db.len()`), and `db += Σ_rows dz`.
    fn relu_backward(da: &mut [f32], a: &[f32], db: &mut [f32]) {
        let w = db.len();
        if w == RELU_BLOCK {
            // The bias gradient summed in registers across the rows and stored once: the same
            // additions in the same order as summing into `db` row by row, where every row
            // waited for the previous row's stores (8 % of the fast field's step with AVX2).
            // Wider layers have enough independent columns per row, and passes over blocks of
            // their columns were slower.
            let mut acc: [f32; RELU_BLOCK] = (&*db).try_into().expect("a row of biases");
            for (drow, arow) in da.chunks_exact_mut(w).zip(a.chunks_exact(w)) {
                let drow: &mut [f32; RELU_BLOCK] = drow.try_into().expect("a row");
                let arow: &[f32; RELU_BLOCK] = arow.try_into().expect("a row");
                for j in 0..RELU_BLOCK {
                    let v = if arow[j] > 0.0 { drow[j] } else { 0.0 };
                    drow[j] = v;
                    acc[j] += v;
                }
            }
            db.copy_from_slice(&acc);
            return;
        }
        for (drow, arow) in da.chunks_exact_mut(w).zip(a.chunks_exact(w)) {
            for ((d, &a), g) in drow.iter_mut().zip(arow).zip(db.iter_mut()) {
                let v = if a > 0.0 { *d } else { 0.0 };
                *d = v;
                *g += v;
            }
        }
    }
}

multiversion! {
    /// Swish backward fused with the bias gradient:
    /// `dz = da · σ(z) (1 + z (1 − σ(z)))` in place over `da`, and `db += Σ_rows dz`.
    fn swish_backward(da: &mut [f32], z: &[f32], db: &mut [f32]) {
        let w = db.len();
        for (drow, zrow) in da.chunks_exact_mut(w).zip(z.chunks_exact(w)) {
            for ((d, &z), g) in drow.iter_mut().zip(zrow).zip(db.iter_mut()) {
                let s = sigmoid(z);
                let v = *d * (s * (1.0 + z * (1.0 - s)));
                *d = v;
                *g += v;
            }
        }
    }
}

multiversion! {
    /// Row-wise dot products: `out[i] = bias + Σ_j a[i, j] w[j]` for `a` of shape
    /// `out.len() × w.len()`.
    fn rows_dot(a: &[f32], w: &[f32], bias: f32, out: &mut [f32]) {
        let h = w.len();
        for (o, row) in out.iter_mut().zip(a.chunks_exact(h)) {
            // Eight partial sums so the reduction vectorises without reassociation.
            let mut acc = [0.0f32; 8];
            let mut chunks = row.chunks_exact(8);
            let mut wchunks = w.chunks_exact(8);
            for (r, ww) in (&mut chunks).zip(&mut wchunks) {
                for l in 0..8 {
                    acc[l] += r[l] * ww[l];
                }
            }
            let mut s = 0.0;
            for (r, ww) in chunks.remainder().iter().zip(wchunks.remainder()) {
                s += r * ww;
            }
            *o = bias + s + acc.iter().sum::<f32>();
        }
    }
}

multiversion! {
    /// Output-layer backward: `da[i, j] = g[i] w[j]` (outer product) and
    /// `dw[j] += Σ_i a[i, j] g[i]`.
    fn rows_dot_backward(a: &[f32], w: &[f32], g: &[f32], da: &mut [f32], dw: &mut [f32]) {
        let h = w.len();
        for ((arow, darow), &gi) in a.chunks_exact(h).zip(da.chunks_exact_mut(h)).zip(g) {
            for (((d, &wj), &aij), dwj) in darow.iter_mut().zip(w).zip(arow).zip(dw.iter_mut()) {
                *d = gi * wj;
                *dwj += aij * gi;
            }
        }
    }
}

multiversion! {
    /// `dst += src`.
    fn add_assign(dst: &mut [f32], src: &[f32]) {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d += s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ReLU backward pass, with the bias gradient held in registers (width 64) or summed
    /// row by row (other widths), gives the bits of the plain loop written out here: masked
    /// gradients, and bias gradients added to what `db` held, row after row.
    #[test]
    fn relu_backward_matches_the_row_by_row_sums() {
        for (rows, w) in [(37, 64), (200, 128), (9, 48), (5, 70)] {
            let val = |i: usize, s: usize| (((i * 7919 + s) % 1013) as f32 / 1013.0 - 0.4) * 1.7;
            let a: Vec<f32> = (0..rows * w).map(|i| val(i, 3)).collect();
            let da0: Vec<f32> = (0..rows * w).map(|i| val(i, 11)).collect();
            let db0: Vec<f32> = (0..w).map(|j| val(j, 29)).collect();
            let (mut want_da, mut want_db) = (da0.clone(), db0.clone());
            for r in 0..rows {
                for j in 0..w {
                    let v = if a[r * w + j] > 0.0 { want_da[r * w + j] } else { 0.0 };
                    want_da[r * w + j] = v;
                    want_db[j] += v;
                }
            }
            let (mut da, mut db) = (da0, db0);
            relu_backward(&mut da, &a, &mut db);
            assert!(da.iter().zip(&want_da).all(|(x, y)| x.to_bits() == y.to_bits()), "{rows}×{w}: dz");
            assert!(db.iter().zip(&want_db).all(|(x, y)| x.to_bits() == y.to_bits()), "{rows}×{w}: db");
        }
    }

    #[test]
    fn softplus_is_accurate() {
        let mut worst = 0.0f64;
        let mut x = -60.0f32;
        while x < 60.0 {
            let xd = x as f64;
            let want = xd.max(0.0) + (-xd.abs()).exp().ln_1p();
            let got = softplus(x) as f64;
            worst = worst.max(((got - want) / want).abs());
            x += 0.001_3;
        }
        assert!(worst < 4e-7, "softplus relative error {worst}");
        // The dispatched kernel (AVX-512 or AVX2 where the CPU has them) gives the bits of the
        // baseline scalar function: results do not depend on the CPU.
        let z: Vec<f32> = (0..20_000).map(|i| (i as f32 - 10_000.0) * 0.004_7).collect();
        let mut out = vec![0f32; z.len()];
        softplus_into(&z, &mut out);
        assert!(z.iter().zip(&out).all(|(&a, &b)| b.to_bits() == softplus(a).to_bits()));
        softplus_inplace(&mut out);
        assert!(z.iter().zip(&out).all(|(&a, &b)| b.to_bits() == softplus(softplus(a)).to_bits()));
        assert!((softplus(0.0) - std::f32::consts::LN_2).abs() < 1e-7);
    }

    #[test]
    fn fast_exp_is_accurate() {
        let mut worst = 0.0f64;
        for i in -8000..8000 {
            let x = i as f32 * 0.01;
            let want = (x as f64).exp();
            let got = fast_exp(x) as f64;
            worst = worst.max(((got - want) / want).abs());
        }
        assert!(worst < 4e-7, "fast_exp relative error {worst}");
    }

    #[test]
    fn matmul_matches_naive_for_all_transpositions() {
        let (m, n, k) = (5, 7, 3);
        let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.21).cos()).collect();
        let at: Vec<f32> = (0..m * k).map(|i| a[(i % m) * k + i / m]).collect();
        let bt: Vec<f32> = (0..k * n).map(|i| b[(i % k) * n + i / k]).collect();
        let mut want = vec![0.0f32; m * n];
        for i in 0..m {
            for j in 0..n {
                want[i * n + j] = (0..k).map(|l| a[i * k + l] * b[l * n + j]).sum();
            }
        }
        for (lhs, lop) in [(&a, Op::N), (&at, Op::T)] {
            for (rhs, rop) in [(&b, Op::N), (&bt, Op::T)] {
                let mut got = vec![1.0f32; m * n];
                matmul(&mut got, m, n, k, lhs, lop, rhs, rop, true);
                for (g, w) in got.iter().zip(&want) {
                    assert!((g - 1.0 - w).abs() < 1e-5, "{lop:?}{rop:?}: {g} vs {w}+1");
                }
            }
        }
    }
}
