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
        frame_times(&self.frames)
    }

    /// The frame times no ground-truth volume is at, when the truth is given per time (some
    /// entry has a time): a time-resolved run writes a volume there but cannot score it, so its
    /// scores cover only the other times. Empty without truth, and for one volume without a
    /// time, which stands for every time.
    pub fn times_without_truth(&self) -> Vec<f64> {
        if !self.truth.iter().any(|t| t.time.is_some()) {
            return Vec::new();
        }
        let timed: Vec<f64> = self.truth.iter().filter_map(|t| t.time).collect();
        self.times().into_iter().filter(|&f| !timed.iter().any(|&t| same_time(f, t))).collect()
    }

    /// The instants of a recording of several instants that fewer cameras imaged than the
    /// recording has, in increasing time: a camera whose frame at that instant is missing
    /// (dropped, or left out of the scene), or a frame whose time was mistyped or jittered off
    /// its instant into one of its own. Cameras are told apart by their names; in a scene whose
    /// frames are not all named, an instant counts as short of cameras when it has fewer frames
    /// than the fullest instant. Held-out frames count: their camera imaged the instant.
    pub fn instants_short_of_cameras(&self) -> Vec<ShortInstant> {
        let times = self.times();
        if times.len() < 2 {
            return Vec::new();
        }
        let at = |t: f64| self.frames.iter().filter(move |f| f.time.is_some_and(|ft| same_time(ft, t)));
        let named: Option<Vec<&str>> = self.frames.iter().map(|f| f.camera_name.as_deref()).collect();
        let mut short = Vec::new();
        match named {
            Some(mut all) => {
                all.sort_unstable();
                all.dedup();
                for &t in &times {
                    let present: Vec<&str> = at(t).filter_map(|f| f.camera_name.as_deref()).collect();
                    let missing: Vec<String> =
                        all.iter().filter(|n| !present.contains(n)).map(|n| n.to_string()).collect();
                    if !missing.is_empty() {
                        short.push(ShortInstant {
                            time: t,
                            cameras: all.len() - missing.len(),
                            of: all.len(),
                            missing,
                        });
                    }
                }
            }
            None => {
                let counts: Vec<usize> = times.iter().map(|&t| at(t).count()).collect();
                let most = counts.iter().copied().max().unwrap_or(0);
                for (&t, &n) in times.iter().zip(&counts) {
                    if n < most {
                        short.push(ShortInstant { time: t, cameras: n, of: most, missing: Vec::new() });
                    }
                }
            }
        }
        short
    }

    /// The times of ground-truth volumes that no frame has, when the frames have times: a
    /// time-resolved run scores each instant against the volume at its time, so these are
    /// never scored there (a sign of a mistyped time).
    pub fn unmatched_truth_times(&self) -> Vec<f64> {
        let times = self.times();
        if times.is_empty() {
            return Vec::new();
        }
        self.truth.iter().filter_map(|t| t.time).filter(|&t| !times.iter().any(|&f| same_time(f, t))).collect()
    }
}

/// An instant of a recording that fewer cameras imaged than the recording has
/// ([`Scene::instants_short_of_cameras`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ShortInstant {
    pub time: f64,
    /// Cameras (or, in a scene of unnamed cameras, frames) at this instant.
    pub cameras: usize,
    /// Cameras of the recording (or frames of its fullest instant).
    pub of: usize,
    /// The names of the cameras without a frame at this instant (empty for unnamed cameras).
    pub missing: Vec<String>,
}

/// Whether two times name the same instant (equal to a relative 10⁻⁹, so that times written
/// and read back as text still match).
pub fn same_time(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * (1.0 + a.abs())
}

/// The distinct times of `frames` in increasing order (empty when none has a time).
pub fn frame_times(frames: &[Frame]) -> Vec<f64> {
    let mut t: Vec<f64> = frames.iter().filter_map(|f| f.time).collect();
    t.sort_by(f64::total_cmp);
    t.dedup();
    t
}

/// Settings of [`estimate_box`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxEstimateParams {
    /// Lattice points per axis of the search cube. Default 64.
    pub grid: usize,
    /// A pixel is bright when its value is at least `background + bright_fraction · (peak −
    /// background)`, with the background the image's median and the peak its maximum.
    /// Default 0.1.
    pub bright_fraction: f64,
    /// The hull's bounding box grows by this fraction of its size on every side (plus one
    /// lattice step). Default 0.1.
    pub margin_fraction: f64,
}

impl Default for BoxEstimateParams {
    fn default() -> Self {
        BoxEstimateParams { grid: 64, bright_fraction: 0.1, margin_fraction: 0.1 }
    }
}

/// A box found by [`estimate_box`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxEstimate {
    pub aabb: Aabb,
    /// Lattice points kept (inside the hull).
    pub points: usize,
    /// `true` when the box bounds the bright pixels' visual hull; `false` when no point was
    /// bright in every view and the box bounds the cameras' common view only.
    pub from_bright_pixels: bool,
}

/// Estimates a reconstruction box from calibrated views and their images: the bounding box of
/// a coarse visual hull, with a margin.
///
/// 1. Frames with the same camera (a time series) are merged into one view, their images by
///    the pixelwise maximum.
/// 2. The search region is a cube centred on the point closest, in least squares, to every
///    camera's optical axis, with half-side the largest distance from it to a camera centre
///    (the mean of the camera centres when the axes are parallel).
/// 3. A `grid`³ lattice of points fills the cube; the points that lie in front of every camera
///    and inside every image bound the common view.
/// 4. A second `grid`³ lattice fills the common view's bounds, grown by one step of the first
///    on every side; a point of it is kept when it is in the common view and on a bright pixel
///    (nearest pixel; see [`BoxEstimateParams`]) in every image.
/// 5. The box bounds the kept points, grown by one step of that lattice and `margin_fraction`
///    of its size on each side.
///
/// When no point is bright in every view, the common view alone is used. `None` when no
/// point is in the common view at all. `frames` and `images` pair up one to one.
pub fn estimate_box(frames: &[Frame], images: &[crate::Image], params: &BoxEstimateParams) -> Option<BoxEstimate> {
    use crate::glam::{DMat3, DVec3};
    assert_eq!(frames.len(), images.len(), "estimate_box: one image per frame");
    assert!(params.grid >= 2, "estimate_box: grid must be at least 2");
    // One view per distinct camera, its images merged by the maximum.
    let mut views: Vec<(&Camera, crate::Image)> = Vec::new();
    for (f, img) in frames.iter().zip(images) {
        assert_eq!((img.width, img.height), (f.camera.width(), f.camera.height()), "estimate_box: image size");
        match views.iter_mut().find(|(c, _)| **c == f.camera) {
            Some((_, merged)) => merged.data.iter_mut().zip(&img.data).for_each(|(m, v)| *m = m.max(*v)),
            None => views.push((&f.camera, img.clone())),
        }
    }
    if views.is_empty() {
        return None;
    }
    let thresholds: Vec<f32> = views
        .iter()
        .map(|(_, img)| {
            let mut sorted = img.data.clone();
            let mid = sorted.len() / 2;
            let (_, median, _) = sorted.select_nth_unstable_by(mid, f32::total_cmp);
            let median = *median;
            let peak = img.data.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            if peak > median {
                median + params.bright_fraction as f32 * (peak - median)
            } else {
                f32::INFINITY
            }
        })
        .collect();

    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for (cam, _) in &views {
        let d = cam.forward().normalize();
        let p = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * cam.centre();
    }
    let mean_centre = views.iter().map(|(c, _)| c.centre()).sum::<DVec3>() / views.len() as f64;
    let centre = if a.determinant().abs() > 1e-9 * views.len().pow(3) as f64 { a.inverse() * b } else { mean_centre };
    let half = views.iter().map(|(c, _)| (c.centre() - centre).length()).fold(0.0, f64::max);
    if !(centre.is_finite() && half.is_finite() && half > 0.0) {
        return None;
    }
    let n = params.grid;
    // Points of a `n`³ lattice from `origin`, `step` apart on each axis: the bounds and count
    // of those in the common view, and of those also bright in every view.
    type Found = (DVec3, DVec3, usize);
    let scan = |origin: DVec3, step: DVec3| -> (Found, Found) {
        let mut common = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY), 0usize);
        let mut bright = common;
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let p = origin + step * DVec3::new(i as f64, j as f64, k as f64);
                    let mut in_all = true;
                    let mut bright_all = true;
                    for ((cam, img), &t) in views.iter().zip(&thresholds) {
                        let Some(uv) = cam.project(p) else {
                            in_all = false;
                            break;
                        };
                        let (col, row) = (uv.x.round(), uv.y.round());
                        if !(col >= 0.0 && row >= 0.0 && col < img.width as f64 && row < img.height as f64) {
                            in_all = false;
                            break;
                        }
                        if img.get(col as usize, row as usize) < t {
                            bright_all = false;
                        }
                    }
                    if in_all {
                        common = (common.0.min(p), common.1.max(p), common.2 + 1);
                        if bright_all {
                            bright = (bright.0.min(p), bright.1.max(p), bright.2 + 1);
                        }
                    }
                }
            }
        }
        (common, bright)
    };
    // The cube reaching the farthest camera finds the common view; its lattice is far coarser
    // than the flow when the cameras stand many times its size away (cameras at 360 mm put
    // points 11 mm apart around a jet a few mm across, between which no point was bright in
    // every view), so the hull is sought on a second lattice filling the common view.
    let coarse = DVec3::splat(2.0 * half / (n - 1) as f64);
    let (common, _) = scan(centre - DVec3::splat(half), coarse);
    if common.2 == 0 {
        return None;
    }
    let (lo, hi) = (common.0 - coarse, common.1 + coarse);
    let step = (hi - lo) / (n - 1) as f64;
    let (fine_common, bright) = scan(lo, step);
    let (lo, hi, points, from_bright_pixels, step) = if bright.2 > 0 {
        (bright.0, bright.1, bright.2, true, step)
    } else if fine_common.2 > 0 {
        (fine_common.0, fine_common.1, fine_common.2, false, step)
    } else {
        (common.0, common.1, common.2, false, coarse)
    };
    let grow = (hi - lo) * params.margin_fraction + step;
    Some(BoxEstimate { aabb: Aabb::new(lo - grow, hi + grow), points, from_bright_pixels })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::glam::DVec3;
    use crate::{Image, Intrinsics};

    /// A frame at `time` of one small camera, for the time-matching tests.
    fn frame(time: Option<f64>) -> Frame {
        let k = Intrinsics { width: 8, height: 8, fx: 8.0, fy: 8.0, cx: 3.5, cy: 3.5, skew: 0.0 };
        let camera = Camera::look_at(k, DVec3::new(0.0, 0.0, 10.0), DVec3::ZERO, DVec3::Y);
        Frame { camera, file_path: "a.png".into(), time, camera_name: None, holdout: false }
    }

    /// A truth entry at `time`.
    fn truth(time: Option<f64>) -> TruthRef {
        TruthRef { time, file_path: "t.npy".into() }
    }

    /// A scene of `frames` and `truth`.
    fn timed_scene(frames: Vec<Frame>, truth: Vec<TruthRef>) -> Scene {
        Scene {
            root: ".".into(),
            aabb: Aabb::cube(DVec3::ZERO, 2.0),
            units: "mm".into(),
            intensity_scale: 1.0,
            frames,
            truth,
        }
    }

    #[test]
    fn truth_at_a_time_no_frame_has_is_found() {
        let mut scene = timed_scene(
            vec![frame(Some(14.0)), frame(Some(15.0))],
            vec![truth(Some(14.0)), truth(Some(-15.0)), truth(Some(15.0 + 1e-12))],
        );
        assert_eq!(scene.unmatched_truth_times(), vec![-15.0]);
        assert!(scene.times_without_truth().is_empty(), "15 is matched within 1e-9");
        // Frames without times (a static scene): every truth volume is the scene's.
        scene.frames = vec![frame(None)];
        assert!(scene.unmatched_truth_times().is_empty());
    }

    #[test]
    fn frame_times_without_truth_are_found() {
        let mut scene = timed_scene(
            vec![frame(Some(14.0)), frame(Some(15.0)), frame(Some(16.0))],
            vec![truth(Some(16.0)), truth(Some(14.0))],
        );
        assert_eq!(scene.times_without_truth(), vec![15.0]);
        // One volume without a time stands for every time; no truth leaves nothing to score.
        scene.truth = vec![truth(None)];
        assert!(scene.times_without_truth().is_empty());
        scene.truth.clear();
        assert!(scene.times_without_truth().is_empty());
        // Beside a timed one, a volume without a time covers no time.
        scene.truth = vec![truth(None), truth(Some(15.0))];
        assert_eq!(scene.times_without_truth(), vec![14.0, 16.0]);
    }

    fn named(time: f64, name: &str, holdout: bool) -> Frame {
        Frame { camera_name: Some(name.into()), holdout, ..frame(Some(time)) }
    }

    /// An instant a named camera has no frame at is short of it, a held-out frame counting as
    /// its camera's; without names, an instant with fewer frames than the fullest is short.
    #[test]
    fn instants_short_of_cameras_name_the_missing_ones() {
        let mut scene = timed_scene(
            vec![
                named(0.0, "A", false),
                named(0.0, "B", false),
                named(1.0, "A", false),
                named(2.0, "A", false),
                named(2.0, "B", true),
            ],
            vec![],
        );
        let short = vec![ShortInstant { time: 1.0, cameras: 1, of: 2, missing: vec!["B".to_string()] }];
        assert_eq!(scene.instants_short_of_cameras(), short);
        scene.frames.iter_mut().for_each(|f| f.camera_name = None);
        let short = vec![ShortInstant { time: 1.0, cameras: 1, of: 2, missing: vec![] }];
        assert_eq!(scene.instants_short_of_cameras(), short);
        // One instant is never short of itself.
        scene.frames.retain(|f| f.time == Some(1.0));
        assert!(scene.instants_short_of_cameras().is_empty());
    }

    #[test]
    fn scenes_split_frames_resolve_paths_and_match_times() {
        let mut scene = timed_scene(vec![frame(Some(2.0)), frame(Some(1.0)), frame(Some(2.0))], vec![]);
        scene.frames[1].holdout = true;
        scene.root = "/data/scene".into();
        assert_eq!(scene.training_frames().map(|(i, _)| i).collect::<Vec<_>>(), vec![0, 2]);
        assert_eq!(scene.holdout_frames().map(|(i, _)| i).collect::<Vec<_>>(), vec![1]);
        assert_eq!(scene.times(), vec![1.0, 2.0]);
        if cfg!(unix) {
            assert_eq!(scene.resolve(Path::new("images/a.png")), PathBuf::from("/data/scene/images/a.png"));
            assert_eq!(scene.resolve(Path::new("/elsewhere/a.png")), PathBuf::from("/elsewhere/a.png"));
        }
        assert!(same_time(1e6, 1e6 + 1e-4) && !same_time(1e6, 1e6 + 1e-2));
        assert!(same_time(0.0, 5e-10) && !same_time(0.0, 2e-9) && !same_time(-1.0, 1.0));
    }

    /// The ball of the box tests and six cameras at two heights around it, `scale` × 60 units
    /// from the axis with `scale` × 50 px focal lengths (the ball as large in the images at every
    /// scale), each with its image: the ball bright (1000) on a dim ground (5).
    fn ball_rig(scale: f64) -> (DVec3, f64, Vec<Frame>, Vec<Image>) {
        let (ball, radius) = (DVec3::new(3.0, -2.0, 1.0), 4.0);
        let f = 50.0 * scale;
        let k = Intrinsics { width: 48, height: 40, fx: f, fy: f, cx: 23.5, cy: 19.5, skew: 0.0 };
        let mut frames = Vec::new();
        let mut images = Vec::new();
        for c in 0..6 {
            let a = c as f64 / 6.0 * std::f64::consts::TAU;
            let z = if c % 2 == 0 { 25.0 } else { -20.0 };
            let centre = DVec3::new(60.0 * a.cos(), 60.0 * a.sin(), z) * scale;
            let camera = Camera::look_at(k, centre, DVec3::ZERO, DVec3::Z);
            let mut img = Image::from_vec(48, 40, vec![5.0; 48 * 40]);
            for row in 0..40 {
                for col in 0..48 {
                    let ray = camera.pixel_ray(col as f64, row as f64).expect("ray");
                    if (ray.at((ball - ray.origin).dot(ray.dir)) - ball).length() < radius {
                        img.set(col, row, 1000.0);
                    }
                }
            }
            frames.push(Frame {
                camera,
                file_path: format!("c{c}.png").into(),
                time: None,
                camera_name: None,
                holdout: false,
            });
            images.push(img);
        }
        (ball, radius, frames, images)
    }

    /// The estimate from `ball_rig(scale)` holds the ball and is not much larger.
    fn assert_box_bounds_the_ball(scale: f64) -> (Vec<Frame>, Vec<Image>) {
        let (ball, radius, frames, images) = ball_rig(scale);
        let est = estimate_box(&frames, &images, &BoxEstimateParams::default()).expect("a box");
        assert!(est.from_bright_pixels, "{est:?}");
        for axis in 0..3 {
            let (lo, hi) = (est.aabb.min[axis], est.aabb.max[axis]);
            assert!(lo <= ball[axis] - radius && hi >= ball[axis] + radius, "axis {axis}: {lo} .. {hi}");
            assert!(hi - lo < 2.0 * 2.0 * radius, "axis {axis}: {lo} .. {hi} is far larger than the ball");
        }
        (frames, images)
    }

    /// Cameras ten times farther from the ball than in the test below, with ten times the focal
    /// length, as a laboratory rig stands around a flow: the ball is as large in the images.
    /// The lattice of the cube reaching the cameras had its points 19 units apart around a
    /// ball of radius 4, none of them bright in every view, and the box fell back to the
    /// common view, 60 units across.
    #[test]
    fn a_bright_ball_seen_from_afar_bounds_the_estimated_box() {
        assert_box_bounds_the_ball(10.0);
    }

    /// Six cameras at two heights around a bright ball: the estimated box holds the ball and
    /// is not much larger; with black images the common view is used instead.
    #[test]
    fn estimated_box_bounds_a_bright_ball() {
        let (frames, images) = assert_box_bounds_the_ball(1.0);
        let dark: Vec<Image> = images.iter().map(|i| Image::zeros(i.width, i.height)).collect();
        let est = estimate_box(&frames, &dark, &BoxEstimateParams::default()).expect("common view");
        assert!(!est.from_bright_pixels);
        assert!(est.aabb.contains(DVec3::ZERO) && est.aabb.size().max_element() < 120.0, "{est:?}");
    }
}
