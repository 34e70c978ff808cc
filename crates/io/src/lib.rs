//! Scene formats, images, volumes and meshes on disk.
//!
//! Everything here converts between files and the types of `fluidnerf-core`; no numerics
//! beyond format conversions live here.
//!
//! - [`scene`]: nerfstudio-style `transforms.json` with fluidnerf's additions (the native
//!   scene format; files from nerfstudio, instant-ngp and Blender/NeRF exporters read too),
//!   and loading a scene's images and ground-truth volumes with their checks.
//! - [`calib`]: OpenCV (`cv::FileStorage` YAML/XML/JSON, stereo pairs), COLMAP (text or
//!   binary) and Agisoft Metashape (camera export XML) calibrations.
//! - [`image`]: 8/16-bit PNG, 8-bit JPEG and 8/16/32-bit and float TIFF, read as f32 with an
//!   explicit linearisation of 8-bit values, and LaVision DaVis images (through [`davis`]).
//! - [`davis`]: LaVision DaVis `.im7`/`.imx` files: every frame of a recorded instant, with
//!   the attributes that name each frame's camera.
//! - [`volume`]: `.npy` (C or Fortran order), `.vti` (VTK XML ImageData), raw + JSON
//!   sidecar and ImageJ TIFF stack volumes.
//! - [`mesh`]: binary PLY and OBJ triangle meshes.
//! - [`video`]: recordings as frames with times (MJPEG AVI natively, other formats through
//!   ffmpeg), limited-range luma handled.
//!
//! # Conventions
//! - Pixel centres: fluidnerf (OpenCV) puts pixel `(col, row)` at continuous image
//!   coordinates `(col, row)`; nerfstudio, COLMAP and Metashape put it at `(col + ½, row + ½)`.
//!   Readers and writers of those formats convert principal points exactly: `cx_core = cx_file
//!   − ½` (Metashape's `cx` counts from the image centre: `cx_core = width / 2 + cx − ½`).
//! - Camera axes: OpenCV (x right, y down, z forward) in memory; nerfstudio's
//!   `transform_matrix` uses OpenGL axes (x right, y up, z backward) and is converted with
//!   `R_cv = R_gl · diag(1, −1, −1)`.
//! - Every writer goes through [`atomic_write`]: a reader never sees a half-written file.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

pub mod calib;
mod cine;
pub mod davis;
mod error;
pub mod folder;
pub mod image;
pub mod json;
pub mod mesh;
mod mraw;
pub mod scene;
pub mod video;
pub mod volume;

pub use error::IoError;

/// Refuses an input that is not a regular file (after following links): a folder, a device
/// such as `/dev/zero` or a pipe would make a whole-file read fail late, never end, or grow
/// without limit.
pub fn check_regular_file(path: &Path, what: &'static str) -> Result<(), IoError> {
    let meta = std::fs::metadata(path).map_err(|e| IoError::io(path, what, e))?;
    if meta.is_file() {
        return Ok(());
    }
    let kind = if meta.is_dir() { "a folder" } else { "a device, pipe or socket" };
    Err(IoError::invalid(path, format!("{what} is {kind}, not a regular file")))
}

/// The whole of the input file `path` ([`check_regular_file`] first); `what` names it in errors.
pub fn read_input(path: &Path, what: &'static str) -> Result<Vec<u8>, IoError> {
    check_regular_file(path, what)?;
    std::fs::read(path).map_err(|e| IoError::io(path, what, e))
}

/// The whole of the text input file `path` ([`check_regular_file`] first), without the
/// byte-order mark Windows editors put at the start of UTF-8 files ([`without_bom`]).
pub fn read_input_text(path: &Path, what: &'static str) -> Result<String, IoError> {
    check_regular_file(path, what)?;
    std::fs::read_to_string(path).map(without_bom).map_err(|e| IoError::io(path, what, e))
}

/// `text` without a leading UTF-8 byte-order mark: invisible in an editor, it made the first
/// key, number or name of a file unreadable (a YAML file "not a mapping", a JSON file malformed
/// at column 1, a COLMAP camera id or a matrix entry "not a number").
pub fn without_bom(text: String) -> String {
    match text.strip_prefix('\u{feff}') {
        Some(rest) => rest.to_string(),
        None => text,
    }
}

/// Writes a file atomically: `write` fills a temporary file in the same folder, which is then
/// renamed over `path`. Missing parent folders are created. On any error the temporary file is
/// removed and `path` is left as it was.
pub fn atomic_write(path: &Path, write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<(), IoError> {
    atomic_write_seekable(path, |w| write(w))
}

/// [`atomic_write`] for formats whose writer moves about in the file (a TIFF's directories
/// point at data written before them).
pub fn atomic_write_seekable(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&std::fs::File>) -> std::io::Result<()>,
) -> Result<(), IoError> {
    let (tmp, _unfinished) = filled_beside(path, write)?;
    tmp.persist(path).map_err(|e| IoError::Io { path: path.to_path_buf(), error: e.error })?;
    Ok(())
}

/// A temporary file beside `path` (its folder created if missing), filled by `write` and
/// listed as unfinished until the guard is dropped; removed again on any error.
fn filled_beside(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&std::fs::File>) -> std::io::Result<()>,
) -> Result<(tempfile::NamedTempFile, Unfinished), IoError> {
    let dir = folder_of(path);
    std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, "output folder", e))?;
    remove_abandoned_writes(dir);
    let tmp = temporary_file_in(dir)?;
    let unfinished = Unfinished::register(tmp.path());
    let io_err = |e| IoError::Io { path: path.to_path_buf(), error: e };
    {
        let mut w = BufWriter::new(tmp.as_file());
        write(&mut w).map_err(io_err)?;
        w.flush().map_err(io_err)?;
    }
    Ok((tmp, unfinished))
}

/// What fills one file of [`atomic_write_together`].
pub type FillFile<'a> = Box<dyn FnOnce(&mut dyn Write) -> std::io::Result<()> + 'a>;

/// [`atomic_write`] of several files that belong together (a raw volume and its sidecar): every
/// file is filled beside its target first, and only once all are complete are they renamed
/// into place, in order. A failure while filling (a full disk) leaves every target as it was,
/// never a new file beside an earlier one it does not match.
pub fn atomic_write_together<'a>(files: Vec<(&'a Path, FillFile<'a>)>) -> Result<(), IoError> {
    let mut staged = Vec::with_capacity(files.len());
    for (path, write) in files {
        let (tmp, unfinished) = filled_beside(path, |w| write(w))?;
        staged.push((path, tmp, unfinished));
    }
    for (path, tmp, _unfinished) in staged {
        tmp.persist(path).map_err(|e| IoError::Io { path: path.to_path_buf(), error: e.error })?;
    }
    Ok(())
}

/// The temporary files of the [`atomic_write`]s under way, in any thread.
static UNFINISHED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// A temporary file listed in [`UNFINISHED`] until the write is over (renamed or removed).
struct Unfinished(PathBuf);

impl Unfinished {
    fn register(path: &Path) -> Self {
        UNFINISHED.lock().unwrap_or_else(std::sync::PoisonError::into_inner).push(path.to_path_buf());
        Self(path.to_path_buf())
    }
}

impl Drop for Unfinished {
    fn drop(&mut self) {
        let mut list = UNFINISHED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(k) = list.iter().position(|p| *p == self.0) {
            list.swap_remove(k);
        }
    }
}

/// Removes the temporary files of the [`atomic_write`]s under way: for a program about to exit
/// at once (a second Ctrl-C), which runs no destructor, so that each would otherwise stay
/// beside its target as a hidden `.fluidnerf-*.tmp`. The targets are left as they were.
pub fn remove_unfinished_writes() {
    remove_unfinished_writes_where(|_| true);
}

/// [`remove_unfinished_writes`] of the temporary files `which` picks (a test's own folder, so
/// that the writes of tests running beside it are left alone).
fn remove_unfinished_writes_where(which: impl Fn(&Path) -> bool) {
    let list = UNFINISHED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    for p in list.iter().filter(|p| which(p)) {
        let _ = std::fs::remove_file(p);
    }
}

/// Checks, before any work, that [`atomic_write`] could write `path` into its existing folder:
/// a temporary file is created there the same way and removed. A folder that is read-only, on
/// a read-only file system or not a folder at all would otherwise fail only once the results
/// are ready. The error names the folder.
pub fn check_writable(path: &Path) -> Result<(), IoError> {
    temporary_file_in(folder_of(path)).map(drop)
}

/// The folder `path` is written into: its parent, or the working folder for a bare name.
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// This machine's name, as temporary files carry it (Linux; empty elsewhere).
fn machine() -> &'static str {
    static NAME: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    NAME.get_or_init(|| {
        std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().replace('/', "_")).unwrap_or_default()
    })
}

/// The temporary files' prefix: `.fluidnerf-<machine>-<process id>-`, so that one left by a
/// process that was killed can be told from one being written ([`remove_abandoned_writes`]).
fn temporary_prefix() -> String {
    format!(".fluidnerf-{}-{}-", machine(), std::process::id())
}

/// Removes from `dir`, once per folder and process, the temporary files of writes that a
/// killed process left (SIGKILL runs no clean-up; an export's volume left 85 MB hidden there):
/// those named by [`temporary_prefix`] for this machine and a process that no longer runs.
/// Files of other machines (a shared file system) and of live processes are left alone, and
/// nothing is done where `/proc` cannot tell (not Linux).
fn remove_abandoned_writes(dir: &Path) {
    static SWEPT: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
    if machine().is_empty() || !Path::new("/proc/self").exists() {
        return;
    }
    {
        let mut swept = SWEPT.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if swept.iter().any(|d| d == dir) {
            return;
        }
        swept.push(dir.to_path_buf());
    }
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    let own = format!(".fluidnerf-{}-", machine());
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(rest) = name.to_str().and_then(|n| n.strip_prefix(&own)).and_then(|n| n.strip_suffix(".tmp")) else {
            continue;
        };
        // `<pid>-<random letters>`: another dash means another machine whose name extends this
        // one's (`node` and `node-12`).
        let Some(pid) =
            rest.split_once('-').filter(|(_, r)| !r.contains('-')).and_then(|(pid, _)| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// The temporary file [`atomic_write`] fills in `dir` before renaming it over its target.
fn temporary_file_in(dir: &Path) -> Result<tempfile::NamedTempFile, IoError> {
    let mut builder = tempfile::Builder::new();
    let prefix = temporary_prefix();
    builder.prefix(&prefix).suffix(".tmp");
    #[cfg(unix)]
    {
        // tempfile's default 0600 would make results unreadable to others; the umask still applies.
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    builder.tempfile_in(dir).map_err(|e| IoError::io(dir, "output folder", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Folders and devices are refused by what they are, before any read.
    #[test]
    fn inputs_must_be_regular_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let err = read_input(dir.path(), "image file").expect_err("a folder").to_string();
        assert!(err.contains("image file is a folder, not a regular file"), "{err}");
        #[cfg(unix)]
        {
            let err = read_input(Path::new("/dev/zero"), "image file").expect_err("a device").to_string();
            assert!(err.contains("/dev/zero") && err.contains("a device, pipe or socket"), "{err}");
            let link = dir.path().join("a.png");
            std::os::unix::fs::symlink("/dev/zero", &link).expect("symlink");
            let err = read_input_text(&link, "scene file").expect_err("a link to a device").to_string();
            assert!(err.contains("a.png") && err.contains("not a regular file"), "{err}");
        }
        let file = dir.path().join("f.txt");
        std::fs::write(&file, "text").expect("write");
        assert_eq!(read_input_text(&file, "scene file").expect("a file"), "text");
        std::fs::write(&file, "\u{feff}text\u{feff}").expect("write");
        assert_eq!(read_input_text(&file, "scene file").expect("a file"), "text\u{feff}", "the leading mark only");
        let err = read_input(&dir.path().join("missing"), "image file").expect_err("missing").to_string();
        assert!(err.contains("image file not found"), "{err}");
    }

    /// A write removes the temporary files that killed processes of this machine left in its
    /// folder, and leaves those of live processes, of other machines and of other programs.
    #[cfg(target_os = "linux")]
    #[test]
    fn temporary_files_of_killed_processes_are_removed() {
        let dir = tempfile::tempdir().expect("tempdir");
        let host = machine();
        // Above the largest process id Linux gives (2²²): no process runs with it.
        let dead = format!(".fluidnerf-{host}-4194305-abc123.tmp");
        let live = format!(".fluidnerf-{host}-1-abc123.tmp");
        let other = format!(".fluidnerf-{host}x-4194305-abc123.tmp");
        let longer = format!(".fluidnerf-{host}-12-4194305-abc123.tmp");
        let kept = [live.as_str(), other.as_str(), longer.as_str(), ".fluidnerf-abc123.tmp", "notes.tmp"];
        for name in kept.iter().chain([&dead.as_str()]) {
            std::fs::write(dir.path().join(name), "x").expect("writes");
        }
        atomic_write(&dir.path().join("out.txt"), |w| w.write_all(b"done")).expect("writes");
        assert!(!dir.path().join(&dead).exists(), "the killed process's file is left");
        for name in kept {
            assert!(dir.path().join(name).exists(), "{name} was removed");
        }
        assert_eq!(std::fs::read_to_string(dir.path().join("out.txt")).expect("reads"), "done");
    }

    /// A folder that takes no new file is refused naming it, and a writable one is left as it was.
    #[test]
    fn check_writable_probes_the_folder_and_leaves_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        check_writable(&dir.path().join("out.json")).expect("a writable folder");
        assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 0, "the probe left a file");
        let err = check_writable(&dir.path().join("missing/out.json")).expect_err("a missing folder").to_string();
        assert!(err.contains("missing"), "{err}");
        let file = dir.path().join("f.txt");
        std::fs::write(&file, "text").expect("write");
        let err = check_writable(&file.join("out.json")).expect_err("a file for a folder").to_string();
        assert!(err.contains("f.txt"), "{err}");
        // Read-only for everyone, root included.
        #[cfg(target_os = "linux")]
        if Path::new("/sys").is_dir() {
            let err = check_writable(Path::new("/sys/out.json")).expect_err("sysfs").to_string();
            assert!(err.contains("/sys"), "{err}");
        }
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporaries() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("sub/out.txt");
        atomic_write(&path, |w| w.write_all(b"first")).expect("write");
        atomic_write(&path, |w| w.write_all(b"second")).expect("write");
        assert_eq!(std::fs::read(&path).expect("read"), b"second");
        let failed = atomic_write(&path, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("encoder failed"))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&path).expect("read"), b"second", "a failed write must not touch the file");
        let names: Vec<_> = std::fs::read_dir(path.parent().expect("parent"))
            .expect("list")
            .map(|e| e.expect("entry").file_name())
            .collect();
        assert_eq!(names.len(), 1, "temporary files left behind: {names:?}");
    }

    /// A program that exits at once in the middle of a write first removes its temporary file:
    /// none is left, and the earlier file stays whole.
    #[test]
    fn unfinished_writes_are_removed_on_request() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("out.txt");
        atomic_write(&path, |w| w.write_all(b"whole")).expect("write");
        let result = atomic_write(&path, |w| {
            w.write_all(b"half")?;
            w.flush()?;
            assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 2, "the temporary file is there");
            remove_unfinished_writes_where(|p| p.starts_with(dir.path()));
            assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 1, "the temporary file is gone");
            Ok(())
        });
        assert!(result.is_err(), "a write whose file was removed cannot be completed");
        assert_eq!(std::fs::read(&path).expect("read"), b"whole");
        assert!(UNFINISHED.lock().expect("lock").iter().all(|p| !p.starts_with(dir.path())), "still listed");
    }
}
