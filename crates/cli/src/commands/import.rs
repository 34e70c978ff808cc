//! `fluidnerf import`: builds a scene (`transforms.json`) from an OpenCV or COLMAP calibration
//! and a folder of images.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context};
use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Camera, Frame, Scene};
use fluidnerf_io::scene::{load_images, save_scene, validate_scene, SCENE_FILE};
use serde::Serialize;

/// Build a scene from an OpenCV or COLMAP calibration and a folder of images.
///
/// OpenCV (`--opencv`): a `cv::FileStorage` YAML/JSON file or a folder of them, with
/// `camera_matrix`, `distortion_coefficients`, `rvec`/`tvec` or `R`/`T` (world to camera) and
/// `image_width`/`image_height`; several cameras in one file use keys suffixed `_<name>`, a
/// single-camera file names its camera after the file stem. Camera NAME takes the image
/// `IMAGES/NAME.png` (or `.tif`/`.tiff`), or, for a time series, every image in the folder
/// `IMAGES/NAME/` in name order, the n-th image getting time n (edit the times in
/// `transforms.json` if they are physical).
///
/// COLMAP (`--colmap`): a text model (`cameras.txt`, `images.txt`); each image of
/// `images.txt` is looked up as `IMAGES/NAME`. COLMAP's pixel centres (+0.5) are converted.
///
/// Every calibrated camera must find its image(s), and every image in IMAGES must belong to a
/// camera (unless --skip-uncalibrated). The scene is validated (each camera must see the box,
/// image sizes must match the calibration, no NaN/Inf pixels) before `OUT/transforms.json` is
/// written, together with `OUT/import.json` (the settings of this run). Image paths are
/// written relative to OUT when IMAGES is inside OUT, absolute otherwise.
#[derive(clap::Args, Debug, Serialize)]
pub struct Args {
    /// OpenCV calibration: a `.yml`/`.yaml`/`.json` file or a folder of them.
    #[arg(long, conflicts_with = "colmap", required_unless_present = "colmap")]
    pub opencv: Option<PathBuf>,
    /// COLMAP text model folder (holding `cameras.txt` and `images.txt`).
    #[arg(long)]
    pub colmap: Option<PathBuf>,
    /// Folder with the images.
    #[arg(long)]
    pub images: PathBuf,
    /// Reconstruction box in world units: xmin,ymin,zmin,xmax,ymax,zmax (e.g.
    /// `-10,-10,-10,10,10,10`).
    #[arg(long, allow_hyphen_values = true)]
    pub aabb: String,
    /// Length unit of the calibration's world frame.
    #[arg(long, default_value = "mm")]
    pub units: String,
    /// Pixel value = intensity_scale × ∫E ds (world units).
    #[arg(long, default_value_t = 1.0)]
    pub intensity_scale: f64,
    /// Output scene folder (created if missing).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Overwrite an existing `transforms.json` in OUT.
    #[arg(long)]
    pub force: bool,
    /// Leave out images that no camera is calibrated for (with a warning) instead of failing.
    #[arg(long)]
    pub skip_uncalibrated: bool,
}

fn is_image(p: &Path) -> bool {
    p.is_file()
        && p.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| ["png", "tif", "tiff"].contains(&e.to_ascii_lowercase().as_str()))
}

fn list_dir(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot list the image folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    v.sort();
    Ok(v)
}

/// Frames for OpenCV cameras matched to images by name, and the image entries used.
fn match_opencv(cameras: &[(String, Camera)], images: &Path) -> anyhow::Result<(Vec<Frame>, BTreeSet<PathBuf>)> {
    let mut frames = Vec::new();
    let mut used = BTreeSet::new();
    let mut unmatched = Vec::new();
    for (name, cam) in cameras {
        let folder = images.join(name);
        if folder.is_dir() {
            let series: Vec<PathBuf> = list_dir(&folder)?.into_iter().filter(|p| is_image(p)).collect();
            if series.is_empty() {
                unmatched.push(format!("{name} (the folder {} holds no images)", folder.display()));
            }
            for (t, p) in series.into_iter().enumerate() {
                frames.push(Frame {
                    camera: cam.clone(),
                    file_path: p,
                    time: Some(t as f64),
                    camera_name: Some(name.clone()),
                    holdout: false,
                });
            }
            used.insert(folder);
            continue;
        }
        let candidates: Vec<PathBuf> =
            ["png", "tif", "tiff"].iter().map(|e| images.join(format!("{name}.{e}"))).collect();
        let found: Vec<&PathBuf> = candidates.iter().filter(|p| p.is_file()).collect();
        match found.as_slice() {
            [one] => {
                used.insert((*one).clone());
                frames.push(Frame {
                    camera: cam.clone(),
                    file_path: (*one).clone(),
                    time: None,
                    camera_name: Some(name.clone()),
                    holdout: false,
                });
            }
            [] => unmatched.push(format!("{name} (no {name}.png, {name}.tif, {name}.tiff or folder {name}/)")),
            several => bail!(
                "camera {name} matches several images: {}",
                several.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
            ),
        }
    }
    if !unmatched.is_empty() {
        bail!("no image found in {} for camera(s): {}", images.display(), unmatched.join("; "));
    }
    Ok((frames, used))
}

/// Frames for COLMAP images, and the image files used.
fn match_colmap(cameras: &[(String, Camera)], images: &Path) -> anyhow::Result<(Vec<Frame>, BTreeSet<PathBuf>)> {
    let mut frames = Vec::new();
    let mut used = BTreeSet::new();
    let mut missing = Vec::new();
    for (name, cam) in cameras {
        let p = images.join(name);
        if !p.is_file() {
            missing.push(name.clone());
            continue;
        }
        used.insert(p.clone());
        frames.push(Frame { camera: cam.clone(), file_path: p, time: None, camera_name: None, holdout: false });
    }
    if !missing.is_empty() {
        bail!("images.txt lists image(s) missing from {}: {}", images.display(), missing.join(", "));
    }
    Ok((frames, used))
}

#[derive(Serialize)]
struct Settings<'a> {
    command: &'static str,
    version: &'static str,
    #[serde(flatten)]
    args: &'a Args,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let a: Vec<f64> = args
        .aabb
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--aabb {}: not a list of numbers", args.aabb))?;
    ensure!(a.len() == 6, "--aabb takes 6 numbers xmin,ymin,zmin,xmax,ymax,zmax, got {}", a.len());
    let aabb = Aabb { min: DVec3::new(a[0], a[1], a[2]), max: DVec3::new(a[3], a[4], a[5]) };
    aabb.validate().context("--aabb")?;
    ensure!(args.images.is_dir(), "the image folder {} does not exist", args.images.display());
    let out_file = args.out.join(SCENE_FILE);
    if out_file.exists() && !args.force {
        bail!("{} already exists; pass --force to overwrite it", out_file.display());
    }

    let (frames, used) = if let Some(path) = &args.opencv {
        let cams = fluidnerf_io::calib::read_opencv(path).context("cannot read the OpenCV calibration")?;
        match_opencv(&cams, &args.images)?
    } else if let Some(dir) = &args.colmap {
        let cams = fluidnerf_io::calib::read_colmap(dir).context("cannot read the COLMAP model")?;
        match_colmap(&cams, &args.images)?
    } else {
        bail!("give --opencv or --colmap");
    };
    let extra: Vec<String> = list_dir(&args.images)?
        .into_iter()
        .filter(|p| (is_image(p) || p.is_dir()) && !used.contains(p))
        .map(|p| p.display().to_string())
        .collect();
    if !extra.is_empty() {
        if args.skip_uncalibrated {
            log::warn!("left out {} image(s) without a calibrated camera: {}", extra.len(), extra.join(", "));
        } else {
            bail!(
                "no calibrated camera for {} entr(ies) of {}: {} (pass --skip-uncalibrated to leave them out)",
                extra.len(),
                args.images.display(),
                extra.join(", ")
            );
        }
    }

    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let out_abs = args.out.canonicalize().with_context(|| format!("cannot resolve {}", args.out.display()))?;
    let mut scene = Scene {
        root: out_abs.clone(),
        aabb,
        units: args.units.clone(),
        intensity_scale: args.intensity_scale,
        frames,
        truth: vec![],
    };
    for f in &mut scene.frames {
        let abs = f.file_path.canonicalize().with_context(|| format!("cannot resolve {}", f.file_path.display()))?;
        f.file_path = abs.strip_prefix(&out_abs).map(Path::to_path_buf).unwrap_or(abs);
    }
    validate_scene(&scene, &out_file).context("the imported scene is invalid")?;
    load_images(&scene).context("the images do not fit the calibration")?;
    save_scene(&scene, &args.out)?;
    let settings = Settings { command: "import", version: env!("CARGO_PKG_VERSION"), args: &args };
    let json = serde_json::to_string_pretty(&settings)?;
    fluidnerf_io::atomic_write(&args.out.join("import.json"), |w| w.write_all(json.as_bytes()))?;

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
    use std::io::Write as _;
    std::io::stdout().lock().write_all(line.as_bytes())?;
    Ok(())
}
