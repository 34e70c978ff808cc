//! The boundary between the CPU engine (ray sampling, rendering, loss, backward; see
//! [`crate::engine::cpu`]) and the field representation (encoding + network). The engine only
//! ever talks to a [`TrainableField`]; a representation only ever sees batches of points. A
//! new representation implements this trait; a GPU backend implements
//! [`crate::engine::Engine`] for existing representations (their configuration and their
//! parameters as [`TrainableField::tensors`] lays them out), running kernels of its own.
//!
//! # Contract
//! - Inputs are row-major `n × input_dim()` f32: box-normalised coordinates in `[0, 1]³`
//!   (`Aabb::to_unit`), followed for space–time fields by the frame time `t' = t / Δt`.
//! - Outputs are `n` non-negative values of the field E.
//! - Calls are single-threaded and take one chunk of rows (typically 256–8192); callers
//!   parallelise over chunks with one `Tape` and one gradient buffer per thread and sum the
//!   gradient buffers afterwards. This keeps each thread's activations in its own cache and
//!   avoids any synchronisation inside the hot loop.
//! - `backward` accumulates (`+=`) into `grads`, laid out like `params()`.

use std::ops::Range;

/// A differentiable scalar field with a flat parameter vector.
pub trait TrainableField: Send + Sync {
    /// Per-thread scratch space and the activations `forward` records for `backward`.
    /// Allocated once with [`TrainableField::new_tape`] and reused across calls.
    type Tape: Send;

    /// 3 for E(x), 4 for E(x, t).
    fn input_dim(&self) -> usize;

    /// A fresh tape (buffers grow on first use to the chunk size they are given).
    fn new_tape(&self) -> Self::Tape;

    /// All trainable parameters, flat.
    fn params(&self) -> &[f32];

    fn params_mut(&mut self) -> &mut [f32];

    fn num_params(&self) -> usize {
        self.params().len()
    }

    /// Turns a freshly initialised field into one that evaluates to about `level` (> 0)
    /// everywhere, keeping enough of its random initialisation to break symmetry.
    ///
    /// Training calls this before the first iteration with the uniform field that explains the
    /// mean training pixel ([`crate::train::Learner::fresh`]). Emission images are mostly dark:
    /// started far brighter than that, the first optimiser steps push every unit of a deep
    /// ReLU network coherently down, and the network can end in the trivial field E = 0 with
    /// its units dead.
    fn start_uniform(&mut self, level: f32);

    /// Inference: writes E for each input row into `out`; records nothing for backward.
    fn eval(&self, inputs: &[f32], out: &mut [f32], tape: &mut Self::Tape);

    /// Training forward pass: like [`TrainableField::eval`] but records what
    /// [`TrainableField::backward`] needs in `tape`.
    fn forward(&self, inputs: &[f32], out: &mut [f32], tape: &mut Self::Tape);

    /// Given `d_out[i] = ∂L/∂out[i]` for the rows of the last `forward` on this tape, adds
    /// `∂L/∂params` into `grads` (same length and layout as `params()`).
    fn backward(&self, tape: &mut Self::Tape, d_out: &[f32], grads: &mut [f32]);

    /// Named tensors as `(name, shape, range into params())`, for checkpoints
    /// (safetensors) and inspection. The ranges partition `params()`.
    fn tensors(&self) -> Vec<(String, Vec<usize>, Range<usize>)>;

    /// Called with the number of optimiser steps taken so far before each step: a field may
    /// zero parts of the summed gradient `grads` it does not want trained yet (coarse-to-fine
    /// schedules). Those parameters then keep their values. Default: nothing.
    fn restrict_gradient(&self, _steps_taken: u64, _grads: &mut [f32]) {}

    /// Cells along each box-normalised axis that resolve the field's finest detail, if it is
    /// a grid (see [`fluidnerf_core::ScalarField::detail_dims`]). Default: none.
    fn detail_dims(&self) -> Option<[usize; 3]> {
        None
    }

    /// Whether a space–time field reads time on the frame axis of its window (0 at the
    /// window's first frame, 1 at the next, linear in time between frames) rather than as
    /// `t' = (t − t₀) / Δt`: true for a grid with one time vertex per frame, which would
    /// otherwise misplace frames that are not evenly spaced (see
    /// [`crate::temporal::TimeAxis`]). Default: false.
    fn time_on_frame_axis(&self) -> bool {
        false
    }

    /// Whether training takes some of the field's products in bfloat16 (the hash grid's
    /// `mlp_precision`, on a CPU that has it); the training report records it.
    fn bf16_products(&self) -> bool {
        false
    }

    /// Whether the field implements the priors of [`Prior`] ([`TrainableField::add_prior`]).
    fn supports_prior(&self) -> bool {
        false
    }

    /// Adds the gradient of the prior term `prior` to `grads` and returns its value, which
    /// the training loss includes. Fields without priors return 0 (training refuses a
    /// non-zero prior for them, see [`TrainableField::supports_prior`]).
    fn add_prior(&self, prior: &Prior, grads: &mut [f32]) -> f32 {
        let _ = (prior, grads);
        0.0
    }
}

/// Priors on the field, added to the training loss (Eq. 5.5):
/// `tv · TV(E) + smooth · S(E) + sparsity · E`,
/// each the mean over the dense grid's cells (fields that implement
/// [`TrainableField::add_prior`]), or its Monte Carlo estimate on `points` random points with
/// cell size `step` for every other field ([`crate::prior`]), of
/// - `TV`: the isotropic total variation `√(|∇E|² + ε²)` with forward differences
///   (edge preserving; ε = 1e-3 keeps it differentiable),
/// - `S`: the squared gradient `|∇E|²` (second-order Tikhonov in its first-order form:
///   smoothness),
/// - `E` itself, an L1 norm since E ≥ 0 (sparsity: dark space stays dark),
///
/// in the field's normalised units. Both default to 0 (no prior).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Prior {
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub tv: f32,
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub smooth: f32,
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub sparsity: f32,
    /// Random points per iteration for fields without a grid prior. Default 2048.
    pub points: usize,
    /// Their finite-difference step in box-normalised units. Default 1/128.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub step: f32,
}

impl Default for Prior {
    fn default() -> Self {
        Prior { tv: 0.0, smooth: 0.0, sparsity: 0.0, points: 2048, step: 1.0 / 128.0 }
    }
}

impl Prior {
    pub fn is_zero(&self) -> bool {
        self.tv == 0.0 && self.smooth == 0.0 && self.sparsity == 0.0
    }
}
