//! Reading and writing run files: every file goes through `fluidnerf_io::atomic_write`, so an
//! interrupted run never leaves a half-written result, and errors name the file.

use std::path::Path;

use anyhow::Context;
use fluidnerf_neural::train::Learner;
use fluidnerf_neural::TrainableField;
use serde::de::DeserializeOwned;
use serde::Serialize;

/// Writes `bytes` to `path` atomically.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    fluidnerf_io::atomic_write(path, |w| w.write_all(bytes)).with_context(|| format!("writing {}", path.display()))
}

/// Reads the JSON file `path` as a `T`; `what` names what it should be ("a neural run
/// configuration") in the error.
pub fn read_json<T: DeserializeOwned>(path: &Path, what: &str) -> anyhow::Result<T> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not {what}", path.display()))
}

/// Writes `value` as pretty JSON, with a final newline, atomically.
pub fn write_json(path: &Path, value: &impl Serialize) -> anyhow::Result<()> {
    let mut text = serde_json::to_string_pretty(value).context("serialising JSON")?;
    text.push('\n');
    write_bytes(path, text.as_bytes())
}

/// Writes a training checkpoint (weights, optimiser state, histories) atomically.
pub fn write_checkpoint<F: TrainableField>(path: &Path, learner: &Learner<F>) -> anyhow::Result<()> {
    write_bytes(path, &fluidnerf_neural::weights::checkpoint_bytes(learner)?)
}
