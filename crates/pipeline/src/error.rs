//! The crate's error type.

use std::path::PathBuf;

/// Everything that can stop a run before or while it works. Each message names the file, the
/// configuration key or the camera it is about.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A setting out of range or inconsistent with the others; `key` is its configuration path.
    #[error("{key}: {why}")]
    Invalid { key: String, why: String },
    /// A file that cannot be read, parsed or written.
    #[error("{}: {why}", path.display())]
    File { path: PathBuf, why: String },
    /// The run folder cannot be used as asked (results present, locked, the scene folder).
    #[error("{}: {why}", path.display())]
    RunDir { path: PathBuf, why: String },
    /// The run would need more memory than allowed (`memory_limit_gib`, else what is
    /// available); the message says how much and what to lower.
    #[error("{0}")]
    Memory(String),
    /// Reading or writing a scene, image, volume or calibration; the message names the file.
    #[error(transparent)]
    Io(#[from] fluidnerf_io::IoError),
    /// A voxel method refused its settings or the problem.
    #[error(transparent)]
    Classical(#[from] fluidnerf_classical::ClassicalError),
    /// A neural field, its training or its checkpoint refused the settings or the data.
    #[error(transparent)]
    Neural(#[from] fluidnerf_neural::NeuralError),
    /// Scoring a volume against the ground truth.
    #[error(transparent)]
    Metrics(#[from] fluidnerf_metrics::MetricsError),
    /// Geometry: a camera, box or volume that is not valid.
    #[error(transparent)]
    Core(#[from] fluidnerf_core::CoreError),
    /// Drawing the pictures of `report.html`.
    #[error("drawing the report: {0}")]
    Viz(#[from] fluidnerf_viz::VizError),
}

impl PipelineError {
    /// A [`PipelineError::Invalid`] setting: `key` its configuration path (`stopping.rule`,
    /// `method.train.validate_pixels`), `why` what is wrong with it and what to give instead.
    pub fn invalid(key: impl Into<String>, why: impl Into<String>) -> Self {
        PipelineError::Invalid { key: key.into(), why: why.into() }
    }

    pub(crate) fn file(path: &std::path::Path, why: impl std::fmt::Display) -> Self {
        PipelineError::File { path: path.to_path_buf(), why: why.to_string() }
    }
}
