//! Static neural methods (`fluidnerf`, `fast`): a field trained on the scene's images.
//!
//! Writes `weights.safetensors` and `model.json` (what `fluidnerf_neural::trained::
//! load_trained` reads), `checkpoint.safetensors` (weights, Adam state and histories, every
//! `checkpoint_every` iterations and at the end, for resuming), and `volume.npy`/`.vti`, the
//! field sampled at the output resolution. Under held-out early stopping the field of the
//! evaluation with the lowest held-out loss is written; the checkpoint keeps the last state.

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_core::glam::Vec3;
use fluidnerf_core::{Scene, Volume};
use fluidnerf_metrics::{NrmsePoint, TruthSample};
use fluidnerf_neural::train::{
    render_view, train, train_fitting_gains, GainFit, Learner, Prepared, Problem, Split, TrainConfig, View, ViewMasks,
};
use fluidnerf_neural::trained::{build_field, FieldConfig, ModelRecord, WorldField};
use fluidnerf_neural::TrainableField;

use crate::measured::Measured;
use crate::{
    check_memory, finish, peak_rss, write_volume, BestHoldout, Family, GainConfig, GainMode, History, HoldoutPoint,
    HoldoutScore, LossKind, MethodConfig, NeuralDetails, NeuralSpec, PipelineError, RunConfig, RunDir, RunEvent,
    RunReport, Session, StartSpec, StopReason, StopRule, StoppingPolicy, VolumeRecord, REPORT_FORMAT,
};

/// A rough peak-memory estimate of a neural run: images and their ray tables, an iteration's
/// rays (`views` of them drawn from), parameters with optimiser state and per-thread
/// gradients, the output volume and the truth.
pub(crate) fn estimate_memory(
    pixels: u64,
    views: u64,
    params: u64,
    out_voxels: u64,
    truth_voxels: u64,
    threads: u64,
    train: &TrainConfig,
) -> u64 {
    // Saturating: a setting too large for any memory is refused as such, not wrapped round
    // into a small estimate.
    let mul = |factors: &[u64]| factors.iter().fold(1u64, |acc, &f| acc.saturating_mul(f));
    let images = mul(&[pixels, 4 + 4 + 32]);
    let per_pixel = match train.pixel_supersample {
        fluidnerf_neural::train::Supersample::Fixed(s) => mul(&[s as u64, s as u64]),
        fluidnerf_neural::train::Supersample::Auto => 1,
    };
    // Each ray with its pixel, sample span and the values the iteration keeps of it.
    let rays = mul(&[views, train.rays_per_image as u64, per_pixel, 128]);
    let optimiser = mul(&[params, 4, 3u64.saturating_add(threads)]);
    let samples = (train.coarse_samples as u64).saturating_add(train.fine_samples as u64);
    let scratch = mul(&[threads, mul(&[train.chunk_samples as u64, 4, 16]).saturating_add(mul(&[samples, 64]))]);
    // The occupancy grid is carved into one byte per cell, and a copy when it is dilated.
    let occupancy = train
        .occupancy
        .as_ref()
        .map_or(0, |o| mul(&[2, o.resolution as u64, o.resolution as u64, o.resolution as u64]));
    [images, rays, optimiser, scratch, occupancy, mul(&[out_voxels, 4, 2]), mul(&[truth_voxels, 4, 3])]
        .into_iter()
        .fold(0u64, u64::saturating_add)
}

/// The training problem of a scene: its training and held-out views, their images
/// preprocessed and balanced as `gains` asks ([`crate::measured`]), and the masks.
pub(crate) fn problem(
    scene: &Scene,
    gains: &GainConfig,
    temporal: bool,
) -> Result<(Problem, ViewMasks, Measured), PipelineError> {
    let measured = crate::measured::load(scene, gains, temporal)?;
    let images = measured.images.clone();
    let mut masks = ViewMasks::default();
    if measured.masks.iter().any(Option::is_some) {
        for (frame, m) in scene.frames.iter().zip(&measured.masks) {
            if frame.holdout {
                masks.holdout.push(m.clone());
            } else {
                masks.train.push(m.clone());
            }
        }
    }
    let mut problem = Problem {
        aabb: scene.aabb,
        intensity_scale: scene.intensity_scale,
        views: Vec::new(),
        holdout: Vec::new(),
        time_step: 1.0,
    };
    for (frame, image) in scene.frames.iter().zip(images) {
        let view = View { camera: frame.camera.clone(), image, time: frame.time.unwrap_or(0.0) };
        if frame.holdout {
            problem.holdout.push(view);
        } else {
            problem.views.push(view);
        }
    }
    Ok((problem, masks, measured))
}

pub(crate) fn run(
    scene: &Scene,
    config: &RunConfig,
    dir: &RunDir,
    truth: &[(Option<f64>, Volume)],
    session: &mut Session,
) -> Result<RunReport, PipelineError> {
    let MethodConfig::Neural(method, spec) = config.effective_method() else { unreachable!("a neural method") };
    if dir.resuming() && dir.checkpoint().is_dir() {
        return Err(PipelineError::file(
            &dir.checkpoint(),
            "is a folder, not the run's checkpoint: move it away (the run can then only be replaced, --force)",
        ));
    }
    if dir.resuming() && !dir.checkpoint().is_file() {
        return Err(PipelineError::RunDir {
            path: dir.root().to_path_buf(),
            why: "nothing to resume: no checkpoint.safetensors to continue from (the run stopped before its first \
                  checkpoint); use --force to replace it"
                .into(),
        });
    }
    if scene.training_frames().next().is_none() {
        return Err(PipelineError::invalid(
            "scene",
            format!("{}: every frame is held out; nothing to reconstruct from", scene.root.display()),
        ));
    }
    if scene.times().len() > 1 {
        session.warn(&format!(
            "the scene has {} time steps; static training mixes them into one field{}",
            scene.times().len(),
            crate::first_truth_only(scene)
        ));
    }
    if config.stopping.rule == StopRule::HeldOut && scene.holdout_frames().next().is_none() {
        return Err(PipelineError::invalid(
            "stopping.rule",
            "held-out early stopping needs held-out views in the scene (frames with \"holdout\": true)",
        ));
    }
    let field = build_field(&spec.field, &scene.aabb, 3, config.seed)?;
    let num_params = fluidnerf_neural::with_field!(&field, f => f.num_params());
    let pixels: u64 = scene.frames.iter().map(|f| (f.camera.width() * f.camera.height()) as u64).sum();
    let out_dims = Volume::dims_for(&scene.aabb, config.resolution);
    let needed = estimate_memory(
        pixels,
        scene.frames.len() as u64,
        num_params as u64,
        out_dims.iter().map(|&n| n as u64).product(),
        truth.first().map_or(0, |(_, t)| t.len() as u64),
        rayon::current_num_threads() as u64,
        &spec.train,
    );
    check_memory(config, needed, || {
        format!(
            "{method} with {num_params} parameters, {pixels} pixels, {} rays per image and a {out_dims:?} output \
             volume",
            spec.train.rays_per_image
        )
    })?;
    if dir.resuming() {
        crate::rundir::check_resume_settings(dir, config)?;
    }
    // An earlier curve is read before the report that holds it is removed.
    let earlier = if dir.resuming() { earlier_report(dir) } else { None };
    let t0 = Instant::now();
    let (problem, masks, measured) = problem(scene, &config.gains, false)?;
    for warning in &measured.warnings {
        session.warn(warning);
    }
    let prep = Prepared::with_masks(&problem, &spec.train, &masks).map_err(crate::config::training_error)?;
    let setup_s = t0.elapsed().as_secs_f64();
    // Written once everything has been read and checked: a refused run leaves nothing. A
    // resumed run replaces its report and settings once its checkpoint has loaded.
    if !dir.resuming() {
        dir.write_json("config.json", config)?;
    }
    let (rays_kept, rays_on_box) = prep.ray_counts();
    log::info!(
        "{} training views, {} held out; {rays_kept} of {rays_on_box} rays kept, {:.1} % of the box occupied",
        problem.views.len(),
        problem.holdout.len(),
        100.0 * prep.occupied_fraction()
    );
    if spec.train.pixel_supersample == fluidnerf_neural::train::Supersample::Auto {
        let (per_axis, pixels) = spec.train.pixel_rays(prep.noise());
        let noise = prep.noise().map_or("not estimated".into(), |n| format!("{:.2} % of their range", 100.0 * n));
        log::info!("images' noise {noise}: {pixels} pixels per image, {per_axis} × {per_axis} rays each");
    }
    let ctx = Ctx {
        scene,
        config,
        dir,
        truth,
        spec: &spec,
        prep,
        setup_s,
        needed,
        earlier,
        method,
        problem: &problem,
        measured: &measured,
    };
    fluidnerf_neural::with_field!(field, f => ctx.train_and_write(f, session))
}

/// Runs the voxel `method` of a start on `scene` into `path` with `config`'s seed, output grid
/// and gains: its own iteration cap, the held-out rule when `held_out` (otherwise its own
/// rule) and at most `budget_s` seconds, so that a budget rule or a large cap set for the field
/// cannot let it take the whole budget. It reports to a session of its own: the caller's
/// progress and time estimate follow the field. With `reuse` (a resumed run), a start that
/// finished earlier in `path` with the same settings is read back instead of run again.
pub(crate) fn run_voxel_start(
    method: crate::Method,
    scene: &Scene,
    truth: &[(Option<f64>, Volume)],
    config: &RunConfig,
    held_out: bool,
    budget_s: Option<f64>,
    path: &std::path::Path,
    reuse: bool,
    on_event: &mut dyn FnMut(&RunEvent) -> ControlFlow<()>,
) -> Result<RunReport, PipelineError> {
    let mut voxel = RunConfig::new(config.scene.clone(), method);
    voxel.seed = config.seed;
    voxel.resolution = config.resolution;
    voxel.stopping = StoppingPolicy {
        rule: if held_out { StopRule::HeldOut } else { StopRule::Own },
        max_iterations: None,
        time_budget_s: budget_s,
        holdout_every: None,
        patience: config.stopping.patience,
    };
    voxel.gains = config.gains;
    voxel.memory_limit_gib = config.memory_limit_gib;
    voxel.eval_every = Some(0);
    if let Some(report) = Some(path).filter(|_| reuse).and_then(|p| finished_start(p, &voxel, scene)) {
        log::info!("{}: finished earlier with these settings and views; read back", path.display());
        return Ok(report);
    }
    let dir = RunDir::create(path, crate::Overwrite::Force, Some(&scene.root))?;
    let mut inner = Session {
        on_event,
        stopped: false,
        started: Instant::now(),
        cpu0: None,
        budget_s,
        estimate: Default::default(),
        warnings: Vec::new(),
    };
    crate::classical::run(scene, &voxel, &dir, truth, &mut inner)
}

/// The report of the voxel start in `path` when it finished with the settings `voxel`, from the
/// views `scene` holds now (its recorded fingerprint, [`crate::measured::Measured::fingerprint`])
/// and its volumes are all there: deterministic, a run of it again would write the same. A
/// start whose views changed (images or cameras replaced after a run was killed in its start,
/// leaving no checkpoint to check them against) is run again.
fn finished_start(path: &std::path::Path, voxel: &RunConfig, scene: &Scene) -> Option<RunReport> {
    let config: RunConfig = crate::rundir::read_json(&path.join("config.json")).ok()?;
    let report = RunReport::read(&path.join("report.json")).ok()?;
    let complete = report.status == crate::RunStatus::Finished
        && !report.volumes.is_empty()
        && report.volumes.iter().all(|v| path.join(&v.file).is_file());
    if config != *voxel || !complete {
        return None;
    }
    let recorded = report.classical.as_ref()?.views_fingerprint.as_deref()?;
    let measured = crate::measured::load(scene, &voxel.gains, false).ok()?;
    if measured.fingerprint(scene) != recorded {
        log::warn!("{}: made from other images or cameras than the scene's now; run again", path.display());
        return None;
    }
    Some(report)
}

/// Fits `field` to the reconstruction [`StartSpec`] names (running its voxel method first into
/// `start/` when it names no run) and returns the seconds of this run's that took.
fn start_from<F: TrainableField>(
    start: &StartSpec,
    scene: &Scene,
    config: &RunConfig,
    run_dir: &RunDir,
    truth: &[(Option<f64>, Volume)],
    prep: &Prepared,
    field: &mut F,
    session: &mut Session,
) -> Result<f64, PipelineError> {
    let mut seconds = 0.0;
    let path = match &start.run {
        Some(p) => p.clone(),
        None => {
            let path = run_dir.path("start");
            let held_out = config.stopping.rule == StopRule::HeldOut;
            let budget = config.stopping.time_budget_s.map(|b| b / 2.0);
            let (method, why) = start.method.resolve(prep.noise());
            log::info!("start: {why}");
            // Its events go to the caller, who sees its progress and can stop it.
            let reuse = run_dir.resuming();
            let report =
                run_voxel_start(method, scene, truth, config, held_out, budget, &path, reuse, session.on_event)?;
            if report.status == crate::RunStatus::Interrupted {
                session.stopped = true;
            }
            log::info!(
                "{} for the start: {} iterations in {:.1} s, kept {}",
                method,
                report.iterations,
                report.train_time_s,
                report.kept_iteration
            );
            seconds += report.train_time_s;
            path
        }
    };
    if session.stopped {
        // Stopped during the voxel start: the fit would only delay the stop by seconds.
        return Ok(seconds);
    }
    let run = start_run(&path, scene)?;
    let source = run.field()?;
    let target = |_: f64, points: &[Vec3], out: &mut [f32]| source.eval(points, 0.0, out);
    // The fit is the run's work too: it ends with the budget, as the voxel start and the field do.
    let limit = config.stopping.time_budget_s.map(|b| (b - seconds).max(0.0));
    let steps = start.fit.iterations;
    let mut on_step = |step: usize| {
        if step.is_multiple_of(crate::event::START_FIT_EVENT_EVERY) || step == steps {
            session.emit(RunEvent::StartFit { step, steps })
        } else {
            ControlFlow::Continue(())
        }
    };
    let report = fluidnerf_neural::start::fit_to_frames(
        field,
        prep,
        &[(0.0, 0.0)],
        &target,
        &start.fit,
        config.seed,
        limit,
        &mut on_step,
    )
    .map_err(|e| match e {
        // Which run the start was read from: the user's, or the hybrid's own in start/.
        fluidnerf_neural::NeuralError::Invalid { what, why } => {
            fluidnerf_neural::NeuralError::Invalid { what, why: format!("{}: {why}", path.display()) }
        }
        other => other,
    })?;
    log::info!(
        "started from {}: relative RMS difference {:.4} after {} steps ({:.1} s)",
        path.display(),
        report.relative_difference(),
        report.steps,
        report.seconds
    );
    if report.steps < start.fit.iterations && !report.stopped {
        session.warn(&format!(
            "the time budget ended the fit to the start after {} of its {} steps (relative RMS difference {:.4}); \
             a larger time budget gives it all (--time-budget; stopping.time_budget_s in a configuration and from Python)",
            report.steps,
            start.fit.iterations,
            report.relative_difference()
        ));
    }
    Ok(seconds + report.seconds)
}

/// The run a field starts from, refused under `method.start.run` (the key a run names it by)
/// when it is no static run of the scene's box: checked before the run does any work, and again
/// when the field starts from it.
pub(crate) fn start_run(path: &std::path::Path, scene: &Scene) -> Result<crate::load::LoadedRun, PipelineError> {
    let refuse = |why: String| PipelineError::invalid("method.start.run", why);
    let run = crate::load::LoadedRun::open(path, Some(scene.aabb)).map_err(|e| refuse(e.to_string()))?;
    if run.kind == crate::RunKind::Temporal {
        return Err(refuse(format!(
            "{}: a time-resolved run; a static field starts from a static one",
            path.display()
        )));
    }
    if run.aabb != scene.aabb {
        return Err(refuse(format!(
            "{}: its box {:?}–{:?} is not the scene's {:?}–{:?}",
            path.display(),
            run.aabb.min.to_array(),
            run.aabb.max.to_array(),
            scene.aabb.min.to_array(),
            scene.aabb.max.to_array()
        )));
    }
    Ok(run)
}

/// What a resumed run keeps of the report of the run it continues.
fn earlier_report(dir: &RunDir) -> Option<RunReport> {
    let path = dir.report();
    if !path.is_file() {
        return None;
    }
    match RunReport::read(&path) {
        Ok(r) => Some(r),
        Err(e) => {
            log::warn!("the earlier NRMSE curve is not continued: {e}");
            None
        }
    }
}

/// The held-out rule's state when a run is resumed: the earlier report's held-out curve up to
/// the checkpoint replayed through the rule, with the field kept for its best evaluation (the
/// earlier run's `weights.safetensors`). None, with a warning, when the earlier run kept
/// another field (it stopped by another rule): then the rule starts afresh.
fn resumed_best<F: TrainableField>(
    earlier: Option<&RunReport>,
    dir: &RunDir,
    learner: &mut Learner<F>,
    patience: usize,
) -> Option<BestHoldout<Vec<f32>>> {
    let r = earlier?;
    let mut best = BestHoldout::new(patience);
    for p in r.history.holdout.iter().filter(|p| p.iteration <= learner.iteration) {
        best.record(p.iteration, p.loss, Vec::new);
    }
    let (iteration, loss, _) = best.best.as_ref()?;
    if r.stopping.rule != StopRule::HeldOut || r.kept_iteration != *iteration {
        log::warn!(
            "the earlier run kept the field of iteration {}, not that of its best held-out loss (iteration \
             {iteration}); the held-out rule starts afresh from the checkpoint",
            r.kept_iteration
        );
        return None;
    }
    log::info!("resumed held-out rule: best at iteration {iteration} (loss {loss:.3e})");
    // The kept field is read into the learner's, which then gets its checkpoint state back.
    let current = learner.field.params().to_vec();
    let weights = dir.root().join("weights.safetensors");
    let loaded = fluidnerf_neural::weights::load_weights(&weights, &mut learner.field);
    let kept = learner.field.params().to_vec();
    learner.field.params_mut().copy_from_slice(&current);
    if let Err(e) = loaded {
        log::warn!("{}: {e}; the held-out rule starts afresh from the checkpoint", weights.display());
        return None;
    }
    if let Some(b) = best.best.as_mut() {
        b.2 = kept;
    }
    Some(best)
}

/// The held-out rule's state for a run resumed from a checkpoint alone (killed: no report, no
/// kept weights), replayed from the checkpoint's held-out losses: exact when the best
/// evaluation is the checkpoint's own iteration, whose field the learner holds; otherwise that
/// field is lost, and the iteration it was at comes back with None for the rule to start afresh.
fn best_from_checkpoint<F: TrainableField>(
    learner: &Learner<F>,
    patience: usize,
) -> (Option<BestHoldout<Vec<f32>>>, Option<usize>) {
    let mut best = BestHoldout::new(patience);
    for &(iteration, loss) in learner.holdout_losses.iter().filter(|p| p.0 <= learner.iteration) {
        best.record(iteration, f64::from(loss), Vec::new);
    }
    match best.best.as_mut() {
        None => (None, None),
        Some(b) if b.0 == learner.iteration => {
            b.2 = learner.field.params().to_vec();
            log::info!("resumed held-out rule from the checkpoint: best at iteration {} (loss {:.3e})", b.0, b.1);
            (Some(best), None)
        }
        Some(b) => (None, Some(b.0)),
    }
}

struct Ctx<'a> {
    scene: &'a Scene,
    config: &'a RunConfig,
    dir: &'a RunDir,
    truth: &'a [(Option<f64>, Volume)],
    spec: &'a NeuralSpec,
    prep: Prepared,
    problem: &'a Problem,
    measured: &'a Measured,
    setup_s: f64,
    needed: u64,
    earlier: Option<RunReport>,
    method: crate::Method,
}

impl Ctx<'_> {
    fn train_and_write<F: TrainableField>(self, field: F, session: &mut Session) -> Result<RunReport, PipelineError> {
        let (config, dir) = (self.config, self.dir);
        let mut prep = self.prep;
        let mut train_cfg = &self.spec.train;
        let mut learner = Learner::fresh(field, &prep, train_cfg);
        let ckpt = dir.checkpoint();
        let mut budgeted;
        // Before any gain is fitted (the fingerprint reads the measured pixels either way).
        let views = prep.fingerprint();
        let settings = settings_tag(config)?;
        if dir.resuming() {
            check_checkpoint(&ckpt, &self.scene.aabb, &self.spec.field, &settings, &views)?;
        }
        // A run stopped during its field's start has no training to continue: it starts again.
        let restart = dir.resuming() && self.spec.start.is_some() && checkpoint_start_unfinished(&ckpt)?;
        if restart {
            log::warn!(
                "{} was stopped during its start, before its field trained: there is no training to continue, so \
                 the run starts again from its start",
                dir.root().display()
            );
            dir.replace_finished(config)?;
        }
        let mut start_unfinished = false;
        if dir.resuming() && !restart {
            fluidnerf_neural::weights::load_checkpoint(&ckpt, &mut learner)?;
            // A resumed run only continues: below the checkpoint's iteration it would keep the
            // result of the longer run and record the lower cap in config.json, which reruns
            // to another result.
            if learner.iteration > train_cfg.max_iterations {
                return Err(PipelineError::invalid(
                    "stopping.max_iterations",
                    format!(
                        "{} is at iteration {}, beyond the cap of {} asked for; a resumed run only continues, so \
                         give --max-iterations of at least {} (or start afresh with --force)",
                        ckpt.display(),
                        learner.iteration,
                        train_cfg.max_iterations,
                        learner.iteration
                    ),
                ));
            }
            // The time budget bounds the run's whole training (its start's included), as in a
            // run without a break, so that config.json reruns it: the time the checkpoint has
            // trained is spent.
            budgeted = train_cfg.clone();
            if let Some(b) = budgeted.time_budget_s {
                if learner.train_time_s >= b {
                    return Err(PipelineError::invalid(
                        "stopping.time_budget_s",
                        format!(
                            "{} has trained for {:.1} s, the whole time budget of {} s asked for; a resumed run \
                             only continues, within the budget of the whole run, so give a --time-budget above \
                             {:.1} s",
                            ckpt.display(),
                            learner.train_time_s,
                            fluidnerf_core::num(b),
                            learner.train_time_s
                        ),
                    ));
                }
                budgeted.time_budget_s = Some(b - learner.train_time_s);
            }
            // A field started from a volume trains at the start's lower rate throughout, after a
            // break too.
            if let Some(start) = &self.spec.start {
                budgeted.schedule.initial *= start.learning_rate_scale;
                budgeted.schedule.at_decay_iters *= start.learning_rate_scale;
            }
            train_cfg = &budgeted;
            dir.replace_finished(config)?;
            log::info!("resuming at iteration {}", learner.iteration);
        } else if let Some(start) = &self.spec.start {
            let seconds = start_from(start, self.scene, config, dir, self.truth, &prep, &mut learner.field, session)?;
            start_unfinished = session.stopped;
            // Its time is the run's: the curves of NRMSE against time start after it.
            learner.train_time_s += seconds;
            budgeted = train_cfg.clone();
            budgeted.schedule.initial *= start.learning_rate_scale;
            budgeted.schedule.at_decay_iters *= start.learning_rate_scale;
            // The start is part of the run's work: it counts against the time budget.
            if let Some(b) = budgeted.time_budget_s {
                budgeted.time_budget_s = Some((b - seconds).max(1e-3));
            }
            train_cfg = &budgeted;
        }
        let sample = self.truth.first().map(|(_, t)| TruthSample::new(t));
        let eval_every = config.eval_interval();
        // Copies, so that gain fitting may change the prepared targets while these are held.
        let (meta, occupancy) = (prep.meta.clone(), prep.occupancy().cloned());
        let nrmse_of =
            |field: &F, s: &TruthSample| s.nrmse(&WorldField { field, meta: &meta, occupancy: occupancy.as_ref() });
        // A resumed run continues the curves of the run it resumes, up to the checkpoint.
        let (mut nrmse_history, mut holdout_history) = match self.earlier.as_ref().filter(|_| !restart) {
            Some(r) => (
                r.history.nrmse.iter().filter(|p| p.iteration <= learner.iteration).copied().collect(),
                r.history.holdout.iter().filter(|p| p.iteration <= learner.iteration).copied().collect(),
            ),
            // A run killed without a report: its checkpoint's own held-out losses.
            None if dir.resuming() && !restart => (
                Vec::new(),
                learner
                    .holdout_losses
                    .iter()
                    .map(|&(iteration, loss)| HoldoutPoint { iteration, loss: f64::from(loss), train_time_s: None })
                    .collect(),
            ),
            None => (Vec::new(), Vec::new()),
        };
        let held_out_rule = config.stopping.rule == StopRule::HeldOut;
        let mut best = match (held_out_rule, dir.resuming() && !restart, self.earlier.as_ref()) {
            (true, true, Some(_)) => resumed_best(self.earlier.as_ref(), dir, &mut learner, config.stopping.patience),
            (true, true, None) => {
                let (best, lost) = best_from_checkpoint(&learner, config.stopping.patience);
                if let Some(at) = lost {
                    session.warn(&format!(
                        "the run resumed was stopped without its results (killed) after its best held-out loss, at \
                         iteration {at}, and its checkpoint holds the field of iteration {}: that field is lost, so \
                         the held-out rule starts afresh from the checkpoint and may keep a later, worse one; rerun \
                         with --force for the uninterrupted result",
                        learner.iteration
                    ));
                }
                best
            }
            _ => None,
        }
        .unwrap_or_else(|| BestHoldout::new(config.stopping.patience));
        let mut cause = None;
        let mut ckpt_error = None;
        let mut eval_s = 0.0;
        let _ = session.emit(RunEvent::Started {
            method: self.method,
            max_iterations: train_cfg.max_iterations,
            windows: 1,
            start_iteration: learner.iteration,
        });
        let on_iter = |s: &fluidnerf_neural::train::TrainState<F>| {
            let t_eval = Instant::now();
            let mut out_of_patience = false;
            if let Some(h) = s.holdout_loss {
                holdout_history.push(HoldoutPoint {
                    iteration: s.iteration,
                    loss: h as f64,
                    train_time_s: Some(s.train_time_s),
                });
                if held_out_rule {
                    out_of_patience = best.record(s.iteration, h as f64, || s.field.params().to_vec());
                }
            }
            let nrmse = match &sample {
                Some(t) if eval_every > 0 && s.iteration.is_multiple_of(eval_every) => {
                    let n = nrmse_of(s.field, t);
                    nrmse_history.push(NrmsePoint { iteration: s.iteration, train_time_s: s.train_time_s, nrmse: n });
                    Some(n)
                }
                _ => None,
            };
            eval_s += t_eval.elapsed().as_secs_f64();
            let mut flow = session.emit(RunEvent::Iteration {
                window: None,
                iteration: s.iteration,
                loss: s.loss as f64,
                smoothed: Some(s.smoothed_loss as f64),
                train_time_s: s.train_time_s,
            });
            if nrmse.is_some() || s.holdout_loss.is_some() {
                let evaluation = RunEvent::Evaluation {
                    window: None,
                    iteration: s.iteration,
                    nrmse,
                    holdout: s.holdout_loss.map(f64::from),
                };
                if session.emit(evaluation).is_break() {
                    flow = ControlFlow::Break(());
                }
            }
            if config.checkpoint_every > 0 && s.iteration.is_multiple_of(config.checkpoint_every) {
                match write_checkpoint(
                    dir,
                    s.learner,
                    &self.scene.aabb,
                    &self.spec.field,
                    &settings,
                    &views,
                    start_unfinished,
                ) {
                    Ok(path) => {
                        let _ = session.emit(RunEvent::Checkpoint { path: &path });
                    }
                    Err(e) => {
                        ckpt_error = Some(e);
                        return ControlFlow::Break(());
                    }
                }
            }
            // `stopped` also holds a stop asked for during the voxel start.
            if flow.is_break() || session.stopped {
                cause = Some(StopReason::Interrupted);
            } else if out_of_patience {
                cause = Some(StopReason::HeldOutPatience);
            }
            if cause.is_some() {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        };
        let (report, fitted) = if self.measured.mode == GainMode::Fit {
            let fit = GainFit {
                every: config.gains.interval(Family::Neural),
                rays_per_view: 2048,
                offset: config.gains.offset,
            };
            let (r, g) = train_fitting_gains(&mut prep, &mut learner, train_cfg, config.seed, &fit, on_iter)?;
            let scale = prep.image_scale();
            log::info!("fitted gains: {}", g.iter().map(|(g, _)| format!("{g:.3}")).collect::<Vec<_>>().join(", "));
            (r, Some(g.iter().map(|&(g, b)| (g as f64, b as f64 * scale)).collect::<Vec<_>>()))
        } else {
            (train(&prep, &mut learner, train_cfg, config.seed, on_iter)?, None)
        };
        let prep = &prep;
        if let Some(e) = ckpt_error {
            return Err(e);
        }
        let _ = session.emit(RunEvent::Writing);
        // The checkpoint holds the last state, so a resumed run continues where this one stopped.
        write_checkpoint(dir, &learner, &self.scene.aabb, &self.spec.field, &settings, &views, start_unfinished)?;
        let stop_reason = cause.unwrap_or(report.stop_reason.into());
        if start_unfinished {
            let own = dir.path("start").join("volume.npy");
            let kept = if self.spec.start.as_ref().is_some_and(|s| s.run.is_none()) && own.is_file() {
                format!("; the voxel start's volume is {}", own.display())
            } else {
                String::new()
            };
            session.warn(&format!(
                "stopped during the field's start, before it trained: volume.npy is the field before training, not a \
                 reconstruction{kept}; `reconstruct -o {} --resume` (`overwrite=\"resume\"` from Python) runs the \
                 start again",
                dir.root().display()
            ));
        }
        let mut kept_iteration = learner.iteration;
        if let Some((iteration, loss, params)) = best.best.take() {
            learner.field.params_mut().copy_from_slice(&params);
            kept_iteration = iteration;
            log::info!("keeping the field of iteration {iteration} (held-out loss {loss:.3e})");
        }
        let weights = fluidnerf_neural::weights::weights_bytes(&learner.field)?;
        dir.write_bytes("weights.safetensors", &weights)?;
        dir.write_json(
            "model.json",
            &ModelRecord {
                field: self.spec.field.clone(),
                input_dim: learner.field.input_dim(),
                meta: prep.meta.clone(),
            },
        )?;

        let t_eval = Instant::now();
        let holdout_scores =
            holdout_scores(self.scene, self.problem, self.measured, prep, &learner.field, train_cfg, config.seed);
        let world = WorldField { field: &learner.field, meta: &prep.meta, occupancy: prep.occupancy() };
        let dims = Volume::dims_for(&self.scene.aabb, config.resolution);
        let volume = Volume::from_field(dims, self.scene.aabb, &world, 0.0);
        write_volume(dir, "volume", &volume, None)?;
        if let Some(w) = crate::empty_field_warning(self.problem, volume.min_max().1, train_cfg) {
            session.warn(&w);
        }
        let metrics = match self.truth.first() {
            Some((time, t)) => {
                // The field at the truth's voxel centres, as the dissertation interrogates it.
                let v = if volume.dims == t.dims && volume.aabb == t.aabb {
                    volume.clone()
                } else {
                    Volume::from_field(t.dims, t.aabb, &world, 0.0)
                };
                Some(fluidnerf_metrics::evaluate_volume(&v, t, *time, &crate::metric_options(self.scene, self.truth)?)?)
            }
            None => None,
        };
        if let Some(s) = &sample {
            if kept_iteration == learner.iteration && nrmse_history.last().is_none_or(|p| p.iteration != kept_iteration)
            {
                nrmse_history.push(NrmsePoint {
                    iteration: learner.iteration,
                    train_time_s: learner.train_time_s,
                    nrmse: nrmse_of(&learner.field, s),
                });
            }
        }
        eval_s += t_eval.elapsed().as_secs_f64();
        let report = RunReport {
            format: REPORT_FORMAT,
            fluidnerf_version: env!("CARGO_PKG_VERSION").to_string(),
            method: self.method,
            aabb: self.scene.aabb,
            units: self.scene.units.clone(),
            status: stop_reason.status(),
            stop_reason,
            stopping: config.stopping,
            stopping_rule: config.stopping.describe(Family::Neural),
            iterations: learner.iteration,
            kept_iteration,
            setup_s: self.setup_s,
            train_time_s: learner.train_time_s,
            eval_s,
            cpu_s: session.cpu_s(),
            peak_rss_bytes: peak_rss(),
            memory_estimate_bytes: self.needed,
            result_bytes: weights.len() as u64,
            history: History {
                loss_kind: Some(LossKind::TrainingMse),
                loss: learner.losses.iter().map(|&l| l as f64).collect(),
                holdout: holdout_history,
                nrmse: nrmse_history,
                eval_every,
            },
            final_nrmse: metrics.as_ref().map(|m| m.global.nrmse),
            final_ssim_global: metrics.as_ref().map(|m| m.global.ssim_global),
            volumes: vec![VolumeRecord {
                file: "volume.npy".into(),
                time: None,
                trained: true,
                dims,
                metrics,
                digest: None,
            }],
            not_reached: Vec::new(),
            classical: None,
            neural: Some(NeuralDetails {
                preset: self.spec.preset.clone(),
                num_params: learner.field.num_params(),
                weights_bytes: weights.len(),
                image_scale: prep.image_scale(),
                occupied_fraction: prep.occupied_fraction(),
                rays_kept: prep.ray_counts().0,
                rays_on_box: prep.ray_counts().1,
                train: report,
            }),
            windows: Vec::new(),
            preprocessing: Some(self.measured.report(self.scene, fitted.as_deref(), &holdout_scores)),
            warnings: Vec::new(),
        };
        finish(self.scene, dir, report, self.truth, Some(self.measured), session)
    }
}

/// Every held-out frame (frame index, in order) scored against the field's rendering of its
/// kept rays, as measured and after the best-fit gain.
fn holdout_scores<F: TrainableField>(
    scene: &Scene,
    problem: &Problem,
    measured: &Measured,
    prep: &Prepared,
    field: &F,
    cfg: &TrainConfig,
    seed: u64,
) -> Vec<(usize, HoldoutScore)> {
    let held: Vec<usize> = scene.holdout_frames().map(|(i, _)| i).collect();
    let scale = prep.image_scale() as f32;
    held.iter()
        .enumerate()
        .filter(|(v, _)| !prep.views(Split::Holdout)[*v].rays().is_empty())
        .map(|(v, &frame)| {
            let pixels = render_view(field, prep, cfg, Split::Holdout, v, seed);
            // Pixels whose ray misses the box render as 0 and are measured as they are.
            let image = &problem.holdout[v].image;
            let mut rendered = vec![0f32; image.data.len()];
            for (p, r, _) in pixels {
                rendered[p as usize] = r * scale;
            }
            (frame, crate::measured::holdout_score(&image.data, &rendered, measured.masks[frame].as_deref()))
        })
        .collect()
}

/// The checkpoint tag of the box a field was trained in: its coordinates are the box's, so a
/// scene whose box changed cannot continue it.
const BOX_TAG: &str = "aabb";

fn box_tag(aabb: &fluidnerf_core::Aabb) -> String {
    format!("{:?}", [aabb.min.to_array(), aabb.max.to_array()])
}

/// The checkpoint tag of the field's configuration (JSON): its parameters are that field's, and
/// another one of the same tensor shapes (another activation, scale or hash) would take them
/// without a word.
const FIELD_TAG: &str = "field";

fn field_tag(field: &FieldConfig) -> Result<String, PipelineError> {
    serde_json::to_string(field).map_err(|e| PipelineError::invalid("method.field", e.to_string()))
}

/// The checkpoint tag of the fingerprint of the views a field was trained on
/// ([`fluidnerf_neural::train::Prepared::fingerprint`]): their images and cameras.
const VIEWS_TAG: &str = "views";

/// The checkpoint tag of the run's training settings ([`crate::rundir::training_settings`]).
const SETTINGS_TAG: &str = "settings";

/// The checkpoint tag of a field whose start (the voxel method run first, or the fit of the
/// field to it) was stopped before it finished, with the value [`START_UNFINISHED`]. Such a
/// field has not begun the training a resume continues: continued, it would train from an
/// unfitted field at the start's lower learning rate, a run its `config.json` does not describe.
/// A resume starts such a run again.
pub(crate) const START_TAG: &str = "start";

/// The value of [`START_TAG`].
const START_UNFINISHED: &str = "unfinished";

/// Whether the checkpoint at `path` is of a field whose start did not finish ([`START_TAG`]).
pub(crate) fn checkpoint_start_unfinished(path: &std::path::Path) -> Result<bool, PipelineError> {
    Ok(fluidnerf_neural::weights::checkpoint_tag(path, START_TAG)?.as_deref() == Some(START_UNFINISHED))
}

/// The training settings of `config` as a checkpoint records them.
fn settings_tag(config: &RunConfig) -> Result<String, PipelineError> {
    crate::rundir::training_settings(config).map(|v| v.to_string()).map_err(|e| PipelineError::invalid("config", e))
}

/// Writes a training checkpoint (weights, optimiser state, histories, the scene's box, the
/// field's configuration, the run's training settings and the fingerprint of the training
/// views, and whether the field's start was stopped before it finished) atomically.
pub(crate) fn write_checkpoint<F: TrainableField>(
    dir: &RunDir,
    learner: &Learner<F>,
    aabb: &fluidnerf_core::Aabb,
    field: &FieldConfig,
    settings: &str,
    views: &str,
    start_unfinished: bool,
) -> Result<std::path::PathBuf, PipelineError> {
    let tags = vec![(BOX_TAG, box_tag(aabb)), (FIELD_TAG, field_tag(field)?), (SETTINGS_TAG, settings.to_string())];
    write_tagged(dir, "checkpoint.safetensors", learner, tags, views, start_unfinished)
}

/// Refuses to continue a checkpoint trained in another box than the scene's now, as another
/// field than the settings now describe, with other training settings than the run's
/// `config.json` (`settings`, [`settings_tag`]: the file was edited after the checkpoint was
/// written, or the checkpoint is another run's), or on other images or cameras (a checkpoint
/// written before the field, the settings or the views' fingerprint was recorded is not checked
/// for them).
fn check_checkpoint(
    path: &std::path::Path,
    aabb: &fluidnerf_core::Aabb,
    field: &FieldConfig,
    settings: &str,
    views: &str,
) -> Result<(), PipelineError> {
    if let Some(saved) = fluidnerf_neural::weights::checkpoint_tag(path, BOX_TAG)?.filter(|s| *s != box_tag(aabb)) {
        return Err(PipelineError::file(
            path,
            format!(
                "was trained in the box {saved}, but the scene's box is now {}; the field's coordinates are \
                 the box's, so it cannot be continued: restore the scene's aabb, or start a new run (--force)",
                box_tag(aabb)
            ),
        ));
    }
    if let Some(differences) = tag_differences(path, FIELD_TAG, &field_tag(field)?, "field is")? {
        return Err(PipelineError::file(
            path,
            format!(
                "was trained as another field than the run's settings now describe ({differences}); its parameters \
                 are that field's: restore the field's settings in config.json (or give the run's own), or start a \
                 new run (--force)"
            ),
        ));
    }
    if let Some(differences) = tag_differences(path, SETTINGS_TAG, settings, "settings are")? {
        return Err(PipelineError::file(
            path,
            format!(
                "was written by a run trained with other settings than the run's config.json records \
                 ({differences}): config.json was edited after the checkpoint was written, or the checkpoint is \
                 another run's; a resumed run only continues the run it holds: restore the settings it was \
                 trained with, or start a new run (--force)"
            ),
        ));
    }
    check_views(path, || Ok(views.to_string()))
}

/// How the JSON the checkpoint `path` records under `tag` differs from `now` (as
/// [`crate::rundir::settings_differences`] lists it); None when it records none or the same.
/// `what` names the record, with its verb, in the error of one that is not JSON.
fn tag_differences(path: &std::path::Path, tag: &str, now: &str, what: &str) -> Result<Option<String>, PipelineError> {
    let Some(saved) = fluidnerf_neural::weights::checkpoint_tag(path, tag)?.filter(|s| s != now) else {
        return Ok(None);
    };
    let saved: serde_json::Value = serde_json::from_str(&saved)
        .map_err(|e| PipelineError::file(path, format!("its recorded {what} not JSON: {e}")))?;
    let now: serde_json::Value = serde_json::from_str(now).unwrap_or_default();
    Ok(Some(crate::rundir::settings_differences(&saved, &now, 5)))
}

/// Refuses to continue a checkpoint whose recorded fingerprint of its training views differs
/// from `views()`, the fingerprint of the views it would continue on (computed only for a
/// checkpoint that records one: one written before it was recorded is not checked).
pub(crate) fn check_views(
    path: &std::path::Path,
    views: impl FnOnce() -> Result<String, PipelineError>,
) -> Result<(), PipelineError> {
    let Some(saved) = fluidnerf_neural::weights::checkpoint_tag(path, VIEWS_TAG)? else {
        return Ok(());
    };
    if saved != views()? {
        return Err(PipelineError::file(
            path,
            "was trained on other images or cameras than the scene's now, or on pixels picked or scaled otherwise \
             (the fingerprint of its training views differs: an image, mask or camera changed, or a setting that \
             picks or scales the pixels, such as the empty-space hull or the image scale); a run continues only \
             on the views it started with: restore them, or start a new run (--force)",
        ));
    }
    Ok(())
}

/// Writes the checkpoint `name` of the run folder (training state, the fingerprint of the views
/// trained on, `views`, and whether the window's start was stopped before it finished,
/// [`START_TAG`]) atomically.
pub(crate) fn write_checkpoint_to<F: TrainableField>(
    dir: &RunDir,
    name: &str,
    learner: &Learner<F>,
    views: &str,
    start_unfinished: bool,
) -> Result<std::path::PathBuf, PipelineError> {
    write_tagged(dir, name, learner, Vec::new(), views, start_unfinished)
}

/// Writes the checkpoint `name` with the tags `tags`, then the views' fingerprint and, when
/// `start_unfinished`, [`START_TAG`]: what every checkpoint records, static or a window's.
fn write_tagged<F: TrainableField>(
    dir: &RunDir,
    name: &str,
    learner: &Learner<F>,
    mut tags: Vec<(&str, String)>,
    views: &str,
    start_unfinished: bool,
) -> Result<std::path::PathBuf, PipelineError> {
    tags.push((VIEWS_TAG, views.to_string()));
    if start_unfinished {
        tags.push((START_TAG, START_UNFINISHED.to_string()));
    }
    dir.write_bytes(name, &fluidnerf_neural::weights::checkpoint_bytes_tagged(learner, &tags)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Settings too large for any memory give an estimate no memory holds, not one wrapped
    /// round to a few bytes that lets the run start and abort.
    #[test]
    fn the_memory_estimate_saturates_instead_of_wrapping() {
        let mut train = TrainConfig { chunk_samples: 1 << 60, ..TrainConfig::default() };
        assert_eq!(estimate_memory(1024, 4, 1000, 512, 0, 2, &train), u64::MAX);
        train.chunk_samples = 256;
        train.rays_per_image = usize::MAX;
        assert_eq!(estimate_memory(1024, 4, 1000, 512, 0, 2, &train), u64::MAX);
        train.rays_per_image = 1024;
        assert!(estimate_memory(1024, 4, 1000, 512, 0, 2, &train) < 1 << 30);
    }
}
