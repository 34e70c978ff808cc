//! Scenes: the reconstruction box, the calibrated frames (one image each) and optional ground
//! truth. The on-disk form is nerfstudio's `transforms.json` with fluidnerf's additions; reading
//! and writing it lives in `fluidnerf-io`. Paths here are as written in the file, relative to
//! [`Scene::root`] unless absolute.

use std::path::{Path, PathBuf};

use crate::{Aabb, Camera};

/// One image: the camera that took it, where it is, when it was taken.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub camera: Camera,
    /// Image file, relative to the scene root unless absolute.
    pub file_path: PathBuf,
    /// Acquisition time in the scene's time unit (`None` for static scenes).
    pub time: Option<f64>,
    /// Name of the physical camera, grouping its frames across time steps.
    pub camera_name: Option<String>,
    /// Kept out of training and used for validation.
    pub holdout: bool,
}

/// A ground-truth volume filling the scene's box, at one time.
#[derive(Clone, Debug, PartialEq)]
pub struct TruthRef {
    pub time: Option<f64>,
    /// `.npy` volume, relative to the scene root unless absolute.
    pub file_path: PathBuf,
}

/// A calibrated multi-camera recording.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Directory against which relative paths resolve (the folder holding `transforms.json`).
    pub root: PathBuf,
    /// Reconstruction box in world units.
    pub aabb: Aabb,
    /// Length unit of the world frame, e.g. `"mm"`.
    pub units: String,
    /// Pixel value = `intensity_scale × ∫E ds` (world units).
    pub intensity_scale: f64,
    pub frames: Vec<Frame>,
    pub truth: Vec<TruthRef>,
}

impl Scene {
    /// Resolves a path from the scene file against [`Scene::root`].
    pub fn resolve(&self, path: &Path) -> PathBuf {
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.root.join(path)
        }
    }

    /// Frames used for reconstruction (not held out).
    pub fn training_frames(&self) -> impl Iterator<Item = (usize, &Frame)> {
        self.frames.iter().enumerate().filter(|(_, f)| !f.holdout)
    }

    /// Frames held out for validation.
    pub fn holdout_frames(&self) -> impl Iterator<Item = (usize, &Frame)> {
        self.frames.iter().enumerate().filter(|(_, f)| f.holdout)
    }

    /// The distinct frame times in increasing order (empty for a static scene).
    pub fn times(&self) -> Vec<f64> {
        let mut t: Vec<f64> = self.frames.iter().filter_map(|f| f.time).collect();
        t.sort_by(f64::total_cmp);
        t.dedup();
        t
    }
}
