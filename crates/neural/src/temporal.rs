//! Time-resolved FluidNeRF (dissertation §5.2): one field E(x, t) trained on every frame of a
//! recording, and its scaling to long recordings by sliding windows.
//!
//! # The method (§5.2, Table 5.2)
//! - Inputs `(x, y, z, t')`: box-normalised space (the field contract, [`crate::field`]) and the
//!   frame time `t' = (t − t₀) / Δt`, `Δt` the frame spacing and `t₀` the time origin (below).
//!   The dissertation normalises by `Δt` so that the temporal encoding (Eq. 5.2 with `L_t`
//!   frequencies) does not collapse for small time steps; the origin only shifts `t'` by an
//!   integer number of frames.
//! - One iteration = `N_pix/img` pixels from every image of ONE time step, cycling through the
//!   time steps ([`crate::train::Batching::OneTimeStep`]); everything else (sampling,
//!   rendering, loss, Adam, stopping rule, checkpoints) is the static method of
//!   [`crate::train`] on the CPU engine ([`crate::engine::cpu`]).
//! - Presets ([`temporal_preset`]): `tr-faithful` (Table 5.2, with `L_t = 1` as the results of
//!   chapter 7.2 use), `tr-table-5.2` (literally `L_t = 0`), `tr-experimental` (Table 8.4),
//!   `tr-fast` (a space–time hash grid with a tiny MLP), `tr-small` (a machine-sized MLP for
//!   CPU studies), and the static comparison of §5.2 (`static-swish`: D 8, H 256, other settings
//!   as TR) and `static-small` (as `tr-small` without time).
//!
//! # The fast field
//! `tr-fast` is [`crate::hashgrid::HashGridField`] with 4D inputs: its time axis spans the
//! window's frames (`time_span = W − 1`, one grid cell per frame interval at every level whose
//! spatial resolution allows it), so between frames it interpolates linearly in the features.
//! Every level holds at most `2^T` entries: memory is bounded whatever the number of frames, and
//! only the coarse (dense) levels grow with them until they too reach `2^T`
//! ([`fast_field_memory`]).
//!
//! # Windows
//! Frames are split into overlapping windows of `W` frames ([`crate::window`]); each window is
//! a separate training problem. With `warm_start`, a window starts from the previous window's
//! trained weights (same shape: all windows have `W` frames), with a fresh optimiser. Outputs
//! of overlapping windows are cross-faded linearly in time ([`crate::window::blend`],
//! [`StitchedField`]).
//!
//! # Time origin ([`TimeOrigin`])
//! A warm start only helps if the copied field means the same thing in the new window. With
//! the origin at each window's first frame, a frame shared by two windows has `t'` smaller by
//! the stride `W − O` in the later one, so the copied field starts out shifted in time by
//! `W − O` frames. The MLP takes any `t'`, so its windows can share the recording's first frame
//! as origin (`recording`): shared frames keep their `t'` and the warm start continues the same
//! function there, but the new frames then lie beyond the copied field's time range (an
//! extrapolation), where the shifted copy offers them an earlier frame's field instead. On the
//! starting jet both end equal (docs/time-resolved.md), so the default stays `window`, which
//! also keeps `t'` within `[0, W − 1]` however long the recording. The hash grid clamps `t'` to
//! its time axis `[0, W − 1]` and needs `window`; aligning it would need a time axis that
//! wraps around (a ring of `≥ W` frames), which the grid does not have.
//!
//! # Resuming
//! [`train_windows`] takes a [`ResumeState`] (finished windows, the running window's learner)
//! and reports [`WindowEvent::Finished`] when a window is done, the moment a caller saves it.
//! Training is deterministic per seed and thread count, so a resumed run ends with the same
//! weights as an uninterrupted one.
//!
//! Per-frame static FluidNeRF is the special case `W = 1`, no overlap, a 3D field, no warm
//! start; its stitched field interpolates linearly between neighbouring frames.

use std::ops::{ControlFlow, Range};
use std::path::Path;
use std::sync::OnceLock;

use fluidnerf_core::{num, Aabb, ScalarField, Support};
use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::hashgrid::{HashGridConfig, HashGridField};
use crate::mlp::{Activation, MlpConfig};
use crate::occupancy::OccupancyConfig;
use crate::optim::LrSchedule;
use crate::train::{
    converged, running_mean, train, Batching, FieldMeta, Learner, Prepared, Problem, StopReason, StopRule, TrainConfig,
    TrainReport, TrainState, ViewMasks,
};
use crate::trained::{build_field_for_weights, AnyField, FieldConfig, NeuralConfig, TrainedField};
use crate::window::{blend, frame_position, plan_windows, time_at};
use crate::{NeuralError, TrainableField};

/// How a recording is cut into windows.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WindowConfig {
    /// Frames per window `W`; 0 trains one field on all frames. Default 0.
    pub frames: usize,
    /// Frames shared by consecutive windows `O` (< W). Default 2.
    pub overlap: usize,
    /// Start each window from the previous window's weights. Default true.
    pub warm_start: bool,
    /// Iteration cap of warm-started windows, 1 to [`fluidnerf_core::MAX_ITERATIONS`] (None: the
    /// training config's). Default None.
    pub warm_max_iterations: Option<usize>,
    /// Where each window's time axis starts (module doc, "Time origin"). Default window.
    pub time_origin: TimeOrigin,
}

impl Default for WindowConfig {
    fn default() -> Self {
        WindowConfig {
            frames: 0,
            overlap: 2,
            warm_start: true,
            warm_max_iterations: None,
            time_origin: TimeOrigin::Window,
        }
    }
}

/// The origin `t₀` of a window's frame time `t' = (t − t₀) / Δt`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TimeOrigin {
    /// Each window's first frame: `t' ∈ [0, W − 1]`, the span of the grid field's time axis.
    #[default]
    Window,
    /// The recording's first frame, for every window: a frame shared by two windows keeps its
    /// `t'`, so a warm-started window continues the previous window's function of time instead
    /// of seeing it shifted by the stride. Needs a field without a bounded time axis (the MLP).
    Recording,
}

impl WindowConfig {
    /// One window per frame, no overlap, independent training: per-frame static FluidNeRF.
    pub fn per_frame() -> Self {
        WindowConfig {
            frames: 1,
            overlap: 0,
            warm_start: false,
            warm_max_iterations: None,
            time_origin: TimeOrigin::Window,
        }
    }

    pub fn validate(&self) -> Result<(), NeuralError> {
        if self.frames > 0 && self.overlap >= self.frames {
            return Err(NeuralError::invalid(
                "windows.overlap",
                format!("{} frames must be fewer than the window's {}", self.overlap, self.frames),
            ));
        }
        let max = fluidnerf_core::MAX_ITERATIONS;
        if let Some(n) = self.warm_max_iterations.filter(|n| !(1..=max).contains(n)) {
            return Err(NeuralError::invalid(
                "windows.warm_max_iterations",
                format!("must be 1 to {max} iterations, got {n}"),
            ));
        }
        Ok(())
    }
}

/// Everything a time-resolved reconstruction is configured by.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TemporalConfig {
    pub field: FieldConfig,
    pub train: TrainConfig,
    pub windows: WindowConfig,
}

impl Default for TemporalConfig {
    fn default() -> Self {
        temporal_preset("tr-faithful").unwrap_or_else(|| unreachable!())
    }
}

impl TemporalConfig {
    /// Rejects settings no run can use; in particular the hash grid clamps `t'` to its time
    /// axis `[0, W − 1]`, so it cannot take the recording's origin once there are windows.
    pub fn validate(&self) -> Result<(), NeuralError> {
        self.windows.validate()?;
        self.train.validate()?;
        if self.windows.time_origin == TimeOrigin::Recording
            && matches!(self.field, FieldConfig::HashGrid(_))
            && self.windows.frames > 0
        {
            return Err(NeuralError::invalid(
                "windows.time_origin",
                "the hash grid's time axis spans one window; windows of a grid field need the window origin",
            ));
        }
        Ok(())
    }
}

/// Names accepted by [`temporal_preset`].
pub const TEMPORAL_PRESETS: [&str; 7] =
    ["tr-faithful", "tr-table-5.2", "tr-experimental", "tr-fast", "tr-small", "static-swish", "static-small"];

/// A named time-resolved configuration (module doc). The static ones (`static-*`) use
/// per-frame windows and all-view batching; their field is built with 3 inputs.
pub fn temporal_preset(name: &str) -> Option<TemporalConfig> {
    let tr_train = TrainConfig {
        coarse_samples: 64,
        fine_samples: 64,
        rays_per_image: 1024,
        batching: Batching::OneTimeStep,
        ..TrainConfig::default()
    };
    let tr = |field: MlpConfig| TemporalConfig {
        field: FieldConfig::Mlp(field),
        train: tr_train.clone(),
        windows: WindowConfig::default(),
    };
    let small = MlpConfig {
        depth: 6,
        width: 64,
        space_freqs: 8,
        time_freqs: 1,
        activation: Activation::Swish,
        ..MlpConfig::default()
    };
    let small_train = TrainConfig {
        coarse_samples: 32,
        fine_samples: 32,
        rays_per_image: 256,
        schedule: LrSchedule { initial: 2e-3, at_decay_iters: 2e-4, decay_iters: 6000 },
        max_iterations: 6000,
        stop: StopRule { smoothing: 100, window: 1000, tolerance: 0.01 },
        ..tr_train.clone()
    };
    let per_frame = |mut c: TemporalConfig| {
        c.train.batching = Batching::AllViews;
        c.windows = WindowConfig::per_frame();
        c
    };
    match name {
        "tr-faithful" => Some(tr(MlpConfig { time_freqs: 1, ..MlpConfig::table_5_2() })),
        "tr-table-5.2" => Some(tr(MlpConfig::table_5_2())),
        "tr-experimental" => Some(tr(MlpConfig {
            depth: 10,
            width: 256,
            space_freqs: 2,
            time_freqs: 1,
            activation: Activation::Swish,
            ..MlpConfig::default()
        })),
        "tr-small" => Some(TemporalConfig { train: small_train, ..tr(small.clone()) }),
        "static-swish" => Some(per_frame(tr(MlpConfig {
            depth: 8,
            width: 256,
            activation: Activation::Swish,
            ..MlpConfig::default()
        }))),
        "static-small" => {
            Some(per_frame(TemporalConfig { train: small_train, ..tr(MlpConfig { time_freqs: 0, ..small }) }))
        }
        "tr-fast" => {
            let base = NeuralConfig::preset("fast")?;
            let FieldConfig::HashGrid(grid) = base.field else { return None };
            Some(TemporalConfig {
                // No levels without a time axis (`static_levels`): they helped the 12-camera jet
                // and cost the 60-camera one at equal time (docs/time-resolved.md, "Levels
                // without a time axis, three seeds").
                field: FieldConfig::HashGrid(HashGridConfig { log2_table_size: 18, ..grid }),
                // Each frame's learning rates are those a run on that frame alone would give
                // it; Adam stays dense, which measured better than lazy updates of the
                // frames' table entries (docs/time-resolved.md, "Each frame trained as if
                // alone"). Like `fast`, rays over each pixel's area on clean images.
                train: TrainConfig {
                    batching: Batching::OneTimeStep,
                    schedule_per_frame: true,
                    // Judged settled per frame, as the schedule runs per frame: counted in
                    // iterations, the rule stopped a three-frame window of the 60-camera jet
                    // at 0.105 where twice the iterations reach 0.07 (docs/time-resolved.md,
                    // "When a window has settled").
                    stop_per_frame: true,
                    occupancy: Some(OccupancyConfig::default()),
                    ..base.train
                },
                // Each window from the uniform start, not from the previous window's field:
                // trained until they settle, warm-started windows ended level or worse in the
                // mean of two seeds (3 % at the 12-camera jet's new frames, 2–7 % on the
                // plume, where they also took 24–36 % more iterations; docs/time-resolved.md,
                // "Warm starts of the hash grid"). Independent windows also run in parallel.
                windows: WindowConfig {
                    frames: 16,
                    overlap: 4,
                    warm_start: false,
                    warm_max_iterations: None,
                    time_origin: TimeOrigin::Window,
                },
            })
        }
        _ => None,
    }
}

/// The distinct acquisition times of the training views, increasing.
pub fn frame_times(problem: &Problem) -> Vec<f64> {
    let mut times: Vec<f64> = problem.views.iter().map(|v| v.time).collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    times
}

/// The frame spacing Δt: the smallest gap between consecutive frame times (1 for one frame).
pub fn infer_time_step(times: &[f64]) -> f64 {
    let gap = times.windows(2).map(|w| w[1] - w[0]).filter(|&d| d > 0.0).fold(f64::INFINITY, f64::min);
    if gap.is_finite() {
        gap
    } else {
        1.0
    }
}

/// The field configuration for windows of `frames` frames: a 4D hash grid gets its time axis
/// (`time_span = time_resolution = max(frames − 1, 1)`); other fields are unchanged.
pub fn field_for_window(field: &FieldConfig, frames: usize) -> FieldConfig {
    match field {
        FieldConfig::HashGrid(c) => {
            let span = frames.saturating_sub(1).max(1);
            FieldConfig::HashGrid(HashGridConfig { time_span: span as f32, time_resolution: span, ..c.clone() })
        }
        other => other.clone(),
    }
}

/// Parameters and training memory of the `tr-fast` field over `frames` frames in one window:
/// `(parameters, weight bytes, training bytes)`, training = weights + two Adam moments + one
/// gradient buffer per thread (`threads`).
pub fn fast_field_memory(frames: usize, threads: usize) -> Result<(usize, usize, usize), NeuralError> {
    let cfg = temporal_preset("tr-fast").ok_or_else(|| NeuralError::invalid("preset", "tr-fast missing"))?;
    let FieldConfig::HashGrid(grid) = field_for_window(&cfg.field, frames) else {
        return Err(NeuralError::invalid("preset", "tr-fast is not a hash grid"));
    };
    let params = HashGridField::new(&grid, 4, 0)?.num_params();
    Ok((params, 4 * params, 4 * params * (3 + threads)))
}

/// The training problem of the frames `range` of a recording with frame times `times`: the
/// views at those times (training and held out), their times shifted by `origin` (`t − t₀`,
/// [`TimeAxis::Time`]) or placed on the window's frame axis with a time step of 1
/// ([`TimeAxis::Frames`]: `origin` is then not used).
pub fn window_problem(problem: &Problem, times: &[f64], range: Range<usize>, origin: f64, axis: TimeAxis) -> Problem {
    let first = range.start as f64;
    let inside = in_window(times, range);
    let at = |t: f64| match axis {
        TimeAxis::Time => t - origin,
        TimeAxis::Frames => frame_position(times, t) - first,
    };
    let keep = |v: &crate::train::View| inside(v).then(|| crate::train::View { time: at(v.time), ..v.clone() });
    Problem {
        aabb: problem.aabb,
        intensity_scale: problem.intensity_scale,
        views: problem.views.iter().filter_map(keep).collect(),
        holdout: problem.holdout.iter().filter_map(keep).collect(),
        time_step: match axis {
            TimeAxis::Time => problem.time_step,
            TimeAxis::Frames => 1.0,
        },
    }
}

/// The masks of the views [`window_problem`] keeps, in its order (no masks stay no masks).
pub fn window_masks(problem: &Problem, masks: &ViewMasks, times: &[f64], range: Range<usize>) -> ViewMasks {
    let inside = in_window(times, range);
    let pick = |views: &[crate::train::View], list: &[Option<Vec<bool>>]| -> Vec<Option<Vec<bool>>> {
        if list.is_empty() {
            return Vec::new();
        }
        views.iter().zip(list).filter(|(v, _)| inside(v)).map(|(_, m)| m.clone()).collect()
    };
    ViewMasks { train: pick(&problem.views, &masks.train), holdout: pick(&problem.holdout, &masks.holdout) }
}

/// Whether a view's time lies in the frames `range` of `times` (up to rounding).
fn in_window(times: &[f64], range: Range<usize>) -> impl Fn(&crate::train::View) -> bool {
    let inside = time_in_window(times, range);
    move |v| inside(v.time)
}

/// Whether a time lies in the frames `range` of `times` (up to rounding).
fn time_in_window(times: &[f64], range: Range<usize>) -> impl Fn(f64) -> bool {
    let (t_first, t_last) = (times[range.start], times[range.end - 1]);
    let tol = 1e-9 * (1.0 + t_first.abs().max(t_last.abs()));
    move |t| t >= t_first - tol && t <= t_last + tol
}

/// The origin `t₀` of window `range` ([`TimeOrigin`]).
pub fn window_origin(origin: TimeOrigin, times: &[f64], range: &Range<usize>) -> f64 {
    match origin {
        TimeOrigin::Recording => times[0],
        TimeOrigin::Window => times[range.start],
    }
}

/// How a window's field reads time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TimeAxis {
    /// `t' = (t − t₀) / Δt`, the dissertation's normalisation: a network reads any `t'`.
    #[default]
    Time,
    /// `t'` is the position on the window's frame axis: 0 at its first frame, `k` at its
    /// `k`-th, linear in time between two frames ([`frame_position`]). For a grid with one
    /// time vertex per frame (the 4D hash grid, [`field_for_window`]): with `t / Δt` a
    /// recording whose frames are not evenly spaced (steps 50, 52, 60) would put its frames
    /// off the vertices, and clamp the times past `W − 1` gaps onto the last one.
    Frames,
}

/// Where training is: which window of how many.
#[derive(Clone, Debug)]
pub struct WindowInfo {
    pub index: usize,
    pub count: usize,
    /// Frame indices of the window.
    pub frames: Range<usize>,
    /// The fingerprint of the views the window trains on ([`Prepared::fingerprint`]).
    pub views: String,
}

/// One trained window.
#[derive(Clone, Debug)]
pub struct TrainedWindow<F> {
    pub frames: Range<usize>,
    /// Absolute time `t₀` of `t' = (t − t₀) / Δt` ([`TimeOrigin`]; the time of the window's
    /// first frame on [`TimeAxis::Frames`]).
    pub time_origin: f64,
    /// How the window's field reads time (its `meta.time_step` is 1 on the frame axis).
    pub time_axis: TimeAxis,
    pub learner: Learner<F>,
    pub meta: FieldMeta,
    pub report: TrainReport,
    /// Fraction of the box occupied (1 without empty-space skipping).
    pub occupied_fraction: f64,
    /// The fingerprint of the views it was trained on ([`Prepared::fingerprint`]).
    pub views: String,
}

/// The result of [`train_windows`].
#[derive(Clone, Debug)]
pub struct TemporalRun<F> {
    pub frame_times: Vec<f64>,
    pub plan: Vec<Range<usize>>,
    pub windows: Vec<TrainedWindow<F>>,
    /// True when the callback stopped training (later windows were not trained).
    pub interrupted: bool,
}

/// What a stopped [`train_windows`] run left behind, to continue it: the learners of the
/// windows it finished and the state of the window it was training.
#[derive(Clone, Debug)]
pub struct ResumeState<F> {
    /// The first windows of the plan, in order, as they finished: learner (weights, optimiser
    /// state, histories) and report. They are not trained again.
    pub finished: Vec<(Learner<F>, TrainReport)>,
    /// The next window's learner at its last checkpoint; it continues from there (None: the
    /// window starts as usual, warm or fresh).
    pub running: Option<Learner<F>>,
}

impl<F> Default for ResumeState<F> {
    fn default() -> Self {
        ResumeState { finished: Vec::new(), running: None }
    }
}

/// What [`train_windows`] reports to its callback.
#[derive(Debug)]
pub enum WindowEvent<'a, F> {
    /// After every training iteration of the window.
    Iteration(&'a WindowInfo, &'a TrainState<'a, F>),
    /// The window has finished training (converged, iteration cap or time budget; not when the
    /// callback stopped it): the moment to save it as finished. Not sent for windows taken
    /// from a [`ResumeState`].
    Finished(&'a WindowInfo, &'a TrainedWindow<F>),
    /// A fresh window's fit to its instants' reconstructions ([`FrameStart`]): `step` of
    /// `steps` done, sent once before the first step (`step` 0) and after every step. Breaking
    /// stops the fit; the window then trains a single iteration (its report needs a loss) and
    /// says [`StopReason::Interrupted`], so that its field is known not to have trained.
    StartFit(&'a WindowInfo, usize, usize),
}

/// Trains every window of `problem` (absolute view times; `problem.time_step` is Δt) in turn,
/// starting the first window (and, without warm start, every window) from `init`, which must
/// be built for [`plan_windows`]' window length (see [`field_for_window`]). Window times are
/// relative to `windows.time_origin` ([`window_origin`]).
///
/// `on_event` sees every iteration, every finished window and every step of a fresh window's
/// fit to `start`; breaking stops after that iteration (the window is returned as it is,
/// `interrupted` set), before the next window, or the fit, after which the window trains one
/// iteration and is returned stopped ([`WindowEvent::StartFit`]).
/// Seeds: window `k` trains with `seed + k`.
///
/// `resume` continues a stopped run with the same settings: its finished windows are taken as
/// they are (their data prepared again for the metadata, not trained), the running one
/// continues from its learner, later ones train as usual. Since every random choice is keyed
/// by (seed, iteration), the result equals that of an uninterrupted run (time budgets aside:
/// they count from the resume).
pub fn train_windows<F: TrainableField + Clone>(
    problem: &Problem,
    masks: &ViewMasks,
    train_cfg: &TrainConfig,
    windows: &WindowConfig,
    init: F,
    seed: u64,
    resume: ResumeState<F>,
    start: Option<&FrameStart>,
    mut on_event: impl FnMut(WindowEvent<'_, F>) -> ControlFlow<()>,
) -> Result<TemporalRun<F>, NeuralError> {
    windows.validate()?;
    let times = frame_times(problem);
    if times.is_empty() {
        return Err(NeuralError::invalid("scene", "no training images"));
    }
    let plan = plan_windows(times.len(), windows.frames, windows.overlap);
    if resume.finished.len() > plan.len() {
        return Err(NeuralError::invalid(
            "resume",
            format!("{} finished windows but the plan has {}", resume.finished.len(), plan.len()),
        ));
    }
    let n_params = init.num_params();
    let mut saved = resume.finished.iter().map(|(l, _)| l).chain(resume.running.as_ref());
    if saved.any(|l| l.field.num_params() != n_params || l.adam.m.len() != n_params) {
        return Err(NeuralError::invalid("resume", "a saved window does not have the field's parameter count"));
    }
    let mut finished = resume.finished.into_iter();
    let mut running = resume.running;
    let mut out: Vec<TrainedWindow<F>> = Vec::with_capacity(plan.len());
    let mut interrupted = false;
    for k in 0..plan.len() {
        if let Some((learner, report)) = finished.next() {
            // A finished window is taken as it is: no events, not trained.
            let start = WindowStart::Finished(learner, report);
            let no_events = |_: WindowEvent<'_, F>| ControlFlow::Continue(());
            out.push(train_window(problem, masks, &times, &plan, k, train_cfg, windows, seed, start, None, no_events)?);
            continue;
        }
        let begin = match (running.take(), out.last().filter(|_| windows.warm_start && k > 0)) {
            (Some(saved), _) => WindowStart::Resume(saved),
            (None, Some(prev)) => WindowStart::Warm(prev.learner.field.clone()),
            (None, None) => WindowStart::Fresh(init.clone()),
        };
        let w = train_window(problem, masks, &times, &plan, k, train_cfg, windows, seed, begin, start, &mut on_event)?;
        out.push(w);
        let views = out.last().map(|w| w.views.clone()).unwrap_or_default();
        let info = WindowInfo { index: k, count: plan.len(), frames: plan[k].clone(), views };
        let stopped = out.last().is_some_and(|w| w.report.stop_reason == StopReason::Interrupted);
        if stopped || out.last().is_some_and(|w| on_event(WindowEvent::Finished(&info, w)).is_break()) {
            interrupted = stopped || k + 1 < plan.len();
            break;
        }
    }
    Ok(TemporalRun { frame_times: times, plan, windows: out, interrupted })
}

pub use crate::start::FrameTarget;

/// Reconstructions of single instants that a window's fresh field is fitted to before it
/// trains ([`crate::start`]), one instant at a time: `target(frame_time, points, out)` writes
/// the value (world units) at world points at one of the recording's frame times. The window
/// then trains at `learning_rate_scale` times its schedule's rates, and the time those
/// reconstructions took (`seconds`: per frame time) and the fit's come out of its time budget.
pub struct FrameStart<'a> {
    pub target: &'a FrameTarget<'a>,
    pub fit: crate::start::StartFit,
    pub learning_rate_scale: f32,
    pub seconds: Vec<(f64, f64)>,
}

/// Where the learner of one window starts ([`train_window`]).
#[derive(Clone, Debug)]
pub enum WindowStart<F> {
    /// A field never trained: the run's initial field (first window, or no warm start).
    Fresh(F),
    /// The previous window's trained field, with a fresh optimiser (warm start).
    Warm(F),
    /// The window's own learner at its last checkpoint; training continues from there.
    Resume(Learner<F>),
    /// The window finished earlier: taken as it is, not trained (its data are prepared again
    /// for the metadata).
    Finished(Learner<F>, TrainReport),
}

/// Trains window `k` of `plan` (from [`plan_windows`] over the frame times `times` of
/// `problem`) alone, as [`train_windows`] trains it in turn: the same window problem, seed
/// `seed + k`, and, for warm-started windows, `windows.warm_max_iterations`. Because a window
/// depends on the others only through its start ([`WindowStart::Warm`] takes the previous
/// window's final field), windows can be trained in separate processes and give the windows of
/// a serial run. `on_event` sees every iteration ([`WindowEvent::Iteration`]; breaking stops
/// after it, and the report says [`StopReason::Interrupted`]) and every step of a fresh
/// window's fit to `frame_start` ([`WindowEvent::StartFit`]); it is sent no
/// [`WindowEvent::Finished`].
#[allow(clippy::too_many_arguments)]
pub fn train_window<F: TrainableField + Clone>(
    problem: &Problem,
    masks: &ViewMasks,
    times: &[f64],
    plan: &[Range<usize>],
    k: usize,
    train_cfg: &TrainConfig,
    windows: &WindowConfig,
    seed: u64,
    start: WindowStart<F>,
    frame_start: Option<&FrameStart>,
    mut on_event: impl FnMut(WindowEvent<'_, F>) -> ControlFlow<()>,
) -> Result<TrainedWindow<F>, NeuralError> {
    let range = window_range(plan, k)?;
    let axis = match &start {
        WindowStart::Finished(l, _) | WindowStart::Resume(l) => l.field.time_on_frame_axis(),
        WindowStart::Warm(f) | WindowStart::Fresh(f) => f.time_on_frame_axis(),
    };
    let (origin, time_axis, prep) = prepare_window(problem, masks, times, range, train_cfg, windows, axis)?;
    let views = prep.fingerprint();
    let info = WindowInfo { index: k, count: plan.len(), frames: range.clone(), views: views.clone() };
    let trained = |learner: Learner<F>, report: TrainReport| TrainedWindow {
        frames: range.clone(),
        time_origin: origin,
        time_axis,
        learner,
        meta: prep.meta.clone(),
        report,
        occupied_fraction: prep.occupied_fraction(),
        views: views.clone(),
    };
    let warm = windows.warm_start && k > 0;
    let mut cfg = train_cfg.clone();
    if cfg.stop_per_frame && cfg.batching == Batching::OneTimeStep {
        cfg.stop = cfg.stop.in_cycles(range.len());
    }
    if warm {
        if let Some(m) = windows.warm_max_iterations {
            cfg.max_iterations = m;
        }
    }
    // A window that does not continue the previous one starts from the instants' own
    // reconstructions, and trains (or resumes) at the reduced rates.
    let frame_start = frame_start.filter(|_| !warm);
    if let Some(fs) = frame_start {
        cfg.schedule.initial *= fs.learning_rate_scale;
        cfg.schedule.at_decay_iters *= fs.learning_rate_scale;
    }
    // Whether the fit to the instants' reconstructions was stopped.
    let mut fit_stopped = false;
    let mut learner = match start {
        WindowStart::Finished(learner, report) => return Ok(trained(learner, report)),
        WindowStart::Resume(saved) => saved,
        WindowStart::Warm(previous) => Learner::new(previous),
        WindowStart::Fresh(init) => {
            let mut learner = Learner::fresh(init, &prep, &cfg);
            let inside = time_in_window(times, range.clone());
            // The seconds of the window's instants' voxel runs.
            let voxel: f64 =
                frame_start.map_or(0.0, |fs| fs.seconds.iter().filter(|(t, _)| inside(*t)).map(|(_, s)| s).sum());
            let steps = frame_start.map_or(0, |fs| fs.fit.iterations);
            fit_stopped = frame_start.is_some() && on_event(WindowEvent::StartFit(&info, 0, steps)).is_break();
            if fit_stopped {
                learner.train_time_s += voxel;
            }
            if let Some(fs) = frame_start.filter(|_| !fit_stopped) {
                let t0 = std::time::Instant::now();
                let first = range.start as f64;
                let at = |t: f64| match time_axis {
                    TimeAxis::Time => t - origin,
                    TimeAxis::Frames => frame_position(times, t) - first,
                };
                let frames: Vec<(f32, f64)> = times[range.clone()].iter().map(|&t| (at(t) as f32, t)).collect();
                // The fit counts against the window's budget, as its instants' voxel runs do.
                let limit = cfg.time_budget_s.map(|b| (b - voxel).max(0.0));
                let report = crate::start::fit_to_frames(
                    &mut learner.field,
                    &prep,
                    &frames,
                    fs.target,
                    &fs.fit,
                    seed.wrapping_add(k as u64),
                    limit,
                    &mut |step| on_event(WindowEvent::StartFit(&info, step, steps)),
                )?;
                fit_stopped = report.stopped;
                log::info!(
                    "window {k} started from its instants' reconstructions: relative RMS difference {:.4} ({:.1} s)",
                    report.relative_difference(),
                    report.seconds
                );
                let spent = voxel + t0.elapsed().as_secs_f64();
                learner.train_time_s += spent;
                if let Some(b) = cfg.time_budget_s {
                    cfg.time_budget_s = Some((b - spent).max(1e-3));
                }
            }
            learner
        }
    };
    // A window saved at the iteration at which it converged stops there, as it did then.
    let report = if learner.iteration > 0 && converged(&learner.losses, &cfg.stop) {
        finished_report(&learner, &cfg)
    } else if fit_stopped {
        // One iteration, for the loss a report holds; the field has not trained.
        cfg.max_iterations = 1;
        let mut report = train(&prep, &mut learner, &cfg, seed.wrapping_add(k as u64), |_| ControlFlow::Continue(()))?;
        report.stop_reason = StopReason::Interrupted;
        report
    } else {
        train(&prep, &mut learner, &cfg, seed.wrapping_add(k as u64), |s| on_event(WindowEvent::Iteration(&info, s)))?
    };
    Ok(trained(learner, report))
}

/// Window `range` of `problem` prepared for training as [`train_window`] prepares it, for a
/// field that reads time on the frame axis (`frame_axis`) or not: its time origin, time axis
/// and training data.
#[allow(clippy::too_many_arguments)]
fn prepare_window(
    problem: &Problem,
    masks: &ViewMasks,
    times: &[f64],
    range: &Range<usize>,
    train_cfg: &TrainConfig,
    windows: &WindowConfig,
    frame_axis: bool,
) -> Result<(f64, TimeAxis, Prepared), NeuralError> {
    let origin = window_origin(windows.time_origin, times, range);
    let time_axis = if frame_axis { TimeAxis::Frames } else { TimeAxis::Time };
    let sub = window_problem(problem, times, range.clone(), origin, time_axis);
    let prep = Prepared::with_masks(&sub, train_cfg, &window_masks(problem, masks, times, range.clone()))?;
    Ok((origin, time_axis, prep))
}

/// Window `k` of `plan`, refused when the plan has no such window.
fn window_range(plan: &[Range<usize>], k: usize) -> Result<&Range<usize>, NeuralError> {
    plan.get(k).ok_or_else(|| {
        NeuralError::invalid("window", format!("window {k} is not in the plan of {} windows", plan.len()))
    })
}

/// The fingerprint ([`Prepared::fingerprint`]) of the views that window `k` of `plan` trains
/// on, as [`train_window`] prepares them for a field that reads time on the frame axis
/// (`frame_axis`, [`TrainableField::time_on_frame_axis`]) or not: a saved window is continued
/// only on the views it was trained on.
#[allow(clippy::too_many_arguments)]
pub fn window_fingerprint(
    problem: &Problem,
    masks: &ViewMasks,
    times: &[f64],
    plan: &[Range<usize>],
    k: usize,
    train_cfg: &TrainConfig,
    windows: &WindowConfig,
    frame_axis: bool,
) -> Result<String, NeuralError> {
    let range = window_range(plan, k)?;
    let (_, _, prep) = prepare_window(problem, masks, times, range, train_cfg, windows, frame_axis)?;
    Ok(prep.fingerprint())
}

/// The report of a window that had already converged when it was saved.
fn finished_report<F: TrainableField>(learner: &Learner<F>, cfg: &TrainConfig) -> TrainReport {
    let smoothing = cfg.stop.smoothing.max(1);
    TrainReport {
        stop_reason: StopReason::Converged,
        iterations: learner.iteration,
        final_loss: learner.losses.last().copied().unwrap_or(f32::NAN),
        smoothed_loss: running_mean(&learner.losses, smoothing),
        train_time_s: learner.train_time_s,
        seconds_per_iteration: 0.0,
        samples_per_second: 0.0,
        bf16_products: learner.field.bf16_products(),
    }
}

/// Trained windows stitched into one field of space and time, in world units (module doc of
/// [`crate::window`] for the blending).
pub struct StitchedField {
    pub frame_times: Vec<f64>,
    pub plan: Vec<Range<usize>>,
    pub origins: Vec<f64>,
    /// How each window reads time.
    pub axes: Vec<TimeAxis>,
    /// Each window's field, queried with times relative to its origin (on [`TimeAxis::Time`])
    /// or with its frame position (on [`TimeAxis::Frames`]).
    pub fields: Vec<Box<dyn ScalarField + Send + Sync>>,
    /// The windows' hulls ([`StitchedHull`]), gathered on first use.
    hull: OnceLock<StitchedHull>,
}

/// What the windows' hulls give the stitched field: the union of them (`None` unless every
/// window has one, on the same grid), and whether they are all the same hull.
#[derive(Debug, Default)]
struct StitchedHull {
    union: Option<(Aabb, [usize; 3], Vec<bool>)>,
    shared: bool,
}

impl std::fmt::Debug for StitchedField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StitchedField").field("frame_times", &self.frame_times).field("plan", &self.plan).finish()
    }
}

impl StitchedField {
    /// The windows `fields`, trained over the frames `plan` of the recording's `frame_times`,
    /// with their time origins and axes (one per window), stitched into one field.
    pub fn new(
        frame_times: Vec<f64>,
        plan: Vec<Range<usize>>,
        origins: Vec<f64>,
        axes: Vec<TimeAxis>,
        fields: Vec<Box<dyn ScalarField + Send + Sync>>,
    ) -> Self {
        StitchedField { frame_times, plan, origins, axes, fields, hull: OnceLock::new() }
    }

    fn hull(&self) -> &StitchedHull {
        self.hull.get_or_init(|| {
            let hulls: Option<Vec<Support<'_>>> = self.fields.iter().map(|f| f.support()).collect();
            let Some((first, rest)) = hulls.as_deref().and_then(|h| h.split_first()) else {
                return StitchedHull::default();
            };
            if rest.iter().any(|h| (h.aabb, h.dims) != (first.aabb, first.dims)) {
                return StitchedHull::default();
            }
            let mut cells = first.cells.to_vec();
            for h in rest {
                for (c, &o) in cells.iter_mut().zip(h.cells) {
                    *c |= o;
                }
            }
            let shared = rest.iter().all(|h| h.cells == first.cells);
            StitchedHull { union: Some((first.aabb, first.dims, cells)), shared }
        })
    }

    /// Stitches the windows of `run` (all trained windows; an interrupted run covers fewer
    /// frames and is stitched over those).
    pub fn from_run<F: TrainableField + Clone + 'static>(run: &TemporalRun<F>) -> Result<Self, NeuralError> {
        let n = run.windows.len();
        let mut fields: Vec<Box<dyn ScalarField + Send + Sync>> = Vec::with_capacity(n);
        for w in &run.windows {
            fields.push(Box::new(TrainedField::new(w.learner.field.clone(), w.meta.clone())?));
        }
        let covered = run.windows.last().map_or(0, |w| w.frames.end);
        Ok(StitchedField::new(
            run.frame_times[..covered.max(1).min(run.frame_times.len())].to_vec(),
            run.plan[..n].to_vec(),
            run.windows.iter().map(|w| w.time_origin).collect(),
            run.windows.iter().map(|w| w.time_axis).collect(),
            fields,
        ))
    }
}

impl ScalarField for StitchedField {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.eval_windows(points, time, out, true);
    }

    /// The windows' own values without their masks when they share one hull; with different
    /// hulls, the masked values. (A bake reads its grid inside the union of the hulls: at a
    /// vertex on one window's face the cells on one side need that window's values and those
    /// on the other its zeros, so the masks stay.)
    fn eval_unmasked(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        let shared = self.hull().shared;
        self.eval_windows(points, time, out, !shared);
    }

    /// The union of the windows' hulls (when every window has one, on the same grid): where
    /// the field may be non-zero at some time, so renders sample only there. Each window still
    /// masks its own values with its own hull.
    fn support(&self) -> Option<Support<'_>> {
        self.hull().union.as_ref().map(|(aabb, dims, cells)| Support { aabb: *aabb, dims: *dims, cells })
    }

    /// The finest detail of any window (windows share their configuration, so their grids
    /// agree): what a bake of the stitched field must resolve.
    fn detail_dims(&self) -> Option<[usize; 3]> {
        self.fields.iter().try_fold([0usize; 3], |acc, f| {
            let d = f.detail_dims()?;
            Some([0, 1, 2].map(|a| acc[a].max(d[a])))
        })
    }
}

impl StitchedField {
    /// [`ScalarField::eval`], each window's mask applied when `masked`.
    fn eval_windows(&self, points: &[Vec3], time: f64, out: &mut [f32], masked: bool) {
        assert_eq!(points.len(), out.len(), "StitchedField::eval: points and out differ in length");
        out.fill(0.0);
        let f = frame_position(&self.frame_times, time);
        let mut tmp = vec![0.0f32; out.len()];
        for (i, w, pos) in blend(&self.plan, f) {
            if w <= 0.0 {
                continue;
            }
            let t = match self.axes[i] {
                TimeAxis::Time => time_at(&self.frame_times, pos) - self.origins[i],
                TimeAxis::Frames => pos - self.plan[i].start as f64,
            };
            if masked {
                self.fields[i].eval(points, t, &mut tmp);
            } else {
                self.fields[i].eval_unmasked(points, t, &mut tmp);
            }
            for (o, &v) in out.iter_mut().zip(&tmp) {
                *o += w as f32 * v;
            }
        }
    }
}

/// One window of `temporal.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindowRecord {
    /// First and one-past-last frame index.
    pub frames: [usize; 2],
    pub time_origin: f64,
    /// How the window's field reads time (runs written before it existed read `time`).
    #[serde(default)]
    pub time_axis: TimeAxis,
    pub meta: FieldMeta,
    /// Weights file, relative to the run directory.
    pub weights: String,
}

/// `temporal.json`: how to rebuild the stitched field of a time-resolved run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemporalRecord {
    /// The field of every window (after [`field_for_window`]).
    pub field: FieldConfig,
    /// 3 (per-frame static) or 4.
    pub input_dim: usize,
    pub frame_times: Vec<f64>,
    pub windows: Vec<WindowRecord>,
}

/// What is wrong with the `frame_times` of a run's `temporal.json`, if anything. The stitching
/// places a time on the frame axis between the two frames around it: a time listed twice, or
/// out of order, would put one instant at two frame positions (or none).
pub fn frame_times_problem(times: &[f64]) -> Option<String> {
    if times.is_empty() {
        return Some("frame_times: no frames".into());
    }
    let i = (0..times.len()).find(|&i| !times[i].is_finite() || (i > 0 && times[i] <= times[i - 1]))?;
    let listed = times.iter().map(|&t| num(t).to_string()).collect::<Vec<_>>().join(", ");
    Some(if !times[i].is_finite() {
        format!("frame_times: frame {i} has the time {}, not a finite number ({listed})", num(times[i]))
    } else {
        format!(
            "frame_times: frame {i} at t = {} does not come after frame {} at t = {}: a run lists each instant once, \
             in increasing order ({listed}); the file was edited or is damaged: restore it, or rerun the \
             reconstruction",
            num(times[i]),
            i - 1,
            num(times[i - 1])
        )
    })
}

/// The tag of a window's weights file ([`crate::weights::weights_bytes_tagged`]) that says
/// which window of its run it holds: [`WindowTag`] as JSON.
pub const WINDOW_TAG: &str = "window";

/// What identifies the weights of one window of a run: its index in the plan, its frames, their
/// times and its time origin. A run writes it into each window's weights file, and reading the
/// run refuses a file whose tag is not the window `temporal.json` lists there (one window's
/// weights copied over another's were read as that window's). Files written before the tag
/// existed have none and are read as before.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindowTag {
    pub index: usize,
    /// First and one-past-last frame index.
    pub frames: [usize; 2],
    /// The times of its frames.
    pub times: Vec<f64>,
    pub time_origin: f64,
}

impl WindowTag {
    /// Window `index` of the run whose frames are at `frame_times`, as `temporal.json` records it.
    pub fn of(index: usize, window: &WindowRecord, frame_times: &[f64]) -> Self {
        let [a, b] = window.frames;
        WindowTag {
            index,
            frames: window.frames,
            times: frame_times.get(a..b).map(<[f64]>::to_vec).unwrap_or_default(),
            time_origin: window.time_origin,
        }
    }

    /// The tag as the metadata of a weights file.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_else(|_| unreachable!("numbers and lists serialise"))
    }

    fn describe(&self) -> String {
        let times = self.times.iter().map(|&t| num(t).to_string()).collect::<Vec<_>>().join(", ");
        format!(
            "window {} (frames {}..{}, t = {times}, time origin {})",
            self.index,
            self.frames[0],
            self.frames[1],
            num(self.time_origin)
        )
    }
}

/// Refuses the weights file `path` of window `expected` when its tag ([`WINDOW_TAG`]) names
/// another window (or cannot be read as one); a file without the tag is accepted.
fn check_window_tag(path: &Path, expected: &WindowTag) -> Result<(), NeuralError> {
    let Some(text) = crate::weights::checkpoint_tag(path, WINDOW_TAG)? else { return Ok(()) };
    let held: WindowTag = serde_json::from_str(&text).map_err(|e| {
        NeuralError::checkpoint(path, format!("its tag `{WINDOW_TAG}` is not a window's record ({e}): {text}"))
    })?;
    // Times as written and read back as text (`same_time`).
    let same = |a: f64, b: f64| fluidnerf_core::scene::same_time(a, b);
    let same_times =
        held.times.len() == expected.times.len() && held.times.iter().zip(&expected.times).all(|(&a, &b)| same(a, b));
    if held.index != expected.index
        || held.frames != expected.frames
        || !same_times
        || !same(held.time_origin, expected.time_origin)
    {
        return Err(NeuralError::checkpoint(
            path,
            format!(
                "holds the weights of {}, but temporal.json lists this file as those of {}: the file is another \
                 window's or another run's (copied over?); restore it, or rerun the reconstruction",
                held.describe(),
                expected.describe()
            ),
        ));
    }
    Ok(())
}

/// Reads `run_dir/temporal.json` and the window weights it names; returns the stitched field.
pub fn load_temporal(run_dir: &Path) -> Result<StitchedField, NeuralError> {
    let path = run_dir.join("temporal.json");
    let text = std::fs::read_to_string(&path).map_err(|error| NeuralError::Io { path: path.clone(), error })?;
    let rec: TemporalRecord = serde_json::from_str(&text)
        .map_err(|e| NeuralError::checkpoint(&path, format!("malformed time-resolved run description: {e}")))?;
    if rec.frame_times.is_empty() || rec.windows.is_empty() {
        return Err(NeuralError::checkpoint(&path, "no frames or no windows"));
    }
    if let Some(why) = frame_times_problem(&rec.frame_times) {
        return Err(NeuralError::checkpoint(&path, why));
    }
    let mut fields: Vec<Box<dyn ScalarField + Send + Sync>> = Vec::new();
    let mut plan: Vec<Range<usize>> = Vec::new();
    for (k, w) in rec.windows.iter().enumerate() {
        if w.frames[0] >= w.frames[1] || w.frames[1] > rec.frame_times.len() {
            return Err(NeuralError::checkpoint(&path, format!("window frames {:?} out of range", w.frames)));
        }
        // The stitching reads the windows as a run plans them (crate::window): from the first
        // frame on, in order, each starting after the previous one starts and no later than
        // it ends. Windows reordered, or one left out, would blend other frames' fields.
        let follows = match plan.last() {
            None => w.frames[0] == 0,
            Some(p) => p.start < w.frames[0] && w.frames[0] <= p.end && p.end < w.frames[1],
        };
        if !follows {
            let listed: Vec<[usize; 2]> = rec.windows.iter().map(|w| w.frames).collect();
            return Err(NeuralError::checkpoint(
                &path,
                format!(
                    "window frames {:?} do not follow the window before them (windows {listed:?}): windows start at \
                     frame 0 and each starts after the one before starts and no later than it ends",
                    w.frames
                ),
            ));
        }
        // A run writes its windows' weights inside its folder; a description naming a file
        // elsewhere (another run's) would have that field read as this run's.
        if Path::new(&w.weights).components().any(|c| !matches!(c, std::path::Component::Normal(_))) {
            return Err(NeuralError::checkpoint(
                &path,
                format!("window frames {:?}: its weights {} are not a file inside the run folder", w.frames, w.weights),
            ));
        }
        plan.push(w.frames[0]..w.frames[1]);
        if let Some(why) = w.meta.problem() {
            return Err(NeuralError::checkpoint(&path, format!("window {:?}: {why}", w.frames)));
        }
        let weights = run_dir.join(&w.weights);
        let mut field = build_field_for_weights(&rec.field, &w.meta.aabb, rec.input_dim, &weights)?;
        check_window_tag(&weights, &WindowTag::of(k, w, &rec.frame_times))?;
        crate::with_field!(&mut field, f => crate::weights::load_weights(&weights, f))?;
        let boxed: Box<dyn ScalarField + Send + Sync> = match field {
            AnyField::Mlp(f) => Box::new(TrainedField::new(f, w.meta.clone())?),
            AnyField::HashGrid(f) => Box::new(TrainedField::new(f, w.meta.clone())?),
            AnyField::Dense(f) => Box::new(TrainedField::new(f, w.meta.clone())?),
        };
        fields.push(boxed);
    }
    Ok(StitchedField::new(
        rec.frame_times,
        plan,
        rec.windows.iter().map(|w| w.time_origin).collect(),
        rec.windows.iter().map(|w| w.time_axis).collect(),
        fields,
    ))
}
