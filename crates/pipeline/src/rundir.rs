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
//!
//! A lock ([`FileLock`]) names its process and machine, and its holder refreshes the file's
//! modification time every [`LOCK_HEARTBEAT`] while it holds it, so that a lock left by a
//! machine that died on a shared file system is recognised as stale after
//! [`LOCK_STALE_AFTER`] (see [`FileLock`] for the rules).
//!
//! A run folder is never the scene's folder, a folder inside it, or one that holds anything
//! the scene reads (its images, masks, background frames and ground truth); nor a folder of
//! another kind ([`FolderKind`]). `--force` replaces only a fluidnerf run: a folder whose
//! `config.json` is a run's configuration.

use std::path::{Component, Path, PathBuf};
use std::time::{Duration, SystemTime};

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
    /// Files with the names a run writes (e.g. `volume.npy`) but no run configuration
    /// (`config.json` of a run): not a fluidnerf run, so never replaced or continued.
    Foreign,
}

pub use fluidnerf_io::folder::{folder_kind, FolderKind};

mod scene_aside;
pub use scene_aside::SceneAside;

/// Refuses `out` as the output folder of `command`, which writes folders of kind `kind`, when
/// it is a fluidnerf folder of another kind: writing there would mix two kinds of results (and
/// make, e.g., a scene folder pass for a run).
pub fn refuse_other_kind(out: &Path, kind: FolderKind, command: &str) -> Result<(), PipelineError> {
    refuse_non_folder(out)?;
    match folder_kind(out) {
        Some(found) if found != kind => Err(PipelineError::RunDir {
            path: out.to_path_buf(),
            why: format!(
                "is {}; `{command}` writes {} only: choose another output folder",
                found.describe(),
                match kind {
                    FolderKind::Scene => "scene folders",
                    FolderKind::Run => "run folders",
                    FolderKind::Export => "export folders",
                    FolderKind::Render => "folders of rendered views",
                    FolderKind::Compare => "comparison folders",
                    FolderKind::Study => "study folders",
                    FolderKind::Demo => "demo folders",
                }
            ),
        }),
        _ => Ok(()),
    }
}

/// Refuses `out` as an output folder when it cannot be one: an existing file, or a file where one
/// of its parent folders would go. Commands check this before their work, not when they come to
/// write (`synth` took half a minute to make a scene, then refused a file given as its folder).
pub fn refuse_non_folder(out: &Path) -> Result<(), PipelineError> {
    if out.exists() && !out.is_dir() {
        return Err(PipelineError::RunDir {
            path: out.to_path_buf(),
            why: "exists and is not a folder; give a new or existing folder for the output".into(),
        });
    }
    if let Some(file) = out.ancestors().skip(1).find(|a| a.is_file()) {
        return Err(PipelineError::RunDir {
            path: out.to_path_buf(),
            why: format!("cannot create the output folder, {} is a file", file.display()),
        });
    }
    Ok(())
}

/// Refuses `out` as an output folder for results of the scene in `scene_root` when it is the
/// scene's folder, lies inside it, contains it, or contains a file the scene reads (listed in
/// its `transforms.json`: images, masks, background frames, ground truth), wherever those lie.
/// Results written there would mix with the scene's inputs, and replacing them could delete
/// them.
pub fn refuse_scene_inputs(out: &Path, scene_root: &Path) -> Result<(), PipelineError> {
    let (out_abs, root) = (resolved(out), resolved(scene_root));
    if out_abs != root && out_abs.starts_with(&root) {
        return Err(PipelineError::RunDir {
            path: out.to_path_buf(),
            why: format!(
                "lies inside the scene folder {} (which holds its images and truth); choose an output folder \
                 outside the scene",
                scene_root.display()
            ),
        });
    }
    refuse_among_scene_inputs(out, scene_root)
}

/// Refuses `out` as an output folder of pictures or volumes made from the scene in
/// `scene_root` when it is the scene's folder, contains it, or holds a file the scene reads:
/// renders written among a scene's images would be read as more images. A folder of its own
/// inside the scene's (`scene/renders`) is allowed, unlike for runs ([`refuse_scene_inputs`]).
pub fn refuse_among_scene_inputs(out: &Path, scene_root: &Path) -> Result<(), PipelineError> {
    let refuse = |why: String| PipelineError::RunDir { path: out.to_path_buf(), why };
    let out_abs = resolved(out);
    let root = resolved(scene_root);
    if out_abs == root {
        return Err(refuse("is the scene's own folder; choose another output folder".into()));
    }
    if root.starts_with(&out_abs) {
        return Err(refuse(format!(
            "contains the scene folder {}; choose an output folder that does not hold the scene",
            scene_root.display()
        )));
    }
    refuse_inputs_in(out, scene_root, false)
}

/// Refuses `out` when it holds a file the scene in `scene_root` reads, apart from those in the
/// scene's own folder when `own_scene` (a run's own scene, [`OWN_SCENE`]).
fn refuse_inputs_in(out: &Path, scene_root: &Path, own_scene: bool) -> Result<(), PipelineError> {
    let (out_abs, root) = (resolved(out), resolved(scene_root));
    for (file, what) in scene_inputs(&scene_root.join(fluidnerf_io::scene::SCENE_FILE)) {
        let file_abs = resolved(&file);
        if file_abs.starts_with(&out_abs) && !(own_scene && file_abs.starts_with(&root)) {
            return Err(PipelineError::RunDir {
                path: out.to_path_buf(),
                why: format!(
                    "holds {} ({what} the scene reads); choose an output folder apart from the scene's inputs",
                    file.display()
                ),
            });
        }
    }
    Ok(())
}

/// Files of results that commands write into a scene folder beside its scene file: the
/// settings `synth` and `import` record, and `synth`'s preview picture.
const SCENE_RECORDS: [&str; 3] = ["synth.json", "import.json", "preview.png"];

/// Refuses `out` as a file of results made from the scene file `scene_file` when it is that
/// file, a file the scene reads (an image, mask, background frame or ground truth it lists) or
/// a record written with the scene ([`SCENE_RECORDS`] beside the scene file). Replacing any of
/// them, even when asked to overwrite, would destroy the scene.
pub fn refuse_scene_file(out: &Path, scene_file: &Path) -> Result<(), PipelineError> {
    let out_abs = resolved(out);
    let refuse = |why: String| {
        Err(PipelineError::File {
            path: out.to_path_buf(),
            why: format!("{why}; it is never overwritten, even with --force: choose another output file"),
        })
    };
    if out_abs == resolved(scene_file) {
        return refuse("is the scene file".into());
    }
    let root = scene_file.parent().unwrap_or(Path::new(""));
    for name in SCENE_RECORDS {
        if out_abs == resolved(&root.join(name)) {
            return refuse(format!("is the scene's record {name}, written with it"));
        }
    }
    for (file, what) in scene_inputs(scene_file) {
        if out_abs == resolved(&file) {
            return refuse(format!("is listed in the scene file {} as {what}", scene_file.display()));
        }
    }
    Ok(())
}

/// Refuses `out` as a file of results about the run in `run_root` when it is a file the run
/// wrote ([`RUN_FILES`], anything in its `frames/`, `windows/` or [`OWN_RUNS`] folders, its
/// lock), or lies inside one of them. The evaluation of a run ([`EVAL_FILES`]) is written into
/// its folder and may be replaced.
pub fn refuse_run_file(out: &Path, run_root: &Path) -> Result<(), PipelineError> {
    let (out_abs, root) = (resolved(out), resolved(run_root));
    let Ok(inside) = out_abs.strip_prefix(&root) else { return Ok(()) };
    let Some(first) = inside.components().next().and_then(|c| c.as_os_str().to_str()) else {
        return Err(PipelineError::File {
            path: out.to_path_buf(),
            why: format!("is the run folder {}; give a file", run_root.display()),
        });
    };
    let written = RUN_FILES.contains(&first) && !EVAL_FILES.contains(&first);
    if written || OWN_RUNS.contains(&first) || first == ".lock" {
        let what = if inside.components().count() > 1 { "lies in the folder" } else { "is the file" };
        return Err(PipelineError::File {
            path: out.to_path_buf(),
            why: format!(
                "{what} {first} that the run in {} wrote; a run's files are never overwritten, even with --force: \
                 choose another output file (a new name inside the run folder is fine)",
                run_root.display()
            ),
        });
    }
    Ok(())
}

/// Refuses `out` as a file of results when it is `input`, a file the command reads (`what`
/// says which, e.g. "the reconstruction").
pub fn refuse_input_file(out: &Path, input: &Path, what: &str) -> Result<(), PipelineError> {
    if resolved(out) == resolved(input) {
        return Err(PipelineError::File {
            path: out.to_path_buf(),
            why: format!("is {what}; an input is never overwritten, even with --force: choose another output file"),
        });
    }
    Ok(())
}

/// The files the scene file `scene_file` lists, each with what it is for: frame images, masks,
/// background frames, flat-field frames and ground truth (relative paths resolved against the
/// file's folder).
/// The scene was read before; a file that cannot be read here lists nothing.
fn scene_inputs(scene_file: &Path) -> Vec<(PathBuf, &'static str)> {
    use serde_json::Value;
    let scene_root = scene_file.parent().unwrap_or(Path::new(""));
    let Some(raw) = std::fs::read_to_string(scene_file).ok().and_then(|t| serde_json::from_str::<Value>(&t).ok())
    else {
        return Vec::new();
    };
    let mut found = Vec::new();
    let mut add = |v: Option<&Value>, what: &'static str| {
        if let Some(p) = v.and_then(Value::as_str) {
            let p = Path::new(p);
            found.push((if p.is_absolute() { p.to_path_buf() } else { scene_root.join(p) }, what));
        }
    };
    // A list, or (for `background` and `flat_field`) one path alone.
    let list = |v: Option<&Value>| match v {
        Some(Value::Array(a)) => a.clone(),
        Some(s @ Value::String(_)) => vec![s.clone()],
        _ => Vec::new(),
    };
    for t in list(raw.get("truth")) {
        add(t.get("file_path"), "ground truth");
    }
    for b in list(raw.get("background")) {
        add(Some(&b), "a background frame");
    }
    for b in list(raw.get("flat_field")) {
        add(Some(&b), "a flat-field frame");
    }
    for f in list(raw.get("frames")) {
        add(f.get("file_path"), "an image");
        add(f.get("mask_path"), "a mask");
        for b in list(f.get("background")) {
            add(Some(&b), "a background frame");
        }
        for b in list(f.get("flat_field")) {
            add(Some(&b), "a flat-field frame");
        }
    }
    found
}

/// Whether `a` and `b` name one file, however they are spelled (`./a.json`, `a.json`,
/// `out/../a.json`, a link), whether or not it exists yet.
pub fn same_path(a: &Path, b: &Path) -> bool {
    resolved(a) == resolved(b)
}

/// `path` made absolute, with symbolic links and `..` resolved as far as it exists; the part
/// that does not exist yet is appended with `.` and `..` applied as written.
fn resolved(path: &Path) -> PathBuf {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let parts: Vec<Component> = abs.components().collect();
    for k in (1..=parts.len()).rev() {
        let head: PathBuf = parts[..k].iter().collect();
        if let Ok(mut out) = head.canonicalize() {
            for c in &parts[k..] {
                match c {
                    Component::ParentDir => {
                        out.pop();
                    }
                    Component::CurDir => {}
                    other => out.push(other),
                }
            }
            return out;
        }
    }
    abs
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

/// The files of [`RUN_FILES`] that `eval` writes into a run's folder: not the run's own, so an
/// evaluation may replace them.
const EVAL_FILES: [&str; 2] = ["metrics.json", "metrics.csv"];

/// The files and folders a run itself writes (those of [`RUN_FILES`] that `eval` does not), in
/// the order a listing of them reads best: settings and reports, results, frames, windows.
pub fn run_outputs() -> impl Iterator<Item = &'static str> {
    RUN_FILES.into_iter().filter(|f| !EVAL_FILES.contains(f))
}

/// Folders inside a run's folder that hold runs of their own, written by the run (`hybrid`'s
/// voxel run, its start). They go with the run's files when they hold a run (its `config.json`),
/// and do not make a folder read as one with run files ([`DirState::Foreign`]).
const OWN_RUNS: [&str; 1] = ["start"];

/// Where `--force` keeps the run it replaces until the new run writes its configuration.
const REPLACED: &str = ".replaced";

/// Where the Python API keeps a run's own scene ([`OWN_SCENE`]) while a scene from arrays
/// replaces it, until the run writes its configuration.
const SCENE_SET_ASIDE: &str = ".scene-replaced";

/// [`REPLACED`] once the new run has written its configuration, while it is removed.
const REPLACED_DISCARDED: &str = ".replaced-discarded";

/// The folder inside a run's folder that may hold the run's own scene: the Python API saves a
/// scene built from arrays there (`reconstruct(scene, method, out)` into `out/scene`). A run
/// writes nothing there ([`RUN_FILES`], [`OWN_RUNS`]), so the scene is neither overwritten nor
/// read as the run's, and `--force` leaves it.
pub const OWN_SCENE: &str = "scene";

/// The folder of one run. Opening it for writing ([`RunDir::create`]) takes its lock, which is
/// released when the `RunDir` is dropped.
#[derive(Debug)]
pub struct RunDir {
    root: PathBuf,
    lock: Option<FileLock>,
    resume: bool,
    /// The folder did not exist before: if the run is refused before writing anything, it goes.
    created: bool,
    /// The folders of [`OWN_RUNS`] holding a run when this one began (a resumed run's start):
    /// not this run's to discard.
    kept_runs: Vec<PathBuf>,
    /// `--force` moved the earlier run into [`REPLACED`] and the new run has not yet written
    /// its configuration: dropped so, the folder gets the earlier run back.
    staged: std::sync::atomic::AtomicBool,
}

impl Drop for RunDir {
    fn drop(&mut self) {
        if self.staged.swap(false, std::sync::atomic::Ordering::Relaxed) {
            // Refused (or failed) before it wrote anything: the run it was to replace stays.
            self.restore_replaced();
        }
        if let Some(lock) = self.lock.take() {
            // The lock goes first (its heartbeat stopped, its file removed), then the folder.
            drop(lock);
            if self.created {
                // Removes the folder only when nothing was written into it.
                let _ = std::fs::remove_dir(&self.root);
            }
        }
    }
}

impl RunDir {
    /// The folder `root` as found: no lock taken, nothing created, moved or resumed.
    fn plain(root: PathBuf) -> Self {
        RunDir { root, lock: None, resume: false, created: false, kept_runs: Vec::new(), staged: Default::default() }
    }

    /// A run folder to read (no lock, nothing created). A run that a killed `--force` had set
    /// aside is put back first ([`RunDir::recover_replaced`]), so that every reader sees it.
    pub fn open(root: impl Into<PathBuf>) -> Result<Self, PipelineError> {
        let root = root.into();
        if !root.is_dir() {
            return Err(PipelineError::RunDir { path: root, why: "is not a folder".into() });
        }
        Self::recover_replaced(&root);
        Ok(RunDir::plain(root))
    }

    /// Creates (or reuses, as `overwrite` allows) the folder of a new run and takes its lock. A
    /// stale lock (its process is gone, or its machine's heartbeat stopped; [`FileLock`]) is
    /// replaced. Refused: a folder apart from the scene in
    /// `scene_root` is needed ([`refuse_scene_inputs`]), a folder of another kind
    /// ([`FolderKind`]), and one that holds run files but no run ([`DirState::Foreign`]).
    pub fn create(
        root: impl Into<PathBuf>,
        overwrite: Overwrite,
        scene_root: Option<&Path>,
    ) -> Result<Self, PipelineError> {
        let root: PathBuf = root.into();
        let refuse = |why: String| PipelineError::RunDir { path: root.clone(), why };
        check_new_run_folder(&root, scene_root)?;
        let created = !root.exists();
        std::fs::create_dir_all(&root).map_err(|e| refuse(format!("cannot create the folder: {e}")))?;
        let resume = overwrite == Overwrite::Resume;
        let mut dir = RunDir::plain(root.clone());
        (dir.resume, dir.created) = (resume, created);
        dir.take_lock()?;
        // A window trained by another process (`--window-index`) holds only its own lock: a
        // whole run replacing, resuming or finishing the folder meanwhile took it over, and the
        // window then wrote its old settings' checkpoint into the new run, which --finish mixed
        // with the new windows.
        if let Some((lock, holder)) = live_window_holders(&root).into_iter().next() {
            return Err(refuse(format!(
                "a window of its run is being trained by another process ({holder}, lock file {}); wait for it to \
                 finish, or stop it, before replacing, resuming or finishing the run",
                lock.display()
            )));
        }
        // A replacement whose run died before writing anything left the earlier run aside.
        dir.restore_replaced();
        let state = dir.state();
        dir.refusal(state, overwrite)?;
        match (state, overwrite) {
            (DirState::Empty, _) => dir.resume = false,
            (_, Overwrite::Force) => dir.stage_earlier()?,
            _ => {}
        }
        dir.kept_runs = dir.own_runs();
        Ok(dir)
    }

    /// The refusals of [`RunDir::create`] for `overwrite` (the folder's lock aside), without
    /// creating, locking or clearing anything: for a caller that writes into the folder before
    /// the run (the Python API saves a scene built from arrays into [`OWN_SCENE`]).
    pub fn check(root: impl Into<PathBuf>, overwrite: Overwrite) -> Result<(), PipelineError> {
        let root: PathBuf = root.into();
        check_new_run_folder(&root, None)?;
        let dir = RunDir::plain(root);
        dir.refusal(dir.state(), overwrite)
    }

    /// Why a folder in `state` cannot take a run as `overwrite` asks, if it cannot.
    fn refusal(&self, state: DirState, overwrite: Overwrite) -> Result<(), PipelineError> {
        let refuse = |why: &str| Err(PipelineError::RunDir { path: self.root.clone(), why: why.into() });
        match (state, overwrite) {
            (DirState::Foreign, _) => Err(self.foreign()),
            (DirState::Empty, Overwrite::Resume) => {
                refuse("nothing to resume (--resume; `overwrite=\"resume\"` from Python): it holds no run")
            }
            (DirState::Finished, Overwrite::Refuse) => refuse(
                "already holds a finished run; use --force to replace it (or --resume to continue training a neural \
                 run; from Python `overwrite=\"force\"` or `\"resume\"`)",
            ),
            (DirState::Unfinished, Overwrite::Refuse)
                if !self.checkpoint().exists() && !self.path("windows").exists() =>
            {
                refuse(
                    "holds an unfinished run that stopped before its first checkpoint (run files but no \
                     report.json: it died or was killed), so there is nothing to resume; use --force to replace \
                     it (from Python `overwrite=\"force\"`)",
                )
            }
            (DirState::Unfinished, Overwrite::Refuse) => refuse(
                "holds an unfinished run (run files but no report.json: it died or was killed); use --resume to \
                 continue it (neural methods) or --force to replace it (from Python `overwrite=\"resume\"` or \
                 `\"force\"`)",
            ),
            _ => Ok(()),
        }
    }

    /// The refusal of a folder with run files but no run ([`DirState::Foreign`]).
    fn foreign(&self) -> PipelineError {
        let files: Vec<&str> = RUN_FILES.iter().copied().filter(|n| self.root.join(n).exists()).collect();
        PipelineError::RunDir {
            path: self.root.clone(),
            why: format!(
                "holds {} but is not a fluidnerf run folder (no run configuration in config.json); a run is never \
                 written into it, and --force replaces only fluidnerf's own runs: choose another output folder",
                files.join(", ")
            ),
        }
    }

    fn take_lock(&mut self) -> Result<(), PipelineError> {
        self.lock = Some(FileLock::take(&self.root, &self.root.join(".lock"))?);
        Ok(())
    }

    /// A run folder in which windows of a time-resolved run are trained one at a time, by
    /// this process and possibly others at once
    /// ([`crate::reconstruct_windows`]): created if missing, refused when it is the scene's
    /// folder, holds a finished run, or is locked by a whole run. It takes no lock itself;
    /// each window is locked while it trains ([`RunDir::lock_file`]).
    pub fn for_windows(root: impl Into<PathBuf>, scene_root: Option<&Path>) -> Result<Self, PipelineError> {
        let root: PathBuf = root.into();
        Self::check_windows(&root, scene_root)?;
        std::fs::create_dir_all(&root)
            .map_err(|e| PipelineError::RunDir { path: root.clone(), why: format!("cannot create the folder: {e}") })?;
        Ok(RunDir::plain(root))
    }

    /// The refusals of [`RunDir::for_windows`], without creating anything: for a caller that
    /// writes into the folder before its windows are trained (the Python API saves a scene
    /// built from arrays into [`OWN_SCENE`]).
    pub fn check_windows(root: impl Into<PathBuf>, scene_root: Option<&Path>) -> Result<(), PipelineError> {
        let root: PathBuf = root.into();
        let refuse = |why: String| PipelineError::RunDir { path: root.clone(), why };
        check_new_run_folder(&root, scene_root)?;
        Self::recover_replaced(&root);
        let dir = RunDir::plain(root.clone());
        if dir.state() == DirState::Foreign {
            return Err(dir.foreign());
        }
        if dir.report().is_file() {
            // A run in one piece stopped by Ctrl-C writes its report too: it is continued with
            // --resume, not by training its windows one at a time.
            let interrupted = std::fs::read_to_string(dir.report())
                .ok()
                .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
                .is_some_and(|v| v.get("status").and_then(|s| s.as_str()) == Some("interrupted"));
            if interrupted {
                return Err(refuse(
                    "holds a run that was interrupted (its report.json says so), not windows trained one at a time; \
                     continue it with `reconstruct --resume` (`overwrite=\"resume\"` from Python), or use another \
                     folder"
                        .into(),
                ));
            }
            return Err(refuse(
                "already holds a finished run; training windows into it would mix two runs (remove it, or use \
                 another folder)"
                    .into(),
            ));
        }
        if let Some(holder) = live_holder(&root) {
            return Err(refuse(format!(
                "is in use by a whole run ({holder}, lock file {}); wait for it to finish",
                root.join(".lock").display()
            )));
        }
        Ok(())
    }

    /// The process that holds the folder's run lock and still runs (a run under way, such as
    /// a `--resume`), in words; None when no live process holds it.
    pub fn running_holder(&self) -> Option<String> {
        live_holder(&self.root)
    }

    /// Takes the lock file `name` (relative to the folder) until the guard is dropped; refused
    /// while a live process holds it, a stale one is replaced ([`FileLock`]).
    pub fn lock_file(&self, name: &str) -> Result<FileLock, PipelineError> {
        FileLock::take(&self.root, &self.path(name))
    }

    /// Moves the files of an earlier run (only those a run writes, and only from a folder that
    /// holds a run) and its own runs into [`REPLACED`], where they stay until the new run writes
    /// its configuration ([`RunDir::write_json`]): a run refused by its own checks, which come
    /// before that, leaves the earlier run as it was.
    fn stage_earlier(&self) -> Result<(), PipelineError> {
        if self.state() == DirState::Foreign {
            return Err(self.foreign());
        }
        let aside = self.path(REPLACED);
        std::fs::create_dir(&aside)
            .map_err(|e| PipelineError::file(&aside, format!("cannot make a folder for the earlier run: {e}")))?;
        self.staged.store(true, std::sync::atomic::Ordering::Relaxed);
        let move_aside = |from: &Path, to: &Path| {
            std::fs::rename(from, to)
                .map_err(|e| PipelineError::file(from, format!("cannot move the earlier run's file aside: {e}")))
        };
        for name in RUN_FILES {
            let p = self.root.join(name);
            if p.exists() {
                move_aside(&p, &aside.join(name))?;
            }
        }
        for p in self.own_runs() {
            let to = aside.join(p.strip_prefix(&self.root).unwrap_or(&p));
            if let Some(parent) = to.parent() {
                std::fs::create_dir_all(parent).map_err(|e| PipelineError::file(parent, e))?;
            }
            move_aside(&p, &to)?;
        }
        self.remove_emptied_own_folders();
        Ok(())
    }

    /// The new run has written its configuration: the earlier run it replaces goes.
    fn drop_replaced(&self) {
        if !self.staged.swap(false, std::sync::atomic::Ordering::Relaxed) {
            return;
        }
        // Renamed first, so that a removal cut short is never taken for a run to restore.
        let discard = self.path(REPLACED_DISCARDED);
        let removed = std::fs::rename(self.path(REPLACED), &discard).and_then(|()| std::fs::remove_dir_all(&discard));
        if let Err(e) = removed {
            log::warn!("{}: cannot remove the replaced run's files: {e}", discard.display());
        }
    }

    /// Puts back the earlier run that a `--force` run set aside in [`REPLACED`] and never
    /// replaced, its process having died before it wrote its configuration, for a caller about
    /// to read the folder or train windows into it: without this, `eval`, `export`, `render` and
    /// window training would see no run there until the next `reconstruct`. Done under the
    /// folder's lock, so never while a live process holds it (a run that is setting the earlier
    /// one aside right now keeps it), and only into a folder that holds no run files
    /// ([`RunDir::restore_replaced`]). A scene the Python API set aside for the run in the same
    /// call is settled first ([`SceneAside`]); while it cannot be, the run stays aside too.
    pub fn recover_replaced(root: &Path) {
        // The Python API's scene aside first ([`SceneAside`]): the run put back must be read
        // with the scene it was made on.
        let scene_aside = scene_aside::recover(root);
        if !root.join(REPLACED).is_dir() {
            return;
        }
        if scene_aside {
            // Still there: the call that set it aside is alive (and the run aside is its
            // `--force`'s), or it left no record of its run. Left as it is, and said.
            log::warn!(
                "{}: a run set aside by a --force run that never finished is in {REPLACED}, and the scene it was made \
                 on may be in {SCENE_SET_ASIDE}; neither is put back while the call that set them aside runs, or \
                 when that call left no record of its run: move them back by hand, or replace the run",
                root.display()
            );
            return;
        }
        let mut dir = RunDir::plain(root.to_path_buf());
        if dir.take_lock().is_ok() {
            log::info!("{}: putting back the run a --force run that never finished had set aside", root.display());
            dir.restore_replaced();
        }
    }

    /// Puts the earlier run that [`RunDir::stage_earlier`] moved aside back in place, when the
    /// folder holds no run files (the run that set it aside wrote none). A folder that holds
    /// another run's files by now (windows trained into it since) keeps them: nothing is put
    /// back over them, and the earlier run stays in [`REPLACED`], with a warning.
    fn restore_replaced(&self) {
        let _ = std::fs::remove_dir_all(self.path(REPLACED_DISCARDED));
        let aside = self.path(REPLACED);
        if !aside.is_dir() {
            return;
        }
        if self.state() == DirState::Empty {
            for name in RUN_FILES {
                let from = aside.join(name);
                if from.exists() {
                    let _ = std::fs::rename(&from, self.path(name));
                }
            }
            // Run by run: `start/` may hold files of the user's, which stayed when it went aside.
            for own in OWN_RUNS {
                let (from, to) = (aside.join(own), self.path(own));
                if !from.is_dir() || std::fs::create_dir_all(&to).is_err() {
                    continue;
                }
                for entry in std::fs::read_dir(&from).into_iter().flatten().filter_map(Result::ok) {
                    let target = to.join(entry.file_name());
                    if !target.exists() {
                        let _ = std::fs::rename(entry.path(), target);
                    }
                }
                let _ = std::fs::remove_dir(&from);
            }
        }
        if std::fs::remove_dir(&aside).is_err() {
            log::warn!(
                "{}: a run that a --force run was to replace, which could not be put back in place (the folder holds \
                 another run's files); it is kept here",
                aside.display()
            );
        }
    }

    /// The runs a run wrote into its [`OWN_RUNS`] folders: the folder itself when it holds a run
    /// (a static field's `start/`), else its `tNN` folders that hold one (the runs of the
    /// instants a time-resolved run starts from, `start/t00/`, `start/t01/`, …).
    fn own_runs(&self) -> Vec<PathBuf> {
        let holds_run = |p: &Path| p.join("config.json").is_file();
        let instant =
            |name: &str| name.len() > 1 && name.starts_with('t') && name[1..].bytes().all(|b| b.is_ascii_digit());
        let mut runs = Vec::new();
        for folder in OWN_RUNS.iter().map(|n| self.root.join(n)) {
            if holds_run(&folder) {
                runs.push(folder);
                continue;
            }
            let Ok(entries) = std::fs::read_dir(&folder) else { continue };
            let mut instants: Vec<PathBuf> = entries
                .filter_map(Result::ok)
                .filter(|e| e.file_name().to_str().is_some_and(instant))
                .map(|e| e.path())
                .filter(|p| holds_run(p))
                .collect();
            instants.sort();
            runs.extend(instants);
        }
        runs
    }

    /// Removes the [`OWN_RUNS`] folders that removing their runs left empty.
    fn remove_emptied_own_folders(&self) {
        for folder in OWN_RUNS.iter().map(|n| self.root.join(n)) {
            // Only an empty folder goes: anything else in it is not the run's.
            let _ = std::fs::remove_dir(folder);
        }
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

    /// After a fresh run failed: when it left nothing to resume (no checkpoint, no window's),
    /// removes the run files it wrote, so that the folder does not read as an unfinished run
    /// that `--resume` could continue. Only [`RUN_FILES`] go, and the runs of [`OWN_RUNS`] it
    /// wrote: a fresh run starts in a folder holding none of them (or whose earlier ones
    /// `--force` removed), so they are its own.
    pub fn discard_unresumable(&self) {
        if self.resume || self.lock.is_none() || self.checkpoint().exists() || self.path("windows").exists() {
            return;
        }
        for name in RUN_FILES {
            let path = self.path(name);
            let _ = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        }
        for path in self.own_runs().into_iter().filter(|p| !self.kept_runs.contains(p)) {
            let _ = std::fs::remove_dir_all(&path);
        }
        self.remove_emptied_own_folders();
    }

    /// A resumed run, once its saved state has loaded: drops the scores `eval` wrote of the
    /// earlier run's field ([`EVAL_FILES`]) and its series of volumes (`frames/`,
    /// `volumes.pvd`), marks its report as stopped (`interrupted`) or, when its volumes went with
    /// the series, drops it (so a continuation that dies reads as unfinished), and records the
    /// settings it goes on with (`config`). The continuation writes its own volumes: those of
    /// the earlier run that it does not rewrite (a held-out time dropped, frames numbered anew)
    /// and the earlier scores would otherwise sit beside its results as if they were theirs. A
    /// static run's volume and weights stay until the continuation replaces them: with its
    /// report kept, a continuation that fails (a full disk) or is killed leaves a stopped run
    /// that `eval`, `export` and `render` read and `--resume` continues with its histories.
    /// Until then a refused resume leaves the run as it was.
    pub fn replace_finished(&self, config: &impl Serialize) -> Result<(), PipelineError> {
        for name in EVAL_FILES.into_iter().chain(["volumes.pvd"]) {
            let path = self.path(name);
            if path.is_file() {
                std::fs::remove_file(&path)
                    .map_err(|e| PipelineError::file(&path, format!("cannot remove the earlier run's file: {e}")))?;
            }
        }
        let frames = self.path("frames");
        if frames.is_dir() {
            std::fs::remove_dir_all(&frames)
                .map_err(|e| PipelineError::file(&frames, format!("cannot remove the earlier run's volumes: {e}")))?;
        }
        // The report stays, marked stopped, while every volume it lists is still there.
        let kept = crate::RunReport::read(&self.report())
            .ok()
            .filter(|r| !r.volumes.is_empty() && r.volumes.iter().all(|v| self.path(&v.file).is_file()));
        match kept {
            Some(mut report) => {
                report.status = crate::RunStatus::Interrupted;
                report.stop_reason = crate::report::StopReason::Interrupted;
                self.write_json("report.json", &report)?;
            }
            None => {
                let _ = std::fs::remove_file(self.report());
            }
        }
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
        if !RUN_FILES.iter().any(|n| self.root.join(n).exists()) {
            DirState::Empty
        } else if !self.holds_run_config() {
            DirState::Foreign
        } else if self.report().is_file() {
            DirState::Finished
        } else {
            DirState::Unfinished
        }
    }

    /// Whether `config.json` is a run's configuration (written first by every run): a JSON
    /// object with the keys `scene` and `method`. Checked by shape rather than read as a
    /// [`crate::RunConfig`], so that a run written by another version is still recognised.
    fn holds_run_config(&self) -> bool {
        std::fs::read_to_string(self.config())
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|v| v.get("scene").is_some() && v.get("method").is_some())
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
    /// Writes `name` atomically. The run's configuration (`config.json`, its first file) is
    /// the point of no return of `--force`: the earlier run it replaces goes then.
    pub fn write_json(&self, name: &str, value: &impl Serialize) -> Result<PathBuf, PipelineError> {
        let written = write_json(&self.path(name), value)?;
        if name == "config.json" {
            self.drop_replaced();
        }
        Ok(written)
    }
}

/// The checks of a folder about to receive a run, before anything is created: apart from the
/// scene (unless the scene is the run's own, in [`OWN_SCENE`]), a folder (when it exists) and
/// not one of another kind ([`refuse_other_kind`]). [`RunDir::create`] makes them before it
/// reads what the folder holds; a caller that refuses a folder for what it holds makes them
/// first too, so that a folder refused for its place is refused as `create` refuses it.
pub fn check_new_run_folder(root: &Path, scene_root: Option<&Path>) -> Result<(), PipelineError> {
    match scene_root {
        Some(scene) if resolved(scene) == resolved(&root.join(OWN_SCENE)) => refuse_inputs_in(root, scene, true)?,
        Some(scene) => refuse_scene_inputs(root, scene)?,
        None => {}
    }
    // A file at the folder's place, or at a parent's, is refused there too.
    refuse_other_kind(root, FolderKind::Run, "reconstruct")
}

/// Refuses a run that replaces the run in `out` (`overwrite` [`Overwrite::Force`]) while it starts
/// (`config`'s `method.start.run`, `--start-from`) from that run or from a folder its clearing
/// removes ([`RUN_FILES`], [`OWN_RUNS`] such as a hybrid run's `start/`): the clearing happens
/// before the run reads its start, so the start was deleted and then refused as holding
/// nothing. A run in another subfolder of `out` is kept, and may be started from. Called
/// before [`RunDir::create`].
pub fn check_start_outside(config: &crate::RunConfig, out: &Path, overwrite: Overwrite) -> Result<(), PipelineError> {
    let crate::MethodConfig::Neural(_, crate::NeuralSpec { start: Some(start), .. }) = &config.method else {
        return Ok(());
    };
    let Some(run) = &start.run else { return Ok(()) };
    if overwrite != Overwrite::Force || !out.exists() {
        return Ok(());
    }
    let (run_path, out_path) = (resolved(run), resolved(out));
    let removed =
        run_path == out_path || RUN_FILES.iter().chain(&OWN_RUNS).any(|name| run_path.starts_with(out_path.join(name)));
    if removed {
        return Err(PipelineError::invalid(
            "method.start.run",
            format!(
                "{} is the run in the output folder {} or one of its start runs, which --force \
                 (`overwrite=\"force\"` from Python) removes before the new run reads its start; copy the start \
                 run elsewhere, or write the new run to another folder",
                run.display(),
                out.display()
            ),
        ));
    }
    Ok(())
}

/// How often the holder of a lock refreshes its file's modification time (its heartbeat).
pub const LOCK_HEARTBEAT: Duration = Duration::from_secs(10);

/// How long a lock of another machine may go without a heartbeat before it is taken as
/// abandoned (that machine died, or lost the file system, with the lock held) and replaced:
/// twelve missed heartbeats, room for a loaded machine or a slow network file system.
pub const LOCK_STALE_AFTER: Duration = Duration::from_secs(120);

/// The third line of a lock file whose holder refreshes it every [`LOCK_HEARTBEAT`].
const HEARTBEAT_MARK: &str = "heartbeat";

/// A lock file held until dropped ([`RunDir::create`], [`RunDir::lock_file`]).
///
/// The file holds three lines: the process id, the machine's name and `heartbeat`. While the
/// lock is held a background thread rewrites the file every [`LOCK_HEARTBEAT`] (the same
/// bytes: the file system stamps its modification time); it is stopped and joined when the
/// lock is dropped, before the file is removed, and it never creates the file, so a dropped
/// lock does not come back. A lock found taken over (its file gone or another holder's) is
/// neither refreshed nor removed any more.
///
/// Whether an existing lock is held:
/// - one of this machine is held while its process lives (the process id tells; the
///   heartbeat is not needed);
/// - one of another machine, which this one cannot ask about its processes, is held while its
///   heartbeat goes on: it is stale, and replaced with a warning, once its file has not been
///   refreshed for [`LOCK_STALE_AFTER`]. The file's age is measured on the file system's
///   clock, not this machine's: against the modification time of a probe file just created
///   beside it (and removed), so that clocks set apart on the two machines do not matter;
/// - one of another machine without the `heartbeat` line was written by an earlier fluidnerf,
///   which never refreshed it: its age says nothing about whether its run still goes on (a
///   live run of hours has an old lock), so it is never taken as stale: it is held until
///   removed by hand, as the refusal says.
#[derive(Debug)]
pub struct FileLock {
    path: PathBuf,
    /// What this lock wrote into its file.
    contents: String,
    /// The heartbeat thread, stopped by dropping the sender.
    heartbeat: Option<(std::sync::mpsc::Sender<()>, std::thread::JoinHandle<()>)>,
}

impl FileLock {
    /// Takes the lock file `path` of the run folder `root` (creating its folder if missing),
    /// refreshed every [`LOCK_HEARTBEAT`]; refused while it is held, a stale one is replaced.
    /// Also the lock of a study's folder.
    pub fn take(root: &Path, path: &Path) -> Result<FileLock, PipelineError> {
        Self::take_with(root, path, LOCK_HEARTBEAT)
    }

    /// [`FileLock::take`] with a heartbeat every `every`.
    fn take_with(root: &Path, path: &Path, every: Duration) -> Result<FileLock, PipelineError> {
        let contents = format!("{}\n{}\n{HEARTBEAT_MARK}\n", std::process::id(), host_name());
        acquire_lock(root, path, &contents)?;
        let (stop, stopped) = std::sync::mpsc::channel::<()>();
        let (file, text) = (path.to_path_buf(), contents.clone());
        let thread = std::thread::Builder::new()
            .name("fluidnerf-lock-heartbeat".into())
            .spawn(move || heartbeat(&file, &text, every, &stopped));
        let heartbeat = match thread {
            Ok(thread) => Some((stop, thread)),
            Err(e) => {
                let _ = std::fs::remove_file(path);
                return Err(PipelineError::file(path, format!("cannot start the lock's heartbeat: {e}")));
            }
        };
        Ok(FileLock { path: path.to_path_buf(), contents, heartbeat })
    }
}

impl Drop for FileLock {
    fn drop(&mut self) {
        if let Some((stop, thread)) = self.heartbeat.take() {
            drop(stop);
            let _ = thread.join();
        }
        // Only while it is still this lock: one taken over as stale (this process was stopped
        // past the limit) is another run's now.
        if std::fs::read_to_string(&self.path).is_ok_and(|t| t == self.contents) {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// The heartbeat of the lock file `path` holding `contents`: rewrites it every `every` until
/// `stop` is dropped, and ends once the file is gone or another holder's.
fn heartbeat(path: &Path, contents: &str, every: Duration, stop: &std::sync::mpsc::Receiver<()>) {
    let mut failed = false;
    while let Err(std::sync::mpsc::RecvTimeoutError::Timeout) = stop.recv_timeout(every) {
        match refresh(path, contents) {
            Ok(true) => failed = false,
            Ok(false) => {
                log::warn!(
                    "{}: the lock was removed or taken over by another run while this one held it (its heartbeat \
                     stopped for more than {} s?); it is no longer refreshed",
                    path.display(),
                    LOCK_STALE_AFTER.as_secs()
                );
                return;
            }
            // A file system that failed once (a network hiccup) is tried again at the next beat.
            Err(e) if !failed => {
                failed = true;
                log::warn!("{}: cannot refresh the lock: {e}", path.display());
            }
            Err(_) => {}
        }
    }
}

/// Rewrites the lock file `path` with its `contents` (the file system stamps the time), if it
/// still holds them; false when it is gone or holds another's. Never creates it.
fn refresh(path: &Path, contents: &str) -> std::io::Result<bool> {
    use std::io::{Read, Seek, Write};
    let mut f = match std::fs::File::options().read(true).write(true).open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(e),
    };
    let mut text = String::new();
    if f.read_to_string(&mut text).is_err() || text != contents {
        return Ok(false);
    }
    f.rewind()?;
    f.write_all(contents.as_bytes())?;
    Ok(true)
}

/// Creates the lock file `path` of the run folder `root` holding `contents`; refused while it
/// is held, a stale one is replaced ([`FileLock`]).
fn acquire_lock(root: &Path, path: &Path, contents: &str) -> Result<(), PipelineError> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| PipelineError::file(parent, e))?;
    }
    for _ in 0..3 {
        match create_whole(path, contents) {
            Ok(()) => {
                sweep_scratch(path);
                return Ok(());
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let holder = LockHolder::read(path);
                let why = match holder.as_ref().map(|h| h.liveness(path)) {
                    Some(Liveness::Held(note)) => {
                        let holder = holder.as_ref().map_or_else(String::new, ToString::to_string);
                        return Err(in_use(root, path, &holder, &note));
                    }
                    Some(Liveness::Stale(why)) => why,
                    // Created and not yet written, by a taker on a file system without hard
                    // links (`create_whole`): held for now.
                    None if just_made(path) => {
                        return Err(in_use(root, path, "a run that is taking it", ", just now"));
                    }
                    None => "unreadable".to_string(),
                };
                let named = holder.as_ref().map_or_else(|| "an unreadable holder".to_string(), |h| h.to_string());
                // Removed only if it is still the lock judged stale: another process may have
                // replaced it meanwhile, and that one is tried again.
                if LockHolder::read(path).map(|h| (h.text, h.modified)) != holder.map(|h| (h.text, h.modified)) {
                    continue;
                }
                log::warn!("{}: removing the stale lock of {named} ({why})", root.display());
                match std::fs::remove_file(path) {
                    Ok(()) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                    Err(e) => return Err(PipelineError::file(path, e)),
                }
            }
            Err(e) => return Err(PipelineError::file(path, format!("cannot take the run lock: {e}"))),
        }
    }
    Err(PipelineError::file(path, "cannot take the run lock"))
}

/// The refusal of a lock file `path` of the run folder `root` that `holder` holds (`note`
/// says more about it).
fn in_use(root: &Path, path: &Path, holder: &str, note: &str) -> PipelineError {
    PipelineError::RunDir {
        path: root.to_path_buf(),
        why: format!(
            "is in use by another run ({holder}, lock file {}); wait for it to finish or use another output \
             folder{note}",
            path.display()
        ),
    }
}

/// Creates the file `path` with `contents` whole, or fails (`AlreadyExists` when it exists): a
/// reader never sees it empty or half written, which a taker of a lock would take for an
/// unreadable, stale lock and replace. The contents go to a file of their own beside it,
/// linked to `path` (a hard link is created only where no file is, on network file systems
/// as well); where the file system has no hard links, `path` is created and then written.
fn create_whole(path: &Path, contents: &str) -> std::io::Result<()> {
    use std::io::Write;
    let Some(part) = scratch_beside(path, SCRATCH_PART) else {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "a lock path names no file"));
    };
    let written = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&part)
        .and_then(|mut f| f.write_all(contents.as_bytes()));
    let linked = written.and_then(|()| std::fs::hard_link(&part, path));
    let _ = std::fs::remove_file(&part);
    match linked {
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Err(e),
        Ok(()) => Ok(()),
        Err(_) => {
            let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(path)?;
            f.write_all(contents.as_bytes()).inspect_err(|_| {
                let _ = std::fs::remove_file(path);
            })
        }
    }
}

/// A name for a short-lived file of this process beside the file `path`, `NAME.KIND-PID-N`,
/// unique among this process's (None when `path` names no file).
fn scratch_beside(path: &Path, kind: &str) -> Option<PathBuf> {
    static MADE: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = MADE.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let name = path.file_name()?.to_string_lossy();
    Some(path.with_file_name(format!("{name}.{kind}-{}-{n}", std::process::id())))
}

/// Removes the short-lived files beside the lock file `path` ([`scratch_beside`]) that a
/// process killed between creating and removing one left behind: those modified more than a
/// heartbeat before the lock itself, just taken, was (one file system's clock for both). A
/// live one exists for microseconds, so only leftovers are that old.
fn sweep_scratch(path: &Path) {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else { return };
    let Ok(taken) = std::fs::metadata(path).and_then(|m| m.modified()) else { return };
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let name = name.to_string_lossy();
    for entry in entries.flatten() {
        let file = entry.file_name();
        let Some(rest) = file.to_str().and_then(|f| f.strip_prefix(name.as_ref())) else { continue };
        if !SCRATCH_KINDS.iter().any(|kind| is_scratch_tail(rest, kind)) {
            continue;
        }
        let modified = entry.metadata().and_then(|m| m.modified());
        if modified.is_ok_and(|m| taken.duration_since(m).is_ok_and(|age| age > LOCK_HEARTBEAT)) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// The kinds of [`scratch_beside`] files made beside a lock: a lock's contents before they
/// are linked into place ([`create_whole`]), and a clock probe ([`heartbeat_age`]).
const SCRATCH_PART: &str = "part";
const SCRATCH_PROBE: &str = "probe";
const SCRATCH_KINDS: [&str; 2] = [SCRATCH_PART, SCRATCH_PROBE];

/// Whether `rest`, what follows a lock file's name, is `.KIND-PID-N` ([`scratch_beside`]).
fn is_scratch_tail(rest: &str, kind: &str) -> bool {
    let Some(numbers) = rest.strip_prefix('.').and_then(|r| r.strip_prefix(kind)).and_then(|r| r.strip_prefix('-'))
    else {
        return false;
    };
    let mut parts = numbers.split('-');
    let mut number = || parts.next().is_some_and(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    number() && number() && parts.next().is_none()
}

/// Whether the file `path` was modified less than a heartbeat ago (on its file system's clock).
fn just_made(path: &Path) -> bool {
    let modified = std::fs::metadata(path).and_then(|m| m.modified());
    modified.ok().and_then(|m| heartbeat_age(path, m)).is_some_and(|age| age < LOCK_HEARTBEAT)
}

/// This machine's name, written into lock files beside the process id: run folders may lie on
/// a file system that several machines share, where a process id means nothing on another
/// machine (a live lock of one read as stale on another whose process ids differ, or a dead
/// one kept because the id is in use there).
fn host_name() -> &'static str {
    static HOST: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    HOST.get_or_init(|| {
        std::fs::read_to_string("/proc/sys/kernel/hostname")
            .ok()
            .or_else(|| std::env::var("HOSTNAME").ok())
            .map(|h| h.trim().to_string())
            .unwrap_or_default()
    })
}

/// Who holds a lock file: a process id and, in files written since machines were recorded,
/// the machine it runs on; whether it refreshes the file ([`FileLock`]), and when it last did.
#[derive(Debug)]
struct LockHolder {
    pid: u32,
    host: Option<String>,
    heartbeat: bool,
    /// The file's modification time, read from the same opening as its text (on a network
    /// file system, opening the file fetches its current attributes).
    modified: Option<SystemTime>,
    text: String,
}

/// Whether a lock is held ([`LockHolder::liveness`]).
enum Liveness {
    /// Held; what a refusal adds about it.
    Held(String),
    /// Not held any more, and why.
    Stale(String),
}

impl LockHolder {
    fn read(path: &Path) -> Option<LockHolder> {
        use std::io::Read;
        let mut f = std::fs::File::open(path).ok()?;
        let mut text = String::new();
        f.read_to_string(&mut text).ok()?;
        let modified = f.metadata().and_then(|m| m.modified()).ok();
        let mut lines = text.lines();
        let pid = lines.next()?.trim().parse().ok()?;
        let host = lines.next().map(|h| h.trim().to_string()).filter(|h| !h.is_empty());
        let heartbeat = lines.next().is_some_and(|l| l.trim() == HEARTBEAT_MARK);
        Some(LockHolder { pid, host, heartbeat, modified, text })
    }

    /// Whether it runs on another machine than this one.
    fn elsewhere(&self) -> bool {
        self.host.as_deref().is_some_and(|h| h != host_name())
    }

    /// Whether this very process holds it.
    fn is_this_process(&self) -> bool {
        self.pid == std::process::id() && !self.elsewhere()
    }

    /// Whether the lock file `path` it was read from is held, by the rules of [`FileLock`].
    fn liveness(&self, path: &Path) -> Liveness {
        if !self.elsewhere() {
            if !process_alive(self.pid) {
                return Liveness::Stale("no longer running".into());
            }
            // The holder wrote (and refreshes) the file while it ran: a process of that id
            // started since is another program, given the id after the holder ended (a machine
            // or container restarted). A held run stopped by Ctrl-Z is still its holder.
            let reused = process_start(self.pid)
                .zip(self.modified)
                .is_some_and(|(started, written)| started > written + Duration::from_secs(2));
            return if reused {
                Liveness::Stale(format!(
                    "no longer running: process {} started after the lock file was last written, so it is another \
                     program that was given the same id",
                    self.pid
                ))
            } else {
                Liveness::Held(String::new())
            };
        }
        let limit = LOCK_STALE_AFTER.as_secs();
        if !self.heartbeat {
            return Liveness::Held(format!(
                "; the lock was written by an earlier fluidnerf, which does not refresh it, so whether a process of \
                 another machine still runs cannot be told (a refreshed lock is taken as abandoned {limit} s after \
                 its last refresh): if it has ended, remove the lock file"
            ));
        }
        match self.modified.and_then(|m| heartbeat_age(path, m)) {
            Some(age) if age > LOCK_STALE_AFTER => Liveness::Stale(format!(
                "its heartbeat stopped {} s ago, more than the {limit} s after which a lock of another machine is \
                 taken as abandoned",
                age.as_secs()
            )),
            Some(age) => Liveness::Held(format!(
                "; its heartbeat refreshed the lock file {} s ago, and it is taken as abandoned (and replaced) once \
                 it has not for {limit} s",
                age.as_secs()
            )),
            None => Liveness::Held(format!(
                "; the age of its heartbeat cannot be measured here (no probe file can be created beside the lock \
                 file), so it is not taken as abandoned even after {limit} s"
            )),
        }
    }
}

/// How long ago the lock file `path` was last modified (`modified`), on the clock of its file
/// system: the modification time of a probe file created beside it, then removed, is "now".
/// Zero for a file modified after the probe; None when no probe can be created.
fn heartbeat_age(path: &Path, modified: SystemTime) -> Option<Duration> {
    let probe = scratch_beside(path, SCRATCH_PROBE)?;
    let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&probe).ok()?;
    let now = file.metadata().and_then(|m| m.modified());
    drop(file);
    let _ = std::fs::remove_file(&probe);
    Some(now.ok()?.duration_since(modified).unwrap_or_default())
}

impl std::fmt::Display for LockHolder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.host {
            Some(h) if self.elsewhere() => write!(f, "process {} on {h}", self.pid),
            _ => write!(f, "process {}", self.pid),
        }
    }
}

/// When process `pid` of this machine started, from `/proc` (Linux; None elsewhere or when it
/// cannot be read): the machine's boot time plus the process's start in clock ticks after it
/// (`USER_HZ`, 100 a second on Linux).
fn process_start(pid: u32) -> Option<SystemTime> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name, in parentheses, may hold spaces: the fields after it count from the
    // state, the third field; the start time is the 22nd.
    let after = &stat[stat.rfind(')')? + 1..];
    let ticks: u64 = after.split_whitespace().nth(19)?.parse().ok()?;
    let boot: u64 = std::fs::read_to_string("/proc/stat")
        .ok()?
        .lines()
        .find_map(|l| l.strip_prefix("btime "))?
        .trim()
        .parse()
        .ok()?;
    Some(std::time::UNIX_EPOCH + Duration::from_secs(boot) + Duration::from_millis(ticks * 10))
}

/// Another live process holding the run lock of the folder `root`, in words.
/// The window locks (`windows/wNNN.lock`) of `root` held by live processes other than this one,
/// with each holder in words, in window order.
fn live_window_holders(root: &Path) -> Vec<(PathBuf, String)> {
    let Ok(entries) = std::fs::read_dir(root.join("windows")) else { return Vec::new() };
    let mut locks: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "lock"))
        .collect();
    locks.sort();
    locks
        .into_iter()
        .filter_map(|lock| {
            let holder = LockHolder::read(&lock)?;
            let live = !holder.is_this_process() && matches!(holder.liveness(&lock), Liveness::Held(_));
            live.then(|| (lock, holder.to_string()))
        })
        .collect()
}

fn live_holder(root: &Path) -> Option<String> {
    let lock = root.join(".lock");
    let holder = LockHolder::read(&lock)?;
    (!holder.is_this_process() && matches!(holder.liveness(&lock), Liveness::Held(_))).then(|| holder.to_string())
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
    serde_path_to_error::deserialize(de).map_err(|e| PipelineError::file(path, describe(&text, &e)))
}

/// The keys in which two settings differ, as `path: saved → given` (values in JSON), at most
/// `max` of them and a count of the rest: a refusal of "other settings" says which.
pub fn settings_differences<T: serde::Serialize>(saved: &T, given: &T, max: usize) -> String {
    fn walk(a: &serde_json::Value, b: &serde_json::Value, path: &str, out: &mut Vec<String>) {
        use serde_json::Value;
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => {
                let mut keys: Vec<&String> = x.keys().chain(y.keys().filter(|k| !x.contains_key(*k))).collect();
                keys.sort();
                for k in keys {
                    let sub = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                    walk(x.get(k).unwrap_or(&Value::Null), y.get(k).unwrap_or(&Value::Null), &sub, out);
                }
            }
            _ if a != b => out.push(format!("`{path}`: {a} → {b}")),
            _ => {}
        }
    }
    let (Ok(a), Ok(b)) = (serde_json::to_value(saved), serde_json::to_value(given)) else {
        return String::new();
    };
    let mut found = Vec::new();
    walk(&a, &b, "", &mut found);
    let more = found.len().saturating_sub(max);
    found.truncate(max);
    if more > 0 {
        found.push(format!("and {more} more"));
    }
    found.join(", ")
}

/// Refuses to resume the run in `dir` with settings that would change how it trains: the run
/// it continues was trained with those of its `config.json`, and the `config.json` the resumed
/// run writes must rerun it (`--config`). What may change is what only bounds or reports the
/// training: the iteration cap, the time budget and the held-out rule's patience, the
/// checkpoint and evaluation intervals, the memory limit, the output grid, and the scene's path.
pub(crate) fn check_resume_settings(dir: &RunDir, config: &crate::RunConfig) -> Result<(), PipelineError> {
    let path = dir.config();
    let saved: crate::RunConfig = read_json(&path)?;
    let (saved, given) = (
        training_settings(&saved).map_err(|e| PipelineError::file(&path, e))?,
        training_settings(config).map_err(|e| PipelineError::file(&path, e))?,
    );
    if saved == given {
        return Ok(());
    }
    Err(resume_refused(dir, path, &settings_differences(&saved, &given, 5)))
}

/// The settings of `config` that decide how a run trains, as JSON: all but what only bounds or
/// reports the training (see [`check_resume_settings`]). A checkpoint records them, so that a
/// resume refuses a `config.json` edited after it was written, or another run's checkpoint.
pub(crate) fn training_settings(config: &crate::RunConfig) -> Result<serde_json::Value, String> {
    let mut v = serde_json::to_value(config).map_err(|e| e.to_string())?;
    if let Some(o) = v.as_object_mut() {
        for key in ["fluidnerf_version", "scene", "resolution", "checkpoint_every", "eval_every", "memory_limit_gib"] {
            o.remove(key);
        }
        if let Some(s) = o.get_mut("stopping").and_then(|s| s.as_object_mut()) {
            for key in ["max_iterations", "time_budget_s", "patience"] {
                s.remove(key);
            }
        }
    }
    Ok(v)
}

/// The refusal of a resume whose training settings differ from the run's (`differences`, as
/// [`settings_differences`] lists them), reported against the file `path` that records them.
pub(crate) fn resume_refused(dir: &RunDir, path: PathBuf, differences: &str) -> PipelineError {
    PipelineError::RunDir {
        path,
        why: format!(
            "cannot resume: the run was trained with other settings ({differences}); a resumed run only continues, \
             and its config.json must rerun it: resume with the run's settings (`--config {}`, which a raised \
             --max-iterations or --time-budget may follow), or use --force (`overwrite=\"force\"` from Python) to \
             start over",
            dir.config().display()
        ),
    }
}

/// A fluidnerf JSON file, told by its keys ([`JsonFileKind::of`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JsonFileKind {
    /// A scene file (`transforms.json`).
    Scene,
    /// A synthetic scene's settings (`synth.json`).
    SynthSettings,
    /// A run's report (`report.json`).
    RunReport,
    /// A run's configuration (`config.json`).
    RunConfig,
}

impl JsonFileKind {
    /// What kind of fluidnerf file a JSON document is, told by its keys. Readers name it when
    /// they are given the wrong one, instead of the first key they do not know.
    pub fn of(value: &serde_json::Value) -> Option<Self> {
        let has = |key: &str| value.get(key).is_some();
        if has("frames") {
            Some(Self::Scene)
        } else if value.get("command").and_then(serde_json::Value::as_str) == Some("synth") || has("settings") {
            Some(Self::SynthSettings)
        } else if has("method") && (has("status") || has("stop_reason") || has("final_nrmse")) {
            Some(Self::RunReport)
        } else if has("method") && has("scene") {
            Some(Self::RunConfig)
        } else {
            None
        }
    }

    /// The kind in words, with its usual file name.
    pub fn describe(self) -> &'static str {
        match self {
            Self::Scene => "a scene file (transforms.json)",
            Self::SynthSettings => "the settings of a synthetic scene (synth.json)",
            Self::RunReport => "a run's report (report.json)",
            Self::RunConfig => "a run's configuration (config.json)",
        }
    }
}

/// A JSON value as `T`, with the key path in the error.
pub fn from_json_value<T: DeserializeOwned>(value: serde_json::Value) -> Result<T, PipelineError> {
    serde_path_to_error::deserialize(value).map_err(|e| PipelineError::invalid("configuration", describe("", &e)))
}

fn describe(text: &str, e: &serde_path_to_error::Error<serde_json::Error>) -> String {
    // A NaN or an infinity (as Python's `json.dump` writes them) is named with its key.
    if let Some(why) = fluidnerf_io::json::non_finite_error(text, e.inner()) {
        return why;
    }
    let why = e.inner().to_string();
    // A file cut short (a write that was interrupted) ends inside a value: no key is at fault.
    if e.inner().is_eof() {
        return format!("the JSON text ends early, as in a file cut short: {why}");
    }
    // `?` stands for a key the parser had not read yet; it names nothing in the file.
    let path = e.path().to_string().split('.').filter(|s| *s != "?").collect::<Vec<_>>().join(".");
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
    #[test]
    fn a_file_cut_short_is_said_to_be_so_and_names_no_unknown_key() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("cut.json");
        for text in ["{\"seed\": 1, ", "{\"a\": {\"b\": [1,", "{"] {
            std::fs::write(&path, text).expect("writes");
            let e = super::read_json::<serde_json::Value>(&path).expect_err("cut short").to_string();
            assert!(e.contains("cut.json") && e.contains("ends early, as in a file cut short"), "{text}: {e}");
            assert!(!e.contains('?'), "{text}: {e}");
        }
        // Other errors keep the key's path.
        std::fs::write(&path, "{\"seed\": \"x\"}").expect("writes");
        #[derive(serde::Deserialize, Debug)]
        #[allow(dead_code)]
        struct Seed {
            seed: u64,
        }
        let e = super::read_json::<Seed>(&path).expect_err("a string").to_string();
        assert!(e.contains("at `seed`: invalid type"), "{e}");
    }

    #[test]
    fn settings_differences_name_the_keys() {
        let a = serde_json::json!({"seed": 0, "method": {"name": "tr-fast", "windows": {"frames": 4}}, "x": [1, 2]});
        let b = serde_json::json!({"seed": 1, "method": {"name": "tr-fast", "windows": {"frames": 3}}, "x": [1, 2]});
        assert_eq!(super::settings_differences(&a, &b, 5), "`method.windows.frames`: 4 → 3, `seed`: 0 → 1");
        assert_eq!(super::settings_differences(&a, &b, 1), "`method.windows.frames`: 4 → 3, and 1 more");
        assert_eq!(super::settings_differences(&a, &a, 5), "");
        let c = serde_json::json!({"seed": 0});
        assert_eq!(super::settings_differences(&c, &serde_json::json!({}), 5), "`seed`: 0 → null");
    }

    use super::*;

    /// A window trained by another process holds only `windows/wNNN.lock`: a whole run that
    /// replaced, resumed or finished the folder meanwhile took it, and the window then wrote
    /// its old settings into the new run. Refused now while the window's process lives.
    #[test]
    fn a_whole_run_waits_for_a_window_another_process_trains() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("run");
        std::fs::create_dir_all(out.join("windows")).unwrap();
        write_json(&out.join("config.json"), &run_config()).unwrap();
        let mut other = std::process::Command::new("sleep").arg("30").spawn().unwrap();
        let lock = out.join("windows/w001.lock");
        std::fs::write(&lock, format!("{}\n{}\n{HEARTBEAT_MARK}\n", other.id(), host_name())).unwrap();
        for overwrite in [Overwrite::Force, Overwrite::Resume] {
            let e = RunDir::create(&out, overwrite, None).unwrap_err().to_string();
            assert!(e.contains("a window of its run is being trained by another process"), "{e}");
            assert!(e.contains(&other.id().to_string()) && e.contains("windows/w001.lock"), "{e}");
            assert!(out.join("config.json").is_file(), "the run was left as it was");
        }
        other.kill().unwrap();
        other.wait().unwrap();
        // Its process gone, the lock is stale and the run is replaced.
        RunDir::create(&out, Overwrite::Force, None).unwrap();
    }

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
            dir.write_json("config.json", &run_config()).unwrap();
            // A second run into the same folder while the first holds it.
            let e = RunDir::create(&out, Overwrite::Force, None).unwrap_err().to_string();
            assert!(e.contains("in use by another run") && e.contains(&std::process::id().to_string()), "{e}");
        }
        assert!(!out.join(".lock").exists(), "the lock goes with the run");
        // A lock whose process id is now another program's, started after the lock was last
        // written (here this test's own process, the lock dated before it started), is stale.
        std::fs::write(out.join(".lock"), format!("{}\n{}\n{HEARTBEAT_MARK}\n", std::process::id(), host_name()))
            .unwrap();
        let lock = std::fs::File::options().write(true).open(out.join(".lock")).unwrap();
        lock.set_modified(SystemTime::now() - Duration::from_secs(365 * 86_400)).unwrap();
        drop(lock);
        assert!(process_start(std::process::id()).is_some_and(|t| t < SystemTime::now()));
        let holder = LockHolder::read(&out.join(".lock")).unwrap();
        assert!(matches!(holder.liveness(&out.join(".lock")), Liveness::Stale(why) if why.contains("same id")));
        std::fs::remove_file(out.join(".lock")).unwrap();
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

    /// A `config.json` as a run writes it (the keys that tell a run).
    fn run_config() -> serde_json::Value {
        serde_json::json!({ "scene": "scene", "method": { "name": "asart" } })
    }

    /// A scene folder whose files lie inside it (`images/`, `truth/`) and outside it
    /// (`elsewhere/`, by an absolute path).
    fn scene_with_inputs(tmp: &Path) -> PathBuf {
        let scene = tmp.join("scene");
        std::fs::create_dir_all(scene.join("images")).unwrap();
        std::fs::create_dir_all(scene.join("truth")).unwrap();
        std::fs::create_dir_all(tmp.join("elsewhere")).unwrap();
        std::fs::write(scene.join("truth/volume.npy"), "truth").unwrap();
        let outside = tmp.join("elsewhere/mask.png");
        let text = serde_json::json!({
            "truth": [{ "file_path": "truth/volume.npy" }],
            "frames": [{ "file_path": "images/r_0.png", "mask_path": outside }],
        });
        std::fs::write(scene.join("transforms.json"), text.to_string()).unwrap();
        scene
    }

    #[test]
    fn refuses_every_folder_that_holds_the_scenes_inputs() {
        let tmp = tempfile::tempdir().unwrap();
        let scene = scene_with_inputs(tmp.path());
        let cases = [
            (scene.join("truth"), "inside the scene folder"),
            (scene.join("images"), "inside the scene folder"),
            (scene.join("new"), "inside the scene folder"),
            (scene.join("../scene/./truth"), "inside the scene folder"),
            // The scene is the run's own (in OWN_SCENE), but one of its inputs lies beside it.
            (tmp.path().to_path_buf(), "mask.png (a mask the scene reads)"),
            (tmp.path().join("elsewhere"), "mask.png (a mask the scene reads)"),
        ];
        for (out, needle) in cases {
            for overwrite in [Overwrite::Refuse, Overwrite::Force, Overwrite::Resume] {
                let e = RunDir::create(&out, overwrite, Some(&scene)).unwrap_err().to_string();
                assert!(e.contains(needle), "{}: {e}", out.display());
                let e = RunDir::for_windows(&out, Some(&scene)).unwrap_err().to_string();
                assert!(e.contains(needle), "{}: {e}", out.display());
            }
        }
        assert_eq!(std::fs::read_to_string(scene.join("truth/volume.npy")).unwrap(), "truth");
        assert!(!scene.join("new").exists(), "a refused folder is not created");
        assert!(!scene.join("truth/.lock").exists());
        // A folder beside the scene is fine.
        drop(RunDir::create(tmp.path().join("run"), Overwrite::Refuse, Some(&scene)).unwrap());
        // A folder holding the scene other than as its own is not.
        let holder = tempfile::tempdir().unwrap();
        let deep = scene_with_inputs(&holder.path().join("data"));
        let e = RunDir::create(holder.path(), Overwrite::Force, Some(&deep)).unwrap_err().to_string();
        assert!(e.contains("contains the scene folder"), "{e}");
    }

    /// A folder holding a flat-field frame the scene reads, at the top level or in a frame, is
    /// refused as one holding its masks is.
    #[test]
    fn refuses_a_folder_that_holds_the_scenes_flat_fields() {
        let tmp = tempfile::tempdir().unwrap();
        let scene = tmp.path().join("scene");
        std::fs::create_dir_all(&scene).unwrap();
        for (top, frame) in [(Some("../flats/f.png"), None), (None, Some(vec!["../flats/f.png"]))] {
            let mut text = serde_json::json!({ "frames": [{ "file_path": "images/r_0.png" }] });
            if let Some(top) = top {
                text["flat_field"] = top.into();
            }
            if let Some(frame) = frame {
                text["frames"][0]["flat_field"] = frame.into();
            }
            std::fs::write(scene.join("transforms.json"), text.to_string()).unwrap();
            let e = RunDir::create(tmp.path().join("flats"), Overwrite::Force, Some(&scene)).unwrap_err().to_string();
            assert!(e.contains("f.png (a flat-field frame the scene reads)"), "{e}");
        }
    }

    /// The Python API saves a scene built from arrays into `OUT/scene`, the run's own scene: the
    /// run goes into OUT (before, "contains the scene folder" refused every such run), and
    /// `--force` keeps the scene.
    #[test]
    fn a_runs_own_scene_lives_in_its_folder() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("run");
        let scene = out.join(OWN_SCENE);
        std::fs::create_dir_all(scene.join("images")).unwrap();
        let text = serde_json::json!({ "frames": [{ "file_path": "images/r_0.png" }] });
        std::fs::write(scene.join("transforms.json"), text.to_string()).unwrap();
        std::fs::write(scene.join("images/r_0.png"), "image").unwrap();
        let dir = RunDir::create(&out, Overwrite::Refuse, Some(&scene)).unwrap();
        dir.write_json("config.json", &run_config()).unwrap();
        dir.write_json("report.json", &serde_json::json!({})).unwrap();
        drop(dir);
        let forced = RunDir::create(&out, Overwrite::Force, Some(&scene)).unwrap();
        forced.write_json("config.json", &run_config()).unwrap();
        drop(forced);
        assert_eq!(std::fs::read_to_string(scene.join("images/r_0.png")).unwrap(), "image");
        assert!(!out.join("report.json").exists(), "--force replaced the run");
        drop(RunDir::for_windows(&out, Some(&scene)).unwrap());
    }

    #[test]
    fn refuses_output_files_that_are_the_scenes_or_the_runs() {
        let tmp = tempfile::tempdir().unwrap();
        let scene = scene_with_inputs(tmp.path());
        let file = scene.join("transforms.json");
        for (out, needle) in [
            (file.clone(), "is the scene file"),
            (scene.join("images/../truth/volume.npy"), "as ground truth"),
            (scene.join("images/r_0.png"), "as an image"),
            (tmp.path().join("elsewhere/mask.png"), "as a mask"),
            (scene.join("synth.json"), "the scene's record synth.json"),
        ] {
            let e = refuse_scene_file(&out, &file).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains("--force"), "{}: {e}", out.display());
        }
        for fine in [scene.join("metrics.json"), scene.join("images/notes.csv"), tmp.path().join("metrics.json")] {
            refuse_scene_file(&fine, &file).unwrap();
        }

        let run = tmp.path().join("run");
        std::fs::create_dir_all(&run).unwrap();
        for (name, needle) in [
            ("config.json", "the file config.json"),
            ("weights.safetensors", "the file weights.safetensors"),
            ("frames/volume_000.npy", "in the folder frames"),
            ("windows/progress.json", "in the folder windows"),
            ("start/config.json", "in the folder start"),
        ] {
            let e = refuse_run_file(&run.join(name), &run).unwrap_err().to_string();
            assert!(e.contains(needle), "{name}: {e}");
        }
        for fine in ["metrics.json", "metrics.csv", "eval.json"] {
            refuse_run_file(&run.join(fine), &run).unwrap();
        }
        refuse_run_file(&tmp.path().join("config.json"), &run).unwrap();
    }

    #[test]
    fn force_replaces_only_fluidnerf_runs() {
        let tmp = tempfile::tempdir().unwrap();
        // Files with a run's names but no run: a user's volume, an export.
        let mine = tmp.path().join("mine");
        std::fs::create_dir_all(&mine).unwrap();
        std::fs::write(mine.join("volume.npy"), "mine").unwrap();
        std::fs::write(mine.join("config.json"), "{\"other\": \"tool\"}").unwrap();
        for overwrite in [Overwrite::Refuse, Overwrite::Force, Overwrite::Resume] {
            let e = RunDir::create(&mine, overwrite, None).unwrap_err().to_string();
            assert!(e.contains("not a fluidnerf run folder") && e.contains("volume.npy"), "{e}");
        }
        assert!(RunDir::for_windows(&mine, None).unwrap_err().to_string().contains("not a fluidnerf run folder"));
        assert_eq!(std::fs::read_to_string(mine.join("volume.npy")).unwrap(), "mine");
        assert!(!mine.join(".lock").exists());
        // Folders of another kind.
        for (marker, needle) in [
            ("transforms.json", "a scene folder"),
            ("export.json", "an export folder"),
            ("render.json", "rendered views"),
        ] {
            let d = tmp.path().join(marker);
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(d.join(marker), "{}").unwrap();
            let e = RunDir::create(&d, Overwrite::Force, None).unwrap_err().to_string();
            assert!(e.contains(needle), "{e}");
            assert_eq!(std::fs::read_dir(&d).unwrap().count(), 1, "{marker}: nothing written or removed");
        }
        // A run is replaced.
        let run = tmp.path().join("run");
        std::fs::create_dir_all(&run).unwrap();
        write_json(&run.join("config.json"), &run_config()).unwrap();
        std::fs::write(run.join("volume.npy"), "old").unwrap();
        let dir = RunDir::create(&run, Overwrite::Force, None).unwrap();
        assert_eq!(dir.state(), DirState::Empty);
    }

    /// `--force` keeps the run it replaces aside until the new run writes its configuration: a
    /// run refused by its own checks before that (no held-out view, too little memory) leaves
    /// the earlier run as it was, its starts included; one that wrote it replaces it. An
    /// earlier run left aside by a process that died then is put back by the next.
    #[test]
    fn a_forced_run_refused_before_it_writes_leaves_the_earlier_run() {
        let tmp = tempfile::tempdir().unwrap();
        let run = tmp.path().join("run");
        let make_earlier = || {
            std::fs::create_dir_all(run.join("start/t00")).unwrap();
            write_json(&run.join("start/t00/config.json"), &run_config()).unwrap();
            write_json(&run.join("config.json"), &run_config()).unwrap();
            std::fs::write(run.join("volume.npy"), "old").unwrap();
            std::fs::write(run.join("report.json"), "{}").unwrap();
        };
        let earlier_there = || {
            std::fs::read_to_string(run.join("volume.npy")).is_ok_and(|v| v == "old")
                && run.join("report.json").is_file()
                && run.join("start/t00/config.json").is_file()
                && !run.join(REPLACED).exists()
        };
        make_earlier();
        let dir = RunDir::create(&run, Overwrite::Force, None).unwrap();
        assert_eq!(dir.state(), DirState::Empty);
        assert!(!run.join("volume.npy").exists() && !run.join("start").exists());
        drop(dir);
        assert!(earlier_there(), "a refused --force put the earlier run back");
        assert_eq!(RunDir::open(&run).unwrap().state(), DirState::Finished);
        // Written: replaced.
        let dir = RunDir::create(&run, Overwrite::Force, None).unwrap();
        dir.write_json("config.json", &run_config()).unwrap();
        assert!(!run.join(REPLACED).exists() && !run.join("volume.npy").exists() && !run.join("start").exists());
        drop(dir);
        assert_eq!(RunDir::open(&run).unwrap().state(), DirState::Unfinished);
        // A process that died with the earlier run aside: the next run puts it back first.
        for f in ["config.json", "volume.npy", "report.json"] {
            let _ = std::fs::remove_file(run.join(f));
        }
        make_earlier();
        let dir = RunDir::create(&run, Overwrite::Force, None).unwrap();
        std::mem::forget(dir);
        std::fs::remove_file(run.join(".lock")).unwrap();
        assert!(!earlier_there());
        let e = RunDir::create(&run, Overwrite::Refuse, None).unwrap_err().to_string();
        assert!(e.contains("already holds a finished run"), "{e}");
        assert!(earlier_there());
        // Another run written into the folder since (windows trained one at a time) is never
        // overwritten by the run set aside, which stays aside.
        std::mem::forget(RunDir::create(&run, Overwrite::Force, None).unwrap());
        std::fs::remove_file(run.join(".lock")).unwrap();
        write_json(&run.join("config.json"), &serde_json::json!({"scene": "s", "method": "windows"})).unwrap();
        std::fs::create_dir(run.join("windows")).unwrap();
        drop(RunDir::create(&run, Overwrite::Resume, None).unwrap());
        let config = std::fs::read_to_string(run.join("config.json")).unwrap();
        assert!(config.contains("windows") && !run.join("volume.npy").exists(), "{config}");
        assert!(run.join(REPLACED).join("volume.npy").is_file());
    }

    /// An earlier run left aside by a `--force` run whose process died is put back by whoever
    /// opens the folder next to read it or to train windows into it, not only by the next run;
    /// but never while a live `--force` run holds the folder, which is setting it aside.
    #[test]
    fn a_run_left_aside_by_a_dead_force_is_put_back_for_readers() {
        let tmp = tempfile::tempdir().unwrap();
        let run = tmp.path().join("run");
        std::fs::create_dir_all(&run).unwrap();
        write_json(&run.join("config.json"), &run_config()).unwrap();
        std::fs::write(run.join("volume.npy"), "old").unwrap();
        std::fs::write(run.join("report.json"), "{}").unwrap();
        // Live: the run setting it aside keeps it aside.
        let live = RunDir::create(&run, Overwrite::Force, None).unwrap();
        RunDir::recover_replaced(&run);
        assert!(run.join(REPLACED).join("volume.npy").is_file() && !run.join("volume.npy").exists());
        // Dead (its lock left behind by a process that is gone reads as stale; here removed).
        std::mem::forget(live);
        std::fs::remove_file(run.join(".lock")).unwrap();
        RunDir::recover_replaced(&run);
        assert_eq!(std::fs::read_to_string(run.join("volume.npy")).unwrap(), "old");
        assert!(!run.join(REPLACED).exists() && !run.join(".lock").exists());
        assert_eq!(RunDir::open(&run).unwrap().state(), DirState::Finished);
        // Window training checks the folder as it then is: a finished run, refused.
        std::mem::forget(RunDir::create(&run, Overwrite::Force, None).unwrap());
        std::fs::remove_file(run.join(".lock")).unwrap();
        let e = RunDir::for_windows(&run, None).unwrap_err().to_string();
        assert!(e.contains("already holds a finished run"), "{e}");
        assert!(!run.join(REPLACED).exists());
        // With the Python API's scene aside too, `scene/` may be the killed call's: nothing is
        // put back, so the earlier run is never read with another call's images.
        std::mem::forget(RunDir::create(&run, Overwrite::Force, None).unwrap());
        std::fs::remove_file(run.join(".lock")).unwrap();
        std::fs::create_dir(run.join(SCENE_SET_ASIDE)).unwrap();
        RunDir::recover_replaced(&run);
        assert!(run.join(REPLACED).join("volume.npy").is_file() && !run.join("volume.npy").exists());
    }

    /// A time-resolved run's starts (`start/tNN/`, one run per instant) are its own: `--force`
    /// removes them with it, so a new run with fewer instants, or none started, does not keep
    /// the earlier run's beside its own. What else `start/` holds is not the run's and stays.
    #[test]
    fn force_removes_the_runs_of_a_time_resolved_runs_instants() {
        let tmp = tempfile::tempdir().unwrap();
        let run = tmp.path().join("run");
        for keep in [false, true] {
            for t in ["t00", "t01", "t02"] {
                std::fs::create_dir_all(run.join("start").join(t)).unwrap();
                write_json(&run.join("start").join(t).join("config.json"), &run_config()).unwrap();
                std::fs::write(run.join("start").join(t).join("volume.npy"), "old").unwrap();
            }
            write_json(&run.join("config.json"), &run_config()).unwrap();
            std::fs::write(run.join("temporal.json"), "{}").unwrap();
            if keep {
                std::fs::write(run.join("start/notes.txt"), "mine").unwrap();
            }
            let dir = RunDir::create(&run, Overwrite::Force, None).unwrap();
            assert_eq!(dir.state(), DirState::Empty);
            dir.write_json("config.json", &run_config()).unwrap();
            drop(dir);
            assert!(!run.join(REPLACED).exists() && !run.join(REPLACED_DISCARDED).exists());
            for t in ["t00", "t01", "t02"] {
                assert!(!run.join("start").join(t).exists(), "start/{t} left by --force (keep {keep})");
            }
            assert_eq!(run.join("start").exists(), keep, "start/ with a file of the user's: {keep}");
        }
        assert_eq!(std::fs::read_to_string(run.join("start/notes.txt")).unwrap(), "mine");
    }

    #[test]
    fn a_stale_lock_is_replaced() {
        let tmp = tempfile::tempdir().unwrap();
        // No process has this id (above the kernel's pid_max), with and without its machine.
        for holder in ["4194305\n".to_string(), format!("4194305\n{}\n", host_name())] {
            std::fs::write(tmp.path().join(".lock"), holder).unwrap();
            let dir = RunDir::create(tmp.path(), Overwrite::Refuse, None).unwrap();
            let text = std::fs::read_to_string(tmp.path().join(".lock")).unwrap();
            assert_eq!(text, format!("{}\n{}\nheartbeat\n", std::process::id(), host_name()));
            drop(dir);
        }
    }

    /// Sets the modification time of `path` to `ago` before now.
    fn age(path: &Path, ago: Duration) {
        std::fs::File::options().write(true).open(path).unwrap().set_modified(SystemTime::now() - ago).unwrap();
    }

    fn modified(path: &Path) -> SystemTime {
        std::fs::metadata(path).unwrap().modified().unwrap()
    }

    /// Part and probe files that a killed process left beside a lock go when the lock is next
    /// taken; a young one (its maker may still be about to link or remove it) and files of
    /// other names stay.
    #[test]
    fn leftover_scratch_files_go_when_the_lock_is_taken() {
        let tmp = tempfile::tempdir().unwrap();
        let names = [
            ".lock.part-4194305-0",
            ".lock.probe-4194305-7",
            ".lock.part-4194306-2",
            ".lock.part-1-x",
            ".lock.partial",
            "notes.part-1-0",
        ];
        for name in names {
            std::fs::write(tmp.path().join(name), "4194305\n").unwrap();
        }
        for name in [names[0], names[1], names[3], names[4], names[5]] {
            age(&tmp.path().join(name), LOCK_HEARTBEAT + Duration::from_secs(20));
        }
        let dir = RunDir::create(tmp.path(), Overwrite::Refuse, None).unwrap();
        drop(dir);
        let mut left: Vec<_> =
            std::fs::read_dir(tmp.path()).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
        left.sort();
        assert_eq!(left, [".lock.part-1-x", ".lock.part-4194306-2", ".lock.partial", "notes.part-1-0"]);
    }

    /// A lock of another machine whose heartbeat stopped longer ago than the limit (that
    /// machine died with it held) is stale, and replaced as a dead local process's is; a whole
    /// run's no longer keeps windows out of the folder either.
    #[test]
    fn a_lock_of_another_machine_whose_heartbeat_stopped_is_replaced() {
        let tmp = tempfile::tempdir().unwrap();
        let lock = tmp.path().join(".lock");
        std::fs::write(&lock, "4194305\nanother-machine.example\nheartbeat\n").unwrap();
        age(&lock, LOCK_STALE_AFTER + Duration::from_secs(30));
        RunDir::check_windows(tmp.path(), None).unwrap();
        let dir = RunDir::create(tmp.path(), Overwrite::Refuse, None).unwrap();
        let text = std::fs::read_to_string(&lock).unwrap();
        assert_eq!(text, format!("{}\n{}\nheartbeat\n", std::process::id(), host_name()));
        drop(dir);
        assert!(!lock.exists());
        let names: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert!(names.is_empty(), "no probe file is left: {names:?}");
    }

    /// A lock of another machine whose heartbeat is recent is held, as is one just short of
    /// the limit; the refusal states the limit.
    #[test]
    fn a_lock_of_another_machine_with_a_recent_heartbeat_is_held() {
        let tmp = tempfile::tempdir().unwrap();
        let lock = tmp.path().join("windows/w000.lock");
        std::fs::create_dir_all(lock.parent().unwrap()).unwrap();
        for ago in [Duration::ZERO, LOCK_STALE_AFTER - Duration::from_secs(20)] {
            std::fs::write(&lock, "4194305\nanother-machine.example\nheartbeat\n").unwrap();
            age(&lock, ago);
            let dir = RunDir::open(tmp.path()).unwrap();
            let e = dir.lock_file("windows/w000.lock").unwrap_err().to_string();
            assert!(
                e.contains("in use by another run (process 4194305 on another-machine.example")
                    && e.contains(&format!("once it has not for {} s", LOCK_STALE_AFTER.as_secs()))
                    && !e.contains("remove the lock file"),
                "{e}"
            );
            assert_eq!(std::fs::read_to_string(&lock).unwrap(), "4194305\nanother-machine.example\nheartbeat\n");
        }
        assert_eq!(std::fs::read_dir(lock.parent().unwrap()).unwrap().count(), 1, "no probe file is left");
    }

    /// Threads of one process racing for one lock hold it one at a time. The lock file was
    /// created empty and then written, and a taker that read it in between took the empty file
    /// for an unreadable, stale lock and replaced it: two tasks trained the same window.
    #[test]
    fn a_lock_is_held_by_one_taker_at_a_time() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("windows/w000.lock");
        let (holders, most, taken) = (AtomicUsize::new(0), AtomicUsize::new(0), AtomicUsize::new(0));
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| {
                    for _ in 0..200 {
                        if let Ok(lock) = FileLock::take(tmp.path(), &path) {
                            let now = holders.fetch_add(1, Ordering::SeqCst) + 1;
                            most.fetch_max(now, Ordering::SeqCst);
                            taken.fetch_add(1, Ordering::SeqCst);
                            std::thread::yield_now();
                            holders.fetch_sub(1, Ordering::SeqCst);
                            drop(lock);
                        }
                    }
                });
            }
        });
        assert!(taken.load(Ordering::SeqCst) > 0, "nobody took the lock");
        assert_eq!(most.load(Ordering::SeqCst), 1, "takers that held the lock at once");
        assert!(!path.exists());
        assert_eq!(std::fs::read_dir(path.parent().unwrap()).unwrap().count(), 0, "no file is left beside it");
    }

    /// An unreadable lock file (empty here) is being written by its taker while it is young,
    /// and held; an old one is stale, and replaced.
    #[test]
    fn an_unreadable_lock_is_held_while_young() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("w000.lock");
        std::fs::write(&path, "").unwrap();
        let e = FileLock::take(tmp.path(), &path).map(drop).unwrap_err().to_string();
        assert!(e.contains("in use by another run") && e.contains("w000.lock"), "{e}");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "");
        age(&path, LOCK_HEARTBEAT * 2);
        let lock = FileLock::take(tmp.path(), &path).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), lock.contents);
        drop(lock);
        assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0, "no file is left");
    }

    /// A held lock's file is refreshed by its heartbeat, and keeps its holder.
    #[test]
    fn a_held_lock_is_refreshed() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("w000.lock");
        let lock = FileLock::take_with(tmp.path(), &path, Duration::from_millis(20)).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let long_ago = SystemTime::now() - Duration::from_secs(3600);
        std::fs::File::options().write(true).open(&path).unwrap().set_modified(long_ago).unwrap();
        let t0 = std::time::Instant::now();
        while modified(&path) <= long_ago && t0.elapsed() < Duration::from_secs(2) {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(modified(&path) > long_ago + Duration::from_secs(3000), "the heartbeat did not refresh the lock");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), text);
        drop(lock);
    }

    /// A dropped lock's heartbeat ends with it: the file is removed, does not come back, and a
    /// lock another run takes afterwards at the same path is not touched.
    #[test]
    fn the_heartbeat_ends_when_the_lock_is_dropped() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("w000.lock");
        let every = Duration::from_millis(20);
        let lock = FileLock::take_with(tmp.path(), &path, every).unwrap();
        std::thread::sleep(every * 3);
        drop(lock);
        assert!(!path.exists());
        std::thread::sleep(every * 5);
        assert!(!path.exists(), "the dropped lock came back");
        std::fs::write(&path, "4194305\nanother-machine.example\nheartbeat\n").unwrap();
        age(&path, Duration::from_secs(3600));
        let before = modified(&path);
        std::thread::sleep(every * 10);
        assert_eq!(modified(&path), before, "a heartbeat still refreshes the file");
    }

    /// A lock taken over while held (this process was stopped past the limit, and another
    /// machine replaced it) is the other run's: neither refreshed nor removed by this one.
    #[test]
    fn a_lock_taken_over_is_left_to_its_new_holder() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("w000.lock");
        let every = Duration::from_millis(20);
        let lock = FileLock::take_with(tmp.path(), &path, every).unwrap();
        // Replaced as a stale lock is: removed, and created anew.
        let theirs = "4194305\nanother-machine.example\nheartbeat\n";
        std::fs::remove_file(&path).unwrap();
        std::fs::write(&path, theirs).unwrap();
        age(&path, Duration::from_secs(3600));
        let before = modified(&path);
        std::thread::sleep(every * 10);
        assert_eq!(modified(&path), before, "another run's lock was refreshed");
        drop(lock);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), theirs);
    }

    /// A lock of another machine sharing the folder is held whatever its process id means
    /// here: neither taken as stale when no process of this machine has that id, nor as this
    /// process's own when one has (this very process's id, here). One written by an earlier
    /// fluidnerf (no heartbeat line) is held however old, since nothing refreshed it.
    #[test]
    fn a_lock_of_another_machine_is_held() {
        let tmp = tempfile::tempdir().unwrap();
        let lock = tmp.path().join(".lock");
        for pid in [4194305, std::process::id()] {
            for ago in [Duration::ZERO, Duration::from_secs(24 * 3600)] {
                std::fs::write(&lock, format!("{pid}\nanother-machine.example\n")).unwrap();
                age(&lock, ago);
                let e = RunDir::create(tmp.path(), Overwrite::Refuse, None).unwrap_err().to_string();
                assert!(
                    e.contains(&format!("in use by another run (process {pid} on another-machine.example"))
                        && e.contains("does not refresh it")
                        && e.contains("remove the lock file"),
                    "{e}"
                );
                let e = RunDir::check_windows(tmp.path(), None).unwrap_err().to_string();
                assert!(e.contains("in use by a whole run"), "{e}");
            }
        }
    }
}
