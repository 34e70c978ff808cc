//! The error type of the neural crate.

use std::path::PathBuf;

use fluidnerf_core::num;

use crate::Prior;

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
    /// parameters and optimiser state are those after the previous iteration. `prior` is the
    /// training's, whose weights the loss includes.
    #[error(
        "training diverged: the loss of iteration {iteration} is {loss}; the parameters and optimiser state \
         are kept as they were before that iteration ({})",
        diverged_hint(*iteration, prior)
    )]
    Diverged { iteration: usize, loss: f64, prior: Prior },
}

/// What to look at when the loss of `iteration` is not finite. Iteration 0's loss is that of
/// the start, before any step, so the learning rate cannot be its cause. The loss includes the
/// priors' terms, so non-zero prior weights are named as a cause too.
fn diverged_hint(iteration: usize, prior: &Prior) -> String {
    let weights: Vec<String> =
        [("prior.tv", prior.tv), ("prior.smooth", prior.smooth), ("prior.sparsity", prior.sparsity)]
            .into_iter()
            .filter(|&(_, w)| w != 0.0)
            .map(|(key, w)| format!("{key} {}", num(w)))
            .collect();
    let priors = if weights.is_empty() {
        String::new()
    } else {
        format!("the training's prior weights ({}) may be too large; ", weights.join(", "))
    };
    if iteration == 0 {
        format!(
            "no step was taken yet, so the learning rate is not the cause: {priors}look at the start, the \
             training's image_scale, the hash grid's init_scale, the field given to start from, and the scene's \
             intensity_scale"
        )
    } else if priors.is_empty() {
        "a lower learning rate may help".into()
    } else {
        format!("{priors}lower weights or a lower learning rate may help")
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The loss a prior's weight makes non-finite is not blamed on the learning rate alone:
    /// the weights that are not zero are named.
    #[test]
    fn a_divergence_names_the_prior_weights_that_are_not_zero() {
        let prior = Prior { tv: 3e38, sparsity: 0.5, ..Prior::default() };
        let e = NeuralError::Diverged { iteration: 4, loss: f64::INFINITY, prior }.to_string();
        assert!(
            e.ends_with(
                "(the training's prior weights (prior.tv 3e38, prior.sparsity 0.5) may be too large; lower weights \
                 or a lower learning rate may help)"
            ),
            "{e}"
        );
        let e = NeuralError::Diverged { iteration: 0, loss: f64::NAN, prior }.to_string();
        assert!(e.contains("not the cause: the training's prior weights (prior.tv 3e38, prior.sparsity"), "{e}");
        let e = NeuralError::Diverged { iteration: 4, loss: f64::NAN, prior: Prior::default() }.to_string();
        assert!(e.ends_with("(a lower learning rate may help)") && !e.contains("prior"), "{e}");
    }
}
