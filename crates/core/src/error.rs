//! The error type of the core crate.

/// What can go wrong in geometry and camera computations.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// Inverting the lens distortion for a pixel did not converge.
    #[error(
        "lens undistortion did not converge for pixel ({u:.3}, {v:.3}) \
         (residual {residual_px:.2e} px); the distortion coefficients may be invalid this far \
         from the image centre"
    )]
    UndistortionFailed { u: f64, v: f64, residual_px: f64 },
    /// The lens distortion folds the image over between its centre and a pixel, so that the
    /// pixel's ray found by inverting it lies past the fold.
    #[error(
        "the lens distortion folds the image over between its centre and pixel ({u:.3}, {v:.3}) (its Jacobian \
         changes sign {fold:.0} % of the way there): several rays land on the same pixels, and the distortion \
         coefficients are invalid this far from the image centre"
    )]
    DistortionFolds { u: f64, v: f64, fold: f64 },
    /// A parameter is out of its valid range.
    #[error("invalid {what}: {why}")]
    Invalid { what: String, why: String },
}

impl CoreError {
    /// Shorthand for [`CoreError::Invalid`].
    pub fn invalid(what: impl Into<String>, why: impl Into<String>) -> Self {
        CoreError::Invalid { what: what.into(), why: why.into() }
    }
}
