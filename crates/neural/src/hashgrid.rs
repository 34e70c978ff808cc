//! A fast field representation beyond the dissertation: the multiresolution hash encoding of
//! instant-ngp (Müller et al. 2022, "Instant Neural Graphics Primitives with a
//! Multiresolution Hash Encoding", Eq. 2–4) followed by a tiny MLP with a non-negative output,
//! as a [`TrainableField`].
//!
//! # Encoding
//! Level `l ∈ 0 … L−1` has resolution `N_l = ⌊N_min · b^l⌋`, `b = exp((ln N_max − ln N_min) /
//! (L − 1))` (instant-ngp Eq. 2–3). A point `u ∈ [0, 1]³` (clamped) sits at `p = u N_l` in a
//! grid of `(N_l + 1)³` vertices; its feature vector at that level is the trilinear blend of
//! the `F` features stored at the 8 surrounding vertices. Levels whose vertex count fits the
//! table (`≤ 2^T`) are **dense** (vertex index `x + (N+1)(y + (N+1) z)`, no collisions, the
//! table sized exactly); finer levels are **hashed** into `2^T` entries with instant-ngp's
//! spatial hash `⊕_i x_i π_i mod 2^T`, `π = (1, 2654435761, 805459861, 3674653429)`. The
//! `L · F` features (level-major) feed the MLP.
//!
//! # Space–time (4D inputs)
//! The frame time `t'` is mapped to `[0, 1]` by `t' / time_span` (clamped) and the grid is 4D:
//! level `l` has `min(N_l, time_resolution)` cells along time (or, with
//! `time_base_resolution`, from that many at the coarsest level growing geometrically to
//! `time_resolution` at the finest), the 16 surrounding vertices are blended quadrilinearly,
//! and hashing uses the 4th prime. Dense levels stay dense in 4D while they fit.
//!
//! With `static_levels = S > 0` a 4D field has `S` more levels without a time axis, at
//! resolutions from `N_min` to `N_max` spaced as above: one table that every instant reads,
//! for what the instants have in common (the static-plus-dynamic split of dynamic radiance
//! fields such as K-Planes and HexPlane), while the space–time levels keep each frame apart.
//! Their features follow the space–time levels' (`(L + S) · F` inputs to the MLP).
//!
//! # Parameter layout
//! `grid.level.l` `[entries_l, F]` for each level (feature-fastest), then the MLP's tensors
//! prefixed `mlp.` (see [`crate::mlp`]). Table entries start uniform in `±init_scale`
//! (instant-ngp: 10⁻⁴), the MLP as in [`crate::mlp`].
//!
//! # Backward
//! The gradient of a table entry is the sum over the points and corners that touched it. Each
//! call works level by level over its chunk, so one level's table stays in cache, and scatters
//! into the caller's per-thread gradient buffer, which needs no synchronisation (the
//! threading contract of [`TrainableField`]); the caller's reduction sums the buffers.

use std::ops::Range;

use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::error::NeuralError;
use crate::field::TrainableField;
use crate::mlp::{Activation, Mlp, MlpTape, OutputActivation};

/// Whether the encoding may use the vectorised kernels (see [`set_vectorised`]).
pub(crate) static VECTORISED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(true);

/// Turns the vectorised passes of the encoding (forward, and the backward's weights and
/// indices) on (the default, where the CPU has AVX2 and FMA) or off (the scalar loop
/// everywhere), for every field in the process: for
/// benchmarks that compare the two in one run, and as a fallback.
pub fn set_vectorised(enabled: bool) {
    VECTORISED.store(enabled, std::sync::atomic::Ordering::Relaxed);
}

pub(crate) const PRIMES: [u32; 4] = [1, 2_654_435_761, 805_459_861, 3_674_653_429];

/// The widest start of the hash tables ([`HashGridConfig::init_scale`]), 10⁴ times the default.
/// On a small synthetic jet (4 cameras, 30 iterations of `fast`) a start of ±1 trained (volume
/// NRMSE 0.72), ±10 barely (0.96), ±10³ left the field black (1.0) and ±10³⁰ made the loss of
/// iteration 0 infinite.
pub const MAX_INIT_SCALE: f32 = 1.0;

/// Configuration of [`HashGridField`]; defaults follow instant-ngp's NeRF setting, with the
/// finest resolution matched to the volumes we reconstruct.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HashGridConfig {
    /// Number of levels `L`. Default 16.
    pub levels: usize,
    /// Features per level `F`: 1, 2, 4 or 8. Default 2.
    pub features_per_level: usize,
    /// log₂ of the entries per hashed level `T`. Default 19.
    pub log2_table_size: u32,
    /// Coarsest resolution `N_min` (cells per box side). Default 16.
    pub base_resolution: usize,
    /// Finest resolution `N_max`. Default 512.
    pub max_resolution: usize,
    /// 4D only: the most cells along time at any level. Default 16.
    pub time_resolution: usize,
    /// 4D only: cells along time at the coarsest level. The levels between grow geometrically
    /// to `time_resolution` at the finest (rounded, at most `N_l`), so coarse levels blend
    /// neighbouring frames and fine ones keep each frame apart. 0: every level has
    /// `min(N_l, time_resolution)` cells. Default 0.
    pub time_base_resolution: usize,
    /// 4D only: the span of `t'` mapped onto `[0, 1]` (e.g. number of frames − 1). Default 1.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub time_span: f32,
    /// 4D only: levels without a time axis added to the `levels` space–time ones, at
    /// resolutions from `base_resolution` to `max_resolution` (module docs). Default 0.
    pub static_levels: usize,
    /// Hidden layers of the MLP. Default 2.
    pub mlp_depth: usize,
    /// Width of the MLP's hidden layers. Default 64.
    pub mlp_width: usize,
    /// Hidden activation of the MLP. Default ReLU.
    pub activation: Activation,
    /// Output activation. Default softplus.
    pub output_activation: OutputActivation,
    /// Table entries start uniform in `±init_scale`, at most [`MAX_INIT_SCALE`]. Default 1e-4.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub init_scale: f32,
    /// Coarse-to-fine training: the finer half of the levels (`⌊L/2⌋` finest) are not trained
    /// at first, one more joins every `coarse_to_fine` optimiser steps (their tables keep their
    /// near-zero start until then), at most [`crate::train::MAX_ITERATION_SPAN`]. 0 trains
    /// every level from the start. Default 0.
    pub coarse_to_fine: usize,
    /// The precision of the MLP's matrix products while training. Default `f32`.
    pub mlp_precision: MlpPrecision,
}

/// The precision of the hash grid's MLP products in training (see [`HashGridConfig`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MlpPrecision {
    /// f32 throughout.
    #[default]
    F32,
    /// On CPUs where AVX-512 BF16 pays ([`crate::bf16_products_available`]: AMD Zen 4 and 5),
    /// the products of the forward and backward passes take their operands in bfloat16 and sum
    /// in f32 (two multiply–adds per lane and instruction); the activations, biases, gradients'
    /// sums and Adam stay in f32, as does inference. Only for the ReLU MLPs of width 64 whose
    /// input is at most 64 features wide; everywhere else, and on other CPUs, f32.
    Bf16,
}

impl Default for HashGridConfig {
    fn default() -> Self {
        Self {
            levels: 16,
            features_per_level: 2,
            log2_table_size: 19,
            base_resolution: 16,
            max_resolution: 512,
            time_resolution: 16,
            time_base_resolution: 0,
            time_span: 1.0,
            static_levels: 0,
            mlp_depth: 2,
            mlp_width: 64,
            activation: Activation::Relu,
            output_activation: OutputActivation::Softplus,
            init_scale: 1e-4,
            coarse_to_fine: 0,
            mlp_precision: MlpPrecision::F32,
        }
    }
}

impl HashGridConfig {
    pub fn validate(&self) -> Result<(), NeuralError> {
        // Named by their keys, under "hash-grid." (the key of this field in a configuration).
        let bad = |what: &str, why: String| Err(NeuralError::invalid(format!("hash-grid.{what}"), why));
        if self.levels == 0 || self.levels > 32 {
            return bad("levels", format!("{} not in 1..=32", self.levels));
        }
        if ![1, 2, 4, 8].contains(&self.features_per_level) {
            return bad("features_per_level", format!("{} not 1, 2, 4 or 8", self.features_per_level));
        }
        if !(4..=24).contains(&self.log2_table_size) {
            return bad("log2_table_size", format!("{} not in 4..=24", self.log2_table_size));
        }
        if self.base_resolution == 0 || self.max_resolution < self.base_resolution || self.max_resolution > 1 << 16 {
            return bad(
                "max_resolution",
                format!("need 1 ≤ base {} ≤ max {} ≤ 65536", self.base_resolution, self.max_resolution),
            );
        }
        if self.time_resolution == 0 || !(self.time_span > 0.0 && self.time_span.is_finite()) {
            return bad(
                "time_span",
                format!("time_resolution {} and time_span {} must be positive", self.time_resolution, self.time_span),
            );
        }
        if self.static_levels > 32 {
            return bad("static_levels", format!("{} not in 0..=32", self.static_levels));
        }
        if !(1..=16).contains(&self.mlp_depth) {
            return bad("mlp_depth", format!("{} not in 1..=16 hidden layers", self.mlp_depth));
        }
        if !(1..=1024).contains(&self.mlp_width) {
            return bad("mlp_width", format!("{} not in 1..=1024 units per hidden layer", self.mlp_width));
        }
        // A level that joins only after more steps than any run takes would never train.
        if self.coarse_to_fine > crate::train::MAX_ITERATION_SPAN {
            return bad(
                "coarse_to_fine",
                format!(
                    "{} not in 0..={} optimiser steps between levels",
                    self.coarse_to_fine,
                    crate::train::MAX_ITERATION_SPAN
                ),
            );
        }
        if !(0.0..=MAX_INIT_SCALE).contains(&self.init_scale) {
            return bad(
                "init_scale",
                format!(
                    "{} is not a half-width of the tables' start in [0, {MAX_INIT_SCALE}] (default 1e-4; wider \
                     starts leave the field black or make the first loss infinite)",
                    self.init_scale
                ),
            );
        }
        Ok(())
    }
}

/// One level of the grid.
#[derive(Clone, Debug)]
struct Level {
    /// Cells per spatial side.
    res: u32,
    /// Cells along time (4D; 0 on a level without a time axis, whose time weight is then
    /// exactly 1 at the lower vertex, so the upper one is never read).
    res_t: u32,
    /// Entries (vertices or hash slots).
    entries: usize,
    dense: bool,
    /// Offset of the level's table in `params`.
    offset: usize,
}

/// Cells along time at level `l` before the cap by `N_l` (see
/// [`HashGridConfig::time_base_resolution`]).
fn time_cells(config: &HashGridConfig, l: usize) -> u32 {
    let top = config.time_resolution.max(1) as f64;
    let base = config.time_base_resolution;
    if base == 0 || config.levels < 2 {
        return top as u32;
    }
    let base = (base as f64).min(top);
    let f = l as f64 / (config.levels - 1) as f64;
    (base * (top / base).powf(f)).round().clamp(1.0, top) as u32
}

/// Multiresolution hash encoding + tiny MLP (module docs).
#[derive(Clone, Debug)]
pub struct HashGridField {
    config: HashGridConfig,
    input_dim: usize,
    levels: Vec<Level>,
    grid_params: usize,
    mlp: Mlp,
    params: Vec<f32>,
}

/// Per-thread scratch of [`HashGridField`].
#[derive(Debug, Default)]
pub struct HashGridTape {
    rows: usize,
    inputs: Vec<f32>,
    features: Vec<f32>,
    d_features: Vec<f32>,
    /// Features of `eval`, kept apart from those `backward` needs.
    eval_features: Vec<f32>,
    mlp: MlpTape,
}

impl HashGridField {
    /// A freshly initialised field for `input_dim` = 3 or 4 inputs.
    pub fn new(config: &HashGridConfig, input_dim: usize, seed: u64) -> Result<Self, NeuralError> {
        Self::build(config, input_dim, Some(seed), usize::MAX)
    }

    /// The field with every parameter zero, for weights about to be loaded into all of them
    /// ([`crate::weights::load_weights`]): no random draws (a second and more of a load's time
    /// for the larger tables went to drawing values that were then overwritten).
    ///
    /// Refused before anything is allocated when it has more than `max_params` parameters (those
    /// the weights' file can hold).
    pub fn zeroed(config: &HashGridConfig, input_dim: usize, max_params: usize) -> Result<Self, NeuralError> {
        Self::build(config, input_dim, None, max_params)
    }

    fn build(
        config: &HashGridConfig,
        input_dim: usize,
        seed: Option<u64>,
        max_params: usize,
    ) -> Result<Self, NeuralError> {
        config.validate()?;
        if input_dim != 3 && input_dim != 4 {
            return Err(NeuralError::invalid("field input dimension", format!("{input_dim} (must be 3 or 4)")));
        }
        if input_dim == 3 && config.static_levels > 0 {
            return Err(NeuralError::invalid(
                "hash-grid static levels",
                format!(
                    "{} given to a field of space alone (they are for fields of space and time)",
                    config.static_levels
                ),
            ));
        }
        let f = config.features_per_level;
        let table = 1usize << config.log2_table_size;
        // `count` resolutions from N_min to N_max (instant-ngp Eq. 2–3).
        let resolutions = |count: usize| -> Vec<u32> {
            let growth = if count > 1 {
                ((config.max_resolution as f64).ln() - (config.base_resolution as f64).ln()) / (count - 1) as f64
            } else {
                0.0
            }
            .exp();
            (0..count)
                .map(|l| ((config.base_resolution as f64 * growth.powi(l as i32)) + 1e-9).floor().max(1.0) as u32)
                .collect()
        };
        let timed = resolutions(config.levels).into_iter().enumerate().map(|(l, res)| {
            let res_t = if input_dim == 4 { res.min(time_cells(config, l)) } else { 0 };
            (res, res_t)
        });
        let fixed = resolutions(config.static_levels).into_iter().map(|res| (res, 0));
        let mut levels = Vec::with_capacity(config.levels + config.static_levels);
        let mut offset = 0;
        for (res, res_t) in timed.chain(fixed) {
            let side = res as u128 + 1;
            let vertices = side * side * side * (res_t as u128 + 1);
            let dense = vertices <= table as u128;
            let entries = if dense { vertices as usize } else { table };
            levels.push(Level { res, res_t, entries, dense, offset });
            offset += entries * f;
        }
        let mlp = Mlp::new(
            levels.len() * f,
            config.mlp_width,
            config.mlp_depth,
            config.activation,
            config.output_activation,
            false,
        )
        .with_bf16_products(config.mlp_precision == MlpPrecision::Bf16);
        crate::trained::check_param_count(offset + mlp.num_params(), max_params)?;
        let mut params = vec![0.0; offset + mlp.num_params()];
        if let Some(seed) = seed {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let s = config.init_scale;
            if s > 0.0 {
                for p in &mut params[..offset] {
                    *p = rng.random_range(-s..s);
                }
            }
            mlp.init(&mut params[offset..], &mut rng);
        }
        Ok(Self { config: config.clone(), input_dim, levels, grid_params: offset, mlp, params })
    }

    pub fn config(&self) -> &HashGridConfig {
        &self.config
    }

    /// `(resolution, entries, dense)` of each level, coarse to fine.
    pub fn level_summary(&self) -> Vec<(u32, usize, bool)> {
        self.levels.iter().map(|l| (l.res, l.entries, l.dense)).collect()
    }

    /// Number of grid-table parameters (the MLP's follow them).
    pub fn grid_params(&self) -> usize {
        self.grid_params
    }

    /// Encodes `inputs` (`n × input_dim`) into `features` (grown to `n × L·F` if needed);
    /// `training`: the points are training samples in random order (see
    /// [`crate::hashgrid_simd::LevelArgs::fetch_ahead`]).
    fn encode(&self, inputs: &[f32], features: &mut Vec<f32>, training: bool) {
        let lf = self.levels.len() * self.config.features_per_level;
        let n = inputs.len() / self.input_dim;
        if features.len() < n * lf {
            features.resize(n * lf, 0.0);
        }
        let feats = &mut features[..n * lf];
        for l in 0..self.levels.len() {
            self.dispatch::<false>(l, inputs, feats, &mut [], training);
        }
    }

    /// Runs `level_pass` monomorphised for the input dimension and features per level.
    fn dispatch<const BACKWARD: bool>(
        &self,
        l: usize,
        inputs: &[f32],
        feats: &mut [f32],
        grads: &mut [f32],
        training: bool,
    ) {
        match self.input_dim {
            3 => self.dispatch_f::<3, BACKWARD>(l, inputs, feats, grads, training),
            _ => self.dispatch_f::<4, BACKWARD>(l, inputs, feats, grads, training),
        }
    }

    fn dispatch_f<const D: usize, const B: bool>(&self, l: usize, x: &[f32], f: &mut [f32], g: &mut [f32], t: bool) {
        let level = &self.levels[l];
        match (self.config.features_per_level, level.dense) {
            (1, true) => self.level_pass::<D, 1, B, true>(l, level, x, f, g, t),
            (1, false) => self.level_pass::<D, 1, B, false>(l, level, x, f, g, t),
            (2, true) => self.level_pass::<D, 2, B, true>(l, level, x, f, g, t),
            (2, false) => self.level_pass::<D, 2, B, false>(l, level, x, f, g, t),
            (4, true) => self.level_pass::<D, 4, B, true>(l, level, x, f, g, t),
            (4, false) => self.level_pass::<D, 4, B, false>(l, level, x, f, g, t),
            (_, true) => self.level_pass::<D, 8, B, true>(l, level, x, f, g, t),
            (_, false) => self.level_pass::<D, 8, B, false>(l, level, x, f, g, t),
        }
    }

    /// One level over all rows. Forward: gathers the interpolated features into `feats`
    /// (`n × L·F`). Backward (`BACKWARD`): `feats` holds ∂L/∂features and is scattered into the
    /// level's slice of `grads` (the grid part of the gradient, laid out like the tables).
    #[inline(never)]
    fn level_pass<const D: usize, const F: usize, const BACKWARD: bool, const DENSE: bool>(
        &self,
        l: usize,
        level: &Level,
        inputs: &[f32],
        feats: &mut [f32],
        grads: &mut [f32],
        training: bool,
    ) {
        let lf = self.levels.len() * F;
        debug_assert_eq!(DENSE, level.dense);
        let res = level.res;
        let res_t = level.res_t;
        let side = res as usize + 1;
        // Vertex-index strides of a dense level (x fastest).
        let mut stride = [0usize; 4];
        let mut acc_stride = 1;
        for a in 0..D {
            stride[a] = acc_stride;
            acc_stride *= side;
        }
        let mask = level.entries.wrapping_sub(1);
        let inv_span = 1.0 / self.config.time_span;
        let time_exact = D == 4 && res_t as f32 == self.config.time_span;
        let table_range = level.offset..level.offset + level.entries * F;
        let table = &self.params[table_range.clone()];
        let gtable: &mut [f32] = if BACKWARD { &mut grads[table_range] } else { &mut [] };
        // Whole groups of sixteen or eight rows run vectorised where the CPU can.
        let mut done = 0;
        #[cfg(target_arch = "x86_64")]
        if crate::hashgrid_simd::available() {
            let args = crate::hashgrid_simd::LevelArgs {
                res,
                res_t,
                inv_span,
                time_exact,
                stride,
                mask,
                table,
                column: l * F,
                row_len: lf,
                fetch_ahead: training,
            };
            // SAFETY: AVX2 and FMA were detected just above; `table` and `gtable` are this
            // level's whole table and its gradient (`entries × F`: every dense vertex, or
            // `mask + 1` hash slots).
            done = unsafe {
                if BACKWARD {
                    crate::hashgrid_simd::level_backward::<D, F, DENSE>(&args, inputs, feats, gtable)
                } else {
                    crate::hashgrid_simd::level_forward::<D, F, DENSE>(&args, inputs, feats)
                }
            };
        }
        for (x, row) in inputs.chunks_exact(D).zip(feats.chunks_exact_mut(lf)).skip(done) {
            // Per axis: the weights of the lower and upper vertex, and their contributions to the
            // vertex index (dense: coordinate × stride, summed) or hash (coordinate × prime, xored).
            let mut wgt = [[0.0f32; 2]; 4];
            let mut part = [[0u32; 2]; 4];
            for a in 0..D {
                let (u, r) = if a < 3 { (x[a], res) } else { (x[a] * inv_span, res_t) };
                let p = if a == 3 && time_exact { x[a].clamp(0.0, r as f32) } else { u.clamp(0.0, 1.0) * r as f32 };
                let c = (p as u32).min(r.saturating_sub(1));
                let t = p - c as f32;
                wgt[a] = [1.0 - t, t];
                part[a] = if DENSE {
                    [c * stride[a] as u32, (c + 1) * stride[a] as u32]
                } else {
                    [c.wrapping_mul(PRIMES[a]), (c + 1).wrapping_mul(PRIMES[a])]
                };
            }
            let out: &mut [f32; F] = (&mut row[l * F..(l + 1) * F]).try_into().expect("F features");
            let mut acc = [0.0f32; F];
            for c in 0..1usize << D {
                if D == 4 && wgt[3][(c >> 3) & 1] == 0.0 {
                    // A zero time weight adds exactly nothing (points on a frame's vertex).
                    continue;
                }
                let mut w = 1.0f32;
                let mut key = 0u32;
                for a in 0..D {
                    let bit = (c >> a) & 1;
                    w *= wgt[a][bit];
                    key = if DENSE { key + part[a][bit] } else { key ^ part[a][bit] };
                }
                let idx = if DENSE { key as usize } else { key as usize & mask };
                if BACKWARD {
                    let g = &mut gtable[idx * F..idx * F + F];
                    for k in 0..F {
                        g[k] += w * out[k];
                    }
                } else {
                    let t = &table[idx * F..idx * F + F];
                    for k in 0..F {
                        acc[k] += w * t[k];
                    }
                }
            }
            if !BACKWARD {
                *out = acc;
            }
        }
    }
}

impl TrainableField for HashGridField {
    type Tape = HashGridTape;

    fn input_dim(&self) -> usize {
        self.input_dim
    }

    fn time_on_frame_axis(&self) -> bool {
        // The time axis has one vertex per frame of the window (`field_for_window`).
        self.input_dim == 4
    }

    fn restrict_gradient(&self, steps_taken: u64, grads: &mut [f32]) {
        let every = self.config.coarse_to_fine as u64;
        if every == 0 {
            return;
        }
        // The space–time levels and the static ones each open coarse to fine.
        let (timed, fixed) = self.levels.split_at(self.config.levels);
        for group in [timed, fixed] {
            let active = (group.len().div_ceil(2) as u64 + steps_taken / every).min(group.len() as u64) as usize;
            if let (Some(first), Some(last)) = (group.get(active), group.last()) {
                let f = self.config.features_per_level;
                grads[first.offset..last.offset + last.entries * f].fill(0.0);
            }
        }
    }

    fn detail_dims(&self) -> Option<[usize; 3]> {
        let finest = self.levels.last().map_or(1, |l| l.res as usize);
        Some([finest; 3])
    }

    fn new_tape(&self) -> HashGridTape {
        HashGridTape::default()
    }

    fn params(&self) -> &[f32] {
        &self.params
    }

    fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }

    fn start_uniform(&mut self, level: f32) {
        self.mlp.start_uniform(&mut self.params[self.grid_params..], level);
    }

    fn bf16_products(&self) -> bool {
        self.mlp.bf16_products()
    }

    fn eval(&self, inputs: &[f32], out: &mut [f32], tape: &mut HashGridTape) {
        let n = out.len();
        let d = self.input_dim;
        assert_eq!(inputs.len(), n * d, "HashGridField: inputs are not {n}×{d}");
        self.encode(inputs, &mut tape.eval_features, false);
        let lf = self.mlp.in_dim();
        self.mlp.infer(&self.params[self.grid_params..], &tape.eval_features[..n * lf], out, &mut tape.mlp);
    }

    fn forward(&self, inputs: &[f32], out: &mut [f32], tape: &mut HashGridTape) {
        let n = out.len();
        let d = self.input_dim;
        assert_eq!(inputs.len(), n * d, "HashGridField: inputs are not {n}×{d}");
        if tape.inputs.len() < n * d {
            tape.inputs.resize(n * d, 0.0);
        }
        tape.inputs[..n * d].copy_from_slice(inputs);
        tape.rows = n;
        self.encode(&tape.inputs[..n * d], &mut tape.features, true);
        let lf = self.mlp.in_dim();
        self.mlp.forward(&self.params[self.grid_params..], &tape.features[..n * lf], out, &mut tape.mlp);
    }

    fn backward(&self, tape: &mut HashGridTape, d_out: &[f32], grads: &mut [f32]) {
        let n = tape.rows;
        assert_eq!(grads.len(), self.params.len(), "HashGridField::backward: wrong gradient length");
        let lf = self.mlp.in_dim();
        if tape.d_features.len() < n * lf {
            tape.d_features.resize(n * lf, 0.0);
        }
        let (grid_grads, mlp_grads) = grads.split_at_mut(self.grid_params);
        self.mlp.backward(
            &self.params[self.grid_params..],
            &tape.features[..n * lf],
            &mut tape.mlp,
            d_out,
            mlp_grads,
            Some(&mut tape.d_features[..n * lf]),
        );
        let inputs = &tape.inputs[..n * self.input_dim];
        let dfeat = &mut tape.d_features[..n * lf];
        // The level tables come first in `params`, so `grid_grads` indexes like them.
        for l in 0..self.levels.len() {
            self.dispatch::<true>(l, inputs, dfeat, grid_grads, true);
        }
    }

    fn tensors(&self) -> Vec<(String, Vec<usize>, Range<usize>)> {
        let f = self.config.features_per_level;
        let mut t: Vec<_> = self
            .levels
            .iter()
            .enumerate()
            .map(|(l, level)| {
                (format!("grid.level.{l}"), vec![level.entries, f], level.offset..level.offset + level.entries * f)
            })
            .collect();
        t.extend(self.mlp.tensors("mlp.", self.grid_params));
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table start wider than [`MAX_INIT_SCALE`] is refused naming init_scale (±10³⁰ made the
    /// loss of iteration 0 infinite); 0, the default and the bound pass.
    #[test]
    fn init_scale_beyond_the_bound_is_refused() {
        for s in [1.01, 1e3, 1e30, f32::INFINITY, -1e-4, f32::NAN] {
            let e = HashGridConfig { init_scale: s, ..HashGridConfig::default() }.validate().expect_err("refused");
            let e = e.to_string();
            assert!(e.starts_with("invalid hash-grid.init_scale: ") && e.contains("in [0, 1]"), "{s}: {e}");
        }
        for s in [0.0, 1e-4, MAX_INIT_SCALE] {
            HashGridConfig { init_scale: s, ..HashGridConfig::default() }.validate().expect("valid");
        }
    }

    #[test]
    fn coarse_levels_are_dense_and_fine_levels_hashed() {
        let f = HashGridField::new(&HashGridConfig::default(), 3, 1).unwrap();
        let s = f.level_summary();
        assert_eq!(s[0], (16, 17 * 17 * 17, true));
        assert_eq!(s.last().unwrap().0, 512);
        assert!(!s.last().unwrap().2);
        assert!(s.iter().all(|&(r, e, dense)| dense == ((r as usize + 1).pow(3) <= 1 << 19) && e <= 1 << 19));
    }

    /// Trilinear (quadrilinear) interpolation on a dense level reproduces a field linear in the
    /// vertex coordinates exactly; coordinates outside the box are clamped to it.
    #[test]
    fn interpolation_reproduces_linear_functions() {
        for (d, log2) in [(3, 12), (4, 14)] {
            let cfg = HashGridConfig {
                levels: 1,
                base_resolution: 7,
                max_resolution: 7,
                time_resolution: 5,
                time_span: 2.0,
                log2_table_size: log2,
                ..HashGridConfig::default()
            };
            let mut f = HashGridField::new(&cfg, d, 3).unwrap();
            let level = f.levels[0].clone();
            let side = level.res as usize + 1;
            let verts = side.pow(3) * (level.res_t as usize + 1);
            for v in 0..verts {
                let (x, z) = (v % side, (v / (side * side)) % side);
                let t = v / side.pow(3);
                assert!(level.dense);
                let idx = v;
                f.params[2 * idx] = x as f32 / 7.0 + if d == 4 { t as f32 / 5.0 } else { 0.0 };
                f.params[2 * idx + 1] = z as f32 / 7.0;
            }
            let inputs = [0.1f32, 0.5, 0.93, 1.2, 0.77, 0.01, 0.4, 0.3, 1.0, 0.999, 0.0, 2.0];
            let n = inputs.len() / d;
            let mut tape = f.new_tape();
            let mut out = vec![0.0; n];
            f.forward(&inputs[..n * d], &mut out, &mut tape);
            for (i, x) in inputs[..n * d].chunks(d).enumerate() {
                let want0 = x[0].clamp(0.0, 1.0) + if d == 4 { (x[3] / 2.0).clamp(0.0, 1.0) } else { 0.0 };
                assert!((tape.features[2 * i] - want0).abs() < 1e-5, "d {d} T {log2}: {x:?}");
                assert!((tape.features[2 * i + 1] - x[2].clamp(0.0, 1.0)).abs() < 1e-5, "d {d} T {log2}: {x:?}");
            }
        }
    }

    /// Checks that `batch` (the encoding of all of `inputs`, `n × d`) equals the encoding of
    /// each row alone (the scalar loop) to rounding.
    fn assert_encoding_matches_rows(field: &HashGridField, inputs: &[f32], batch: &[f32], what: &str) {
        let (d, lf) = (field.input_dim, field.levels.len() * field.config.features_per_level);
        let mut single = Vec::new();
        for (r, x) in inputs.chunks(d).enumerate() {
            field.encode(x, &mut single, false);
            for k in 0..lf {
                let (a, b) = (batch[r * lf + k], single[k]);
                assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{what}: row {r} feature {k}: {a} vs {b}");
            }
        }
    }

    /// The gradient of every level's table given ∂L/∂features `dfeat`, scattered for the whole
    /// batch `inputs` at once and row by row (the scalar loop): `(batch, rows)`.
    fn gradients_batched_and_by_row(field: &HashGridField, inputs: &[f32], dfeat: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let (d, levels) = (field.input_dim, field.levels.len());
        let lf = levels * field.config.features_per_level;
        let mut batch = vec![0.0f32; field.num_params()];
        let mut df = dfeat.to_vec();
        for l in 0..levels {
            field.dispatch::<true>(l, inputs, &mut df, &mut batch, true);
        }
        let mut rows = vec![0.0f32; field.num_params()];
        for (r, x) in inputs.chunks(d).enumerate() {
            let mut df = dfeat[r * lf..(r + 1) * lf].to_vec();
            for l in 0..levels {
                field.dispatch::<true>(l, x, &mut df, &mut rows, false);
            }
        }
        (batch, rows)
    }

    /// The small grid of the batch tests: dense and hashed levels, a time axis for 4D inputs.
    fn mixed_grid(f: usize, log2: u32, init_scale: f32) -> HashGridConfig {
        HashGridConfig {
            levels: 6,
            features_per_level: f,
            base_resolution: 5,
            max_resolution: 90,
            time_resolution: 6,
            time_span: 3.0,
            log2_table_size: log2,
            init_scale,
            ..HashGridConfig::default()
        }
    }

    /// The encoding of a batch (sixteen or eight rows at a time vectorised where the CPU can) equals the
    /// row-by-row scalar encoding, for dense and hashed levels, 3D and 4D inputs and every
    /// feature count, with coordinates outside the box clamped alike.
    #[test]
    fn batched_encoding_matches_row_by_row() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (d, f, log2) in [(3, 2, 14), (3, 1, 12), (3, 4, 15), (4, 2, 15), (4, 8, 12)] {
            let field = HashGridField::new(&mixed_grid(f, log2, 1.0), d, 5).unwrap();
            assert!(field.levels.iter().any(|l| l.dense) && field.levels.iter().any(|l| !l.dense));
            let n = 43;
            let inputs: Vec<f32> = (0..n * d)
                .map(|i| if i % d == 3 { rng.random_range(-0.5..3.5) } else { rng.random_range(-0.1..1.1) })
                .collect();
            // Both ways the vectorised pass runs: fetching entries ahead (training) or not.
            for_each_width(|width| {
                for training in [false, true] {
                    let mut batch = Vec::new();
                    field.encode(&inputs, &mut batch, training);
                    let what = format!("d {d} F {f} training {training} {width}");
                    assert_encoding_matches_rows(&field, &inputs, &batch, &what);
                }
            });
        }
    }

    /// Runs `check` with the vectorised passes at each width this CPU takes: sixteen rows at a
    /// time where it does, then eight (43 or 45 rows run sixteen, eight and the scalar loop).
    fn for_each_width(mut check: impl FnMut(&str)) {
        #[cfg(target_arch = "x86_64")]
        for narrow in [false, true] {
            crate::hashgrid_simd::NARROW.with(|n| n.set(narrow));
            check(if narrow { "narrow" } else { "widest" });
        }
        #[cfg(target_arch = "x86_64")]
        crate::hashgrid_simd::NARROW.with(|n| n.set(false));
        #[cfg(not(target_arch = "x86_64"))]
        check("scalar");
    }

    /// The encoding's gradient scattered for a batch (weights and indices sixteen or eight rows at a time,
    /// vectorised where the CPU can) is bit-identical to the scalar loop run row by row: the
    /// same products added in the same order, also where the rows share vertices.
    #[test]
    fn batched_encoding_gradient_matches_row_by_row_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
        for (d, f, log2) in [(3, 2, 14), (3, 1, 12), (3, 4, 15), (4, 2, 15), (4, 8, 12)] {
            let cfg = mixed_grid(f, log2, HashGridConfig::default().init_scale);
            let field = HashGridField::new(&cfg, d, 5).unwrap();
            let n = 45;
            // Points along a short segment share cells at every level; a few fall outside.
            let start: Vec<f32> = (0..d).map(|_| rng.random_range(-0.05..1.0)).collect();
            let inputs: Vec<f32> =
                (0..n * d).map(|i| start[i % d] + (i / d) as f32 * 0.004 + rng.random_range(0.0..0.002)).collect();
            let lf = cfg.levels * f;
            let dfeat: Vec<f32> = (0..n * lf).map(|_| rng.random_range(-1.0..1.0)).collect();
            for_each_width(|width| {
                let (batch, single) = gradients_batched_and_by_row(&field, &inputs, &dfeat);
                assert!(batch.iter().filter(|&&g| g != 0.0).count() > n, "d {d} F {f}: too few entries touched");
                for (i, (a, b)) in batch.iter().zip(&single).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "d {d} F {f} {width}: gradient entry {i}: {a} vs {b}");
                }
            });
        }
    }

    /// A space–time grid with one time cell per time unit (as `tr-fast` windows have): points at
    /// whole times (every training sample) skip the corners of the other time vertex. Their
    /// features are continuous with those just before and after, in the vectorised and the
    /// scalar pass alike, and the gradient is bit-identical between the two.
    #[test]
    fn whole_times_on_an_exact_time_axis_use_one_time_vertex() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
        let cfg = HashGridConfig {
            levels: 5,
            features_per_level: 2,
            base_resolution: 4,
            max_resolution: 40,
            time_resolution: 3,
            time_span: 3.0,
            log2_table_size: 14,
            init_scale: 1.0,
            ..HashGridConfig::default()
        };
        let field = HashGridField::new(&cfg, 4, 3).unwrap();
        let n = 72;
        let lf = cfg.levels * 2;
        let mut inputs = Vec::new();
        for i in 0..n {
            inputs.extend((0..3).map(|_| rng.random_range(0.0..1.0f32)));
            // Groups of sixteen points share a whole time, as a training chunk does.
            inputs.push(((i / 16) % 4) as f32);
        }
        let shifted = |dt: f32| -> Vec<f32> {
            inputs.iter().enumerate().map(|(i, &x)| if i % 4 == 3 { (x + dt).clamp(0.0, 3.0) } else { x }).collect()
        };
        let (mut at, mut before, mut after) = (Vec::new(), Vec::new(), Vec::new());
        field.encode(&inputs, &mut at, false);
        field.encode(&shifted(-1e-3), &mut before, false);
        field.encode(&shifted(1e-3), &mut after, false);
        for k in 0..n * lf {
            let near = (at[k] - before[k]).abs().min((at[k] - after[k]).abs());
            assert!(near < 1e-2, "feature {k}: {} at a whole time, {} / {} around it", at[k], before[k], after[k]);
        }
        assert_encoding_matches_rows(&field, &inputs, &at, "whole times");
        let dfeat: Vec<f32> = (0..n * lf).map(|_| rng.random_range(-1.0..1.0)).collect();
        for_each_width(|width| {
            let (batch, rows) = gradients_batched_and_by_row(&field, &inputs, &dfeat);
            for (i, (a, b)) in batch.iter().zip(&rows).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{width}: gradient entry {i}: {a} vs {b}");
            }
        });
    }

    /// With a base time resolution the cells along time grow geometrically from the coarsest
    /// level to the finest (capped by the spatial cells); without it every level has the most.
    #[test]
    fn time_cells_grow_from_the_base_to_the_top_resolution() {
        let cells = |base: usize, top: usize| -> Vec<u32> {
            let cfg = HashGridConfig {
                levels: 8,
                base_resolution: 16,
                max_resolution: 128,
                time_resolution: top,
                time_base_resolution: base,
                time_span: top as f32,
                log2_table_size: 14,
                ..HashGridConfig::default()
            };
            HashGridField::new(&cfg, 4, 0).unwrap().levels.iter().map(|l| l.res_t).collect()
        };
        assert_eq!(cells(0, 2), [2; 8]);
        assert_eq!(cells(1, 2), [1, 1, 1, 1, 1, 2, 2, 2]);
        assert_eq!(cells(1, 15), [1, 1, 2, 3, 5, 7, 10, 15]);
        assert_eq!(cells(4, 4), [4; 8]);
        // More cells along time than in space are capped by the spatial cells.
        assert_eq!(cells(0, 40), [16, 21, 28, 39, 40, 40, 40, 40]);
    }

    /// Static levels: a 4D field's extra levels read the same features at every time (and the
    /// batched encoding and gradient agree with the row-by-row ones on them), the space–time
    /// levels do not; a field of space alone refuses them.
    #[test]
    fn static_levels_read_the_same_features_at_every_time() {
        let cfg = HashGridConfig { static_levels: 3, ..mixed_grid(2, 12, 1.0) };
        let field = HashGridField::new(&cfg, 4, 9).unwrap();
        let fixed = &field.levels[6..];
        assert_eq!(fixed.iter().map(|l| (l.res, l.res_t)).collect::<Vec<_>>(), [(5, 0), (21, 0), (90, 0)]);
        assert!(fixed[0].dense && !fixed[2].dense);
        assert_eq!(field.mlp.in_dim(), 18);
        let points = [[0.3f32, 0.61, 0.17], [0.92, 0.05, 0.5], [-0.1, 0.4, 1.2]];
        let times = [0.0f32, 0.4, 1.0, 2.5, 3.0];
        let inputs: Vec<f32> =
            points.iter().flat_map(|p| times.iter().flat_map(move |&t| [p[0], p[1], p[2], t])).collect();
        let mut feats = Vec::new();
        field.encode(&inputs, &mut feats, false);
        assert_encoding_matches_rows(&field, &inputs, &feats, "static levels");
        // Row by row (one arithmetic path), the static features are the same bits at every time.
        let mut rows = Vec::new();
        for x in inputs.chunks(4) {
            field.encode(x, &mut feats, false);
            rows.push(feats[..18].to_vec());
        }
        for (i, by_time) in rows.chunks(times.len()).enumerate() {
            for (k, row) in by_time.iter().enumerate() {
                assert_eq!(row[12..], by_time[0][12..], "point {i}: static features at time {}", times[k]);
            }
            assert_ne!(by_time[0][..12], by_time[3][..12], "point {i}: the space–time levels must see the time");
        }
        field.encode(&inputs, &mut feats, false);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let dfeat: Vec<f32> = (0..feats.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (batch, rows) = gradients_batched_and_by_row(&field, &inputs, &dfeat);
        for (i, (a, b)) in batch.iter().zip(&rows).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "gradient entry {i}: {a} vs {b}");
        }
        // Every instant's gradient reaches the static tables.
        let at = fixed[0].offset..fixed[0].offset + fixed[0].entries * 2;
        assert!(batch[at].iter().any(|&g| g != 0.0));
        let err = HashGridField::new(&cfg, 3, 9).unwrap_err().to_string();
        assert!(err.contains("static levels") && err.contains("space alone"), "{err}");
    }

    /// Coarse-to-fine: the finer half of the levels gets no gradient at first, one level joins
    /// every `coarse_to_fine` steps, and the MLP always trains.
    #[test]
    fn coarse_to_fine_opens_the_levels_in_turn() {
        let cfg = HashGridConfig {
            levels: 6,
            log2_table_size: 12,
            max_resolution: 64,
            coarse_to_fine: 10,
            ..HashGridConfig::default()
        };
        let f = HashGridField::new(&cfg, 3, 1).unwrap();
        let trained = |steps: u64| -> Vec<bool> {
            let mut g = vec![1.0f32; f.num_params()];
            f.restrict_gradient(steps, &mut g);
            assert!(g[f.grid_params()..].iter().all(|&v| v == 1.0), "the MLP always trains");
            f.levels.iter().map(|l| g[l.offset..l.offset + l.entries * 2].iter().all(|&v| v == 1.0)).collect()
        };
        assert_eq!(trained(0), [true, true, true, false, false, false]);
        assert_eq!(trained(9), [true, true, true, false, false, false]);
        assert_eq!(trained(10), [true, true, true, true, false, false]);
        assert_eq!(trained(30), [true; 6]);
        assert_eq!(trained(1000), [true; 6]);
    }
}
