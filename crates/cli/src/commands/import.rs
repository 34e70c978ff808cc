//! `fluidnerf import`: builds a scene (`transforms.json`) from an OpenCV, COLMAP or Metashape
//! calibration and a folder of images, or from a `transforms.json` written by another tool.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context};
use fluidnerf_core::glam::DVec3;
use fluidnerf_core::scene::{estimate_box, same_time, BoxEstimateParams};
use fluidnerf_core::{num, Aabb, Camera, Frame, Scene, TruthRef};
use fluidnerf_io::image::{read_image_with, Linearisation, SampleKind};
use fluidnerf_io::scene::{
    load_images_with, load_preprocessed_with, read_scene_draft, save_scene_recording, validate_scene, SCENE_FILE,
};
use fluidnerf_pipeline::rundir::{refuse_other_kind, FolderKind};
use serde::Serialize;
use std::io::Write as _;

mod davis;

/// Build a scene from an OpenCV, COLMAP or Metashape calibration, or from projection matrices or
/// DLT coefficients, and a folder of images; or from a `transforms.json` written by nerfstudio,
/// instant-ngp or a Blender/NeRF exporter.
///
/// transforms.json (`--transforms`): read as `load_scene` reads scene files (`fl_x`/`fl_y` or
/// `camera_angle_x`/`camera_angle_y`, sizes from the images when `w`/`h` are missing), its
/// images where its `file_path`s point. Its `aabb`, `units`, `intensity_scale` and
/// `linearisation`, when present, are kept unless given on the command line; its ground truth
/// too, which fills the file's box, so another box is refused for a file with truth.
///
/// OpenCV (`--opencv`): a `cv::FileStorage` YAML/XML/JSON file or a folder of them (a stereo
/// pair's `M1 D1 M2 D2 R T` too, see docs/real-data.md), with
/// `camera_matrix`, `distortion_coefficients`, `rvec`/`tvec` or `R`/`T` (world to camera) and
/// `image_width`/`image_height`; several cameras in one file use keys suffixed `_<name>`, a
/// single-camera file names its camera after the file stem. Camera NAME takes the image
/// `IMAGES/NAME.png` (or `.jpg`/`.tif`/`.tiff`, or a DaVis `.im7`/`.imx` of one frame), or,
/// for a time series, every image in the
/// folder `IMAGES/NAME/` in name order (numbers compared as numbers: `img_2` before `img_10`,
/// `t_1.25ms` before `t_1.5ms`, `t_-1` before `t_0`; a `-` after a letter is a dash, with a
/// warning when it may be a sign), the n-th image getting time n (edit the times in
/// `transforms.json` if they are physical): every camera's folder must hold as many images,
/// under the same names when the folders share names, and no folder named like an image; a
/// camera with a single image cannot join cameras recorded over time. Or the video
/// `IMAGES/NAME.avi` (`.mp4`, `.mov`, `.mkv`, `.m4v`, `.webm`, a Phantom `.cine`, or a
/// Photron `.mraw` with its `NAME.cihx`/`NAME.cih` header): its frames are decoded (MJPEG
/// AVI, cine and MRAW directly, other formats with ffmpeg), range-mapped and linearised (the
/// frames of a cine or MRAW are its sensor's counts, as stored, a cine's above its black level),
/// and written as float TIFFs to `OUT/frames/NAME/` with their times in seconds (see
/// --video-range, --video-frames, --video-every, --video-time-offset); videos cannot join
/// series of images. Raw recordings (cine, MRAW) are paired by their frames' times from the
/// trigger: files of one rate that began or ended apart keep the instants every camera
/// recorded. How each video was read (decoder, range and why,
/// clipped pixels) is recorded in `OUT/import.json`.
///
/// A DaVis recording (`--opencv`): when IMAGES holds LaVision DaVis files (`B00001.im7`, …,
/// or `.imx`) and no camera has an entry of its own there, each file is one instant holding a
/// frame of every camera; it is split into `OUT/frames/NAME/B00001.png` (16-bit counts as
/// stored, or `.tif` for float images). Calibrated cameras are matched to DaVis cameras by the
/// number their name ends with (`cam1` is DaVis camera 1, as the file's `CameraName<k>`
/// attributes say, else frame k is camera k + 1), never by order; a double-frame recording's
/// exposures A and B are consecutive instants. See docs/real-data.md.
///
/// Projection matrices (`--projection`): text files of one camera's 3 × 4 matrix `P` (three
/// lines of four numbers), or of one camera per column (11 lines of DLT coefficients, `P` with
/// its last entry 1, as a `*_dltCoefs.csv`; or 12 lines of `P` row by row; a first line of names
/// names the columns' cameras, else `cam1` …), or a folder of such files. Each `P` is split into
/// the pinhole's focal lengths, principal point and skew and its pose (an RQ decomposition; no
/// distortion), for the size of the camera's images, which are found as for OpenCV. Pixels are
/// OpenCV's: `(0, 0)` the top-left pixel's centre, v down; --bottom-left-origin for v counted
/// up from the bottom (DLTdv, Easy-WAND).
///
/// COLMAP (`--colmap`): a text or binary model (`cameras.txt`/`images.txt` or
/// `cameras.bin`/`images.bin`); each image of the model is looked up as `IMAGES/NAME`, or by
/// its name stem when the extension differs (`a.jpg` finds `a.png`). COLMAP's pixel centres
/// (+0.5) are converted.
///
/// Metashape (`--metashape`): the XML of File > Export > Export Cameras ("Agisoft XML"), frame
/// sensors only. Each enabled camera is looked up by its label, as a COLMAP image is (`IMG_1`
/// finds `IMG_1.tif`). Poses go through the chunk's transform (Metashape 2: the camera's
/// component's) into the chunk's coordinate system, in metres: the scene's units are `m` unless
/// --units says otherwise; a file without a chunk transform holds Metashape's internal frame, of
/// arbitrary scale (a warning says so; the units are then mm unless --units). Principal points
/// (offsets from the image centre) and Metashape's tangential terms (its P1 is OpenCV's p2) are
/// converted; b1 and b2 become fx − fy and the skew. k4, p3, p4 other than zero and fisheye or
/// spherical sensors are refused. Cameras the file has not aligned (no transform) are refused,
/// named, unless --skip-uncalibrated; disabled cameras are left out, with their images.
///
/// The box: `--aabb`, else the file's (`--transforms`), else estimated from the images: the
/// bounding box of the points seen bright by every camera (a coarse visual hull), grown by a
/// tenth of its size on every side; it is printed and written into the scene. Check it with
/// `fluidnerf info`.
///
/// Every calibrated camera must find its image(s), and every image in IMAGES must belong to a
/// camera (unless --skip-uncalibrated). The scene is validated (each camera must see the box,
/// image sizes must match the calibration, no NaN/Inf pixels, a transforms.json's masks,
/// backgrounds and flat fields must fit their frames) before `OUT/transforms.json` is
/// written, together with `OUT/import.json` (the settings of this run). Image paths are
/// written relative to OUT when IMAGES is inside OUT, absolute otherwise.
///
/// Decoded frames and the scene files are written into the hidden folder `OUT/.import-staging`
/// first, and go into place only once the scene is validated and written: an import that
/// fails leaves OUT as it was (an earlier scene there untouched, byte for byte; OUT removed
/// when it made it), so the same command can run again once the input is fixed. An import
/// that succeeds with --force removes the files the earlier import decoded or split that the
/// new scene does not read. One stopped (killed) before it was done leaves the staging
/// folder, which the next import into OUT removes, or, when the scene was complete, finishes
/// putting into place (as `fluidnerf info OUT` does).
#[derive(clap::Args, Debug, Serialize)]
#[command(group(clap::ArgGroup::new("source").required(true)))]
pub struct Args {
    /// OpenCV calibration: a `.yml`/`.yaml`/`.xml`/`.json` file or a folder of them (one or
    /// several cameras per file, or a stereo pair's `M1 D1 M2 D2 R T`).
    #[arg(long, group = "source", requires = "images")]
    pub opencv: Option<PathBuf>,
    /// COLMAP model folder (holding `cameras.txt` and `images.txt`, or `.bin`).
    #[arg(long, group = "source", requires = "images")]
    pub colmap: Option<PathBuf>,
    /// Agisoft Metashape camera export (`.xml`, File > Export > Export Cameras).
    #[arg(long, group = "source", requires = "images")]
    pub metashape: Option<PathBuf>,
    /// Projection matrices or DLT coefficients: a text file or a folder of them (`.txt`,
    /// `.csv`, `.dat`): one camera's 3 × 4 matrix, or one camera per column (11 DLT
    /// coefficients or 12 matrix entries row by row, as a `*_dltCoefs.csv`). Pixels in OpenCV's
    /// convention (`(0, 0)` the top-left pixel's centre, v down); image sizes from the images.
    #[arg(long, group = "source", requires = "images")]
    pub projection: Option<PathBuf>,
    /// The --projection's v counts up from the image's bottom edge (DLTdv, Easy-WAND): each
    /// camera's v is taken as its image height − v.
    #[arg(long, requires = "projection")]
    pub bottom_left_origin: bool,
    /// A `transforms.json` (nerfstudio, instant-ngp, Blender/NeRF synthetic), or its folder.
    #[arg(long, group = "source")]
    pub transforms: Option<PathBuf>,
    /// Folder with the images (for --opencv, --projection, --colmap and --metashape).
    #[arg(long, conflicts_with = "transforms")]
    pub images: Option<PathBuf>,
    /// Reconstruction box in world units: xmin,ymin,zmin,xmax,ymax,zmax (e.g.
    /// `-10,-10,-10,10,10,10`). Without it, the box is estimated from the images.
    #[arg(long, allow_hyphen_values = true)]
    pub aabb: Option<String>,
    /// Length unit of the calibration's world frame [default: mm, or the file's; m for a
    /// Metashape chunk with a transform].
    #[arg(long, value_parser = parse_units)]
    pub units: Option<String>,
    /// Pixel value = intensity_scale × ∫E ds (world units) [default: 1, or the file's].
    #[arg(long)]
    pub intensity_scale: Option<f64>,
    /// How 8-bit images (PNG, JPEG, TIFF) and video frames become linear: `linear` (counts as
    /// stored), `srgb` (undo the sRGB curve, right for camera JPEGs) or a gamma such as `2.2`;
    /// written into the scene [default: linear, or the file's]. Images of more bits are always
    /// read as linear (a warning says so when this is given for them).
    #[arg(long, value_parser = parse_linearisation)]
    pub linearisation: Option<Linearisation>,
    /// Output scene folder (created if missing).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Replace the scene in OUT: its `transforms.json` and `import.json`, and the frames an
    /// earlier import decoded or split there (those the new scene does not read are removed).
    /// A failed import leaves the earlier scene as it was.
    #[arg(long)]
    pub force: bool,
    /// Leave out images that no camera is calibrated for (with a warning) instead of failing
    /// (for --opencv, --projection, --colmap and --metashape), and cameras a Metashape file has
    /// not aligned.
    #[arg(long, conflicts_with = "transforms")]
    pub skip_uncalibrated: bool,
    /// Cameras to hold out for validation, comma separated: camera names, or image names
    /// without extension for frames that name no camera. Every frame of such a camera is held
    /// out.
    #[arg(long, value_delimiter = ',')]
    pub holdout: Vec<String>,
    /// Luma range of video recordings: `auto` (what the file states: MJPEG is full range
    /// unless its JPEGs are marked limited, other video is limited unless its stream says
    /// `pc`), `full` (0–255 kept) or `limited` (16–235 mapped to 0–255, pixels outside
    /// clipped and counted).
    #[arg(long, value_name = "auto|full|limited", default_value = "auto")]
    pub video_range: fluidnerf_io::video::VideoRange,
    /// Frames of video recordings to import, as `A..B`: 0-based indices in the file, B
    /// excluded (a B past a file's last frame is refused); `A..` runs to the end, `..B` starts
    /// at 0. Times stay those of the recording (plus --video-time-offset).
    #[arg(long, value_name = "A..B")]
    pub video_frames: Option<String>,
    /// Import every N-th frame of video recordings, counted from the first of --video-frames.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub video_every: u32,
    /// Seconds added to the time of every video frame (e.g. to put the trigger at 0).
    #[arg(long, value_name = "SECONDS", default_value_t = 0.0, allow_hyphen_values = true, value_parser = parse_time_offset)]
    pub video_time_offset: f64,
}

fn parse_time_offset(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(t) if t.is_finite() => Ok(t),
        _ => Err(format!("`{s}` is not a time in seconds")),
    }
}

/// How one camera's video was read, for `import.json`.
#[derive(Serialize)]
struct VideoRecord {
    camera: String,
    file: PathBuf,
    #[serde(flatten)]
    info: fluidnerf_io::video::VideoInfo,
    first_time_s: f64,
    last_time_s: f64,
}

/// The hidden folder in OUT that an import decodes its recordings' frames into and writes its
/// scene files into, under the paths they take in OUT (`frames/<camera>/…`, `transforms.json`,
/// `import.json`). They go into place only once the scene is validated and written
/// ([`commit`]), so an import that fails leaves an earlier scene in OUT as it was, byte for
/// byte, instead of one that mixes two recordings.
///
/// After a kill, what the folder holds tells what happened ([`settle_staging`]): without the
/// commit record ([`COMMIT_RECORD`]) the import was stopped before its scene was complete, OUT
/// still holds the earlier scene untouched, and the next import into OUT removes the folder;
/// with it, the import had succeeded and was stopped while putting its files into place, and
/// the next import into OUT, or `fluidnerf info OUT`, finishes that. Nothing else reads the
/// folder.
const STAGING: &str = ".import-staging";

/// The record in [`STAGING`] that the import's files there are complete and go into place: a
/// [`Commit`].
const COMMIT_RECORD: &str = "commit.json";

/// What an import that has succeeded does in OUT: recorded in [`STAGING`] before any of it is
/// done, so that it is finished after a kill ([`settle_staging`]). Each step can be done again.
#[derive(Serialize, serde::Deserialize)]
struct Commit {
    /// Files of the staging folder, relative to it, each moved to the same path in OUT (over
    /// the file there), in this order: the frames, then `transforms.json` and `import.json`.
    moves: Vec<PathBuf>,
    /// Files an earlier import wrote, relative to OUT, that the new scene does not read:
    /// removed once the new files are in place, and their folders when that leaves them empty.
    removals: Vec<PathBuf>,
}

impl Commit {
    /// Does what `self` records: a move whose file is gone from `staging` was done before.
    fn apply(&self, out: &Path, staging: &Path) -> anyhow::Result<()> {
        for rel in &self.moves {
            let (from, to) = (staging.join(rel), out.join(rel));
            if let Some(parent) = to.parent() {
                std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
            }
            match std::fs::rename(&from, &to) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound && !from.exists() => {}
                Err(e) => return Err(e).with_context(|| format!("cannot move {} to {}", from.display(), to.display())),
            }
        }
        let mut removed = 0usize;
        let mut dirs = BTreeSet::new();
        for rel in &self.removals {
            let file = out.join(rel);
            match std::fs::remove_file(&file) {
                Ok(()) => removed += 1,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => log::warn!("cannot remove {}, a file of the earlier import: {e}", file.display()),
            }
            dirs.extend(file.parent().map(Path::to_path_buf));
        }
        for dir in dirs {
            // Only when empty: a file of the user's keeps its folder.
            let _ = std::fs::remove_dir(&dir);
        }
        if removed > 0 {
            log::info!("removed {removed} file(s) of the earlier import that this one does not use");
        }
        Ok(())
    }

    /// The record in `staging`, None when there is none; an error when it is not one an
    /// import wrote (its paths must lead to places under OUT and the staging folder).
    fn read(staging: &Path) -> anyhow::Result<Option<Commit>> {
        let file = staging.join(COMMIT_RECORD);
        let text = match std::fs::read_to_string(&file) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("cannot read {}", file.display())),
        };
        let plain = |p: &PathBuf| {
            !p.as_os_str().is_empty() && p.components().all(|c| matches!(c, std::path::Component::Normal(_)))
        };
        match serde_json::from_str::<Commit>(&text) {
            Ok(commit) if commit.moves.iter().chain(&commit.removals).all(plain) => Ok(Some(commit)),
            _ => bail!(
                "{} is not the record of an import into {}: look at the folder {} and remove it",
                file.display(),
                staging.parent().unwrap_or(staging).display(),
                staging.display()
            ),
        }
    }
}

/// Settles what an import into `out` left in its staging folder ([`STAGING`]), before an
/// import starts (`discard`) or `info` reads the scene: an import recorded as committed is
/// finished, and one that was not is removed when `discard` (`info` leaves it: it may be an
/// import under way). Its files are never taken for the scene's.
pub(crate) fn settle_staging(out: &Path, discard: bool) -> anyhow::Result<()> {
    let staging = out.join(STAGING);
    if !staging.is_dir() {
        return Ok(());
    }
    if let Some(commit) = Commit::read(&staging)? {
        log::warn!(
            "{}: finishing an import that was stopped while it put its files into place (its scene was complete)",
            out.display()
        );
        commit.apply(out, &staging)?;
    } else if discard {
        log::info!("{}: removing what an import that was stopped before it finished left", staging.display());
    } else {
        return Ok(());
    }
    let _ = std::fs::remove_file(staging.join(COMMIT_RECORD));
    std::fs::remove_dir_all(&staging).with_context(|| format!("cannot remove {}", staging.display()))
}

/// Puts the import staged in `staging` into place in `out`: records what is to be done
/// (`commit`, from when on the import counts as done: a kill leaves the rest to
/// [`settle_staging`]), does it, and removes the staging folder.
fn commit(out: &Path, staging: &Path, commit: &Commit, created: &mut Created) -> anyhow::Result<()> {
    let json = serde_json::to_string_pretty(commit)?;
    fluidnerf_io::atomic_write(&staging.join(COMMIT_RECORD), |w| w.write_all(json.as_bytes()))?;
    created.staging = None;
    commit.apply(out, staging).with_context(|| {
        format!(
            "the import is complete in {} but could not be put into place; the next import into {} or `fluidnerf \
             info {}` finishes it",
            staging.display(),
            out.display(),
            out.display()
        )
    })?;
    let _ = std::fs::remove_file(staging.join(COMMIT_RECORD));
    if let Err(e) = std::fs::remove_dir_all(staging) {
        log::warn!("cannot remove {} after the import: {e}", staging.display());
    }
    Ok(())
}

/// The lock of an import into OUT (the runs' [`fluidnerf_pipeline::rundir::FileLock`]: process,
/// machine and heartbeat): a second import into the same folder would settle the first one's
/// staging folder as left by a killed import and remove it, or stage its files among the
/// first one's. A stale lock (its process gone) is replaced.
pub(crate) const IMPORT_LOCK: &str = ".import.lock";

/// What an import made in OUT before its scene went into place: undone when it fails, so that
/// a failed import leaves OUT as it was and its rerun needs no --force.
#[derive(Default)]
struct Created {
    /// Folders made, parents before their children.
    dirs: Vec<PathBuf>,
    /// The staging folder ([`STAGING`]) until the import is committed.
    staging: Option<PathBuf>,
    /// The import's lock of OUT ([`IMPORT_LOCK`]), held until the import ends.
    lock: Option<fluidnerf_pipeline::rundir::FileLock>,
}

impl Created {
    /// Takes the lock of the folder `out` ([`IMPORT_LOCK`]), unless this import holds it.
    fn lock(&mut self, out: &Path) -> anyhow::Result<()> {
        if self.lock.is_none() {
            let lock = fluidnerf_pipeline::rundir::FileLock::take(out, &out.join(IMPORT_LOCK))
                .with_context(|| format!("{}: another import is writing into this folder", out.display()))?;
            self.lock = Some(lock);
        }
        Ok(())
    }

    /// Creates `dir` and its missing parents, recording the folders it makes.
    fn dir_all(&mut self, dir: &Path) -> anyhow::Result<()> {
        let missing: Vec<PathBuf> =
            dir.ancestors().take_while(|d| !d.as_os_str().is_empty() && !d.exists()).map(Path::to_path_buf).collect();
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        self.dirs.extend(missing.into_iter().rev());
        Ok(())
    }

    /// Creates the staging folder `dir`, which must not exist: what an earlier import left
    /// was settled when this one started, so one there now is another import's, under way.
    fn staging(&mut self, dir: &Path) -> anyhow::Result<()> {
        match std::fs::create_dir(dir) {
            Ok(()) => {
                self.staging = Some(dir.to_path_buf());
                Ok(())
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => bail!(
                "{} exists: another import into {} is under way; wait for it to finish",
                dir.display(),
                dir.parent().unwrap_or(dir).display()
            ),
            Err(e) => Err(e).with_context(|| format!("cannot create {}", dir.display())),
        }
    }

    /// Removes what was recorded: the staging folder with what it holds, then the folders,
    /// children first and only when empty (a file someone else put there meanwhile keeps its
    /// folder).
    fn undo(mut self) {
        // Its file first: a folder the import made is removed only when empty.
        drop(self.lock.take());
        if let Some(staging) = &self.staging {
            if let Err(e) = std::fs::remove_dir_all(staging) {
                if e.kind() != std::io::ErrorKind::NotFound {
                    log::warn!("cannot remove {} after the failed import: {e}", staging.display());
                }
            }
        }
        for d in self.dirs.iter().rev() {
            if std::fs::remove_dir(d).is_err() && d.exists() {
                log::warn!("cannot remove the folder {} after the failed import", d.display());
            }
        }
    }
}

/// `A..B` or `A..` as (start, end).
fn parse_frame_range(s: &str) -> anyhow::Result<(usize, Option<usize>)> {
    let bad = || anyhow::anyhow!("--video-frames: expected A..B or A.. (frame indices from 0), got `{s}`");
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let a: usize = if a.is_empty() { 0 } else { a.trim().parse().map_err(|_| bad())? };
    let b: Option<usize> = if b.is_empty() { None } else { Some(b.trim().parse().map_err(|_| bad())?) };
    if b.is_some_and(|b| b <= a) {
        bail!("--video-frames {s}: the range is empty");
    }
    Ok((a, b))
}

/// Why a picture of `width` × `height` pixels decoded from a recording (a video's frame, a
/// DaVis file's frame of a camera) cannot be `camera`'s image, when it cannot. Checked as each
/// is decoded, before it is written: the check of the scene's images would come after the
/// whole recording was decoded and name a decoded file that the failed import removes, not
/// the recording the user gave.
fn decoded_size_problem(camera: &Camera, width: usize, height: usize) -> Option<String> {
    let (w, h) = (camera.width(), camera.height());
    ((width, height) != (w, h))
        .then(|| format!("{width}x{height} pixels, but the camera's calibration is for {w}x{h} (w x h)"))
}

/// Replaces every frame whose file is a video by its decoded frames, each written as a float
/// TIFF (linearised, range-mapped values) into `staging/frames/<camera>/` as it is decoded,
/// with its time; the frames go to `out/frames/<camera>/` when the import is committed, where
/// a file of the same name is replaced only with `force`. All videos must give their frames at the same times (a synchronised recording);
/// raw recordings that began or ended apart keep the frames of the times every one of them
/// recorded, the others' files removed again, with a warning.
/// Also returns, for each frame returned, the index of the frame it came from (a video's
/// frames keep its mask, background and flat field).
fn expand_videos(
    frames: Vec<Frame>,
    out: &Path,
    staging: &Path,
    opts: &fluidnerf_io::video::VideoOptions,
    force: bool,
) -> anyhow::Result<(Vec<Frame>, Vec<VideoRecord>, Vec<usize>)> {
    // A video's frames go to `frames/<name>/`, by its camera's name, else its file's stem.
    let video_name = |f: &Frame| {
        f.camera_name
            .clone()
            .unwrap_or_else(|| f.file_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default())
    };
    // Two videos of one name would write into one folder, the second over the first's frames.
    let mut folders: std::collections::HashMap<String, &Path> = std::collections::HashMap::new();
    for f in frames.iter().filter(|f| fluidnerf_io::video::is_video(&f.file_path)) {
        // A name of several components (`../x`, `/tmp/x`) would put the frames outside OUT/frames.
        let name = video_name(f);
        let mut parts = Path::new(&name).components();
        if !matches!((parts.next(), parts.next()), (Some(std::path::Component::Normal(_)), None)) {
            bail!(
                "the video {} goes by the name `{name}`, which cannot name its frames' folder in {} (it is empty, \
                 `.` or `..`, or holds a path separator): give its frame a plain `camera` name",
                f.file_path.display(),
                out.join("frames").display()
            );
        }
        if let Some(other) = folders.insert(name, &f.file_path) {
            bail!(
                "the videos {} and {} both go by the name `{}` (their camera's, else their file's name), and the \
                 frames of both would be decoded into {}: give each video's frame its own `camera` name",
                other.display(),
                f.file_path.display(),
                video_name(f),
                out.join("frames").join(video_name(f)).display()
            );
        }
    }
    // One recording decoded for two cameras gives both the same pictures from different poses,
    // as one image named by two frames would (which the scene's validation refuses).
    let label = |i: usize, f: &Frame| f.camera_name.as_ref().map_or(format!("frame {i}"), |n| format!("camera {n}"));
    let mut recordings: std::collections::HashMap<PathBuf, (usize, &Frame)> = std::collections::HashMap::new();
    for (i, f) in frames.iter().enumerate().filter(|(_, f)| fluidnerf_io::video::is_video(&f.file_path)) {
        let file = f.file_path.canonicalize().unwrap_or_else(|_| f.file_path.clone());
        if let Some((j, other)) = recordings.insert(file, (i, f)) {
            bail!(
                "{} and {} both name the video {}: each camera needs its own recording",
                label(j, other),
                label(i, f),
                f.file_path.display()
            );
        }
        // A frame's own time cannot go with every frame decoded from its video.
        if let Some(t) = f.time {
            log::warn!(
                "{} ({}): its `time` {} is not used: a video's frames take their times from the recording, in                  seconds (shift them with --video-time-offset)",
                label(i, f),
                f.file_path.display(),
                num(t)
            );
        }
    }
    let mut expanded = Vec::new();
    let mut sources = Vec::new();
    let mut records: Vec<VideoRecord> = Vec::new();
    // Each video's frame times, and the index of its frame in `frames`, in the order of `records`.
    let mut all_times: Vec<Vec<f64>> = Vec::new();
    let mut video_sources: Vec<usize> = Vec::new();
    for (source, f) in frames.into_iter().enumerate() {
        if !fluidnerf_io::video::is_video(&f.file_path) {
            expanded.push(f);
            sources.push(source);
            continue;
        }
        let name = video_name(&f);
        // The raw recordings of high-speed cameras hold linear counts.
        let raw =
            f.file_path.extension().is_some_and(|e| e.eq_ignore_ascii_case("cine") || e.eq_ignore_ascii_case("mraw"));
        if records.is_empty() && opts.linearisation == Linearisation::Linear && !raw {
            log::warn!(
                "video frames are read as linear; most cameras store gamma-encoded video (pass --linearisation \
                 srgb or a gamma) unless they record raw or linear luma"
            );
        }
        let dir = staging.join("frames").join(&name);
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let mut times = Vec::new();
        let bar = crate::progress::counter(&name, "frames");
        let info = fluidnerf_io::video::read_video_frames(&f.file_path, opts, |frame| {
            if let Some(problem) = decoded_size_problem(&f.camera, frame.image.width, frame.image.height) {
                return Err(fluidnerf_io::IoError::invalid(
                    &f.file_path,
                    format!("frame {} is {problem}", frame.index),
                ));
            }
            let file = format!("{:06}.tif", times.len());
            let target = out.join("frames").join(&name).join(&file);
            if target.exists() && !force {
                return Err(fluidnerf_io::IoError::invalid(
                    &target,
                    "exists (from an earlier import); pass --force to overwrite it",
                ));
            }
            let path = dir.join(&file);
            fluidnerf_io::image::write_tiff_f32(&path, &frame.image)?;
            times.push(frame.time_s);
            expanded.push(Frame { file_path: path, time: Some(frame.time_s), ..f.clone() });
            sources.push(source);
            bar.inc(1);
            Ok(())
        })
        .with_context(|| format!("camera {name}: reading its video"))?;
        bar.finish_and_clear();
        if info.clipped_pixels > 0 {
            log::warn!(
                "{}: {} pixel(s) {} were clipped",
                f.file_path.display(),
                info.clipped_pixels,
                if info.range_source == fluidnerf_io::video::RangeSource::Raw {
                    "below the camera's black level"
                } else {
                    "outside the limited range 16–235"
                }
            );
        }
        if info.saturated_pixels > 0 {
            log::warn!(
                "camera {name}: {}: {} pixel(s) of the frames kept at the recording's full scale (saturated): they \
                 recorded less light than arrived, so the line-integral model does not hold there; mask them \
                 (mask_path) or record with less exposure",
                f.file_path.display(),
                info.saturated_pixels
            );
        }
        let range = match info.range_source {
            fluidnerf_io::video::RangeSource::Option => format!("{} range, as --video-range says", info.range),
            fluidnerf_io::video::RangeSource::File => format!("{} range, as the file states", info.range),
            fluidnerf_io::video::RangeSource::JpegDefault => format!("{} range, the JPEG default", info.range),
            fluidnerf_io::video::RangeSource::VideoDefault => {
                format!("{} range, the video default; the file states none", info.range)
            }
            fluidnerf_io::video::RangeSource::Raw => "raw sensor counts above the black level".to_owned(),
        };
        log::info!(
            "{}: {} of {} frame(s) decoded ({}, {range})",
            f.file_path.display(),
            info.frames_kept,
            info.frames_in_file,
            info.decoder,
        );
        records.push(VideoRecord {
            camera: name,
            file: f.file_path.clone(),
            info,
            first_time_s: times.first().copied().unwrap_or(0.0),
            last_time_s: times.last().copied().unwrap_or(0.0),
        });
        all_times.push(times);
        video_sources.push(source);
    }
    let Some(first) = records.first() else { return Ok((expanded, records, sources)) };
    let same_times = |times: &Vec<f64>| {
        times.len() == all_times[0].len() && times.iter().zip(&all_times[0]).all(|(&t, &t0)| same_time(t, t0))
    };
    if all_times.iter().all(same_times) {
        return Ok((expanded, records, sources));
    }
    // Cameras triggered together whose files keep different spans of one rate: the times all
    // of them recorded, a run of consecutive frames in each file. Only recordings whose times
    // count from the trigger (a high-speed camera's raw files) are paired so; other videos'
    // times count from each file's start, and files of different lengths say nothing of which
    // frames were simultaneous.
    let from_trigger = records.iter().all(|r| r.info.range_source == fluidnerf_io::video::RangeSource::Raw);
    let common: Vec<f64> = all_times[0]
        .iter()
        .copied()
        .filter(|&t| {
            // Frames are decoded in time order: the first time not below `t` is `t` or none is.
            all_times[1..].iter().all(|times| {
                times.get(times.partition_point(|&u| u < t && !same_time(u, t))).is_some_and(|&u| same_time(t, u))
            })
        })
        .collect();
    let runs: Option<Vec<usize>> = all_times
        .iter()
        .map(|times| {
            let start = times.iter().position(|&t| common.first().is_some_and(|&c| same_time(t, c)))?;
            let run = times.get(start..start + common.len())?;
            run.iter().zip(&common).all(|(&t, &c)| same_time(t, c)).then_some(start)
        })
        .collect();
    let aligned = runs.filter(|_| !common.is_empty() && from_trigger);
    let Some(starts) = aligned else {
        if let Some(other) = records.iter().find(|r| r.info.frames_kept != first.info.frames_kept) {
            // Files whose times count from their own start may well share times: what they do
            // not tell is which frames were simultaneous.
            let why = if from_trigger {
                "and they share no run of frames at the same times"
            } else {
                "and their times count from each file's start, so files of different lengths do not tell which \
                 frames were simultaneous"
            };
            bail!(
                "the videos are not synchronised: camera {} gives {} frame(s), camera {} {}, {why}; select the same \
                 instants of each with --video-frames",
                first.camera,
                first.info.frames_kept,
                other.camera,
                other.info.frames_kept
            );
        }
        // The n-th frames of the cameras are one instant only at one time: videos of other frame
        // rates or starts would give instants seen by one camera each.
        for (other, times) in records.iter().zip(&all_times).skip(1) {
            let Some(n) = times.iter().zip(&all_times[0]).position(|(&t, &t0)| !same_time(t, t0)) else {
                continue;
            };
            let rate = |r: &VideoRecord| r.info.frame_rate.map_or_else(|| "no stated".to_string(), |f| format!("{f}"));
            bail!(
                "the videos are not synchronised: the frame {n} kept of camera {} is at {} s, that of camera {} at \
                 {} s (frame rates {} and {} fps); every camera's n-th frame must be the same instant: record \
                 the cameras at one rate from one trigger and keep the same frames of each (a high-speed camera's \
                 file may begin before or after the others'), or import them separately",
                first.camera,
                all_times[0][n],
                other.camera,
                times[n],
                rate(first),
                rate(other)
            );
        }
        bail!("the videos are not synchronised: their frames are at different times");
    };
    // Each video's frames outside the common run are left out, their files removed.
    let (t0, t1) = (common[0], common[common.len() - 1]);
    for ((record, times), &start) in records.iter_mut().zip(&all_times).zip(&starts) {
        let after = times.len() - start - common.len();
        if start + after == 0 {
            continue;
        }
        log::warn!(
            "camera {}: {start} frame(s) before {} s and {after} after {} s, times not every camera recorded, are left \
             out",
            record.camera,
            num(t0),
            num(t1)
        );
        record.info.frames_kept = common.len();
        (record.first_time_s, record.last_time_s) = (t0, t1);
    }
    if all_times.iter().any(|times| times.len() != common.len()) {
        // The k-th frame decoded from the video of `source` is kept when its file's run holds it.
        let mut seen = vec![0usize; records.len()];
        let mut kept_frames = Vec::with_capacity(expanded.len());
        let mut kept_sources = Vec::with_capacity(sources.len());
        for (f, source) in expanded.into_iter().zip(sources) {
            // `video_sources` is in increasing order, as the frames were enumerated.
            if let Ok(r) = video_sources.binary_search(&source) {
                let k = seen[r];
                seen[r] += 1;
                if !(starts[r]..starts[r] + common.len()).contains(&k) {
                    std::fs::remove_file(&f.file_path)
                        .with_context(|| format!("removing {}, a frame left out", f.file_path.display()))?;
                    continue;
                }
            }
            kept_frames.push(f);
            kept_sources.push(source);
        }
        return Ok((kept_frames, records, kept_sources));
    }
    Ok((expanded, records, sources))
}

fn parse_linearisation(s: &str) -> Result<Linearisation, String> {
    s.parse()
}

/// The median distance of the cameras from the box's centre, when it is below 10 (mm, the
/// default unit): a calibration in metres read as millimetres puts cameras a metre away
/// within a millimetre of the flow. None otherwise.
fn near_cameras(scene: &Scene) -> Option<f64> {
    let centre = scene.aabb.centre();
    let mut d: Vec<f64> = scene.frames.iter().map(|f| (f.camera.centre() - centre).length()).collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().filter(|&m| m < 10.0)
}

/// A length unit's name, checked as a scene's `units` is.
pub(crate) fn parse_units(s: &str) -> Result<String, String> {
    fluidnerf_io::scene::check_units(s).map(|()| s.to_string())
}

fn is_image(p: &Path) -> bool {
    p.is_file() && named_like_image(p)
}

fn named_like_image(p: &Path) -> bool {
    fluidnerf_io::image::has_image_extension(p)
}

/// The entries of `dir` in name order, numbers in names compared as numbers
/// ([`natural_order`]): the order of a time series' images and of a DaVis recording's files,
/// the n-th of which is instant n.
fn list_dir(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot list the image folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    v.sort_by(|a, b| natural_order(&name(a), &name(b)).then_with(|| a.cmp(b)));
    Ok(v)
}

/// Orders names as recordings number them: numbers compare as numbers, everything else as
/// text, and names that are equal so (`a01`, `a1`) by their text. A number is
/// - a run of digits, compared as an integer: `img_2` before `img_10` (text order put
///   `img_10` first, giving it the second instant of a series numbered without leading
///   zeros); leading zeros do not count, so names numbered with them keep their text order;
/// - or a decimal: one run of digits, a point and another run, compared as a decimal number
///   (`t_1.25ms` before `t_1.5ms`, which integers 25 and 5 put the other way round), unless
///   a point and a digit follow it or a digit and a point come before it: three or more runs
///   joined by points (`v1.2.3`, `v1.10.0`, `img.1.10.2`) compare one by one, as integers,
///   as versions do (`img.001.png` holds no decimal);
/// - either with a sign: a `-` or `+` right before it that begins the name or follows a
///   character that is no letter or digit (`t_-1.5`, `-2.png`). After a letter or a digit it
///   is a dash (`cam-1`, `frame-2`, `2024-01-05`) and the number after it has no sign:
///   [`sign_read_as_dash`] finds the names where that may be wrong.
///
/// Against a character that is not part of a number, a number compares as its first digit
/// does, a negative one as if just before `-`; the order stays total, as sorting needs.
fn natural_order(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (x, y) = (a.as_bytes(), b.as_bytes());
    let (mut i, mut j) = (0, 0);
    loop {
        match (i < x.len(), j < y.len()) {
            (false, false) => return a.cmp(b),
            (false, true) => return Ordering::Less,
            (true, false) => return Ordering::Greater,
            (true, true) => {}
        }
        let ((p, next_i), (q, next_j)) = (NamePiece::at(x, i), NamePiece::at(y, j));
        match p.cmp(&q) {
            Ordering::Equal => (i, j) = (next_i, next_j),
            other => return other,
        }
    }
}

/// A piece of a name as [`natural_order`] compares it: a character (a byte of its UTF-8,
/// whose order is that of the characters), or a number.
#[derive(Clone, Copy, Debug)]
enum NamePiece<'a> {
    Byte(u8),
    /// `int` without its leading zeros, `fraction` without its trailing ones.
    Number {
        negative: bool,
        int: &'a [u8],
        fraction: &'a [u8],
    },
}

impl<'a> NamePiece<'a> {
    /// The piece of the name `s` that begins at `i`, and where the next one begins.
    fn at(s: &'a [u8], i: usize) -> (NamePiece<'a>, usize) {
        let digits_from =
            |k: usize| s.get(k..).map_or(0, |rest| rest.iter().take_while(|c| c.is_ascii_digit()).count());
        let signed = matches!(s[i], b'-' | b'+')
            && s.get(i + 1).is_some_and(u8::is_ascii_digit)
            && (i == 0 || !s[i - 1].is_ascii_alphanumeric());
        let start = i + usize::from(signed);
        if !s[start].is_ascii_digit() {
            return (NamePiece::Byte(s[i]), i + 1);
        }
        let int_end = start + digits_from(start);
        let (mut fraction, mut end): (&[u8], usize) = (&[], int_end);
        let after_dotted = start >= 2 && s[start - 1] == b'.' && s[start - 2].is_ascii_digit();
        let point = s.get(int_end) == Some(&b'.');
        let fraction_digits = if point && !after_dotted { digits_from(int_end + 1) } else { 0 };
        if fraction_digits > 0 {
            let fraction_end = int_end + 1 + fraction_digits;
            let dotted_on =
                s.get(fraction_end) == Some(&b'.') && s.get(fraction_end + 1).is_some_and(u8::is_ascii_digit);
            if !dotted_on {
                (fraction, end) = (&s[int_end + 1..fraction_end], fraction_end);
            }
        }
        let int = &s[start..int_end];
        let int = &int[int.iter().take_while(|&&c| c == b'0').count()..];
        let fraction = &fraction[..fraction.len() - fraction.iter().rev().take_while(|&&c| c == b'0').count()];
        (NamePiece::Number { negative: signed && s[i] == b'-', int, fraction }, end)
    }

    /// Where the piece stands among characters: a character by its byte, a negative number
    /// just before `-`, any other number at `0` (no character is a digit: digits are numbers).
    fn rank(&self) -> u16 {
        match self {
            NamePiece::Byte(c) => 2 * u16::from(*c) + 1,
            NamePiece::Number { negative: true, .. } => 2 * u16::from(b'-'),
            NamePiece::Number { negative: false, .. } => 2 * u16::from(b'0'),
        }
    }

    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        match (self, other) {
            (
                NamePiece::Number { negative, int, fraction },
                NamePiece::Number { negative: other_negative, int: other_int, fraction: other_fraction },
            ) if negative == other_negative => {
                // Digits without leading zeros: the longer run is the larger; fractions
                // without trailing zeros compare as text.
                let size = int
                    .len()
                    .cmp(&other_int.len())
                    .then_with(|| int.cmp(other_int))
                    .then_with(|| fraction.cmp(other_fraction));
                if *negative {
                    size.reverse()
                } else {
                    size
                }
            }
            _ => self.rank().cmp(&other.rank()),
        }
    }
}

/// Two of `names` that show a `-` or `+` between a letter and a number, which
/// [`natural_order`] reads as a dash, may be a sign: one holding it (`t-1`), and one with the
/// same text before an unsigned number (`t0`). With the dash, `t-1` and `t-2` come before
/// `t0`, in that order; as signs, -2 would come first. Names with dashes only (`frame-1`,
/// `frame-2`) are not taken for signs.
fn sign_read_as_dash(names: &[String]) -> Option<(String, String)> {
    for name in names {
        let s = name.as_bytes();
        for i in 1..s.len().saturating_sub(1) {
            if !(matches!(s[i], b'-' | b'+') && s[i - 1].is_ascii_alphabetic() && s[i + 1].is_ascii_digit()) {
                continue;
            }
            let unsigned = |other: &&String| {
                let o = other.as_bytes();
                o.starts_with(&s[..i]) && o.get(i).is_some_and(u8::is_ascii_digit)
            };
            if let Some(other) = names.iter().find(unsigned) {
                return Some((name.clone(), other.clone()));
            }
        }
    }
    None
}

/// Warns, once for all cameras, of the series of images whose names may hold a sign that
/// [`natural_order`] reads as a dash ([`sign_read_as_dash`]): their time order may be wrong.
fn warn_of_signs_read_as_dashes(series: &[(&str, Vec<PathBuf>)], images: &Path) {
    let mut cameras = Vec::new();
    let mut example = None;
    for (camera, files) in series {
        let names: Vec<String> =
            files.iter().filter_map(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned()).collect();
        if let Some((signed, unsigned)) = sign_read_as_dash(&names) {
            cameras.push(*camera);
            let instant = |n: &String| names.iter().position(|m| m == n).unwrap_or_default();
            example.get_or_insert((camera, instant(&signed), signed, instant(&unsigned), unsigned));
        }
    }
    let Some((camera, k, signed, l, unsigned)) = example else { return };
    let sign = signed.bytes().find(|&c| c == b'-' || c == b'+').map_or('-', char::from);
    log::warn!(
        "camera(s) {}: images are named both `{signed}` and `{unsigned}` (in {}): a `{sign}` between a letter and a \
         number is read as a dash, not as a {} sign, so the numbers after it are ordered as if unsigned \
         (`{signed}` is instant {k}, `{unsigned}` instant {l}); if it is a sign, rename the images with a separator \
         before it (`t_-1.png` is read as -1)",
        cameras.join(", "),
        images.join(camera).display(),
        if sign == '-' { "minus" } else { "plus" }
    );
}

/// The images, videos and folders in `images` that no camera uses. A folder that holds used
/// images (a COLMAP model's `cam1/0001.png`) is looked into instead of counted whole, and paths
/// are compared as the files they name (a model's `../images/a.png` or absolute path is the
/// image it names).
fn unused_entries(images: &Path, used: &BTreeSet<PathBuf>) -> anyhow::Result<Vec<PathBuf>> {
    fn canonical(p: &Path) -> PathBuf {
        p.canonicalize().unwrap_or_else(|_| p.to_path_buf())
    }
    fn walk(
        dir: &Path,
        used: &BTreeSet<PathBuf>,
        visited: &mut BTreeSet<PathBuf>,
        out: &mut Vec<PathBuf>,
    ) -> anyhow::Result<()> {
        // A link back up the tree is looked into once.
        if !visited.insert(canonical(dir)) {
            return Ok(());
        }
        for p in list_dir(dir)? {
            let c = canonical(&p);
            if used.contains(&c) {
                continue;
            }
            if p.is_dir() {
                if used.iter().any(|u| u.starts_with(&c)) {
                    walk(&p, used, visited, out)?;
                } else {
                    out.push(p);
                }
            } else if is_image(&p) || (p.is_file() && fluidnerf_io::video::is_video(&p)) {
                out.push(p);
            }
        }
        Ok(())
    }
    let used: BTreeSet<PathBuf> = used.iter().map(|p| canonical(p)).collect();
    let mut out = Vec::new();
    walk(images, &used, &mut BTreeSet::new(), &mut out)?;
    Ok(out)
}

/// Frames for OpenCV cameras matched to images by name, and the image entries used. The
/// cameras' time series must line up ([`check_series`]), a camera with a single image cannot
/// join cameras recorded over time (a folder of images or a video), and series of images cannot
/// join videos (their instants are counted, the videos' frames timed in seconds).
fn match_opencv(cameras: &[(String, Camera)], images: &Path) -> anyhow::Result<(Vec<Frame>, BTreeSet<PathBuf>)> {
    let mut frames = Vec::new();
    let mut used = BTreeSet::new();
    let mut unmatched = Vec::new();
    // The cameras recorded over time (a series of images or a video), and those with a single
    // image.
    let mut timed: Vec<&str> = Vec::new();
    let mut stills: Vec<(&str, PathBuf)> = Vec::new();
    let mut videos: Vec<&str> = Vec::new();
    // Each series of images, with its camera, and what its folders hold that is no image.
    let mut series: Vec<(&str, Vec<PathBuf>)> = Vec::new();
    let mut folders_named_like_images = Vec::new();
    let by_stem = entries_by_stem(images)?;
    for (name, cam) in cameras {
        let folder = under(images, name).map_err(|e| anyhow::anyhow!("camera {name}: {e}"))?;
        let named: &[PathBuf] = by_stem.get(name.as_str()).map_or(&[], Vec::as_slice);
        let found: Vec<&PathBuf> = named.iter().filter(|p| p.is_file()).collect();
        let not_files: Vec<String> = named.iter().filter(|p| !p.is_file()).map(|p| p.display().to_string()).collect();
        if folder.is_dir() {
            if !found.is_empty() {
                bail!(
                    "camera {name} matches several inputs: the folder {} and {}; keep one",
                    folder.display(),
                    found.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
                );
            }
            let entries = list_dir(&folder)?;
            folders_named_like_images.extend(entries.iter().filter(|p| p.is_dir() && named_like_image(p)).cloned());
            let files: Vec<PathBuf> = entries.into_iter().filter(|p| is_image(p)).collect();
            if files.is_empty() {
                unmatched.push(format!("{name} (the folder {} holds no images)", folder.display()));
            }
            for (t, p) in files.iter().enumerate() {
                frames.push(Frame {
                    camera: cam.clone(),
                    file_path: p.clone(),
                    time: Some(t as f64),
                    camera_name: Some(name.clone()),
                    holdout: false,
                });
            }
            timed.push(name);
            series.push((name, files));
            used.insert(folder);
            continue;
        }
        match found.as_slice() {
            [one] => {
                if fluidnerf_io::video::is_video(one) {
                    timed.push(name);
                    videos.push(name);
                } else {
                    stills.push((name, (*one).clone()));
                }
                used.insert((*one).clone());
                frames.push(Frame {
                    camera: cam.clone(),
                    file_path: (*one).clone(),
                    time: None,
                    camera_name: Some(name.clone()),
                    holdout: false,
                });
            }
            [] if !not_files.is_empty() => {
                unmatched.push(format!("{name} ({} is not a file)", not_files.join(", ")));
            }
            [] => unmatched.push(format!(
                "{name} (no {name}.png, .jpg, .tif, .im7, a video {name}.avi/.mp4/.mov/.cine/.mraw or folder {name}/)"
            )),
            several => bail!(
                "camera {name} matches several images: {}",
                several.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
            ),
        }
    }
    if !unmatched.is_empty() {
        bail!("no image found in {} for camera(s): {}", images.display(), unmatched.join("; "));
    }
    if !folders_named_like_images.is_empty() {
        bail!(
            "{}: folder(s) named like images in the cameras' series folders; a camera's folder holds its images, \
             one per instant, and a folder among them would leave its series an instant short: move or rename it",
            folders_named_like_images.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        );
    }
    if !stills.is_empty() && !timed.is_empty() {
        bail!(
            "camera(s) {} have a single image ({}) while camera(s) {} are recorded over time (a folder of images or \
             a video): a single image belongs to no instant of theirs; give each such camera a folder \
             {}/NAME/ holding one image per instant, or import the cameras of one instant only",
            stills.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
            stills.iter().map(|(_, p)| p.display().to_string()).collect::<Vec<_>>().join(", "),
            timed.join(", "),
            images.display()
        );
    }
    if !series.is_empty() && !videos.is_empty() {
        bail!(
            "camera(s) {} are series of images, whose n-th image is instant n, and camera(s) {} are videos, whose \
             frames are timed in seconds: their frames cannot be matched instant by instant; record every camera \
             the same way (the videos' frames as folders of images, one per instant under the same names, or the \
             series as videos), or import the two kinds separately",
            series.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
            videos.join(", ")
        );
    }
    check_series(&series, images)?;
    warn_of_signs_read_as_dashes(&series, images);
    Ok((frames, used))
}

/// The calibration options with their paths, given or not.
fn calibrations(args: &Args) -> [(&'static str, &Option<PathBuf>); 5] {
    [
        ("--opencv", &args.opencv),
        ("--colmap", &args.colmap),
        ("--metashape", &args.metashape),
        ("--projection", &args.projection),
        ("--transforms", &args.transforms),
    ]
}

/// What an imported scene that does not validate says first: the calibration it came from
/// (the check that follows names the frame in the `transforms.json` it was checked as, which
/// the failed import then removes).
fn invalid_scene(args: &Args) -> String {
    let from = calibrations(args)
        .into_iter()
        .find_map(|(flag, path)| path.as_ref().map(|p| format!(" from {} ({flag})", p.display())))
        .unwrap_or_default();
    format!(
        "the scene imported{from} is invalid (checked as the transforms.json below, not kept){}",
        projection_hint(args)
    )
}

/// For projection matrices read with v counting down: a matrix whose v counts up from the
/// bottom is a mirror image, whose camera faces away from the scene.
fn projection_hint(args: &Args) -> &'static str {
    if args.projection.is_some() && !args.bottom_left_origin {
        " (if the projection matrices count v up from the image's bottom edge, as DLTdv and Easy-WAND write \
         them, each camera faces away from the scene: pass --bottom-left-origin)"
    } else {
        ""
    }
}

/// The entries of `images` named like an image or a video, by stem: where [`match_opencv`]
/// looks for camera NAME's `NAME.*`. Extensions in any case (cameras write `.JPG`).
fn entries_by_stem(images: &Path) -> anyhow::Result<HashMap<String, Vec<PathBuf>>> {
    let mut by_stem: HashMap<String, Vec<PathBuf>> = HashMap::new();
    for p in list_dir(images)? {
        if !(named_like_image(&p) || fluidnerf_io::video::is_video(&p)) {
            continue;
        }
        if let Some(stem) = p.file_stem().and_then(|s| s.to_str()) {
            by_stem.entry(stem.to_string()).or_default().push(p);
        }
    }
    Ok(by_stem)
}

/// The size of camera `name`'s images: of its image `IMAGES/NAME.*`, of the first image of its
/// folder `IMAGES/NAME/`, or of its video's first frame, as [`match_opencv`] finds them; None
/// when it has none (which `match_opencv` then reports with the other cameras').
fn image_size_of(
    name: &str,
    images: &Path,
    by_stem: &HashMap<String, Vec<PathBuf>>,
) -> anyhow::Result<Option<(u32, u32)>> {
    let folder = under(images, name).map_err(|e| anyhow::anyhow!("camera {name}: {e}"))?;
    let first = if folder.is_dir() {
        list_dir(&folder)?.into_iter().find(|p| is_image(p))
    } else {
        by_stem.get(name).and_then(|named| named.iter().find(|p| p.is_file())).cloned()
    };
    let Some(file) = first else { return Ok(None) };
    if fluidnerf_io::video::is_video(&file) {
        let opts = fluidnerf_io::video::VideoOptions { end: Some(1), ..Default::default() };
        let video = fluidnerf_io::video::read_video(&file, &opts)
            .with_context(|| format!("camera {name}: cannot read its video's first frame for the image size"))?;
        let f = &video.frames[0];
        return Ok(Some((f.width as u32, f.height as u32)));
    }
    let size = fluidnerf_io::image::read_dimensions(&file).with_context(|| format!("camera {name}: its image size"))?;
    Ok(Some(size))
}

/// The cameras of projection matrices, each for the size of its images (a matrix has none);
/// with `bottom_left_origin`, v counted up from the bottom is turned round first.
fn projection_cameras(
    read: &[fluidnerf_io::calib::ProjectionCamera],
    images: &Path,
    bottom_left_origin: bool,
) -> anyhow::Result<Vec<(String, Camera)>> {
    let by_stem = entries_by_stem(images)?;
    let mut cameras = Vec::new();
    let mut missing = Vec::new();
    for p in read {
        let Some((width, height)) = image_size_of(&p.name, images, &by_stem)? else {
            missing.push(p.name.as_str());
            continue;
        };
        let cam = p.camera(width, height, bottom_left_origin)?;
        let k = &cam.intrinsics;
        if let Some(why) = fluidnerf_io::calib::principal_point_outside(k) {
            log::warn!("{}: camera `{}`: {why}", p.file.display(), p.name);
        }
        log::info!(
            "{}: camera `{}` ({}): fx {}, fy {}, cx {}, cy {}, skew {}",
            p.file.display(),
            p.name,
            match p.form {
                fluidnerf_io::calib::ProjectionForm::Matrix => "projection matrix",
                fluidnerf_io::calib::ProjectionForm::Dlt => "DLT coefficients",
            },
            fluidnerf_core::num(k.fx),
            fluidnerf_core::num(k.fy),
            fluidnerf_core::num(k.cx),
            fluidnerf_core::num(k.cy),
            fluidnerf_core::num(k.skew)
        );
        cameras.push((p.name.clone(), cam));
    }
    if !missing.is_empty() {
        bail!(
            "no image found in {} for camera(s) {} (no NAME.png, .jpg, .tif, .im7, a video NAME.avi/.mp4/.mov/.cine/.mraw \
             or folder NAME/); a projection matrix gives no image size, so every camera needs its images",
            images.display(),
            missing.join(", ")
        );
    }
    Ok(cameras)
}

/// Most file names listed in an error about series that do not line up.
const NAMES_SHOWN: usize = 5;

/// Checks that the cameras' series of images (each in name order) line up instant by instant:
/// the n-th image of every series is instant n, so every series must hold as many images, and
/// series that share file names (the usual `t000.png`, `t001.png`, … in every camera's folder)
/// must hold the same names. A camera lacking one image would otherwise see every later
/// instant one step early. The error gives each camera's count and, when the names are
/// shared, the names each camera lacks.
fn check_series(series: &[(&str, Vec<PathBuf>)], images: &Path) -> anyhow::Result<()> {
    let names: Vec<BTreeSet<String>> = series
        .iter()
        .map(|(_, files)| {
            files.iter().filter_map(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned()).collect()
        })
        .collect();
    let counts: BTreeSet<usize> = series.iter().map(|(_, files)| files.len()).collect();
    let all: BTreeSet<&String> = names.iter().flatten().collect();
    let shared = all.iter().any(|n| names.iter().filter(|set| set.contains(*n)).count() > 1);
    let same_names = names.windows(2).all(|w| w[0] == w[1]);
    if counts.len() <= 1 && (same_names || !shared) {
        return Ok(());
    }
    let held = by_camera(series.iter().map(|(camera, files)| (*camera, format!("{} image(s)", files.len()))));
    let mut text = format!(
        "the cameras' image series in {} do not line up: the n-th image of each camera's folder (in name order) is \
         instant n, but they hold {} ({})",
        images.display(),
        if counts.len() > 1 { "different numbers of images" } else { "different file names" },
        held.iter().map(|(count, cameras)| format!("{}: {count}", cameras.join(", "))).collect::<Vec<_>>().join("; ")
    );
    if shared {
        let lacking = by_camera(series.iter().zip(&names).filter_map(|((camera, _), own)| {
            let missing: Vec<&str> = all.iter().filter(|n| !own.contains(**n)).map(|n| n.as_str()).collect();
            let shown = missing.iter().take(NAMES_SHOWN).copied().collect::<Vec<_>>().join(", ");
            match missing.len() {
                0 => None,
                n if n > NAMES_SHOWN => Some((*camera, format!("{shown} and {} more", n - NAMES_SHOWN))),
                _ => Some((*camera, shown)),
            }
        }));
        for (missing, cameras) in lacking {
            text += &format!("; {} lack(s) {missing}", cameras.join(", "));
        }
    }
    bail!("{text}; give every camera one image per instant (or remove the instants some camera lacks)")
}

/// `(camera, what)` pairs grouped by what, in order of first appearance: the cameras that hold
/// the same, together.
fn by_camera<'a>(pairs: impl Iterator<Item = (&'a str, String)>) -> Vec<(String, Vec<&'a str>)> {
    let mut groups: Vec<(String, Vec<&'a str>)> = Vec::new();
    for (camera, what) in pairs {
        match groups.iter_mut().find(|(w, _)| *w == what) {
            Some((_, cameras)) => cameras.push(camera),
            None => groups.push((what, vec![camera])),
        }
    }
    groups
}

/// `IMAGES/NAME`, for a NAME that leads to a path under IMAGES (a `..` that comes back in, as
/// in `../images/left/a.png`, is followed): a calibration's image or camera name that is
/// absolute or climbs out (`/etc/passwd`, `../other/cam1.png`) was followed out of the folder
/// given.
fn under(images: &Path, name: &str) -> Result<PathBuf, String> {
    use std::path::Component;
    // The path with `.` and `..` resolved as written, without the file system.
    fn lexical(p: &Path) -> Vec<Component<'_>> {
        let mut out: Vec<Component> = Vec::new();
        for c in p.components() {
            match c {
                Component::CurDir => {}
                Component::ParentDir if matches!(out.last(), Some(Component::Normal(_))) => {
                    out.pop();
                }
                other => out.push(other),
            }
        }
        out
    }
    let joined = images.join(name);
    let (base, path) = (lexical(images), lexical(&joined));
    if path.len() > base.len() && path[..base.len()] == base[..] {
        Ok(joined)
    } else {
        Err(format!(
            "the name {name:?} leads out of the images folder {} (an absolute path, or '..' out of it); names \
             are looked up under it",
            images.display()
        ))
    }
}

/// The image `IMAGES/NAME`, or the one image whose stem is NAME's when that is no file (`a.jpg`
/// finds `a.png`, `IMG_1` finds `IMG_1.tif`); `None` when there is none. Several images of that
/// stem are an error.
fn image_by_name(images: &Path, name: &str) -> Result<Option<PathBuf>, String> {
    let p = under(images, name)?;
    if p.is_file() {
        return Ok(Some(p));
    }
    fluidnerf_io::image::find_image_by_stem(&p)
}

/// Frames for cameras named by their image (COLMAP's image names, Metashape's labels), found
/// by [`image_by_name`], and the image files used; `source` names the file in errors.
fn match_by_name(
    cameras: &[(String, Camera)],
    images: &Path,
    source: &str,
) -> anyhow::Result<(Vec<Frame>, BTreeSet<PathBuf>)> {
    let mut frames = Vec::new();
    let mut used = BTreeSet::new();
    let mut missing = Vec::new();
    for (name, cam) in cameras {
        let p = match image_by_name(images, name) {
            Ok(Some(p)) => p,
            Ok(None) => {
                missing.push(name.clone());
                continue;
            }
            Err(e) => bail!("image {name} of {source}: {e}"),
        };
        used.insert(p.clone());
        frames.push(Frame { camera: cam.clone(), file_path: p, time: None, camera_name: None, holdout: false });
    }
    if !missing.is_empty() {
        bail!(
            "{source} lists image(s) missing from {} (also looked for other extensions): {}",
            images.display(),
            missing.join(", ")
        );
    }
    Ok((frames, used))
}

/// Frames for the enabled, aligned cameras of a Metashape export (by label, as
/// [`match_by_name`]), and the image files used. Cameras the file has not aligned are refused,
/// named, unless `skip_uncalibrated` (their images are then left out as any image without a
/// calibrated camera is); disabled cameras are left out, and their images with them.
fn match_metashape(
    file: &Path,
    read: &fluidnerf_io::calib::MetashapeCameras,
    images: &Path,
    skip_uncalibrated: bool,
) -> anyhow::Result<(Vec<Frame>, BTreeSet<PathBuf>)> {
    if !read.unaligned.is_empty() {
        let (n, list) = (read.unaligned.len(), read.unaligned.join(", "));
        if !skip_uncalibrated {
            bail!(
                "{}: {n} camera(s) have no pose (not aligned in Metashape): {list}; align them, disable them, or \
                 pass --skip-uncalibrated to leave them out",
                file.display()
            );
        }
        log::warn!("{}: left out {n} camera(s) without a pose (not aligned in Metashape): {list}", file.display());
    }
    let (frames, mut used) = match_by_name(&read.cameras, images, &format!("the Metashape file {}", file.display()))?;
    if !read.disabled.is_empty() {
        log::warn!(
            "{}: left out {} disabled camera(s) and their images: {}",
            file.display(),
            read.disabled.len(),
            read.disabled.join(", ")
        );
        // A disabled camera's image is accounted for: not one that no camera is calibrated for.
        used.extend(read.disabled.iter().filter_map(|label| image_by_name(images, label).ok().flatten()));
    }
    Ok((frames, used))
}

#[derive(Serialize)]
struct Settings<'a> {
    command: &'static str,
    version: &'static str,
    #[serde(flatten)]
    args: &'a Args,
    /// How each video was read.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    videos: &'a [VideoRecord],
    /// Which DaVis camera of a recording each calibrated camera is.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    davis_cameras: &'a [davis::CameraRecord],
    /// The cameras' images split from a DaVis recording, relative to OUT.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    davis_frames: &'a [String],
}

/// The box given as `xmin,ymin,zmin,xmax,ymax,zmax`.
fn parse_aabb(text: &str) -> anyhow::Result<Aabb> {
    let a: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--aabb {text}: not a list of numbers"))?;
    ensure!(a.len() == 6, "--aabb takes 6 numbers xmin,ymin,zmin,xmax,ymax,zmax, got {}", a.len());
    let aabb = Aabb { min: DVec3::new(a[0], a[1], a[2]), max: DVec3::new(a[3], a[4], a[5]) };
    aabb.validate().context("--aabb")?;
    Ok(aabb)
}

/// What a source gives besides frames: settings found in a scene file.
#[derive(Default)]
struct FromFile {
    aabb: Option<Aabb>,
    units: Option<String>,
    intensity_scale: Option<f64>,
    linearisation: Option<Linearisation>,
    truth: Vec<TruthRef>,
    /// The preprocessing keys, paths absolute (resolved against the file's folder).
    recording: Option<fluidnerf_io::scene::Recording>,
}

fn aabb_text(a: &Aabb) -> String {
    let v = |p: DVec3| format!("{:.4},{:.4},{:.4}", p.x, p.y, p.z);
    format!("{},{}", v(a.min), v(a.max))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // clap's `requires` lets a flag through when the argument it requires is absent but another
    // of its group is given: --bottom-left-origin was ignored with --opencv or --transforms.
    if args.bottom_left_origin && args.projection.is_none() {
        anyhow::bail!(
            "--bottom-left-origin flips the v of --projection's matrices; the other calibrations state \
             their own pixel convention: leave it out"
        );
    }
    let mut created = Created::default();
    let result = import(&args, &mut created);
    if result.is_err() {
        created.undo();
    }
    result
}

/// The name a frame goes by for --holdout: its camera's, else its image's stem.
fn frame_name(f: &Frame) -> Option<String> {
    f.camera_name.clone().or_else(|| f.file_path.file_stem().map(|s| s.to_string_lossy().into_owned()))
}

/// The `import.json` an earlier import wrote into `out`, if there is one it can read.
fn earlier_import(out: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(out.join("import.json")).ok()?;
    let record = serde_json::from_str::<serde_json::Value>(&text).ok()?;
    (record["command"] == "import").then_some(record)
}

/// The frames an earlier import into `out` decoded from videos, by camera, as its `import.json`
/// records them (`frames/<camera>/000000.tif` onwards). Empty when there is no such record.
fn earlier_video_frames(out: &Path) -> Vec<(String, usize)> {
    let Some(record) = earlier_import(out) else { return Vec::new() };
    let videos = record["videos"].as_array().map(Vec::as_slice).unwrap_or_default();
    videos
        .iter()
        .filter_map(|v| Some((v["camera"].as_str()?.to_owned(), usize::try_from(v["frames_kept"].as_u64()?).ok()?)))
        // Only plain names: anything else did not come from an import.
        .filter(|(name, _)| {
            let mut parts = Path::new(name).components();
            matches!((parts.next(), parts.next()), (Some(std::path::Component::Normal(_)), None))
        })
        .collect()
}

/// The frames an earlier import decoded (`earlier`) that this import does not write again,
/// relative to OUT: the rest of a longer selection, or a camera that has no video now. Left
/// behind, they would sit beside the new frames in `frames/<camera>/` as if they belonged to
/// the scene.
fn stale_video_frames(earlier: &[(String, usize)], videos: &[VideoRecord]) -> Vec<PathBuf> {
    let mut stale = Vec::new();
    for (camera, count) in earlier {
        let kept = videos.iter().find(|v| &v.camera == camera).map_or(0, |v| v.info.frames_kept);
        let dir = Path::new("frames").join(camera);
        stale.extend((kept..*count).map(|i| dir.join(format!("{i:06}.tif"))));
    }
    stale
}

/// The cameras' images an earlier import into `out` split from a DaVis recording, as its
/// `import.json` records them (`frames/<camera>/<name>.png|tif`). Empty without such a record.
fn earlier_davis_frames(out: &Path) -> Vec<PathBuf> {
    let Some(record) = earlier_import(out) else { return Vec::new() };
    let listed = record["davis_frames"].as_array().map(Vec::as_slice).unwrap_or_default();
    listed
        .iter()
        .filter_map(|v| v.as_str())
        .map(PathBuf::from)
        // Only what a split writes: anything else did not come from an import.
        .filter(|p| {
            use std::path::Component::Normal;
            let parts: Vec<_> = p.components().collect();
            matches!(parts.as_slice(), [Normal(f), Normal(_), Normal(_)] if *f == "frames")
                && p.extension().is_some_and(|e| e == "png" || e == "tif")
        })
        .collect()
}

/// The files `scene` reads, images, masks, background frames and flat fields, as canonical
/// paths.
fn referenced_files(scene: &Scene, recording: &fluidnerf_io::scene::Recording) -> HashSet<PathBuf> {
    let images = scene.frames.iter().map(|f| scene.resolve(&f.file_path));
    let masks = recording.frames.iter().filter_map(|r| r.mask_path.as_ref()).map(|m| scene.resolve(m));
    let flats = recording.frames.iter().flat_map(|r| &r.flat_field).map(|p| scene.resolve(p));
    let backgrounds = recording
        .frames
        .iter()
        .filter_map(|r| match &r.background {
            fluidnerf_io::scene::Background::Frames(list) => Some(list),
            _ => None,
        })
        .flatten()
        .map(|p| scene.resolve(p));
    images.chain(masks).chain(flats).chain(backgrounds).filter_map(|p| p.canonicalize().ok()).collect()
}

fn is_referenced(path: &Path, referenced: &HashSet<PathBuf>) -> bool {
    path.canonicalize().is_ok_and(|p| referenced.contains(&p))
}

/// The import; what it creates in OUT is recorded in `created`.
fn import(args: &Args, created: &mut Created) -> anyhow::Result<()> {
    refuse_other_kind(&args.out, FolderKind::Scene, "import")?;
    // One import into a folder at a time; a folder still to be made is locked once made.
    if args.out.is_dir() {
        created.lock(&args.out)?;
    }
    // Before the earlier scene is looked at: an import stopped while putting its scene into
    // place is finished first, and what one stopped earlier left is removed.
    settle_staging(&args.out, true)?;
    let calibrations = calibrations(args);
    let given =
        calibrations.into_iter().chain([("--images", &args.images)]).filter_map(|(o, p)| Some((o, p.as_deref()?)));
    super::recordable("import.json", given.chain([("--out", args.out.as_path())]))?;
    let given_aabb = args.aabb.as_deref().map(parse_aabb).transpose()?;
    if let Some(scale) = args.intensity_scale {
        ensure!(
            scale > 0.0 && scale.is_finite(),
            "--intensity-scale must be a positive number (pixel value per unit of ∫E ds), got {}",
            fluidnerf_core::num(scale)
        );
    }
    let (start, end) = args.video_frames.as_deref().map(parse_frame_range).transpose()?.unwrap_or((0, None));
    if let Some(images) = &args.images {
        ensure!(
            images.is_dir(),
            "--images {}: {}",
            images.display(),
            if images.exists() { "not a folder; give the folder that holds the images" } else { "no such folder" }
        );
    }
    let out_file = args.out.join(SCENE_FILE);
    let written = [out_file.clone(), args.out.join("import.json")];
    // A calibration imported into its own folder (`--transforms OUT/transforms.json -o OUT
    // --force`) was replaced by the scene made from it.
    for (option, input) in calibrations.iter().filter_map(|(o, p)| Some((o, p.as_deref()?))) {
        if let Some(written) = written.iter().find(|w| fluidnerf_pipeline::rundir::same_path(w, input)) {
            bail!(
                "{option} {}: is the file {} that the import writes; an input is never overwritten, even with \
                 --force: import into another folder",
                input.display(),
                written.display()
            );
        }
    }
    if let Some(p) = written.iter().find(|p| p.exists() && !args.force) {
        bail!("{} already exists; pass --force to overwrite it", p.display());
    }
    // Read before it is replaced: the frames an earlier import decoded that this one does not
    // write again are removed once this one has succeeded.
    let earlier_frames = earlier_video_frames(&args.out);
    let earlier_davis = earlier_davis_frames(&args.out);
    // A DaVis recording given as --images, split into the cameras' images once OUT exists.
    let mut davis_recording: Option<davis::Recording> = None;

    let (frames, mut from_file) = if let Some(path) = &args.transforms {
        let draft = read_scene_draft(path).context("cannot read the transforms.json")?;
        let root = draft.root.clone();
        let frames: Vec<Frame> = draft
            .frames
            .into_iter()
            .map(|mut f| {
                f.file_path = if f.file_path.is_absolute() { f.file_path } else { root.join(&f.file_path) };
                f
            })
            .collect();
        let file = fluidnerf_io::scene::scene_file_path(path);
        ensure!(!frames.is_empty(), "{}: lists no frames (its `frames` is empty): nothing to import", file.display());
        // An input the file names that is not there: refused here with its entry and file, not
        // later as a path that cannot be resolved.
        let missing = |what: String, path: &Path| {
            anyhow::anyhow!(
                "{}: {what} {} does not exist (`file_path` {:?}, relative to the file's folder)",
                file.display(),
                path.display(),
                path.strip_prefix(&root).unwrap_or(path).display()
            )
        };
        if let Some((i, f)) = frames.iter().enumerate().find(|(_, f)| !f.file_path.exists()) {
            return Err(missing(format!("frame {i}'s image"), &f.file_path));
        }
        let truth: Vec<TruthRef> =
            draft.truth.into_iter().map(|t| TruthRef { time: t.time, file_path: root.join(&t.file_path) }).collect();
        // A missing one would be written with a path that no longer resolves from OUT.
        if let Some((i, t)) = truth.iter().enumerate().find(|(_, t)| !t.file_path.exists()) {
            return Err(missing(format!("truth entry {i}'s volume"), &t.file_path));
        }
        let mut recording = draft.recording.clone();
        for r in &mut recording.frames {
            if let fluidnerf_io::scene::Background::Frames(list) = &mut r.background {
                list.iter_mut().filter(|p| !p.is_absolute()).for_each(|p| *p = root.join(&*p));
            }
            if let Some(m) = &mut r.mask_path {
                if !m.is_absolute() {
                    *m = root.join(&*m);
                }
            }
            r.flat_field.iter_mut().filter(|p| !p.is_absolute()).for_each(|p| *p = root.join(&*p));
        }
        // Named here with the frame and the key, not later as a path that cannot be resolved.
        for (i, r) in recording.frames.iter().enumerate() {
            if let Some(m) = r.mask_path.as_ref().filter(|m| !m.exists()) {
                bail!("{}: frame {i}'s `mask_path` {} does not exist", file.display(), m.display());
            }
            if let fluidnerf_io::scene::Background::Frames(list) = &r.background {
                if let Some(b) = list.iter().find(|b| !b.exists()) {
                    bail!("{}: frame {i}'s `background` image {} does not exist", file.display(), b.display());
                }
            }
            if let Some(f) = r.flat_field.iter().find(|f| !f.exists()) {
                bail!("{}: frame {i}'s `flat_field` image {} does not exist", file.display(), f.display());
            }
        }
        let file = FromFile {
            recording: Some(recording),
            aabb: draft.aabb,
            units: Some(draft.units),
            intensity_scale: Some(draft.intensity_scale),
            linearisation: Some(draft.linearisation),
            truth,
        };
        (frames, file)
    } else {
        let Some(images) = &args.images else {
            bail!("--opencv, --projection, --colmap and --metashape need --images")
        };
        let mut units = None;
        let (frames, used) = if let Some(path) = &args.opencv {
            let cams = fluidnerf_io::calib::read_opencv(path).context("cannot read the OpenCV calibration")?;
            match davis::recording(&cams, images, &list_dir(images)?, args.skip_uncalibrated)? {
                Some((recording, frames)) => {
                    let used = recording.files.iter().cloned().collect();
                    davis_recording = Some(recording);
                    (frames, used)
                }
                None => match_opencv(&cams, images)?,
            }
        } else if let Some(path) = &args.projection {
            let read = fluidnerf_io::calib::read_projection(path).context("cannot read the projection matrices")?;
            let cams = projection_cameras(&read, images, args.bottom_left_origin)?;
            match_opencv(&cams, images)?
        } else if let Some(dir) = &args.colmap {
            let cams = fluidnerf_io::calib::read_colmap(dir).context("cannot read the COLMAP model")?;
            match_by_name(&cams, images, "the COLMAP model")?
        } else if let Some(file) = &args.metashape {
            let read = fluidnerf_io::calib::read_metashape(file).context("cannot read the Metashape cameras")?;
            units = read.units;
            if units.is_none() {
                log::warn!(
                    "{}: the chunk has no transform: the cameras stand in Metashape's internal frame, whose scale \
                     is arbitrary (scale the chunk with scale bars or markers in Metashape to measure in metres)",
                    file.display()
                );
            }
            match_metashape(file, &read, images, args.skip_uncalibrated)?
        } else {
            bail!("give --transforms, --opencv, --projection, --colmap or --metashape");
        };
        let extra: Vec<String> = unused_entries(images, &used)?.iter().map(|p| p.display().to_string()).collect();
        if !extra.is_empty() {
            if args.skip_uncalibrated {
                log::warn!("left out {} image(s) without a calibrated camera: {}", extra.len(), extra.join(", "));
            } else {
                bail!(
                    "no calibrated camera for {} entr(ies) of {}: {} (pass --skip-uncalibrated to leave them out)",
                    extra.len(),
                    images.display(),
                    extra.join(", ")
                );
            }
        }
        (frames, FromFile { units: units.map(String::from), ..FromFile::default() })
    };
    ensure!(!frames.is_empty(), "no frames to import");
    // Checked before anything is written (a video's frames go by its camera's name).
    let names: BTreeSet<String> = frames.iter().filter_map(frame_name).collect();
    super::given_once("--holdout", &args.holdout)?;
    if let Some(h) = args.holdout.iter().find(|h| !names.contains(*h)) {
        bail!(
            "--holdout: no camera or image named `{h}` (cameras: {})",
            names.into_iter().collect::<Vec<_>>().join(", ")
        );
    }
    let held_out = |f: &Frame| f.holdout || frame_name(f).is_some_and(|n| args.holdout.contains(&n));
    if !args.holdout.is_empty() && frames.iter().all(held_out) {
        bail!("--holdout: every frame would be held out, leaving none to reconstruct from; keep at least one camera");
    }

    // A truth volume (.npy) fills its scene's box: placed in another box it would stand where
    // the flow is not, and every score against it would be meaningless.
    if let (Some(path), Some(first)) = (&args.transforms, from_file.truth.first()) {
        let file = fluidnerf_io::scene::scene_file_path(path);
        let truth = if from_file.truth.len() == 1 {
            first.file_path.display().to_string()
        } else {
            format!("{} and {} more", first.file_path.display(), from_file.truth.len() - 1)
        };
        match (from_file.aabb, given_aabb) {
            (Some(own), Some(given)) if own != given => bail!(
                "--aabb {}: the truth volume(s) of {} ({truth}) fill its box {}; in another box they would stand in \
                 the wrong place: leave --aabb out, or remove the truth entries from the file",
                aabb_text(&given),
                file.display(),
                aabb_text(&own)
            ),
            (None, None) => bail!(
                "{} has truth volume(s) ({truth}) but no `aabb`: a truth volume fills the scene's box, which an \
                 estimate from the images would not be; give the box the truth fills with --aabb",
                file.display()
            ),
            _ => {}
        }
    }
    created.dir_all(&args.out)?;
    created.lock(&args.out)?;
    let out_abs = args.out.canonicalize().with_context(|| format!("cannot resolve {}", args.out.display()))?;
    let staging = out_abs.join(STAGING);
    created.staging(&staging)?;
    let video_opts = fluidnerf_io::video::VideoOptions {
        range: args.video_range,
        start,
        end,
        every: args.video_every as usize,
        time_offset_s: args.video_time_offset,
        linearisation: args.linearisation.or(from_file.linearisation).unwrap_or_default(),
    };
    let mut frames = frames;
    let davis_frames = match &davis_recording {
        Some(recording) => davis::split(recording, &mut frames, &out_abs, &staging, args.force)?,
        None => Vec::new(),
    };
    let (frames, videos, sources) = expand_videos(frames, &out_abs, &staging, &video_opts, args.force)?;
    // The file's masks, backgrounds and flat fields follow its frames into the decoded video
    // frames.
    if let Some(r) = &mut from_file.recording {
        r.frames = sources.iter().map(|&k| r.frames[k].clone()).collect();
    }
    // The video options given, as given, so that the warning names each one.
    let video_flags: Vec<String> = [
        args.video_frames.as_ref().map(|r| format!("--video-frames {r}")),
        (args.video_every != 1).then(|| format!("--video-every {}", args.video_every)),
        (args.video_time_offset != 0.0)
            .then(|| format!("--video-time-offset {}", fluidnerf_core::num(args.video_time_offset))),
        (args.video_range != fluidnerf_io::video::VideoRange::Auto)
            .then(|| format!("--video-range {}", args.video_range)),
    ]
    .into_iter()
    .flatten()
    .collect();
    if videos.is_empty() && !video_flags.is_empty() {
        log::warn!(
            "{} {} no effect: no camera's recording is a video file (the images are stills or series of images, \
             whose frames are all imported with the times they have)",
            video_flags.join(", "),
            if video_flags.len() == 1 { "has" } else { "have" }
        );
    }
    let relative = |p: &Path| -> anyhow::Result<PathBuf> {
        let abs = p.canonicalize().with_context(|| format!("cannot resolve {}", p.display()))?;
        Ok(abs.strip_prefix(&out_abs).map(Path::to_path_buf).unwrap_or(abs))
    };
    let units_defaulted = args.units.is_none() && from_file.units.is_none();
    let mut scene = Scene {
        root: out_abs.clone(),
        // Replaced below; reading the images does not use the box.
        aabb: Aabb::cube(DVec3::ZERO, 1.0),
        units: args.units.clone().or(from_file.units.clone()).unwrap_or_else(|| "mm".into()),
        intensity_scale: args.intensity_scale.or(from_file.intensity_scale).unwrap_or(1.0),
        frames,
        truth: from_file.truth,
    };
    for f in &mut scene.frames {
        f.file_path = relative(&f.file_path)?;
    }
    for f in &mut scene.frames {
        if frame_name(f).is_some_and(|n| args.holdout.contains(&n)) {
            f.holdout = true;
        }
    }
    let mut recording = match from_file.recording.take() {
        Some(mut r) => {
            assert_eq!(r.frames.len(), scene.frames.len(), "one recording entry per frame");
            for fr in &mut r.frames {
                if let fluidnerf_io::scene::Background::Frames(list) = &mut fr.background {
                    for p in list.iter_mut() {
                        *p = relative(p)?;
                    }
                }
                if let Some(m) = &mut fr.mask_path {
                    *m = relative(m)?;
                }
                for p in fr.flat_field.iter_mut() {
                    *p = relative(p)?;
                }
            }
            r
        }
        None => fluidnerf_io::scene::Recording::plain(scene.frames.len()),
    };
    for t in &mut scene.truth {
        if t.file_path.exists() {
            t.file_path = relative(&t.file_path)?;
        }
    }
    let known_aabb = given_aabb.or(from_file.aabb);
    if let Some(aabb) = known_aabb {
        // Geometry first: a box no camera sees is the likelier mistake than an image.
        scene.aabb = aabb;
        validate_scene(&scene, &out_file).with_context(|| invalid_scene(args))?;
    }
    let linearisation = args.linearisation.or(from_file.linearisation).unwrap_or_default();
    let images = load_images_with(&scene, linearisation).context("the images do not fit the calibration")?;
    recording.linearisation = linearisation;
    // The masks, backgrounds and flat fields a transforms.json brings must fit the images too,
    // or the scene written would be refused by every command that reads it.
    if recording.preprocesses() {
        load_preprocessed_with(&scene, recording.clone())
            .context("the masks, backgrounds or flat fields do not fit the images")?;
    }
    let first = scene.resolve(&scene.frames[0].file_path);
    if args.linearisation.is_none() && linearisation == Linearisation::Linear {
        if let Ok((_, SampleKind::Integer(8))) = read_image_with(&first, linearisation) {
            log::warn!(
                "8-bit images are read as linear counts; if they are ordinary camera images (JPEG, sRGB PNG) \
                 pass --linearisation srgb"
            );
        }
    }
    // Only 8-bit images (and video frames, as they are decoded) are linearised; the images'
    // kinds agree, so the first one's tells.
    if let Some(given) = args.linearisation.filter(|l| *l != Linearisation::Linear && videos.is_empty()) {
        if let Ok((_, kind)) = read_image_with(&first, linearisation) {
            if kind != SampleKind::Integer(8) {
                log::warn!(
                    "--linearisation {given} has no effect: the images are {kind}, and only 8-bit images (and \
                     video frames) are linearised; images of more bits are read as linear"
                );
            }
        }
    }
    if known_aabb.is_none() {
        scene.aabb = {
            let est = estimate_box(&scene.frames, &images, &BoxEstimateParams::default()).with_context(|| {
                format!("cannot estimate a box: no point is seen by every camera; give --aabb{}", projection_hint(args))
            })?;
            let how = if est.from_bright_pixels {
                "the bright pixels seen by every camera"
            } else {
                log::warn!("no point is bright in every image; the box bounds the cameras' common view");
                "the cameras' common view"
            };
            let line = format!(
                "estimated the box from {how}: --aabb {} (size {:.4} x {:.4} x {:.4} {})\n",
                aabb_text(&est.aabb),
                est.aabb.size().x,
                est.aabb.size().y,
                est.aabb.size().z,
                scene.units
            );
            std::io::stdout().lock().write_all(line.as_bytes())?;
            est.aabb
        };
        validate_scene(&scene, &out_file).with_context(|| invalid_scene(args))?;
    }
    for found in fluidnerf_io::scene::cameras_at_one_place(&scene) {
        log::warn!("{}", fluidnerf_io::scene::describe_one_place(&scene, &found));
    }
    if units_defaulted {
        if let Some(d) = near_cameras(&scene) {
            log::warn!(
                "the cameras stand {} mm from the box's centre (the median), far nearer than cameras stand to a \
                 flow: is the calibration in metres? The scene's lengths are the calibration's, taken as mm unless \
                 --units says otherwise (--units m)",
                fluidnerf_core::num(d)
            );
        }
    }
    // The staged frames are named by where they go in OUT.
    let mut moves: Vec<PathBuf> = Vec::new();
    for f in &mut scene.frames {
        if let Ok(rel) = f.file_path.strip_prefix(STAGING) {
            f.file_path = rel.to_path_buf();
            moves.push(f.file_path.clone());
        }
    }
    // What the earlier import wrote that the new scene neither reads nor replaces.
    let referenced = referenced_files(&scene, &recording);
    let removals: Vec<PathBuf> = stale_video_frames(&earlier_frames, &videos)
        .into_iter()
        .chain(earlier_davis)
        .filter(|rel| !moves.contains(rel) && !is_referenced(&out_abs.join(rel), &referenced))
        .collect();
    save_scene_recording(&scene, &staging, &recording, true)?;
    let davis_cameras = davis_recording.map(|r| r.record).unwrap_or_default();
    let settings = Settings {
        command: "import",
        version: env!("CARGO_PKG_VERSION"),
        args,
        videos: &videos,
        davis_cameras: &davis_cameras,
        davis_frames: &davis_frames,
    };
    let json = serde_json::to_string_pretty(&settings)?;
    fluidnerf_io::atomic_write(&staging.join("import.json"), |w| w.write_all(json.as_bytes()))?;
    moves.extend([PathBuf::from(SCENE_FILE), PathBuf::from("import.json")]);
    commit(&out_abs, &staging, &Commit { moves, removals }, created)?;

    let cameras: BTreeSet<String> = scene
        .frames
        .iter()
        .map(|f| f.camera_name.clone().unwrap_or_else(|| f.file_path.display().to_string()))
        .collect();
    let line = format!(
        "imported {} frames of {} cameras into {} (check it with `fluidnerf info {}`)\n",
        scene.frames.len(),
        cameras.len(),
        out_file.display(),
        args.out.display()
    );
    std::io::stdout().lock().write_all(line.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::path::{Path, PathBuf};

    use super::{natural_order, settle_staging, sign_read_as_dash, Commit, COMMIT_RECORD, STAGING};

    #[test]
    fn numbers_in_names_are_ordered_as_numbers() {
        let mut names = vec!["img_10.png", "img_2.png", "img_1.png", "img_11.png", "img_02.png", "b1", "a10", "a9"];
        names.sort_by(|a, b| natural_order(a, b));
        assert_eq!(names, ["a9", "a10", "b1", "img_1.png", "img_02.png", "img_2.png", "img_10.png", "img_11.png"]);
        // Zero-padded names keep their text order; long numbers do not overflow.
        let padded = ["B00001.im7", "B00002.im7", "B00010.im7"];
        assert!(padded.windows(2).all(|w| natural_order(w[0], w[1]).is_lt()));
        assert!(natural_order("t99999999999999999999999", "t100000000000000000000000").is_lt());
    }

    fn write(path: &Path, text: &str) {
        std::fs::create_dir_all(path.parent().expect("a folder")).expect("mkdir");
        std::fs::write(path, text).expect("writes");
    }

    fn read(path: &Path) -> String {
        std::fs::read_to_string(path).expect("reads")
    }

    fn sorted<'a>(names: &[&'a str]) -> Vec<&'a str> {
        let mut names = names.to_vec();
        names.sort_by(|a, b| natural_order(a, b));
        names
    }

    #[test]
    fn a_number_with_a_decimal_fraction_is_ordered_as_a_decimal() {
        let want = ["t_0.75ms", "t_1ms", "t_1.25ms", "t_1.5ms", "t_1.5ms_b", "t_2ms", "t_10.0ms", "t_10.05ms"];
        let mut given = want.to_vec();
        given.reverse();
        assert_eq!(sorted(&given), want);
        // Equal values are ordered by their text.
        assert_eq!(sorted(&["t_1.50", "t_01.5", "t_1.5"]), ["t_01.5", "t_1.5", "t_1.50"]);
        // Only one `digits.digits` is a decimal: dotted counters and versions compare their
        // numbers one by one.
        assert_eq!(sorted(&["img.010.png", "img.9.png", "img.001.png"]), ["img.001.png", "img.9.png", "img.010.png"]);
        assert_eq!(sorted(&["v1.10.0", "v1.2.3", "v1.2.10", "v10.0.0"]), ["v1.2.3", "v1.2.10", "v1.10.0", "v10.0.0"]);
    }

    #[test]
    fn a_sign_after_a_separator_is_a_sign_and_after_a_letter_a_dash() {
        let want = ["t_-2", "t_-1.5", "t_-1", "t_0", "t_+0.5", "t_1", "t_2"];
        let mut given = want.to_vec();
        given.reverse();
        assert_eq!(sorted(&given), want);
        assert_eq!(sorted(&["1.png", "-1.png", "0.png"]), ["-1.png", "0.png", "1.png"]);
        // After a letter or a digit: a dash (`cam-1`, dates).
        assert_eq!(sorted(&["cam-2", "cam-10", "cam-1"]), ["cam-1", "cam-2", "cam-10"]);
        assert_eq!(sorted(&["2024-01-06", "2024-01-05", "2023-12-31"]), ["2023-12-31", "2024-01-05", "2024-01-06"]);
    }

    /// Names a sort puts in one order whatever pairs it compares (`sort_by` needs a total
    /// order): numbers with and without signs, decimals, and the characters around them.
    #[test]
    fn the_order_is_total() {
        let names = [
            "t_+2", "t_,", "t_1", "t_-1", "t_.", "t_-", "t_-x", "t_0", "t_1.5", "t_1.5.2", "t_01", "t_", "t", "t_/",
            "t-1", "t1", "t+1", "t_+", "t_-0", "t_0.0",
        ];
        for a in names {
            assert!(natural_order(a, a).is_eq());
            for b in names {
                assert_eq!(natural_order(a, b), natural_order(b, a).reverse(), "{a} {b}");
                for c in names {
                    if natural_order(a, b).is_lt() && natural_order(b, c).is_lt() {
                        assert!(natural_order(a, c).is_lt(), "{a} < {b} < {c}");
                    }
                }
            }
        }
    }

    #[test]
    fn a_dash_that_may_be_a_minus_sign_is_found() {
        let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            sign_read_as_dash(&names(&["t-1.png", "t-2.png", "t0.png"])),
            Some(("t-1.png".into(), "t0.png".into()))
        );
        assert_eq!(sign_read_as_dash(&names(&["t+1.png", "t2.png"])), Some(("t+1.png".into(), "t2.png".into())));
        assert_eq!(sign_read_as_dash(&names(&["frame-1.png", "frame-2.png"])), None);
        assert_eq!(sign_read_as_dash(&names(&["t_-1.png", "t_0.png", "2024-01-05.png", "2024-01-06.png"])), None);
    }

    /// An import killed while it put its files into place (one frame moved, the rest and the
    /// scene files not) is finished from its record: the new scene whole, the earlier import's
    /// frame it does not read removed, the staging folder gone.
    #[test]
    fn an_import_killed_while_putting_its_files_into_place_is_finished() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path();
        let staging = out.join(STAGING);
        write(&out.join("transforms.json"), "earlier scene");
        write(&out.join("frames/cam0/000000.tif"), "earlier 0");
        write(&out.join("frames/cam0/000001.tif"), "new 1");
        write(&out.join("frames/cam0/000002.tif"), "earlier 2");
        write(&out.join("frames/cam0/notes.txt"), "mine");
        write(&staging.join("frames/cam0/000000.tif"), "new 0");
        write(&staging.join("transforms.json"), "new scene");
        write(&staging.join("import.json"), "new record");
        let commit = Commit {
            moves: ["frames/cam0/000000.tif", "frames/cam0/000001.tif", "transforms.json", "import.json"]
                .map(PathBuf::from)
                .to_vec(),
            removals: vec![PathBuf::from("frames/cam0/000002.tif")],
        };
        write(&staging.join(COMMIT_RECORD), &serde_json::to_string(&commit).expect("json"));
        settle_staging(out, false).expect("settles");
        assert_eq!(read(&out.join("transforms.json")), "new scene");
        assert_eq!(read(&out.join("import.json")), "new record");
        assert_eq!(read(&out.join("frames/cam0/000000.tif")), "new 0");
        assert_eq!(read(&out.join("frames/cam0/000001.tif")), "new 1");
        assert!(!out.join("frames/cam0/000002.tif").exists());
        assert_eq!(read(&out.join("frames/cam0/notes.txt")), "mine");
        assert!(!staging.exists());
    }

    /// What an import killed before its scene was complete left is removed before an import,
    /// and left alone by `info` (it may be an import under way); the earlier scene is not
    /// touched. A record that names paths outside the folder is refused, not followed.
    #[test]
    fn an_import_killed_before_its_scene_was_complete_is_removed() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path();
        let staging = out.join(STAGING);
        write(&out.join("transforms.json"), "earlier scene");
        write(&staging.join("frames/cam0/000000.tif"), "new 0");
        settle_staging(out, false).expect("settles");
        assert!(staging.join("frames/cam0/000000.tif").exists(), "left for the import under way");
        settle_staging(out, true).expect("settles");
        assert!(!staging.exists());
        assert_eq!(read(&out.join("transforms.json")), "earlier scene");

        write(&staging.join(COMMIT_RECORD), r#"{"moves": ["../elsewhere"], "removals": []}"#);
        let e = settle_staging(out, true).expect_err("refused").to_string();
        assert!(e.contains(COMMIT_RECORD) && e.contains("not the record of an import"), "{e}");
        assert!(staging.join(COMMIT_RECORD).exists());
    }
}
