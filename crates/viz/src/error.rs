//! The error type of the viz crate.

use std::path::PathBuf;

/// What can go wrong while drawing or writing pictures, meshes and reports.
#[derive(Debug, thiserror::Error)]
pub enum VizError {
    /// Writing a file failed.
    #[error(transparent)]
    File(#[from] fluidnerf_io::IoError),
    /// Reading an input file failed.
    #[error("cannot read {path}: {error}")]
    Read { path: PathBuf, error: std::io::Error },
    /// The drawing library failed (a font or backend problem).
    #[error("drawing {what} failed: {message}")]
    Draw { what: String, message: String },
    /// Encoding a PNG failed.
    #[error("cannot encode {what}: {error}")]
    Encode { what: String, error: image::ImageError },
    /// Encoding a GIF failed.
    #[error("cannot encode {what}: {error}")]
    EncodeGif { what: String, error: gif::EncodingError },
    /// An argument is out of its valid range.
    #[error("invalid {what}: {why}")]
    Invalid { what: String, why: String },
}

impl VizError {
    /// Shorthand for [`VizError::Invalid`].
    pub fn invalid(what: impl Into<String>, why: impl Into<String>) -> Self {
        VizError::Invalid { what: what.into(), why: why.into() }
    }

    pub(crate) fn draw(what: &str, err: impl std::fmt::Display) -> Self {
        VizError::Draw { what: what.to_string(), message: err.to_string() }
    }
}
