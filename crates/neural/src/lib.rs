//! FluidNeRF: the field E(x) or E(x, t) as a trainable representation (positional encoding +
//! MLP as in the dissertation, or a multiresolution grid encoding with a tiny MLP), trained so
//! that line integrals rendered along camera rays match the measured pixels.

pub mod batch;
pub mod dense;
pub mod encoding;
pub mod engine;
pub mod error;
pub mod field;
pub mod hashgrid;
pub(crate) mod kernels;
pub mod mlp;
pub mod occupancy;
pub mod optim;
pub mod render;
pub mod sampling;
pub mod temporal;
pub mod train;
pub mod trained;
pub mod weights;
pub mod window;

pub use engine::cpu::CpuEngine;
pub use engine::Engine;
pub use error::NeuralError;
pub use field::TrainableField;
pub use hashgrid::{HashGridConfig, HashGridField};
pub use mlp::{Activation, MlpConfig, MlpField, OutputActivation};
