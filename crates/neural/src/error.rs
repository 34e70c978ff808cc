//! The error type of the neural crate.

use std::path::PathBuf;

/// What can go wrong building, training, saving or loading a field.
#[derive(Debug, thiserror::Error)]
pub enum NeuralError {
    /// A configuration value is out of its valid range.
    #[error("invalid {what}: {why}")]
    Invalid { what: String, why: String },
    /// Reading or writing a file failed.
    #[error("{}: {error}", path.display())]
    Io { path: PathBuf, error: std::io::Error },
    /// A file of a trained field (its weights, a checkpoint, `model.json` or `temporal.json`) is
    /// malformed or does not match the field it is loaded into. The message names the file,
    /// which says which of them it is.
    #[error("{}: {why}", path.display())]
    Checkpoint { path: PathBuf, why: String },
    /// Training produced a non-finite loss. It is caught before the optimiser step, so the
    /// parameters and optimiser state are those after the previous iteration.
    #[error(
        "training diverged: the loss of iteration {iteration} is {loss}; the parameters and optimiser state \
         are kept as they were before that iteration ({})",
        diverged_hint(*iteration)
    )]
    Diverged { iteration: usize, loss: f64 },
}

/// What to look at when the loss of `iteration` is not finite. Iteration 0's loss is that of
/// the start, before any step, so the learning rate cannot be its cause.
fn diverged_hint(iteration: usize) -> &'static str {
    if iteration == 0 {
        "no step was taken yet, so the learning rate is not the cause: look at the start, the training's \
         image_scale, the hash grid's init_scale, the field given to start from, and the scene's intensity_scale"
    } else {
        "a lower learning rate may help"
    }
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
