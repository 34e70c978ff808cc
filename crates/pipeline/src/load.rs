//! Reading a finished run folder of any kind — voxel, static neural, time-resolved — for the
//! commands that use runs (`eval`, `export`, `render`, `compare`) and for scripts.

use std::path::{Path, PathBuf};

use fluidnerf_core::{Aabb, ScalarField, Volume};

use crate::{PipelineError, RunConfig, RunDir, RunKind, RunReport};

/// A finished run: its configuration, its report, and access to its results.
pub struct LoadedRun {
    pub dir: PathBuf,
    pub kind: RunKind,
    pub config: RunConfig,
    pub report: RunReport,
}

impl std::fmt::Debug for LoadedRun {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadedRun").field("dir", &self.dir).field("kind", &self.kind).finish()
    }
}

impl LoadedRun {
    /// Opens the run in `dir`; refuses a folder without a finished run, saying why.
    pub fn open(dir: &Path) -> Result<Self, PipelineError> {
        let rd = RunDir::open(dir)?;
        let Some(kind) = rd.kind() else {
            return Err(PipelineError::RunDir {
                path: dir.to_path_buf(),
                why: "holds no reconstruction (no volume.npy, model.json or temporal.json)".into(),
            });
        };
        if !rd.report().is_file() {
            return Err(PipelineError::RunDir {
                path: dir.to_path_buf(),
                why: "holds an unfinished run (no report.json); resume it with `reconstruct --resume` or rerun it"
                    .into(),
            });
        }
        let report = RunReport::read(&rd.report())?;
        let config = RunConfig::read(&rd.config())?;
        Ok(LoadedRun { dir: dir.to_path_buf(), kind, config, report })
    }

    pub fn aabb(&self) -> Aabb {
        self.report.aabb
    }

    /// The result as a continuous field: the trained network (static or of space and time),
    /// or the volume (sampled trilinearly).
    pub fn field(&self) -> Result<Box<dyn ScalarField + Send + Sync>, PipelineError> {
        Ok(match self.kind {
            RunKind::Field => fluidnerf_neural::trained::load_trained(&self.dir)?.0,
            RunKind::Temporal => Box::new(fluidnerf_neural::temporal::load_temporal(&self.dir)?),
            RunKind::Volume => Box::new(self.first_volume()?),
        })
    }

    /// Every volume written, with its time (None for static runs).
    pub fn volumes(&self) -> Result<Vec<(Option<f64>, Volume)>, PipelineError> {
        self.report
            .volumes
            .iter()
            .map(|v| Ok((v.time, fluidnerf_io::volume::read_npy(&self.dir.join(&v.file), self.aabb())?)))
            .collect()
    }

    /// The first (for static runs: the only) volume.
    pub fn first_volume(&self) -> Result<Volume, PipelineError> {
        let first = self
            .report
            .volumes
            .first()
            .ok_or_else(|| PipelineError::file(&self.dir.join("report.json"), "lists no volume"))?;
        Ok(fluidnerf_io::volume::read_npy(&self.dir.join(&first.file), self.aabb())?)
    }

    /// The times of a time-resolved run's volumes (empty for static runs).
    pub fn times(&self) -> Vec<f64> {
        self.report.volumes.iter().filter_map(|v| v.time).collect()
    }
}
