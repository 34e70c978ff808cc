//! FluidNeRF: the field E(x) or E(x, t) as a trainable representation (positional encoding +
//! MLP as in the dissertation, or a multiresolution grid encoding with a tiny MLP), trained so
//! that line integrals rendered along camera rays match the measured pixels.

pub mod field;

pub use field::TrainableField;
