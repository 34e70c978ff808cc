//! The error type of the neural crate.

use std::path::PathBuf;

/// What can go wrong building, training, saving or loading a field.
#[derive(Debug, thiserror::Error)]
pub enum NeuralError {
    /// A configuration value is out of its valid range.
    #[error("invalid {what}: {why}")]
    Invalid { what: String, why: String },
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A checkpoint file is malformed or does not match the field it is loaded into.
    #[error("checkpoint {}: {why}", path.display())]
    Checkpoint { path: PathBuf, why: String },
}

impl NeuralError {
    /// Shorthand for [`NeuralError::Invalid`].
    pub fn invalid(what: impl Into<String>, why: impl Into<String>) -> Self {
        NeuralError::Invalid { what: what.into(), why: why.into() }
    }

    /// Shorthand for [`NeuralError::Checkpoint`].
    pub fn checkpoint(path: impl Into<PathBuf>, why: impl Into<String>) -> Self {
        NeuralError::Checkpoint { path: path.into(), why: why.into() }
    }
}
