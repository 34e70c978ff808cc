//! Time-resolved methods (`tr-fluidnerf`, `tr-fast`, `static-per-frame`): a field of space and
//! time trained on a scene whose frames carry times (dissertation §5.2), in windows.
//!
//! Writes `frames/volume_NNN.npy|.vti` at every training time and every held-out time, in
//! increasing time (a stopped run: at those up to the last frame its windows trained; the
//! later ones are listed in the report's `not_reached`), `volumes.pvd` (the ParaView
//! collection of the series), the weights and
//! checkpoints of every window under `windows/`, and `temporal.json`, from which
//! `fluidnerf_neural::temporal::load_temporal` rebuilds the stitched field E(x, t).
//! `windows/progress.json` records the window plan and the finished windows when each
//! finishes (its checkpoint first), so a resumed run loads finished windows, continues the
//! running one from its last checkpoint, and equals an uninterrupted run (same seed and
//! thread count).

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_core::num;
use fluidnerf_core::scene::same_time;
use fluidnerf_core::{ScalarField, Scene, Volume};
use fluidnerf_neural::temporal::{
    field_for_window, frame_times, infer_time_step, train_windows, window_fingerprint, FrameStart, ResumeState,
    StitchedField, TemporalRecord, TemporalRun, TimeOrigin, WindowEvent, WindowRecord, WindowTag, WINDOW_TAG,
};
use fluidnerf_neural::train::ViewMasks;
use fluidnerf_neural::train::{Learner, TrainConfig, TrainReport};
use fluidnerf_neural::trained::{build_field, FieldConfig};
use fluidnerf_neural::window::plan_windows;
use fluidnerf_neural::TrainableField;
use serde::{Deserialize, Serialize};

use crate::neural::{check_views, estimate_memory, run_voxel_start, write_checkpoint_to};
use crate::{
    check_memory, finish, mean, peak_rss, write_volume, Family, History, LossKind, Method, MethodConfig, PipelineError,
    Preprocessing, RunConfig, RunDir, RunEvent, RunReport, RunStatus, Session, StopReason, TemporalSpec, VolumeRecord,
    WindowDetails, WindowPos, REPORT_FORMAT,
};

/// `windows/progress.json`: what a run is and how far it got, for resuming.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Progress {
    /// The field of every window (after `field_for_window`).
    field: FieldConfig,
    input_dim: usize,
    frame_times: Vec<f64>,
    /// First and one-past-last frame of every window.
    plan: Vec<[usize; 2]>,
    time_origin: TimeOrigin,
    warm_start: bool,
    seed: u64,
    train: TrainConfig,
    /// The first windows of the plan, finished, in order.
    finished: Vec<FinishedWindow>,
    /// The scene's box, in whose coordinates the fields were trained (absent in runs written
    /// before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    aabb: Option<fluidnerf_core::Aabb>,
    /// The frame spacing Δt of a network's time input `t' = (t − t₀)/Δt`; absent for fields
    /// that do not read it (of space alone, or the hash grid's frame axis) and in runs written
    /// before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    time_step: Option<f64>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FinishedWindow {
    /// Checkpoint of the window as it finished, relative to the run folder.
    checkpoint: String,
    report: TrainReport,
}

impl Progress {
    /// Why a run with the settings of `self` cannot continue the run recorded in `saved`.
    fn mismatch(&self, saved: &Progress) -> Option<String> {
        let differs = |what: &str| Some(format!("the run being resumed has a different {what}"));
        if saved.frame_times != self.frame_times {
            return differs(&format!("set of training frame times ({:?})", saved.frame_times));
        }
        if saved.plan != self.plan {
            return differs(&format!("window plan ({:?}, now {:?})", saved.plan, self.plan));
        }
        if saved.field != self.field || saved.input_dim != self.input_dim {
            return differs("field (preset, configuration or method)");
        }
        if saved.time_origin != self.time_origin || saved.warm_start != self.warm_start {
            return differs("time origin or warm start");
        }
        if saved.seed != self.seed {
            return differs(&format!("seed ({}, now {})", saved.seed, self.seed));
        }
        if let (Some(a), Some(b)) = (saved.time_step, self.time_step) {
            if a != b {
                return differs(&format!(
                    "time step Δt ({}, now {}; its windows' networks read t' = (t − t₀)/Δt, so --time-step must stay \
                     the same)",
                    num(a),
                    num(b)
                ));
            }
        }
        if let (Some(a), Some(b)) = (saved.aabb, self.aabb) {
            if a != b {
                return differs(&format!(
                    "box (the scene's aabb was {:?}..{:?}, now {:?}..{:?}; the fields' coordinates are the box's)",
                    a.min.to_array(),
                    a.max.to_array(),
                    b.min.to_array(),
                    b.max.to_array()
                ));
            }
        }
        None
    }
}

/// The ParaView collection of a volume series.
fn pvd(entries: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n",
    );
    for (t, file) in entries {
        s.push_str(&format!("    <DataSet timestep=\"{t}\" group=\"\" part=\"0\" file=\"{file}\"/>\n"));
    }
    s.push_str("  </Collection>\n</VTKFile>\n");
    s
}

/// The checkpoint of window `k`, relative to the run folder.
fn checkpoint_name(k: usize) -> String {
    format!("windows/w{k:03}.checkpoint.safetensors")
}

/// The file that marks window `k` as finished when windows run one at a time (written after
/// its final checkpoint), relative to the run folder.
fn done_name(k: usize) -> String {
    format!("windows/w{k:03}.done.json")
}

/// Refuses the checkpoint `name` of window `k` (loaded into `learner`) when it was trained on
/// other images or cameras than the window's now: a window continues only on its own views.
#[allow(clippy::too_many_arguments)]
fn check_window_views<F: TrainableField>(
    dir: &RunDir,
    name: &str,
    k: usize,
    learner: &Learner<F>,
    (problem, masks): (&fluidnerf_neural::train::Problem, &ViewMasks),
    spec: &TemporalSpec,
    progress: &Progress,
) -> Result<(), PipelineError> {
    check_views(&dir.path(name), || {
        let plan: Vec<std::ops::Range<usize>> = progress.plan.iter().map(|&[a, b]| a..b).collect();
        let frame_axis = learner.field.time_on_frame_axis();
        let times = &progress.frame_times;
        Ok(window_fingerprint(problem, masks, times, &plan, k, &spec.train, &spec.windows, frame_axis)?)
    })
}

/// Window `k`'s done file, if it has finished.
fn read_done(root: &std::path::Path, k: usize) -> Result<Option<FinishedWindow>, PipelineError> {
    let path = root.join(done_name(k));
    if path.is_file() {
        let done: FinishedWindow = crate::rundir::read_json(&path)?;
        check_own_checkpoint(&path, k, &done)?;
        Ok(Some(done))
    } else {
        Ok(None)
    }
}

/// Refuses the record of finished window `k` (in `path`, a done file or `progress.json`) when it
/// records a negative time or loss, or names another checkpoint than the window's own: a run writes each window's final state to
/// [`checkpoint_name`], so another name is another window's state, or another run's, which a
/// resume would stitch in as this window (and, of the same views, could not tell apart).
fn check_own_checkpoint(path: &std::path::Path, k: usize, done: &FinishedWindow) -> Result<(), PipelineError> {
    let own = checkpoint_name(k);
    if done.checkpoint != own {
        return Err(PipelineError::file(
            path,
            format!(
                "window {k} is recorded as finished with the checkpoint {}, but a window's final state is its own \
                 {own}: the record is not this window's (copied or edited?); restore it, or start a new run (--force)",
                done.checkpoint
            ),
        ));
    }
    // Its times and losses go into the run's report (the run's training time is their sum):
    // a negative one was edited in, and would be reported as measured.
    let r = &done.report;
    let recorded = [
        ("train_time_s", r.train_time_s),
        ("seconds_per_iteration", r.seconds_per_iteration),
        ("samples_per_second", r.samples_per_second),
        ("final_loss", f64::from(r.final_loss)),
        ("smoothed_loss", f64::from(r.smoothed_loss)),
    ];
    if let Some((key, v)) = recorded.into_iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
        return Err(PipelineError::file(
            path,
            format!(
                "window {k} is recorded as finished with report.{key} {}, which no run writes (a finite number \
                 ≥ 0): the record was edited or is damaged; restore it, or start a new run (--force)",
                fluidnerf_core::num(v)
            ),
        ));
    }
    Ok(())
}

/// A time-resolved run set up: its training problem, window plan, initial field and the
/// progress record it starts from.
struct Setup {
    spec: TemporalSpec,
    method: Method,
    problem: fluidnerf_neural::train::Problem,
    /// Pixel masks of the problem's views (`mask_path`), in its order.
    masks: ViewMasks,
    field_cfg: FieldConfig,
    input_dim: usize,
    field: fluidnerf_neural::trained::AnyField,
    needed: u64,
    progress: Progress,
    /// The report's record of what was done to the images (gains as taken, not fitted).
    preprocessing: Preprocessing,
}

/// Validates a time-resolved run and prepares it (images read, plan made, field built, memory
/// checked); writes nothing.
fn setup(
    scene: &Scene,
    config: &RunConfig,
    truth: &[(Option<f64>, Volume)],
    session: &mut Session,
) -> Result<Setup, PipelineError> {
    let MethodConfig::Temporal(method, mut spec) = config.effective_method() else {
        return Err(PipelineError::invalid(
            "method",
            format!("{} is not a time-resolved method (tr-fluidnerf, tr-fast, static-per-frame)", config.method()),
        ));
    };
    refuse_timeless_scene(scene, method)?;
    let (mut problem, mut masks, measured) = crate::neural::problem(scene, &config.gains, true)?;
    for warning in &measured.warnings {
        session.warn(warning);
    }
    // A held-out time that matches no frame holds no image out: a mistyped time trained on
    // every image, unannounced.
    for &h in &spec.holdout_times {
        if !problem.views.iter().chain(&problem.holdout).any(|v| same_time(v.time, h)) {
            session.warn(&format!(
                "held-out time {} matches no frame of the scene, so no image is held out there; a volume is \
                 still written at that time",
                num(h)
            ));
        }
    }
    // Held-out times leave training with their masks.
    let held = |t: f64| spec.holdout_times.iter().any(|&h| same_time(h, t));
    let keep = |views: &[fluidnerf_neural::train::View], list: Vec<Option<Vec<bool>>>| -> Vec<Option<Vec<bool>>> {
        if list.is_empty() {
            return list;
        }
        views.iter().zip(list).filter(|(v, _)| !held(v.time)).map(|(_, m)| m).collect()
    };
    masks.train = keep(&problem.views, std::mem::take(&mut masks.train));
    masks.holdout = keep(&problem.holdout, std::mem::take(&mut masks.holdout));
    problem.views.retain(|v| !held(v.time));
    problem.holdout.retain(|v| !held(v.time));
    let times = frame_times(&problem);
    if times.is_empty() {
        return Err(PipelineError::invalid(
            "method.holdout_times",
            format!("{}: no training images left (all their times are held out)", scene.root.display()),
        ));
    }
    // A time whose every frame the scene holds out has no image to train on either: it is
    // reconstructed and scored as a held-out time, as those of `holdout_times` are.
    let mut unseen: Vec<f64> =
        problem.holdout.iter().map(|v| v.time).filter(|&t| !times.iter().any(|&f| same_time(f, t))).collect();
    unseen.sort_by(f64::total_cmp);
    unseen.dedup_by(|a, b| same_time(*a, *b));
    for &t in &unseen {
        session.warn(&format!(
            "every frame at t = {t} is held out in the scene, so no image of that time is trained on: t = {t} is \
             reconstructed from the training times and scored as a held-out time (as with --holdout-times)"
        ));
    }
    spec.holdout_times.extend(unseen);
    if let Some(message) = crate::instants_short_of_cameras(scene) {
        session.warn(&message);
    }
    if let Some(message) = crate::truth_gaps(scene) {
        session.warn(&message);
    }
    if let Some(message) = crate::timeless_truth(scene) {
        session.warn(&message);
    }
    if times.len() < 2 && method != Method::StaticPerFrame {
        session.warn("the scene has a single training time; a time-resolved field reduces to a static one");
    }
    problem.time_step = spec.time_step.unwrap_or_else(|| infer_time_step(&times));
    if spec.time_step.is_some() && input_dim_of(method) == 4 && matches!(spec.field, FieldConfig::HashGrid(_)) {
        session.warn(
            "the time step is not used by a hash-grid field: it reads time on each window's frame axis \
             (one time vertex per frame, whatever their spacing)",
        );
    }
    check_time_range(&spec, method, &times, problem.time_step)?;
    for &h in &spec.holdout_times {
        if h < times[0] || h > times[times.len() - 1] {
            session.warn(&format!(
                "held-out time {} lies outside the training times; the field is held at the nearest end",
                num(h)
            ));
        }
    }
    let plan = plan_windows(times.len(), spec.windows.frames, spec.windows.overlap);
    let window_len = plan.first().map_or(1, |r| r.len());
    let field_cfg = field_for_window(&spec.field, window_len);
    let input_dim = input_dim_of(method);
    if input_dim == 4 {
        refuse_replaced_time_axis(method, &spec.field, &field_cfg, window_len)?;
    }
    let field = build_field(&field_cfg, &scene.aabb, input_dim, config.seed)?;
    let num_params = fluidnerf_neural::with_field!(&field, f => f.num_params());
    let pixels: u64 = scene.frames.iter().map(|f| (f.camera.width() * f.camera.height()) as u64).sum();
    let out_dims = Volume::dims_for(&scene.aabb, config.resolution);
    // Finished windows stay in memory until the field is stitched.
    let needed = estimate_memory(
        pixels,
        scene.frames.len() as u64,
        (num_params * plan.len().max(1)) as u64,
        out_dims.iter().map(|&n| n as u64).product(),
        truth.first().map_or(0, |(_, t)| t.len() as u64),
        rayon::current_num_threads() as u64,
        &spec.train,
    );
    check_memory(config, needed, || {
        format!(
            "{method} with {} windows of {num_params} parameters, {pixels} pixels and {} rays per image",
            plan.len(),
            spec.train.rays_per_image
        )
    })?;
    let progress = Progress {
        field: field_cfg.clone(),
        input_dim,
        frame_times: times.clone(),
        plan: plan.iter().map(|r| [r.start, r.end]).collect(),
        time_origin: spec.windows.time_origin,
        warm_start: spec.windows.warm_start,
        seed: config.seed,
        train: spec.train.clone(),
        finished: Vec::new(),
        aabb: Some(scene.aabb),
        time_step: (input_dim == 4 && !matches!(field_cfg, FieldConfig::HashGrid(_))).then_some(problem.time_step),
    };
    log::info!(
        "{} frames at t = {:?}, Δt = {}, {} training views, window {} frames",
        times.len(),
        times,
        problem.time_step,
        problem.views.len(),
        window_len
    );
    // A time-resolved run fits no gains, and scores no held-out view by reprojection.
    let preprocessing = measured.report(scene, None, &[]);
    Ok(Setup { spec, method, problem, masks, field_cfg, input_dim, field, needed, progress, preprocessing })
}

/// Runs (or, resuming, continues) a whole time-resolved run. With `require_all`, the run must
/// be one whose windows have all finished (it only stitches and writes the results).
pub(crate) fn run(
    scene: &Scene,
    config: &RunConfig,
    dir: &RunDir,
    truth: &[(Option<f64>, Volume)],
    session: &mut Session,
    require_all: bool,
) -> Result<RunReport, PipelineError> {
    let progress_path = dir.progress();
    if dir.resuming() && !progress_path.is_file() {
        return Err(PipelineError::RunDir {
            path: dir.root().to_path_buf(),
            why: "no windows/progress.json: nothing to continue or finish".into(),
        });
    }
    let Setup { spec, method, problem, masks, field_cfg, input_dim, field, needed, mut progress, preprocessing } =
        setup(scene, config, truth, session)?;
    if dir.resuming() {
        let saved: Progress = crate::rundir::read_json(&progress_path)?;
        if let Some(why) = progress.mismatch(&saved) {
            return Err(PipelineError::RunDir {
                path: progress_path,
                why: format!(
                    "cannot resume: {why}; rerun with its settings, or use --force (`overwrite=\"force\"` from \
                     Python) to start over"
                ),
            });
        }
        // The finished windows were trained with the saved settings, and the config.json this run
        // writes must rerun it: only the caps may change.
        let caps_aside = |t: &TrainConfig| TrainConfig { max_iterations: 0, time_budget_s: None, ..t.clone() };
        if caps_aside(&saved.train) != caps_aside(&progress.train) {
            let differences =
                crate::rundir::settings_differences(&caps_aside(&saved.train), &caps_aside(&progress.train), 5);
            return Err(crate::rundir::resume_refused(
                dir,
                progress_path,
                &format!("under `method.train`: {differences}"),
            ));
        }
        for (k, done) in saved.finished.iter().enumerate() {
            check_own_checkpoint(&progress_path, k, done)?;
        }
        progress.finished = saved.finished;
        // Windows run one at a time (`reconstruct_windows`) record themselves in done files.
        while progress.finished.len() < progress.plan.len() {
            match read_done(dir.root(), progress.finished.len())? {
                Some(done) => progress.finished.push(done),
                None => break,
            }
        }
        if require_all && progress.finished.len() < progress.plan.len() {
            let missing: Vec<String> = (progress.finished.len()..progress.plan.len())
                .filter(|&k| !dir.path(&done_name(k)).is_file())
                .map(|k| k.to_string())
                .collect();
            return Err(PipelineError::RunDir {
                path: dir.root().to_path_buf(),
                why: format!(
                    "cannot finish: window(s) {} of {} have not finished (no {}); run them first (--window-index K; \
                     `fluidnerf.dask.train_window` from Python), or --resume to train what is left here",
                    missing.join(", "),
                    progress.plan.len(),
                    done_name(progress.finished.len())
                ),
            });
        }
    } else {
        dir.write_json("config.json", config)?;
        dir.write_json("windows/progress.json", &progress)?;
    }
    let ctx = Ctx {
        scene,
        config,
        dir,
        truth,
        spec: &spec,
        field_cfg: &field_cfg,
        input_dim,
        method,
        needed,
        problem: &problem,
        masks: &masks,
        preprocessing: &preprocessing,
    };
    fluidnerf_neural::with_field!(field, f => ctx.train_and_write(f, progress, session))
}

struct Ctx<'a> {
    scene: &'a Scene,
    config: &'a RunConfig,
    dir: &'a RunDir,
    truth: &'a [(Option<f64>, Volume)],
    spec: &'a TemporalSpec,
    field_cfg: &'a FieldConfig,
    input_dim: usize,
    method: Method,
    needed: u64,
    problem: &'a fluidnerf_neural::train::Problem,
    masks: &'a ViewMasks,
    preprocessing: &'a Preprocessing,
}

/// The voxel reconstructions of the instants that start a window: time, field, seconds.
type InstantStarts = Vec<(f64, Box<dyn ScalarField + Send + Sync>, f64)>;

impl Ctx<'_> {
    /// Runs `start.method` on every training instant of a window that starts afresh (the
    /// first, or every one without warm starts) alone, into `start/tNN/` of the run folder
    /// ([`TemporalSpec::start`]), with at most half the window's time budget over its instants.
    fn instant_starts(&self, start: &crate::StartSpec, session: &mut Session) -> Result<InstantStarts, PipelineError> {
        let (scene, config, spec) = (self.scene, self.config, self.spec);
        let times = frame_times(self.problem);
        let plan = plan_windows(times.len(), spec.windows.frames, spec.windows.overlap);
        let fresh = plan.iter().enumerate().filter(|(k, _)| *k == 0 || !spec.windows.warm_start);
        let mut wanted: Vec<(usize, usize)> = fresh.flat_map(|(_, r)| r.clone().map(move |i| (i, r.len()))).collect();
        wanted.sort_unstable();
        wanted.dedup_by_key(|w| w.0);
        let mut fields = Vec::with_capacity(wanted.len());
        for (i, frames) in wanted {
            let t = times[i];
            let mut sub = scene.clone();
            sub.frames.retain(|f| same_time(f.time.unwrap_or(0.0), t));
            sub.truth.retain(|r| r.time.is_none_or(|rt| same_time(rt, t)));
            let truth: Vec<(Option<f64>, Volume)> =
                self.truth.iter().filter(|(rt, _)| rt.is_none_or(|rt| same_time(rt, t))).cloned().collect();
            let held_out = sub.holdout_frames().next().is_some();
            let budget = config.stopping.time_budget_s.map(|b| b / (2.0 * frames as f64));
            let path = self.dir.path(&format!("start/t{i:02}"));
            let views = self.problem.views.iter().filter(|v| same_time(v.time, t));
            let (method, why) = start.method.resolve(fluidnerf_neural::train::median_noise(views));
            log::info!("start at t = {t}: {why}");
            let reuse = self.dir.resuming();
            let report =
                run_voxel_start(method, &sub, &truth, config, held_out, budget, &path, reuse, session.on_event)?;
            log::info!(
                "{} at t = {t}: {} iterations in {:.1} s, kept {}",
                method,
                report.iterations,
                report.train_time_s,
                report.kept_iteration
            );
            fields.push((t, crate::load::LoadedRun::open(&path, Some(scene.aabb))?.field()?, report.train_time_s));
            if report.status == crate::RunStatus::Interrupted {
                // Stopped: the other instants' starts would only delay the stop.
                session.stopped = true;
                break;
            }
        }
        Ok(fields)
    }

    /// The saved state of an interrupted run, as learners of the field `init`.
    fn resume_state<F: TrainableField + Clone>(
        &self,
        init: &F,
        progress: &Progress,
    ) -> Result<ResumeState<F>, PipelineError> {
        // Every saved window, checked against the views it would continue on.
        let load = |k: usize, name: &str| -> Result<Learner<F>, PipelineError> {
            let mut learner = Learner::new(init.clone());
            fluidnerf_neural::weights::load_checkpoint(&self.dir.path(name), &mut learner)?;
            check_window_views(self.dir, name, k, &learner, (self.problem, self.masks), self.spec, progress)?;
            Ok(learner)
        };
        let mut state = ResumeState::default();
        for (k, w) in progress.finished.iter().enumerate() {
            state.finished.push((load(k, &w.checkpoint)?, w.report.clone()));
        }
        let next = checkpoint_name(progress.finished.len());
        if progress.finished.len() < progress.plan.len() && self.dir.path(&next).is_file() {
            let k = progress.finished.len();
            // Loaded and checked in any case: a resume continues only on the views the run
            // started with, and a window started again reads back starts made from them.
            let learner = load(k, &next)?;
            if crate::neural::checkpoint_start_unfinished(&self.dir.path(&next))? {
                log::warn!(
                    "{} was stopped during its start, before window {k} trained: there is no training to continue, \
                     so the window starts again from its start",
                    self.dir.root().display()
                );
            } else {
                Self::check_cap(self.spec, k, &learner, &self.dir.path(&next))?;
                state.running = Some(learner);
            }
        }
        // After the running window's own check, whose refusal says more.
        for (k, w) in progress.finished.iter().enumerate() {
            Self::check_finished_cap(self.spec, k, &w.report, &self.dir.path(&w.checkpoint))?;
        }
        log::info!(
            "resuming: {} of {} windows finished{}",
            state.finished.len(),
            progress.plan.len(),
            state.running.as_ref().map(|l| format!(", the next at iteration {}", l.iteration)).unwrap_or_default()
        );
        Ok(state)
    }

    /// Window `k`'s iteration cap, with the configuration key that sets it and how to give a
    /// value `n` for it.
    fn window_cap(spec: &TemporalSpec, k: usize) -> (usize, &'static str, impl Fn(&str) -> String) {
        let warm = spec.windows.warm_start && k > 0;
        let (cap, key) = match spec.windows.warm_max_iterations.filter(|_| warm) {
            Some(m) => (m, "method.windows.warm_max_iterations"),
            None => (spec.train.max_iterations, "stopping.max_iterations"),
        };
        let give = move |n: &str| match key {
            "stopping.max_iterations" => format!("--max-iterations {n}"),
            _ => format!("{key} {n} in the configuration"),
        };
        (cap, key, give)
    }

    /// Refuses to continue window `k`'s saved `learner` (at `path`) beyond the iteration cap asked
    /// for now.
    fn check_cap<F: TrainableField>(
        spec: &TemporalSpec,
        k: usize,
        learner: &Learner<F>,
        path: &std::path::Path,
    ) -> Result<(), PipelineError> {
        // The running window only continues: below its checkpoint's iteration it would keep
        // the longer training and record the lower cap in config.json, which reruns to
        // another result (as a static run refuses it).
        let (cap, key, give) = Self::window_cap(spec, k);
        if learner.iteration > cap {
            let give = give(&format!("of at least {}", learner.iteration));
            return Err(PipelineError::invalid(
                key,
                format!(
                    "{} (window {k}, still training) is at iteration {}, beyond the cap of {cap} asked for; a \
                     resumed run only continues, so give {give} (or start afresh with --force)",
                    path.display(),
                    learner.iteration,
                ),
            ));
        }
        Ok(())
    }

    /// Refuses an iteration cap that finished window `k` (its `report`, its checkpoint at
    /// `path`) contradicts: a resumed run reads finished windows back without training them,
    /// so a cap above the one a window stopped at, or below the iterations it did, was written
    /// into config.json and ignored, and a rerun from that file gave another result.
    fn check_finished_cap(
        spec: &TemporalSpec,
        k: usize,
        report: &fluidnerf_neural::train::TrainReport,
        path: &std::path::Path,
    ) -> Result<(), PipelineError> {
        let (cap, key, give) = Self::window_cap(spec, k);
        let stopped_at_cap = report.stop_reason == fluidnerf_neural::train::StopReason::MaxIterations;
        if report.iterations > cap || (stopped_at_cap && report.iterations < cap) {
            let give = give(&report.iterations.to_string());
            let how = if stopped_at_cap { "stopped at its cap of" } else { "trained for" };
            return Err(PipelineError::invalid(
                key,
                format!(
                    "{} (window {k}, finished) {how} {} iterations, and a resumed run does not train finished \
                     windows again, so a cap of {cap} would be recorded for a run that did not use it; give {give} \
                     (or start afresh with --force to train with the new cap)",
                    path.display(),
                    report.iterations,
                ),
            ));
        }
        Ok(())
    }

    fn train_and_write<F: TrainableField + Clone + 'static>(
        &self,
        init: F,
        mut progress: Progress,
        session: &mut Session,
    ) -> Result<RunReport, PipelineError> {
        let (config, dir, spec) = (self.config, self.dir, self.spec);
        let resume = if dir.resuming() {
            let state = self.resume_state(&init, &progress)?;
            dir.replace_finished(config)?;
            state
        } else {
            ResumeState::default()
        };
        let windows = progress.plan.len().max(1);
        let mut io_error = None;
        let t_start = Instant::now();
        // The instants' own reconstructions, when the windows start from them. Their runs
        // report their own events first, each from its start to its writing.
        let starts = match &spec.start {
            Some(start) => Some(self.instant_starts(start, session)?),
            None => None,
        };
        let mut interrupted = session.stopped;
        // Whether the run was stopped before its last window's field trained: during the
        // window's fit to its instants' starts, or before it when a start was stopped (its first
        // fit event then stops it; a window resumed from its checkpoint has no fit and trained
        // before) ([`crate::neural::START_TAG`]).
        let mut start_unfinished = false;
        let _ = session.emit(RunEvent::Started {
            method: self.method,
            max_iterations: spec.train.max_iterations,
            windows,
            start_iteration: 0,
        });
        let target = |t: f64, points: &[fluidnerf_core::glam::Vec3], out: &mut [f32]| {
            let nearest = starts.iter().flatten().min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()));
            match nearest {
                Some((_, field, _)) => field.eval(points, 0.0, out),
                None => out.fill(0.0),
            }
        };
        let frame_start = spec.start.as_ref().map(|s| FrameStart {
            target: &target,
            fit: s.fit,
            learning_rate_scale: s.learning_rate_scale,
            seconds: starts.iter().flatten().map(|(t, _, s)| (*t, *s)).collect(),
        });
        let run: TemporalRun<F> = train_windows(
            self.problem,
            self.masks,
            &spec.train,
            &spec.windows,
            init,
            config.seed,
            resume,
            frame_start.as_ref(),
            |e| {
                let (w, s) = match e {
                    WindowEvent::Iteration(w, s) => (w, s),
                    WindowEvent::StartFit(_, step, steps) => {
                        let every = step.is_multiple_of(crate::event::START_FIT_EVENT_EVERY) || step == steps;
                        if every && session.emit(RunEvent::StartFit { step, steps }).is_break() {
                            interrupted = true;
                        }
                        if interrupted {
                            start_unfinished = true;
                            return ControlFlow::Break(());
                        }
                        return ControlFlow::Continue(());
                    }
                    WindowEvent::Finished(w, done) => {
                        // The checkpoint first: a window listed as finished always has its final one.
                        let name = checkpoint_name(progress.finished.len());
                        let saved = write_checkpoint_to(dir, &name, &done.learner, &done.views, false).and_then(|_| {
                            progress.finished.push(FinishedWindow { checkpoint: name, report: done.report.clone() });
                            dir.write_json("windows/progress.json", &progress)
                        });
                        if let Err(e) = saved {
                            io_error = Some(e);
                            return ControlFlow::Break(());
                        }
                        let pos = WindowPos { index: w.index, count: w.count, frames: [w.frames.start, w.frames.end] };
                        if session.emit(RunEvent::WindowFinished(pos)).is_break() {
                            interrupted = true;
                            return ControlFlow::Break(());
                        }
                        return ControlFlow::Continue(());
                    }
                };
                let pos = WindowPos { index: w.index, count: w.count, frames: [w.frames.start, w.frames.end] };
                let event = RunEvent::Iteration {
                    window: Some(pos),
                    iteration: s.iteration,
                    loss: s.loss as f64,
                    smoothed: Some(s.smoothed_loss as f64),
                    train_time_s: s.train_time_s,
                };
                if session.emit(event).is_break() {
                    interrupted = true;
                }
                if config.checkpoint_every > 0 && s.iteration % config.checkpoint_every == 0 {
                    match write_checkpoint_to(dir, &checkpoint_name(w.index), s.learner, &w.views, false) {
                        Ok(path) => {
                            let _ = session.emit(RunEvent::Checkpoint { path: &path });
                        }
                        Err(e) => {
                            io_error = Some(e);
                            return ControlFlow::Break(());
                        }
                    }
                }
                if interrupted {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            },
        )
        .map_err(crate::config::training_error)?;
        if let Some(e) = io_error {
            return Err(e);
        }
        let _ = session.emit(RunEvent::Writing);
        let wall_s = t_start.elapsed().as_secs_f64();
        if let Some(w) = run.windows.last().filter(|_| start_unfinished) {
            let (a, b) = (run.frame_times[w.frames.start], run.frame_times[w.frames.end - 1]);
            let at = if w.frames.len() == 1 { format!("t = {a}") } else { format!("t = {a}–{b}") };
            session.warn(&format!(
                "stopped during the start of window {} ({at}), before its field trained: the volumes there are the \
                 field before training, not a reconstruction; the instants' voxel starts are in {}; `reconstruct -o \
                 {} --resume` (`overwrite=\"resume\"` from Python) runs the start again",
                run.windows.len() - 1,
                dir.path("start").display(),
                dir.root().display()
            ));
        }

        // Weights, checkpoints and the description of the stitched field.
        let mut records = Vec::new();
        let mut result_bytes = 0u64;
        for (k, w) in run.windows.iter().enumerate() {
            let name = format!("windows/w{k:03}.safetensors");
            let record = WindowRecord {
                frames: [w.frames.start, w.frames.end],
                time_origin: w.time_origin,
                time_axis: w.time_axis,
                meta: w.meta.clone(),
                weights: name.clone(),
            };
            // The file says which window it holds: reading the run refuses it in another's place.
            let tag = WindowTag::of(k, &record, &run.frame_times).to_json();
            let bytes = fluidnerf_neural::weights::weights_bytes_tagged(&w.learner.field, &[(WINDOW_TAG, tag)])?;
            result_bytes += bytes.len() as u64;
            dir.write_bytes(&name, &bytes)?;
            // The window stopped before it trained is marked, so that a resume fits it again.
            let unfinished = start_unfinished && k + 1 == run.windows.len();
            write_checkpoint_to(dir, &checkpoint_name(k), &w.learner, &w.views, unfinished)?;
            records.push(record);
        }
        dir.write_json(
            "temporal.json",
            &TemporalRecord {
                field: self.field_cfg.clone(),
                input_dim: self.input_dim,
                frame_times: run.frame_times.clone(),
                windows: records,
            },
        )?;
        let stitched = StitchedField::from_run(&run)?;

        // Volumes at every training and held-out time the windows reached, and their metrics.
        let t_eval = Instant::now();
        let mut all_times: Vec<(f64, bool)> = run.frame_times.iter().map(|&t| (t, true)).collect();
        all_times.extend(spec.holdout_times.iter().map(|&t| (t, false)));
        all_times.sort_by(|a, b| a.0.total_cmp(&b.0));
        // A stopped run's windows cover the first frames only: after the last of them its field
        // only repeats that frame, so no volume stands for a later time.
        let covered = run.windows.iter().map(|w| w.frames.end).max().unwrap_or(0).max(1);
        let last_reached = run.frame_times[covered - 1];
        let reached = |t: f64| covered == run.frame_times.len() || t <= last_reached || same_time(t, last_reached);
        let not_reached: Vec<f64> = all_times.iter().map(|&(t, _)| t).filter(|&t| !reached(t)).collect();
        let out_times: Vec<(f64, bool)> = all_times.into_iter().filter(|&(t, _)| reached(t)).collect();
        if !not_reached.is_empty() {
            let list: Vec<String> = not_reached.iter().map(f64::to_string).collect();
            session.warn(&format!(
                "the run was stopped before it reached t = {} (its windows trained up to t = {last_reached}): no \
                 volume is written there; continue it with `reconstruct --resume` (`overwrite=\"resume\"` from \
                 Python)",
                list.join(", ")
            ));
        }
        let dims = Volume::dims_for(&self.scene.aabb, config.resolution);
        let mut volumes = Vec::new();
        let mut pvd_entries = Vec::new();
        let options = crate::metric_options(self.scene, self.truth)?;
        let mut volumes_max = 0.0f32;
        for (i, &(t, trained)) in out_times.iter().enumerate() {
            let volume = Volume::from_field(dims, self.scene.aabb, &stitched, t);
            let stem = frame_stem(i, out_times.len());
            volumes_max = volumes_max.max(volume.min_max().1);
            write_volume(dir, &stem, &volume, Some(t))?;
            pvd_entries.push((t, format!("{stem}.vti")));
            let truth = self
                .truth
                .iter()
                .find(|(tt, _)| tt.is_some_and(|tt| same_time(tt, t)))
                .or(if self.truth.len() == 1 && self.truth[0].0.is_none() { self.truth.first() } else { None });
            let metrics = match truth {
                Some((_, tv)) => {
                    let v = Volume::from_field(tv.dims, tv.aabb, &stitched as &dyn ScalarField, t);
                    Some(fluidnerf_metrics::evaluate_volume(&v, tv, Some(t), &options)?)
                }
                None => None,
            };
            let digest = Some(crate::volume_digest(&volume));
            volumes.push(VolumeRecord { file: format!("{stem}.npy"), time: Some(t), trained, dims, metrics, digest });
        }
        dir.write_bytes("volumes.pvd", pvd(&pvd_entries).as_bytes())?;
        if let Some(w) = crate::empty_field_warning(self.problem, volumes_max, &self.spec.train) {
            session.warn(&w);
        }
        let eval_s = t_eval.elapsed().as_secs_f64();

        let trained = || volumes.iter().filter(|v| v.trained).filter_map(|v| v.metrics.as_ref());
        let train_time_s: f64 = run.windows.iter().map(|w| w.report.train_time_s).sum();
        let iterations: usize = run.windows.iter().map(|w| w.learner.iteration).sum();
        let last_reason = run.windows.last().map(|w| w.report.stop_reason);
        let final_nrmse = mean(trained().map(|m| m.global.nrmse));
        let stop_reason = if run.interrupted || interrupted {
            StopReason::Interrupted
        } else {
            last_reason.map_or(StopReason::IterationCap, StopReason::from)
        };
        log::debug!("{}: prepare and train {wall_s:.1} s", self.method);
        let report = RunReport {
            preprocessing: Some(self.preprocessing.clone()),
            warnings: Vec::new(),
            format: REPORT_FORMAT,
            fluidnerf_version: env!("CARGO_PKG_VERSION").to_string(),
            method: self.method,
            aabb: self.scene.aabb,
            units: self.scene.units.clone(),
            status: stop_reason.status(),
            stop_reason,
            stopping: config.stopping,
            stopping_rule: config.stopping.describe(Family::Temporal),
            iterations,
            kept_iteration: iterations,
            setup_s: 0.0,
            train_time_s,
            eval_s,
            cpu_s: session.cpu_s(),
            peak_rss_bytes: peak_rss(),
            memory_estimate_bytes: self.needed,
            result_bytes,
            history: History {
                loss_kind: Some(LossKind::TrainingMse),
                loss: run.windows.iter().flat_map(|w| w.learner.losses.iter().map(|&l| l as f64)).collect(),
                holdout: Vec::new(),
                // One point, at the end: the mean over the trained times (no curve during training).
                nrmse: final_nrmse
                    .map(|nrmse| vec![fluidnerf_metrics::NrmsePoint { iteration: iterations, train_time_s, nrmse }])
                    .unwrap_or_default(),
                eval_every: 0,
            },
            final_nrmse,
            final_ssim_global: mean(trained().map(|m| m.global.ssim_global)),
            volumes,
            not_reached,
            classical: None,
            neural: None,
            windows: run
                .windows
                .iter()
                .map(|w| WindowDetails {
                    frames: [w.frames.start, w.frames.end],
                    time_origin: w.time_origin,
                    occupied_fraction: w.occupied_fraction,
                    train: w.report.clone(),
                })
                .collect(),
        };
        finish(self.scene, dir, report, self.truth, None, session)
    }
}

/// The windows a time-resolved run trains: what a scheduler splits the work by.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WindowPlan {
    /// The distinct training frame times, increasing (held-out times removed).
    pub frame_times: Vec<f64>,
    /// First and one-past-last frame index of every window, in training order.
    pub windows: Vec<[usize; 2]>,
    /// Each window after the first starts from the previous window's trained field, so window
    /// `k` can only start once window `k − 1` has finished.
    pub warm_start: bool,
}

impl WindowPlan {
    /// The window that window `k` starts from, if any.
    pub fn depends_on(&self, k: usize) -> Option<usize> {
        (self.warm_start && k > 0).then(|| k - 1)
    }

    /// The windows whose frames all lie in `frames` (frame indices into
    /// [`WindowPlan::frame_times`]); refused when there is none.
    pub fn windows_in(&self, frames: std::ops::Range<usize>) -> Result<std::ops::Range<usize>, PipelineError> {
        let inside: Vec<usize> = (0..self.windows.len())
            .filter(|&k| self.windows[k][0] >= frames.start && self.windows[k][1] <= frames.end)
            .collect();
        match (inside.first(), inside.last()) {
            (Some(&a), Some(&b)) => Ok(a..b + 1),
            _ => Err(PipelineError::invalid(
                "frames",
                format!(
                    "no window lies inside frames {}..{} (the run has {} frames in {} windows: {:?})",
                    frames.start,
                    frames.end,
                    self.frame_times.len(),
                    self.windows.len(),
                    self.windows
                ),
            )),
        }
    }
}

/// Refuses a time-resolved `method` on a scene none of whose frames has a time: each frame's
/// time would be taken as 0, one window of one frame at a time the scene has not. Every path of
/// a run (in one piece, by windows, the window plan) refuses it with these words.
fn refuse_timeless_scene(scene: &Scene, method: Method) -> Result<(), PipelineError> {
    if scene.frames.iter().any(|f| f.time.is_some()) {
        return Ok(());
    }
    let named = if scene.root.as_os_str().is_empty() {
        "the scene".to_string()
    } else {
        format!("the scene {}", scene.root.display())
    };
    Err(PipelineError::invalid(
        "method",
        format!(
            "{method} plans its windows over the frames' times, and {named} has no frame times (no frame has a \
             `time`); give every frame its time, or reconstruct the scene with a static method"
        ),
    ))
}

/// The window settings a front end was given for a run (the others come from its configuration
/// file or its preset), named as that front end names them: `--window` and `--overlap` on the
/// command line, `method.windows.frames` and `method.windows.overlap` from Python.
#[derive(Clone, Copy, Debug)]
pub struct GivenWindows<'a> {
    /// Frames per window given, if any.
    pub frames: Option<usize>,
    /// Overlap given, if any.
    pub overlap: Option<usize>,
    /// The name of the frames setting.
    pub frames_name: &'a str,
    /// The name of the overlap setting.
    pub overlap_name: &'a str,
    /// Whose overlap the run takes when none is given: `"the preset's"` or `"the configuration's"`.
    pub overlap_from: &'a str,
}

/// Refuses window settings given for the time-resolved run `config` that it would not take as
/// given, as every front end refuses them (a run that is not time-resolved passes):
/// - windows of `W` frames given without an overlap, whose overlap (the preset's, or the
///   configuration's, set for its own window length) is not fewer frames than `W`;
/// - an overlap above 0 given for windows of 0 frames (one field on every frame);
/// - with `scene`, an overlap above 0 given where the scene has a single training frame, or where
///   the windows hold every training frame in one window.
///
/// In the last two the overlap would be recorded in `config.json` and ignored. `config` holds
/// the given settings already; without `scene` the checks of the scene's frames are left out.
pub fn check_given_windows(
    config: &RunConfig,
    scene: Option<&Scene>,
    given: &GivenWindows,
) -> Result<(), PipelineError> {
    let MethodConfig::Temporal(_, spec) = &config.method else { return Ok(()) };
    let GivenWindows { frames_name, overlap_name, .. } = *given;
    let (w, o) = (spec.windows.frames, spec.windows.overlap);
    if given.frames.is_some() && given.overlap.is_none() && w > 0 && o >= w {
        let give = if w == 1 { format!("{overlap_name} 0") } else { format!("{overlap_name} below {w}") };
        return Err(PipelineError::invalid(
            "method.windows.overlap",
            format!(
                "windows of {w} frames would overlap by {o} frames ({} overlap, as {overlap_name} is not given), but \
                 an overlap must be fewer frames than the window's; give {give} with {frames_name} {w} (0: windows \
                 that do not overlap)",
                given.overlap_from
            ),
        ));
    }
    let Some(o) = given.overlap else { return Ok(()) };
    let key = format!("{overlap_name} {o}");
    // An overlap of 0 asks for nothing to overlap, which one field on every frame satisfies.
    if w == 0 && o > 0 {
        return Err(PipelineError::invalid(
            key,
            format!(
                "the run trains one field on every frame (windows of 0 frames), so there are no windows to overlap; \
                 give {frames_name} N frames per window with it, or leave {overlap_name} out"
            ),
        ));
    }
    let Some(scene) = scene.filter(|_| o > 0) else { return Ok(()) };
    let plan = window_plan(scene, config)?;
    let frames = plan.frame_times.len();
    if frames < 2 {
        return Err(PipelineError::invalid(
            key,
            format!(
                "the scene has a single training frame, so there are no windows to overlap; leave {overlap_name} out"
            ),
        ));
    }
    if plan.windows.len() == 1 {
        return Err(PipelineError::invalid(
            key,
            format!(
                "windows of {w} frames hold all {frames} training frames of the scene in one window, so there are no \
                 windows to overlap; give {frames_name} below {frames} with it, or leave {overlap_name} out"
            ),
        ));
    }
    Ok(())
}

/// The window plan of the time-resolved run `config` of `scene`, from the scene file alone
/// (no image is read).
pub fn window_plan(scene: &Scene, config: &RunConfig) -> Result<WindowPlan, PipelineError> {
    let config = &config.resolved(scene);
    config.validate()?;
    let MethodConfig::Temporal(_, spec) = config.effective_method() else {
        return Err(PipelineError::invalid(
            "method",
            format!("{} is not a time-resolved method (tr-fluidnerf, tr-fast, static-per-frame)", config.method()),
        ));
    };
    refuse_timeless_scene(scene, config.method())?;
    let mut times: Vec<f64> = scene
        .frames
        .iter()
        .filter(|f| !f.holdout)
        .map(|f| f.time.unwrap_or(0.0))
        .filter(|&t| !spec.holdout_times.iter().any(|&h| same_time(h, t)))
        .collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    let plan = plan_windows(times.len(), spec.windows.frames, spec.windows.overlap);
    Ok(WindowPlan {
        frame_times: times,
        windows: plan.iter().map(|r| [r.start, r.end]).collect(),
        warm_start: spec.windows.warm_start,
    })
}

/// What [`reconstruct_windows`] did with one window.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WindowOutcome {
    pub index: usize,
    /// First and one-past-last frame of the window.
    pub frames: [usize; 2],
    /// The window had finished before (its done file was read back; nothing was trained).
    pub reused: bool,
    /// Whether the window finished; an interrupted window has its checkpoint written and
    /// continues from it when run again.
    pub status: RunStatus,
    /// Training iterations of the window.
    pub iterations: usize,
    /// Its last training loss.
    pub final_loss: f64,
}

/// Trains the windows `windows` of the time-resolved run `config` of `scene` into the run
/// folder `out`, one after the other, as the serial run trains them: each window's final
/// checkpoint `windows/wNNN.checkpoint.safetensors` and then its done file
/// `windows/wNNN.done.json` are written atomically when it finishes. `config.json` and
/// `windows/progress.json` are written by the first call and must match in every later one.
///
/// A window whose done file exists is read back, not trained again, so calls are idempotent
/// (a scheduler may repeat them). A window whose checkpoint exists without a done file (its
/// process died) continues from that checkpoint. A warm-started window (`k > 0` with
/// `windows.warm_start`) starts from window `k − 1`'s final checkpoint, which must exist
/// (finished earlier or in this call); several processes may run different windows at once
/// (each window is locked while it trains). [`finish_windows`] then writes the results.
/// `on_event` may stop the run after any iteration.
pub fn reconstruct_windows(
    scene: &Scene,
    config: &RunConfig,
    out: &std::path::Path,
    windows: std::ops::Range<usize>,
    mut on_event: impl FnMut(&RunEvent) -> ControlFlow<()>,
) -> Result<Vec<WindowOutcome>, PipelineError> {
    let config = &config.resolved(scene);
    crate::check_scene_named(config, scene)?;
    config.validate()?;
    let mut session = Session {
        on_event: &mut on_event,
        stopped: false,
        started: Instant::now(),
        cpu0: None,
        budget_s: config.stopping.time_budget_s,
        estimate: crate::Estimator::default(),
        warnings: Vec::new(),
    };
    let Setup { spec, method, problem, masks, field, progress, .. } = setup(scene, config, &[], &mut session)?;
    if spec.start.is_some() {
        return Err(PipelineError::invalid(
            "method.start",
            "a run trained window by window does not start from its instants' reconstructions yet; run it whole",
        ));
    }
    let count = progress.plan.len();
    if windows.start >= windows.end || windows.end > count {
        return Err(PipelineError::invalid(
            "window",
            format!(
                "windows {}..{} are not in the plan: the run has {count} window(s), 0..{count} (frames {:?})",
                windows.start, windows.end, progress.plan
            ),
        ));
    }
    let dir = RunDir::for_windows(out, Some(&scene.root))?;
    prepare_folder(&dir, config, &progress)?;
    let _ = session.emit(RunEvent::Started {
        method,
        max_iterations: spec.train.max_iterations,
        windows: windows.len(),
        start_iteration: 0,
    });
    fluidnerf_neural::with_field!(field, f => {
        train_some(&dir, config, &spec, (&problem, &masks), &progress, f, windows, &mut session)
    })
}

/// Refuses the `config.json` at `config_path` of a run trained window by window when it holds
/// other settings than `config` (resolved).
fn same_settings(config_path: &std::path::Path, config: &RunConfig) -> Result<(), PipelineError> {
    let saved = RunConfig::read(config_path)?;
    let mut ours = config.clone();
    ours.fluidnerf_version.clone_from(&saved.fluidnerf_version);
    if saved != ours {
        let keys = crate::rundir::settings_differences(&saved, &ours, 5);
        return Err(PipelineError::RunDir {
            path: config_path.to_path_buf(),
            why: format!(
                "holds a run with other settings ({keys}); run every window with the same settings (or use another \
                 folder)"
            ),
        });
    }
    Ok(())
}

/// Refuses the folder `out` when it holds a run trained window by window with other settings
/// than `config` of `scene`: checked before a window asked for by its index, which is an index
/// of that run's plan and may not be one of this configuration's.
pub fn check_window_folder(scene: &Scene, config: &RunConfig, out: &std::path::Path) -> Result<(), PipelineError> {
    let config_path = out.join("config.json");
    if !config_path.is_file() {
        return Ok(());
    }
    same_settings(&config_path, &config.resolved(scene))
}

/// Writes `config.json` and `windows/progress.json` of a run trained window by window, or
/// checks that the folder's are those of this run.
fn prepare_folder(dir: &RunDir, config: &RunConfig, progress: &Progress) -> Result<(), PipelineError> {
    let config_path = dir.config();
    if config_path.is_file() {
        same_settings(&config_path, config)?;
    } else {
        dir.write_json("config.json", config)?;
    }
    let progress_path = dir.progress();
    if progress_path.is_file() {
        let saved: Progress = crate::rundir::read_json(&progress_path)?;
        let why = progress.mismatch(&saved).or_else(|| {
            (saved.train != progress.train).then(|| "the run in this folder has other training settings".to_string())
        });
        if let Some(why) = why {
            return Err(PipelineError::RunDir { path: progress_path, why: format!("{why}; use another folder") });
        }
    } else {
        dir.write_json("windows/progress.json", progress)?;
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn train_some<F: TrainableField + Clone>(
    dir: &RunDir,
    config: &RunConfig,
    spec: &TemporalSpec,
    (problem, masks): (&fluidnerf_neural::train::Problem, &ViewMasks),
    progress: &Progress,
    init: F,
    windows: std::ops::Range<usize>,
    session: &mut Session,
) -> Result<Vec<WindowOutcome>, PipelineError> {
    use fluidnerf_neural::temporal::{train_window, WindowStart};
    let times = &progress.frame_times;
    let plan: Vec<std::ops::Range<usize>> = progress.plan.iter().map(|&[a, b]| a..b).collect();
    // A saved window, checked against the views it was trained on.
    let load = |k: usize| -> Result<Learner<F>, PipelineError> {
        let mut learner = Learner::new(init.clone());
        let name = checkpoint_name(k);
        fluidnerf_neural::weights::load_checkpoint(&dir.path(&name), &mut learner)?;
        check_window_views(dir, &name, k, &learner, (problem, masks), spec, progress)?;
        Ok(learner)
    };
    let mut outcomes = Vec::new();
    for k in windows {
        let _lock = dir.lock_file(&format!("windows/w{k:03}.lock"))?;
        let frames = [plan[k].start, plan[k].end];
        if let Some(done) = read_done(dir.root(), k)? {
            log::info!("window {k}: finished earlier ({}); read back", done_name(k));
            outcomes.push(WindowOutcome {
                index: k,
                frames,
                reused: true,
                status: RunStatus::Finished,
                iterations: done.report.iterations,
                final_loss: done.report.final_loss as f64,
            });
            continue;
        }
        let start = if dir.path(&checkpoint_name(k)).is_file() {
            log::info!("window {k}: continuing from {}", checkpoint_name(k));
            WindowStart::Resume(load(k)?)
        } else if progress.warm_start && k > 0 {
            if read_done(dir.root(), k - 1)?.is_none() {
                return Err(PipelineError::RunDir {
                    path: dir.path(&checkpoint_name(k - 1)),
                    why: format!(
                        "window {k} starts from the field of window {} (warm start), whose final checkpoint is missing \
                         (window {} has not finished: no {}); run window {} first, or train without warm start",
                        k - 1,
                        k - 1,
                        done_name(k - 1),
                        k - 1
                    ),
                });
            }
            WindowStart::Warm(load(k - 1)?.field)
        } else {
            WindowStart::Fresh(init.clone())
        };
        let pos = WindowPos { index: k, count: plan.len(), frames };
        let mut io_error = None;
        let trained =
            train_window(problem, masks, times, &plan, k, &spec.train, &spec.windows, config.seed, start, None, |e| {
                // Split windows have no start to fit to.
                let WindowEvent::Iteration(info, s) = e else {
                    return ControlFlow::Continue(());
                };
                let event = RunEvent::Iteration {
                    window: Some(pos),
                    iteration: s.iteration,
                    loss: s.loss as f64,
                    smoothed: Some(s.smoothed_loss as f64),
                    train_time_s: s.train_time_s,
                };
                let flow = session.emit(event);
                if config.checkpoint_every > 0 && s.iteration % config.checkpoint_every == 0 {
                    if let Err(e) = write_checkpoint_to(dir, &checkpoint_name(k), s.learner, &info.views, false) {
                        io_error = Some(e);
                        return ControlFlow::Break(());
                    }
                }
                flow
            })
            .map_err(crate::config::training_error)?;
        if let Some(e) = io_error {
            return Err(e);
        }
        // The checkpoint first: a window with a done file always has its final checkpoint.
        write_checkpoint_to(dir, &checkpoint_name(k), &trained.learner, &trained.views, false)?;
        let interrupted = trained.report.stop_reason == fluidnerf_neural::train::StopReason::Interrupted;
        outcomes.push(WindowOutcome {
            index: k,
            frames,
            reused: false,
            status: if interrupted { RunStatus::Interrupted } else { RunStatus::Finished },
            iterations: trained.learner.iteration,
            final_loss: trained.report.final_loss as f64,
        });
        if interrupted {
            break;
        }
        dir.write_json(
            &done_name(k),
            &FinishedWindow { checkpoint: checkpoint_name(k), report: trained.report.clone() },
        )?;
        if session.emit(RunEvent::WindowFinished(pos)).is_break() {
            break;
        }
    }
    Ok(outcomes)
}

/// Finishes a time-resolved run whose windows were trained by [`reconstruct_windows`]: reads
/// every window back, stitches the field and writes what the serial run writes (volumes,
/// `temporal.json`, `report.json`, …), identical to it for the same settings. Refused, naming
/// them, while windows have not finished.
pub fn finish_windows(
    scene: &Scene,
    config: &RunConfig,
    out: &std::path::Path,
    mut on_event: impl FnMut(&RunEvent) -> ControlFlow<()>,
) -> Result<RunReport, PipelineError> {
    let config = &config.resolved(scene);
    config.validate()?;
    if config.method().family() != Family::Temporal {
        return Err(PipelineError::invalid(
            "method",
            format!("{} is not a time-resolved method (tr-fluidnerf, tr-fast, static-per-frame)", config.method()),
        ));
    }
    let dir = RunDir::create(out, crate::Overwrite::Resume, Some(&scene.root))?;
    let mut session = Session {
        on_event: &mut on_event,
        stopped: false,
        started: Instant::now(),
        cpu0: crate::cpu_seconds(),
        budget_s: config.stopping.time_budget_s,
        estimate: crate::Estimator::default(),
        warnings: Vec::new(),
    };
    let truth = crate::load_truth(scene)?;
    run(scene, config, &dir, &truth, &mut session, true)
}

/// Refuses a hash grid's `time_span` or `time_resolution` that [`field_for_window`] replaces
/// (`given`, the configuration's field, becomes `used` for windows of `window_len` frames) when
/// it was set to another value than its default and the one used: it would be ignored.
fn refuse_replaced_time_axis(
    method: Method,
    given: &FieldConfig,
    used: &FieldConfig,
    window_len: usize,
) -> Result<(), PipelineError> {
    let (FieldConfig::HashGrid(given), FieldConfig::HashGrid(used)) = (given, used) else {
        return Ok(());
    };
    let d = fluidnerf_neural::HashGridConfig::default();
    let span = |v: f32| num(v).to_string();
    let keys = [
        (
            "time_span",
            given.time_span != d.time_span && given.time_span != used.time_span,
            span(given.time_span),
            span(used.time_span),
            span(d.time_span),
        ),
        (
            "time_resolution",
            given.time_resolution != d.time_resolution && given.time_resolution != used.time_resolution,
            given.time_resolution.to_string(),
            used.time_resolution.to_string(),
            d.time_resolution.to_string(),
        ),
    ];
    match keys.into_iter().find(|k| k.1) {
        Some((key, _, given, used, default)) => Err(PipelineError::invalid(
            format!("method.field.hash-grid.{key}"),
            format!(
                "{given} would be ignored: the grid's time axis spans each window's frames, one cell per frame \
                 interval, so {method} sets it to {used} for windows of {window_len} frames; leave it at its \
                 default {default} or give {used}"
            ),
        )),
        None => Ok(()),
    }
}

/// The most time steps the span of a run's times may take: 2²⁴, beyond which a 32-bit `t'` no
/// longer holds a time to a fraction of a step, so that the time encoding's sines read rounding
/// instead of time. A time step of 10⁻³⁰ on times 0 to 2 (2·10³⁰ steps, within f32's range)
/// made the first loss infinite and was reported as a divergence asking for a lower learning
/// rate.
const MAX_TIME_STEPS: f64 = 16_777_216.0;

/// The least gap between two of a run's times, in time steps: the network's lowest time
/// frequency turns by π per step, so times a thousandth of a step apart are one instant to it.
/// A time step of 10³⁰ on times a second apart trained every frame as one static field.
const MIN_TIME_GAP_STEPS: f64 = 1e-3;

/// Refuses a time step by which the span of the run's times (training and held out) is more
/// than [`MAX_TIME_STEPS`] steps: a space–time network reads `t' = (t − t₀)/Δt` in 32 bits.
/// Two times less than [`MIN_TIME_GAP_STEPS`] apart, which it reads as one instant, are refused
/// too. A hash-grid field reads frame positions instead and a per-frame field no time at all.
fn check_time_range(spec: &TemporalSpec, method: Method, times: &[f64], step: f64) -> Result<(), PipelineError> {
    if input_dim_of(method) != 4 || matches!(spec.field, FieldConfig::HashGrid(_)) {
        return Ok(());
    }
    let all = || times.iter().chain(&spec.holdout_times).copied();
    let (first, last) = (all().fold(f64::INFINITY, f64::min), all().fold(f64::NEG_INFINITY, f64::max));
    let steps = (last - first) / step;
    // A span of more steps than 32 bits tell apart comes first: its later times all read as an
    // infinite `t'`, which the test below would take for one instant and ask for a smaller
    // step, the opposite of what they need.
    if steps > MAX_TIME_STEPS {
        return Err(PipelineError::invalid(
            "method.time_step",
            format!(
                "the times run from {} to {}, {} time steps of Δt = {}{}: more than the {} steps in which the \
                 network's 32-bit time input t' = (t − t₀)/Δt tells one step from the next; give a larger time step \
                 (--time-step) or the times in another unit",
                num(first),
                num(last),
                num(steps),
                num(step),
                if spec.time_step.is_some() { "" } else { " (the smallest gap between training times)" },
                num(MAX_TIME_STEPS)
            ),
        ));
    }
    // Two times whose `t'` round to one 32-bit float are one instant to the network: a time
    // step far beyond the frames' spacing trained every frame as one static field.
    let mut sorted: Vec<f64> = all().collect();
    sorted.sort_by(f64::total_cmp);
    let input = |t: f64| ((t - first) / step) as f32;
    let one_instant = |a: f64, b: f64| input(a) == input(b) || (b - a) / step < MIN_TIME_GAP_STEPS;
    match sorted.windows(2).find(|w| w[0] < w[1] && one_instant(w[0], w[1])) {
        Some(w) => Err(PipelineError::invalid(
            "method.time_step",
            format!(
                "the times {} and {} are {} time steps of Δt = {}{} apart, which the network's time input \
                 t' = (t − t₀)/Δt reads as one instant (they must be at least {} steps apart); give a smaller \
                 time step (--time-step) or the times in another unit",
                num(w[0]),
                num(w[1]),
                num((w[1] - w[0]) / step),
                num(step),
                if spec.time_step.is_some() { "" } else { " (the smallest gap between training times)" },
                num(MIN_TIME_GAP_STEPS)
            ),
        )),
        None => Ok(()),
    }
}

/// The field's input dimension for a time-resolved method: 3 for per-frame static fields, 4
/// for space–time ones.
fn input_dim_of(method: Method) -> usize {
    if method == Method::StaticPerFrame {
        3
    } else {
        4
    }
}

/// The file stem of frame `i` of `count`: `frames/volume_NNN`, numbered with as many digits as
/// the last frame needs and at least three, so that the names sort in the frames' order
/// (`volume_1000` sorted before `volume_101` with three).
fn frame_stem(i: usize, count: usize) -> String {
    let digits = count.saturating_sub(1).to_string().len().max(3);
    format!("frames/volume_{i:0digits$}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::glam::DVec3;
    use fluidnerf_core::{Aabb, Camera, Frame, Intrinsics};

    #[test]
    fn frame_names_sort_in_the_frames_order() {
        assert_eq!(frame_stem(7, 3), "frames/volume_007");
        assert_eq!(frame_stem(999, 1000), "frames/volume_999");
        let mut names: Vec<String> = (0..1001).map(|i| frame_stem(i, 1001)).collect();
        assert_eq!((names[0].as_str(), names[1000].as_str()), ("frames/volume_0000", "frames/volume_1000"));
        let order = names.clone();
        names.sort();
        assert_eq!(names, order);
    }

    /// A scene of one camera at `times` (no files: the window plan reads none).
    fn scene_at(times: &[f64]) -> Scene {
        let k = Intrinsics { width: 8, height: 8, fx: 10.0, fy: 10.0, cx: 3.5, cy: 3.5, skew: 0.0 };
        let camera = Camera::look_at(k, DVec3::new(0.0, 0.0, 5.0), DVec3::ZERO, DVec3::Y);
        let frames = times
            .iter()
            .enumerate()
            .map(|(i, &t)| Frame {
                file_path: format!("images/t{i}.tiff").into(),
                camera: camera.clone(),
                time: Some(t),
                camera_name: None,
                holdout: false,
            })
            .collect();
        Scene {
            root: std::path::PathBuf::new(),
            aabb: Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0)),
            units: "mm".into(),
            intensity_scale: 1.0,
            frames,
            truth: Vec::new(),
        }
    }

    /// `tr-fast` with windows of `frames` overlapping by `overlap`, as given to a front end.
    fn given(frames: Option<usize>, overlap: Option<usize>) -> (RunConfig, GivenWindows<'static>) {
        let mut config = RunConfig::new(std::path::PathBuf::from("scene"), Method::TrFast);
        let MethodConfig::Temporal(_, spec) = &mut config.method else { unreachable!("tr-fast is time-resolved") };
        spec.windows.frames = frames.unwrap_or(spec.windows.frames);
        spec.windows.overlap = overlap.unwrap_or(spec.windows.overlap);
        let names = GivenWindows {
            frames,
            overlap,
            frames_name: "--window",
            overlap_name: "--overlap",
            overlap_from: "the preset's",
        };
        (config, names)
    }

    fn refusal(frames: Option<usize>, overlap: Option<usize>, scene: Option<&Scene>) -> String {
        let (config, names) = given(frames, overlap);
        check_given_windows(&config, scene, &names).expect_err("refused").to_string()
    }

    #[test]
    fn given_window_settings_the_run_would_not_take_are_refused() {
        let three = scene_at(&[0.0, 1.0, 2.0]);
        let e = refusal(Some(3), Some(1), Some(&three));
        assert!(e.starts_with("--overlap 1: windows of 3 frames hold all 3 training frames of the scene in one window"));
        assert!(e.contains("give --window below 3 with it, or leave --overlap out"), "{e}");
        let e = refusal(Some(0), Some(2), None);
        assert!(e.starts_with("--overlap 2: the run trains one field on every frame (windows of 0 frames)"), "{e}");
        let e = refusal(Some(2), Some(1), Some(&scene_at(&[0.0])));
        assert!(e.starts_with("--overlap 1: the scene has a single training frame"), "{e}");
        // tr-fast's own overlap is 4 frames: a window of 3 without an overlap cannot take it.
        let e = refusal(Some(3), None, None);
        assert!(
            e.starts_with(
                "method.windows.overlap: windows of 3 frames would overlap by 4 frames (the preset's overlap, as \
                 --overlap is not given)"
            ) && e.contains("give --overlap below 3 with --window 3"),
            "{e}"
        );
        assert!(refusal(Some(1), None, None).contains("give --overlap 0 with --window 1"));
    }

    #[test]
    fn given_window_settings_the_run_takes_pass() {
        let three = scene_at(&[0.0, 1.0, 2.0]);
        for (frames, overlap) in
            [(Some(2), Some(1)), (Some(3), Some(0)), (None, None), (Some(0), None), (Some(5), None)]
        {
            let (config, names) = given(frames, overlap);
            assert!(check_given_windows(&config, Some(&three), &names).is_ok(), "{frames:?} {overlap:?}");
        }
        // Windows that overlap on the scene pass; without the scene, its frames are not planned over.
        let (config, names) = given(Some(3), Some(1));
        assert!(check_given_windows(&config, None, &names).is_ok());
        // A method that is not time-resolved takes no windows.
        let config = RunConfig::new(std::path::PathBuf::from("scene"), Method::Asart);
        assert!(check_given_windows(&config, Some(&three), &given(Some(3), Some(1)).1).is_ok());
    }
}
