//! [`RunDir`]: the folder of one run — every path in it, atomic writes, a lock for the run's
//! lifetime, and the rules for replacing (`--force`) or continuing (`--resume`) a run.
//!
//! Layout:
//! - every run: `config.json` (written first), `report.json` (written last: its presence
//!   marks a finished or cleanly stopped run), `report.html`, and `.lock` while running;
//! - voxel and static neural runs: `volume.npy` and `volume.vti`; neural runs also
//!   `weights.safetensors`, `model.json` and `checkpoint.safetensors`;
//! - time-resolved runs: `frames/volume_NNN.npy|.vti`, `volumes.pvd`, `temporal.json` and
//!   `windows/` (weights, checkpoints, `progress.json`).
//!
//! A folder with run files but no `report.json` holds a run that died (or is still running,
//! which the lock tells): it is never taken for a finished one, and it is resumed or replaced
//! only when asked.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::PipelineError;

/// What to do with a run folder that already holds a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Overwrite {
    /// Refuse (the default): nothing a user made is overwritten without being asked.
    #[default]
    Refuse,
    /// Delete the earlier run's files and start afresh.
    Force,
    /// Continue the earlier run from its checkpoints (neural and time-resolved methods).
    Resume,
}

/// What a run folder holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DirState {
    /// No run files.
    Empty,
    /// A run that wrote its report.
    Finished,
    /// Run files without a report: a run that died, or one still running.
    Unfinished,
}

/// The kind of result a run folder holds, as the commands that read runs see it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunKind {
    /// `volume.npy` only (a voxel method).
    Volume,
    /// A trained static field (`model.json` + weights) and its `volume.npy`.
    Field,
    /// A trained field of space and time (`temporal.json`) and one volume per frame.
    Temporal,
}

/// Files and folders a run writes, relative to its folder (removed by [`Overwrite::Force`]).
const RUN_FILES: [&str; 14] = [
    "config.json",
    "report.json",
    "report.html",
    "volume.npy",
    "volume.vti",
    "weights.safetensors",
    "model.json",
    "checkpoint.safetensors",
    "temporal.json",
    "volumes.pvd",
    "frames",
    "windows",
    "metrics.json",
    "metrics.csv",
];

/// The folder of one run. Opening it for writing ([`RunDir::create`]) takes its lock, which is
/// released when the `RunDir` is dropped.
#[derive(Debug)]
pub struct RunDir {
    root: PathBuf,
    lock: Option<PathBuf>,
    resume: bool,
    /// The folder did not exist before: if the run is refused before writing anything, it goes.
    created: bool,
}

impl Drop for RunDir {
    fn drop(&mut self) {
        if let Some(lock) = &self.lock {
            let _ = std::fs::remove_file(lock);
            if self.created {
                // Removes the folder only when nothing was written into it.
                let _ = std::fs::remove_dir(&self.root);
            }
        }
    }
}

impl RunDir {
    /// A run folder to read (no lock, nothing created).
    pub fn open(root: impl Into<PathBuf>) -> Result<Self, PipelineError> {
        let root = root.into();
        if !root.is_dir() {
            return Err(PipelineError::RunDir { path: root, why: "is not a folder".into() });
        }
        Ok(RunDir { root, lock: None, resume: false, created: false })
    }

    /// Creates (or reuses, as `overwrite` allows) the folder of a new run, refusing the scene's
    /// own folder, and takes its lock. A stale lock (its process is gone) is replaced.
    pub fn create(
        root: impl Into<PathBuf>,
        overwrite: Overwrite,
        scene_root: Option<&Path>,
    ) -> Result<Self, PipelineError> {
        let root: PathBuf = root.into();
        let refuse = |why: String| PipelineError::RunDir { path: root.clone(), why };
        if let Some(scene) = scene_root {
            let same = match (root.canonicalize(), scene.canonicalize()) {
                (Ok(a), Ok(b)) => a == b,
                _ => false,
            };
            if same {
                return Err(refuse("is the scene's own folder; choose another output folder".into()));
            }
        }
        if root.exists() && !root.is_dir() {
            return Err(refuse("exists and is not a folder".into()));
        }
        let created = !root.exists();
        std::fs::create_dir_all(&root).map_err(|e| refuse(format!("cannot create the folder: {e}")))?;
        let mut dir = RunDir { root: root.clone(), lock: None, resume: overwrite == Overwrite::Resume, created };
        dir.take_lock()?;
        match (dir.state(), overwrite) {
            (DirState::Empty, Overwrite::Resume) => {
                return Err(refuse(
                    "nothing to resume (--resume; `overwrite=\"resume\"` from Python): it holds no run".into(),
                ));
            }
            (DirState::Empty, _) => dir.resume = false,
            (DirState::Finished, Overwrite::Refuse) => {
                return Err(refuse(
                    "already holds a finished run; use --force to replace it (or --resume to continue training a \
                     neural run; from Python `overwrite=\"force\"` or `\"resume\"`)"
                        .into(),
                ))
            }
            (DirState::Unfinished, Overwrite::Refuse) => {
                return Err(refuse(
                    "holds an unfinished run (run files but no report.json: it died or was killed); use --resume \
                     to continue it (neural methods) or --force to replace it (from Python `overwrite=\"resume\"` \
                     or `\"force\"`)"
                        .into(),
                ))
            }
            (_, Overwrite::Force) => dir.clear()?,
            (_, Overwrite::Resume) => {}
        }
        Ok(dir)
    }

    fn take_lock(&mut self) -> Result<(), PipelineError> {
        self.lock = Some(acquire_lock(&self.root, &self.root.join(".lock"))?);
        Ok(())
    }

    /// A run folder in which windows of a time-resolved run are trained one at a time, by
    /// this process and possibly others at once
    /// ([`crate::reconstruct_windows`]): created if missing, refused when it is the scene's
    /// folder, holds a finished run, or is locked by a whole run. It takes no lock itself;
    /// each window is locked while it trains ([`RunDir::lock_file`]).
    pub fn for_windows(root: impl Into<PathBuf>, scene_root: Option<&Path>) -> Result<Self, PipelineError> {
        let root: PathBuf = root.into();
        let refuse = |why: String| PipelineError::RunDir { path: root.clone(), why };
        if let Some(scene) = scene_root {
            if let (Ok(a), Ok(b)) = (root.canonicalize(), scene.canonicalize()) {
                if a == b {
                    return Err(refuse("is the scene's own folder; choose another output folder".into()));
                }
            }
        }
        std::fs::create_dir_all(&root).map_err(|e| refuse(format!("cannot create the folder: {e}")))?;
        let dir = RunDir { root: root.clone(), lock: None, resume: false, created: false };
        if dir.report().is_file() {
            return Err(refuse(
                "already holds a finished run; training windows into it would mix two runs (remove it, or use \
                 another folder)"
                    .into(),
            ));
        }
        let lock = root.join(".lock");
        if let Some(pid) = std::fs::read_to_string(&lock).ok().and_then(|h| h.trim().parse::<u32>().ok()) {
            if pid != std::process::id() && process_alive(pid) {
                return Err(refuse(format!(
                    "is in use by a whole run (process {pid}, lock file {}); wait for it to finish",
                    lock.display()
                )));
            }
        }
        Ok(dir)
    }

    /// Takes the lock file `name` (relative to the folder) until the guard is dropped; refused
    /// while a live process holds it, a stale one (its process gone) is replaced.
    pub fn lock_file(&self, name: &str) -> Result<FileLock, PipelineError> {
        Ok(FileLock { path: acquire_lock(&self.root, &self.path(name))? })
    }

    /// Removes the files of an earlier run (only those a run writes).
    fn clear(&self) -> Result<(), PipelineError> {
        for name in RUN_FILES {
            let p = self.root.join(name);
            let removed = if p.is_dir() {
                std::fs::remove_dir_all(&p)
            } else if p.exists() {
                std::fs::remove_file(&p)
            } else {
                Ok(())
            };
            removed.map_err(|e| PipelineError::file(&p, format!("cannot remove the earlier run's file: {e}")))?;
        }
        Ok(())
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Whether this run continues an earlier one.
    pub fn resuming(&self) -> bool {
        self.resume
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.root.join(name)
    }

    /// A resumed run, once its saved state has loaded: drops the finished run's report (so a
    /// continuation that is interrupted reads as unfinished) and records the settings it goes
    /// on with (`config`). Until then a refused resume leaves the run as it was.
    pub fn replace_finished(&self, config: &impl Serialize) -> Result<(), PipelineError> {
        let _ = std::fs::remove_file(self.report());
        self.write_json("config.json", config).map(drop)
    }

    pub fn config(&self) -> PathBuf {
        self.path("config.json")
    }

    pub fn report(&self) -> PathBuf {
        self.path("report.json")
    }

    pub fn report_html(&self) -> PathBuf {
        self.path("report.html")
    }

    pub fn volume(&self) -> PathBuf {
        self.path("volume.npy")
    }

    pub fn checkpoint(&self) -> PathBuf {
        self.path("checkpoint.safetensors")
    }

    pub fn progress(&self) -> PathBuf {
        self.path("windows/progress.json")
    }

    /// What the folder holds.
    pub fn state(&self) -> DirState {
        if self.report().is_file() {
            return DirState::Finished;
        }
        let any = RUN_FILES.iter().any(|n| self.root.join(n).exists());
        if any {
            DirState::Unfinished
        } else {
            DirState::Empty
        }
    }

    /// The kind of result the folder holds, if any.
    pub fn kind(&self) -> Option<RunKind> {
        if self.path("temporal.json").is_file() {
            Some(RunKind::Temporal)
        } else if self.path("model.json").is_file() {
            Some(RunKind::Field)
        } else if self.volume().is_file() {
            Some(RunKind::Volume)
        } else {
            None
        }
    }

    /// Writes `bytes` atomically.
    pub fn write_bytes(&self, name: &str, bytes: &[u8]) -> Result<PathBuf, PipelineError> {
        let path = self.path(name);
        fluidnerf_io::atomic_write(&path, |w| w.write_all(bytes))?;
        Ok(path)
    }

    /// Writes `value` as pretty JSON with a final newline, atomically.
    pub fn write_json(&self, name: &str, value: &impl Serialize) -> Result<PathBuf, PipelineError> {
        write_json(&self.path(name), value)
    }
}

/// A lock file held until dropped ([`RunDir::lock_file`]).
#[derive(Debug)]
pub struct FileLock {
    path: PathBuf,
}

impl Drop for FileLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Creates the lock file `path` of the run folder `root` holding this process's id; refused
/// while a live process holds it, a stale one (its process gone) is replaced.
fn acquire_lock(root: &Path, path: &Path) -> Result<PathBuf, PipelineError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| PipelineError::file(parent, e))?;
    }
    let me = format!("{}\n", std::process::id());
    for _ in 0..2 {
        match std::fs::OpenOptions::new().write(true).create_new(true).open(path) {
            Ok(mut f) => {
                use std::io::Write;
                f.write_all(me.as_bytes()).map_err(|e| PipelineError::file(path, e))?;
                return Ok(path.to_path_buf());
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let holder = std::fs::read_to_string(path).unwrap_or_default();
                let pid: Option<u32> = holder.trim().parse().ok();
                if pid.is_some_and(process_alive) {
                    return Err(PipelineError::RunDir {
                        path: root.to_path_buf(),
                        why: format!(
                            "is in use by another run (process {}, lock file {}); wait for it to finish or use \
                             another output folder",
                            holder.trim(),
                            path.display()
                        ),
                    });
                }
                log::warn!(
                    "{}: removing the stale lock of process {} (no longer running)",
                    root.display(),
                    holder.trim()
                );
                std::fs::remove_file(path).map_err(|e| PipelineError::file(path, e))?;
            }
            Err(e) => return Err(PipelineError::file(path, format!("cannot take the run lock: {e}"))),
        }
    }
    Err(PipelineError::file(path, "cannot take the run lock"))
}

fn process_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    if cfg!(target_os = "linux") {
        Path::new(&format!("/proc/{pid}")).exists()
    } else {
        // Without a way to ask, a lock is assumed held.
        true
    }
}

/// Writes `value` as pretty JSON with a final newline, atomically.
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<PathBuf, PipelineError> {
    let mut text = serde_json::to_string_pretty(value).map_err(|e| PipelineError::file(path, e))?;
    text.push('\n');
    fluidnerf_io::atomic_write(path, |w| w.write_all(text.as_bytes()))?;
    Ok(path.to_path_buf())
}

/// Reads a JSON file; errors name the file and the path of the offending key.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, PipelineError> {
    let text = std::fs::read_to_string(path).map_err(|e| PipelineError::file(path, format!("cannot read: {e}")))?;
    let de = &mut serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(de).map_err(|e| PipelineError::file(path, describe(&e)))
}

/// A JSON value as `T`, with the key path in the error.
pub fn from_json_value<T: DeserializeOwned>(value: serde_json::Value) -> Result<T, PipelineError> {
    serde_path_to_error::deserialize(value).map_err(|e| PipelineError::invalid("configuration", describe(&e)))
}

fn describe(e: &serde_path_to_error::Error<serde_json::Error>) -> String {
    let path = e.path().to_string();
    let why = e.inner().to_string();
    if path.is_empty() || path == "." {
        return why;
    }
    // A key inside a block read in two steps (`method`) comes back in the message: join the
    // paths, and drop the position, which is the end of the block rather than the key.
    if let Some(rest) = why.strip_prefix(crate::config::NESTED_KEY) {
        if let Some((inner, why)) = rest.split_once("`: ") {
            let why = why.rsplit_once(" at line ").map_or(why, |(w, _)| w);
            return format!("at `{path}.{inner}`: {why}");
        }
    }
    format!("at `{path}`: {why}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_results_and_the_scene_folder_and_honours_the_lock() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("run");
        let scene = tmp.path().join("scene");
        std::fs::create_dir_all(&scene).unwrap();
        let e = RunDir::create(&scene, Overwrite::Force, Some(&scene)).unwrap_err().to_string();
        assert!(e.contains("scene's own folder"), "{e}");
        {
            let dir = RunDir::create(&out, Overwrite::Refuse, Some(&scene)).unwrap();
            assert_eq!(dir.state(), DirState::Empty);
            dir.write_json("config.json", &1).unwrap();
            // A second run into the same folder while the first holds it.
            let e = RunDir::create(&out, Overwrite::Force, None).unwrap_err().to_string();
            assert!(e.contains("in use by another run") && e.contains(&std::process::id().to_string()), "{e}");
        }
        assert!(!out.join(".lock").exists(), "the lock goes with the run");
        // A run refused before writing anything leaves no folder behind.
        drop(RunDir::create(tmp.path().join("refused"), Overwrite::Refuse, None).unwrap());
        assert!(!tmp.path().join("refused").exists());
        // Killed before the report: unfinished, refused without --force or --resume.
        let e = RunDir::create(&out, Overwrite::Refuse, None).unwrap_err().to_string();
        assert!(e.contains("unfinished"), "{e}");
        let dir = RunDir::create(&out, Overwrite::Resume, None).unwrap();
        assert!(dir.resuming());
        dir.write_json("report.json", &1).unwrap();
        assert_eq!(dir.state(), DirState::Finished);
        drop(dir);
        let e = RunDir::create(&out, Overwrite::Refuse, None).unwrap_err().to_string();
        assert!(e.contains("finished run"), "{e}");
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let dir = RunDir::create(&out, Overwrite::Force, None).unwrap();
        assert_eq!(dir.state(), DirState::Empty);
        assert!(out.join("notes.txt").exists(), "--force removes run files only");
    }

    #[test]
    fn a_stale_lock_is_replaced() {
        let tmp = tempfile::tempdir().unwrap();
        // No process has this id (above the kernel's pid_max).
        std::fs::write(tmp.path().join(".lock"), "4194305\n").unwrap();
        let dir = RunDir::create(tmp.path(), Overwrite::Refuse, None).unwrap();
        assert_eq!(std::fs::read_to_string(tmp.path().join(".lock")).unwrap().trim(), std::process::id().to_string());
        drop(dir);
    }
}
