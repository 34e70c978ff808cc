//! The FluidNeRF training loop (dissertation §5.1.4–5.1.5), generic over the field
//! representation.
//!
//! # Method and engine
//! This module is the method: settings ([`TrainConfig`]), the prepared problem ([`Prepared`]:
//! cached rays, normalised targets, occupancy), the training state ([`Learner`]), and the loop
//! ([`train_with_engine`]) that, per iteration, draws the ray batch
//! ([`crate::batch::training_batch`]: `N_pix/img` random pixels with replacement from every
//! training image, §5.1.5), asks an [`Engine`] for its loss and gradient, checks that the loss
//! is finite, has the engine take one Adam step with the learning rate of the schedule
//! `lr(i) = lr₀ (lr₁ / lr₀)^{i / N_decay}` (5e-4 → 5e-5 at 25 000 iterations), evaluates the
//! held-out views, reports and applies the stopping rule. Sampling, field evaluation,
//! quadrature, loss and backward are the engine's ([`crate::engine`]; [`train`] uses the fused
//! CPU engine [`CpuEngine`]).
//!
//! # Normalisation
//! Pixels are divided by `image_scale` (the largest training pixel unless set), so targets are
//! O(1) as in NeRF and the learning rates of the dissertation carry over. Distances in the
//! quadrature are divided by `L = ` the longest box side. The field therefore learns
//! `e = E / value_scale` with `value_scale = image_scale / (intensity_scale · L)`, and
//! [`FieldMeta`] records that factor so trained fields are read back in physical units.
//!
//! # Stopping (§5.1.5)
//! The loss smoothed by a running mean over [`StopRule::smoothing`] iterations; training stops
//! when it changed by less than [`StopRule::tolerance`] (relative) across the last
//! [`StopRule::window`] iterations, at `max_iterations`, at the wall-time budget, or when the
//! callback breaks.
//!
//! Determinism: all randomness comes from ChaCha8 streams keyed by (seed, iteration, chunk)
//! ([`crate::batch`]), so a run is reproducible for a given engine and thread count, and
//! resuming at iteration `k` continues exactly as an uninterrupted run would (given the
//! optimiser state).

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_core::num;
use fluidnerf_core::{Aabb, Camera, Image};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::batch::{holdout_batch, training_batch, view_batch, RayBatch};
use crate::engine::cpu::CpuEngine;
use crate::engine::{BatchLoss, Engine};
use crate::occupancy::{OccupancyConfig, OccupancyGrid, OccupancyRecord};
use crate::optim::{Adam, AdamConfig, LrSchedule};
use crate::render::Quadrature;
use crate::sampling::ImageRays;
use crate::{NeuralError, Prior, TrainableField};

/// The stopping rule of §5.1.5.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StopRule {
    /// Iterations of the running mean, at most [`MAX_ITERATION_SPAN`]. Default 200.
    pub smoothing: usize,
    /// Iterations over which the smoothed loss must stay within the tolerance, at most
    /// [`MAX_ITERATION_SPAN`]; 0 disables the rule. Default 2000.
    pub window: usize,
    /// Relative change of the smoothed loss across the window, at most
    /// [`MAX_STOP_TOLERANCE`]. Default 0.02.
    pub tolerance: f64,
}

impl StopRule {
    /// The rule counted in cycles through `frames` frames instead of iterations (see
    /// [`TrainConfig::stop_per_frame`]).
    pub(crate) fn in_cycles(&self, frames: usize) -> StopRule {
        let f = frames.max(1);
        StopRule { smoothing: self.smoothing * f, window: self.window * f, ..*self }
    }
}

impl Default for StopRule {
    fn default() -> Self {
        StopRule { smoothing: 200, window: 2000, tolerance: 0.02 }
    }
}

/// Which training views one iteration draws its pixels from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Batching {
    /// `N_pix/img` pixels from every training image (static FluidNeRF, §5.1.5).
    #[default]
    AllViews,
    /// `N_pix/img` pixels from every image of ONE time step, cycling through the distinct
    /// frame times in increasing order, iteration `i` taking step `i mod N_t`
    /// (TR-FluidNeRF, §5.2: "an iteration accounts for all images at a specific time step").
    OneTimeStep,
}

/// The most samples a ray may take (coarse and fine together): the dissertation's are 64 + 128.
pub const MAX_SAMPLES_PER_RAY: usize = 4096;

/// The most random points of the field's priors per iteration ([`Prior::points`]): they are
/// evaluated in one pass, four field rows each, held with the field's activations.
pub const MAX_PRIOR_POINTS: usize = 1 << 16;

/// The largest [`StopRule::tolerance`]: a change of the smoothed loss as large as the loss
/// itself. A falling loss cannot change by more, so beyond 1 the rule stops every run after
/// its first window.
pub const MAX_STOP_TOLERANCE: f64 = 1.0;

/// The largest weight of each of the field's priors ([`Prior::tv`], [`Prior::smooth`],
/// [`Prior::sparsity`]). The data term they are weighed against is a mean squared residual of
/// images scaled to a peak of about 1, so it is at most about 1, and the prior terms are means
/// of the normalised field's differences and values, of the same order: the weights that help
/// are 10⁻⁴ to 10⁻² (docs/claims.md), and at 1 a prior already outweighs the images. A thousand
/// leaves that far behind; beyond it a run only trains a flat field (10³⁰ did, without a word),
/// or, nearer f32's end, overflows the loss and is reported as a divergence.
pub const MAX_PRIOR_WEIGHT: f32 = 1e3;

/// The most pixels drawn from one image per iteration: every pixel of a 2048 × 2048 image.
/// More would only repeat pixels, and their rays could not be held.
pub const MAX_RAYS_PER_IMAGE: usize = 1 << 22;

/// The most field rows a chunk of rays may hold ([`TrainConfig::chunk_samples`]): 2²⁴, a
/// gibibyte of scratch a thread, 2048 times the dense grid's 8192. A larger chunk only puts
/// every ray of an iteration on one thread, and its scratch was refused as a run needing
/// thousands of gibibytes, with advice to lower the resolution or the image count.
pub const MAX_CHUNK_SAMPLES: usize = 1 << 24;

/// The most iterations a span of a run's schedule may take ([`fluidnerf_core::MAX_ITERATION_SPAN`]):
/// the stopping rule's window and smoothing ([`StopRule`]), the hash grid's steps between
/// levels ([`crate::hashgrid::HashGridConfig::coarse_to_fine`]), the held-out interval
/// ([`TrainConfig::validate_every`]).
pub use fluidnerf_core::MAX_ITERATION_SPAN;

/// The smallest and largest the brightest training pixel may be once divided by a given
/// [`TrainConfig::image_scale`] (by default it is 1). Outside, the squared residuals the loss
/// sums leave the range where f32 holds them: a scale of 10⁻³⁰ made the loss of iteration 0
/// infinite.
pub const MIN_TARGET_PEAK: f64 = 1e-6;
/// See [`MIN_TARGET_PEAK`].
pub const MAX_TARGET_PEAK: f64 = 1e6;

/// Sampling, optimisation and stopping settings (defaults: Table 5.1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Stratified samples per ray, N_c. Default 128.
    pub coarse_samples: usize,
    /// Hierarchical feature samples per ray, N_f (0 disables the coarse pass). Default 128.
    pub fine_samples: usize,
    /// Random pixels per training image per iteration, N_pix/img. Default 1024.
    pub rays_per_image: usize,
    /// Add the ray's end pieces to the quadrature ([`crate::render`]). Default true.
    pub close_ends: bool,
    /// Learning-rate schedule (5e-4 decaying exponentially to 5e-5 at 25 000 iterations).
    pub schedule: LrSchedule,
    /// Adam hyperparameters (β₁ 0.9, β₂ 0.999, ε 1e-7).
    pub adam: AdamConfig,
    /// Iteration cap, at most [`fluidnerf_core::MAX_ITERATIONS`]. Default 25 000.
    pub max_iterations: usize,
    /// Wall-time budget of the training loop in seconds (None: unlimited). Default None.
    pub time_budget_s: Option<f64>,
    pub stop: StopRule,
    /// Empty-space skipping (None: off, as in the dissertation). Default None.
    pub occupancy: Option<OccupancyConfig>,
    /// Field rows per chunk of rays handed to one thread (at least one ray), 1 to
    /// [`MAX_CHUNK_SAMPLES`]. Default 256, the
    /// MLP's sweet spot (its activations stay in cache); the `fast` preset's grid field takes
    /// 2048, the dense grid 8192.
    pub chunk_samples: usize,
    /// Pixel normalisation; None takes the largest training pixel. A given scale must put the
    /// largest training pixel between [`MIN_TARGET_PEAK`] and [`MAX_TARGET_PEAK`]. Default None.
    #[serde(deserialize_with = "fluidnerf_core::number::optional_f32_setting")]
    pub image_scale: Option<f32>,
    /// Iterations between evaluations of the held-out views (0: never), at most
    /// [`MAX_ITERATION_SPAN`]. Default 100.
    pub validate_every: usize,
    /// Held-out pixels evaluated each time (a fixed random subset). Default 4096.
    pub validate_pixels: usize,
    /// Views of one iteration. Default all views.
    pub batching: Batching,
    /// With [`Batching::OneTimeStep`], advance the learning-rate schedule once per cycle
    /// through the frames instead of once per iteration: a frame's `n`-th update then uses
    /// `schedule.lr(n)`, as a run on that frame alone would. Default false (the dissertation's
    /// schedule counts iterations).
    pub schedule_per_frame: bool,
    /// With [`Batching::OneTimeStep`], count the stopping rule's smoothing and window
    /// ([`StopRule`]) in cycles through the window's frames instead of iterations, so that a
    /// frame is judged settled after as many of its own updates as a run on that frame alone
    /// would need (the companion of [`Self::schedule_per_frame`]; applied per window by
    /// [`crate::temporal`]). Default false.
    pub stop_per_frame: bool,
    /// Start a fresh field from the uniform value that explains the mean training pixel
    /// ([`TrainableField::start_uniform`]) instead of the representation's own
    /// initialisation. Default true.
    pub uniform_start: bool,
    /// Priors on the field added to the loss ([`Prior`]: on the dense grid's cells, on random
    /// points for other fields).
    /// Default none.
    pub prior: Prior,
    /// Rays per training pixel along each axis, `S`: a drawn pixel is rendered as the mean of
    /// `S × S` rays through the centres of an `S × S` lattice of sub-pixels, and that mean is
    /// scored, so that the field is fitted to the pixel's average over its area, which is what
    /// a camera pixel measures (and what the synthetic images' supersampled pixels hold).
    /// Costs `S²` rays per pixel. Held-out scoring and rendering keep one ray per pixel centre.
    /// `"auto"` in a configuration chooses by the images' noise ([`Supersample::Auto`]).
    /// Default 1 (the dissertation's pixel-centre rays); `"auto"` in the `fast` and `tr-fast`
    /// presets.
    pub pixel_supersample: Supersample,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            coarse_samples: 128,
            fine_samples: 128,
            rays_per_image: 1024,
            close_ends: true,
            schedule: LrSchedule::default(),
            adam: AdamConfig::default(),
            max_iterations: 25_000,
            time_budget_s: None,
            stop: StopRule::default(),
            occupancy: None,
            chunk_samples: 256,
            image_scale: None,
            validate_every: 100,
            validate_pixels: 4096,
            batching: Batching::AllViews,
            schedule_per_frame: false,
            stop_per_frame: false,
            uniform_start: true,
            prior: Prior::default(),
            pixel_supersample: Supersample::Fixed(1),
        }
    }
}

/// Rays per training pixel along each axis ([`TrainConfig::pixel_supersample`]): a number, or
/// `"auto"` in a configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Supersample {
    /// `S` rays per axis, 1 to 4.
    Fixed(usize),
    /// By the training images' noise ([`Prepared::noise`]): when they are clean (at most
    /// [`fluidnerf_core::image::NOISY_ABOVE`]), 2 per axis over a quarter of `rays_per_image`
    /// pixels, so the same rays per iteration; when they are noisy, or give no estimate, one
    /// ray per pixel. Area rays make the fit to clean images sharper; on noisy ones, fewer
    /// distinct pixels per iteration average less noise (docs/claims.md).
    Auto,
}

impl Serialize for Supersample {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Supersample::Fixed(n) => s.serialize_u64(*n as u64),
            Supersample::Auto => s.serialize_str("auto"),
        }
    }
}

impl<'de> Deserialize<'de> for Supersample {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visit;
        impl serde::de::Visitor<'_> for Visit {
            type Value = Supersample;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("rays per pixel along each axis (1 to 4) or \"auto\"")
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Supersample, E> {
                Ok(Supersample::Fixed(usize::try_from(v).map_err(E::custom)?))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Supersample, E> {
                usize::try_from(v)
                    .map(Supersample::Fixed)
                    .map_err(|_| E::custom(format!("rays per pixel must be 1 to 4 or \"auto\", got {v}")))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Supersample, E> {
                if v == "auto" {
                    Ok(Supersample::Auto)
                } else {
                    Err(E::custom(format!("expected 1 to 4 or \"auto\", got {v:?}")))
                }
            }
        }
        d.deserialize_any(Visit)
    }
}

impl TrainConfig {
    /// Rays per pixel along each axis, and pixels drawn from each training image per
    /// iteration, for training images whose median estimated noise is `noise`
    /// ([`Supersample::Auto`]).
    pub fn pixel_rays(&self, noise: Option<f64>) -> (usize, usize) {
        match self.pixel_supersample {
            Supersample::Fixed(s) => (s, self.rays_per_image),
            Supersample::Auto if fluidnerf_core::image::reads_clean(noise) => (2, self.rays_per_image.div_ceil(4)),
            Supersample::Auto => (1, self.rays_per_image),
        }
    }

    /// Rejects settings no run can use.
    pub fn validate(&self) -> Result<(), NeuralError> {
        let bad = |what: &str, why: String| Err(NeuralError::invalid(what, why));
        if let Supersample::Fixed(s) = self.pixel_supersample {
            if !(1..=4).contains(&s) {
                return bad("pixel_supersample", format!("must be 1 to 4 or \"auto\", got {s}"));
            }
        }
        for (what, w) in
            [("prior.tv", self.prior.tv), ("prior.smooth", self.prior.smooth), ("prior.sparsity", self.prior.sparsity)]
        {
            if !(w >= 0.0 && w.is_finite()) {
                return bad(what, format!("must be a non-negative weight, got {}", num(w)));
            }
            if w > MAX_PRIOR_WEIGHT {
                return bad(
                    what,
                    format!(
                        "must be at most {} (the images' term is about 1 and weights that help are 1e-4 to \
                         1e-2; a larger one trains a flat field), got {}",
                        num(MAX_PRIOR_WEIGHT),
                        num(w)
                    ),
                );
            }
        }
        if !(1..=MAX_PRIOR_POINTS).contains(&self.prior.points) {
            return bad(
                "prior.points",
                format!("must be 1 to {MAX_PRIOR_POINTS} points per iteration, got {}", self.prior.points),
            );
        }
        if !(self.prior.step > 0.0 && self.prior.step < 0.5) {
            return bad("prior.step", format!("must be in (0, 0.5) box units, got {}", num(self.prior.step)));
        }
        if self.coarse_samples < 2 {
            return bad("coarse_samples", format!("needs at least 2, got {}", self.coarse_samples));
        }
        if self.coarse_samples + self.fine_samples > MAX_SAMPLES_PER_RAY {
            return bad(
                "coarse_samples",
                format!(
                    "coarse and fine samples together must be at most {MAX_SAMPLES_PER_RAY} per ray, got {} + {}",
                    self.coarse_samples, self.fine_samples
                ),
            );
        }
        if !(1..=fluidnerf_core::MAX_ITERATIONS).contains(&self.max_iterations) {
            return bad(
                "max_iterations",
                format!("must be 1 to {} iterations, got {}", fluidnerf_core::MAX_ITERATIONS, self.max_iterations),
            );
        }
        if let Some(occupancy) = &self.occupancy {
            occupancy.validate()?;
        }
        if !(1..=MAX_RAYS_PER_IMAGE).contains(&self.rays_per_image) {
            return bad(
                "rays_per_image",
                format!("must be 1 to {MAX_RAYS_PER_IMAGE} pixels per image, got {}", self.rays_per_image),
            );
        }
        if !(1..=MAX_CHUNK_SAMPLES).contains(&self.chunk_samples) {
            return bad(
                "chunk_samples",
                format!("must be 1 to {MAX_CHUNK_SAMPLES} field rows per chunk, got {}", self.chunk_samples),
            );
        }
        self.schedule.validate()?;
        self.adam.validate()?;
        if let Some(t) = self.time_budget_s {
            if t.is_nan() || t <= 0.0 {
                return bad("time_budget_s", format!("must be positive, got {}", num(t)));
            }
        }
        if let Some(s) = self.image_scale {
            if !(s > 0.0 && s.is_finite()) {
                return bad("image_scale", format!("must be positive, got {}", num(s)));
            }
        }
        for (what, n) in [
            ("stop.window", self.stop.window),
            ("stop.smoothing", self.stop.smoothing),
            ("validate_every", self.validate_every),
        ] {
            if n > MAX_ITERATION_SPAN {
                return bad(what, format!("must be at most {MAX_ITERATION_SPAN} iterations, got {n}"));
            }
        }
        if self.stop.tolerance > MAX_STOP_TOLERANCE {
            return bad(
                "stop.tolerance",
                format!(
                    "must be at most {} (a fraction of the smoothed loss; a larger one stops the run after its \
                     first window), got {}",
                    num(MAX_STOP_TOLERANCE),
                    num(self.stop.tolerance)
                ),
            );
        }
        if self.stop.window > 0
            && (self.stop.smoothing == 0 || self.stop.tolerance.is_nan() || self.stop.tolerance <= 0.0)
        {
            return bad("stop", "needs smoothing > 0 and tolerance > 0".into());
        }
        Ok(())
    }
}

/// One calibrated image.
#[derive(Clone, Debug)]
pub struct View {
    pub camera: Camera,
    pub image: Image,
    /// Acquisition time in the scene's unit (0 for static scenes).
    pub time: f64,
}

/// What is reconstructed from what.
#[derive(Clone, Debug)]
pub struct Problem {
    pub aabb: Aabb,
    /// Pixel = `intensity_scale × ∫E ds` (`Scene::intensity_scale`).
    pub intensity_scale: f64,
    /// Training views.
    pub views: Vec<View>,
    /// Views held out for validation.
    pub holdout: Vec<View>,
    /// Frame spacing Δt: space–time fields receive `t' = t / Δt` (§5.2). 1 for static scenes.
    pub time_step: f64,
}

/// How a trained field maps to the world: box, value scale, time scale and the empty-space
/// mask. Saved next to the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldMeta {
    pub aabb: Aabb,
    /// E (world units) = `value_scale` × field output.
    pub value_scale: f64,
    /// Δt of `t' = t / Δt`.
    pub time_step: f64,
    /// Cells outside which E is zero (empty-space skipping), if used.
    pub occupancy: Option<OccupancyRecord>,
}

impl FieldMeta {
    /// Why a description read from a file cannot place a field, if it cannot: a box that is
    /// not finite and positive on every axis, a value scale or time step that is not finite
    /// and positive, or one that the field's 32-bit arithmetic turns into infinity or zero
    /// (a value scale of 1e300 made every value infinite, 1e-300 every value zero).
    pub fn problem(&self) -> Option<String> {
        if let Err(e) = self.aabb.validate() {
            return Some(e.to_string());
        }
        for (key, v) in [("value_scale", self.value_scale), ("time_step", self.time_step)] {
            if !(v.is_finite() && v > 0.0) {
                return Some(format!("{key} must be finite and positive, got {}", num(v)));
            }
            if !(v as f32).is_normal() {
                return Some(format!(
                    "{key} {} lies outside what the field's 32-bit floats hold ({:e} … {:e})",
                    num(v),
                    f32::MIN_POSITIVE,
                    f32::MAX
                ));
            }
        }
        None
    }
}

/// Training data prepared once: cached rays, normalised targets, occupancy.
#[derive(Debug)]
pub struct Prepared {
    pub meta: FieldMeta,
    occupancy: Option<OccupancyGrid>,
    train: Vec<PreparedView>,
    holdout: Vec<PreparedView>,
    /// Normalisation of the quadrature: 1 / (longest box side).
    length_scale: f32,
    quad: Quadrature,
    /// `intensity_scale × L`.
    intensity_length: f64,
    /// The training images' median estimated noise ([`median_noise`]).
    noise: Option<f64>,
}

/// The median over `views` of their images' estimated noise, a fraction of each image's range
/// ([`Image::relative_noise`]); `None` when no image gives an estimate.
pub fn median_noise<'a>(views: impl IntoIterator<Item = &'a View>) -> Option<f64> {
    fluidnerf_core::image::median_noise(views.into_iter().filter_map(|v| v.image.relative_noise()))
}

/// One prepared view: its cached rays, their normalised target pixels and its frame time.
#[derive(Debug)]
pub struct PreparedView {
    pub(crate) rays: ImageRays,
    pub(crate) targets: Vec<f32>,
    pub(crate) time: f32,
    /// The targets as measured, kept once a gain is set ([`Prepared::set_gains`]).
    pub(crate) measured: Option<Vec<f32>>,
}

impl PreparedView {
    /// The kept rays (geometry in box-normalised and world units, see [`ImageRays`]).
    pub fn rays(&self) -> &ImageRays {
        &self.rays
    }

    /// Per kept ray, the measured pixel divided by [`Prepared::image_scale`].
    pub fn targets(&self) -> &[f32] {
        &self.targets
    }

    /// Frame time `t' = t / Δt`.
    pub fn time(&self) -> f32 {
        self.time
    }
}

impl Prepared {
    /// Casts and clips every training ray, carves the occupancy grid (when configured) and
    /// normalises the images.
    pub fn new(problem: &Problem, cfg: &TrainConfig) -> Result<Self, NeuralError> {
        Prepared::with_masks(problem, cfg, &ViewMasks::default())
    }

    /// [`Prepared::new`] leaving out the rays of masked pixels: they are never sampled, do not
    /// count towards `image_scale`, and count as unknown (not dark) when the occupancy grid is
    /// carved.
    pub fn with_masks(problem: &Problem, cfg: &TrainConfig, masks: &ViewMasks) -> Result<Self, NeuralError> {
        for (what, list, views) in
            [("train", &masks.train, &problem.views), ("holdout", &masks.holdout, &problem.holdout)]
        {
            if !list.is_empty() && list.len() != views.len() {
                return Err(NeuralError::invalid(
                    format!("masks.{what}"),
                    format!("{} masks for {} views", list.len(), views.len()),
                ));
            }
            for (i, (m, v)) in list.iter().zip(views.iter()).enumerate() {
                if m.as_ref().is_some_and(|m| m.len() != v.image.data.len()) {
                    return Err(NeuralError::invalid(format!("masks.{what}[{i}]"), "does not have the image's size"));
                }
            }
        }
        fn mask_of(list: &[Option<Vec<bool>>], i: usize) -> Option<&[bool]> {
            list.get(i).and_then(Option::as_deref)
        }
        cfg.validate()?;
        problem.aabb.validate().map_err(|e| NeuralError::invalid("reconstruction box", e.to_string()))?;
        if problem.views.is_empty() {
            return Err(NeuralError::invalid("scene", "no training images"));
        }
        if !(problem.intensity_scale > 0.0 && problem.intensity_scale.is_finite()) {
            return Err(NeuralError::invalid(
                "intensity_scale",
                format!("must be positive, got {}", num(problem.intensity_scale)),
            ));
        }
        if !(problem.time_step > 0.0 && problem.time_step.is_finite()) {
            return Err(NeuralError::invalid("time_step", format!("must be positive, got {}", num(problem.time_step))));
        }
        for (i, v) in problem.views.iter().chain(&problem.holdout).enumerate() {
            if (v.camera.width(), v.camera.height()) != (v.image.width, v.image.height) {
                return Err(NeuralError::invalid(
                    format!("view {i}"),
                    format!(
                        "image is {}x{} but its camera is {}x{}",
                        v.image.width,
                        v.image.height,
                        v.camera.width(),
                        v.camera.height()
                    ),
                ));
            }
            if let Some((c, r)) = v.image.first_non_finite() {
                return Err(NeuralError::invalid(format!("view {i}"), format!("pixel ({c}, {r}) is not finite")));
            }
        }
        let largest = problem
            .views
            .iter()
            .enumerate()
            .map(|(i, v)| match mask_of(&masks.train, i) {
                Some(m) => v.image.data.iter().zip(m).filter(|(_, &k)| k).fold(0.0f32, |a, (&p, _)| a.max(p)),
                None => v.image.min_max().1,
            })
            .fold(0.0f32, f32::max);
        let image_scale = cfg.image_scale.unwrap_or(largest);
        // Targets far from 1 leave the f32 range the loss is summed in: a scale of 1e-30 made
        // the loss of iteration 0 infinite, one of 1e8 made every target vanish beside the
        // field's start.
        let ratio = largest as f64 / image_scale as f64;
        if largest > 0.0 && !(MIN_TARGET_PEAK..=MAX_TARGET_PEAK).contains(&ratio) {
            return Err(NeuralError::invalid(
                "image_scale",
                format!(
                    "{} puts the largest training pixel ({}) at {} once divided: it must come out between \
                     {MIN_TARGET_PEAK:e} and {MAX_TARGET_PEAK:e}; leave image_scale out to take the largest pixel",
                    num(image_scale),
                    num(largest),
                    num(ratio)
                ),
            ));
        }
        if image_scale.is_nan() || image_scale <= 0.0 {
            return Err(NeuralError::invalid("images", fluidnerf_core::image::ALL_BLACK));
        }
        let length = problem.aabb.size().max_element();
        // A hull holds for one instant: carve each training time's views on their own and take
        // the union, so a flow that moves between instants is never carved away by the views
        // of another instant.
        let occupancy = cfg.occupancy.as_ref().map(|oc| {
            // A masked pixel says nothing about the cells behind it: it carves none.
            let mut times: Vec<f64> = problem.views.iter().map(|v| v.time).collect();
            times.sort_by(f64::total_cmp);
            times.dedup();
            times
                .iter()
                .map(|&t| {
                    let views: Vec<(&Camera, &Image, Option<&[bool]>)> = problem
                        .views
                        .iter()
                        .enumerate()
                        .filter(|(_, v)| v.time == t)
                        .map(|(i, v)| (&v.camera, &v.image, mask_of(&masks.train, i)))
                        .collect();
                    OccupancyGrid::from_masked_views(&problem.aabb, &views, oc)
                })
                .reduce(|mut a, b| {
                    a.union_with(&b);
                    a
                })
                .expect("at least one training view")
        });
        let prep = |v: &View,
                    what: &str,
                    mask: Option<&[bool]>,
                    occ: Option<&OccupancyGrid>|
         -> Result<PreparedView, NeuralError> {
            let mut rays = ImageRays::new(&v.camera, &problem.aabb, occ)
                .map_err(|e| NeuralError::invalid(format!("camera of {what}"), e.to_string()))?;
            if let Some(m) = mask {
                drop_masked_rays(&mut rays, m);
            }
            let targets = rays.targets(&v.image, image_scale);
            Ok(PreparedView { rays, targets, time: (v.time / problem.time_step) as f32, measured: None })
        };
        let train = problem
            .views
            .par_iter()
            .enumerate()
            .map(|(i, v)| prep(v, &format!("training view {i}"), mask_of(&masks.train, i), occupancy.as_ref()))
            .collect::<Result<Vec<_>, _>>()?;
        if train.iter().all(|v| v.rays.is_empty()) {
            return Err(NeuralError::invalid("scene", "no camera sees the reconstruction box"));
        }
        // Held-out views are rendered through the same model (mask included) as the result.
        let holdout = problem
            .holdout
            .par_iter()
            .enumerate()
            .map(|(i, v)| prep(v, &format!("held-out view {i}"), mask_of(&masks.holdout, i), occupancy.as_ref()))
            .collect::<Result<Vec<_>, _>>()?;
        let meta = FieldMeta {
            aabb: problem.aabb,
            value_scale: image_scale as f64 / (problem.intensity_scale * length),
            time_step: problem.time_step,
            occupancy: occupancy.as_ref().map(OccupancyGrid::to_record),
        };
        Ok(Prepared {
            meta,
            occupancy,
            train,
            holdout,
            length_scale: (1.0 / length) as f32,
            quad: Quadrature { close_ends: cfg.close_ends },
            intensity_length: problem.intensity_scale * length,
            noise: median_noise(&problem.views),
        })
    }

    /// The training images' median estimated noise, a fraction of each image's range
    /// ([`median_noise`]); `None` when no image gives an estimate.
    pub fn noise(&self) -> Option<f64> {
        self.noise
    }

    /// Sets the gain and offset of every training view: training then fits the field to
    /// `(measured − offset) / gain` (the measured targets, normalised like them), i.e. models
    /// a view's pixels as `gain × rendered + offset`. `gains` has one `(gain, offset)` per
    /// training view, offsets in normalised pixel units; results below 0 are clipped.
    pub fn set_gains(&mut self, gains: &[(f32, f32)]) {
        assert_eq!(gains.len(), self.train.len(), "set_gains: one gain per training view");
        for (v, &(g, b)) in self.train.iter_mut().zip(gains) {
            let measured = v.measured.get_or_insert_with(|| v.targets.clone());
            let inv = 1.0 / g;
            v.targets.iter_mut().zip(measured.iter()).for_each(|(t, &m)| *t = ((m - b) * inv).max(0.0));
        }
    }

    /// A fingerprint of what the field is fitted to: every view's time, camera centre, pixels,
    /// ray directions and measured pixel values (before any fitted gain), as 16 hex digits of a
    /// 64-bit FNV-1a hash. A checkpoint records it, so that a run is not continued on other
    /// images or cameras than it started with.
    pub fn fingerprint(&self) -> String {
        const PRIME: u64 = 0x0000_0100_0000_01b3;
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |word: u32| {
            for byte in word.to_le_bytes() {
                h = (h ^ u64::from(byte)).wrapping_mul(PRIME);
            }
        };
        for (set, views) in [&self.train, &self.holdout].into_iter().enumerate() {
            eat(set as u32);
            eat(views.len() as u32);
            for v in views {
                eat(v.time.to_bits());
                v.rays.origin_unit.iter().for_each(|c| eat(c.to_bits()));
                eat(v.rays.len() as u32);
                v.rays.pixel.iter().for_each(|&p| eat(p));
                v.rays.dir_unit.iter().flatten().for_each(|c| eat(c.to_bits()));
                v.measured.as_ref().unwrap_or(&v.targets).iter().for_each(|t| eat(t.to_bits()));
            }
        }
        format!("{h:016x}")
    }

    /// Rays kept for training, and rays whose pixel sees the box at all (their difference is
    /// what empty-space skipping dropped).
    pub fn ray_counts(&self) -> (usize, usize) {
        (self.train.iter().map(|v| v.rays.len()).sum(), self.train.iter().map(|v| v.rays.pixels_on_box).sum())
    }

    /// Fraction of the box declared occupied (1 without skipping).
    pub fn occupied_fraction(&self) -> f64 {
        self.occupancy.as_ref().map_or(1.0, OccupancyGrid::occupied_fraction)
    }

    /// Pixel normalisation: measured pixels were divided by this.
    pub fn image_scale(&self) -> f64 {
        self.meta.value_scale * self.intensity_length
    }

    /// The uniform field (normalised units) whose renders match the training pixels on
    /// average: Σ pixels / Σ normalised chord lengths over all kept training rays.
    pub fn mean_level(&self) -> f32 {
        let (mut sum_t, mut sum_l) = (0.0f64, 0.0f64);
        for v in &self.train {
            sum_t += v.targets.iter().map(|&t| t as f64).sum::<f64>();
            sum_l += v.rays.near.iter().zip(&v.rays.far).map(|(&n, &f)| (f - n) as f64).sum::<f64>();
        }
        (sum_t / (sum_l * self.length_scale as f64)) as f32
    }

    /// The empty-space mask, if any.
    pub fn occupancy(&self) -> Option<&OccupancyGrid> {
        self.occupancy.as_ref()
    }

    /// The training or held-out views, as [`crate::batch::RayBatch`]es index them.
    pub fn views(&self, split: Split) -> &[PreparedView] {
        match split {
            Split::Train => &self.train,
            Split::Holdout => &self.holdout,
        }
    }

    /// `1 / L`, `L` the longest box side: the quadrature's distances are `s / L`.
    pub fn length_scale(&self) -> f32 {
        self.length_scale
    }

    /// The quadrature options (end pieces).
    pub fn quadrature(&self) -> Quadrature {
        self.quad
    }

    /// The distinct frame times `t'` of the training views that see the box, increasing:
    /// [`Batching::OneTimeStep`] cycles through them.
    pub fn time_steps(&self) -> Vec<f32> {
        let mut steps: Vec<f32> = self.train.iter().filter(|v| !v.rays.is_empty()).map(|v| v.time).collect();
        steps.sort_by(f32::total_cmp);
        steps.dedup();
        steps
    }
}

/// A field being trained and everything needed to continue: optimiser state, iteration count,
/// loss history, time spent. This is what a checkpoint holds.
#[derive(Clone, Debug)]
pub struct Learner<F> {
    pub field: F,
    pub adam: Adam,
    /// Iterations completed.
    pub iteration: usize,
    /// Training loss (normalised pixels², Eq. 5.5) of every completed iteration.
    pub losses: Vec<f32>,
    /// `(iteration, MSE)` on held-out views.
    pub holdout_losses: Vec<(usize, f32)>,
    /// Seconds spent in training iterations (callbacks excluded).
    pub train_time_s: f64,
}

impl<F: TrainableField> Learner<F> {
    pub fn new(field: F) -> Self {
        let n = field.num_params();
        Learner {
            field,
            adam: Adam::new(n, AdamConfig::default()),
            iteration: 0,
            losses: Vec::new(),
            holdout_losses: Vec::new(),
            train_time_s: 0.0,
        }
    }
}

impl<F: TrainableField> Learner<F> {
    /// A learner for a field that has not been trained yet: with `cfg.uniform_start` the
    /// field first starts from [`Prepared::mean_level`] ([`TrainableField::start_uniform`]).
    /// Use [`Learner::new`] for warm starts and checkpoints.
    pub fn fresh(mut field: F, prep: &Prepared, cfg: &TrainConfig) -> Self {
        let level = prep.mean_level();
        if cfg.uniform_start && level > 0.0 && level.is_finite() {
            field.start_uniform(level);
        }
        Learner::new(field)
    }
}

/// Per-view pixel masks for [`Prepared::with_masks`]: `true` = use the pixel. Empty lists
/// mean no masks; otherwise one entry per view of [`Problem::views`] / [`Problem::holdout`],
/// each `None` or `width × height` values, row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViewMasks {
    pub train: Vec<Option<Vec<bool>>>,
    pub holdout: Vec<Option<Vec<bool>>>,
}

/// Keeps the rays whose pixel the mask uses.
fn drop_masked_rays(rays: &mut ImageRays, mask: &[bool]) {
    let keep: Vec<bool> = rays.pixel.iter().map(|&p| mask[p as usize]).collect();
    let filter = |v: &mut Vec<f32>| {
        let mut k = keep.iter();
        v.retain(|_| *k.next().unwrap_or(&false));
    };
    for d in rays.dir_unit.iter_mut().chain(&mut rays.dir_du).chain(&mut rays.dir_dv) {
        filter(d);
    }
    filter(&mut rays.near);
    filter(&mut rays.far);
    let mut k = keep.iter();
    rays.pixel.retain(|_| *k.next().unwrap_or(&false));
}

/// Per-view gains fitted with the field ([`train_fitting_gains`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GainFit {
    /// Iterations between refits. Must be positive.
    pub every: usize,
    /// Rays per training view rendered for a refit (a fixed, evenly spread subset).
    pub rays_per_view: usize,
    /// Also fit an offset per view.
    pub offset: bool,
}

/// [`train`] with a gain (and optionally an offset) per training view fitted jointly with the
/// field: the model of view `v`'s pixels is `g_v × rendered + b_v`. Training alternates
/// blocks: `fit.every` field iterations on the targets `(measured − b_v) / g_v`, then for
/// every view the exact least-squares `(g_v, b_v)` of its measured pixels against the field's
/// renders of a fixed subset of `fit.rays_per_view` rays (no gradients; stream
/// [`crate::batch::GAIN_STREAM`]), gains normalised to mean 1 (the absolute scale stays with
/// the field). A run with gains already trained (a resumed one) refits first. Returns the
/// report and the final `(gain, offset)` per training view, offsets in normalised pixel
/// units ([`Prepared::image_scale`]).
pub fn train_fitting_gains<F: TrainableField>(
    prep: &mut Prepared,
    learner: &mut Learner<F>,
    cfg: &TrainConfig,
    seed: u64,
    fit: &GainFit,
    mut on_iter: impl FnMut(&TrainState<F>) -> ControlFlow<()>,
) -> Result<(TrainReport, Vec<(f32, f32)>), NeuralError> {
    if fit.every == 0 || fit.rays_per_view == 0 {
        return Err(NeuralError::invalid("gains", "refit interval and rays per view must be positive"));
    }
    let mut engine = CpuEngine::new(&learner.field, rayon::current_num_threads());
    let mut gains = vec![(1.0f32, 0.0f32); prep.train.len()];
    let start_time = learner.train_time_s;
    let start_iteration = learner.iteration;
    let mut samples = 0.0f64;
    if learner.iteration > 0 {
        refit_gains(prep, &learner.field, cfg, seed, fit, &mut engine, &mut gains);
    }
    let report = loop {
        let next = ((learner.iteration / fit.every + 1) * fit.every).min(cfg.max_iterations);
        let mut segment = TrainConfig { max_iterations: next, ..cfg.clone() };
        if let Some(b) = cfg.time_budget_s {
            let left = b - (learner.train_time_s - start_time);
            if left <= 0.0 {
                break None;
            }
            segment.time_budget_s = Some(left);
        }
        let before = learner.iteration;
        let r = train_with_engine(prep, learner, &segment, seed, &mut engine, &mut on_iter)?;
        samples += r.samples_per_second * r.seconds_per_iteration * (learner.iteration - before) as f64;
        if r.stop_reason != StopReason::MaxIterations || learner.iteration >= cfg.max_iterations {
            break Some(r);
        }
        refit_gains(prep, &learner.field, cfg, seed, fit, &mut engine, &mut gains);
    };
    let loop_time = learner.train_time_s - start_time;
    let done = learner.iteration - start_iteration;
    let smoothing = cfg.stop.smoothing.max(1);
    let report = TrainReport {
        stop_reason: report.map_or(StopReason::TimeBudget, |r| r.stop_reason),
        iterations: learner.iteration,
        final_loss: learner.losses.last().copied().unwrap_or(f32::NAN),
        smoothed_loss: running_mean(&learner.losses, smoothing),
        train_time_s: learner.train_time_s,
        seconds_per_iteration: if done > 0 { loop_time / done as f64 } else { 0.0 },
        samples_per_second: if loop_time > 0.0 { samples / loop_time } else { 0.0 },
        bf16_products: learner.field.bf16_products(),
    };
    Ok((report, gains))
}

/// One gain refit of [`train_fitting_gains`]: renders the fixed ray subset of every training
/// view, fits `(g, b)` against the measured targets, normalises to mean gain 1 and sets the
/// targets. A view whose fit fails (dark render, or no light measured) keeps its gain and
/// counts in no mean: a dead camera would otherwise rescale every other one.
fn refit_gains<F: TrainableField, E: Engine<F>>(
    prep: &mut Prepared,
    field: &F,
    cfg: &TrainConfig,
    seed: u64,
    fit: &GainFit,
    engine: &mut E,
    gains: &mut [(f32, f32)],
) {
    let mut rendered = Vec::new();
    let mut fitted = vec![false; gains.len()];
    for v in 0..prep.train.len() {
        let n = prep.train[v].rays.len();
        if n == 0 {
            continue;
        }
        let take = fit.rays_per_view.min(n);
        let rays: Vec<(u32, u32)> = (0..take).map(|k| (v as u32, (k * n / take) as u32)).collect();
        let batch = RayBatch {
            split: Split::Train,
            rays,
            seed,
            stream: crate::batch::GAIN_STREAM,
            jitter: Vec::new(),
            group: 1,
        };
        engine.render(field, prep, cfg, &batch, &mut rendered);
        let pv = &prep.train[v];
        let measured = pv.measured.as_deref().unwrap_or(&pv.targets);
        let (mut sn, mut sr, mut sp, mut srr, mut srp) = (0.0f64, 0.0, 0.0, 0.0, 0.0);
        for (&r, &(_, ray)) in rendered.iter().zip(&batch.rays) {
            let (r, p) = (r as f64, measured[ray as usize] as f64);
            sn += 1.0;
            sr += r;
            sp += p;
            srr += r * r;
            srp += r * p;
        }
        let (g, b) = if fit.offset {
            let det = sn * srr - sr * sr;
            if det.is_nan() || det <= 1e-12 * sn * srr {
                continue;
            }
            ((sn * srp - sr * sp) / det, (srr * sp - sr * srp) / det)
        } else if srr > 0.0 {
            (srp / srr, 0.0)
        } else {
            continue;
        };
        if g.is_finite() && g > 0.0 && b.is_finite() {
            gains[v] = (g as f32, b as f32);
            fitted[v] = true;
        }
    }
    let used = fitted.iter().filter(|&&f| f).count();
    let mean = gains.iter().zip(&fitted).filter(|(_, &f)| f).map(|(g, _)| g.0 as f64).sum::<f64>() / used.max(1) as f64;
    if mean > 0.0 && mean.is_finite() {
        gains.iter_mut().for_each(|g| g.0 /= mean as f32);
    }
    prep.set_gains(gains);
}

/// What the callback sees after each iteration.
#[derive(Debug)]
pub struct TrainState<'a, F> {
    pub field: &'a F,
    /// Everything a checkpoint needs (the field again, optimiser state, histories).
    pub learner: &'a Learner<F>,
    pub meta: &'a FieldMeta,
    /// Iterations completed.
    pub iteration: usize,
    pub loss: f32,
    /// Running mean over `stop.smoothing` iterations.
    pub smoothed_loss: f32,
    pub learning_rate: f32,
    /// Latest held-out MSE, if evaluated at this iteration.
    pub holdout_loss: Option<f32>,
    /// Training seconds so far (callbacks excluded).
    pub train_time_s: f64,
    /// Field evaluations (forward rows) in this iteration.
    pub samples: usize,
}

/// Why training stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StopReason {
    Converged,
    MaxIterations,
    TimeBudget,
    Interrupted,
}

/// Summary of a call to [`train`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainReport {
    pub stop_reason: StopReason,
    pub iterations: usize,
    pub final_loss: f32,
    pub smoothed_loss: f32,
    pub train_time_s: f64,
    /// Mean seconds per iteration in this call.
    pub seconds_per_iteration: f64,
    /// Field rows forwarded per second in this call (coarse passes not counted).
    pub samples_per_second: f64,
    /// Whether training took some of the field's products in bfloat16
    /// ([`TrainableField::bf16_products`]): which arithmetic this machine ran.
    #[serde(default)]
    pub bf16_products: bool,
}

/// Which views of a [`Prepared`] problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    Train,
    Holdout,
}

/// Renders every kept ray of view `index` of `split` with the training renderer (sampling,
/// skipping and quadrature as in training, no gradients); returns
/// `(pixel index, rendered, measured)` in normalised units (× `image_scale` for pixels).
pub fn render_view<F: TrainableField>(
    field: &F,
    prep: &Prepared,
    cfg: &TrainConfig,
    split: Split,
    index: usize,
    seed: u64,
) -> Vec<(u32, f32, f32)> {
    let batch = view_batch(prep, split, index, seed);
    let mut engine = CpuEngine::new(field, rayon::current_num_threads());
    let mut pixels = Vec::new();
    engine.render(field, prep, cfg, &batch, &mut pixels);
    let pv = &prep.views(split)[index];
    pixels
        .into_iter()
        .zip(&batch.rays)
        .map(|(i, &(_, r))| (pv.rays.pixel[r as usize], i, pv.targets[r as usize]))
        .collect()
}

/// Trains `learner.field` on `prep` from `learner.iteration` on (Eq. 5.1–5.5, §5.1.5) with the
/// CPU engine ([`CpuEngine`], one worker per thread of the current rayon pool), calling
/// `on_iter` after every iteration; breaking from it stops training with
/// [`StopReason::Interrupted`]. `seed` keys every random choice. See [`train_with_engine`].
pub fn train<F: TrainableField>(
    prep: &Prepared,
    learner: &mut Learner<F>,
    cfg: &TrainConfig,
    seed: u64,
    on_iter: impl FnMut(&TrainState<F>) -> ControlFlow<()>,
) -> Result<TrainReport, NeuralError> {
    let mut engine = CpuEngine::new(&learner.field, rayon::current_num_threads());
    train_with_engine(prep, learner, cfg, seed, &mut engine, on_iter)
}

/// The training loop of [`train`] over any [`Engine`]: per iteration the batch
/// ([`training_batch`]), the engine's loss and gradient, the check that the loss is finite,
/// the engine's Adam step at `cfg.schedule.lr(i)`, the held-out MSE every `validate_every`
/// iterations ([`holdout_batch`], [`Engine::render`]), the callback and the stopping rule.
///
/// A non-finite loss stops training with [`NeuralError::Diverged`] before the optimiser step:
/// `learner` (parameters, moments, iteration, histories) is left as it was after the last
/// finite iteration.
pub fn train_with_engine<F: TrainableField, E: Engine<F>>(
    prep: &Prepared,
    learner: &mut Learner<F>,
    cfg: &TrainConfig,
    seed: u64,
    engine: &mut E,
    mut on_iter: impl FnMut(&TrainState<F>) -> ControlFlow<()>,
) -> Result<TrainReport, NeuralError> {
    cfg.validate()?;
    engine.load_state(&learner.field, &learner.adam)?;
    let start_iteration = learner.iteration;
    let mut total_samples = 0usize;
    let mut loop_time = 0.0f64;
    let mut batch = RayBatch::new(Split::Train, seed, 0);
    batch.rays.reserve(prep.train.len() * cfg.rays_per_image);
    let holdout = holdout_batch(prep, cfg, seed);
    let mut holdout_pixels = Vec::new();
    let smoothing = cfg.stop.smoothing.max(1);
    let mut stop_reason = StopReason::MaxIterations;
    let steps = prep.time_steps();
    while learner.iteration < cfg.max_iterations {
        let t0 = Instant::now();
        let it = learner.iteration;
        training_batch(prep, cfg, seed, it, &steps, &mut batch);
        let BatchLoss { loss, samples } = engine.loss_and_gradient(&learner.field, prep, cfg, &batch);
        if !loss.is_finite() {
            engine.save_state(&mut learner.field, &mut learner.adam);
            return Err(NeuralError::Diverged { iteration: it, loss, prior: cfg.prior });
        }
        total_samples += samples;
        let lr = crate::batch::learning_rate(cfg, it, steps.len());
        learner.adam.config = cfg.adam;
        engine.apply_gradient(&mut learner.field, &mut learner.adam, lr);
        learner.losses.push(loss as f32);
        learner.iteration += 1;
        let holdout = match &holdout {
            Some(h) if cfg.validate_every > 0 && learner.iteration.is_multiple_of(cfg.validate_every) => {
                let mse = engine.render(&learner.field, prep, cfg, h, &mut holdout_pixels).loss as f32;
                learner.holdout_losses.push((learner.iteration, mse));
                Some(mse)
            }
            _ => None,
        };
        let dt = t0.elapsed().as_secs_f64();
        loop_time += dt;
        learner.train_time_s += dt;
        let smoothed = running_mean(&learner.losses, smoothing);
        engine.save_state(&mut learner.field, &mut learner.adam);
        let state = TrainState {
            field: &learner.field,
            learner,
            meta: &prep.meta,
            iteration: learner.iteration,
            loss: loss as f32,
            smoothed_loss: smoothed,
            learning_rate: lr,
            holdout_loss: holdout,
            train_time_s: learner.train_time_s,
            samples,
        };
        if on_iter(&state).is_break() {
            stop_reason = StopReason::Interrupted;
            break;
        }
        if converged(&learner.losses, &cfg.stop) {
            stop_reason = StopReason::Converged;
            break;
        }
        if cfg.time_budget_s.is_some_and(|b| loop_time >= b) {
            stop_reason = StopReason::TimeBudget;
            break;
        }
    }
    engine.save_state(&mut learner.field, &mut learner.adam);
    let done = learner.iteration - start_iteration;
    Ok(TrainReport {
        stop_reason,
        iterations: learner.iteration,
        final_loss: learner.losses.last().copied().unwrap_or(f32::NAN),
        smoothed_loss: running_mean(&learner.losses, smoothing),
        train_time_s: learner.train_time_s,
        seconds_per_iteration: if done > 0 { loop_time / done as f64 } else { 0.0 },
        samples_per_second: if loop_time > 0.0 { total_samples as f64 / loop_time } else { 0.0 },
        bf16_products: learner.field.bf16_products(),
    })
}

/// Mean of the last `n` values (of all, if fewer).
pub fn running_mean(values: &[f32], n: usize) -> f32 {
    let tail = &values[values.len().saturating_sub(n)..];
    if tail.is_empty() {
        return f32::NAN;
    }
    (tail.iter().map(|&v| v as f64).sum::<f64>() / tail.len() as f64) as f32
}

/// The §5.1.5 rule: the running mean now and `window` iterations ago differ by less than
/// `tolerance` (relative to the earlier one).
pub fn converged(losses: &[f32], rule: &StopRule) -> bool {
    if rule.window == 0 || losses.len() < rule.window + rule.smoothing {
        return false;
    }
    let now = running_mean(losses, rule.smoothing) as f64;
    let then = running_mean(&losses[..losses.len() - rule.window], rule.smoothing) as f64;
    then > 0.0 && ((now - then) / then).abs() < rule.tolerance
}
