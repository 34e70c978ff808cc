//! The crate's error type.

use fluidnerf_core::CoreError;

/// Everything that can go wrong when setting up or running a reconstruction.
#[derive(Debug, thiserror::Error)]
pub enum ClassicalError {
    /// A camera, box or image was rejected by the core checks (e.g. undistortion failed).
    #[error(transparent)]
    Core(#[from] CoreError),
    /// The inputs do not fit together or are out of range.
    #[error("invalid {what}: {why}")]
    Invalid { what: String, why: String },
    /// An image value is NaN or infinite.
    #[error("image of view {view} has a non-finite value at pixel ({col}, {row})")]
    NonFiniteImage { view: usize, col: usize, row: usize },
    /// No camera sees any voxel: nothing can be reconstructed.
    #[error("no camera sees the reconstruction box")]
    NothingSeen,
    /// The iteration produced NaN or infinity: too large a relaxation factor, or values beyond
    /// single precision (images on a scale far from the field's, see `intensity_scale`).
    #[error(
        "{method} diverged at iteration {iteration} (residual {}): its values left single precision; \
         check that the images and the scene's intensity_scale put the field's values between about 1e-30 and \
         1e30, and lower the relaxation factor if the method has one",
        fluidnerf_core::num(*residual)
    )]
    Diverged { method: &'static str, iteration: usize, residual: f64 },
}

/// What the solvers return on failure (the same type; the name reads better at call sites).
pub type SolveError = ClassicalError;

impl ClassicalError {
    pub fn invalid(what: impl Into<String>, why: impl Into<String>) -> Self {
        ClassicalError::Invalid { what: what.into(), why: why.into() }
    }
}
