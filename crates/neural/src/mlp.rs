//! The dissertation's network (section 5.1, Fig. 5.4) as a [`TrainableField`]: positional
//! encoding (Eq. 5.2, see [`crate::encoding`]) → `D` dense layers of height `H` with ReLU or
//! Swish, the encoded input concatenated back in at the middle layer → one non-negative output
//! E. Forward and backward are written by hand and fused per layer over a GEMM, so a chunk of
//! rows goes through the whole network without allocating.
//!
//! # Architecture
//! - layer 0: `E → H` (`E` = encoded width), layers `1 … D−1`: `H → H`, except layer
//!   `s = ⌊D/2⌋` (when `skip` and `D ≥ 2`), which takes `[h, γ(x)]` (`H + E → H`): the skip of
//!   Fig. 5.4 ("a residual connection after four layers" for `D = 8`, as in NeRF);
//! - output: `H → 1`, then the output activation ([`OutputActivation`]).
//!
//! # Parameter layout (flat, f32)
//! For each layer `l`: `layers.l.weight` `[fan_in, H]` row-major (`z = x W + b`; rows of the
//! skip layer are ordered hidden first, then the encoding), `layers.l.bias` `[H]`; then
//! `output.weight` `[H, 1]` and `output.bias` `[1]`. The defaults have 487 169 parameters
//! (1.95 MB), the dissertation's "≈ 1.9 MB".
//!
//! # Initialisation (seeded, ChaCha8)
//! Hidden weights He/Kaiming-uniform `U(±√(6 / fan_in))` (keeps the activation variance
//! constant through ReLU layers), the output weights Glorot-uniform `U(±√(6 / (H + 1)))`,
//! all biases zero.

use std::ops::Range;

use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::encoding::PositionalEncoding;
use crate::error::NeuralError;
use crate::field::TrainableField;
use crate::kernels::{self, matmul, Op};

#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
mod amx;
mod bf16;
mod tile64;

/// Whether the hash grid's decoder takes its training products in bfloat16 on this CPU when its
/// configuration asks for them (`mlp_precision = "bf16"`): where AVX-512 BF16 runs them faster
/// than f32, on AMD's Zen 4 and Zen 5, or on AMX tiles (Intel, Sapphire Rapids onwards);
/// elsewhere it trains in f32.
pub fn bf16_products_available() -> bool {
    bf16::bf16_pays()
}

/// Factor on the initial output weights in [`TrainableField::start_uniform`]: small enough
/// that the initial field is nearly uniform, large enough that every hidden unit receives a
/// gradient from the first iteration on.
pub const UNIFORM_START_WEIGHT_SCALE: f32 = 0.1;

/// Hidden-layer activation σ.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Activation {
    /// `max(z, 0)`, Table 5.1.
    Relu,
    /// `z · sigmoid(z)`, Table 5.2 (TR-FluidNeRF).
    Swish,
}

/// The activation that makes the single output E non-negative.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OutputActivation {
    /// `max(z, 0)`: exact zeros for empty space, but once a region's pre-activation is
    /// negative no gradient reaches it again ("dead" output), which can freeze training on
    /// the large empty parts of a flow volume.
    Relu,
    /// `ln(1 + e^z)`: smooth, always passes a gradient `sigmoid(z)`; empty space is
    /// approached as `z → −∞` (E ≈ e^z). The default for that reason.
    Softplus,
}

impl Activation {
    fn name(self) -> &'static str {
        match self {
            Activation::Relu => "relu",
            Activation::Swish => "swish",
        }
    }
}

/// Configuration of [`MlpField`]. Defaults are Table 5.1 (static FluidNeRF);
/// [`MlpConfig::table_5_2`] gives the TR-FluidNeRF defaults.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MlpConfig {
    /// Number of hidden layers `D`. Default 8.
    pub depth: usize,
    /// Height `H` of each hidden layer. Default 256.
    pub width: usize,
    /// Encoding frequencies `L_x` per spatial coordinate (Eq. 5.2). Default 8.
    pub space_freqs: usize,
    /// Encoding frequencies `L_t` of the time coordinate (4D fields only). Default 0.
    pub time_freqs: usize,
    /// Hidden activation. Default ReLU.
    pub activation: Activation,
    /// Output activation. Default softplus (see [`OutputActivation`]).
    pub output_activation: OutputActivation,
    /// Concatenate the encoded input back in at layer `⌊D/2⌋` (Fig. 5.4). Default true.
    pub skip: bool,
}

impl Default for MlpConfig {
    fn default() -> Self {
        Self {
            depth: 8,
            width: 256,
            space_freqs: 8,
            time_freqs: 0,
            activation: Activation::Relu,
            output_activation: OutputActivation::Softplus,
            skip: true,
        }
    }
}

impl MlpConfig {
    /// Table 5.1, static FluidNeRF: D 8, H 256, L 8, ReLU.
    pub fn table_5_1() -> Self {
        Self::default()
    }

    /// Table 5.2, TR-FluidNeRF: D 10, H 200, L_x 8, L_t 0, Swish.
    pub fn table_5_2() -> Self {
        Self { depth: 10, width: 200, activation: Activation::Swish, ..Self::default() }
    }

    pub fn validate(&self) -> Result<(), NeuralError> {
        if self.depth == 0 || self.depth > 64 {
            return Err(NeuralError::invalid("mlp.depth", format!("{} not in 1..=64", self.depth)));
        }
        if self.width == 0 || self.width > 4096 {
            return Err(NeuralError::invalid("mlp.width", format!("{} not in 1..=4096", self.width)));
        }
        // 2^{L−1} π τ must stay well inside f32's exact-integer range.
        if self.space_freqs > 20 || self.time_freqs > 20 {
            return Err(NeuralError::invalid(
                "mlp.space_freqs",
                format!("L_x = {}, L_t = {}: at most 20", self.space_freqs, self.time_freqs),
            ));
        }
        Ok(())
    }
}

/// One dense layer's place in the parameter vector.
#[derive(Clone, Debug)]
struct Layer {
    fan_in: usize,
    weight: Range<usize>,
    bias: Range<usize>,
}

/// A dense network `in_dim → D × H → 1` over an arbitrary input matrix, operating on a
/// parameter slice that starts at its first weight. Shared by [`MlpField`] and the tiny MLP
/// of [`crate::hashgrid::HashGridField`].
#[derive(Clone, Debug)]
pub(crate) struct Mlp {
    in_dim: usize,
    width: usize,
    activation: Activation,
    output_activation: OutputActivation,
    skip: Option<usize>,
    layers: Vec<Layer>,
    out_weight: Range<usize>,
    out_bias: usize,
    num_params: usize,
    /// Whether training takes the matrix products in bfloat16 ([`bf16`]).
    bf16: bool,
}

/// Activations of one chunk, recorded by [`Mlp::forward`] for [`Mlp::backward`]. All buffers
/// grow to the largest chunk seen and are then reused.
#[derive(Debug, Default)]
pub(crate) struct MlpTape {
    rows: usize,
    cap: usize,
    /// `D × cap × H`: post-activation of every hidden layer.
    acts: Vec<f32>,
    /// `D × cap × H`: pre-activation (Swish only; ReLU recovers its mask from `acts`).
    pre: Vec<f32>,
    /// `cap`: output pre-activation, then its gradient during backward.
    pre_out: Vec<f32>,
    /// Two ping-pong buffers for ∂L/∂h of the GEMM path's backward pass (sized by it).
    da: [Vec<f32>; 2],
    /// Two ping-pong buffers for inference, separate so that `infer` between a `forward` and
    /// its `backward` leaves the recorded pass intact.
    eval: [Vec<f32>; 2],
    /// Scratch of the bfloat16 passes.
    bf16: bf16::Scratch,
    /// Scratch of the f32 backward pass in tiles.
    tiles: tile64::Scratch,
}

impl Mlp {
    pub(crate) fn new(
        in_dim: usize,
        width: usize,
        depth: usize,
        activation: Activation,
        output_activation: OutputActivation,
        skip: bool,
    ) -> Self {
        let skip = (skip && depth >= 2).then_some(depth / 2);
        let mut off = 0;
        let mut layers = Vec::with_capacity(depth);
        for l in 0..depth {
            let mut fan_in = if l == 0 { in_dim } else { width };
            if Some(l) == skip {
                fan_in += in_dim;
            }
            let weight = off..off + fan_in * width;
            let bias = weight.end..weight.end + width;
            off = bias.end;
            layers.push(Layer { fan_in, weight, bias });
        }
        let out_weight = off..off + width;
        let out_bias = out_weight.end;
        Self {
            in_dim,
            width,
            activation,
            output_activation,
            skip,
            layers,
            out_weight,
            out_bias,
            num_params: out_bias + 1,
            bf16: false,
        }
    }

    /// With `want`, training takes the products in bfloat16 where this network allows and the
    /// CPU runs them faster than f32 ([`bf16_products_available`]), and inference takes the
    /// same products: with `vdpbf16ps` on AMD, on AMX tiles on Intel.
    pub(crate) fn with_bf16_products(mut self, want: bool) -> Self {
        self.bf16 = want && bf16::fits(&self) && bf16::bf16_pays();
        self
    }

    /// The bfloat16 passes wherever the CPU has AVX-512 BF16, for tests of the kernels.
    #[cfg(test)]
    pub(crate) fn with_bf16_kernels(mut self) -> Self {
        self.bf16 = bf16::fits(&self) && bf16::cpu_has_bf16();
        self
    }

    /// The kernel of the f32 passes in register tiles ([`tile64`]), where this network's shape
    /// and the CPU allow them; else the GEMMs run.
    fn tiled(&self) -> Option<tile64::Kernel> {
        tile64::Kernel::detect().filter(|_| tile64::fits(self))
    }

    /// Whether training takes the products in bfloat16.
    pub(crate) fn bf16_products(&self) -> bool {
        self.bf16
    }

    pub(crate) fn num_params(&self) -> usize {
        self.num_params
    }

    pub(crate) fn in_dim(&self) -> usize {
        self.in_dim
    }

    /// Seeded initialisation (see the module docs) of `params` (`num_params()` long).
    pub(crate) fn init(&self, params: &mut [f32], rng: &mut impl Rng) {
        assert_eq!(params.len(), self.num_params, "Mlp::init: wrong parameter count");
        for layer in &self.layers {
            let a = (6.0 / layer.fan_in as f32).sqrt();
            for w in &mut params[layer.weight.clone()] {
                *w = rng.random_range(-a..a);
            }
            params[layer.bias.clone()].fill(0.0);
        }
        let a = (6.0 / (self.width + 1) as f32).sqrt();
        for w in &mut params[self.out_weight.clone()] {
            *w = rng.random_range(-a..a);
        }
        params[self.out_bias] = 0.0;
    }

    /// Makes freshly initialised `params` evaluate to about `level` (> 0) everywhere: the
    /// output bias becomes the pre-activation of `level` and the output weights shrink by
    /// [`UNIFORM_START_WEIGHT_SCALE`], so the field starts nearly uniform (see
    /// [`TrainableField::start_uniform`]).
    pub(crate) fn start_uniform(&self, params: &mut [f32], level: f32) {
        assert!(level > 0.0 && level.is_finite(), "Mlp::start_uniform: level {level} must be positive");
        params[self.out_bias] = match self.output_activation {
            OutputActivation::Relu => level,
            OutputActivation::Softplus => kernels::inverse_softplus(level),
        };
        for w in &mut params[self.out_weight.clone()] {
            *w *= UNIFORM_START_WEIGHT_SCALE;
        }
    }

    /// Named tensors with ranges offset by `base`.
    pub(crate) fn tensors(&self, prefix: &str, base: usize) -> Vec<(String, Vec<usize>, Range<usize>)> {
        let shift = |r: &Range<usize>| r.start + base..r.end + base;
        let mut t = Vec::with_capacity(2 * self.layers.len() + 2);
        for (l, layer) in self.layers.iter().enumerate() {
            t.push((format!("{prefix}layers.{l}.weight"), vec![layer.fan_in, self.width], shift(&layer.weight)));
            t.push((format!("{prefix}layers.{l}.bias"), vec![self.width], shift(&layer.bias)));
        }
        t.push((format!("{prefix}output.weight"), vec![self.width, 1], shift(&self.out_weight)));
        t.push((format!("{prefix}output.bias"), vec![1], base + self.out_bias..base + self.out_bias + 1));
        t
    }

    fn reserve(&self, tape: &mut MlpTape, n: usize) {
        if n > tape.cap {
            let d = self.layers.len();
            tape.cap = n;
            tape.acts.resize(d * n * self.width, 0.0);
            if self.activation == Activation::Swish {
                tape.pre.resize(d * n * self.width, 0.0);
            }
            tape.pre_out.resize(n, 0.0);
        }
        tape.rows = n;
    }

    /// `x` is `n × in_dim`; writes `n` outputs and records the activations in `tape`.
    pub(crate) fn forward(&self, params: &[f32], x: &[f32], out: &mut [f32], tape: &mut MlpTape) {
        let n = out.len();
        assert_eq!(x.len(), n * self.in_dim, "Mlp::forward: input is not {n}×{}", self.in_dim);
        assert_eq!(params.len(), self.num_params, "Mlp::forward: wrong parameter count");
        self.reserve(tape, n);
        let h = self.width;
        let stride = tape.cap * h;
        if self.bf16 {
            bf16::forward(self, params, x, &mut tape.acts, stride, &mut tape.pre_out[..n], &mut tape.bf16);
        } else if let Some(kernel) = self.tiled() {
            tile64::forward(self, params, x, &mut tape.acts, stride, &mut tape.pre_out[..n], kernel);
        } else {
            self.forward_f32(params, x, tape, stride);
        }
        let pre_out = &tape.pre_out[..n];
        match self.output_activation {
            OutputActivation::Relu => {
                for (o, &z) in out.iter_mut().zip(pre_out.iter()) {
                    *o = z.max(0.0);
                }
            }
            OutputActivation::Softplus => kernels::softplus_into(pre_out, out),
        }
    }

    /// The hidden layers and the output's pre-activation of [`Mlp::forward`] over GEMMs in f32.
    fn forward_f32(&self, params: &[f32], x: &[f32], tape: &mut MlpTape, stride: usize) {
        let (n, h) = (tape.rows, self.width);
        for (l, layer) in self.layers.iter().enumerate() {
            let (prev, rest) = tape.acts.split_at_mut(l * stride);
            let act = &mut rest[..n * h];
            let z: &mut [f32] = match self.activation {
                Activation::Relu => act,
                Activation::Swish => &mut tape.pre[l * stride..l * stride + n * h],
            };
            kernels::fill_rows(z, &params[layer.bias.clone()]);
            let w = &params[layer.weight.clone()];
            let (inp, k) =
                if l == 0 { (x, self.in_dim) } else { (&prev[(l - 1) * stride..(l - 1) * stride + n * h], h) };
            matmul(z, n, h, k, inp, Op::N, &w[..k * h], Op::N, true);
            if Some(l) == self.skip {
                matmul(z, n, h, self.in_dim, x, Op::N, &w[k * h..], Op::N, true);
            }
            match self.activation {
                Activation::Relu => kernels::relu_inplace(&mut rest[..n * h]),
                Activation::Swish => kernels::swish(&tape.pre[l * stride..l * stride + n * h], &mut rest[..n * h]),
            }
        }
        let last = (self.layers.len() - 1) * stride;
        kernels::rows_dot(
            &tape.acts[last..last + n * h],
            &params[self.out_weight.clone()],
            params[self.out_bias],
            &mut tape.pre_out[..n],
        );
    }

    /// Inference: like [`Mlp::forward`] but keeps only two layers of activations (ping-pong,
    /// cache-resident for large chunks) and records nothing.
    pub(crate) fn infer(&self, params: &[f32], x: &[f32], out: &mut [f32], tape: &mut MlpTape) {
        let n = out.len();
        assert_eq!(x.len(), n * self.in_dim, "Mlp::infer: input is not {n}×{}", self.in_dim);
        assert_eq!(params.len(), self.num_params, "Mlp::infer: wrong parameter count");
        if self.bf16 && bf16::infer_pays() {
            bf16::infer(self, params, x, out, &mut tape.bf16);
        } else {
            match self.tiled() {
                Some(kernel) => tile64::infer(self, params, x, out, kernel),
                None => self.infer_gemm(params, x, out, tape),
            }
        }
        match self.output_activation {
            OutputActivation::Relu => out.iter_mut().for_each(|o| *o = o.max(0.0)),
            OutputActivation::Softplus => kernels::softplus_inplace(out),
        }
    }

    /// The output's pre-activation of [`Mlp::infer`] over GEMMs, any shape.
    fn infer_gemm(&self, params: &[f32], x: &[f32], out: &mut [f32], tape: &mut MlpTape) {
        let n = out.len();
        let h = self.width;
        for b in &mut tape.eval {
            if b.len() < n * h {
                b.resize(n * h, 0.0);
            }
        }
        let [b0, b1] = &mut tape.eval;
        let (mut prev, mut cur) = (&mut b0[..n * h], &mut b1[..n * h]);
        for (l, layer) in self.layers.iter().enumerate() {
            kernels::fill_rows(cur, &params[layer.bias.clone()]);
            let w = &params[layer.weight.clone()];
            let (inp, k): (&[f32], usize) = if l == 0 { (x, self.in_dim) } else { (prev, h) };
            matmul(cur, n, h, k, inp, Op::N, &w[..k * h], Op::N, true);
            if Some(l) == self.skip {
                matmul(cur, n, h, self.in_dim, x, Op::N, &w[k * h..], Op::N, true);
            }
            match self.activation {
                Activation::Relu => kernels::relu_inplace(cur),
                Activation::Swish => kernels::swish_inplace(cur),
            }
            std::mem::swap(&mut prev, &mut cur);
        }
        kernels::rows_dot(prev, &params[self.out_weight.clone()], params[self.out_bias], out);
    }

    /// Adds ∂L/∂params into `grads` (`num_params()` long) given `d_out = ∂L/∂out` of the last
    /// forward on `tape` with input `x`; writes ∂L/∂x into `d_x` (`n × in_dim`) if given.
    pub(crate) fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        tape: &mut MlpTape,
        d_out: &[f32],
        grads: &mut [f32],
        d_x: Option<&mut [f32]>,
    ) {
        let n = tape.rows;
        let h = self.width;
        assert_eq!(d_out.len(), n, "Mlp::backward: d_out has {} rows, forward had {n}", d_out.len());
        assert_eq!(x.len(), n * self.in_dim, "Mlp::backward: input is not {n}×{}", self.in_dim);
        assert_eq!(grads.len(), self.num_params, "Mlp::backward: wrong gradient length");
        let stride = tape.cap * h;
        // ∂L/∂(output pre-activation), stored over pre_out.
        let g = &mut tape.pre_out[..n];
        match self.output_activation {
            OutputActivation::Relu => {
                for (g, &d) in g.iter_mut().zip(d_out) {
                    *g = if *g > 0.0 { d } else { 0.0 };
                }
            }
            OutputActivation::Softplus => {
                for (g, &d) in g.iter_mut().zip(d_out) {
                    *g = d * kernels::sigmoid(*g);
                }
            }
        }
        grads[self.out_bias] += g.iter().sum::<f32>();
        if let Some(dx) = d_x.as_deref() {
            assert_eq!(dx.len(), n * self.in_dim, "Mlp::backward: d_x is not {n}×{}", self.in_dim);
        }
        if self.bf16 {
            let g = &tape.pre_out[..n];
            bf16::backward(self, params, x, &tape.acts, stride, g, &mut tape.bf16, grads, d_x);
            return;
        }
        if let Some(kernel) = self.tiled() {
            let pass = tile64::Pass { mlp: self, params, x, acts: &tape.acts, stride, g: &tape.pre_out[..n] };
            tile64::backward(pass, &mut tape.tiles, grads, d_x, kernel);
            return;
        }
        self.backward_gemm(params, x, tape, grads, d_x);
    }

    /// The layers of [`Mlp::backward`] over GEMMs in f32, after the output's gradient `g` was
    /// stored over `tape.pre_out`.
    fn backward_gemm(
        &self,
        params: &[f32],
        x: &[f32],
        tape: &mut MlpTape,
        grads: &mut [f32],
        mut d_x: Option<&mut [f32]>,
    ) {
        let (n, h) = (tape.rows, self.width);
        let stride = tape.cap * h;
        let g = &tape.pre_out[..n];
        let last = (self.layers.len() - 1) * stride;
        for b in &mut tape.da {
            if b.len() < n * h {
                b.resize(n * h, 0.0);
            }
        }
        let [da0, da1] = &mut tape.da;
        let (mut cur, mut next) = (&mut da0[..n * h], &mut da1[..n * h]);
        kernels::rows_dot_backward(
            &tape.acts[last..last + n * h],
            &params[self.out_weight.clone()],
            g,
            cur,
            &mut grads[self.out_weight.clone()],
        );
        if let Some(dx) = d_x.as_deref_mut() {
            dx.fill(0.0);
        }
        for (l, layer) in self.layers.iter().enumerate().rev() {
            let db = &mut grads[layer.bias.clone()];
            let off = l * stride;
            match self.activation {
                Activation::Relu => kernels::relu_backward(cur, &tape.acts[off..off + n * h], db),
                Activation::Swish => kernels::swish_backward(cur, &tape.pre[off..off + n * h], db),
            }
            let dz: &[f32] = cur;
            let w = &params[layer.weight.clone()];
            let dw = &mut grads[layer.weight.clone()];
            let (inp, k) = if l == 0 { (x, self.in_dim) } else { (&tape.acts[off - stride..off - stride + n * h], h) };
            // ∂L/∂W = inputᵀ · dz.
            matmul(&mut dw[..k * h], k, h, n, inp, Op::T, dz, Op::N, true);
            if Some(l) == self.skip {
                matmul(&mut dw[k * h..], self.in_dim, h, n, x, Op::T, dz, Op::N, true);
                if let Some(dx) = d_x.as_deref_mut() {
                    matmul(dx, n, self.in_dim, h, dz, Op::N, &w[k * h..], Op::T, true);
                }
            }
            // ∂L/∂input = dz · Wᵀ.
            if l > 0 {
                matmul(next, n, h, h, dz, Op::N, &w[..h * h], Op::T, false);
                std::mem::swap(&mut cur, &mut next);
            } else if let Some(dx) = d_x.as_deref_mut() {
                matmul(dx, n, self.in_dim, h, dz, Op::N, &w[..k * h], Op::T, true);
            }
        }
    }
}

/// The dissertation's field: positional encoding + MLP (module docs).
#[derive(Clone, Debug)]
pub struct MlpField {
    config: MlpConfig,
    encoding: PositionalEncoding,
    mlp: Mlp,
    params: Vec<f32>,
}

/// Per-thread scratch of [`MlpField`]: the encoded inputs and the network's activations.
#[derive(Debug, Default)]
pub struct MlpFieldTape {
    encoded: Vec<f32>,
    /// Encoded inputs of `eval`, kept apart from those `backward` needs.
    eval_encoded: Vec<f32>,
    mlp: MlpTape,
}

impl MlpField {
    /// A freshly initialised field for `input_dim` = 3 (E(x)) or 4 (E(x, t')) inputs.
    pub fn new(config: &MlpConfig, input_dim: usize, seed: u64) -> Result<Self, NeuralError> {
        Self::build(config, input_dim, Some(seed), usize::MAX)
    }

    /// The field with every parameter zero, for weights about to be loaded into all of them;
    /// refused before anything is allocated when it has more than `max_params` parameters
    /// (those the weights' file can hold).
    pub fn zeroed(config: &MlpConfig, input_dim: usize, max_params: usize) -> Result<Self, NeuralError> {
        Self::build(config, input_dim, None, max_params)
    }

    fn build(config: &MlpConfig, input_dim: usize, seed: Option<u64>, max_params: usize) -> Result<Self, NeuralError> {
        config.validate()?;
        if input_dim != 3 && input_dim != 4 {
            return Err(NeuralError::invalid("field input dimension", format!("{input_dim} (must be 3 or 4)")));
        }
        let encoding = PositionalEncoding::new(input_dim, config.space_freqs, config.time_freqs);
        let mlp = Mlp::new(
            encoding.output_dim(),
            config.width,
            config.depth,
            config.activation,
            config.output_activation,
            config.skip,
        );
        crate::trained::check_param_count(mlp.num_params(), max_params)?;
        let mut params = vec![0.0; mlp.num_params()];
        if let Some(seed) = seed {
            mlp.init(&mut params, &mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
        }
        Ok(Self { config: config.clone(), encoding, mlp, params })
    }

    pub fn config(&self) -> &MlpConfig {
        &self.config
    }

    /// Width of an encoded input row (the first layer's fan-in).
    pub fn encoded_dim(&self) -> usize {
        self.encoding.output_dim()
    }

    /// Floating-point operations of one training step per sample (forward + backward, GEMMs
    /// only), for reporting GFLOP/s.
    pub fn flops_per_sample(&self) -> f64 {
        let h = self.config.width as f64;
        let mut fwd = 0.0;
        let mut bwd = 0.0;
        for (l, layer) in self.mlp.layers.iter().enumerate() {
            let mac = layer.fan_in as f64 * h;
            fwd += 2.0 * mac;
            // ∂W always; ∂input only below the first layer (the skip part needs none).
            bwd += 2.0 * mac + if l > 0 { 2.0 * h * h } else { 0.0 };
        }
        fwd + bwd + 4.0 * h
    }

    fn encode(&self, inputs: &[f32], n: usize, tape: &mut MlpFieldTape) {
        let e = self.encoding.output_dim();
        if tape.encoded.len() < n * e {
            tape.encoded.resize(n * e, 0.0);
        }
        self.encoding.encode(inputs, &mut tape.encoded[..n * e]);
    }
}

impl TrainableField for MlpField {
    type Tape = MlpFieldTape;

    fn input_dim(&self) -> usize {
        self.encoding.input_dim()
    }

    fn new_tape(&self) -> MlpFieldTape {
        MlpFieldTape::default()
    }

    fn params(&self) -> &[f32] {
        &self.params
    }

    fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    fn eval(&self, inputs: &[f32], out: &mut [f32], tape: &mut MlpFieldTape) {
        let n = out.len();
        assert_eq!(inputs.len(), n * self.input_dim(), "MlpField: inputs are not {n}×{}", self.input_dim());
        let e = self.encoding.output_dim();
        if tape.eval_encoded.len() < n * e {
            tape.eval_encoded.resize(n * e, 0.0);
        }
        self.encoding.encode(inputs, &mut tape.eval_encoded[..n * e]);
        self.mlp.infer(&self.params, &tape.eval_encoded[..n * e], out, &mut tape.mlp);
    }

    fn forward(&self, inputs: &[f32], out: &mut [f32], tape: &mut MlpFieldTape) {
        let n = out.len();
        assert_eq!(inputs.len(), n * self.input_dim(), "MlpField: inputs are not {n}×{}", self.input_dim());
        self.encode(inputs, n, tape);
        let e = self.encoding.output_dim();
        self.mlp.forward(&self.params, &tape.encoded[..n * e], out, &mut tape.mlp);
    }

    fn backward(&self, tape: &mut MlpFieldTape, d_out: &[f32], grads: &mut [f32]) {
        let n = tape.mlp.rows;
        let e = self.encoding.output_dim();
        self.mlp.backward(&self.params, &tape.encoded[..n * e], &mut tape.mlp, d_out, grads, None);
    }

    fn tensors(&self) -> Vec<(String, Vec<usize>, Range<usize>)> {
        self.mlp.tensors("", 0)
    }

    fn start_uniform(&mut self, level: f32) {
        self.mlp.start_uniform(&mut self.params, level);
    }
}

impl std::fmt::Display for MlpConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "MLP {}×{} {} (L_x {}, L_t {}, skip {})",
            self.depth,
            self.width,
            self.activation.name(),
            self.space_freqs,
            self.time_freqs,
            self.skip
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_parameter_count_matches_the_dissertation() {
        let f = MlpField::new(&MlpConfig::default(), 3, 0).unwrap();
        assert_eq!(f.num_params(), 487_169);
        let t = f.tensors();
        assert_eq!(t.iter().map(|(_, s, _)| s.iter().product::<usize>()).sum::<usize>(), 487_169);
        assert_eq!(t[8].1, vec![256 + 51, 256], "the skip layer takes [h, γ(x)]");
    }
}
