//! The whole generator: settings → truth volumes, cameras, images, sensor counts.
//!
//! [`generate`] validates every setting and estimates the memory it needs before any work
//! starts, then voxelises the phantom at each time, forms every camera's image with the chosen
//! model (from the voxel grid, like the dissertation, or from the continuous phantom), and
//! exposes the images on the sensor. It reports progress through a callback and never prints;
//! writing files is the caller's business ([`Synthesis::scene`] gives the scene description
//! with the file names it expects).

use std::ops::ControlFlow;
use std::path::PathBuf;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::num;
use fluidnerf_core::{Aabb, Frame, Image, Scene, TruthRef, Volume};
use serde::{Deserialize, Serialize};

use crate::image::{pinhole, thin_lens, Emitters, ImageModel};
use crate::phantom::{Phantom, PhantomKind, PhantomSettings};
use crate::real::{self, RealLike, RealRecording};
use crate::rig::{LensSettings, RigCamera, RigSettings};
use crate::sensor::SensorSettings;
use crate::SynthError;

/// Everything that defines a synthetic data set. Serialised next to the outputs, it reruns the
/// generation exactly.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SynthSettings {
    pub phantom: PhantomSettings,
    /// Reconstruction box, mm. Default: the 40 mm cube centred at the origin. The procedural
    /// phantoms fill it; the CFD ones stay in their simulation domain (`phantom::cfd::domain`).
    pub aabb: Aabb,
    /// Truth voxels along the box's longest side (cubic voxels). Default 128.
    pub resolution: usize,
    /// Frame times: t* for `jet-tr` (default 14, 15, 16), solver steps for `plume` and
    /// `cfd-jet` (empty: static at `phantom.cfd_step`); must be empty for the other phantoms.
    /// Made in time order whatever their order here ([`SynthSettings::time_steps`]).
    pub times: Vec<f64>,
    pub rig: RigSettings,
    pub lens: LensSettings,
    pub image: ImageModel,
    pub sensor: SensorSettings,
    /// Record a real-like recording instead of sensor counts (gains, background, dark noise,
    /// 8-bit sRGB JPEG images; [`crate::real`]). Default none.
    pub real: Option<RealLike>,
    /// Seed of every random choice (phantom, jitter, rays, noise). Default 0.
    pub seed: u64,
}

impl Default for SynthSettings {
    fn default() -> Self {
        SynthSettings {
            phantom: PhantomSettings::default(),
            aabb: Aabb::cube(DVec3::ZERO, 40.0),
            resolution: 128,
            times: Vec::new(),
            rig: RigSettings::default(),
            lens: LensSettings { resolution: [256, 256], ..Default::default() },
            image: ImageModel::default(),
            sensor: SensorSettings::default(),
            real: None,
            seed: 0,
        }
    }
}

impl SynthSettings {
    /// Checks every setting that needs no geometry (the rig's view of the box is checked by
    /// [`generate`]).
    pub fn validate(&self) -> Result<(), SynthError> {
        self.phantom.validate()?;
        self.aabb.validate()?;
        // Two voxels along the longest side at least: every reconstruction needs as many.
        if self.phantom.kind != PhantomKind::Volume && !(2..=4096).contains(&self.resolution) {
            return Err(SynthError::invalid("resolution", format!("must be in 2..=4096, got {}", self.resolution)));
        }
        if self.phantom.kind.is_time_resolved() {
            if self.times.is_empty() {
                return Err(SynthError::invalid("times", "a time-resolved phantom needs at least one time"));
            }
        } else if !self.phantom.kind.takes_times() && !self.times.is_empty() {
            return Err(SynthError::invalid(
                "times",
                format!("the {:?} phantom is static; give no times", self.phantom.kind),
            ));
        }
        if let Some(t) = self.times.iter().find(|t| !t.is_finite()) {
            return Err(SynthError::invalid("times", format!("must be finite, got {}", num(*t))));
        }
        if let Some((i, t)) = self.times.iter().enumerate().find(|&(i, t)| self.times[..i].contains(t)) {
            return Err(SynthError::invalid(
                "times",
                format!("{t} is given twice (times {:?}, the second at position {i}); give each time once", self.times),
            ));
        }
        // Times within a relative 1e-9 are one instant to every reader of the scene, which
        // refuses frames of one instant written two ways: the scene could not be reconstructed.
        let same = |i: usize, t: f64| self.times[..i].iter().find(|&&u| fluidnerf_core::scene::same_time(u, t));
        if let Some((i, t, u)) = self.times.iter().enumerate().find_map(|(i, &t)| same(i, t).map(|&u| (i, t, u))) {
            return Err(SynthError::invalid(
                "times",
                format!(
                    "{} and {} (the second at position {i}) are one instant to the scene's readers (times within a \
                     relative 1e-9 of each other); give times further apart, or each time once",
                    num(u),
                    num(t)
                ),
            ));
        }
        if self.phantom.kind.cfd_case().is_some() {
            if let Some(t) = self.times.iter().find(|&&t| crate::phantom::cfd::step_of(t).is_none()) {
                return Err(SynthError::invalid(
                    "times",
                    format!(
                        "the CFD phantoms' times are stored solver steps, one of {:?}; got {}",
                        crate::phantom::cfd::STEPS,
                        num(*t)
                    ),
                ));
            }
        }
        // A solver step that no phantom reads would be ignored without a word.
        if let Some(step) = self.phantom.cfd_step {
            if self.phantom.kind.cfd_case().is_none() {
                return Err(SynthError::invalid(
                    "phantom.cfd_step",
                    format!(
                        "step {step} applies to the CFD phantoms (plume, cfd-jet) only; the {:?} phantom has no \
                         solver steps",
                        self.phantom.kind
                    ),
                ));
            }
            if !self.times.is_empty() {
                return Err(SynthError::invalid(
                    "phantom.cfd_step",
                    format!(
                        "step {step} is the instant of a static scene, but times {:?} make a series of solver \
                         steps; give one or the other",
                        self.times
                    ),
                ));
            }
        }
        self.rig.validate()?;
        self.lens.validate()?;
        self.image.validate()?;
        self.sensor.validate()?;
        // A brightest pixel below one count rounds every image to black (a real-like
        // recording's 8-bit scale is 255 whatever the sensor's bit depth).
        let full = if self.real.is_some() { 255.0 } else { self.sensor.full_scale() };
        if self.sensor.full_scale_fraction * full < 1.0 {
            return Err(SynthError::invalid(
                "sensor.full_scale_fraction",
                format!(
                    "{} puts the brightest pixel at {:.3e} counts of full scale {full}: every image would round to \
                     black; give at least {:.3e} (one count)",
                    num(self.sensor.full_scale_fraction),
                    self.sensor.full_scale_fraction * full,
                    1.0 / full
                ),
            ));
        }
        if let Some(r) = &self.real {
            r.validate()?;
            // A real-like recording has its own noise and background and writes 8-bit JPEGs;
            // the plain sensor's settings would be ignored without a word.
            let defaults = SensorSettings::default();
            let ignored = [
                (
                    self.sensor.gaussian_noise != defaults.gaussian_noise,
                    "gaussian_noise",
                    "--noise",
                    "dark_noise",
                    "--dark-noise",
                ),
                (self.sensor.full_well.is_some(), "full_well", "--full-well", "dark_noise", "--dark-noise"),
                (
                    self.sensor.dark_offset != defaults.dark_offset,
                    "dark_offset",
                    "--dark-offset",
                    "background",
                    "--background-level",
                ),
                (
                    self.sensor.bit_depth != defaults.bit_depth,
                    "bit_depth",
                    "--bit-depth",
                    "jpeg_quality",
                    "--jpeg-quality",
                ),
            ];
            if let Some((_, key, flag, instead, instead_flag)) = ignored.iter().find(|i| i.0) {
                return Err(SynthError::invalid(
                    format!("sensor.{key}"),
                    format!(
                        "{flag} does not apply to a real-like recording, which writes 8-bit JPEGs with its own noise \
                         and background; set real.{instead} ({instead_flag}) instead, or record without `real`"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Time steps in time order, whatever order `times` gives them in (the frames, images and
    /// truth volumes follow it): `[None]` for static phantoms.
    pub fn time_steps(&self) -> Vec<Option<f64>> {
        if self.times.is_empty() {
            vec![None]
        } else {
            let mut times = self.times.clone();
            times.sort_by(f64::total_cmp);
            times.into_iter().map(Some).collect()
        }
    }

    /// Truth grid dimensions for a box.
    pub fn truth_dims(&self, aabb: &Aabb) -> [usize; 3] {
        Volume::dims_for(aabb, self.resolution)
    }

    /// Refuses settings whose [`Self::memory_bytes`] exceed the memory available now, for a
    /// truth grid of `voxels` cells: the allocation would abort the program part-way.
    pub fn check_memory(&self, voxels: u64) -> Result<(), SynthError> {
        let (truth, images) = self.memory_parts(voxels);
        let needed = truth.saturating_add(images);
        match available_memory_bytes() {
            Some(avail) if needed > avail => Err(SynthError::OutOfMemory {
                needed_mib: needed >> 20,
                available_mib: avail >> 20,
                truth_mib: truth >> 20,
                images_mib: images >> 20,
            }),
            _ => Ok(()),
        }
    }

    /// Peak memory of [`generate`] in bytes (truth volumes, emitters, images and per-thread
    /// accumulators), for a truth grid of `voxels` cells.
    pub fn memory_bytes(&self, voxels: u64) -> u64 {
        let (truth, images) = self.memory_parts(voxels);
        truth.saturating_add(images)
    }

    /// [`Self::memory_bytes`] in two parts: the truth's (volumes and emitters) and the
    /// images' (images and per-thread accumulators), so that a refusal can say which is large.
    fn memory_parts(&self, voxels: u64) -> (u64, u64) {
        let times = self.time_steps().len() as u64;
        let [w, h] = self.lens.resolution;
        let px = w as u64 * h as u64;
        let frames = self.rig.count() as u64 * times;
        let threads = rayon::current_num_threads() as u64;
        let mut truth = times.saturating_mul(voxels).saturating_mul(4);
        let mut images = frames.saturating_mul(px).saturating_mul(8);
        if let ImageModel::ThinLens(_) = self.image {
            truth = truth.saturating_add(voxels.saturating_mul(16));
            images = images.saturating_add(threads.saturating_mul(px).saturating_mul(32));
        }
        (truth, images)
    }
}

/// Memory the system can still hand out, from `/proc/meminfo` (`None` where unknown).
pub fn available_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// One image of the data set.
#[derive(Clone, Debug)]
pub struct SynthFrame {
    /// Index into [`Synthesis::cameras`].
    pub camera: usize,
    /// Index into [`Synthesis::truth`] (the time step).
    pub time_index: usize,
    pub time: Option<f64>,
    /// The noiseless image, `∫E ds` (field units × mm).
    pub clean: Image,
    /// Sensor counts (integers stored as f32): `≈ intensity_scale · clean + dark_offset`.
    pub counts: Image,
}

/// Work counters of a run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SynthStats {
    /// Rays traced (sub-pixel rays for the pinhole, voxel rays for the thin lens).
    pub rays: u64,
    /// Non-zero voxels cast by the thin lens, summed over time steps.
    pub emitters: u64,
    pub truth_seconds: f64,
    pub image_seconds: f64,
    pub sensor_seconds: f64,
}

/// A generated data set, in memory.
#[derive(Clone, Debug)]
pub struct Synthesis {
    pub settings: SynthSettings,
    pub aabb: Aabb,
    pub cameras: Vec<RigCamera>,
    /// Ground truth per time step.
    pub truth: Vec<(Option<f64>, Volume)>,
    pub frames: Vec<SynthFrame>,
    /// Counts per unit of `∫E ds` (see [`crate::sensor`]).
    pub intensity_scale: f64,
    pub stats: SynthStats,
    /// With [`SynthSettings::real`]: gains and background frames; the frames' `counts` are then
    /// the recorded linear images on the 0..=255 scale.
    pub real: Option<RealRecording>,
}

impl Synthesis {
    /// Relative path of a frame's image: `images/<camera>.png`, or `images/<camera>_t<k>.png`
    /// with `k` the time-step index for time-resolved data.
    pub fn image_path(&self, frame: &SynthFrame) -> PathBuf {
        let name = &self.cameras[frame.camera].name;
        let ext = if self.real.is_some() { "jpg" } else { "png" };
        if frame.time.is_some() {
            PathBuf::from(format!("images/{name}_t{:0w$}.{ext}", frame.time_index, w = self.time_digits()))
        } else {
            PathBuf::from(format!("images/{name}.{ext}"))
        }
    }

    /// Relative paths of camera `camera`'s background frames (real-like recordings):
    /// `background/<camera>_b<k>.jpg`.
    pub fn background_paths(&self, camera: usize) -> Vec<PathBuf> {
        let n = self.real.as_ref().map_or(0, |r| r.backgrounds[camera].len());
        (0..n).map(|k| PathBuf::from(format!("background/{}_b{k}.jpg", self.cameras[camera].name))).collect()
    }

    /// Relative paths of camera `camera`'s flat-field frames (real-like recordings with
    /// vignetting): `flat/<camera>_f<k>.jpg`.
    pub fn flat_paths(&self, camera: usize) -> Vec<PathBuf> {
        let n = self.real.as_ref().map_or(0, |r| r.flats[camera].len());
        (0..n).map(|k| PathBuf::from(format!("flat/{}_f{k}.jpg", self.cameras[camera].name))).collect()
    }

    /// The digits of the time-step indices in file names: as many as the last needs, at least
    /// two, so that the names sort in the steps' order (`_t99` before `_t100`).
    fn time_digits(&self) -> usize {
        self.truth.len().saturating_sub(1).to_string().len().max(2)
    }

    /// Relative path of a truth volume: `truth/truth.npy` or `truth/truth_t<k>.npy`.
    pub fn truth_path(&self, time_index: usize) -> PathBuf {
        if self.truth[time_index].0.is_some() {
            PathBuf::from(format!("truth/truth_t{time_index:0w$}.npy", w = self.time_digits()))
        } else {
            PathBuf::from("truth/truth.npy")
        }
    }

    /// The scene description (mm, paths as from [`Synthesis::image_path`] and
    /// [`Synthesis::truth_path`], relative to `root`).
    pub fn scene(&self, root: PathBuf) -> Scene {
        let frames = self
            .frames
            .iter()
            .map(|f| {
                let cam = &self.cameras[f.camera];
                Frame {
                    camera: cam.camera.clone(),
                    file_path: self.image_path(f),
                    time: f.time,
                    camera_name: Some(cam.name.clone()),
                    holdout: cam.holdout,
                }
            })
            .collect();
        let truth =
            (0..self.truth.len()).map(|k| TruthRef { time: self.truth[k].0, file_path: self.truth_path(k) }).collect();
        Scene {
            root,
            aabb: self.aabb,
            units: crate::UNITS.into(),
            intensity_scale: self.intensity_scale,
            frames,
            truth,
        }
    }
}

/// Progress of [`generate`]: `done` of `total` steps (one per truth volume and one per image).
#[derive(Clone, Debug, PartialEq)]
pub struct Progress {
    pub stage: &'static str,
    pub done: usize,
    pub total: usize,
}

/// Generates a data set. `volume` is the ground truth for [`PhantomKind::Volume`] (its box
/// replaces `settings.aabb`). `on_progress` may stop the run with `ControlFlow::Break`.
pub fn generate(
    settings: &SynthSettings,
    volume: Option<Volume>,
    mut on_progress: impl FnMut(&Progress) -> ControlFlow<()>,
) -> Result<Synthesis, SynthError> {
    settings.validate()?;
    let aabb = match (&volume, settings.phantom.kind) {
        (Some(v), PhantomKind::Volume) => v.aabb,
        (None, PhantomKind::Volume) => {
            return Err(SynthError::invalid("phantom.kind", "`volume` needs a ground-truth volume"))
        }
        _ => settings.aabb,
    };
    let dims = match (&volume, settings.phantom.kind) {
        (Some(v), PhantomKind::Volume) => v.dims,
        _ => settings.truth_dims(&aabb),
    };
    let voxels = dims.iter().map(|&n| n as u64).product::<u64>();
    settings.check_memory(voxels)?;
    let cameras = settings.rig.build(&settings.lens, &aabb, settings.seed)?;
    let phantom = Phantom::build(&settings.phantom, &aabb, settings.seed, volume)?;
    let steps = settings.time_steps();
    let total = steps.len() * (1 + cameras.len());
    let mut done = 0usize;
    let mut tick = |stage: &'static str, done: &mut usize| -> Result<(), SynthError> {
        *done += 1;
        match on_progress(&Progress { stage, done: *done, total }) {
            ControlFlow::Continue(()) => Ok(()),
            ControlFlow::Break(()) => Err(SynthError::Cancelled),
        }
    };
    let mut stats = SynthStats::default();
    let mut truth = Vec::with_capacity(steps.len());
    let mut frames = Vec::with_capacity(total);
    for (ti, &time) in steps.iter().enumerate() {
        let t0 = std::time::Instant::now();
        let vol = match &phantom {
            Phantom::Volume(v) => v.clone(),
            Phantom::Cfd(c) => c.truth(time, dims, &aabb),
            p => Volume::from_field(dims, aabb, p, time.unwrap_or(0.0)),
        };
        stats.truth_seconds += t0.elapsed().as_secs_f64();
        tick("truth", &mut done)?;
        let t0 = std::time::Instant::now();
        let emitters = match &settings.image {
            ImageModel::ThinLens(s) => {
                let e = Emitters::from_volume(&vol, s.threshold);
                stats.emitters += e.len() as u64;
                Some(e)
            }
            ImageModel::Pinhole(_) => None,
        };
        stats.image_seconds += t0.elapsed().as_secs_f64();
        for (ci, cam) in cameras.iter().enumerate() {
            let t0 = std::time::Instant::now();
            let stream = (ti * cameras.len() + ci) as u64;
            let clean = match &settings.image {
                ImageModel::ThinLens(s) => {
                    let e = emitters
                        .as_ref()
                        .ok_or_else(|| SynthError::invalid("image", "no emitters for the thin-lens model"))?;
                    let (img, rays) =
                        thin_lens::render(e, &cam.camera, s, 1.0, thin_lens::mix_seed(settings.seed, stream))?;
                    stats.rays += rays;
                    img
                }
                ImageModel::Pinhole(s) if s.analytic => {
                    let step = s.step_fraction * vol.spacing().min_element();
                    let img = pinhole::render_field(
                        &phantom,
                        &cam.camera,
                        &aabb,
                        s.supersample,
                        step,
                        time.unwrap_or(0.0),
                        1.0,
                    )?;
                    stats.rays += (img.width * img.height * s.supersample * s.supersample) as u64;
                    img
                }
                ImageModel::Pinhole(s) => {
                    let (img, rays) = pinhole::render_volume_counting(&vol, &cam.camera, s, 1.0)?;
                    stats.rays += rays;
                    img
                }
            };
            if let Some((c, r)) = clean.first_non_finite() {
                return Err(SynthError::invalid(
                    "phantom",
                    format!("image of camera {} has a non-finite pixel at ({c}, {r})", cam.name),
                ));
            }
            stats.image_seconds += t0.elapsed().as_secs_f64();
            frames.push(SynthFrame { camera: ci, time_index: ti, time, counts: Image::zeros(0, 0), clean });
            tick("images", &mut done)?;
        }
        truth.push((time, vol));
    }
    let t0 = std::time::Instant::now();
    let peak = frames.iter().map(|f| f.clean.min_max().1 as f64).fold(0.0, f64::max);
    if peak <= 0.0 {
        return Err(all_black(settings, &truth, cameras.len()));
    }
    let dark: Vec<String> = (0..steps.len())
        .filter(|&ti| frames.iter().filter(|f| f.time_index == ti).all(|f| f.clean.min_max().1 <= 0.0))
        .filter_map(|ti| steps[ti].map(|t| num(t).to_string()))
        .collect();
    if !dark.is_empty() {
        log::warn!("every image at time {} is black: the phantom shows no light then", dark.join(", "));
    }
    let sensor_seed = settings.seed ^ 0x6e6f_6973_6521;
    let (intensity_scale, real) = match &settings.real {
        None => {
            let intensity_scale = settings.sensor.intensity_scale(peak);
            for (k, f) in frames.iter_mut().enumerate() {
                f.counts = settings.sensor.expose(&f.clean, intensity_scale, sensor_seed, k as u64)?;
            }
            (intensity_scale, None)
        }
        Some(r) => {
            let held: Vec<bool> = cameras.iter().map(|c| c.holdout).collect();
            let gains = real::draw_gains(r, &held, settings.seed);
            let gained_peak = frames.iter().map(|f| gains[f.camera] * f.clean.min_max().1 as f64).fold(0.0, f64::max);
            let top = settings.sensor.full_scale_fraction * 255.0;
            let k = if gained_peak > 0.0 { top / gained_peak } else { 1.0 };
            let sigma = r.dark_noise * top;
            let patterns: Vec<Image> = cameras
                .iter()
                .enumerate()
                .map(|(c, cam)| {
                    real::background_pattern(
                        cam.camera.width(),
                        cam.camera.height(),
                        r.background * top,
                        c,
                        settings.seed,
                    )
                })
                .collect();
            let sensitivities: Vec<Image> = cameras
                .iter()
                .enumerate()
                .map(|(c, cam)| {
                    real::sensitivity_pattern(cam.camera.width(), cam.camera.height(), r.vignetting, c, settings.seed)
                })
                .collect();
            for (n, f) in frames.iter_mut().enumerate() {
                let g = (gains[f.camera] * k) as f32;
                let mut signal = patterns[f.camera].clone();
                let sensitivity = &sensitivities[f.camera].data;
                signal.data.iter_mut().zip(&f.clean.data).zip(sensitivity).for_each(|((s, &c), &v)| *s += v * g * c);
                f.counts = real::add_noise(&signal, sigma, sensor_seed, n as u64)?;
            }
            // A uniformly lit target seen through the same sensitivity, over the same background.
            let flat_frames = if r.vignetting > 0.0 { r.flat_frames } else { 0 };
            let level = (real::FLAT_LEVEL * 255.0) as f32;
            let flats = patterns
                .iter()
                .zip(&sensitivities)
                .enumerate()
                .map(|(c, (p, s))| {
                    let mut lit = p.clone();
                    lit.data.iter_mut().zip(&s.data).for_each(|(v, &sv)| *v += level * sv);
                    (0..flat_frames)
                        .map(|b| real::add_noise(&lit, sigma, sensor_seed ^ 0x666c, (c * 1000 + b) as u64))
                        .collect::<Result<Vec<_>, _>>()
                })
                .collect::<Result<Vec<_>, _>>()?;
            let backgrounds = patterns
                .iter()
                .enumerate()
                .map(|(c, p)| {
                    (0..r.background_frames)
                        .map(|b| real::add_noise(p, sigma, sensor_seed ^ 0x6267, (c * 1000 + b) as u64))
                        .collect::<Result<Vec<_>, _>>()
                })
                .collect::<Result<Vec<_>, _>>()?;
            (k, Some(RealRecording { gains, backgrounds, flats, jpeg_quality: r.jpeg_quality }))
        }
    };
    stats.sensor_seconds = t0.elapsed().as_secs_f64();
    Ok(Synthesis { settings: settings.clone(), aabb, cameras, truth, frames, intensity_scale, stats, real })
}

/// The refusal of a data set whose every image is black, which every reader would refuse
/// ([`fluidnerf_core::image::ALL_BLACK`]): it names the setting that made it so and why, the
/// phantom empty at the times asked for, below the thin-lens threshold, or out of every view.
fn all_black(settings: &SynthSettings, truth: &[(Option<f64>, Volume)], cameras: usize) -> SynthError {
    let kind = settings.phantom.kind;
    let head = format!("every image of the {cameras} cameras is black");
    let largest = truth.iter().map(|(_, v)| v.min_max().1).fold(f32::NEG_INFINITY, f32::max);
    let when = || {
        let times: Vec<String> = truth.iter().filter_map(|(t, _)| t.map(|t| num(t).to_string())).collect();
        match kind.cfd_case() {
            Some(_) => format!("solver step {}", times.join(", ")),
            None => format!("t* = {}", times.join(", ")),
        }
    };
    if largest <= 0.0 {
        return if settings.times.is_empty() {
            SynthError::invalid("phantom", format!("{head}: the {} phantom is empty (no voxel above 0)", kind.name()))
        } else {
            SynthError::invalid(
                "times",
                format!(
                    "{head}: the {} phantom is empty (no voxel above 0) at {}; give times at which it holds light",
                    kind.name(),
                    when()
                ),
            )
        };
    }
    if let ImageModel::ThinLens(s) = &settings.image {
        if largest <= s.threshold {
            return SynthError::invalid(
                "image.threshold",
                format!(
                    "{head}: no voxel of the {} phantom is above the threshold {} (the largest is {}), so none \
                     is cast; give a lower threshold",
                    kind.name(),
                    num(s.threshold),
                    num(largest)
                ),
            );
        }
    }
    SynthError::invalid(
        "rig",
        format!("{head}: no camera sees the light of the {} phantom; place the cameras so they see it", kind.name()),
    )
}

/// Convenience for callers without a progress display.
pub fn no_progress(_: &Progress) -> ControlFlow<()> {
    ControlFlow::Continue(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{PinholeSettings, ThinLensSettings};
    use crate::rig::{Jitter, Layout, RingAxis};

    fn tiny() -> SynthSettings {
        let mut s = SynthSettings { resolution: 20, ..Default::default() };
        s.lens.resolution = [20, 20];
        s.rig.layout = Layout::Ring { count: 4, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X };
        s.sensor.gaussian_noise = 0.02;
        s
    }

    /// Times given out of order are made in time order: the frames follow time.
    #[test]
    fn times_given_out_of_order_are_made_in_time_order() {
        let mut s = tiny();
        s.phantom.kind = crate::PhantomKind::JetTr;
        s.times = vec![16.0, 14.0];
        assert_eq!(s.time_steps(), vec![Some(14.0), Some(16.0)]);
        let syn = generate(&s, None, |_| std::ops::ControlFlow::Continue(())).expect("generates");
        let truth: Vec<Option<f64>> = syn.truth.iter().map(|(t, _)| *t).collect();
        assert_eq!(truth, vec![Some(14.0), Some(16.0)]);
    }

    /// The file names of a series of more than a hundred instants sort in time order:
    /// `_t100` came between `_t10` and `_t11` with two digits.
    #[test]
    fn the_files_of_a_long_series_sort_in_time_order() {
        let mut s = tiny();
        s.phantom.kind = crate::PhantomKind::JetTr;
        s.resolution = 4;
        s.lens.resolution = [8, 8];
        s.rig.layout = Layout::Ring { count: 1, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X };
        s.times = (0..101).map(|k| 14.0 + 0.01 * f64::from(k)).collect();
        let syn = generate(&s, None, |_| std::ops::ControlFlow::Continue(())).expect("generates");
        let images: Vec<String> = syn.frames.iter().map(|f| syn.image_path(f).display().to_string()).collect();
        let truth: Vec<String> = (0..101).map(|k| syn.truth_path(k).display().to_string()).collect();
        assert_eq!((images[0].as_str(), truth[100].as_str()), ("images/cam000_t000.png", "truth/truth_t100.npy"));
        for names in [images, truth] {
            let mut sorted = names.clone();
            sorted.sort();
            assert_eq!(sorted, names);
        }
        // Shorter series keep their two digits.
        s.times = vec![14.0, 15.0];
        let syn = generate(&s, None, |_| std::ops::ControlFlow::Continue(())).expect("generates");
        assert_eq!(syn.truth_path(1).display().to_string(), "truth/truth_t01.npy");
    }

    #[test]
    fn repeated_times_and_truths_that_are_not_finite_are_refused() {
        let mut s = tiny();
        s.phantom.kind = crate::PhantomKind::JetTr;
        s.times = vec![14.0, 15.0, 14.0];
        let e = s.validate().unwrap_err().to_string();
        assert!(e.contains("times") && e.contains("14 is given twice"), "{e}");
        // Two times that every reader of the scene takes for one instant: the scene it wrote
        // could not be reconstructed.
        s.times = vec![14.0, 14.000_000_000_1, 15.0];
        let e = s.validate().unwrap_err().to_string();
        assert!(
            e.contains(
                "`times`: 14 and 14.0000000001 (the second at position 1) are one instant to the scene's readers"
            ),
            "{e}"
        );
        s.times = vec![14.0, 14.000_01, 15.0];
        s.validate().expect("times a relative 1e-6 apart are two instants");
        let aabb = s.aabb;
        let mut v = Volume::from_fn([4, 4, 4], aabb, |_| 1.0);
        v.data[5] = f32::INFINITY;
        let settings = crate::PhantomSettings { kind: crate::PhantomKind::Volume, ..Default::default() };
        let Err(e) = crate::Phantom::build(&settings, &aabb, 0, Some(v)) else { panic!("accepted") };
        let e = e.to_string();
        assert!(e.contains("voxel (i 1, j 1, k 0) is inf"), "{e}");
    }

    #[test]
    fn same_seed_same_bytes_other_seed_other_noise() {
        let mut s = tiny();
        s.image = ImageModel::ThinLens(ThinLensSettings { rays_per_voxel: 4.0, threshold: 0.0 });
        s.rig.jitter = Jitter { position_mm: 0.5, rotation_deg: 0.2 };
        let a = generate(&s, None, no_progress).expect("generates");
        let b = generate(&s, None, no_progress).expect("generates");
        for (fa, fb) in a.frames.iter().zip(&b.frames) {
            assert_eq!(fa.counts, fb.counts);
        }
        assert_eq!(a.intensity_scale, b.intensity_scale);
        s.seed = 1;
        let c = generate(&s, None, no_progress).expect("generates");
        assert_ne!(a.frames[0].counts, c.frames[0].counts);
        assert_ne!(a.truth[0].1, c.truth[0].1, "the phantom's turbulence is seeded too");
    }

    #[test]
    fn counts_follow_the_recorded_intensity_scale() {
        let mut s = tiny();
        s.sensor.gaussian_noise = 0.0;
        let syn = generate(&s, None, no_progress).expect("generates");
        let full = s.sensor.full_scale();
        let peak = syn.frames.iter().map(|f| f.counts.min_max().1).fold(0.0f32, f32::max) as f64;
        assert!((peak - 0.8 * full).abs() <= 1.0, "brightest pixel {peak} counts");
        for f in &syn.frames {
            for (c, e) in f.counts.data.iter().zip(&f.clean.data) {
                assert!((*c as f64 - syn.intensity_scale * *e as f64).abs() <= 0.5 + 1e-6 * full);
            }
        }
        let scene = syn.scene(PathBuf::from("/tmp/x"));
        assert_eq!(scene.frames.len(), 4);
        assert_eq!(scene.intensity_scale, syn.intensity_scale);
        assert_eq!(scene.truth[0].file_path, PathBuf::from("truth/truth.npy"));
    }

    #[test]
    fn pinhole_and_thin_lens_agree_on_total_signal() {
        let mut s = tiny();
        s.sensor.gaussian_noise = 0.0;
        s.resolution = 32;
        s.lens.resolution = [32, 32];
        s.image = ImageModel::Pinhole(PinholeSettings::default());
        let pin = generate(&s, None, no_progress).expect("pinhole");
        s.image = ImageModel::ThinLens(ThinLensSettings { rays_per_voxel: 32.0, threshold: 0.0 });
        let thin = generate(&s, None, no_progress).expect("thin lens");
        for (a, b) in pin.frames.iter().zip(&thin.frames) {
            let ratio = b.clean.sum() / a.clean.sum();
            assert!((ratio - 1.0).abs() < 0.03, "thin-lens / pinhole flux {ratio}");
        }
    }

    #[test]
    fn bad_settings_are_rejected_before_any_work() {
        let mut calls = 0;
        let mut count = |_: &Progress| {
            calls += 1;
            ControlFlow::Continue(())
        };
        let mut s = tiny();
        s.rig.layout = Layout::Ring { count: 0, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X };
        assert!(matches!(generate(&s, None, &mut count), Err(SynthError::Invalid { .. })));
        let mut s = tiny();
        s.sensor.gaussian_noise = -0.01;
        assert!(matches!(generate(&s, None, &mut count), Err(SynthError::Invalid { .. })));
        let mut s = tiny();
        s.rig.layout = Layout::Explicit { positions: vec![[0.0, 360.0, 0.0]], targets: vec![[0.0, 720.0, 0.0]] };
        assert!(matches!(generate(&s, None, &mut count), Err(SynthError::CameraMissesBox { .. })));
        let mut s = tiny();
        s.resolution = 4096;
        s.lens.resolution = [8192, 8192];
        assert!(matches!(generate(&s, None, &mut count), Err(SynthError::OutOfMemory { .. })));
        let mut s = tiny();
        s.phantom.kind = PhantomKind::JetTr;
        assert!(matches!(generate(&s, None, &mut count), Err(SynthError::Invalid { .. })), "jet-tr needs times");
        assert_eq!(calls, 0, "no work may start");
        // Cancelling stops the run.
        let r = generate(&tiny(), None, |_| ControlFlow::Break(()));
        assert!(matches!(r, Err(SynthError::Cancelled)));
    }

    #[test]
    fn cfd_truth_is_the_solvers_grid_at_the_asked_steps() {
        use crate::phantom::cfd::{self, CfdCase};
        let mut s = tiny();
        s.sensor.gaussian_noise = 0.0;
        s.phantom.kind = PhantomKind::Plume;
        s.aabb = cfd::domain();
        s.resolution = 72;
        s.rig.layout = Layout::Ring { count: 3, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::Y };
        s.phantom.cfd_step = Some(50);
        let syn = generate(&s, None, no_progress).expect("static plume");
        assert_eq!(syn.truth.len(), 1);
        assert_eq!(syn.truth[0].1, CfdCase::Plume.instant(50).expect("decodes"));
        assert!(syn.frames.iter().all(|f| f.clean.min_max().1 > 0.0), "every camera sees the plume");
        // A series takes its steps from the times alone.
        s.phantom.cfd_step = None;
        s.times = vec![50.0, 60.0];
        s.resolution = 24;
        s.phantom.kind = PhantomKind::CfdJet;
        let syn = generate(&s, None, no_progress).expect("time-resolved jet");
        assert_eq!(syn.truth.len(), 2);
        assert_eq!(syn.truth[1].1.dims, [16, 24, 16]);
        assert_ne!(syn.truth[0].1, syn.truth[1].1);
        assert_eq!(syn.scene(PathBuf::from("/tmp/x")).times(), vec![50.0, 60.0]);
        // Only stored steps are times; the procedural jet's t* are not.
        s.times = vec![51.0];
        let err = generate(&s, None, no_progress).expect_err("step 51 is not stored");
        assert!(err.to_string().contains("solver steps"), "{err}");
        s.times.clear();
        s.phantom.cfd_step = Some(7);
        assert!(matches!(generate(&s, None, no_progress), Err(SynthError::Invalid { .. })));
    }

    #[test]
    fn user_volume_is_the_truth() {
        let aabb = Aabb::cube(DVec3::new(1.0, 0.0, 0.0), 30.0);
        let vol = Volume::from_fn([10, 12, 14], aabb, |p| (1.0 - p.length() / 30.0).max(0.0) as f32);
        let mut s = tiny();
        s.phantom.kind = PhantomKind::Volume;
        let syn = generate(&s, Some(vol.clone()), no_progress).expect("generates");
        assert_eq!(syn.truth[0].1, vol);
        assert_eq!(syn.aabb, aabb);
        // One with no positive voxel would image as black everywhere.
        let dark = Volume::from_fn([4, 4, 4], aabb, |_| 0.0);
        let err = generate(&s, Some(dark), no_progress).expect_err("a dark volume").to_string();
        assert!(err.contains("phantom.volume") && err.contains("no voxel is positive"), "{err}");
    }
}
