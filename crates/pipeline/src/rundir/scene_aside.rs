//! [`SceneAside`]: a run folder's own scene ([`OWN_SCENE`]) set aside while a scene built from
//! arrays replaces it (the Python API's `reconstruct(scene, method, out, overwrite=...)`), and
//! put back or discarded afterwards, also when the process that set it aside was killed.
//!
//! The whole exchange happens under the folder's scene lock (`.scene.lock`, a [`FileLock`]), held
//! from before the scene goes aside until the run has written its configuration (the aside is
//! then discarded) or was refused before it did (the aside is put back). Before the move a record
//! (`.scene-replaced.json`) keeps what the folder's `config.json` was then. Whoever next takes
//! the lock and finds an aside left behind (its holder died: killed outright, or its machine
//! lost) decides by that record:
//! - the folder's `config.json` is missing or still the recorded one: the run never wrote, so
//!   the folder's run (if any) is still the one made on the scene aside, which goes back into
//!   place, and the killed call's scene goes;
//! - `config.json` is another file: the run started on the new scene, and the old one goes.
//!
//! Without the record (an aside of an earlier fluidnerf), nothing is decided for the user.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{write_json, FileLock, OWN_SCENE, SCENE_SET_ASIDE};
use crate::PipelineError;

/// The scene lock's file in a run folder.
pub(super) const SCENE_LOCK: &str = ".scene.lock";

/// The record of a scene set aside: what the folder's `config.json` was before.
const SCENE_SET_ASIDE_RECORD: &str = ".scene-replaced.json";

/// [`SCENE_SET_ASIDE`] while it is removed: never taken for a scene to put back.
const SCENE_DISCARDED: &str = ".scene-replaced-discarded";

/// What tells a file apart from the one that replaces it (every file of a run is written
/// atomically, a new file renamed over the old): its inode, modification time and size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
struct FileState {
    inode: u64,
    modified_ns: u128,
    size: u64,
}

impl FileState {
    /// The state of `path`, None when it does not exist (or cannot be read).
    fn of(path: &Path) -> Option<FileState> {
        let meta = std::fs::metadata(path).ok()?;
        #[cfg(unix)]
        let inode = std::os::unix::fs::MetadataExt::ino(&meta);
        #[cfg(not(unix))]
        let inode = 0;
        let modified_ns =
            meta.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_nanos());
        Some(FileState { inode, modified_ns, size: meta.len() })
    }
}

/// The record written before a scene goes aside.
#[derive(Debug, Serialize, Deserialize)]
struct Record {
    /// The folder's `config.json` before the new scene was saved (None: there was none).
    config: Option<FileState>,
}

/// Whether the run in `root` has written its configuration since `before` was recorded: its
/// `config.json` exists and is another file. A `config.json` missing is not a new one: `--force`
/// moves the earlier run's into `.replaced/` before the new run writes its own.
fn run_wrote(root: &Path, before: Option<FileState>) -> bool {
    FileState::of(&root.join("config.json")).is_some_and(|now| Some(now) != before)
}

/// A run folder's own scene set aside under the folder's scene lock (see the module's notes).
/// Dropped without [`SceneAside::take_back`] or [`SceneAside::finish`], the lock is released
/// and the aside left to the next taker of the lock, who decides as for a killed process.
#[derive(Debug)]
pub struct SceneAside {
    root: PathBuf,
    /// The folder's `config.json` when the scene went aside, None also when nothing went.
    config: Option<FileState>,
    /// Whether the folder's scene went aside (it had one and replacing was asked).
    moved: bool,
    /// The folder held a scene that stayed in place (replacing was not asked): never removed.
    kept_own: bool,
    _lock: FileLock,
}

impl SceneAside {
    /// Takes the scene lock of the run folder `root` (creating the folder if missing; refused
    /// while another live call holds it), settles a scene an earlier call left aside
    /// ([`recover_locked`]) and, when `replace` is asked and the folder holds its own scene,
    /// records the folder's `config.json` and moves the scene aside: [`OWN_SCENE`] is then free
    /// for the new scene.
    pub fn begin(root: &Path, replace: bool) -> Result<SceneAside, PipelineError> {
        let lock = FileLock::take(root, &root.join(SCENE_LOCK))?;
        recover_locked(root)?;
        let (own, aside) = (root.join(OWN_SCENE), root.join(SCENE_SET_ASIDE));
        let config = FileState::of(&root.join("config.json"));
        let moved = replace && own.exists();
        if moved {
            write_json(&root.join(SCENE_SET_ASIDE_RECORD), &Record { config })?;
            std::fs::rename(&own, &aside).map_err(|e| {
                let _ = std::fs::remove_file(root.join(SCENE_SET_ASIDE_RECORD));
                PipelineError::file(&own, format!("cannot move the run's scene aside: {e}"))
            })?;
        }
        let kept_own = !moved && own.exists();
        Ok(SceneAside { root: root.to_path_buf(), config, moved, kept_own, _lock: lock })
    }

    /// Whether the run has written its configuration since the scene went aside.
    pub fn written(&self) -> bool {
        run_wrote(&self.root, self.config)
    }

    /// The run was refused before it wrote its configuration (or the scene could not be
    /// saved): the saved scene goes, and the scene set aside (if any) goes back into place; a
    /// scene the folder held and kept in place stays. Once the run has written, as
    /// [`SceneAside::finish`]: the folder's run was made on the new scene.
    pub fn take_back(self) -> Result<(), PipelineError> {
        if self.written() {
            return self.finish();
        }
        if !self.kept_own {
            remove_dir_all(&self.root.join(OWN_SCENE))?;
        }
        if self.moved {
            put_back(&self.root)?;
        }
        Ok(())
    }

    /// The run has started on the saved scene: the scene set aside goes.
    pub fn finish(self) -> Result<(), PipelineError> {
        if self.moved {
            discard(&self.root)?;
        }
        Ok(())
    }
}

/// Settles a scene left aside in the run folder `root` by a call whose process died, if its
/// scene lock can be taken (a live call's is left alone, and so is a folder without the lock's
/// room to take it: a read-only copy). For readers of the folder ([`super::RunDir::open`]).
/// Returns whether an aside is still there.
pub(super) fn recover(root: &Path) -> bool {
    let aside = root.join(SCENE_SET_ASIDE);
    if !aside.exists() {
        return false;
    }
    let Ok(_lock) = FileLock::take(root, &root.join(SCENE_LOCK)) else { return true };
    if let Err(e) = recover_locked(root) {
        log::warn!("{e}");
    }
    aside.exists()
}

/// [`recover`] with the scene lock held: an aside left behind is put back or discarded by its
/// record (see the module's notes). One without a record is refused: it was left by an earlier
/// fluidnerf, which kept no record of the folder's run.
fn recover_locked(root: &Path) -> Result<(), PipelineError> {
    let _ = std::fs::remove_dir_all(root.join(SCENE_DISCARDED));
    let (aside, record_path) = (root.join(SCENE_SET_ASIDE), root.join(SCENE_SET_ASIDE_RECORD));
    if !aside.exists() {
        // A record without an aside: its call died before the move, or after the aside went.
        let _ = std::fs::remove_file(&record_path);
        return Ok(());
    }
    let record: Option<Record> =
        std::fs::read_to_string(&record_path).ok().and_then(|text| serde_json::from_str(&text).ok());
    let Some(record) = record else {
        return Err(PipelineError::RunDir {
            path: root.to_path_buf(),
            why: format!(
                "holds a scene set aside in {SCENE_SET_ASIDE} by an earlier call that did not finish, with no \
                 record ({SCENE_SET_ASIDE_RECORD}) of whether its run started on the new scene in {OWN_SCENE}/; \
                 move {SCENE_SET_ASIDE} back to {OWN_SCENE}/ if the folder's run was made on it, or remove it"
            ),
        });
    };
    if run_wrote(root, record.config) {
        log::info!("{}: removing the scene a call that never finished had replaced", root.display());
        discard(root)
    } else {
        log::info!("{}: putting back the scene a call that never finished had set aside", root.display());
        remove_dir_all(&root.join(OWN_SCENE))?;
        put_back(root)
    }
}

/// Moves the scene set aside back into [`OWN_SCENE`] (which is free) and removes its record.
fn put_back(root: &Path) -> Result<(), PipelineError> {
    let (aside, own) = (root.join(SCENE_SET_ASIDE), root.join(OWN_SCENE));
    std::fs::rename(&aside, &own)
        .map_err(|e| PipelineError::file(&aside, format!("cannot put the run's scene back into {OWN_SCENE}/: {e}")))?;
    let _ = std::fs::remove_file(root.join(SCENE_SET_ASIDE_RECORD));
    Ok(())
}

/// Removes the scene set aside and then its record; renamed first, so that a removal cut short
/// is never taken for a scene to put back.
fn discard(root: &Path) -> Result<(), PipelineError> {
    let discarded = root.join(SCENE_DISCARDED);
    std::fs::rename(root.join(SCENE_SET_ASIDE), &discarded).map_err(|e| {
        PipelineError::file(&root.join(SCENE_SET_ASIDE), format!("cannot remove the replaced scene: {e}"))
    })?;
    let _ = std::fs::remove_file(root.join(SCENE_SET_ASIDE_RECORD));
    if let Err(e) = std::fs::remove_dir_all(&discarded) {
        log::warn!("{}: cannot remove the replaced scene: {e}", discarded.display());
    }
    Ok(())
}

/// Removes the folder `path` and all it holds; nothing when it does not exist.
fn remove_dir_all(path: &Path) -> Result<(), PipelineError> {
    match std::fs::remove_dir_all(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(PipelineError::file(path, e)),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rundir::{DirState, Overwrite, RunDir};

    /// A run folder holding a finished run made on the scene `scene/` (its one file reads
    /// `A`).
    fn run_on_scene_a(tmp: &Path) -> PathBuf {
        let run = tmp.join("run");
        std::fs::create_dir_all(run.join(OWN_SCENE)).unwrap();
        std::fs::write(run.join(OWN_SCENE).join("images.txt"), "A").unwrap();
        std::fs::write(run.join("config.json"), r#"{"scene": "scene", "method": "asart"}"#).unwrap();
        std::fs::write(run.join("volume.npy"), "old").unwrap();
        std::fs::write(run.join("report.json"), "{}").unwrap();
        run
    }

    /// The scene in `scene/` of the folder `run` (the text of its one file).
    fn scene_of(run: &Path) -> String {
        std::fs::read_to_string(run.join(OWN_SCENE).join("images.txt")).unwrap()
    }

    /// A call that saved scene `B` and was killed: its lock is left behind by a process that is
    /// gone (which reads as stale; here it is removed).
    fn killed_after_saving_b(run: &Path) {
        let aside = SceneAside::begin(run, true).unwrap();
        std::fs::create_dir(run.join(OWN_SCENE)).unwrap();
        std::fs::write(run.join(OWN_SCENE).join("images.txt"), "B").unwrap();
        std::mem::forget(aside);
        std::fs::remove_file(run.join(SCENE_LOCK)).unwrap();
    }

    fn settled(run: &Path) -> bool {
        !run.join(SCENE_SET_ASIDE).exists() && !run.join(SCENE_SET_ASIDE_RECORD).exists()
    }

    /// Killed before its run wrote anything: the folder's run is still the one made on scene A,
    /// so whoever reads the folder next gets scene A back, not the killed call's.
    #[test]
    fn a_scene_left_aside_before_the_run_wrote_is_put_back() {
        let tmp = tempfile::tempdir().unwrap();
        let run = run_on_scene_a(tmp.path());
        killed_after_saving_b(&run);
        assert_eq!(std::fs::read_to_string(run.join(SCENE_SET_ASIDE).join("images.txt")).unwrap(), "A");
        let dir = RunDir::open(&run).unwrap();
        assert_eq!(scene_of(&run), "A");
        assert!(settled(&run) && !run.join(SCENE_LOCK).exists());
        assert_eq!(dir.state(), DirState::Finished);
    }

    /// Killed after its run wrote its configuration: the run is the new scene's, so the scene
    /// set aside goes, and a later call settles it as a reader does.
    #[test]
    fn a_scene_left_aside_after_the_run_wrote_is_discarded() {
        let tmp = tempfile::tempdir().unwrap();
        let run = run_on_scene_a(tmp.path());
        killed_after_saving_b(&run);
        write_json(&run.join("config.json"), &serde_json::json!({"scene": "scene", "method": "sart"})).unwrap();
        let aside = SceneAside::begin(&run, false).unwrap();
        assert_eq!(scene_of(&run), "B");
        assert!(settled(&run) && !run.join(SCENE_DISCARDED).exists());
        // Not replacing: the folder's scene stays, also when the call takes back what it made.
        aside.take_back().unwrap();
        assert_eq!(scene_of(&run), "B");
        assert!(!run.join(SCENE_LOCK).exists());
    }

    /// Killed while its `--force` run had set the earlier run aside too (its `config.json` is
    /// then in `.replaced/`, not replaced): both come back together, the run with the scene
    /// it was made on.
    #[test]
    fn a_scene_and_a_run_left_aside_together_come_back_together() {
        let tmp = tempfile::tempdir().unwrap();
        let run = run_on_scene_a(tmp.path());
        killed_after_saving_b(&run);
        std::mem::forget(RunDir::create(&run, Overwrite::Force, None).unwrap());
        std::fs::remove_file(run.join(".lock")).unwrap();
        assert!(!run.join("config.json").exists());
        let dir = RunDir::open(&run).unwrap();
        assert_eq!((scene_of(&run), dir.state()), ("A".to_string(), DirState::Finished));
        assert_eq!(std::fs::read_to_string(run.join("volume.npy")).unwrap(), "old");
        assert!(settled(&run) && !run.join(super::super::REPLACED).exists());
    }

    /// While the call that set the scene aside lives, readers leave it and another call is
    /// refused; the call itself then takes it back or finishes.
    #[test]
    fn a_live_calls_scene_aside_is_left_to_it() {
        let tmp = tempfile::tempdir().unwrap();
        let run = run_on_scene_a(tmp.path());
        let aside = SceneAside::begin(&run, true).unwrap();
        assert!(!run.join(OWN_SCENE).exists() && !aside.written());
        std::fs::create_dir(run.join(OWN_SCENE)).unwrap();
        std::fs::write(run.join(OWN_SCENE).join("images.txt"), "B").unwrap();
        RunDir::open(&run).unwrap();
        assert!(run.join(SCENE_SET_ASIDE).is_dir() && scene_of(&run) == "B");
        let e = SceneAside::begin(&run, true).unwrap_err().to_string();
        assert!(e.contains("in use by another run") && e.contains(SCENE_LOCK), "{e}");
        aside.take_back().unwrap();
        assert_eq!(scene_of(&run), "A");
        assert!(settled(&run) && !run.join(SCENE_LOCK).exists());
        // Finished once the run wrote: scene B stays, A goes.
        let aside = SceneAside::begin(&run, true).unwrap();
        std::fs::create_dir(run.join(OWN_SCENE)).unwrap();
        std::fs::write(run.join(OWN_SCENE).join("images.txt"), "B").unwrap();
        write_json(&run.join("config.json"), &serde_json::json!({"scene": "scene", "method": "sart"})).unwrap();
        assert!(aside.written());
        aside.take_back().unwrap();
        assert_eq!(scene_of(&run), "B");
        assert!(settled(&run));
    }

    /// An aside without its record (left by an earlier fluidnerf) is not decided for the user:
    /// a call is refused, naming it, and readers leave it.
    #[test]
    fn an_aside_without_a_record_is_refused() {
        let tmp = tempfile::tempdir().unwrap();
        let run = run_on_scene_a(tmp.path());
        std::fs::rename(run.join(OWN_SCENE), run.join(SCENE_SET_ASIDE)).unwrap();
        let e = SceneAside::begin(&run, true).unwrap_err().to_string();
        assert!(e.contains(SCENE_SET_ASIDE) && e.contains("no record"), "{e}");
        RunDir::open(&run).unwrap();
        assert!(run.join(SCENE_SET_ASIDE).join("images.txt").is_file() && !run.join(OWN_SCENE).exists());
        assert!(!run.join(SCENE_LOCK).exists());
    }
}
