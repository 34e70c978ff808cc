//! The native scene format: nerfstudio's `transforms.json` with fluidnerf's additions.
//!
//! # The file
//! ```json
//! {
//!   "camera_model": "OPENCV",
//!   "w": 64, "h": 48, "fl_x": 80.0, "fl_y": 80.0, "cx": 32.0, "cy": 24.0,
//!   "k1": -0.05, "k2": 0.0, "k3": 0.0, "p1": 0.0, "p2": 0.0,
//!   "aabb": [[-10, -10, -10], [10, 10, 10]],
//!   "units": "mm",
//!   "intensity_scale": 1.0,
//!   "truth": [{"time": 0.0, "file_path": "truth/t0.npy"}],
//!   "frames": [
//!     {"file_path": "images/cam0_t0.png", "transform_matrix": [[...4...], ...],
//!      "time": 0.0, "camera": "cam0", "holdout": false,
//!      "thin_lens": {"focal_length": 60, "aperture_diameter": 17.1,
//!                    "magnification": -0.2, "pixel_pitch": 0.01}}
//!   ]
//! }
//! ```
//!
//! - **Intrinsics** (`camera_model w h fl_x fl_y cx cy k1 k2 k3 k4 p1 p2`) may sit at the top
//!   level (shared) or in a frame; a key in a frame overrides the same key at the top level.
//!   As instant-ngp and Blender's NeRF exporters write them: `camera_angle_x`/`camera_angle_y`
//!   (field of view in radians) stand in for a missing `fl_x`/`fl_y`
//!   (`fl = size / (2 tan(angle / 2))`; with `camera_angle_x` alone the pixels are square); when
//!   both are given and disagree by more than 0.1 %, the focal length is used, with a warning;
//!   `w`/`h` may be whole floats (`605.0`) or absent (then read from the image's header);
//!   a missing `cx`/`cy` is the image centre (`w/2`, `h/2` in the file's convention).
//!   `camera_model` may be `PINHOLE`, `SIMPLE_PINHOLE`, `OPENCV`, `SIMPLE_RADIAL`, `RADIAL` or
//!   `FULL_OPENCV` (all read through the same OpenCV model; missing coefficients are 0).
//!   Fisheye and panoramic models are rejected.
//! - **Pixel centres**: nerfstudio generates the ray of pixel `(col, row)` through image
//!   coordinates `(col + 0.5, row + 0.5)` (`Cameras.get_image_coords(pixel_offset=0.5)`, then
//!   `((x − cx) / fx, −(y − cy) / fy, −1)` in OpenGL camera axes), so its `cx, cy` are measured
//!   from the top-left *corner* of the image. fluidnerf (OpenCV) puts pixel centres at integer
//!   coordinates, so on reading `cx_core = cx − 0.5`, `cy_core = cy − 0.5`, and on writing the
//!   reverse. The test `nerfstudio_rays_land_on_our_pixels` proves the two agree.
//! - **k4**: nerfstudio's `k4` is an r⁸ term of a polynomial radial model, which OpenCV's model
//!   does not have: a non-zero `k4` is rejected. OpenCV's rational coefficients (the
//!   denominator `1 + k4 r² + k5 r⁴ + k6 r⁶`) are fluidnerf's keys `opencv_k4`, `opencv_k5`,
//!   `opencv_k6`, and the pixel skew (`K[0][1]`) is the key `skew`; all default to 0.
//! - **Pose**: `transform_matrix` is nerfstudio's 4 × 4 camera-to-world matrix (rows) in
//!   OpenGL camera axes (x right, y up, z backward). fluidnerf's cameras use OpenCV axes, so
//!   `R_cv = R_gl · diag(1, −1, −1)` (negate the second and third columns); the translation
//!   (camera centre) is unchanged.
//! - **fluidnerf's additions**: `aabb` (world units, sides from 10⁻⁶ to 10⁹
//!   ([`fluidnerf_core::geometry::MIN_SIDE`], [`fluidnerf_core::geometry::MAX_SIDE`]); required
//!   by [`load_scene`], which says how to supply it; [`read_scene_draft`] reads files without
//!   one), `units` (default `"mm"`),
//!   `intensity_scale` (default 1: pixel value = intensity_scale × ∫E ds), `linearisation`
//!   (how 8-bit images become linear: `"linear"` (default), `"srgb"` or a gamma; see
//!   [`crate::image`]), `truth` (optional list of `{time, file_path}` `.npy` volumes filling the
//!   aabb); per frame `time` (on every frame of a time-resolved scene, on none of a static
//!   one), `camera` (a physical camera's name), `holdout` (default false) and `thin_lens`
//!   ([`ThinLens`] fields, world units).
//! - Keys fluidnerf does not read are reported in at most two log lines per file, however many
//!   frames hold them: the ones NeRF tools write routinely (`aabb_scale`, `colmap_im_id`,
//!   `applied_transform`, ...) at info level, others as a warning.
//! - Errors name the key path (`frames[3].transform_matrix[1]`) and the frame and its image.
//! - Paths are relative to the folder holding `transforms.json` unless absolute. A path that
//!   names no file, next to exactly one image with the same stem (`train/r_0` →
//!   `train/r_0.png`), reads that image.
//!
//! # Writing
//! [`save_scene`] writes the intrinsics once at the top level when every frame has the same
//! intrinsics and distortion, and otherwise a full set in every frame (never a mix). Values are
//! written with Rust's shortest round-trip float formatting, so reading a written file gives
//! the same scene exactly, except `cx, cy`, which pass through `± 0.5` and may differ in the
//! last bit.

use std::path::{Path, PathBuf};

use fluidnerf_core::glam::{DAffine3, DMat3, DVec3};
use fluidnerf_core::num;
use fluidnerf_core::scene::same_time;
use fluidnerf_core::{
    Aabb, Camera, CoreError, Distortion, Frame, Image, Intrinsics, Scene, ThinLens, TruthRef, Volume,
};
use rayon::prelude::*;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::folder::{folder_kind, FolderKind};
use crate::image::{Linearisation, SampleKind};
use crate::{atomic_write, IoError};

/// The file name of a scene inside its folder.
pub const SCENE_FILE: &str = "transforms.json";

/// Default of `units` when a scene file has none.
pub const DEFAULT_UNITS: &str = "mm";

const MODELS: [&str; 6] = ["PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "SIMPLE_RADIAL", "RADIAL", "FULL_OPENCV"];

const INTRINSIC_KEYS: [&str; 19] = [
    "camera_model",
    "w",
    "h",
    "fl_x",
    "fl_y",
    "camera_angle_x",
    "camera_angle_y",
    "cx",
    "cy",
    "skew",
    "k1",
    "k2",
    "k3",
    "k4",
    "p1",
    "p2",
    "opencv_k4",
    "opencv_k5",
    "opencv_k6",
];
const TOP_KEYS: [&str; 9] =
    ["frames", "aabb", "units", "intensity_scale", "truth", "linearisation", "background", "flat_field", "flow_axis"];
const FRAME_KEYS: [&str; 9] = [
    "file_path",
    "transform_matrix",
    "time",
    "camera",
    "holdout",
    "thin_lens",
    "background",
    "flat_field",
    "mask_path",
];
const TRUTH_KEYS: [&str; 2] = ["time", "file_path"];

/// Keys that nerfstudio (`ns-process-data`), instant-ngp and the Blender/NeRF-synthetic
/// exporters write routinely and fluidnerf does not use: reported in one line at info level.
const ROUTINE_KEYS: [&str; 16] = [
    "aabb_scale",
    "scale",
    "offset",
    "ply_file_path",
    "applied_transform",
    "applied_scale",
    "orientation_override",
    "integer_depth_scale",
    "enable_depth_loading",
    "is_fisheye",
    "colmap_im_id",
    "depth_file_path",
    "depth_path",
    "sharpness",
    "rotation",
    "original_file_path",
];

/// The intrinsics keys, as they appear at the top level or in a frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
struct IntrinsicKeys {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera_model: Option<String>,
    /// Pixels; tools write `605.0` as readily as `605`.
    #[serde(default, deserialize_with = "pixel_count", skip_serializing_if = "Option::is_none")]
    w: Option<u32>,
    #[serde(default, deserialize_with = "pixel_count", skip_serializing_if = "Option::is_none")]
    h: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fl_x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fl_y: Option<f64>,
    /// Horizontal field of view in radians (Blender, instant-ngp): `fl_x = w / (2 tan(a / 2))`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera_angle_x: Option<f64>,
    /// Vertical field of view in radians: `fl_y = h / (2 tan(a / 2))`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    camera_angle_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cy: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    skew: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k3: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    k4: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    p1: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    p2: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    opencv_k4: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    opencv_k5: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    opencv_k6: Option<f64>,
}

impl IntrinsicKeys {
    /// Per-key override: `self` (a frame) wins over `global`.
    fn over(&self, global: &IntrinsicKeys) -> IntrinsicKeys {
        IntrinsicKeys {
            camera_model: self.camera_model.clone().or_else(|| global.camera_model.clone()),
            w: self.w.or(global.w),
            h: self.h.or(global.h),
            fl_x: self.fl_x.or(global.fl_x),
            fl_y: self.fl_y.or(global.fl_y),
            camera_angle_x: self.camera_angle_x.or(global.camera_angle_x),
            camera_angle_y: self.camera_angle_y.or(global.camera_angle_y),
            cx: self.cx.or(global.cx),
            cy: self.cy.or(global.cy),
            skew: self.skew.or(global.skew),
            k1: self.k1.or(global.k1),
            k2: self.k2.or(global.k2),
            k3: self.k3.or(global.k3),
            k4: self.k4.or(global.k4),
            p1: self.p1.or(global.p1),
            p2: self.p2.or(global.p2),
            opencv_k4: self.opencv_k4.or(global.opencv_k4),
            opencv_k5: self.opencv_k5.or(global.opencv_k5),
            opencv_k6: self.opencv_k6.or(global.opencv_k6),
        }
    }

    /// The keys for a camera, converting the principal point to nerfstudio's convention.
    fn from_camera(intrinsics: &Intrinsics, distortion: &Distortion) -> IntrinsicKeys {
        let nz = |v: f64| (v != 0.0).then_some(v);
        let distorted = !distortion.is_identity();
        let some_if_distorted = |v: f64| distorted.then_some(v);
        IntrinsicKeys {
            camera_model: Some(if distorted { "OPENCV" } else { "PINHOLE" }.to_string()),
            w: Some(intrinsics.width),
            h: Some(intrinsics.height),
            fl_x: Some(intrinsics.fx),
            fl_y: Some(intrinsics.fy),
            camera_angle_x: None,
            camera_angle_y: None,
            cx: Some(intrinsics.cx + 0.5),
            cy: Some(intrinsics.cy + 0.5),
            skew: nz(intrinsics.skew),
            k1: some_if_distorted(distortion.k1),
            k2: some_if_distorted(distortion.k2),
            k3: some_if_distorted(distortion.k3),
            k4: None,
            p1: some_if_distorted(distortion.p1),
            p2: some_if_distorted(distortion.p2),
            opencv_k4: nz(distortion.k4),
            opencv_k5: nz(distortion.k5),
            opencv_k6: nz(distortion.k6),
        }
    }
}

/// `w`/`h`: a positive whole number, written as an integer or a float (`605.0`).
fn pixel_count<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<u32>, D::Error> {
    match Option::<f64>::deserialize(d)? {
        None => Ok(None),
        Some(v) if v.fract() == 0.0 && (1.0..=f64::from(u32::MAX)).contains(&v) => Ok(Some(v as u32)),
        Some(v) => Err(serde::de::Error::custom(format!("expected a positive whole number of pixels, got {}", num(v)))),
    }
}

#[derive(Debug, Serialize, Deserialize)]
struct TruthEntry {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    time: Option<f64>,
    file_path: String,
}

/// A frame as written.
#[derive(Debug, Serialize)]
struct FrameEntry {
    file_path: String,
    transform_matrix: [[f64; 4]; 4],
    #[serde(skip_serializing_if = "Option::is_none")]
    time: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    camera: Option<String>,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    holdout: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    thin_lens: Option<ThinLens>,
    #[serde(skip_serializing_if = "Option::is_none")]
    background: Option<BackgroundKey>,
    #[serde(skip_serializing_if = "Option::is_none")]
    flat_field: Option<FlatFieldKey>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mask_path: Option<String>,
    #[serde(flatten)]
    intrinsics: IntrinsicKeys,
}

/// The file as written.
#[derive(Debug, Serialize)]
struct TransformsFile {
    #[serde(flatten)]
    intrinsics: IntrinsicKeys,
    aabb: [[f64; 3]; 2],
    #[serde(skip_serializing_if = "Option::is_none")]
    units: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    intensity_scale: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    linearisation: Option<Linearisation>,
    #[serde(skip_serializing_if = "Option::is_none")]
    flow_axis: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    truth: Vec<TruthEntry>,
    frames: Vec<FrameEntry>,
}

/// A frame as read, without its intrinsics (read separately from the same object, so that
/// every key keeps its path in error messages; serde's `flatten` loses it).
#[derive(Debug, Deserialize)]
struct FrameIn {
    file_path: String,
    transform_matrix: [[f64; 4]; 4],
    #[serde(default)]
    time: Option<f64>,
    #[serde(default)]
    camera: Option<String>,
    #[serde(default)]
    holdout: bool,
    #[serde(default)]
    thin_lens: Option<ThinLens>,
    #[serde(default)]
    background: Option<BackgroundKey>,
    #[serde(default)]
    flat_field: Option<FlatFieldKey>,
    #[serde(default)]
    mask_path: Option<String>,
}

/// The top level as read, without its intrinsics.
#[derive(Debug, Deserialize)]
struct TopIn {
    #[serde(default)]
    aabb: Option<[[f64; 3]; 2]>,
    #[serde(default)]
    units: Option<String>,
    #[serde(default)]
    intensity_scale: Option<f64>,
    #[serde(default)]
    linearisation: Option<Linearisation>,
    #[serde(default)]
    truth: Vec<TruthEntry>,
    #[serde(default)]
    background: Option<BackgroundKey>,
    #[serde(default)]
    flat_field: Option<FlatFieldKey>,
    #[serde(default)]
    flow_axis: Option<[f64; 3]>,
    frames: Vec<Value>,
}

/// `background` as written: a constant, or the images whose pixelwise median is subtracted (a
/// list, or one path alone).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "a number of counts, an image's path or a list of images' paths")]
enum BackgroundKey {
    Constant(f64),
    Frames(Vec<String>),
    Frame(String),
}

/// `flat_field` as written: the flat-field images whose pixelwise median is the flat (a list,
/// or one path alone).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, expecting = "an image's path or a list of images' paths")]
enum FlatFieldKey {
    Frames(Vec<String>),
    Frame(String),
}

impl BackgroundKey {
    /// The background images named (none for a constant).
    fn paths(&self) -> Vec<&str> {
        match self {
            BackgroundKey::Constant(_) => Vec::new(),
            BackgroundKey::Frames(v) => v.iter().map(String::as_str).collect(),
            BackgroundKey::Frame(p) => vec![p.as_str()],
        }
    }
}

impl FlatFieldKey {
    fn paths(&self) -> Vec<&str> {
        match self {
            FlatFieldKey::Frames(v) => v.iter().map(String::as_str).collect(),
            FlatFieldKey::Frame(p) => vec![p.as_str()],
        }
    }
}

/// What is subtracted from a frame's image before reconstruction (key `background`).
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Background {
    /// Nothing.
    #[default]
    None,
    /// A constant (linear units, after the linearisation), e.g. a camera's dark level.
    Constant(f64),
    /// The pixelwise median of these images (background or dark frames of the frame's camera,
    /// relative to the scene folder unless absolute), read like the frame's image.
    Frames(Vec<PathBuf>),
}

impl std::fmt::Display for Background {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Background::None => f.write_str("none"),
            Background::Constant(c) => write!(f, "constant {c}"),
            Background::Frames(v) if v.len() == 1 => f.write_str("one background frame"),
            Background::Frames(v) => write!(f, "median of {} background frames", v.len()),
        }
    }
}

/// How a recording's images are to be read and preprocessed, as its scene file records it:
/// the keys [`Scene`] has no field for.
///
/// - `linearisation` (top level): 8-bit images to linear values ([`Linearisation`]).
/// - `background` (top level or per frame; the frame's wins): a number subtracted from every
///   pixel, or a list of images whose pixelwise median is subtracted. Negative results are
///   clipped to 0 and counted.
/// - `flat_field` (top level or per frame; the frame's wins): the camera's per-pixel
///   sensitivity, one image or a list of images whose pixelwise median is taken (recordings
///   of a uniformly lit target or diffuser). The image is divided by it after the background
///   ([`flat_field_correct`] states the formula).
/// - `mask_path` (per frame, nerfstudio's key): an image of the frame's size; pixels with a
///   non-zero value are used, the others are left out of every method's data.
/// - `flow_axis` (top level): the mean flow direction, a vector in world coordinates
///   (normalised on reading).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recording {
    pub linearisation: Linearisation,
    /// Per frame of the scene, in frame order.
    pub frames: Vec<FrameRecording>,
    pub flow_axis: Option<DVec3>,
}

/// The preprocessing keys of one frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameRecording {
    pub background: Background,
    /// The flat-field images (relative to the scene folder unless absolute) whose pixelwise
    /// median is the flat; empty for none.
    pub flat_field: Vec<PathBuf>,
    /// Relative to the scene folder unless absolute.
    pub mask_path: Option<PathBuf>,
}

impl Recording {
    /// A recording of `frames` frames with nothing to preprocess.
    pub fn plain(frames: usize) -> Self {
        Recording { frames: vec![FrameRecording::default(); frames], ..Default::default() }
    }

    /// One line on what preprocessing the recording asks for, e.g. "background: median of 3
    /// background frames (12 frames); flat field: one flat frame (12 frames); masks: 12
    /// frame(s); 8-bit images: srgb".
    pub fn describe(&self) -> String {
        // Each kind with the number of frames of that kind, in order of first appearance.
        let tally = |kind: &dyn Fn(&FrameRecording) -> String| {
            let mut kinds: Vec<(String, usize)> = Vec::new();
            for f in &self.frames {
                let k = kind(f);
                match kinds.iter_mut().find(|(d, _)| *d == k) {
                    Some((_, n)) => *n += 1,
                    None => kinds.push((k, 1)),
                }
            }
            if kinds.iter().all(|(k, _)| k == "none") {
                "none".to_string()
            } else {
                kinds.iter().map(|(k, n)| format!("{k} ({n} frames)")).collect::<Vec<_>>().join(", ")
            }
        };
        let background = tally(&|f| f.background.to_string());
        let flat = tally(&|f| match f.flat_field.len() {
            0 => "none".to_string(),
            1 => "one flat frame".to_string(),
            n => format!("median of {n} flat frames"),
        });
        let masks = self.frames.iter().filter(|f| f.mask_path.is_some()).count();
        format!(
            "background: {background}; flat field: {flat}; masks: {masks} frame(s); 8-bit images: {}",
            self.linearisation
        )
    }

    /// Whether any frame asks for a background, a flat field or a mask (else the images are
    /// used as read).
    pub fn preprocesses(&self) -> bool {
        self.frames
            .iter()
            .any(|f| f.background != Background::None || !f.flat_field.is_empty() || f.mask_path.is_some())
    }
}

fn flat_field_from_key(key: Option<&FlatFieldKey>) -> Vec<PathBuf> {
    key.map(|k| k.paths().into_iter().map(PathBuf::from).collect()).unwrap_or_default()
}

fn flat_field_to_key(file: &Path, flat: &[PathBuf]) -> Result<Option<FlatFieldKey>, IoError> {
    if flat.is_empty() {
        return Ok(None);
    }
    Ok(Some(FlatFieldKey::Frames(flat.iter().map(|p| path_str(file, p)).collect::<Result<_, _>>()?)))
}

fn background_from_key(key: Option<&BackgroundKey>) -> Background {
    match key {
        None => Background::None,
        Some(BackgroundKey::Constant(c)) => Background::Constant(*c),
        Some(BackgroundKey::Frames(v)) => Background::Frames(v.iter().map(PathBuf::from).collect()),
        Some(BackgroundKey::Frame(p)) => Background::Frames(vec![PathBuf::from(p)]),
    }
}

fn background_to_key(file: &Path, b: &Background) -> Result<Option<BackgroundKey>, IoError> {
    Ok(match b {
        Background::None => None,
        Background::Constant(c) => Some(BackgroundKey::Constant(*c)),
        Background::Frames(v) => {
            Some(BackgroundKey::Frames(v.iter().map(|p| path_str(file, p)).collect::<Result<_, _>>()?))
        }
    })
}

/// Checks the preprocessing keys of a file: finite constants, non-empty background and flat-field
/// lists without blank paths, no frame whose flat field is its own image, a non-zero flow axis.
/// Errors name the key and the frame.
fn check_recording(file: &Path, top: &TopIn, frames: &[(usize, &FrameIn)]) -> Result<(), IoError> {
    let check_bg = |b: &Option<BackgroundKey>, place: &str| match b {
        Some(BackgroundKey::Constant(c)) if !(c.is_finite() && *c >= 0.0) => Err(IoError::invalid(
            file,
            format!("{place}: `background` must be a finite number of counts, at least 0, got {}", num(*c)),
        )),
        Some(BackgroundKey::Frames(v)) if v.is_empty() => Err(IoError::invalid(
            file,
            format!("{place}: `background` is an empty list; give at least one background image or a number"),
        )),
        // A blank path was read as the scene's folder ("image file is a folder").
        Some(key) => match key.paths().into_iter().find(|p| p.trim().is_empty()) {
            Some(p) => Err(IoError::invalid(
                file,
                format!(
                    "{place}: `background` names {p:?}, which is no image; give the background image's path or a \
                     number"
                ),
            )),
            None => Ok(()),
        },
        None => Ok(()),
    };
    let check_flat = |flat: &Option<FlatFieldKey>, place: &str| {
        let Some(flat) = flat else { return Ok(()) };
        let paths = flat.paths();
        if paths.is_empty() {
            return Err(IoError::invalid(
                file,
                format!("{place}: is an empty list; give at least one flat-field image (or leave the key out)"),
            ));
        }
        match paths.iter().position(|p| p.trim().is_empty()) {
            Some(k) => Err(IoError::invalid(
                file,
                format!("{place}: entry {k} is {:?}, which names no image; give the flat-field image's path", paths[k]),
            )),
            None => Ok(()),
        }
    };
    check_bg(&top.background, "top level")?;
    check_flat(&top.flat_field, "top level, key `flat_field`")?;
    for (i, f) in frames {
        check_bg(&f.background, &format!("frame {i} ({})", f.file_path))?;
        let image = normalise(Path::new(&f.file_path));
        // Where the key that applies to the frame was written: its own, or the top level's.
        let key = |own: bool, name: &str| match own {
            true => format!("frame {i} ({}), key `frames[{i}].{name}`", f.file_path),
            false => format!("frame {i} ({}), key `{name}` (top level)", f.file_path),
        };
        // Backgrounds, masks and flat fields are recordings of their own: a frame's own image
        // in their place makes it black (carving everything it sees out of the volume), fully
        // used, or divided by itself to 1.
        let own_image = |paths: Vec<&str>, place: String, why: &str| match paths
            .into_iter()
            .find(|p| normalise(Path::new(p)) == image)
        {
            Some(p) => Err(IoError::invalid(file, format!("{place}: names {p}, the frame's own image; {why}"))),
            None => Ok(()),
        };
        // (Over time, an instant recorded before the flow started may be the later instants'
        // background, and itself rightly dark.)
        if let Some(bg) = f.background.as_ref().or(top.background.as_ref()).filter(|_| f.time.is_none()) {
            own_image(
                bg.paths(),
                key(f.background.is_some(), "background"),
                "a background is a separate recording with the same camera (the empty scene, or dark frames with \
                 the lens capped)",
            )?;
        }
        if let Some(m) = &f.mask_path {
            own_image(
                vec![m.as_str()],
                key(true, "mask_path"),
                "a mask is an image of its own, non-zero where the pixels are used",
            )?;
        }
        check_flat(&f.flat_field, &key(true, "flat_field"))?;
        if let Some(flat) = f.flat_field.as_ref().or(top.flat_field.as_ref()) {
            own_image(
                flat.paths(),
                key(f.flat_field.is_some(), "flat_field"),
                "a flat field is a separate recording of a uniformly lit target (a diffuser or a white screen) with \
                 the same camera and lens",
            )?;
        }
    }
    if let Some(a) = top.flow_axis {
        let v = DVec3::from_array(a);
        if !(v.is_finite() && v != DVec3::ZERO) {
            return Err(IoError::invalid(file, format!("`flow_axis` must be a non-zero finite vector, got {a:?}")));
        }
    }
    Ok(())
}

/// Refuses a scene path that is a regular file not ending in `.json`: it would otherwise be
/// read as a folder (`path/transforms.json`) and fail with the system's "Not a directory".
pub fn check_scene_path(path: &Path) -> Result<(), IoError> {
    if path.is_file() && scene_file_path(path) != path {
        return Err(IoError::invalid(
            path,
            format!(
                "is a file, not a scene folder; give the folder holding {SCENE_FILE}, or the scene file itself \
                 (a name ending in .json)"
            ),
        ));
    }
    if let Some(kind) = folder_kind(path).filter(|k| *k != FolderKind::Scene) {
        let advice = match kind {
            // A run's configuration names the scene it was made from.
            FolderKind::Run => {
                let scene = std::fs::read_to_string(path.join("config.json"))
                    .ok()
                    .and_then(|text| serde_json::from_str::<Value>(&text).ok())
                    .and_then(|v| v.get("scene").and_then(Value::as_str).map(|s| format!(" ({s})")));
                format!("; give the scene it was made from{}", scene.unwrap_or_default())
            }
            FolderKind::Study => "; its scenes are the folders in its scenes/".to_string(),
            FolderKind::Demo => "; its scene is the folder scene/ in it".to_string(),
            _ => String::new(),
        };
        return Err(IoError::invalid(
            path,
            format!("is {}, not a scene folder (it has no {SCENE_FILE}){advice}", kind.name()),
        ));
    }
    Ok(())
}

/// The scene file for `path`: `path` itself if it ends in `.json`, else `path/transforms.json`.
pub fn scene_file_path(path: &Path) -> PathBuf {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        path.to_path_buf()
    } else {
        path.join(SCENE_FILE)
    }
}

/// Deserialises `value` (found at key path `prefix`) into `T`; an error names the full key path
/// (`frames[3].transform_matrix[1]`) and, inside a frame, the frame and its image.
fn typed<T: DeserializeOwned>(file: &Path, value: &Value, prefix: &str, frame: Option<usize>) -> Result<T, IoError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let inner = e.path().to_string();
        let key = match (prefix, inner.as_str()) {
            (p, ".") => p.to_string(),
            ("", i) => i.to_string(),
            (p, i) if i.starts_with('[') => format!("{p}{i}"),
            (p, i) => format!("{p}.{i}"),
        };
        let key = if key.is_empty() { "the top level".to_string() } else { format!("key `{key}`") };
        let location = match frame {
            Some(i) => match value.get("file_path").and_then(Value::as_str) {
                Some(name) => format!("frame {i} ({name}), {key}"),
                None => format!("frame {i}, {key}"),
            },
            None => key,
        };
        IoError::Key { path: file.to_path_buf(), location, problem: e.into_inner().to_string() }
    })
}

/// JSON's name for the kind of a value, for messages.
fn kind_of(v: &Value) -> String {
    match v {
        Value::Null => "null".into(),
        Value::Bool(_) => "a boolean".into(),
        Value::Number(_) => "a number".into(),
        Value::String(_) => "a string".into(),
        Value::Array(a) => format!("an array of {} element(s)", a.len()),
        Value::Object(_) => "an object".into(),
    }
}

/// Keys a file holds that fluidnerf does not read, by key, with where they occur.
#[derive(Default)]
struct KeyReport {
    routine: std::collections::BTreeMap<String, Vec<String>>,
    unknown: std::collections::BTreeMap<String, Vec<String>>,
}

impl KeyReport {
    fn scan(&mut self, value: &Value, known: &[&[&str]], place: &str) {
        let Some(map) = value.as_object() else { return };
        for key in map.keys() {
            if known.iter().any(|set| set.contains(&key.as_str())) {
                continue;
            }
            let bucket = if ROUTINE_KEYS.contains(&key.as_str()) { &mut self.routine } else { &mut self.unknown };
            bucket.entry(key.clone()).or_default().push(place.to_string());
        }
    }

    /// One phrase per key: `"colmap_im_id" (in 120 frames)`, `"ply_file_path" (top level)`.
    fn summary(keys: &std::collections::BTreeMap<String, Vec<String>>) -> String {
        let phrase = |key: &String, places: &Vec<String>| match places.as_slice() {
            [one] => format!("\"{key}\" ({one})"),
            many if many.iter().all(|p| p.starts_with("frame ")) => format!("\"{key}\" (in {} frames)", many.len()),
            many => format!("\"{key}\" ({} places, first {})", many.len(), many[0]),
        };
        keys.iter().map(|(k, p)| phrase(k, p)).collect::<Vec<_>>().join(", ")
    }

    /// Logs at most two lines, however many frames there are.
    fn log(&self, file: &Path) {
        if !self.routine.is_empty() {
            log::info!("{}: not used by fluidnerf: {}", file.display(), Self::summary(&self.routine));
        }
        if !self.unknown.is_empty() {
            log::warn!("{}: ignoring unknown key(s) {}", file.display(), Self::summary(&self.unknown));
        }
    }
}

/// OpenGL camera-to-world rows (nerfstudio `transform_matrix`) → pose with OpenCV camera axes:
/// `R_cv = R_gl · diag(1, −1, −1)`, same translation.
pub fn opengl_c2w_to_world_from_camera(rows: &[[f64; 4]; 4]) -> DAffine3 {
    let col = |j: usize| DVec3::new(rows[0][j], rows[1][j], rows[2][j]);
    DAffine3::from_mat3_translation(DMat3::from_cols(col(0), -col(1), -col(2)), col(3))
}

/// Pose with OpenCV camera axes → OpenGL camera-to-world rows (the inverse of
/// [`opengl_c2w_to_world_from_camera`]).
pub fn world_from_camera_to_opengl_c2w(pose: &DAffine3) -> [[f64; 4]; 4] {
    let m = pose.matrix3;
    let cols = [m.x_axis, -m.y_axis, -m.z_axis, pose.translation];
    let mut rows = [[0.0; 4]; 4];
    for (i, row) in rows.iter_mut().take(3).enumerate() {
        for (j, c) in cols.iter().enumerate() {
            row[j] = c[i];
        }
    }
    rows[3] = [0.0, 0.0, 0.0, 1.0];
    rows
}

fn resolve_in(root: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        root.join(p)
    }
}

/// The camera of frame `index`, and the orthonormality error of its rotation when that was a
/// rotation only up to rounding and the nearest rotation was taken. `image` is the frame's
/// image file (resolved), read for its size only when `w` or `h` is missing.
fn frame_camera(
    file: &Path,
    index: usize,
    entry: &FrameIn,
    keys: &IntrinsicKeys,
    image: &Path,
) -> Result<(Camera, Option<f64>), IoError> {
    let k = keys;
    let name = &entry.file_path;
    let bad = |problem: String| IoError::invalid(file, format!("frame {index} ({name}): {problem}"));
    let need = |v: Option<f64>, key: &str| {
        v.ok_or_else(|| bad(format!("`{key}` is given neither at the top level nor in the frame")))
    };
    let model = k.camera_model.as_deref().unwrap_or("OPENCV");
    if !MODELS.contains(&model) {
        return Err(bad(format!("camera_model {model} is not supported (supported: {})", MODELS.join(", "))));
    }
    let (width, height) = match (k.w, k.h) {
        (Some(w), Some(h)) => (w, h),
        (w, h) => {
            let (iw, ih) = crate::image::read_dimensions(image).map_err(|e| {
                bad(format!(
                    "`w`/`h` are given neither at the top level nor in the frame, and the image's size \
                     cannot be read instead: {e}"
                ))
            })?;
            (w.unwrap_or(iw), h.unwrap_or(ih))
        }
    };
    let from_angle = |angle: Option<f64>, key: &str, size: u32| match angle {
        None => Ok(None),
        Some(a) if a > 0.0 && a < std::f64::consts::PI => Ok(Some(0.5 * f64::from(size) / (0.5 * a).tan())),
        Some(a) => Err(bad(format!("`{key}` must be a field of view in (0, π) radians, got {}", num(a)))),
    };
    let fx = match k.fl_x {
        Some(f) => f,
        None => from_angle(k.camera_angle_x, "camera_angle_x", width)?.ok_or_else(|| {
            bad("neither `fl_x` nor `camera_angle_x` is given at the top level or in the frame".into())
        })?,
    };
    let fy = match (k.fl_y, from_angle(k.camera_angle_y, "camera_angle_y", height)?) {
        (Some(f), _) | (None, Some(f)) => f,
        // Blender and NeRF-synthetic files give only the horizontal angle: square pixels.
        (None, None) if k.fl_x.is_none() => fx,
        (None, None) => need(None, "fl_y")?,
    };
    // Without a principal point, tools (instant-ngp, Blender) put it at the image centre.
    let intrinsics = Intrinsics {
        width,
        height,
        fx,
        fy,
        cx: k.cx.unwrap_or(0.5 * f64::from(width)) - 0.5,
        cy: k.cy.unwrap_or(0.5 * f64::from(height)) - 0.5,
        skew: k.skew.unwrap_or(0.0),
    };
    if k.k4.is_some_and(|v| v != 0.0) {
        return Err(bad(
            "k4 is nerfstudio's r⁸ radial term, which the OpenCV model does not have; use 0 (OpenCV's rational k4 is `opencv_k4`)"
                .into(),
        ));
    }
    let z = |v: Option<f64>| v.unwrap_or(0.0);
    let distortion = Distortion {
        k1: z(k.k1),
        k2: z(k.k2),
        p1: z(k.p1),
        p2: z(k.p2),
        k3: z(k.k3),
        k4: z(k.opencv_k4),
        k5: z(k.opencv_k5),
        k6: z(k.opencv_k6),
    };
    let m = &entry.transform_matrix;
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(bad(format!("transform_matrix's last row must be [0, 0, 0, 1], got {:?}", m[3])));
    }
    // A matrix written with few digits is a rotation only up to their rounding, which the
    // camera's check would refuse: the nearest rotation is taken (and said by the caller).
    let mut world_from_camera = opengl_c2w_to_world_from_camera(m);
    let rounded = fluidnerf_core::camera::rounded_rotation(world_from_camera.matrix3);
    if let Some((nearest, _)) = rounded {
        world_from_camera.matrix3 = nearest;
    }
    let camera = Camera { intrinsics, distortion, world_from_camera, lens: entry.thin_lens };
    camera.validate().map_err(|error| IoError::Camera {
        path: file.to_path_buf(),
        frame: index,
        file_path: PathBuf::from(name),
        error,
    })?;
    Ok((camera, rounded.map(|(_, error)| error)))
}

/// How far (relative) a focal length may lie from the one its field of view gives before
/// [`warn_focal_conflicts`] warns.
const FOCAL_ANGLE_TOLERANCE: f64 = 1e-3;

/// Warns when frame `index` (its own keys `frame`, the top level's `global`) gives both a focal
/// length and a field of view for an axis (`fl_x` and `camera_angle_x`, `fl_y` and
/// `camera_angle_y`) that disagree by more than [`FOCAL_ANGLE_TOLERANCE`]; the focal length is
/// used (`intrinsics`). A conflict at the top level is warned about once (`warned_top`).
fn warn_focal_conflicts(
    file: &Path,
    index: usize,
    name: &str,
    frame: &IntrinsicKeys,
    global: &IntrinsicKeys,
    intrinsics: &Intrinsics,
    warned_top: &mut [bool; 2],
) {
    let axes = [
        (
            "fl_x",
            frame.fl_x,
            global.fl_x,
            "camera_angle_x",
            frame.camera_angle_x,
            global.camera_angle_x,
            "w",
            intrinsics.width,
        ),
        (
            "fl_y",
            frame.fl_y,
            global.fl_y,
            "camera_angle_y",
            frame.camera_angle_y,
            global.camera_angle_y,
            "h",
            intrinsics.height,
        ),
    ];
    for (axis, (fl_key, fl_frame, fl_top, angle_key, angle_frame, angle_top, size_key, size)) in
        axes.into_iter().enumerate()
    {
        let (Some(fl), Some(angle)) = (fl_frame.or(fl_top), angle_frame.or(angle_top)) else { continue };
        if !(angle > 0.0 && angle < std::f64::consts::PI) {
            continue;
        }
        let from_angle = 0.5 * f64::from(size) / (0.5 * angle).tan();
        if (fl - from_angle).abs() <= FOCAL_ANGLE_TOLERANCE * from_angle {
            continue;
        }
        let at_top = fl_frame.is_none() && angle_frame.is_none();
        if at_top && warned_top[axis] {
            continue;
        }
        warned_top[axis] |= at_top;
        let place = if at_top { "top level".to_string() } else { format!("frame {index} ({name})") };
        log::warn!(
            "{}: {place}: `{fl_key}` {fl} and `{angle_key}` {angle} disagree (the angle gives a focal length of \
             {from_angle:.4} px at {size_key} = {size}); using `{fl_key}`",
            file.display()
        );
    }
}

/// A scene file as read, before the checks of [`load_scene`]; its box may be missing (the
/// tools that write `transforms.json` for NeRFs do not write one).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneDraft {
    /// The scene file.
    pub file: PathBuf,
    /// Folder against which relative paths resolve.
    pub root: PathBuf,
    pub aabb: Option<Aabb>,
    pub units: String,
    pub intensity_scale: f64,
    /// How 8-bit images become linear (key `linearisation`, default `linear`).
    pub linearisation: Linearisation,
    pub frames: Vec<Frame>,
    pub truth: Vec<TruthRef>,
    /// The preprocessing keys (`linearisation` again, `background`, `mask_path`, `flow_axis`).
    pub recording: Recording,
}

impl SceneDraft {
    /// The scene with box `aabb` (unchecked; see [`validate_scene`]).
    pub fn into_scene(self, aabb: Aabb) -> Scene {
        Scene {
            root: self.root,
            aabb,
            units: self.units,
            intensity_scale: self.intensity_scale,
            frames: self.frames,
            truth: self.truth,
        }
    }
}

/// The error of a scene without a box: it says how to supply one.
fn missing_aabb(file: &Path) -> IoError {
    IoError::invalid(
        file,
        "no `aabb` (the reconstruction box, which NeRF tools do not write): add \
         `\"aabb\": [[xmin, ymin, zmin], [xmax, ymax, zmax]]` in world units at the top level, or run \
         `fluidnerf import --transforms <this file> -o <folder>` to write a scene with a box given by \
         --aabb or estimated from the images",
    )
}

/// Reads a scene file (or the `transforms.json` in a folder) without the checks of
/// [`load_scene`] beyond each key's type and each camera's validity. Images are opened only
/// when a frame's `w`/`h` are missing (for their size) or its `file_path` names no file (an
/// image with the same stem and another extension is then used: `train/r_0` →
/// `train/r_0.png`).
pub fn read_scene_draft(path: &Path) -> Result<SceneDraft, IoError> {
    check_scene_path(path)?;
    let file = scene_file_path(path);
    let text = crate::read_input_text(&file, "scene file")?;
    let raw: Value = serde_json::from_str(&text).map_err(|error| IoError::json(&file, &text, &error))?;
    if !raw.is_object() {
        return Err(IoError::invalid(
            &file,
            format!(
                "expected a JSON object with `frames` (a list of {{file_path, transform_matrix}}) and the camera \
                 keys, as nerfstudio and instant-ngp write it; found {}",
                kind_of(&raw)
            ),
        ));
    }
    let top: TopIn = typed(&file, &raw, "", None)?;
    let global: IntrinsicKeys = typed(&file, &raw, "", None)?;
    if raw.get("is_fisheye") == Some(&Value::Bool(true)) {
        return Err(IoError::invalid(&file, "is_fisheye is true: fisheye cameras are not supported"));
    }
    let mut report = KeyReport::default();
    report.scan(&raw, &[&TOP_KEYS, &INTRINSIC_KEYS], "top level");
    if let Some(truth) = raw.get("truth").and_then(Value::as_array) {
        for (i, t) in truth.iter().enumerate() {
            report.scan(t, &[&TRUTH_KEYS], &format!("truth {i}"));
        }
    }
    let root = match file.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut frames = Vec::with_capacity(top.frames.len());
    let mut frame_recordings = Vec::with_capacity(top.frames.len());
    let mut renamed: Vec<(String, PathBuf)> = Vec::new();
    // Frames whose rotation was one only up to rounding: how many, the largest error, the first.
    let mut rounded_rotations: Option<(usize, f64, usize)> = None;
    // Frames whose pinhole camera_model comes with distortion coefficients: how many, the
    // first, and its model (said once for the file).
    let mut pinholes_distorted: Option<(usize, usize, String)> = None;
    // Whether the top level's focal lengths and angles were found to disagree (warned once).
    let mut warned_top = [false; 2];
    for (i, value) in top.frames.iter().enumerate() {
        let prefix = format!("frames[{i}]");
        if !value.is_object() {
            return Err(IoError::Key {
                path: file.clone(),
                location: format!("frame {i}, key `{prefix}`"),
                problem: format!("expected an object with file_path and transform_matrix, found {}", kind_of(value)),
            });
        }
        let entry: FrameIn = typed(&file, value, &prefix, Some(i))?;
        // An empty path resolves to the scene's folder, which only reading the images would
        // then find is no image, naming neither the frame nor the key.
        if entry.file_path.trim().is_empty() {
            return Err(IoError::Key {
                path: file.clone(),
                location: format!("frame {i}, key `{prefix}.file_path`"),
                problem: format!("is {:?}, which names no image file; give the frame's image", entry.file_path),
            });
        }
        check_recording(&file, &top, &[(i, &entry)])?;
        frame_recordings.push(FrameRecording {
            background: background_from_key(entry.background.as_ref().or(top.background.as_ref())),
            flat_field: flat_field_from_key(entry.flat_field.as_ref().or(top.flat_field.as_ref())),
            mask_path: entry.mask_path.as_ref().map(PathBuf::from),
        });
        let keys: IntrinsicKeys = typed(&file, value, &prefix, Some(i))?;
        report.scan(value, &[&FRAME_KEYS, &INTRINSIC_KEYS], &format!("frame {i}"));
        let mut file_path = PathBuf::from(&entry.file_path);
        let mut image = resolve_in(&root, &file_path);
        if !image.exists() {
            let found = crate::image::find_image_by_stem(&image)
                .map_err(|e| IoError::invalid(&file, format!("frame {i} ({}): {e}", entry.file_path)))?;
            if let Some(found) = found {
                if let Some(name) = found.file_name() {
                    file_path.set_file_name(name);
                    renamed.push((entry.file_path.clone(), file_path.clone()));
                    image = found;
                }
            }
        }
        if value.get("is_fisheye") == Some(&Value::Bool(true)) {
            return Err(IoError::invalid(
                &file,
                format!("frame {i}: is_fisheye is true: fisheye cameras are not supported"),
            ));
        }
        let merged = keys.over(&global);
        let (camera, rounded) = frame_camera(&file, i, &entry, &merged, &image)?;
        if let Some(model) = merged.camera_model.as_deref().filter(|m| matches!(*m, "PINHOLE" | "SIMPLE_PINHOLE")) {
            if !camera.distortion.is_identity() {
                pinholes_distorted.get_or_insert((0, i, model.to_owned())).0 += 1;
            }
        }
        if let Some(error) = rounded {
            let (count, worst, _) = rounded_rotations.get_or_insert((0, 0.0, i));
            *count += 1;
            *worst = error.max(*worst);
        }
        warn_focal_conflicts(&file, i, &entry.file_path, &keys, &global, &camera.intrinsics, &mut warned_top);
        frames.push(Frame {
            camera,
            file_path,
            time: entry.time,
            camera_name: entry.camera.clone(),
            holdout: entry.holdout,
        });
    }
    report.log(&file);
    if let Some((count, worst, first)) = rounded_rotations {
        log::warn!(
            "{}: the transform_matrix of {count} frame(s) (the first: frame {first}) holds a rotation only to within \
             {worst:.1e} (written with few digits?); the nearest rotations are used",
            file.display()
        );
    }
    if let Some((count, first, model)) = pinholes_distorted {
        log::warn!(
            "{}: {count} frame(s) (the first: frame {first}) have camera_model {model} with distortion \
             coefficients; using them",
            file.display()
        );
    }
    // A name without an extension (NeRF datasets' `./train/r_0`) is matched as a matter of
    // course; a name with another image extension than the file found (`cam001.jpg` for
    // `cam001.png`) may be a mistake, and is said so: it was matched without a word.
    let (other, bare): (Vec<_>, Vec<_>) =
        renamed.iter().partition(|(from, _)| crate::image::has_image_extension(Path::new(from)));
    if let Some((from, to)) = other.first() {
        log::warn!(
            "{}: {} frame(s) name an image file that does not exist, and read the one image of the same name \
             with another extension instead (e.g. {from} → {}); correct the names if that is not the image meant",
            file.display(),
            other.len(),
            to.display()
        );
    }
    if let Some((from, to)) = bare.first() {
        log::info!(
            "{}: {} frame(s) name an image without its extension; matched by name stem (e.g. {from} → {})",
            file.display(),
            bare.len(),
            to.display()
        );
    }
    let aabb = match top.aabb {
        None => None,
        Some(a) => {
            let aabb = Aabb { min: DVec3::from_array(a[0]), max: DVec3::from_array(a[1]) };
            aabb.validate().map_err(|e| IoError::invalid(&file, format!("`aabb`: {e}")))?;
            Some(aabb)
        }
    };
    check_recording(&file, &top, &[])?;
    // A truth that names no volume was found only when the truth was read, after the run had
    // trained, as "volume file is a folder" naming neither the entry nor the key: an empty path
    // resolves to the scene's folder.
    for (i, t) in top.truth.iter().enumerate() {
        let location = format!("truth entry {i}, key `truth[{i}].file_path`");
        if t.file_path.trim().is_empty() {
            return Err(IoError::Key {
                path: file.clone(),
                location,
                problem: format!(
                    "is {:?}, which names no volume file; give the ground-truth volume (.npy) of the entry",
                    t.file_path
                ),
            });
        }
        if resolve_in(&root, Path::new(&t.file_path)).is_dir() {
            return Err(IoError::Key {
                path: file.clone(),
                location,
                problem: format!(
                    "{} is a folder, not a volume file; give the ground-truth volume (.npy) of the entry",
                    t.file_path
                ),
            });
        }
    }
    let recording = Recording {
        linearisation: top.linearisation.unwrap_or_default(),
        frames: frame_recordings,
        flow_axis: top.flow_axis.map(|a| DVec3::from_array(a).normalize()),
    };
    Ok(SceneDraft {
        recording,
        root,
        aabb,
        units: top.units.unwrap_or_else(|| DEFAULT_UNITS.to_string()),
        intensity_scale: top.intensity_scale.unwrap_or(1.0),
        linearisation: top.linearisation.unwrap_or_default(),
        frames,
        truth: top
            .truth
            .into_iter()
            .map(|t| TruthRef { time: t.time, file_path: PathBuf::from(t.file_path) })
            .collect(),
        file,
    })
}

/// Checks a length unit's name: it labels axes, exports and reports, so it must be a short
/// printable name such as `mm` or `m`, not empty or blank and without control characters.
pub fn check_units(units: &str) -> Result<(), String> {
    if units.trim().is_empty() {
        return Err(format!("the length unit must be named (e.g. \"mm\"), got {units:?}"));
    }
    if units.chars().any(char::is_control) || units.trim() != units {
        return Err(format!(
            "the length unit {units:?} holds control characters or surrounding blanks; name it as it is printed, e.g. \"mm\""
        ));
    }
    if units.chars().count() > 32 {
        return Err(format!(
            "the length unit {units:?} is longer than 32 characters; name it as it is printed, e.g. \"mm\""
        ));
    }
    Ok(())
}

/// Reads a scene from a `transforms.json` or a folder holding one, and validates it (see
/// [`validate_scene`]); the file must give an `aabb`. Images are not read (see
/// [`load_images`]) except for their size when `w`/`h` are missing. `Scene::root` is the
/// folder of the file.
pub fn load_scene(path: &Path) -> Result<Scene, IoError> {
    let draft = read_scene_draft(path)?;
    let file = draft.file.clone();
    let Some(aabb) = draft.aabb else { return Err(missing_aabb(&file)) };
    let scene = draft.into_scene(aabb);
    validate_scene(&scene, &file)?;
    for (i, clearance) in cameras_near_box(&scene) {
        log::warn!(
            "{}: frame {i} ({}): the camera is only {clearance:.3} {} from the reconstruction box; rays \
             through the box are nearly as long as the box and the view is far from a projection",
            file.display(),
            scene.frames[i].file_path.display(),
            scene.units
        );
    }
    for found in cameras_at_one_place(&scene) {
        log::warn!("{}: {}", file.display(), describe_one_place(&scene, &found));
    }
    Ok(scene)
}

/// How close (as a fraction of the box's diagonal) the centres of two cameras of one instant
/// must be for [`cameras_at_one_place`] to report them.
pub const ONE_PLACE_FRACTION: f64 = 1e-6;

/// Two cameras found at one place by [`cameras_at_one_place`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OnePlace {
    /// The first pair of frames `(j, i)`, `j < i`, of one instant whose cameras stand there.
    pub frames: (usize, usize),
    /// At how many instants the same two cameras do (1 for unnamed cameras).
    pub instants: usize,
}

/// Cameras of one instant (one time, or both without one) that stand at one place: centres
/// closer than [`ONE_PLACE_FRACTION`] of the box's diagonal. Two cameras cannot, so one
/// camera's calibration was most likely copied to another, which then adds no view of its
/// own. Frames of one named camera are never paired (it records one image per instant); each
/// frame is paired with the first such frame of its instant, and the pairs of two named
/// cameras are reported once, with the number of instants.
pub fn cameras_at_one_place(scene: &Scene) -> Vec<OnePlace> {
    let limit = ONE_PLACE_FRACTION * scene.aabb.size().length();
    let mut instants: std::collections::BTreeMap<Option<u64>, Vec<usize>> = std::collections::BTreeMap::new();
    for (i, f) in scene.frames.iter().enumerate() {
        instants.entry(f.time.map(|t| (t + 0.0).to_bits())).or_default().push(i);
    }
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    for frames in instants.values() {
        for (k, &i) in frames.iter().enumerate() {
            let (a, centre) = (&scene.frames[i], scene.frames[i].camera.centre());
            let other = frames[..k].iter().copied().find(|&j| {
                let b = &scene.frames[j];
                let one_camera = a.camera_name.is_some() && a.camera_name == b.camera_name;
                !one_camera && (b.camera.centre() - centre).length() <= limit
            });
            pairs.extend(other.map(|j| (j, i)));
        }
    }
    pairs.sort_unstable();
    let mut out: Vec<OnePlace> = Vec::new();
    for (j, i) in pairs {
        let names = |k: usize| scene.frames[k].camera_name.as_deref();
        let same_cameras = |p: &OnePlace| {
            let (pj, pi) = p.frames;
            names(j).is_some() && names(i).is_some() && (names(pj), names(pi)) == (names(j), names(i))
        };
        match out.iter_mut().find(|p| same_cameras(p)) {
            Some(p) => p.instants += 1,
            None => out.push(OnePlace { frames: (j, i), instants: 1 }),
        }
    }
    out
}

/// The warning for a finding of [`cameras_at_one_place`].
pub fn describe_one_place(scene: &Scene, found: &OnePlace) -> String {
    let (j, i) = found.frames;
    let frame = |k: usize| {
        let f = &scene.frames[k];
        match &f.camera_name {
            Some(c) => format!("frame {k} ({}, camera {c})", f.file_path.display()),
            None => format!("frame {k} ({})", f.file_path.display()),
        }
    };
    let (a, b) = (&scene.frames[j].camera, &scene.frames[i].camera);
    let c = a.centre() + DVec3::ZERO;
    let same_view = a.forward().dot(b.forward()) > 1.0 - 1e-9 && a.intrinsics == b.intrinsics;
    let when = match (found.instants, scene.frames[i].time) {
        (1, Some(t)) => format!(" at time {}", num(t)),
        (1, None) => String::new(),
        (n, _) => format!(" at {n} instants (the first two frames named)"),
    };
    format!(
        "{} and {} stand at one place, ({:.3}, {:.3}, {:.3}) {}{when}{}: two cameras cannot, so one's \
         calibration is most likely the other's copied, and it adds no view of its own",
        frame(j),
        frame(i),
        c.x + 0.0,
        c.y + 0.0,
        c.z + 0.0,
        scene.units,
        if same_view { ", looking the same way through the same intrinsics" } else { "" },
    )
}

/// How close (as a fraction of the box's diagonal) a camera centre may come to the box before
/// [`cameras_near_box`] reports it.
pub const NEAR_BOX_FRACTION: f64 = 0.05;

/// Distance from `point` to the box (0 inside it).
pub fn distance_to_box(aabb: &Aabb, point: DVec3) -> f64 {
    (aabb.min - point).max(point - aabb.max).max(DVec3::ZERO).length()
}

/// Frames whose camera centre lies outside the box but closer to it than
/// [`NEAR_BOX_FRACTION`] of its diagonal, with that distance.
pub fn cameras_near_box(scene: &Scene) -> Vec<(usize, f64)> {
    let limit = NEAR_BOX_FRACTION * scene.aabb.size().length();
    scene
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| (i, distance_to_box(&scene.aabb, f.camera.centre())))
        .filter(|&(_, d)| d > 0.0 && d < limit)
        .collect()
}

/// `path` with `.` removed and `x/..` folded, without touching the file system.
fn normalise(path: &Path) -> PathBuf {
    use std::path::Component;
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.components().next_back(), Some(Component::Normal(_))) => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// The range of `intensity_scale` a scene may have: reconstructions run in f32, whose values
/// (about pixel ÷ intensity_scale) leave its range, or its precision, beyond it (an
/// intensity_scale of 1e-40 wrote a volume of infinities, 1e300 one of zeros).
pub const MIN_INTENSITY_SCALE: f64 = 1e-20;
pub const MAX_INTENSITY_SCALE: f64 = 1e20;

/// Intrinsics beyond this many pixels along a side, or in all, are held to their image's header
/// when the scene is read (the largest camera sensors have about 150 megapixels; a side of
/// 16384 and 2^28 pixels leave room).
const CHECKED_SIDE: usize = 16384;
const CHECKED_PIXELS: usize = 1 << 28;

/// The error of frame `i` whose image's header gives another size than its intrinsics; `None`
/// when they agree or the header cannot be read (the loading of the images names that).
fn header_disagrees(scene: &Scene, i: usize) -> Option<IoError> {
    let frame = &scene.frames[i];
    let path = scene.resolve(&frame.file_path);
    let (w, h) = (frame.camera.width(), frame.camera.height());
    let (iw, ih) = crate::image::read_dimensions(&path).ok()?;
    ((iw as usize, ih as usize) != (w, h)).then_some(IoError::ImageSize {
        path,
        frame: i,
        found_width: iw as usize,
        found_height: ih as usize,
        expected_width: w,
        expected_height: h,
    })
}

/// Checks what [`load_scene`] checks on a scene built in memory: a valid aabb near enough the
/// origin for its size ([`Aabb::check_resolvable`]), at least one frame, a positive intensity
/// scale, finite times, a time on every frame or on none, no two frames on the same image file,
/// every camera valid, outside the box, and seeing the box (at least one pixel's ray crosses
/// it). `file` names the scene in error messages.
pub fn validate_scene(scene: &Scene, file: &Path) -> Result<(), IoError> {
    check_units(&scene.units).map_err(|e| IoError::invalid(file, format!("`units`: {e}")))?;
    let aabb = scene.aabb;
    aabb.validate().map_err(|e| IoError::invalid(file, format!("`aabb`: {e}")))?;
    aabb.check_resolvable().map_err(|e| IoError::invalid(file, format!("`aabb`: {e}")))?;
    if scene.frames.is_empty() {
        return Err(IoError::invalid(file, "the scene has no frames"));
    }
    let s = scene.intensity_scale;
    if !(s.is_finite() && s > 0.0) {
        return Err(IoError::invalid(file, format!("intensity_scale must be positive, got {}", num(s))));
    }
    if !(MIN_INTENSITY_SCALE..=MAX_INTENSITY_SCALE).contains(&s) {
        return Err(IoError::invalid(
            file,
            format!(
                "intensity_scale {s:e} lies outside {MIN_INTENSITY_SCALE:e} … {MAX_INTENSITY_SCALE:e}: the field's \
                 values (pixel ÷ intensity_scale per unit length) would overflow or vanish in 32-bit floating \
                 point; give the pixels or the lengths in other units"
            ),
        ));
    }
    check_times_on_every_frame(scene, file)?;
    let mut seen: std::collections::HashMap<PathBuf, usize> = std::collections::HashMap::new();
    // A camera records one image per instant (its gain and holding out go by its name). Times
    // are compared as numbers (0 and -0 are one instant); times that differ by less than
    // `same_time` tells apart are refused after the loop.
    let mut shots: std::collections::HashMap<(&str, u64), usize> = std::collections::HashMap::new();
    for (i, f) in scene.frames.iter().enumerate() {
        if f.time.is_some_and(|t| !t.is_finite()) {
            return Err(IoError::invalid(file, format!("frame {i} ({}): time must be finite", f.file_path.display())));
        }
        if let Some(name) = &f.camera_name {
            if name.trim().is_empty() {
                return Err(IoError::invalid(
                    file,
                    format!(
                        "frame {i} ({}), key `frames[{i}].camera`: is {name:?}, which names no camera; name the \
                         camera that took the frame, or leave the key out",
                        f.file_path.display()
                    ),
                ));
            }
            if let Some(j) = shots.insert((name.as_str(), (f.time.unwrap_or(0.0) + 0.0).to_bits()), i) {
                return Err(IoError::invalid(
                    file,
                    format!(
                        "frames {j} and {i} are both camera {name:?}{}; a camera records one image per \
                         instant: give the frames of different cameras different `camera` names",
                        f.time.map(|t| format!(" at time {}", fluidnerf_core::num(t))).unwrap_or_default()
                    ),
                ));
            }
        }
        f.camera.validate().map_err(|error| IoError::Camera {
            path: file.to_path_buf(),
            frame: i,
            file_path: f.file_path.clone(),
            error,
        })?;
        // The file itself where it exists (links and spellings resolved), else its absolute path.
        let path = scene.resolve(&f.file_path);
        let key = std::fs::canonicalize(&path)
            .unwrap_or_else(|_| normalise(&std::path::absolute(&path).unwrap_or_else(|_| path.clone())));
        if let Some(j) = seen.insert(key, i) {
            return Err(IoError::invalid(
                file,
                format!(
                    "frames {j} and {i} both use the image {}; every frame needs its own image",
                    f.file_path.display()
                ),
            ));
        }
        if aabb.contains(f.camera.centre()) {
            return Err(IoError::invalid(
                file,
                format!(
                    "frame {i} ({}): the camera centre {:?} is inside the reconstruction box; shrink the aabb \
                     or check the pose",
                    f.file_path.display(),
                    f.camera.centre().to_array()
                ),
            ));
        }
    }
    check_time_spread(scene, file)?;
    check_instants_apart(scene, file)?;
    check_time_steps(scene, file)?;
    // A truth's time is matched to the frames' instants: one that is not finite matches none.
    if let Some((i, t)) = scene.truth.iter().enumerate().find(|(_, t)| t.time.is_some_and(|t| !t.is_finite())) {
        return Err(IoError::invalid(
            file,
            format!(
                "truth entry {i} ({}): its time {} is not a finite number; give the time of the instant it holds",
                t.file_path.display(),
                fluidnerf_core::num(t.time.unwrap_or(f64::NAN))
            ),
        ));
    }
    // Among truths with a time, one without is matched to no instant and would go unused,
    // unreported.
    let timed_truth = scene.truth.iter().position(|t| t.time.is_some());
    if let (Some(j), Some(i)) = (timed_truth, scene.truth.iter().position(|t| t.time.is_none())) {
        return Err(IoError::invalid(
            file,
            format!(
                "truth entry {i} ({}) has no `time`, but entry {j} ({}) has one: an entry without a time \
                 would be matched to no instant and left unused; give every truth entry its instant's \
                 `time`, or none for a truth of one instant",
                scene.truth[i].file_path.display(),
                scene.truth[j].file_path.display()
            ),
        ));
    }
    // One ground truth per instant: a second one at the same time would go unused, unreported.
    let same_instant = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) => same_time(a, b),
        (a, b) => a.is_none() && b.is_none(),
    };
    for (i, t) in scene.truth.iter().enumerate() {
        if let Some(j) = scene.truth[..i].iter().position(|u| same_instant(u.time, t.time)) {
            return Err(IoError::invalid(
                file,
                format!(
                    "truth entries {j} ({}) and {i} ({}) are both {}; give one ground truth per instant",
                    scene.truth[j].file_path.display(),
                    t.file_path.display(),
                    t.time
                        .map(|t| format!("at time {}", fluidnerf_core::num(t)))
                        .unwrap_or_else(|| "without a time".into())
                ),
            ));
        }
    }
    // Frames of one physical camera at many times share a camera: test each distinct one once.
    let mut distinct: Vec<usize> = Vec::new();
    let first_equal: Vec<usize> = scene
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| match distinct.iter().find(|&&j| scene.frames[j].camera == f.camera) {
            Some(&j) => j,
            None => {
                distinct.push(i);
                i
            }
        })
        .collect();
    // Intrinsics that claim more pixels than cameras have (`w`/`h` mistyped) are held to the
    // image's header now: every later step sizes its buffers and its memory estimate by them,
    // and a camera imaging the box on such a grid still sees it. Plausible sizes are left to
    // the loading of the images, which compares every image.
    for &i in &distinct {
        let (w, h) = (scene.frames[i].camera.width(), scene.frames[i].camera.height());
        if w.max(h) > CHECKED_SIDE || w.saturating_mul(h) > CHECKED_PIXELS {
            if let Some(e) = header_disagrees(scene, i) {
                return Err(e);
            }
        }
    }
    // Every method casts a ray through every pixel: a distortion that cannot be inverted at the
    // image's edges would stop each of them, unnamed, after the scene was taken.
    let undistortion: Vec<(usize, CoreError)> = distinct
        .par_iter()
        .filter_map(|&i| scene.frames[i].camera.check_undistortion().err().map(|e| (i, e)))
        .collect();
    // The distinct cameras are in the order of their first frames, and so are their errors.
    if let Some((i, error)) = undistortion.into_iter().next() {
        return Err(IoError::Camera {
            path: file.to_path_buf(),
            frame: i,
            file_path: scene.frames[i].file_path.clone(),
            error,
        });
    }
    let blind_cameras: Vec<usize> =
        distinct.par_iter().copied().filter(|&i| !scene.frames[i].camera.sees_box(&aabb)).collect();
    if let Some(i) = first_equal.iter().position(|j| blind_cameras.contains(j)) {
        // Intrinsics of another image size (`w`/`h` mistyped, or the frames of another camera)
        // can leave a camera blind; that is the problem to name, when the image's header says
        // so. An image that cannot be read is left to the loading of the images.
        let frame = &scene.frames[i];
        if let Some(e) = header_disagrees(scene, i) {
            return Err(e);
        }
        if let Some(size) = frame.camera.box_image_size(&aabb).filter(|s| s.min_element() < 1.0) {
            return Err(IoError::BoxBetweenPixels {
                path: file.to_path_buf(),
                frame: i,
                file_path: frame.file_path.clone(),
                width_px: size.x,
                height_px: size.y,
            });
        }
        return Err(IoError::CameraMissesBox {
            path: file.to_path_buf(),
            frame: i,
            file_path: scene.frames[i].file_path.clone(),
        });
    }
    Ok(())
}

/// Refuses frame times (finite each) whose spread, latest minus earliest, overflows: every
/// time-resolved method works with time differences, which would be infinite, and its training
/// would diverge or its volumes be garbage.
fn check_time_spread(scene: &Scene, file: &Path) -> Result<(), IoError> {
    let timed = || scene.frames.iter().enumerate().filter_map(|(i, f)| f.time.map(|t| (i, t)));
    // The first frame at the earliest time and the first at the latest.
    let (Some(first), Some(last)) =
        (timed().min_by(|a, b| a.1.total_cmp(&b.1)), timed().reduce(|a, b| if b.1 > a.1 { b } else { a }))
    else {
        return Ok(());
    };
    if (last.1 - first.1).is_finite() {
        return Ok(());
    }
    let frame = |(i, t): (usize, f64)| format!("frame {i} ({}) at {t:e}", scene.frames[i].file_path.display());
    Err(IoError::invalid(
        file,
        format!(
            "the frame times run from {} to {}, a spread too large to represent (it overflows 64-bit floating \
             point), so no time difference can be computed; give the times in another unit or from a nearer origin",
            frame(first),
            frame(last)
        ),
    ))
}

/// Refuses frame times (finite, with a finite spread, [`check_time_spread`]) that span more
/// steps of the smallest gap between them than 32-bit floating point holds: a field of space
/// and time reads `t' = (t − t₀)/Δt` in 32 bits, `Δt` that gap by default, and an infinite `t'`
/// makes its training NaN. Names the first frame at a time too far and its value.
fn check_time_steps(scene: &Scene, file: &Path) -> Result<(), IoError> {
    let mut timed: Vec<(f64, usize)> =
        scene.frames.iter().enumerate().filter_map(|(i, f)| f.time.map(|t| (t, i))).collect();
    timed.sort_by(|a, b| a.0.total_cmp(&b.0));
    timed.dedup_by(|later, first| later.0 == first.0);
    let Some(gap) = timed.windows(2).map(|w| w[1].0 - w[0].0).reduce(f64::min) else {
        return Ok(());
    };
    let first = timed[0];
    let steps = |t: f64| (t - first.0) / gap;
    let Some(&(t, i)) = timed.iter().find(|(t, _)| steps(*t) > f32::MAX as f64) else {
        return Ok(());
    };
    let n = steps(t);
    let n =
        if n.is_finite() { format!("{n:.3e}") } else { format!("about 1e{:.0}", (t - first.0).log10() - gap.log10()) };
    let frame = |(t, i): (f64, usize)| {
        format!("frame {i} ({}) at {}", scene.frames[i].file_path.display(), fluidnerf_core::num(t))
    };
    Err(IoError::invalid(
        file,
        format!(
            "{} lies {n} time steps of Δt = {} (the smallest gap between frame times) after the first, {}: \
             more than a field's 32-bit time input t' = (t − t₀)/Δt holds ({}); check the frame times",
            frame((t, i)),
            fluidnerf_core::num(gap),
            frame(first),
            fluidnerf_core::num(f32::MAX)
        ),
    ))
}

/// Refuses frame times that differ yet name one instant ([`same_time`]: equal to a relative
/// 10⁻⁹): the time-resolved methods would list both as instants and give each the frames of
/// both, so one recorded instant would be reconstructed twice from a mix of its frames.
fn check_instants_apart(scene: &Scene, file: &Path) -> Result<(), IoError> {
    let mut timed: Vec<(f64, usize)> =
        scene.frames.iter().enumerate().filter_map(|(i, f)| f.time.map(|t| (t, i))).collect();
    // The first frame of each time, in order of time.
    timed.sort_by(|a, b| a.0.total_cmp(&b.0));
    timed.dedup_by(|later, first| later.0 == first.0);
    let Some(w) = timed.windows(2).find(|w| same_time(w[0].0, w[1].0)) else {
        return Ok(());
    };
    // Written as `num` writes numbers: a time of 1e-300 took 300 digits of the message.
    let frame = |(t, i): (f64, usize)| {
        format!("frame {i} ({}) at {}", scene.frames[i].file_path.display(), fluidnerf_core::num(t))
    };
    Err(IoError::invalid(
        file,
        format!(
            "{} and {} are one instant written two ways (times within a relative 1e-9 of each other name the \
             same instant); write the instant's time alike in every frame, or, for different instants, times \
             further apart (from a nearer origin, or in a finer unit)",
            frame(w[0]),
            frame(w[1])
        ),
    ))
}

/// Refuses a scene in which some frames have a `time` and others none: a frame without one
/// cannot be placed among the instants (it would be read as time 0, an instant of its own). The
/// error names the frames without time, at most five of them, with their images.
fn check_times_on_every_frame(scene: &Scene, file: &Path) -> Result<(), IoError> {
    const SHOWN: usize = 5;
    let untimed: Vec<usize> =
        scene.frames.iter().enumerate().filter(|(_, f)| f.time.is_none()).map(|(i, _)| i).collect();
    let timed = scene.frames.len() - untimed.len();
    if untimed.is_empty() || timed == 0 {
        return Ok(());
    }
    let mut named: Vec<String> =
        untimed.iter().take(SHOWN).map(|&i| format!("{i} ({})", scene.frames[i].file_path.display())).collect();
    if untimed.len() > SHOWN {
        named.push(format!("{} more", untimed.len() - SHOWN));
    }
    let (which, have) = match named.len() {
        1 => (format!("frame {}", named[0]), "has"),
        n => (format!("frames {} and {}", named[..n - 1].join(", "), named[n - 1]), "have"),
    };
    Err(IoError::invalid(
        file,
        format!(
            "{which} {have} no `time`, but the other {timed} frame(s) have one: in a time-resolved scene every frame \
             needs its `time` (a frame without one would not be placed among the instants); give it, or remove \
             `time` from every frame for a scene of one instant"
        ),
    ))
}

fn path_str(file: &Path, p: &Path) -> Result<String, IoError> {
    p.to_str()
        .map(str::to_string)
        .ok_or_else(|| IoError::invalid(file, format!("path {} is not valid UTF-8", p.display())))
}

/// Writes `scene` as `transforms.json` (`path` is the file or its folder) atomically, in the
/// layout described in the module docs. Frame and truth paths are written as they are in the
/// scene (relative to the folder of the file unless absolute); `scene.root` is not stored.
pub fn save_scene(scene: &Scene, path: &Path) -> Result<(), IoError> {
    save_scene_with(scene, path, None)
}

/// [`save_scene`], also recording how the scene's 8-bit images are to be linearised (the key
/// `linearisation`, omitted when `None`).
pub fn save_scene_with(scene: &Scene, path: &Path, linearisation: Option<Linearisation>) -> Result<(), IoError> {
    let recording =
        Recording { linearisation: linearisation.unwrap_or_default(), ..Recording::plain(scene.frames.len()) };
    save_scene_recording(scene, path, &recording, linearisation.is_some())
}

/// [`save_scene`] with the preprocessing keys of `recording` (one entry per frame);
/// `linearisation` is written when `write_linearisation` or when it is not `linear`.
pub fn save_scene_recording(
    scene: &Scene,
    path: &Path,
    recording: &Recording,
    write_linearisation: bool,
) -> Result<(), IoError> {
    let file = scene_file_path(path);
    assert_eq!(recording.frames.len(), scene.frames.len(), "save_scene_recording: one recording entry per frame");
    let linearisation =
        (write_linearisation || recording.linearisation != Linearisation::Linear).then_some(recording.linearisation);
    let keys: Vec<IntrinsicKeys> =
        scene.frames.iter().map(|f| IntrinsicKeys::from_camera(&f.camera.intrinsics, &f.camera.distortion)).collect();
    let shared = keys.windows(2).all(|w| w[0] == w[1]);
    let global = if shared { keys.first().cloned().unwrap_or_default() } else { IntrinsicKeys::default() };
    let mut frames = Vec::with_capacity(scene.frames.len());
    for ((f, k), r) in scene.frames.iter().zip(keys).zip(&recording.frames) {
        frames.push(FrameEntry {
            background: background_to_key(&file, &r.background)?,
            flat_field: flat_field_to_key(&file, &r.flat_field)?,
            mask_path: r.mask_path.as_deref().map(|p| path_str(&file, p)).transpose()?,
            file_path: path_str(&file, &f.file_path)?,
            transform_matrix: world_from_camera_to_opengl_c2w(&f.camera.world_from_camera),
            time: f.time,
            camera: f.camera_name.clone(),
            holdout: f.holdout,
            thin_lens: f.camera.lens,
            intrinsics: if shared { IntrinsicKeys::default() } else { k },
        });
    }
    let truth = scene
        .truth
        .iter()
        .map(|t| Ok(TruthEntry { time: t.time, file_path: path_str(&file, &t.file_path)? }))
        .collect::<Result<Vec<_>, IoError>>()?;
    let out = TransformsFile {
        intrinsics: global,
        aabb: [scene.aabb.min.to_array(), scene.aabb.max.to_array()],
        units: Some(scene.units.clone()),
        intensity_scale: Some(scene.intensity_scale),
        linearisation,
        flow_axis: recording.flow_axis.map(|a| a.to_array()),
        truth,
        frames,
    };
    let mut text = serde_json::to_string_pretty(&out)
        .map_err(|error| IoError::Json { path: file.clone(), error: error.to_string() })?;
    text.push('\n');
    atomic_write(&file, |w| w.write_all(text.as_bytes()))
}

/// The `linearisation` recorded in the scene file `scene.root/transforms.json`, or `linear`
/// when there is no such file or key. ([`Scene`] has no field for it; a scene written under
/// another file name is read as `linear` by [`load_images`]: use [`load_images_with`].)
pub fn recorded_linearisation(scene: &Scene) -> Result<Linearisation, IoError> {
    Ok(recorded(scene)?.linearisation)
}

/// The preprocessing keys recorded in the scene file `scene.root/transforms.json`
/// ([`Recording`]), one entry per frame of `scene`: the file's frames in order when the counts
/// agree, else matched by `file_path`. Without a file, nothing to preprocess.
pub fn recorded(scene: &Scene) -> Result<Recording, IoError> {
    let file = scene.root.join(SCENE_FILE);
    let text = match std::fs::read_to_string(&file) {
        Ok(t) => crate::without_bom(t),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Recording::plain(scene.frames.len())),
        Err(e) => return Err(IoError::io(&file, "scene file", e)),
    };
    let raw: Value = serde_json::from_str(&text).map_err(|error| IoError::json(&file, &text, &error))?;
    let linearisation = match raw.get("linearisation") {
        None => Linearisation::Linear,
        Some(v) => typed(&file, v, "linearisation", None)?,
    };
    let top_background: Option<BackgroundKey> = match raw.get("background") {
        None => None,
        Some(v) => Some(typed(&file, v, "background", None)?),
    };
    let top_flat: Option<FlatFieldKey> = match raw.get("flat_field") {
        None => None,
        Some(v) => Some(typed(&file, v, "flat_field", None)?),
    };
    let flow_axis: Option<[f64; 3]> = match raw.get("flow_axis") {
        None => None,
        Some(v) => Some(typed(&file, v, "flow_axis", None)?),
    };
    #[derive(Deserialize)]
    struct Keys {
        #[serde(default)]
        file_path: Option<String>,
        #[serde(default)]
        background: Option<BackgroundKey>,
        #[serde(default)]
        flat_field: Option<FlatFieldKey>,
        #[serde(default)]
        mask_path: Option<String>,
    }
    let listed: Vec<Value> = raw.get("frames").and_then(Value::as_array).cloned().unwrap_or_default();
    let mut entries = Vec::with_capacity(listed.len());
    for (i, v) in listed.iter().enumerate() {
        let k: Keys = typed(&file, v, &format!("frames[{i}]"), Some(i))?;
        entries.push(k);
    }
    let record = |k: &Keys| FrameRecording {
        background: background_from_key(k.background.as_ref().or(top_background.as_ref())),
        flat_field: flat_field_from_key(k.flat_field.as_ref().or(top_flat.as_ref())),
        mask_path: k.mask_path.as_ref().map(PathBuf::from),
    };
    let frames = if entries.len() == scene.frames.len() {
        entries.iter().map(record).collect()
    } else {
        scene
            .frames
            .iter()
            .map(|f| {
                entries
                    .iter()
                    .find(|k| k.file_path.as_deref().map(Path::new) == Some(f.file_path.as_path()))
                    .map(record)
                    .unwrap_or_else(|| FrameRecording {
                        background: background_from_key(top_background.as_ref()),
                        flat_field: flat_field_from_key(top_flat.as_ref()),
                        mask_path: None,
                    })
            })
            .collect()
    };
    let flow_axis = match flow_axis.map(DVec3::from_array) {
        Some(v) if v.is_finite() && v.length() > 0.0 => Some(v.normalize()),
        Some(v) => {
            return Err(IoError::invalid(
                &file,
                format!("`flow_axis` must be a non-zero finite vector, got {:?}", v.to_array()),
            ))
        }
        None => None,
    };
    Ok(Recording { linearisation, frames, flow_axis })
}

/// Reads every frame's image as the scene file records it ([`recorded`]): linearised, with
/// its `background` subtracted, negative results clipped to 0 (logged with their count), and
/// divided by its `flat_field`. See [`load_preprocessed`] for the masks and the counts.
pub fn load_images(scene: &Scene) -> Result<Vec<Image>, IoError> {
    Ok(load_preprocessed(scene)?.images)
}

/// The images of a scene ready for reconstruction, with what was done to them.
#[derive(Clone, Debug)]
pub struct Preprocessed {
    /// Per frame: linearised, background subtracted, clipped at 0, divided by the flat field.
    pub images: Vec<Image>,
    /// Per frame: `true` for pixels to use, when the frame has a mask.
    pub masks: Vec<Option<Vec<bool>>>,
    /// Pixels that were negative after background subtraction and were set to 0.
    pub clipped: usize,
    /// Pixels at the full scale of their integer images (saturated: they recorded less light
    /// than arrived), counted before any subtraction.
    pub saturated: usize,
    /// The smallest and largest value of the normalised flat fields ([`normalise_flat`]) over
    /// the used pixels of every frame that has one: the image was divided by them, so a pixel
    /// gained up to `1 / min` and lost up to `1 / max`. `None` without flat fields.
    pub flat_range: Option<(f32, f32)>,
    /// What was asked for ([`Recording::describe`]).
    pub recording: Recording,
}

/// Reads a scene's images and masks and preprocesses the images as its file records
/// ([`Recording`]). Background and flat-field images are read with the scene's linearisation
/// and must have the size of their frame; the median of several is taken pixel by pixel and
/// computed once per distinct list. Errors name the background, flat-field or mask file, the
/// frame and its camera.
///
/// # Flat field
/// A frame with a `flat_field` is corrected as
///
/// ```text
/// corrected = max(raw − D, 0) / F,    F = (flat − D) / mean_used(flat − D),
/// ```
///
/// with `raw` the linearised image, `flat` the pixelwise median of its flat-field images, `D`
/// the frame's `background` (the constant, or the median of its background images; 0 without
/// one), subtracted from the flat as from the image: the standard `(raw − dark) / (flat −
/// dark)`. `mean_used` is the mean over the image, or over the pixels its mask uses, so `F`
/// averages 1 there and the image keeps its overall scale (gains and `intensity_scale` mean
/// what they meant). See [`normalise_flat`] for the pixels it refuses.
pub fn load_preprocessed(scene: &Scene) -> Result<Preprocessed, IoError> {
    load_preprocessed_with(scene, recorded(scene)?)
}

/// A flat-field pixel (after its dark level) at or below this fraction of the flat's mean is
/// refused ([`normalise_flat`]): dividing by it would multiply the pixel's noise 20-fold or more.
pub const FLAT_FIELD_MIN_FRACTION: f64 = 0.05;

/// Normalises a flat field with its dark level already subtracted, `flat` (a frame's size), to
/// mean 1 over the used pixels (`mask`: `true` to use; every pixel without one), and returns the
/// smallest and largest normalised value over them. Pixels the mask leaves out are set to 1
/// (their image pixels stay as they are) when they hold too little light to divide by.
///
/// Refuses, with the problem in words: a flat without light (a mean that is not positive and
/// finite) and used pixels at or below [`FLAT_FIELD_MIN_FRACTION`] of the mean, giving how
/// many, the first and the box of columns and rows that holds them all.
pub fn normalise_flat(flat: &mut Image, mask: Option<&[bool]>) -> Result<(f32, f32), String> {
    let used = |k: usize| mask.is_none_or(|m| m[k]);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for (k, &v) in flat.data.iter().enumerate() {
        if used(k) {
            sum += f64::from(v);
            count += 1;
        }
    }
    let mean = sum / count.max(1) as f64;
    if !(mean.is_finite() && mean > 0.0) {
        return Err(format!(
            "holds no light once its dark level (the frame's background) is subtracted: its mean over the {count} \
             used pixel(s) is {}; a flat field records a uniformly lit target, brighter than the background",
            num(five_digits(mean))
        ));
    }
    // Every used pixel is finite here (one that is not makes the mean so).
    let floor = FLAT_FIELD_MIN_FRACTION * mean;
    let low: Vec<usize> = (0..flat.data.len()).filter(|&k| used(k) && f64::from(flat.data[k]) <= floor).collect();
    if let Some(&first) = low.first() {
        let w = flat.width;
        let (cols, rows) = low.iter().fold(((usize::MAX, 0), (usize::MAX, 0)), |((c0, c1), (r0, r1)), &k| {
            ((c0.min(k % w), c1.max(k % w)), (r0.min(k / w), r1.max(k / w)))
        });
        return Err(format!(
            "has {} of its {count} used pixel(s) at or below {:.0} % of its mean ({}) once its dark level (the \
             frame's background) is subtracted, the first at (col {}, row {}) with {}, all within cols {}..={}, \
             rows {}..={}; dividing by them would multiply their noise {:.0}-fold or more: record the flat \
             brighter, or leave those pixels out with the frame's `mask_path`",
            low.len(),
            100.0 * FLAT_FIELD_MIN_FRACTION,
            num(five_digits(mean)),
            first % w,
            first / w,
            num(five_digits(f64::from(flat.data[first]))),
            cols.0,
            cols.1,
            rows.0,
            rows.1,
            1.0 / FLAT_FIELD_MIN_FRACTION
        ));
    }
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for (k, v) in flat.data.iter_mut().enumerate() {
        let n = (f64::from(*v) / mean) as f32;
        if used(k) {
            lo = lo.min(n);
            hi = hi.max(n);
            *v = n;
        } else {
            *v = if f64::from(*v) > floor { n } else { 1.0 };
        }
    }
    Ok((lo, hi))
}

/// `x` to five significant digits, for messages (a mean of counts has sixteen).
fn five_digits(x: f64) -> f64 {
    format!("{x:.4e}").parse().unwrap_or(x)
}

/// The pixelwise median of the images `list` (a frame's `what`, e.g. "background image"), read
/// with `linearisation`, each of size `size` and, when `kind` is given, stored as `kind`; with
/// the number of their pixels at their kind's full scale. `label` names the frame and `file`
/// the scene file in errors.
#[allow(clippy::too_many_arguments)]
fn median_of_files(
    scene: &Scene,
    file: &Path,
    list: &[PathBuf],
    what: &str,
    label: &str,
    size: (usize, usize),
    kind: Option<SampleKind>,
    linearisation: Linearisation,
) -> Result<(Image, usize), IoError> {
    let (w, h) = size;
    let mut stack = Vec::with_capacity(list.len());
    let mut saturated = 0usize;
    for p in list {
        let path = scene.resolve(p);
        let (img, img_kind) = crate::image::read_image_with(&path, linearisation)
            .map_err(|e| IoError::invalid(file, format!("{label}: {what} {}: {e}", path.display())))?;
        if let Some(kind) = kind.filter(|k| *k != img_kind) {
            return Err(IoError::invalid(
                &path,
                format!(
                    "{what} is {} image but the scene's images are {kind}; {}",
                    img_kind.with_article(),
                    different_scales(img_kind, kind)
                ),
            ));
        }
        if (img.width, img.height) != (w, h) {
            return Err(IoError::invalid(
                &path,
                format!("{what} is {}x{} pixels but {label} is {w}x{h}", img.width, img.height),
            ));
        }
        check_pixels(&path, &img)?;
        saturated += img_kind.saturated(&img);
        stack.push(img);
    }
    Ok((median_image(&stack), saturated))
}

/// [`load_preprocessed`] with the preprocessing keys given (one entry per frame, paths relative
/// to `scene.root` unless absolute) rather than read from the scene file: for a scene about to
/// be written.
pub fn load_preprocessed_with(scene: &Scene, recording: Recording) -> Result<Preprocessed, IoError> {
    assert_eq!(recording.frames.len(), scene.frames.len(), "load_preprocessed_with: one recording entry per frame");
    let (mut images, kind) = load_images_and_kind(scene, recording.linearisation)?;
    let saturated = saturated_pixels(scene, &images, kind);
    // Read first: a flat field is normalised over the pixels its frame's mask uses.
    let masks = load_masks(scene, &recording)?;
    let file = scene.root.join(SCENE_FILE);
    let frame_label = |i: usize| {
        let f = &scene.frames[i];
        match &f.camera_name {
            Some(c) => format!("frame {i} ({}, camera {c})", f.file_path.display()),
            None => format!("frame {i} ({})", f.file_path.display()),
        }
    };
    // The file itself where it exists (links and spellings resolved).
    let canonical = |p: &Path| {
        let path = scene.resolve(p);
        std::fs::canonicalize(&path).unwrap_or_else(|_| normalise(&std::path::absolute(&path).unwrap_or(path)))
    };
    // Medians of background lists, and of flat-field lists.
    let mut medians: std::collections::HashMap<Vec<PathBuf>, Image> = std::collections::HashMap::new();
    let mut flats: std::collections::HashMap<Vec<PathBuf>, Image> = std::collections::HashMap::new();
    #[allow(clippy::type_complexity)]
    let mut normalised: Vec<((&[PathBuf], &Background, Option<&Path>), Image, (f32, f32))> = Vec::new();
    let mut clipped = 0usize;
    let mut flat_range: Option<(f32, f32)> = None;
    for (i, (image, rec)) in images.iter_mut().zip(&recording.frames).enumerate() {
        let (w, h) = (image.width, image.height);
        let label = frame_label(i);
        if let Background::Frames(list) = &rec.background {
            if !medians.contains_key(list) {
                let (median, _) = median_of_files(
                    scene,
                    &file,
                    list,
                    "background image",
                    &label,
                    (w, h),
                    Some(kind),
                    recording.linearisation,
                )?;
                medians.insert(list.clone(), median);
            }
        }
        let background: Option<&Image> = match &rec.background {
            Background::Frames(list) => Some(&medians[list]),
            _ => None,
        };
        let constant = match rec.background {
            Background::Constant(c) => c as f32,
            _ => 0.0,
        };
        if rec.background != Background::None {
            match background {
                Some(bg) => image.data.iter_mut().zip(&bg.data).for_each(|(v, b)| *v -= b),
                None => image.data.iter_mut().for_each(|v| *v -= constant),
            }
            for v in &mut image.data {
                if *v < 0.0 {
                    *v = 0.0;
                    clipped += 1;
                }
            }
            if image.data.iter().all(|&v| v == 0.0) {
                log::warn!(
                    "{label}: nothing is left after its background is subtracted (every pixel at or below it); \
                     the frame now reads as black"
                );
            }
        }
        if rec.flat_field.is_empty() {
            continue;
        }
        let flat_key = format!("{label}, `flat_field`");
        let own = canonical(&scene.frames[i].file_path);
        if let Some(p) = rec.flat_field.iter().find(|p| canonical(p) == own) {
            return Err(IoError::invalid(
                &file,
                format!(
                    "{flat_key}: names {}, the frame's own image; a flat field is a separate recording of a \
                     uniformly lit target (a diffuser or a white screen) with the same camera and lens",
                    p.display()
                ),
            ));
        }
        if let Background::Frames(list) = &rec.background {
            if list.iter().map(|p| canonical(p)).eq(rec.flat_field.iter().map(|p| canonical(p))) {
                return Err(IoError::invalid(
                    &file,
                    format!(
                        "{flat_key}: names the frame's background images, which would leave no light once the \
                         background is subtracted from it; give the images of the uniformly lit target"
                    ),
                ));
            }
        }
        // A flat is normalised once for what sets it: its images, the background subtracted
        // from it and the mask it is averaged over (a camera's frames share all three).
        let key = (rec.flat_field.as_slice(), &rec.background, rec.mask_path.as_deref());
        let at = match normalised.iter().position(|(k, ..)| *k == key) {
            Some(at) => at,
            None => {
                if !flats.contains_key(&rec.flat_field) {
                    // The background is subtracted from the flat too, so it must be on the images'
                    // scale; without one, a flat stored otherwise (a normalised float flat) serves.
                    let same_kind = (rec.background != Background::None).then_some(kind);
                    let (median, saturated) = median_of_files(
                        scene,
                        &file,
                        &rec.flat_field,
                        "`flat_field` image",
                        &label,
                        (w, h),
                        same_kind,
                        recording.linearisation,
                    )?;
                    if saturated > 0 {
                        log::warn!(
                            "{flat_key}: {saturated} pixel(s) of the flat-field image(s) at their full scale (saturated): \
                             the flat is too low there and those pixels are over-corrected; record the flat with less \
                             exposure"
                        );
                    }
                    flats.insert(rec.flat_field.clone(), median);
                }
                let mut flat = flats[&rec.flat_field].clone();
                match background {
                    Some(bg) => flat.data.iter_mut().zip(&bg.data).for_each(|(v, b)| *v -= b),
                    None => flat.data.iter_mut().for_each(|v| *v -= constant),
                }
                let (lo, hi) = normalise_flat(&mut flat, masks[i].as_deref()).map_err(|problem| {
                    let files: Vec<String> = rec.flat_field.iter().map(|p| p.display().to_string()).collect();
                    let which = match files.as_slice() {
                        [one] => format!("flat-field image {one}"),
                        many => format!("median of the flat-field images {}", many.join(", ")),
                    };
                    IoError::invalid(&file, format!("{flat_key}: the {which} {problem}"))
                })?;
                normalised.push((key, flat, (lo, hi)));
                normalised.len() - 1
            }
        };
        let (_, flat, (lo, hi)) = &normalised[at];
        image.data.iter_mut().zip(&flat.data).for_each(|(v, f)| *v /= f);
        flat_range = Some(flat_range.map_or((*lo, *hi), |(a, b)| (a.min(*lo), b.max(*hi))));
    }
    if clipped > 0 {
        let total: usize = images.iter().map(|im| im.data.len()).sum();
        log::info!(
            "background subtraction left {clipped} of {total} pixels ({:.2} %) negative; clipped to 0",
            100.0 * clipped as f64 / total.max(1) as f64
        );
    }
    if let Some((lo, hi)) = flat_range {
        log::info!("divided the images by their flat fields, normalised to mean 1: values {lo:.3} .. {hi:.3}");
    }
    Ok(Preprocessed { images, masks, clipped, saturated, flat_range, recording })
}

/// Pixels at the full scale of `kind` (integer images only) in `images`, the scene's frames;
/// a warning names the frames that have them.
fn saturated_pixels(scene: &Scene, images: &[Image], kind: SampleKind) -> usize {
    let counts: Vec<usize> = images.iter().map(|im| kind.saturated(im)).collect();
    let total: usize = counts.iter().sum();
    if total > 0 {
        let frames: Vec<String> = counts
            .iter()
            .zip(&scene.frames)
            .filter(|(&n, _)| n > 0)
            .map(|(n, f)| format!("{} ({n})", f.file_path.display()))
            .collect();
        log::warn!(
            "{total} pixel(s) at the {kind} full scale (saturated) in {}: they recorded less light than arrived, \
             so the line-integral model does not hold there; mask them (mask_path) or record with less exposure",
            frames.join(", ")
        );
    }
    total
}

/// The pixelwise median of images of one size (the mean of the middle two for an even count).
pub fn median_image(images: &[Image]) -> Image {
    assert!(!images.is_empty(), "median_image: no images");
    let (w, h) = (images[0].width, images[0].height);
    let n = images.len();
    let mut out = Image::zeros(w, h);
    let mut column = vec![0f32; n];
    for (p, o) in out.data.iter_mut().enumerate() {
        for (c, im) in column.iter_mut().zip(images) {
            *c = im.data[p];
        }
        column.sort_by(f32::total_cmp);
        *o = if n % 2 == 1 { column[n / 2] } else { 0.5 * (column[n / 2 - 1] + column[n / 2]) };
    }
    out
}

/// Reads the frames' masks (`mask_path`): an image of the frame's size, non-zero = use.
fn load_masks(scene: &Scene, recording: &Recording) -> Result<Vec<Option<Vec<bool>>>, IoError> {
    let loaded: Vec<Result<Option<Vec<bool>>, IoError>> =
        recording.frames.par_iter().enumerate().map(|(i, rec)| load_mask(scene, i, rec)).collect();
    // The first failing frame in frame order gives the error, and the others are counted:
    // collected straight into a Result, the error was whichever thread met one first, and
    // `info` named another mask on each run.
    let failing: Vec<usize> = loaded.iter().enumerate().filter(|(_, m)| m.is_err()).map(|(i, _)| i).collect();
    let mut masks = Vec::with_capacity(loaded.len());
    for mask in loaded {
        match mask {
            Ok(m) => masks.push(m),
            Err(IoError::Invalid { path, problem }) if failing.len() > 1 => {
                let frames: Vec<String> = failing.iter().map(|i| i.to_string()).collect();
                let problem = format!("{problem} (the masks of frames {} fail; this is the first)", frames.join(", "));
                return Err(IoError::Invalid { path, problem });
            }
            Err(e) => return Err(e),
        }
    }
    Ok(masks)
}

/// Frame `i`'s mask (`true` for the pixels to use), None without one; refused, naming the file,
/// when it cannot be read, has another size than the frame, or uses no pixel.
fn load_mask(scene: &Scene, i: usize, rec: &FrameRecording) -> Result<Option<Vec<bool>>, IoError> {
    let Some(p) = &rec.mask_path else { return Ok(None) };
    let frame = &scene.frames[i];
    let path = scene.resolve(p);
    let mask = crate::image::read_image(&path).map_err(|e| {
        IoError::invalid(
            scene.root.join(SCENE_FILE),
            format!("frame {i} ({}): `mask_path`: {e}", frame.file_path.display()),
        )
    })?;
    let (w, h) = (frame.camera.width(), frame.camera.height());
    if (mask.width, mask.height) != (w, h) {
        return Err(IoError::invalid(
            &path,
            format!(
                "mask is {}x{} pixels but frame {i} ({}) is {w}x{h}",
                mask.width,
                mask.height,
                frame.file_path.display()
            ),
        ));
    }
    let keep: Vec<bool> = mask.data.iter().map(|&v| v > 0.0).collect();
    if !keep.iter().any(|&k| k) {
        return Err(IoError::invalid(
            &path,
            format!("the mask of frame {i} ({}) is all zero: no pixel would be used", frame.file_path.display()),
        ));
    }
    Ok(Some(keep))
}

/// Reads every frame's image, in frame order (in parallel), 8-bit images through
/// `linearisation`, checking that each exists, is readable, has the size of its frame's
/// intrinsics, and holds only finite, non-negative values, and that all images store their
/// samples alike (an 8-bit image among 16-bit ones would read about 257 times too dark). The
/// first failing frame (in frame order) gives the error.
pub fn load_images_with(scene: &Scene, linearisation: Linearisation) -> Result<Vec<Image>, IoError> {
    load_images_and_kind(scene, linearisation).map(|(images, _)| images)
}

/// [`load_images_with`], and how every image stores its samples.
fn load_images_and_kind(scene: &Scene, linearisation: Linearisation) -> Result<(Vec<Image>, SampleKind), IoError> {
    let results: Vec<Result<(Image, SampleKind), IoError>> = scene
        .frames
        .par_iter()
        .enumerate()
        .map(|(i, frame)| {
            let path = scene.resolve(&frame.file_path);
            let (image, kind) = crate::image::read_image_with(&path, linearisation)?;
            let (w, h) = (frame.camera.width(), frame.camera.height());
            if (image.width, image.height) != (w, h) {
                return Err(IoError::ImageSize {
                    path,
                    frame: i,
                    found_width: image.width,
                    found_height: image.height,
                    expected_width: w,
                    expected_height: h,
                });
            }
            check_pixels(&path, &image)?;
            Ok((image, kind))
        })
        .collect();
    let read: Vec<(Image, SampleKind)> = results.into_iter().collect::<Result<_, _>>()?;
    let kinds: Vec<SampleKind> = read.iter().map(|r| r.1).collect();
    if let Some((i, kind, usual)) = odd_sample_kind(&kinds) {
        return Err(IoError::invalid(
            scene.resolve(&scene.frames[i].file_path),
            format!(
                "frame {i} is {} image but the other images of the scene are {usual}; {}",
                kind.with_article(),
                different_scales(kind, usual)
            ),
        ));
    }
    let kind = kinds.first().copied().unwrap_or(SampleKind::Float);
    Ok((read.into_iter().map(|r| r.0).collect(), kind))
}

/// Why images of kinds `a` and `b` cannot be used together, and what to do.
pub fn different_scales(a: SampleKind, b: SampleKind) -> String {
    let example = match (a, b) {
        (SampleKind::Integer(x), SampleKind::Integer(y)) => {
            let (lo, hi) = (x.min(y), x.max(y));
            let full = |bits| SampleKind::Integer(bits).full_scale().map_or(1.0, f64::from);
            let factor = full(hi) / full(lo);
            format!(
                " ({} image among {hi}-bit ones reads about {factor:.0} times too dark)",
                SampleKind::Integer(lo).with_article()
            )
        }
        _ => " (integer counts and floating-point values have no common scale)".into(),
    };
    format!("their values are not on one scale{example}: convert the images to one bit depth")
}

/// The largest pixel value read: squared residuals of larger values overflow 32-bit floats
/// (about 3.4e38), and one such pixel would set the scale of every image.
pub const MAX_PIXEL: f32 = 1e18;

/// Refuses NaN, infinite, negative and overflowing pixels, naming the first.
pub fn check_pixels(path: &Path, image: &Image) -> Result<(), IoError> {
    if let Some((col, row)) = image.first_non_finite() {
        return Err(IoError::NonFinite {
            path: path.to_path_buf(),
            location: format!("pixel (col {col}, row {row})"),
            value: image.get(col, row),
        });
    }
    if let Some(i) = image.data.iter().position(|&v| v < 0.0) {
        return Err(IoError::invalid(
            path,
            format!(
                "pixel (col {}, row {}) is {}; pixel values are emitted light and must not be negative \
                 (clip background-subtracted images at 0)",
                i % image.width,
                i / image.width,
                image.data[i]
            ),
        ));
    }
    if let Some(i) = image.data.iter().position(|&v| v > MAX_PIXEL) {
        return Err(IoError::invalid(
            path,
            format!(
                "pixel (col {}, row {}) is {:e}, above {MAX_PIXEL:e}, where 32-bit arithmetic overflows: a corrupt \
                 or hot pixel, or values that need rescaling (the scene's intensity_scale takes the units)",
                i % image.width,
                i / image.width,
                image.data[i]
            ),
        ));
    }
    Ok(())
}

/// The first image whose sample kind differs from the most common one, with both kinds.
pub fn odd_sample_kind(kinds: &[SampleKind]) -> Option<(usize, SampleKind, SampleKind)> {
    let mut counts: std::collections::BTreeMap<SampleKind, usize> = std::collections::BTreeMap::new();
    for k in kinds {
        *counts.entry(*k).or_default() += 1;
    }
    let usual = counts.iter().max_by_key(|(_, n)| **n).map(|(k, _)| *k)?;
    kinds.iter().position(|k| *k != usual).map(|i| (i, kinds[i], usual))
}

/// Reads the scene's ground-truth volumes (`.npy`, filling the scene's aabb) with their times,
/// in file order. Refuses, naming the file, a volume that is unreadable, not 3-D, holds NaN or
/// infinite values, or whose shape differs from the first volume's.
pub fn load_truth(scene: &Scene) -> Result<Vec<(Option<f64>, Volume)>, IoError> {
    let mut out: Vec<(Option<f64>, Volume)> = Vec::with_capacity(scene.truth.len());
    for t in &scene.truth {
        let path = scene.resolve(&t.file_path);
        let v = crate::volume::read_npy(&path, scene.aabb)?;
        if let Some(i) = v.data.iter().position(|x| !x.is_finite()) {
            let (nx, ny) = (v.dims[0], v.dims[1]);
            return Err(IoError::NonFinite {
                path,
                location: format!("voxel (i {}, j {}, k {})", i % nx, (i / nx) % ny, i / (nx * ny)),
                value: v.data[i],
            });
        }
        if let Some((_, first)) = out.first() {
            if first.dims != v.dims {
                let [a, b, c] = first.dims;
                let [x, y, z] = v.dims;
                return Err(IoError::invalid(
                    path,
                    format!(
                        "{x}x{y}x{z} voxels (nx x ny x nz), but the scene's first truth volume has {a}x{b}x{c}; \
                         all truth volumes must share one grid"
                    ),
                ));
            }
        }
        out.push((t.time, v));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {

    #[test]
    fn pixels_that_would_overflow_are_refused_naming_the_pixel() {
        let path = Path::new("images/cam001.tif");
        let mut image = Image { width: 4, height: 3, data: vec![1.0; 12] };
        check_pixels(path, &image).expect("ordinary pixels");
        image.data[9] = MAX_PIXEL;
        check_pixels(path, &image).expect("the limit itself");
        image.data[9] = 3e38;
        let err = check_pixels(path, &image).expect_err("3e38 overflows").to_string();
        assert!(err.contains("cam001.tif") && err.contains("col 1, row 2") && err.contains("3e38"), "{err}");
    }
    use super::*;
    use fluidnerf_core::glam::DVec2;

    /// A camera's calibration copied to another camera of the same instant was accepted
    /// without a word, the scene then holding one view fewer than its cameras. Reported once
    /// per pair of cameras, however many instants they share; one camera at several instants,
    /// and cameras apart, are not reported.
    #[test]
    fn cameras_of_one_instant_at_one_place_are_reported_once_per_pair() {
        let mut scene = ring_scene(Path::new("."), 4, Distortion::default());
        for f in &mut scene.frames {
            f.time = None;
        }
        assert_eq!(cameras_at_one_place(&scene), []);
        scene.frames[2].camera = scene.frames[1].camera.clone();
        assert_eq!(cameras_at_one_place(&scene), [OnePlace { frames: (1, 2), instants: 1 }]);
        let says = describe_one_place(&scene, &cameras_at_one_place(&scene)[0]);
        assert!(
            says.contains("frame 1 (images/c1.tif, camera cam1) and frame 2 (images/c2.tif, camera cam2)")
                && says.contains("looking the same way"),
            "{says}"
        );
        // Unnamed, the same two frames.
        scene.frames.iter_mut().for_each(|f| f.camera_name = None);
        assert_eq!(cameras_at_one_place(&scene), [OnePlace { frames: (1, 2), instants: 1 }]);

        // Two instants: cam1 and cam2 at one place at both (one report); each camera at its own
        // place at both instants is not reported.
        let mut timed = ring_scene(Path::new("."), 3, Distortion::default());
        timed.frames[2].camera = timed.frames[1].camera.clone();
        let mut later = timed.frames.clone();
        for f in &mut later {
            f.time = Some(1.0);
        }
        for f in &mut timed.frames {
            f.time = Some(0.0);
        }
        timed.frames.extend(later);
        assert_eq!(cameras_at_one_place(&timed), [OnePlace { frames: (1, 2), instants: 2 }]);
        let says = describe_one_place(&timed, &cameras_at_one_place(&timed)[0]);
        assert!(says.contains("at 2 instants"), "{says}");
    }

    fn ring_scene(root: &Path, n: usize, distortion: Distortion) -> Scene {
        let aabb = Aabb::cube(DVec3::ZERO, 20.0);
        let frames = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                let k = Intrinsics { width: 32, height: 24, fx: 40.0, fy: 41.25, cx: 15.5, cy: 11.25, skew: 0.0 };
                let mut camera =
                    Camera::look_at(k, DVec3::new(80.0 * a.cos(), 80.0 * a.sin(), 15.0), DVec3::ZERO, DVec3::Z);
                camera.distortion = distortion;
                if i == 0 {
                    camera.lens = Some(ThinLens::from_f_number(60.0, 3.5, -0.2, 0.01));
                }
                Frame {
                    camera,
                    file_path: PathBuf::from(format!("images/c{i}.tif")),
                    time: Some(0.5 * i as f64),
                    camera_name: Some(format!("cam{i}")),
                    holdout: i == n - 1,
                }
            })
            .collect();
        Scene {
            root: root.to_path_buf(),
            aabb,
            units: "mm".into(),
            intensity_scale: 2.5,
            frames,
            truth: vec![TruthRef { time: Some(0.0), file_path: PathBuf::from("truth/t0.npy") }],
        }
    }

    #[test]
    fn write_read_round_trip_is_identical() {
        let dir = tempfile::tempdir().expect("tempdir");
        let dist = Distortion { k1: -0.1, k2: 0.02, p1: 1e-3, p2: -2e-3, k3: 0.001, k4: 0.01, k5: 0.0, k6: 0.0 };
        let scene = ring_scene(dir.path(), 4, dist);
        save_scene(&scene, dir.path()).expect("save");
        let back = load_scene(dir.path()).expect("load");
        assert_eq!(back, scene);
        let text = std::fs::read_to_string(dir.path().join(SCENE_FILE)).expect("read");
        assert!(text.contains("\"camera_model\": \"OPENCV\"") && text.contains("\"opencv_k4\": 0.01"), "{text}");

        // Per-frame intrinsics when they differ, with principal points that are not exact in
        // binary after ±0.5.
        let mut scene = ring_scene(dir.path(), 3, Distortion::default());
        scene.frames[1].camera.intrinsics.cx = 0.1;
        scene.frames[2].camera.intrinsics.fx = 39.7;
        let file = dir.path().join("other.json");
        save_scene(&scene, &file).expect("save");
        let back = load_scene(&file).expect("load");
        for (a, b) in scene.frames.iter().zip(&back.frames) {
            assert!((a.camera.intrinsics.cx - b.camera.intrinsics.cx).abs() < 1e-15);
            let mut b = b.clone();
            b.camera.intrinsics.cx = a.camera.intrinsics.cx;
            b.camera.intrinsics.cy = a.camera.intrinsics.cy;
            assert_eq!(&b, a);
        }
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("read")).expect("json");
        assert!(v.get("fl_x").is_none() && v["frames"][2]["fl_x"] == 39.7);
    }

    /// A 3D point on the ray nerfstudio generates for pixel (col, row) projects, with our
    /// camera read from the same file, to exactly (col, row): the +0.5 shift is right.
    #[test]
    fn nerfstudio_rays_land_on_our_pixels() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (fx, fy, cx, cy) = (50.0, 52.0, 16.0, 12.0);
        // An arbitrary rotation (OpenGL camera-to-world) and centre.
        let r = DMat3::from_euler(fluidnerf_core::glam::EulerRot::ZYX, 0.3, -0.4, 1.1);
        let t = DVec3::new(3.0, -60.0, 7.0);
        let mut m = [[0.0; 4]; 4];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] = r.col(j)[i];
            }
            m[i][3] = t[i];
        }
        m[3][3] = 1.0;
        // A box 37 units in front of the camera (OpenGL cameras look along −z).
        let ahead = t + 37.0 * (r * DVec3::new(0.0, 0.0, -1.0));
        let (lo, hi) = ((ahead - 5.0).to_array(), (ahead + 5.0).to_array());
        let json = serde_json::json!({
            "camera_model": "PINHOLE", "w": 32, "h": 24, "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
            "aabb": [lo, hi],
            "frames": [{"file_path": "a.png", "transform_matrix": m}]
        });
        std::fs::write(dir.path().join(SCENE_FILE), json.to_string()).expect("write");
        let scene = load_scene(dir.path()).expect("load");
        let cam = &scene.frames[0].camera;
        for (col, row) in [(0usize, 0usize), (31, 0), (7, 19), (31, 23)] {
            // nerfstudio: coords = index + 0.5; dir_gl = ((x − cx)/fx, −(y − cy)/fy, −1).
            let (x, y) = (col as f64 + 0.5, row as f64 + 0.5);
            let dir = r * DVec3::new((x - cx) / fx, -(y - cy) / fy, -1.0);
            let p = t + 37.0 * dir;
            let uv = cam.project(p).expect("in front");
            assert!((uv - DVec2::new(col as f64, row as f64)).length() < 1e-9, "pixel ({col}, {row}) -> {uv}");
        }
    }

    #[test]
    fn per_frame_keys_override_global_ones() {
        let dir = tempfile::tempdir().expect("tempdir");
        let scene = ring_scene(dir.path(), 2, Distortion::default());
        save_scene(&scene, dir.path()).expect("save");
        let file = dir.path().join(SCENE_FILE);
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&file).expect("read")).expect("json");
        v["frames"][1]["fl_x"] = serde_json::json!(44.0);
        v["frames"][1]["k1"] = serde_json::json!(-0.01);
        v["frames"][0]["colmap_im_id"] = serde_json::json!(3);
        std::fs::write(&file, v.to_string()).expect("write");
        let back = load_scene(dir.path()).expect("load");
        assert_eq!(back.frames[0].camera.intrinsics.fx, 40.0);
        assert_eq!(back.frames[1].camera.intrinsics.fx, 44.0);
        assert_eq!(back.frames[1].camera.intrinsics.fy, 41.25);
        assert_eq!(back.frames[1].camera.distortion.k1, -0.01);
        assert_eq!(back.units, "mm");
    }

    fn write_json(dir: &Path, v: &serde_json::Value) -> PathBuf {
        let file = dir.join(SCENE_FILE);
        std::fs::write(&file, serde_json::to_string_pretty(v).expect("json")).expect("write");
        file
    }

    fn good_json(dir: &Path) -> serde_json::Value {
        let scene = ring_scene(dir, 3, Distortion::default());
        save_scene(&scene, dir).expect("save");
        serde_json::from_str(&std::fs::read_to_string(dir.join(SCENE_FILE)).expect("read")).expect("json")
    }

    /// A frame whose `file_path` is empty named the scene's folder as its image, and only
    /// reading the images failed, naming neither the frame nor the key.
    #[test]
    fn a_frame_without_an_image_path_is_refused_at_load() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let mut v = good_json(d);
        for empty in ["", "  "] {
            v["frames"][1]["file_path"] = empty.into();
            let m = load_scene(&write_json(d, &v)).expect_err("must fail").to_string();
            assert!(
                m.contains(&format!("frame 1, key `frames[1].file_path`: is {empty:?}, which names no image")),
                "{m}"
            );
            assert!(m.contains(SCENE_FILE), "{m}");
        }
    }

    /// A truth entry whose `file_path` is empty, or names a folder, loaded, and was refused only
    /// when the truth was read ("volume file is a folder"), naming neither the entry nor the
    /// key; one whose time is not finite (a scene built in memory) matched no instant.
    #[test]
    fn a_truth_entry_without_a_volume_or_a_time_is_refused_at_load() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        std::fs::create_dir_all(d.join("truth")).expect("mkdir");
        let mut v = good_json(d);
        v["truth"] = serde_json::json!([{ "file_path": "truth/t0.npy" }, { "file_path": "truth/t1.npy" }]);
        let cases = [("", "is \"\", which names no volume file"), ("  ", "is \"  \", which names no volume file")];
        for (path, says) in cases.into_iter().chain([("truth", "truth is a folder, not a volume file")]) {
            v["truth"][1]["file_path"] = path.into();
            let m = load_scene(&write_json(d, &v)).expect_err("must fail").to_string();
            assert!(m.contains(&format!("truth entry 1, key `truth[1].file_path`: {says}")), "{m}");
            assert!(m.contains(SCENE_FILE), "{m}");
        }
        let mut scene = ring_scene(d, 3, Distortion::default());
        for (i, f) in scene.frames.iter_mut().enumerate() {
            f.time = Some(i as f64);
        }
        scene.truth = vec![
            TruthRef { time: Some(0.0), file_path: "truth/t0.npy".into() },
            TruthRef { time: Some(f64::INFINITY), file_path: "truth/t1.npy".into() },
        ];
        let m = validate_scene(&scene, Path::new("x.json")).expect_err("must fail").to_string();
        assert!(m.contains("truth entry 1 (truth/t1.npy): its time inf is not a finite number"), "{m}");
    }

    #[test]
    fn frames_without_time_among_timed_ones_are_refused_by_name() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let msg = |v: &serde_json::Value| load_scene(&write_json(d, v)).expect_err("must fail").to_string();
        let mut v = good_json(d);
        v["frames"][1].as_object_mut().expect("object").remove("time");
        let m = msg(&v);
        assert!(m.contains("frame 1 (images/c1.tif) has no `time`") && m.contains("the other 2 frame(s)"), "{m}");
        v["frames"][2]["time"] = serde_json::Value::Null;
        let m = msg(&v);
        assert!(m.contains("frames 1 (images/c1.tif) and 2 (images/c2.tif) have no `time`"), "{m}");
        // A static scene has no time on any frame.
        v["frames"][0].as_object_mut().expect("object").remove("time");
        let scene = load_scene(&write_json(d, &v)).expect("a scene of one instant");
        assert!(scene.times().is_empty());
        // Many frames without time are counted past the first five.
        let mut scene = ring_scene(d, 8, Distortion::default());
        for (i, f) in scene.frames.iter_mut().enumerate() {
            f.time = (i == 7).then_some(1.0);
        }
        let m = validate_scene(&scene, Path::new("x.json")).expect_err("must fail").to_string();
        assert!(m.contains("frames 0 (images/c0.tif), 1 (") && m.contains("4 (images/c4.tif) and 2 more have"), "{m}");
    }

    /// Times a 32-bit time input reads as infinite are refused naming the frame and its time,
    /// for a scene built in memory (as Python's `scene_from_arrays` builds one) as for a file;
    /// far apart but evenly spaced, they are kept.
    #[test]
    fn frame_times_beyond_a_32_bit_time_input_are_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut scene = ring_scene(dir.path(), 3, Distortion::default());
        for (f, t) in scene.frames.iter_mut().zip([0.0, 1.0, 1e39]) {
            f.time = Some(t);
        }
        let m = validate_scene(&scene, Path::new("x.json")).expect_err("must fail").to_string();
        assert!(m.contains("frame 2 (images/c2.tif) at 1e39 lies 1.000e39 time steps of Δt = 1"), "{m}");
        for (f, t) in scene.frames.iter_mut().zip([1e308, 1.5e308, 1.7e308]) {
            f.time = Some(t);
        }
        validate_scene(&scene, Path::new("x.json")).expect("2.5 and 3.5 steps of the smallest gap");
    }

    /// Times that name one instant, or a camera twice at one, are written as numbers are in
    /// every message (`num`): 1e-300 filled the message with 300 digits, 1e300 with 301.
    #[test]
    fn frame_times_in_refusals_are_written_short() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut scene = ring_scene(dir.path(), 3, Distortion::default());
        for (f, t) in scene.frames.iter_mut().zip([0.0, 1e-300, 1.0]) {
            f.time = Some(t);
        }
        let m = validate_scene(&scene, Path::new("x.json")).expect_err("must fail").to_string();
        assert!(m.contains("frame 1 (images/c1.tif) at 1e-300 are one instant written two ways"), "{m}");
        for (f, t) in scene.frames.iter_mut().zip([1e300, 1e300, 2e300]) {
            f.time = Some(t);
            f.camera_name = Some("one".into());
        }
        let m = validate_scene(&scene, Path::new("x.json")).expect_err("must fail").to_string();
        assert!(m.contains("frames 0 and 1 are both camera \"one\" at time 1e300;"), "{m}");
        assert!(m.len() < 400, "{m}");
    }

    #[test]
    fn clear_errors_for_bad_scene_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let msg = |v: &serde_json::Value| load_scene(&write_json(d, v)).expect_err("must fail").to_string();

        // Camera that does not see the box.
        let mut v = good_json(d);
        v["aabb"] = serde_json::json!([[5000, 5000, 5000], [5010, 5010, 5010]]);
        let m = msg(&v);
        assert!(m.contains("frame 0") && m.contains("images/c0.tif") && m.contains("does not see"), "{m}");

        let mut v = good_json(d);
        v["frames"][1]["transform_matrix"][0][0] = serde_json::json!(3.0);
        let m = msg(&v);
        assert!(m.contains("frame 1") && m.contains("rotation"), "{m}");

        let mut v = good_json(d);
        v.as_object_mut().expect("object").remove("fl_y");
        let m = msg(&v);
        assert!(m.contains("fl_y") && m.contains("frame 0"), "{m}");

        let mut v = good_json(d);
        v.as_object_mut().expect("object").remove("aabb");
        let m = msg(&v);
        assert!(m.contains("aabb") && m.contains(SCENE_FILE), "{m}");

        let mut v = good_json(d);
        v["frames"] = serde_json::json!([]);
        assert!(msg(&v).contains("no frames"));

        // A unit that cannot label an axis.
        for bad in ["", "  ", "mm\n", " mm"] {
            let mut v = good_json(d);
            v["units"] = serde_json::json!(bad);
            let m = msg(&v);
            assert!(m.contains("`units`") && m.contains(SCENE_FILE), "{bad:?}: {m}");
        }
        let mut v = good_json(d);
        v["units"] = serde_json::json!("µm");
        assert_eq!(load_scene(&write_json(d, &v)).expect("µm is a unit").units, "µm");

        let mut v = good_json(d);
        v["camera_model"] = serde_json::json!("OPENCV_FISHEYE");
        assert!(msg(&v).contains("OPENCV_FISHEYE"));

        let mut v = good_json(d);
        v["k4"] = serde_json::json!(0.1);
        assert!(msg(&v).contains("k4"));

        let mut v = good_json(d);
        v["aabb"] = serde_json::json!([[0, 0, 0], [1, -1, 1]]);
        assert!(msg(&v).contains("aabb"));

        let file = d.join(SCENE_FILE);
        std::fs::write(&file, "{\n  \"aabb\": [[0,0,0],[1,1,1]],\n  \"frames\": [,]\n}").expect("write");
        let m = load_scene(d).expect_err("malformed").to_string();
        assert!(m.contains(SCENE_FILE) && m.contains("malformed JSON") && m.contains("line 3"), "{m}");

        let m = load_scene(&d.join("nowhere")).expect_err("missing").to_string();
        assert!(m.contains("scene file not found") && m.contains("nowhere"), "{m}");
        // A run's folder given for its scene is named as such, with the scene it was made from.
        let run = d.join("run");
        std::fs::create_dir(&run).expect("mkdir");
        std::fs::write(run.join("config.json"), r#"{"scene": "/data/jet15", "method": {"name": "asart"}}"#)
            .expect("writes");
        let m = load_scene(&run).expect_err("a run folder").to_string();
        let want = "is a reconstruction run folder, not a scene folder (it has no transforms.json); give the scene \
                    it was made from (/data/jet15)";
        assert!(m.contains(want), "{m}");
        std::fs::write(run.join("config.json"), "{").expect("writes");
        let m = load_scene(&run).expect_err("a run folder").to_string();
        assert!(m.contains("is a reconstruction run folder") && m.contains("no transforms.json"), "{m}");
    }

    #[test]
    fn images_and_truth_load_with_checks() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let scene = ring_scene(d, 3, Distortion::default());
        for (i, f) in scene.frames.iter().enumerate() {
            let img = Image::from_vec(32, 24, vec![i as f32; 32 * 24]);
            crate::image::write_tiff_f32(&scene.resolve(&f.file_path), &img).expect("write");
        }
        let vol = Volume::from_fn([4, 4, 4], scene.aabb, |p| p.x as f32);
        crate::volume::write_npy(&d.join("truth/t0.npy"), &vol).expect("npy");
        let images = load_images(&scene).expect("images");
        assert_eq!(images.len(), 3);
        assert_eq!(images[2].data[0], 2.0);
        let truth = load_truth(&scene).expect("truth");
        assert_eq!(truth, vec![(Some(0.0), vol)]);

        crate::image::write_tiff_f32(&d.join("images/c1.tif"), &Image::zeros(31, 24)).expect("write");
        let m = load_images(&scene).expect_err("size").to_string();
        assert!(m.contains("c1.tif") && m.contains("31x24") && m.contains("32x24"), "{m}");

        let mut bad = Image::zeros(32, 24);
        bad.set(5, 6, f32::INFINITY);
        crate::image::write_tiff_f32(&d.join("images/c1.tif"), &bad).expect("write");
        let m = load_images(&scene).expect_err("inf").to_string();
        assert!(m.contains("c1.tif") && m.contains("col 5, row 6") && m.contains("inf"), "{m}");

        let mut bad_truth = Volume::from_fn([4, 4, 4], scene.aabb, |_| 1.0);
        let at = bad_truth.index(1, 2, 3);
        bad_truth.data[at] = f32::NAN;
        crate::volume::write_npy(&d.join("truth/t0.npy"), &bad_truth).expect("npy");
        let m = load_truth(&scene).expect_err("nan").to_string();
        assert!(m.contains("t0.npy") && m.contains("voxel (i 1, j 2, k 3)") && m.contains("NaN"), "{m}");

        std::fs::remove_file(d.join("images/c1.tif")).expect("rm");
        let m = load_images(&scene).expect_err("missing").to_string();
        assert!(m.contains("image file not found") && m.contains("c1.tif"), "{m}");
    }

    #[test]
    fn load_images_refuses_mixed_depths_and_negative_pixels() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let mut scene = ring_scene(d, 3, Distortion::default());
        for (i, f) in scene.frames.iter_mut().enumerate() {
            f.file_path = PathBuf::from(format!("images/c{i}.png"));
            crate::image::write_png16_counts(&d.join(&f.file_path), &Image::from_vec(32, 24, vec![300.0; 32 * 24]))
                .expect("write");
        }
        assert_eq!(load_images(&scene).expect("images").len(), 3);
        image::GrayImage::from_raw(32, 24, vec![1; 32 * 24]).expect("buf").save(d.join("images/c1.png")).expect("save");
        let m = load_images(&scene).expect_err("mixed").to_string();
        assert!(m.contains("c1.png") && m.contains("frame 1 is an 8-bit image") && m.contains("16-bit"), "{m}");

        let mut bad = Image::from_vec(32, 24, vec![1.0; 32 * 24]);
        bad.set(4, 7, -2.0);
        scene.frames[1].file_path = PathBuf::from("images/c1.tif");
        crate::image::write_tiff_f32(&d.join("images/c1.tif"), &bad).expect("write");
        let m = load_images(&scene).expect_err("negative").to_string();
        assert!(m.contains("c1.tif") && m.contains("pixel (col 4, row 7) is -2"), "{m}");
    }

    #[test]
    fn the_recorded_linearisation_is_applied() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let mut scene = ring_scene(d, 2, Distortion::default());
        scene.truth.clear();
        for (i, f) in scene.frames.iter_mut().enumerate() {
            f.file_path = PathBuf::from(format!("images/c{i}.png"));
            std::fs::create_dir_all(d.join("images")).expect("mkdir");
            image::GrayImage::from_raw(32, 24, vec![128; 32 * 24])
                .expect("buf")
                .save(d.join(&f.file_path))
                .expect("save");
        }
        save_scene_with(&scene, d, Some(Linearisation::Gamma(2.0))).expect("save");
        let loaded = load_scene(d).expect("load");
        let v = load_images(&loaded).expect("images")[0].data[0];
        assert!((f64::from(v) - 255.0 * (128.0f64 / 255.0).powi(2)).abs() < 1e-3, "{v}");
        save_scene(&scene, d).expect("save");
        assert_eq!(load_images(&scene).expect("images")[0].data[0], 128.0, "no key: linear");
    }

    /// The median of an odd count is the middle value, of an even count the mean of the two
    /// middle ones, pixel by pixel whatever the order of the images.
    #[test]
    fn the_median_image_takes_the_middle_of_each_pixel() {
        let im = |v: [f32; 2]| Image::from_vec(2, 1, v.to_vec());
        let odd = median_image(&[im([1.0, 30.0]), im([5.0, 10.0]), im([3.0, 20.0])]);
        assert_eq!(odd.data, [3.0, 20.0]);
        let even = median_image(&[im([10.0, 1.0]), im([1.0, 2.0]), im([4.0, 3.0]), im([2.0, 100.0])]);
        assert_eq!(even.data, [3.0, 2.5]);
        assert_eq!((even.width, even.height), (2, 1));
        assert_eq!(median_image(&[im([7.0, 8.0])]).data, [7.0, 8.0]);
    }

    /// A flat is divided by the mean of its used pixels; pixels a mask leaves out are divided too,
    /// or set to 1 when too dark to divide by.
    #[test]
    fn a_flat_is_normalised_to_the_mean_of_its_used_pixels() {
        let mut flat = Image::from_vec(4, 1, vec![2.0, 4.0, 6.0, 8.0]);
        assert_eq!(normalise_flat(&mut flat, None), Ok((0.4, 1.6)));
        assert_eq!(flat.data, [0.4, 0.8, 1.2, 1.6]);
        // Used mean (4 + 6) / 2 = 5, not the mean of all four.
        let mut flat = Image::from_vec(4, 1, vec![0.0, 4.0, 6.0, 30.0]);
        assert_eq!(normalise_flat(&mut flat, Some(&[false, true, true, false])), Ok((0.8, 1.2)));
        assert_eq!(flat.data, [1.0, 0.8, 1.2, 6.0]);
    }

    /// A flat without light, or with used pixels too dark to divide by, is refused saying how
    /// many, the first and the box that holds them.
    #[test]
    fn a_flat_too_dark_to_divide_by_is_refused() {
        for data in [vec![0.0; 4], vec![-1.0, -2.0, 1.0, 1.0]] {
            let e = normalise_flat(&mut Image::from_vec(2, 2, data), None).expect_err("no light");
            assert!(e.contains("holds no light") && e.contains("over the 4 used pixel(s)"), "{e}");
        }
        // Pixel 4 is masked out: the mean of the other 11 is 100.2 / 11, 5 % of it 0.46.
        let mut data = vec![10.0; 12];
        data[5] = 0.2;
        data[11] = 0.0;
        data[4] = 0.0;
        data[6] = 20.0;
        let mut flat = Image::from_vec(4, 3, data);
        let e =
            normalise_flat(&mut flat, Some(&[true, true, true, true, false, true, true, true, true, true, true, true]))
                .expect_err("dark pixels");
        assert!(e.contains("has 2 of its 11 used pixel(s) at or below 5 % of its mean"), "{e}");
        assert!(e.contains("the first at (col 1, row 1) with 0.2, all within cols 1..=3, rows 1..=2"), "{e}");
        assert!(e.contains("20-fold"), "{e}");
    }

    #[test]
    fn the_odd_sample_kind_is_the_first_unlike_the_most_common() {
        let (b8, b16) = (SampleKind::Integer(8), SampleKind::Integer(16));
        assert_eq!(odd_sample_kind(&[b8, b8, b16, b8]), Some((2, b16, b8)));
        assert_eq!(odd_sample_kind(&[b16, b8, b8]), Some((0, b16, b8)));
        assert_eq!(odd_sample_kind(&[b16, b16]), None);
        assert_eq!(odd_sample_kind(&[]), None);
    }

    #[test]
    fn images_on_different_scales_are_told_how_far_apart() {
        for (a, b) in [(8, 16), (16, 8)] {
            let m = different_scales(SampleKind::Integer(a), SampleKind::Integer(b));
            assert!(m.contains("(an 8-bit image among 16-bit ones reads about 257 times too dark)"), "{m}");
        }
        let m = different_scales(SampleKind::Integer(12), SampleKind::Integer(16));
        assert!(m.contains("a 12-bit image among 16-bit ones reads about 16 times too dark"), "{m}");
        let m = different_scales(SampleKind::Integer(16), SampleKind::Float);
        assert!(m.contains("no common scale") && m.ends_with("convert the images to one bit depth"), "{m}");
    }

    #[test]
    fn a_length_unit_is_a_short_printable_name() {
        for ok in ["mm", "m", "µm", &"x".repeat(32), &"µ".repeat(32)] {
            assert_eq!(check_units(ok), Ok(()), "{ok:?}");
        }
        for (bad, why) in [
            ("", "must be named"),
            ("  ", "must be named"),
            (" mm", "surrounding blanks"),
            ("mm\n", "control characters"),
            ("m\u{7}m", "control characters"),
            (&"µ".repeat(33), "longer than 32 characters"),
        ] {
            let e = check_units(bad).expect_err(bad);
            assert!(e.contains(why), "{bad:?}: {e}");
        }
    }

    #[test]
    fn the_distance_to_a_box_is_zero_inside_and_euclidean_outside() {
        let aabb = Aabb::new(DVec3::new(-1.0, 0.0, 2.0), DVec3::new(1.0, 4.0, 3.0));
        assert_eq!(distance_to_box(&aabb, DVec3::new(0.0, 2.0, 2.5)), 0.0);
        assert_eq!(distance_to_box(&aabb, DVec3::new(1.0, 4.0, 3.0)), 0.0, "a corner");
        assert_eq!(distance_to_box(&aabb, DVec3::new(4.0, 2.0, 2.5)), 3.0);
        assert_eq!(distance_to_box(&aabb, DVec3::new(0.0, -2.0, 2.5)), 2.0);
        assert_eq!(distance_to_box(&aabb, DVec3::new(-4.0, 8.0, 2.5)), 5.0, "beyond an edge: 3, 4, 5");
        assert_eq!(distance_to_box(&aabb, DVec3::new(0.0, 2.0, 0.0)), 2.0);
    }

    /// Cameras outside the box but within 5 % of its diagonal are reported, with their distance;
    /// cameras inside it or farther are not.
    #[test]
    fn cameras_just_outside_the_box_are_reported() {
        let mut scene = ring_scene(Path::new("."), 5, Distortion::default());
        // The box is 20 wide: its diagonal 34.6, 5 % of it 1.73.
        let k = scene.frames[0].camera.intrinsics;
        let eyes = [
            DVec3::new(5.0, 0.0, 0.0),
            DVec3::new(11.0, 0.0, 0.0),
            DVec3::new(0.0, 0.0, -11.7),
            DVec3::new(11.8, 0.0, 0.0),
            DVec3::new(80.0, 0.0, 0.0),
        ];
        for (f, eye) in scene.frames.iter_mut().zip(eyes) {
            f.camera = Camera::look_at(k, eye, DVec3::new(0.0, 0.5, 0.0), DVec3::Y);
        }
        let near = cameras_near_box(&scene);
        assert_eq!(near.iter().map(|n| n.0).collect::<Vec<_>>(), [1, 2], "{near:?}");
        assert!((near[0].1 - 1.0).abs() < 1e-9 && (near[1].1 - 1.7).abs() < 1e-9, "{near:?}");
    }

    /// A file not named `.json` is no scene path, and a folder fluidnerf wrote of another kind
    /// is named for what it is, with where its scene is.
    #[test]
    fn scene_paths_of_another_kind_are_refused_saying_what_they_are() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        assert_eq!(scene_file_path(&d.join("s")), d.join("s").join(SCENE_FILE));
        assert_eq!(scene_file_path(&d.join("s/x.JSON")), d.join("s/x.JSON"));
        std::fs::write(d.join("notes.txt"), "x").expect("write");
        let e = check_scene_path(&d.join("notes.txt")).expect_err("a text file").to_string();
        assert!(e.contains("notes.txt") && e.contains("is a file, not a scene folder"), "{e}");
        std::fs::write(d.join("scene.json"), "{}").expect("write");
        check_scene_path(&d.join("scene.json")).expect("a scene file");
        check_scene_path(d).expect("a folder of no kind");
        let kinds = [
            ("run", "config.json", "{\"scene\": \"scenes/s1\"}", "is a reconstruction run folder, not a scene folder (it has no transforms.json); give the scene it was made from (scenes/s1)"),
            ("study", "study.json", "{}", "is a study folder, not a scene folder (it has no transforms.json); its scenes are the folders in its scenes/"),
            ("demo", "comparison.json", "{}", "; its scene is the folder scene/ in it"),
            ("export", "export.json", "{}", "is an export folder, not a scene folder (it has no transforms.json)"),
        ];
        for (name, file, text, says) in kinds {
            let folder = d.join(name);
            std::fs::create_dir(&folder).expect("mkdir");
            std::fs::write(folder.join(file), text).expect("write");
            let e = check_scene_path(&folder).expect_err(name).to_string();
            assert!(e.contains(says), "{name}: {e}");
            if name == "export" {
                assert!(e.ends_with("(it has no transforms.json)"), "{e}");
            }
        }
        let scene = d.join("scene");
        std::fs::create_dir(&scene).expect("mkdir");
        std::fs::write(scene.join(SCENE_FILE), "{}").expect("write");
        std::fs::write(scene.join("report.json"), "{}").expect("write");
        check_scene_path(&scene).expect("a scene folder, whatever else it holds");
    }

    /// OpenGL's camera looks down its −z with y up; OpenCV's down +z with y down: the identity
    /// in one is diag(1, −1, −1) in the other, and the two conversions undo each other.
    #[test]
    fn opengl_poses_turn_their_y_and_z_axes() {
        let rows = [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0], [0.0, 0.0, 0.0, 1.0]];
        let pose = opengl_c2w_to_world_from_camera(&rows);
        assert_eq!(pose.matrix3, DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0)));
        assert_eq!(pose.translation, DVec3::new(1.0, 2.0, 3.0));
        assert_eq!(world_from_camera_to_opengl_c2w(&pose), rows);
        let turned = DAffine3::from_mat3_translation(
            DMat3::from_axis_angle(DVec3::new(0.3, -0.5, 0.8).normalize(), 1.1),
            DVec3::new(-4.0, 0.5, 7.0),
        );
        let back = opengl_c2w_to_world_from_camera(&world_from_camera_to_opengl_c2w(&turned));
        assert!(back.abs_diff_eq(turned, 1e-15), "{back:?}");
        let gl = world_from_camera_to_opengl_c2w(&turned);
        // The OpenGL camera's −z (third column, negated) is the OpenCV camera's +z.
        let forward = DVec3::new(-gl[0][2], -gl[1][2], -gl[2][2]);
        assert!((forward - turned.matrix3.z_axis).length() < 1e-15);
        assert_eq!(gl[3], [0.0, 0.0, 0.0, 1.0]);
    }
}
