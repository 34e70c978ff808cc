//! FluidNeRF: the field E(x) or E(x, t) as a trainable representation (positional encoding +
//! MLP as in the dissertation, or a multiresolution grid encoding with a tiny MLP), trained so
//! that line integrals rendered along camera rays match the measured pixels.
//!
//! # Layers
//! - **Method** (backend-free): [`train`] — settings, the prepared problem (cached rays,
//!   normalised targets, empty-space mask), the training state [`train::Learner`], the loop
//!   with its learning-rate schedule, stopping rule (§5.1.5) and held-out evaluation;
//!   [`batch`] — what a ray batch is and how each iteration draws one; [`temporal`] and
//!   [`window`] — time-resolved training over windows of frames.
//! - **Engine** ([`engine::Engine`]): what a backend computes for the method — the loss and
//!   gradient of a ray batch (sampling, field, quadrature, MSE, backward), the optimiser step,
//!   renders without gradients, and the hand-over of the state. [`CpuEngine`] is the fused
//!   multi-threaded implementation that [`train::train`] uses.
//! - **Fields** ([`TrainableField`]): the representations the CPU engine evaluates and
//!   differentiates chunk by chunk — [`MlpField`], [`HashGridField`],
//!   [`dense::DenseGridField`] — with [`optim`] (Adam), [`weights`] (checkpoints) and
//!   [`trained`] (trained fields in world coordinates).
//!
//! # What a GPU engine implements
//! A type implementing [`engine::Engine`] for its field type; the method layer is reused as
//! it is ([`train::train_with_engine`]). It receives each iteration a [`batch::RayBatch`] —
//! `(view, ray)` pairs of a [`train::Prepared`] problem whose geometry, target and time
//! [`batch::RayBatch::ray`] gathers (upload the prepared rays once) — and must:
//! - `load_state` / `save_state`: take the parameters (`field.params()`, f32, laid out as
//!   [`TrainableField::tensors`] names them) and the Adam moments (`m`, `v` laid out alike,
//!   step count) before training, and write them back whenever the loop asks (before every
//!   callback, on error, at the end);
//! - `loss_and_gradient`: per ray `N_c` stratified samples on `[near, far]` (world units),
//!   with `N_f > 0` a coarse pass without gradients and `N_f` feature samples, the field at
//!   box-normalised points (plus `t'` for 4D fields), the trapezoid quadrature with distances
//!   divided by the longest box side, the MSE over the batch (normalised pixels²) and
//!   `∂L/∂θ`, kept on the device; return the loss and the number of field rows;
//! - `apply_gradient`: one Adam step (Kingma & Ba with bias correction, `adam.config`, the
//!   given learning rate) with that gradient — only called once the method has seen a finite
//!   loss;
//! - `render`: the same sampling and quadrature without gradients, one pixel per ray.
//!
//! Random numbers come from ChaCha8 streams per chunk of rays ([`batch::RayBatch::chunk_rng`]);
//! an engine must be deterministic, and is bit-identical to the CPU engine only if it also
//! uses those streams and the same arithmetic. Conventions in detail: [`engine`].

pub mod batch;
pub mod dense;
pub mod encoding;
pub mod engine;
pub mod error;
pub mod field;
pub mod hashgrid;
#[cfg(target_arch = "x86_64")]
mod hashgrid_simd;
pub(crate) mod kernels;
pub mod mlp;
pub mod occupancy;
pub mod optim;
pub mod prior;
pub mod render;
pub mod sampling;
pub mod start;
pub mod temporal;
pub mod train;
pub mod trained;
pub mod weights;
pub mod window;

pub use engine::cpu::CpuEngine;
pub use engine::Engine;
pub use error::NeuralError;
pub use field::{Prior, TrainableField};
pub use hashgrid::{HashGridConfig, HashGridField, MlpPrecision};
pub use mlp::{bf16_products_available, Activation, MlpConfig, MlpField, OutputActivation};
