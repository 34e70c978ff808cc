//! Voxel methods (ASART, ART, SART, MART, SMART, MLEM, SART-TV, SART-Tikhonov) on the scene's
//! training views.
//!
//! The NRMSE curve is evaluated over the same subset of the truth's voxel centres as the
//! neural methods' ([`TruthSample`], the volume sampled trilinearly); `train_time_s` is the
//! solver's time with the evaluations taken out. Under held-out early stopping the held-out
//! views are forward-projected after every `holdout_every`-th iteration and the volume with
//! the lowest relative held-out misfit `‖p − A g‖² / ‖p‖²` is kept.

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_classical::{voxel_footprint_px, Grid, Problem, Projector, ProjectorConfig, ProjectorKind};
use fluidnerf_core::{Image, Scene, Volume};
use fluidnerf_metrics::{NrmsePoint, TruthSample, VolumeMetricOptions};

use crate::{
    check_memory, finish, peak_rss, write_volume, BestHoldout, ClassicalDetails, Family, History, HoldoutPoint,
    LossKind, MethodConfig, PipelineError, RunConfig, RunDir, RunEvent, RunReport, Session, StopReason, StopRule,
    VolumeRecord, REPORT_FORMAT,
};

pub(crate) fn run(
    scene: &Scene,
    config: &RunConfig,
    dir: &RunDir,
    truth: &[(Option<f64>, Volume)],
    session: &mut Session,
) -> Result<RunReport, PipelineError> {
    let MethodConfig::Classical(spec) = config.effective_method() else { unreachable!("a voxel method") };
    let method = config.method();
    if dir.resuming() {
        session.warn("voxel methods keep no checkpoints; this run starts afresh");
    }
    if scene.times().len() > 1 {
        session.warn(&format!(
            "the scene has {} time steps; a voxel reconstruction mixes them into one volume",
            scene.times().len()
        ));
    }
    let grid = Grid::with_resolution(scene.aabb, config.resolution);
    let cameras: Vec<_> = scene.training_frames().map(|(_, f)| f.camera.clone()).collect();
    if cameras.is_empty() {
        return Err(PipelineError::invalid(
            "scene",
            format!("{}: every frame is held out; nothing to reconstruct from", scene.root.display()),
        ));
    }
    let holdout_cameras: Vec<_> = scene.holdout_frames().map(|(_, f)| f.camera.clone()).collect();
    let held_out_rule = config.stopping.rule == StopRule::HeldOut;
    if held_out_rule && holdout_cameras.is_empty() {
        return Err(PipelineError::invalid(
            "stopping.rule",
            "held-out early stopping needs held-out views in the scene (frames with \"holdout\": true)",
        ));
    }
    let threads = rayon::current_num_threads();
    let estimate = spec.method.memory(&spec.projector, &grid, &cameras, threads);
    // Scoring holds the truth, a resampled copy and temporaries; the curve a copy of the volume.
    let truth_bytes: u64 = truth.first().map_or(0, |(_, t)| 3 * 4 * t.len() as u64 + 4 * grid.len() as u64);
    let needed = estimate.total() + truth_bytes;
    check_memory(config, needed, || format!("{method} at {:?} voxels with {} views", grid.dims, cameras.len()))?;
    let t_setup = Instant::now();
    let all_images = fluidnerf_io::scene::load_images(scene)?;
    let (mut images, mut holdout_images) = (Vec::new(), Vec::new());
    for (f, im) in scene.frames.iter().zip(all_images) {
        if f.holdout {
            holdout_images.push(im);
        } else {
            images.push(im);
        }
    }
    let subdivisions = spec.projector.subdivisions(&grid, &cameras);
    // `auto` resolved once, so the held-out views and the report use the same projector.
    let kind = spec.projector.resolve(&grid, &cameras);
    let resolved = ProjectorConfig { kind, ..spec.projector.clone() };
    let projector = resolved.build(grid, &cameras, scene.intensity_scale)?;
    let footprint_px = voxel_footprint_px(&cameras, &grid);
    if kind == ProjectorKind::Splat && footprint_px / subdivisions as f64 > 2.0 {
        session.warn(&format!(
            "voxels cover about {footprint_px:.1} pixels and are split into only {subdivisions}³: the splat leaves \
             gaps; raise splat_subdivisions (0: automatic) or use the ray projector"
        ));
    }
    let support = spec.projector.support(&grid, &cameras, &images);
    let hull_voxels = support.as_ref().map(|h| h.iter().filter(|&&b| b).count());
    let mut problem = Problem::new(projector.as_ref(), &images)?;
    if let Some(h) = &support {
        problem = problem.with_support(h);
    }
    let holdout = if held_out_rule {
        let fixed = ProjectorConfig { splat_subdivisions: subdivisions, ..resolved.clone() };
        Some(HoldoutScorer::new(fixed.build(grid, &holdout_cameras, scene.intensity_scale)?, holdout_images))
    } else {
        None
    };
    let setup_s = t_setup.elapsed().as_secs_f64();
    // Written once everything has been read and checked: a refused run leaves nothing.
    dir.write_json("config.json", config)?;

    let eval_every = config.eval_interval();
    let holdout_every = config.stopping.holdout_interval(Family::Classical);
    let mut curve = truth.first().map(|(_, t)| Curve::new(t, grid));
    let mut best = BestHoldout::<Vec<f32>>::new(config.stopping.patience);
    let mut holdout_history = Vec::new();
    let mut cause = None;
    let mut eval_s = 0.0;
    let cap = spec.method.stopping().max_iterations;
    let _ = session.emit(RunEvent::Started { method, max_iterations: cap, windows: 1, start_iteration: 0 });
    let budget = config.stopping.time_budget_s;
    let t_solve = Instant::now();
    let result = spec.method.solve(&problem, None, |s| {
        let train_time_s = t_solve.elapsed().as_secs_f64() - eval_s;
        let t_eval = Instant::now();
        let nrmse = match curve.as_mut() {
            Some(c) if eval_every > 0 && s.iteration % eval_every == 0 => {
                Some(c.push(s.iteration, train_time_s, s.volume))
            }
            _ => None,
        };
        let mut out_of_patience = false;
        let held = match &holdout {
            Some(h) if s.iteration % holdout_every == 0 => {
                let loss = h.loss(s.volume);
                holdout_history.push(HoldoutPoint { iteration: s.iteration, loss });
                out_of_patience = best.record(s.iteration, loss, || s.volume.to_vec());
                Some(loss)
            }
            _ => None,
        };
        eval_s += t_eval.elapsed().as_secs_f64();
        let iteration = RunEvent::Iteration {
            window: None,
            iteration: s.iteration,
            loss: s.residual,
            smoothed: None,
            train_time_s,
        };
        let mut flow = session.emit(iteration);
        if nrmse.is_some() || held.is_some() {
            let evaluation = RunEvent::Evaluation { window: None, iteration: s.iteration, nrmse, holdout: held };
            if session.emit(evaluation).is_break() {
                flow = ControlFlow::Break(());
            }
        }
        if flow.is_break() {
            cause = Some(StopReason::Interrupted);
        } else if out_of_patience {
            cause = Some(StopReason::HeldOutPatience);
        } else if budget.is_some_and(|b| train_time_s >= b) {
            cause = Some(StopReason::TimeBudget);
        }
        if cause.is_some() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    })?;
    let train_time_s = t_solve.elapsed().as_secs_f64() - eval_s;
    let _ = session.emit(RunEvent::Writing);
    let stop_reason = cause.unwrap_or(result.stop_reason.into());
    let iterations = result.iterations;
    let (kept_iteration, data) = match best.best.take() {
        Some((it, _, v)) => (it, v),
        None => (iterations, result.volume),
    };
    let volume = grid.volume(data);
    write_volume(dir, "volume", &volume)?;

    let t_eval = Instant::now();
    let metrics = match truth.first() {
        Some((time, t)) => {
            Some(fluidnerf_metrics::evaluate_volume(&volume, t, *time, &VolumeMetricOptions::default())?)
        }
        None => None,
    };
    let mut nrmse_history = curve.map(|c| c.points).unwrap_or_default();
    if let Some(c) = truth.first().map(|(_, t)| TruthSample::new(t)) {
        if nrmse_history.last().is_none_or(|p| p.iteration != iterations) && kept_iteration == iterations {
            nrmse_history.push(NrmsePoint { iteration: iterations, train_time_s, nrmse: c.nrmse(&volume) });
        }
    }
    eval_s += t_eval.elapsed().as_secs_f64();
    let spacing = grid.spacing();
    let report = RunReport {
        format: REPORT_FORMAT,
        fluidnerf_version: env!("CARGO_PKG_VERSION").to_string(),
        method,
        aabb: scene.aabb,
        units: scene.units.clone(),
        status: stop_reason.status(),
        stop_reason,
        stopping: config.stopping,
        stopping_rule: config.stopping.describe(Family::Classical),
        iterations,
        kept_iteration,
        setup_s,
        train_time_s,
        eval_s,
        cpu_s: session.cpu_s(),
        peak_rss_bytes: peak_rss(),
        memory_estimate_bytes: needed,
        result_bytes: std::fs::metadata(dir.volume()).map(|m| m.len()).unwrap_or(0),
        history: History {
            loss_kind: Some(LossKind::RelativeResidual),
            loss: result.residual_history,
            holdout: holdout_history,
            nrmse: nrmse_history,
            eval_every,
        },
        final_nrmse: metrics.as_ref().map(|m| m.global.nrmse),
        final_ssim_global: metrics.as_ref().map(|m| m.global.ssim_global),
        volumes: vec![VolumeRecord { file: "volume.npy".into(), time: None, trained: true, dims: grid.dims, metrics }],
        classical: Some(ClassicalDetails {
            projector: kind,
            splat_subdivisions: (kind == ProjectorKind::Splat).then_some(subdivisions),
            voxel_size: [spacing.x, spacing.y, spacing.z],
            views: cameras.len(),
            pixels: cameras.iter().map(|c| c.width() * c.height()).sum(),
            hull_voxels,
            memory_estimate: estimate,
        }),
        neural: None,
        windows: Vec::new(),
    };
    log::debug!("{method}: {:.1} s in all", session.elapsed_s());
    finish(scene, dir, report, truth, session)
}

/// The NRMSE curve: evaluations over a [`TruthSample`] of the solver's volume.
struct Curve {
    sample: TruthSample,
    /// The solver's volume, copied for trilinear sampling at the truth's voxel centres.
    scratch: Volume,
    points: Vec<NrmsePoint>,
}

impl Curve {
    fn new(truth: &Volume, grid: Grid) -> Self {
        Curve { sample: TruthSample::new(truth), scratch: grid.volume(vec![0.0; grid.len()]), points: Vec::new() }
    }

    fn push(&mut self, iteration: usize, train_time_s: f64, volume: &[f32]) -> f64 {
        self.scratch.data.copy_from_slice(volume);
        let nrmse = self.sample.nrmse(&self.scratch);
        self.points.push(NrmsePoint { iteration, train_time_s, nrmse });
        nrmse
    }
}

/// The relative misfit of a volume on the held-out views.
struct HoldoutScorer {
    projector: Box<dyn Projector>,
    images: Vec<Image>,
    norm2: f64,
}

impl HoldoutScorer {
    fn new(projector: Box<dyn Projector>, images: Vec<Image>) -> Self {
        let norm2: f64 = images.iter().flat_map(|im| &im.data).map(|&p| p as f64 * p as f64).sum();
        HoldoutScorer { projector, images, norm2: norm2.max(f64::MIN_POSITIVE) }
    }

    fn loss(&self, volume: &[f32]) -> f64 {
        let mut sum = 0.0;
        let mut buf = Vec::new();
        for (v, im) in self.images.iter().enumerate() {
            buf.clear();
            buf.resize(self.projector.view_len(v), 0.0);
            self.projector.forward(v, volume, &mut buf);
            sum += buf.iter().zip(&im.data).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum::<f64>();
        }
        sum / self.norm2
    }
}
