//! A dense trilinear voxel grid as a [`TrainableField`]: the simplest field representation
//! with exact, cheap gradients. It is a legitimate reconstruction model of its own (a voxel
//! grid trained through the differentiable renderer instead of by ART), and the reference the
//! method code is tested against.
//!
//! # Conventions
//! - Inputs: box-normalised coordinates `u ∈ [0, 1]³` (the field contract); a space–time grid
//!   is not provided, so `input_dim() == 3`.
//! - Values live at cell centres, x fastest (`params[(k·ny + j)·nx + i]`), exactly like
//!   [`fluidnerf_core::Volume`]; sampling is trilinear between centres, clamped to the
//!   outermost centres, zero outside `[0, 1]³`.
//! - Output `E = softplus(v)` with `v` the trilinear value of the parameters, so E is
//!   non-negative and every parameter keeps a gradient (a ReLU would freeze cells that go
//!   negative).

use std::ops::Range;

use crate::field::Prior;
use crate::kernels::{inverse_softplus, multiversion, sigmoid, softplus};
use crate::TrainableField;

/// A trainable `nx × ny × nz` grid of raw values behind a softplus.
#[derive(Clone, Debug)]
pub struct DenseGridField {
    dims: [usize; 3],
    params: Vec<f32>,
}

/// Per-row corner indices, trilinear weights and softplus slope, recorded by `forward`.
#[derive(Debug, Default)]
pub struct DenseTape {
    idx: Vec<[u32; 8]>,
    wts: Vec<[f32; 8]>,
    slope: Vec<f32>,
}

impl DenseGridField {
    /// A grid whose every cell evaluates to `initial` (> 0).
    pub fn new(dims: [usize; 3], initial: f32) -> Self {
        assert!(dims.iter().all(|&n| n > 0), "DenseGridField::new: dims {dims:?} must be positive");
        let n = dims[0] * dims[1] * dims[2];
        assert!(n <= u32::MAX as usize, "DenseGridField::new: grid too large");
        DenseGridField { dims, params: vec![inverse_softplus(initial); n] }
    }

    /// A grid with the given raw parameters (softplus is applied on evaluation).
    pub fn from_raw(dims: [usize; 3], params: Vec<f32>) -> Self {
        assert_eq!(params.len(), dims[0] * dims[1] * dims[2], "DenseGridField::from_raw: length mismatch");
        DenseGridField { dims, params }
    }

    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }
}

/// Corner indices and weights of the trilinear stencil at `u` in a grid of `dims`, or `None`
/// outside `[0, 1]³`.
#[inline(always)]
fn stencil(dims: [usize; 3], u: [f32; 3]) -> Option<([u32; 8], [f32; 8])> {
    if u.iter().any(|&c| !(0.0..=1.0).contains(&c)) {
        return None;
    }
    let mut i0 = [0usize; 3];
    let mut i1 = [0usize; 3];
    let mut w = [0f32; 3];
    for a in 0..3 {
        let n = dims[a];
        let g = (u[a] * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        // `g` is not negative, so truncation is its floor, without a call to libm's `floorf`
        // where the instruction set has no rounding instruction.
        i0[a] = g as usize;
        let f = i0[a] as f32;
        i1[a] = (i0[a] + 1).min(n - 1);
        w[a] = g - f;
    }
    let (nx, ny) = (dims[0], dims[1]);
    let mut idx = [0u32; 8];
    let mut wts = [0f32; 8];
    for c in 0..8 {
        let (bx, by, bz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let i = if bx == 0 { i0[0] } else { i1[0] };
        let j = if by == 0 { i0[1] } else { i1[1] };
        let k = if bz == 0 { i0[2] } else { i1[2] };
        idx[c] = ((k * ny + j) * nx + i) as u32;
        let wx = if bx == 0 { 1.0 - w[0] } else { w[0] };
        let wy = if by == 0 { 1.0 - w[1] } else { w[1] };
        let wz = if bz == 0 { 1.0 - w[2] } else { w[2] };
        wts[c] = wx * wy * wz;
    }
    Some((idx, wts))
}

#[inline(always)]
fn pre_activation(params: &[f32], idx: &[u32; 8], wts: &[f32; 8]) -> f32 {
    idx.iter().zip(wts).map(|(&i, &w)| params[i as usize] * w).sum()
}

/// Points per block of [`dense_values`]: their pre-activations wait in a stack array between
/// the stencil pass and the softplus and sigmoid passes, which vectorise across the block.
const BLOCK: usize = 64;

multiversion! {
    /// The values at `inputs` (rows of three), and with `tape` the stencils and slopes that
    /// [`DenseGridField::backward`] needs: the body of `eval` and `forward`, compiled for the
    /// CPU's vector instructions (its rounding and `fast_exp` inline there; the same results).
    /// Block by block: the stencils and pre-activations point by point, then the softplus
    /// (and the slope) of the whole block, vectorised across its points.
    fn dense_values(dims: [usize; 3], params: &[f32], inputs: &[f32], out: &mut [f32], tape: Option<&mut DenseTape>) {
        let mut tape = tape;
        if let Some(t) = tape.as_deref_mut() {
            // A point outside the box keeps these zeros: it passes no gradient.
            let n = out.len();
            t.idx.clear();
            t.idx.resize(n, [0; 8]);
            t.wts.clear();
            t.wts.resize(n, [0.0; 8]);
            t.slope.clear();
            t.slope.resize(n, 0.0);
        }
        for (b, (out, inputs)) in out.chunks_mut(BLOCK).zip(inputs.chunks(3 * BLOCK)).enumerate() {
            let mut v = [0f32; BLOCK];
            // 1 inside the box, 0 outside, where the value is 0.
            let mut inside = [0f32; BLOCK];
            for (q, p) in inputs.chunks_exact(3).enumerate() {
                if let Some((idx, wts)) = stencil(dims, [p[0], p[1], p[2]]) {
                    v[q] = pre_activation(params, &idx, &wts);
                    inside[q] = 1.0;
                    if let Some(t) = tape.as_deref_mut() {
                        t.idx[b * BLOCK + q] = idx;
                        t.wts[b * BLOCK + q] = wts;
                    }
                }
            }
            let m = out.len();
            for ((o, &x), &k) in out.iter_mut().zip(&v[..m]).zip(&inside[..m]) {
                let e = softplus(x);
                *o = if k != 0.0 { e } else { 0.0 };
            }
            if let Some(t) = tape.as_deref_mut() {
                let slope = &mut t.slope[b * BLOCK..b * BLOCK + m];
                for ((s, &x), &k) in slope.iter_mut().zip(&v[..m]).zip(&inside[..m]) {
                    let g = sigmoid(x);
                    *s = if k != 0.0 { g } else { 0.0 };
                }
            }
        }
    }
}

impl TrainableField for DenseGridField {
    type Tape = DenseTape;

    fn input_dim(&self) -> usize {
        3
    }

    fn detail_dims(&self) -> Option<[usize; 3]> {
        Some(self.dims)
    }

    fn new_tape(&self) -> DenseTape {
        DenseTape::default()
    }

    fn params(&self) -> &[f32] {
        &self.params
    }

    fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    fn start_uniform(&mut self, level: f32) {
        assert!(level > 0.0 && level.is_finite(), "DenseGridField::start_uniform: level {level} must be positive");
        self.params.fill(inverse_softplus(level));
    }

    fn eval(&self, inputs: &[f32], out: &mut [f32], _tape: &mut DenseTape) {
        assert_eq!(inputs.len(), 3 * out.len(), "DenseGridField::eval: inputs must be n × 3");
        dense_values(self.dims, &self.params, inputs, out, None);
    }

    fn forward(&self, inputs: &[f32], out: &mut [f32], tape: &mut DenseTape) {
        assert_eq!(inputs.len(), 3 * out.len(), "DenseGridField::forward: inputs must be n × 3");
        dense_values(self.dims, &self.params, inputs, out, Some(tape));
    }

    fn backward(&self, tape: &mut DenseTape, d_out: &[f32], grads: &mut [f32]) {
        assert_eq!(d_out.len(), tape.slope.len(), "DenseGridField::backward: d_out does not match the last forward");
        assert_eq!(grads.len(), self.params.len(), "DenseGridField::backward: grads length");
        for (((&d, idx), wts), &s) in d_out.iter().zip(&tape.idx).zip(&tape.wts).zip(&tape.slope) {
            let g = d * s;
            if g == 0.0 {
                continue;
            }
            for c in 0..8 {
                grads[idx[c] as usize] += g * wts[c];
            }
        }
    }

    fn tensors(&self) -> Vec<(String, Vec<usize>, Range<usize>)> {
        let [nx, ny, nz] = self.dims;
        vec![("grid".to_string(), vec![nz, ny, nx], 0..self.params.len())]
    }

    fn supports_prior(&self) -> bool {
        true
    }

    fn add_prior(&self, prior: &Prior, grads: &mut [f32]) -> f32 {
        if prior.is_zero() {
            return 0.0;
        }
        assert_eq!(grads.len(), self.params.len(), "DenseGridField::add_prior: grads length");
        let mut value = 0.0;
        dense_prior(self.dims, &self.params, prior, grads, &mut value);
        value
    }
}

multiversion! {
    /// The body of [`DenseGridField::add_prior`], compiled for the CPU's vector instructions
    /// (its `softplus` and `sigmoid` inline there): adds the prior's gradient to `grads` and
    /// writes its value to `out`.
    fn dense_prior(dims: [usize; 3], params: &[f32], prior: &Prior, grads: &mut [f32], out: &mut f32) {
        let [nx, ny, nz] = dims;
        let n = params.len();
        let e: Vec<f32> = params.iter().map(|&v| softplus(v)).collect();
        // ∂R/∂E first, then through the softplus.
        let mut d_e = vec![0f32; n];
        let mut value = 0f64;
        let inv_n = 1.0 / n as f32;
        const EPS2: f32 = 1e-6;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let c = (k * ny + j) * nx + i;
                    // Forward differences, zero across the far faces.
                    let nbr =
                        [(i + 1 < nx).then(|| c + 1), (j + 1 < ny).then(|| c + nx), (k + 1 < nz).then(|| c + nx * ny)];
                    let d = nbr.map(|m| m.map_or(0.0, |m| e[m] - e[c]));
                    let g2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                    let t = (g2 + EPS2).sqrt();
                    value += (prior.tv * t + prior.smooth * g2 + prior.sparsity * e[c]) as f64;
                    d_e[c] += prior.sparsity * inv_n;
                    // d/dd_a of (tv·t + smooth·g2) = (tv / t + 2 smooth) · d_a
                    let s = (prior.tv / t + 2.0 * prior.smooth) * inv_n;
                    for (a, m) in nbr.iter().enumerate() {
                        if let Some(m) = *m {
                            d_e[m] += s * d[a];
                            d_e[c] -= s * d[a];
                        }
                    }
                }
            }
        }
        for ((g, &de), &v) in grads.iter_mut().zip(&d_e).zip(params) {
            *g += de * sigmoid(v);
        }
        *out = (value / n as f64) as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prior_gradient_matches_finite_differences() {
        let dims = [4, 3, 5];
        let n = 60;
        let params: Vec<f32> = (0..n).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.3).collect();
        let field = DenseGridField::from_raw(dims, params.clone());
        let prior = Prior { tv: 0.7, smooth: 0.4, sparsity: 0.3, ..Prior::default() };
        let mut grads = vec![0f32; n];
        let r0 = field.add_prior(&prior, &mut grads);
        assert!(r0 > 0.0);
        let value = |p: &[f32]| {
            let mut g = vec![0f32; n];
            DenseGridField::from_raw(dims, p.to_vec()).add_prior(&prior, &mut g) as f64
        };
        for i in [0, 7, 23, 59] {
            let h = 1e-2f32;
            let (mut a, mut b) = (params.clone(), params.clone());
            a[i] += h;
            b[i] -= h;
            let fd = (value(&a) - value(&b)) / (2.0 * h as f64);
            assert!((fd - grads[i] as f64).abs() < 2e-3 * (1.0 + fd.abs()), "param {i}: {fd} vs {}", grads[i]);
        }
        // A constant grid has no variation: value ε-level, gradient zero, but for the sparsity
        // term, which is the level itself with the same gradient in every cell.
        let flat = DenseGridField::new(dims, 0.3);
        let mut g = vec![0f32; n];
        let without_sparsity = Prior { sparsity: 0.0, ..prior };
        assert!(flat.add_prior(&without_sparsity, &mut g) < 1e-2);
        assert!(g.iter().all(|&x| x.abs() < 1e-9));
        let mut g = vec![0f32; n];
        let level = Prior { tv: 0.0, smooth: 0.0, ..prior };
        assert!((flat.add_prior(&level, &mut g) - 0.3 * 0.3).abs() < 1e-5);
        assert!(g.iter().all(|&x| x > 0.0 && (x - g[0]).abs() < 1e-9));
    }

    #[test]
    fn constant_grid_is_constant_inside_and_zero_outside() {
        let f = DenseGridField::new([4, 5, 6], 0.7);
        let mut tape = f.new_tape();
        let inputs = [0.0, 0.0, 0.0, 0.5, 0.3, 0.9, 1.0, 1.0, 1.0, 1.2, 0.5, 0.5];
        let mut out = [0.0; 4];
        f.eval(&inputs, &mut out, &mut tape);
        for o in &out[..3] {
            assert!((o - 0.7).abs() < 1e-6, "{o}");
        }
        assert_eq!(out[3], 0.0);
    }

    /// Many points, in and out of the box, over several blocks and a partial one: `forward`
    /// gives each point's value, stencil and slope exactly as it alone would (its stencil,
    /// `pre_activation`, then softplus and sigmoid), and `eval` the same values.
    #[test]
    fn blocks_give_each_point_its_own_value_and_tape() {
        let dims = [5, 4, 6];
        let n = dims.iter().product::<usize>();
        let raw: Vec<f32> = (0..n).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.4).collect();
        let f = DenseGridField::from_raw(dims, raw.clone());
        let points = 3 * BLOCK + 17;
        // Coordinates from −0.2 to 1.2: about a third of the points lie outside the box.
        let inputs: Vec<f32> = (0..3 * points).map(|i| ((i * 7919) % 1000) as f32 * 1.4e-3 - 0.2).collect();
        let mut tape = f.new_tape();
        let mut out = vec![f32::NAN; points];
        f.forward(&inputs, &mut out, &mut tape);
        let mut evaluated = vec![f32::NAN; points];
        f.eval(&inputs, &mut evaluated, &mut f.new_tape());
        let mut outside = 0;
        for (q, p) in inputs.chunks_exact(3).enumerate() {
            let at = format!("point {q} at {p:?}");
            match stencil(dims, [p[0], p[1], p[2]]) {
                Some((idx, wts)) => {
                    let v = pre_activation(&raw, &idx, &wts);
                    assert_eq!(out[q].to_bits(), softplus(v).to_bits(), "{at}");
                    assert_eq!(tape.slope[q].to_bits(), sigmoid(v).to_bits(), "{at}");
                    assert_eq!((tape.idx[q], tape.wts[q]), (idx, wts), "{at}");
                }
                None => {
                    outside += 1;
                    assert_eq!((out[q], tape.slope[q]), (0.0, 0.0), "{at}");
                    assert_eq!((tape.idx[q], tape.wts[q]), ([0; 8], [0.0; 8]), "{at}");
                }
            }
            assert_eq!(evaluated[q].to_bits(), out[q].to_bits(), "{at}");
        }
        assert!(outside > points / 5 && outside < points - points / 5, "{outside} of {points} outside");
        // A second, shorter forward leaves no entry of the first in the tape.
        f.forward(&inputs[..9], &mut out[..3], &mut tape);
        assert_eq!((tape.idx.len(), tape.wts.len(), tape.slope.len()), (3, 3, 3));
    }

    #[test]
    fn backward_matches_finite_differences() {
        let dims = [3, 4, 2];
        let n = 24;
        let raw: Vec<f32> = (0..n).map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.3).collect();
        let f = DenseGridField::from_raw(dims, raw.clone());
        let inputs = [0.1, 0.2, 0.3, 0.77, 0.41, 0.6, 0.5, 0.95, 0.05];
        let d_out = [0.3, -1.1, 0.7];
        let mut tape = f.new_tape();
        let mut out = [0.0; 3];
        f.forward(&inputs, &mut out, &mut tape);
        let mut grads = vec![0.0; n];
        f.backward(&mut tape, &d_out, &mut grads);
        let loss = |p: &[f32]| -> f64 {
            let g = DenseGridField::from_raw(dims, p.to_vec());
            let mut o = [0.0; 3];
            g.eval(&inputs, &mut o, &mut g.new_tape());
            o.iter().zip(&d_out).map(|(a, b)| (*a as f64) * (*b as f64)).sum()
        };
        for i in 0..n {
            let h = 1e-2;
            let mut p = raw.clone();
            p[i] += h;
            let lp = loss(&p);
            p[i] -= 2.0 * h;
            let lm = loss(&p);
            let fd = (lp - lm) / (2.0 * h as f64);
            assert!((fd - grads[i] as f64).abs() < 2e-3, "param {i}: fd {fd} vs {}", grads[i]);
        }
    }
}
