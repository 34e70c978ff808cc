//! The FluidNeRF training loop (dissertation §5.1.4–5.1.5), generic over the field
//! representation.
//!
//! # One iteration
//! `N_pix/img` random pixels (with replacement) from **every** training image (§5.1.5), split
//! into chunks of rays. Each thread takes a fixed share of the chunks (chunk `c` goes to thread
//! `c mod T`, so results do not depend on scheduling) and, fused per chunk without
//! materialising per-step tensors:
//! 1. stratified samples on each ray (Eq. 5.1);
//! 2. with `N_f > 0`, the field evaluated at them without gradients, and `N_f` feature samples
//!    from `|dE/ds|` (see [`crate::sampling`]), merged;
//! 3. `field.forward` at all samples (skipping empty cells, see [`crate::occupancy`]);
//! 4. quadrature (Eq. 5.4), MSE against the measured pixels (Eq. 5.5), and the exact backward
//!    `∂L/∂E_j` ([`crate::render`]);
//! 5. `field.backward` into the thread's own gradient buffer.
//!
//! The gradient buffers are summed and one Adam step is taken with the learning rate of the
//! schedule `lr(i) = lr₀ (lr₁ / lr₀)^{i / N_decay}` (5e-4 → 5e-5 at 25 000 iterations).
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
//! Determinism: all randomness comes from ChaCha8 streams keyed by (seed, iteration, chunk), so
//! a run is reproducible for a given thread count, and resuming at iteration `k` continues
//! exactly as an uninterrupted run would (given the optimiser state).

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_core::{Aabb, Camera, Image};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::occupancy::{OccupancyConfig, OccupancyGrid, OccupancyRecord};
use crate::optim::{sum_gradients, Adam, AdamConfig, LrSchedule};
use crate::render::{mse_term, quadrature_weights, render, Quadrature};
use crate::sampling::{feature_samples, merge_sorted, stratified, ImageRays};
use crate::{NeuralError, TrainableField};

/// The stopping rule of §5.1.5.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StopRule {
    /// Iterations of the running mean. Default 200.
    pub smoothing: usize,
    /// Iterations over which the smoothed loss must stay within the tolerance; 0 disables the
    /// rule. Default 2000.
    pub window: usize,
    /// Relative change of the smoothed loss across the window. Default 0.02.
    pub tolerance: f64,
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
    /// Iteration cap. Default 25 000.
    pub max_iterations: usize,
    /// Wall-time budget of the training loop in seconds (None: unlimited). Default None.
    pub time_budget_s: Option<f64>,
    pub stop: StopRule,
    /// Empty-space skipping (None: off, as in the dissertation). Default None.
    pub occupancy: Option<OccupancyConfig>,
    /// Field rows per chunk of rays handed to one thread (at least one ray). Default 256, the
    /// MLP's sweet spot (its activations stay in cache); grid fields prefer ~8192.
    pub chunk_samples: usize,
    /// Pixel normalisation; None takes the largest training pixel. Default None.
    pub image_scale: Option<f32>,
    /// Iterations between evaluations of the held-out views (0: never). Default 100.
    pub validate_every: usize,
    /// Held-out pixels evaluated each time (a fixed random subset). Default 4096.
    pub validate_pixels: usize,
    /// Views of one iteration. Default all views.
    pub batching: Batching,
    /// Start a fresh field from the uniform value that explains the mean training pixel
    /// ([`TrainableField::start_uniform`]) instead of the representation's own
    /// initialisation. Default true.
    pub uniform_start: bool,
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
            uniform_start: true,
        }
    }
}

impl TrainConfig {
    /// Rejects settings no run can use.
    pub fn validate(&self) -> Result<(), NeuralError> {
        let bad = |what: &str, why: String| Err(NeuralError::invalid(what, why));
        if self.coarse_samples < 2 {
            return bad("coarse_samples", format!("needs at least 2, got {}", self.coarse_samples));
        }
        if self.rays_per_image == 0 {
            return bad("rays_per_image", "must be positive".into());
        }
        self.schedule.validate()?;
        self.adam.validate()?;
        if let Some(t) = self.time_budget_s {
            if t.is_nan() || t <= 0.0 {
                return bad("time_budget_s", format!("must be positive, got {t}"));
            }
        }
        if let Some(s) = self.image_scale {
            if !(s > 0.0 && s.is_finite()) {
                return bad("image_scale", format!("must be positive, got {s}"));
            }
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
}

#[derive(Debug)]
struct PreparedView {
    rays: ImageRays,
    targets: Vec<f32>,
    time: f32,
}

impl Prepared {
    /// Casts and clips every training ray, carves the occupancy grid (when configured) and
    /// normalises the images.
    pub fn new(problem: &Problem, cfg: &TrainConfig) -> Result<Self, NeuralError> {
        cfg.validate()?;
        problem.aabb.validate().map_err(|e| NeuralError::invalid("reconstruction box", e.to_string()))?;
        if problem.views.is_empty() {
            return Err(NeuralError::invalid("scene", "no training images"));
        }
        if !(problem.intensity_scale > 0.0 && problem.intensity_scale.is_finite()) {
            return Err(NeuralError::invalid(
                "intensity_scale",
                format!("must be positive, got {}", problem.intensity_scale),
            ));
        }
        if !(problem.time_step > 0.0 && problem.time_step.is_finite()) {
            return Err(NeuralError::invalid("time_step", format!("must be positive, got {}", problem.time_step)));
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
        let image_scale = match cfg.image_scale {
            Some(s) => s,
            None => problem.views.iter().map(|v| v.image.min_max().1).fold(0.0f32, f32::max),
        };
        if image_scale.is_nan() || image_scale <= 0.0 {
            return Err(NeuralError::invalid("images", "all training images are black"));
        }
        let length = problem.aabb.size().max_element();
        let occupancy = cfg.occupancy.as_ref().map(|oc| {
            let views: Vec<(&Camera, &Image)> = problem.views.iter().map(|v| (&v.camera, &v.image)).collect();
            OccupancyGrid::from_views(&problem.aabb, &views, oc)
        });
        let prep = |v: &View, occ: Option<&OccupancyGrid>| -> Result<PreparedView, NeuralError> {
            let rays = ImageRays::new(&v.camera, &problem.aabb, occ)
                .map_err(|e| NeuralError::invalid("camera", e.to_string()))?;
            let targets = rays.targets(&v.image, image_scale);
            Ok(PreparedView { rays, targets, time: (v.time / problem.time_step) as f32 })
        };
        let train = problem.views.par_iter().map(|v| prep(v, occupancy.as_ref())).collect::<Result<Vec<_>, _>>()?;
        if train.iter().all(|v| v.rays.is_empty()) {
            return Err(NeuralError::invalid("scene", "no camera sees the reconstruction box"));
        }
        // Held-out views are rendered through the same model (mask included) as the result.
        let holdout = problem.holdout.par_iter().map(|v| prep(v, occupancy.as_ref())).collect::<Result<Vec<_>, _>>()?;
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
        })
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
}

/// Per-thread scratch, reused across chunks and iterations.
struct Worker<T> {
    tape: T,
    grads: Vec<f32>,
    inputs: Vec<f32>,
    active: Vec<u32>,
    e_active: Vec<f32>,
    d_active: Vec<f32>,
    s_coarse: Vec<f32>,
    e_coarse: Vec<f32>,
    s_fine: Vec<f32>,
    s_all: Vec<f32>,
    e_all: Vec<f32>,
    w: Vec<f32>,
    loss: f64,
    samples: usize,
}

fn stream_seed(seed: u64, iteration: usize, chunk: usize) -> u64 {
    // SplitMix64 finaliser over the three keys.
    let mut z = seed
        ^ (iteration as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (chunk as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Renders the rays `batch` (view, ray) of `views` and, when `targets` is true, accumulates
/// the loss over `n_pix` pixels and its parameter gradient into the worker.
fn process_chunk<F: TrainableField>(
    field: &F,
    prep: &Prepared,
    views: &[PreparedView],
    cfg: &TrainConfig,
    batch: &[(u32, u32)],
    n_pix: usize,
    rng: &mut ChaCha8Rng,
    wk: &mut Worker<F::Tape>,
    with_grad: bool,
) -> Vec<f32> {
    let (nc, nf) = (cfg.coarse_samples, cfg.fine_samples);
    let nt = nc + nf;
    let dim = field.input_dim();
    let nr = batch.len();
    wk.s_coarse.resize(nr * nc, 0.0);
    wk.s_all.resize(nr * nt, 0.0);
    wk.e_all.resize(nr * nt, 0.0);
    wk.w.resize(nt, 0.0);
    let occ = prep.occupancy.as_ref();
    // Gathers the active samples of `s` (n per ray) into `inputs`, remembering their index.
    let gather = |s: &[f32], n: usize, inputs: &mut Vec<f32>, active: &mut Vec<u32>| {
        inputs.clear();
        active.clear();
        for (r, &(v, ray)) in batch.iter().enumerate() {
            let pv = &views[v as usize];
            for q in 0..n {
                let u = pv.rays.point_unit(ray as usize, s[r * n + q]);
                if occ.is_some_and(|g| !g.is_occupied(u)) {
                    continue;
                }
                inputs.extend_from_slice(&u);
                if dim == 4 {
                    inputs.push(pv.time);
                }
                active.push((r * n + q) as u32);
            }
        }
    };
    for (r, &(v, ray)) in batch.iter().enumerate() {
        let rays = &views[v as usize].rays;
        let (near, far) = (rays.near[ray as usize], rays.far[ray as usize]);
        stratified(near, far, rng, &mut wk.s_coarse[r * nc..(r + 1) * nc]);
    }
    if nf > 0 {
        gather(&wk.s_coarse, nc, &mut wk.inputs, &mut wk.active);
        wk.e_active.resize(wk.active.len(), 0.0);
        if !wk.active.is_empty() {
            field.eval(&wk.inputs, &mut wk.e_active, &mut wk.tape);
        }
        wk.e_coarse.clear();
        wk.e_coarse.resize(nr * nc, 0.0);
        for (&a, &e) in wk.active.iter().zip(&wk.e_active) {
            wk.e_coarse[a as usize] = e;
        }
        wk.s_fine.resize(nf, 0.0);
        for r in 0..nr {
            let sc = &wk.s_coarse[r * nc..(r + 1) * nc];
            feature_samples(sc, &wk.e_coarse[r * nc..(r + 1) * nc], rng, &mut wk.s_fine);
            merge_sorted(sc, &wk.s_fine, &mut wk.s_all[r * nt..(r + 1) * nt]);
        }
    } else {
        wk.s_all.copy_from_slice(&wk.s_coarse);
    }
    gather(&wk.s_all, nt, &mut wk.inputs, &mut wk.active);
    wk.e_active.resize(wk.active.len(), 0.0);
    if !wk.active.is_empty() {
        if with_grad {
            field.forward(&wk.inputs, &mut wk.e_active, &mut wk.tape);
        } else {
            field.eval(&wk.inputs, &mut wk.e_active, &mut wk.tape);
        }
    }
    wk.samples += wk.active.len();
    wk.e_all.fill(0.0);
    for (&a, &e) in wk.active.iter().zip(&wk.e_active) {
        wk.e_all[a as usize] = e;
    }
    // Render, loss, and ∂L/∂E per sample (stored in e_all's place once a ray is rendered).
    let mut rendered = Vec::with_capacity(if with_grad { 0 } else { nr });
    for (r, &(v, ray)) in batch.iter().enumerate() {
        let pv = &views[v as usize];
        let ray = ray as usize;
        let s = &wk.s_all[r * nt..(r + 1) * nt];
        quadrature_weights(
            s,
            pv.rays.near[ray],
            pv.rays.far[ray],
            &pv.rays.emission,
            &prep.quad,
            prep.length_scale,
            &mut wk.w,
        );
        let e = &mut wk.e_all[r * nt..(r + 1) * nt];
        let pixel = render(&wk.w, e);
        let (l, d_pixel) = mse_term(pixel, pv.targets[ray], n_pix);
        wk.loss += l as f64;
        if with_grad {
            for (ej, &wj) in e.iter_mut().zip(&wk.w) {
                *ej = d_pixel * wj;
            }
        } else {
            rendered.push(pixel);
        }
    }
    if with_grad && !wk.active.is_empty() {
        wk.d_active.clear();
        wk.d_active.extend(wk.active.iter().map(|&a| wk.e_all[a as usize]));
        field.backward(&mut wk.tape, &wk.d_active, &mut wk.grads);
    }
    rendered
}

fn new_worker<F: TrainableField>(field: &F, with_grads: bool) -> Worker<F::Tape> {
    Worker {
        tape: field.new_tape(),
        grads: if with_grads { vec![0.0; field.num_params()] } else { Vec::new() },
        inputs: Vec::new(),
        active: Vec::new(),
        e_active: Vec::new(),
        d_active: Vec::new(),
        s_coarse: Vec::new(),
        e_coarse: Vec::new(),
        s_fine: Vec::new(),
        s_all: Vec::new(),
        e_all: Vec::new(),
        w: Vec::new(),
        loss: 0.0,
        samples: 0,
    }
}

/// Runs `batch` over the workers (chunk `c` on worker `c mod T`); returns (loss, samples).
fn run_batch<F: TrainableField>(
    field: &F,
    prep: &Prepared,
    views: &[PreparedView],
    cfg: &TrainConfig,
    workers: &mut [Worker<F::Tape>],
    batch: &[(u32, u32)],
    seed: u64,
    iteration: usize,
    with_grad: bool,
) -> (f64, usize) {
    let rays_per_chunk = (cfg.chunk_samples / (cfg.coarse_samples + cfg.fine_samples)).max(1);
    let chunks: Vec<&[(u32, u32)]> = batch.chunks(rays_per_chunk).collect();
    let nw = workers.len();
    let n_pix = batch.len();
    workers.par_iter_mut().enumerate().for_each(|(t, wk)| {
        wk.loss = 0.0;
        wk.samples = 0;
        for c in (t..chunks.len()).step_by(nw) {
            let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(seed, iteration, c));
            process_chunk(field, prep, views, cfg, chunks[c], n_pix, &mut rng, wk, with_grad);
        }
    });
    (workers.iter().map(|w| w.loss).sum(), workers.iter().map(|w| w.samples).sum())
}

/// Mean squared error over a fixed subset of the held-out pixels (normalised units), or None
/// without held-out views.
fn holdout_mse<F: TrainableField>(
    field: &F,
    prep: &Prepared,
    cfg: &TrainConfig,
    workers: &mut [Worker<F::Tape>],
    seed: u64,
) -> Option<f32> {
    let total: usize = prep.holdout.iter().map(|v| v.rays.len()).sum();
    if total == 0 || cfg.validate_pixels == 0 {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(seed ^ 0x5EED, usize::MAX, 0));
    let per_view = cfg.validate_pixels.div_ceil(prep.holdout.len());
    let mut batch = Vec::new();
    for (v, pv) in prep.holdout.iter().enumerate() {
        for _ in 0..per_view.min(pv.rays.len()) {
            batch.push((v as u32, rng.random_range(0..pv.rays.len()) as u32));
        }
    }
    let (loss, _) = run_batch(field, prep, &prep.holdout, cfg, workers, &batch, seed ^ 0x5EED, usize::MAX, false);
    Some(loss as f32)
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
    let views = match split {
        Split::Train => &prep.train,
        Split::Holdout => &prep.holdout,
    };
    let pv = &views[index];
    let batch: Vec<(u32, u32)> = (0..pv.rays.len() as u32).map(|r| (index as u32, r)).collect();
    let rays_per_chunk = (cfg.chunk_samples / (cfg.coarse_samples + cfg.fine_samples)).max(1);
    let out: Vec<Vec<f32>> = batch
        .par_chunks(rays_per_chunk)
        .enumerate()
        .map_init(
            || new_worker(field, false),
            |wk, (c, chunk)| {
                let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(seed, usize::MAX - 1, c));
                process_chunk(field, prep, views, cfg, chunk, 1, &mut rng, wk, false)
            },
        )
        .collect();
    out.into_iter()
        .flatten()
        .zip(&batch)
        .map(|(i, &(_, r))| (pv.rays.pixel[r as usize], i, pv.targets[r as usize]))
        .collect()
}

/// Trains `learner.field` on `prep` from `learner.iteration` on (Eq. 5.1–5.5, §5.1.5), calling
/// `on_iter` after every iteration; breaking from it stops training with
/// [`StopReason::Interrupted`]. `seed` keys every random choice.
pub fn train<F: TrainableField>(
    prep: &Prepared,
    learner: &mut Learner<F>,
    cfg: &TrainConfig,
    seed: u64,
    mut on_iter: impl FnMut(&TrainState<F>) -> ControlFlow<()>,
) -> Result<TrainReport, NeuralError> {
    cfg.validate()?;
    let input_dim = learner.field.input_dim();
    if input_dim != 3 && input_dim != 4 {
        return Err(NeuralError::invalid("field", format!("input dimension must be 3 or 4, got {input_dim}")));
    }
    if learner.adam.m.len() != learner.field.num_params() {
        return Err(NeuralError::invalid("optimiser state", "does not match the field's parameter count"));
    }
    let nthreads = rayon::current_num_threads().max(1);
    let mut workers: Vec<Worker<F::Tape>> = (0..nthreads).map(|_| new_worker(&learner.field, true)).collect();
    let mut eval_workers: Vec<Worker<F::Tape>> = Vec::new();
    let start_iteration = learner.iteration;
    let mut total_samples = 0usize;
    let mut loop_time = 0.0f64;
    let mut batch: Vec<(u32, u32)> = Vec::with_capacity(prep.train.len() * cfg.rays_per_image);
    let smoothing = cfg.stop.smoothing.max(1);
    let mut grads = vec![0.0f32; learner.field.num_params()];
    let mut stop_reason = StopReason::MaxIterations;
    let steps = time_steps(prep);
    while learner.iteration < cfg.max_iterations {
        let t0 = Instant::now();
        let it = learner.iteration;
        let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(seed, it, usize::MAX));
        let step = (cfg.batching == Batching::OneTimeStep).then(|| steps[it % steps.len()]);
        batch.clear();
        for (v, pv) in prep.train.iter().enumerate() {
            if pv.rays.is_empty() || step.is_some_and(|t| pv.time != t) {
                continue;
            }
            for _ in 0..cfg.rays_per_image {
                batch.push((v as u32, rng.random_range(0..pv.rays.len()) as u32));
            }
        }
        let (loss, samples) = run_batch(&learner.field, prep, &prep.train, cfg, &mut workers, &batch, seed, it, true);
        total_samples += samples;
        let mut per_thread: Vec<Vec<f32>> = workers.iter_mut().map(|w| std::mem::take(&mut w.grads)).collect();
        sum_gradients(&mut per_thread, &mut grads);
        for (w, g) in workers.iter_mut().zip(per_thread) {
            w.grads = g;
        }
        let lr = cfg.schedule.lr(it as u64);
        learner.adam.config = cfg.adam;
        learner.adam.step(learner.field.params_mut(), &grads, lr);
        if !loss.is_finite() {
            return Err(NeuralError::invalid("training", format!("the loss became {loss} at iteration {it}")));
        }
        learner.losses.push(loss as f32);
        learner.iteration += 1;
        let holdout = if cfg.validate_every > 0 && learner.iteration % cfg.validate_every == 0 {
            if eval_workers.is_empty() {
                eval_workers = (0..nthreads).map(|_| new_worker(&learner.field, false)).collect();
            }
            let h = holdout_mse(&learner.field, prep, cfg, &mut eval_workers, seed);
            if let Some(h) = h {
                learner.holdout_losses.push((learner.iteration, h));
            }
            h
        } else {
            None
        };
        let dt = t0.elapsed().as_secs_f64();
        loop_time += dt;
        learner.train_time_s += dt;
        let smoothed = running_mean(&learner.losses, smoothing);
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
    let done = learner.iteration - start_iteration;
    Ok(TrainReport {
        stop_reason,
        iterations: learner.iteration,
        final_loss: learner.losses.last().copied().unwrap_or(f32::NAN),
        smoothed_loss: running_mean(&learner.losses, smoothing),
        train_time_s: learner.train_time_s,
        seconds_per_iteration: if done > 0 { loop_time / done as f64 } else { 0.0 },
        samples_per_second: if loop_time > 0.0 { total_samples as f64 / loop_time } else { 0.0 },
    })
}

/// The distinct frame times `t'` of the training views that see the box, increasing.
fn time_steps(prep: &Prepared) -> Vec<f32> {
    let mut steps: Vec<f32> = prep.train.iter().filter(|v| !v.rays.is_empty()).map(|v| v.time).collect();
    steps.sort_by(f32::total_cmp);
    steps.dedup();
    steps
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
