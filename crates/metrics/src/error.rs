//! The error type of the metrics crate.

/// What can go wrong when computing metrics.
#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    /// An array is smaller than the SSIM window along some axis.
    #[error("array of dims {dims:?} is smaller than the {window}-wide SSIM window")]
    TooSmall { dims: Vec<usize>, window: usize },
    /// A parameter is out of its valid range.
    #[error("invalid {what}: {why}")]
    Invalid { what: String, why: String },
    /// Rendering a reconstruction failed.
    #[error("rendering frame {frame} failed: {error}")]
    Render { frame: usize, error: fluidnerf_core::CoreError },
    /// A reconstruction rendered to values that are not finite.
    #[error("the view rendered for frame {frame} is {value} at pixel (col {col}, row {row}): the reconstruction's values overflow 32-bit floats (finite weights or voxels so large that their sums do not fit); the file is damaged or was edited")]
    Overflow { frame: usize, value: f32, col: usize, row: usize },
}

impl MetricsError {
    /// Shorthand for [`MetricsError::Invalid`].
    pub fn invalid(what: impl Into<String>, why: impl Into<String>) -> Self {
        MetricsError::Invalid { what: what.into(), why: why.into() }
    }
}
