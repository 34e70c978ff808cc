//! The engine: what a backend computes for the method.
//!
//! The method ([`crate::train`], [`crate::batch`]) decides which rays an iteration trains on,
//! the learning rate, when to stop and when to evaluate held-out views; it owns the training
//! state ([`crate::train::Learner`]: parameters in the field, Adam moments, histories) in host
//! memory. An [`Engine`] turns a [`RayBatch`] into a loss and a gradient, applies the optimiser
//! step, and renders batches without gradients. [`cpu::CpuEngine`] is the fused
//! multi-threaded implementation; a GPU backend implements the same trait.
//!
//! # One iteration, as the method drives it
//! ```text
//! engine.load_state(field, adam)                         once, before the first iteration
//! loop:
//!   batch  = training_batch(prep, cfg, seed, i, …)       method: which rays
//!   stats  = engine.loss_and_gradient(field, prep, cfg, &batch)
//!   if !stats.loss.is_finite(): engine.save_state(…); stop with NeuralError::Diverged
//!   engine.apply_gradient(field, adam, schedule.lr(i))   one Adam step, gradient consumed
//!   every validate_every: engine.render(field, prep, cfg, &holdout, …)
//!   engine.save_state(field, adam); callback; stopping rule (§5.1.5)
//! ```
//!
//! # Contract
//! - **State.** `field` (its [`TrainableField::params`]) and `adam` are the state of the run.
//!   `load_state` makes them the engine's: from then until `save_state` the method changes
//!   neither, and an engine may work on its own copy (device memory), taking the host
//!   arguments of the other calls as the run's handles. `save_state` writes the engine's
//!   state back; the method calls it before every callback, on error and at the end, so
//!   checkpoints ([`crate::weights`]) and callbacks always see the parameters and moments
//!   after the last applied step. The CPU engine computes in the host memory itself.
//! - **Step = two calls.** [`Engine::loss_and_gradient`] computes, for every ray of the batch,
//!   stratified samples (Eq. 5.1), with `N_f > 0` the coarse pass without gradients and the
//!   feature samples ([`crate::sampling`]), the field at all samples (skipping empty cells,
//!   [`crate::occupancy`]), the quadrature (Eq. 5.4) and the MSE (Eq. 5.5) over `batch.len()`
//!   pixels, plus the field's prior `cfg.prior` ([`TrainableField::add_prior`]) when set;
//!   it keeps `∂L/∂θ` (laid out like `params()`) and returns the loss. The method
//!   checks the loss before [`Engine::apply_gradient`] takes the Adam step with that gradient,
//!   so a non-finite loss never reaches the parameters. A gradient not applied is discarded by
//!   the next `loss_and_gradient`.
//! - **Units and shapes.** Field inputs are box-normalised positions (`[0, 1]³`), plus
//!   `t' = t / Δt` for 4D fields; distances along rays are world units, divided by the
//!   longest box side in the quadrature ([`Prepared::length_scale`]); targets and rendered
//!   pixels are normalised (`pixel / image_scale`). The loss is in normalised pixels²; the
//!   number of field rows evaluated with gradients is returned alongside it.
//! - **Determinism.** Rays are cut into chunks of [`RayBatch::rays_per_chunk`]; chunk `c`
//!   draws its random numbers from [`RayBatch::chunk_rng`]`(c)`, in ray order: for each ray
//!   `N_c` stratified offsets, then (with `N_f > 0`) for each ray `N_f` feature quantiles. An
//!   engine must give bit-identical results for identical inputs (fixed reduction orders);
//!   the CPU engine's results depend on the thread count only (the order in which per-thread
//!   losses and gradients are summed). An engine with different arithmetic (another
//!   summation order, fused multiply-adds) is deterministic in its own right but not
//!   bit-identical to the CPU engine.
//! - **Rendering.** [`Engine::render`] samples and integrates exactly as a training step does
//!   (same streams), without gradients and without touching the state; it writes one
//!   normalised pixel per ray of the batch, in batch order, and returns the batch's MSE
//!   against the targets.

pub mod cpu;

use crate::batch::RayBatch;
use crate::optim::Adam;
use crate::train::{Prepared, TrainConfig};
use crate::{NeuralError, TrainableField};

/// Loss of one batch and the work it took.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchLoss {
    /// MSE over the batch's pixels (Eq. 5.5), normalised pixels², plus the prior term in
    /// training.
    pub loss: f64,
    /// Field rows evaluated at the rendered samples (the coarse pass of hierarchical sampling
    /// not counted).
    pub samples: usize,
}

/// The operations a training backend provides (module doc: the contract).
pub trait Engine<F: TrainableField> {
    /// Adopts `field`'s parameters and `adam`'s moments as the state to train. Fails when they
    /// do not fit each other or the engine (parameter counts, input dimension).
    fn load_state(&mut self, field: &F, adam: &Adam) -> Result<(), NeuralError>;

    /// Writes the parameters and optimiser state after the last applied step into `field` and
    /// `adam`.
    fn save_state(&mut self, field: &mut F, adam: &mut Adam);

    /// The MSE of `batch` (rays of `prep.views(batch.split)`) and its gradient with respect
    /// to the parameters, which the engine keeps for [`Engine::apply_gradient`].
    fn loss_and_gradient(&mut self, field: &F, prep: &Prepared, cfg: &TrainConfig, batch: &RayBatch) -> BatchLoss;

    /// One Adam step (`adam.config`, learning rate `lr`) with the gradient of the last
    /// [`Engine::loss_and_gradient`].
    fn apply_gradient(&mut self, field: &mut F, adam: &mut Adam, lr: f32);

    /// Renders `batch` without gradients: `pixels` gets one normalised value per ray, in batch
    /// order; returns the MSE against the targets.
    fn render(
        &mut self,
        field: &F,
        prep: &Prepared,
        cfg: &TrainConfig,
        batch: &RayBatch,
        pixels: &mut Vec<f32>,
    ) -> BatchLoss;
}
