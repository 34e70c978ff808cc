//! Voxel methods (ASART, ART, SART, MART, SMART, MLEM, SART-TV, SART-Tikhonov) on the scene's
//! training views.
//!
//! The NRMSE curve is evaluated over the truth's voxel centres as the neural methods' is
//! ([`TruthSample`], the volume sampled trilinearly), or voxel by voxel when the truth lies on
//! the solver's grid, as the final metrics compare them; `train_time_s` is the
//! solver's time with the evaluations taken out. Under held-out early stopping the held-out
//! views are forward-projected after every `holdout_every`-th iteration and the volume with
//! the lowest relative held-out misfit `‖p − A g‖² / ‖p‖²` is kept.

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_classical::{
    voxel_footprint_px, ClassicalMethod, Grid, Problem, Projector, ProjectorConfig, ProjectorKind,
};
use fluidnerf_core::{Image, Scene, Volume};
use fluidnerf_metrics::{NrmsePoint, TruthSample};

use crate::measured::{fit_gain, normalise, MaskedProjector};
use crate::{
    check_memory, finish, memory_limit, peak_rss, write_volume, BestHoldout, ClassicalDetails, Family, GainMode,
    History, HoldoutPoint, HoldoutScore, LossKind, MethodConfig, PipelineError, RunConfig, RunDir, RunEvent, RunReport,
    Session, StopReason, StopRule, VolumeRecord, REPORT_FORMAT,
};

/// At most `wanted` MiB for a cache that speeds a run up but is not needed: half the memory
/// the run leaves free under `limit` (`without`: the run's bytes without the cache), so that
/// it never makes a run refuse to start. The volumes do not depend on it.
fn fit_cache(what: &str, wanted: u64, limit: u64, without: u64) -> u64 {
    let room_mib = (limit.saturating_sub(without) / 2) >> 20;
    if room_mib < wanted {
        log::info!("{what}: at most {room_mib} MiB of the {wanted} MiB asked, for the memory limit");
    }
    wanted.min(room_mib)
}

/// Kept rows (ART and MART, `row_cache_mib`) get what [`fit_cache`] leaves them (`estimate`:
/// the run's bytes with a given method).
fn fit_row_cache(method: &mut ClassicalMethod, limit: u64, estimate: impl Fn(&ClassicalMethod) -> u64) {
    let Some(wanted) = method.row_cache_mib_mut().map(std::mem::take) else { return };
    let fitted = fit_cache("rows kept between iterations", wanted, limit, estimate(method));
    if let Some(m) = method.row_cache_mib_mut() {
        *m = fitted;
    }
}

/// Kept footprints (`kept_footprints_mib`) likewise, for the methods that back-project in
/// every iteration; none for the others.
fn fit_kept_footprints(
    method: &ClassicalMethod,
    projector: &mut ProjectorConfig,
    limit: u64,
    estimate: impl Fn(&ProjectorConfig) -> u64,
) {
    let wanted = std::mem::take(&mut projector.kept_footprints_mib);
    if method.back_projects() {
        projector.kept_footprints_mib =
            fit_cache("footprints kept between projections", wanted, limit, estimate(projector));
    }
}

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
            "the scene has {} time steps; a voxel reconstruction mixes them into one volume{}",
            scene.times().len(),
            crate::first_truth_only(scene)
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
    // `auto` resolved once, so the held-out views and the report use the same projector.
    let kind = spec.projector.resolve(&grid, &cameras);
    // The footprint projector shares footprints along grid rows on `x`: a scene whose cameras
    // ring another axis is solved on axes renamed so that it becomes `x` (an exact rotation;
    // the volume is put back on the scene's axes at the end).
    let shift = spec.projector.row_shift(&grid, &cameras);
    if !shift.is_identity() {
        log::debug!("{method}: solved on shifted axes ({shift:?}), whose grid rows share footprints");
    }
    let (grid_s, cameras_s, holdout_cameras_s) =
        (shift.grid(&grid), shift.cameras(&cameras), shift.cameras(&holdout_cameras));
    let threads = rayon::current_num_threads();
    // Scoring holds the truth, a resampled copy and temporaries; the curve a copy of the volume.
    let truth_bytes: u64 = truth.first().map_or(0, |(_, t)| 3 * 4 * t.len() as u64 + 4 * grid.len() as u64);
    let mut solver = spec.method.clone();
    let mut projector_config = spec.projector.clone();
    let limit = memory_limit(config);
    fit_row_cache(&mut solver, limit, |m| {
        m.memory(&projector_config, &grid_s, &cameras_s, threads).total().saturating_add(truth_bytes)
    });
    fit_kept_footprints(&solver, &mut projector_config, limit, |p| {
        solver.memory(p, &grid_s, &cameras_s, threads).total().saturating_add(truth_bytes)
    });
    let estimate = solver.memory(&projector_config, &grid_s, &cameras_s, threads);
    let needed = estimate.total().saturating_add(truth_bytes);
    check_memory(config, needed, || format!("{method} at {:?} voxels with {} views", grid.dims, cameras.len()))?;
    let t_setup = Instant::now();
    let measured = crate::measured::load(scene, &config.gains, false)?;
    for warning in &measured.warnings {
        session.warn(warning);
    }
    let (train_idx, held_idx) = measured.split(scene);
    // Masked pixels are rows of zeros ([`MaskedProjector`]): zero data, no weight.
    let masked_image = |i: usize| {
        let mut im = measured.images[i].clone();
        if let Some(m) = &measured.masks[i] {
            im.data.iter_mut().zip(m).filter(|(_, &k)| !k).for_each(|(v, _)| *v = 0.0);
        }
        im
    };
    let measured_images: Vec<Image> = train_idx.iter().map(|&i| masked_image(i)).collect();
    if measured_images.iter().all(|im| im.data.iter().all(|&v| v <= 0.0)) {
        return Err(PipelineError::invalid("images", fluidnerf_core::image::ALL_BLACK));
    }
    let train_masks: Vec<Option<Vec<bool>>> = train_idx.iter().map(|&i| measured.masks[i].clone()).collect();
    let holdout_images: Vec<Image> = held_idx.iter().map(|&i| masked_image(i)).collect();
    let holdout_masks: Vec<Option<Vec<bool>>> = held_idx.iter().map(|&i| measured.masks[i].clone()).collect();
    let subdivisions = spec.projector.subdivisions(&grid, &cameras);
    let resolved = ProjectorConfig { kind, ..projector_config };
    let base_projector = resolved.build(grid_s, &cameras_s, scene.intensity_scale)?;
    let masked_projector = MaskedProjector { inner: base_projector.as_ref(), masks: train_masks.clone() };
    let projector: &dyn Projector =
        if train_masks.iter().any(Option::is_some) { &masked_projector } else { base_projector.as_ref() };
    let footprint_px = voxel_footprint_px(&cameras, &grid);
    if kind == ProjectorKind::Splat && footprint_px / subdivisions as f64 > 2.0 {
        session.warn(&format!(
            "voxels cover about {footprint_px:.1} pixels and are split into only {subdivisions}³: the splat leaves \
             gaps; raise splat_subdivisions (0: automatic) or use the ray projector"
        ));
    }
    // The visual hull sees masked pixels as unknown (bright), never as empty.
    let hull_images: Vec<Image> = measured_images
        .iter()
        .zip(&train_masks)
        .map(|(im, m)| {
            let mut im = im.clone();
            if let Some(m) = m {
                let top = im.min_max().1;
                im.data.iter_mut().zip(m).filter(|(_, &k)| !k).for_each(|(v, _)| *v = top);
            }
            im
        })
        .collect();
    let support = spec.projector.support(&grid_s, &cameras_s, &hull_images);
    drop(hull_images);
    let hull_voxels = support.as_ref().map(|h| h.iter().filter(|&&b| b).count());
    // Every method holds the voxels outside the hull at zero: without one inside, the run
    // would write an all-zero volume and report it as a result.
    if hull_voxels == Some(0) {
        let p = &spec.projector;
        return Err(PipelineError::invalid(
            "visual_hull",
            format!(
                "{}: the visual hull is empty: every voxel's centre projects onto a dark pixel in some training \
                 view (at most hull_threshold {} of that image's maximum, or its background plus hull_noise_sigmas \
                 {} deviations), so the volume would be all zeros; check that the cameras' poses match their \
                 images, lower --hull-threshold or --hull-noise-sigmas, or leave out --visual-hull",
                scene.root.display(),
                fluidnerf_core::num(p.hull_threshold),
                fluidnerf_core::num(p.hull_noise_sigmas)
            ),
        ));
    }
    if let (Some(inside), ClassicalMethod::Tv(p)) = (hull_voxels, &spec.method) {
        if p.tv_weight > 0.0
            && inside < grid.len()
            && p.step_rule.resolve(true) == fluidnerf_classical::TvStepRule::Data
        {
            session.warn(&format!(
                "SART-TV inside a visual hull with step_rule \"data\": each total-variation step has the \
                 length it would have without one, and now moves only the hull's {inside} voxels ({:.0} % of \
                 the grid), so tv_weight {} smooths them much harder; the \"balanced\" rule (the default, \
                 \"auto\", with a hull) keeps SART-TV's accuracy there (docs/claims.md)",
                100.0 * inside as f64 / grid.len() as f64,
                p.tv_weight
            ));
        }
    }
    let fit = measured.mode == GainMode::Fit;
    let fixed = ProjectorConfig { splat_subdivisions: subdivisions, ..resolved.clone() };
    let holdout = if holdout_cameras.is_empty() {
        None
    } else {
        Some(HoldoutScorer::new(
            fixed.build(grid_s, &holdout_cameras_s, scene.intensity_scale)?,
            holdout_images,
            holdout_masks,
            measured.mode != GainMode::None,
        ))
    };
    let setup_s = t_setup.elapsed().as_secs_f64();
    // Written once everything has been read and checked: a refused run leaves nothing.
    dir.write_json("config.json", config)?;

    let eval_every = config.eval_interval();
    let holdout_every = config.stopping.holdout_interval(Family::Classical);
    let mut curve = truth.first().map(|(_, t)| Curve::new(&shift.volume(t), grid_s));
    let mut best = BestHoldout::<Vec<f32>>::new(config.stopping.patience);
    let mut holdout_history = Vec::new();
    let mut cause = None;
    let mut eval_s = 0.0;
    let cap = solver.stopping().max_iterations;
    let _ = session.emit(RunEvent::Started { method, max_iterations: cap, windows: 1, start_iteration: 0 });
    let budget = config.stopping.time_budget_s;
    let t_solve = Instant::now();
    // With fitted gains the solve runs in segments: `rounds` of `every` iterations, each
    // followed by a gain fit of every view to its reprojection, then the rest under the run's
    // stopping rule. Iterations are numbered across segments.
    let every = config.gains.interval(Family::Classical);
    let mut gains: Vec<(f64, f64)> = vec![(1.0, 0.0); cameras.len()];
    let mut corrected = measured_images.clone();
    let mut volume: Option<Vec<f32>> = None;
    let mut residual_history = Vec::new();
    let mut done = 0usize;
    let mut last_reason = fluidnerf_classical::solve::StopReason::MaxIterations;
    let segments = if fit { config.gains.rounds.saturating_add(1) } else { 1 };
    for segment in 0..segments {
        let last = segment + 1 == segments;
        let mut seg_method = solver.clone();
        let remaining = cap.saturating_sub(done);
        if remaining == 0 {
            break;
        }
        if !last {
            let s = seg_method.stopping_mut();
            s.max_iterations = every.min(remaining);
            s.plateau = None;
        } else {
            seg_method.stopping_mut().max_iterations = remaining;
        }
        let mut problem = Problem::new(projector, &corrected)?;
        if let Some(h) = &support {
            problem = problem.with_support(h);
        }
        let offset_iter = done;
        let result = seg_method.solve(&problem, volume.as_deref(), |s| {
            let iteration = offset_iter + s.iteration;
            let train_time_s = t_solve.elapsed().as_secs_f64() - eval_s;
            let t_eval = Instant::now();
            let nrmse = match curve.as_mut() {
                Some(c) if eval_every > 0 && iteration.is_multiple_of(eval_every) => {
                    Some(c.push(iteration, train_time_s, s.volume))
                }
                _ => None,
            };
            let mut out_of_patience = false;
            let held = match &holdout {
                Some(h) if held_out_rule && iteration.is_multiple_of(holdout_every) => {
                    let loss = h.loss(s.volume);
                    holdout_history.push(HoldoutPoint { iteration, loss, train_time_s: Some(train_time_s) });
                    out_of_patience = best.record(iteration, loss, || s.volume.to_vec());
                    Some(loss)
                }
                _ => None,
            };
            eval_s += t_eval.elapsed().as_secs_f64();
            let event = RunEvent::Iteration { window: None, iteration, loss: s.residual, smoothed: None, train_time_s };
            let mut flow = session.emit(event);
            if nrmse.is_some() || held.is_some() {
                let evaluation = RunEvent::Evaluation { window: None, iteration, nrmse, holdout: held };
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
        done += result.iterations;
        residual_history.extend(result.residual_history);
        last_reason = result.stop_reason;
        volume = Some(result.volume);
        if cause.is_some() || last {
            break;
        }
        // Each view against its reprojection: p ≈ g · A x + b.
        let x = volume.as_deref().unwrap_or_default();
        let mut buf = Vec::new();
        let mut fitted = vec![false; gains.len()];
        for (v, p) in measured_images.iter().enumerate() {
            buf.clear();
            buf.resize(projector.view_len(v), 0.0);
            projector.forward(v, x, &mut buf);
            if let Some(g) = fit_gain(&p.data, &buf, train_masks[v].as_deref(), config.gains.offset) {
                gains[v] = g;
                fitted[v] = true;
            }
        }
        normalise(&mut gains, &fitted);
        for ((c, p), &(g, b)) in corrected.iter_mut().zip(&measured_images).zip(&gains) {
            let (inv, b) = ((1.0 / g) as f32, b as f32);
            c.data.iter_mut().zip(&p.data).for_each(|(c, &p)| *c = ((p - b) * inv).max(0.0));
        }
        log::info!(
            "gains after {done} iterations: {}",
            gains.iter().map(|(g, _)| format!("{g:.3}")).collect::<Vec<_>>().join(", ")
        );
    }
    let train_time_s = t_solve.elapsed().as_secs_f64() - eval_s;
    let _ = session.emit(RunEvent::Writing);
    let stop_reason = cause.unwrap_or(last_reason.into());
    let iterations = done;
    let (kept_iteration, data) = match best.best.take() {
        Some((it, _, v)) => (it, v),
        None => (iterations, volume.unwrap_or_else(|| vec![0.0; grid.len()])),
    };
    if let Some(r) = diverged(&residual_history, kept_iteration) {
        session.warn(&format!(
            "{} diverged: the kept volume's relative residual is {}, above the 1 of an empty volume and above its \
             lowest, so it fits the images worse than no volume at all; the images disagree with each other (a \
             camera posed against another's image, gains that differ: `fluidnerf info` checks the scene), or the \
             relaxation is too large for them; a method that averages over views (sart, asart, mlem), a lower \
             --relaxation or --stop held-out keeps a better one",
            config.method(),
            fluidnerf_core::num(r)
        ));
    }
    let scores: Vec<(usize, HoldoutScore)> = match &holdout {
        Some(h) => held_idx.iter().copied().zip(h.scores(&data)).collect(),
        None => Vec::new(),
    };
    let preprocessing = measured.report(scene, fit.then_some(gains.as_slice()), &scores);
    let volume = grid.volume(shift.data_back(grid.dims, data));
    write_volume(dir, "volume", &volume, None)?;

    let t_eval = Instant::now();
    let metrics = match truth.first() {
        Some((time, t)) => {
            Some(fluidnerf_metrics::evaluate_volume(&volume, t, *time, &crate::metric_options(scene, truth)?)?)
        }
        None => None,
    };
    let mut nrmse_history = curve.map(|c| c.points).unwrap_or_default();
    // The last iterate, when it is the volume kept and the curve has no point for it: the
    // final metrics' NRMSE, which the curve's points equal on the truth's grid.
    if let Some(m) = &metrics {
        if nrmse_history.last().is_none_or(|p| p.iteration != iterations) && kept_iteration == iterations {
            nrmse_history.push(NrmsePoint { iteration: iterations, train_time_s, nrmse: m.global.nrmse });
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
            loss: residual_history,
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
            dims: grid.dims,
            metrics,
            digest: None,
        }],
        not_reached: Vec::new(),
        classical: Some(ClassicalDetails {
            projector: kind,
            splat_subdivisions: (kind == ProjectorKind::Splat).then_some(subdivisions),
            voxel_size: [spacing.x, spacing.y, spacing.z],
            views: cameras.len(),
            pixels: cameras.iter().map(|c| c.width() * c.height()).sum(),
            hull_voxels,
            memory_estimate: estimate,
            views_fingerprint: Some(measured.fingerprint(scene)),
        }),
        neural: None,
        windows: Vec::new(),
        preprocessing: Some(preprocessing),
        warnings: Vec::new(),
    };
    log::debug!("{method}: {:.1} s in all", session.elapsed_s());
    finish(scene, dir, report, truth, Some(&measured), session)
}

/// The NRMSE curve of the solver's volume.
struct Curve {
    against: Against,
    points: Vec<NrmsePoint>,
}

/// What a [`Curve`] compares the volume with.
enum Against {
    /// The truth on the solver's own grid: voxel by voxel, as the final metrics do, exactly
    /// and without resampling.
    SameGrid(Vec<f32>),
    /// A [`TruthSample`] of a truth on another grid, and the solver's volume copied for
    /// trilinear sampling at its voxel centres.
    Sample(TruthSample, Volume),
}

impl Curve {
    fn new(truth: &Volume, grid: Grid) -> Self {
        let against = if truth.dims == grid.dims && truth.aabb == grid.aabb {
            Against::SameGrid(truth.data.clone())
        } else {
            Against::Sample(TruthSample::new(truth), grid.volume(vec![0.0; grid.len()]))
        };
        Curve { against, points: Vec::new() }
    }

    fn push(&mut self, iteration: usize, train_time_s: f64, volume: &[f32]) -> f64 {
        let nrmse = match &mut self.against {
            Against::SameGrid(truth) => fluidnerf_metrics::nrmse(volume, truth),
            Against::Sample(sample, scratch) => {
                scratch.data.copy_from_slice(volume);
                sample.nrmse(scratch)
            }
        };
        self.points.push(NrmsePoint { iteration, train_time_s, nrmse });
        nrmse
    }
}

/// The relative misfit of a volume on the held-out views (masked pixels left out), after the
/// best-fit gain per view when the run calibrates gains (a held-out camera's gain is unknown).
struct HoldoutScorer {
    projector: Box<dyn Projector>,
    images: Vec<Image>,
    masks: Vec<Option<Vec<bool>>>,
    fit_gains: bool,
    norm2: f64,
}

impl HoldoutScorer {
    fn new(projector: Box<dyn Projector>, images: Vec<Image>, masks: Vec<Option<Vec<bool>>>, fit_gains: bool) -> Self {
        let norm2: f64 = images.iter().flat_map(|im| &im.data).map(|&p| p as f64 * p as f64).sum();
        HoldoutScorer { projector, images, masks, fit_gains, norm2: norm2.max(f64::MIN_POSITIVE) }
    }

    /// Each view's reprojection, masked pixels zeroed.
    fn reprojections(&self, volume: &[f32]) -> Vec<Vec<f32>> {
        let views: Vec<usize> = (0..self.images.len()).collect();
        let mut bufs: Vec<Vec<f32>> = views.iter().map(|&v| vec![0.0; self.projector.view_len(v)]).collect();
        let mut outs: Vec<&mut [f32]> = bufs.iter_mut().map(Vec::as_mut_slice).collect();
        self.projector.forward_views(&views, volume, &mut outs);
        for (buf, mask) in bufs.iter_mut().zip(&self.masks) {
            if let Some(m) = mask {
                buf.iter_mut().zip(m).filter(|(_, &k)| !k).for_each(|(b, _)| *b = 0.0);
            }
        }
        bufs
    }

    fn loss(&self, volume: &[f32]) -> f64 {
        let mut sum = 0.0;
        for ((buf, im), m) in self.reprojections(volume).iter().zip(&self.images).zip(&self.masks) {
            let g =
                if self.fit_gains { fit_gain(&im.data, buf, m.as_deref(), false).map_or(1.0, |f| f.0) } else { 1.0 };
            sum += buf.iter().zip(&im.data).map(|(&a, &b)| (g * a as f64 - b as f64).powi(2)).sum::<f64>();
        }
        sum / self.norm2
    }

    fn scores(&self, volume: &[f32]) -> Vec<HoldoutScore> {
        self.reprojections(volume)
            .iter()
            .zip(&self.images)
            .zip(&self.masks)
            .map(|((r, im), m)| crate::measured::holdout_score(&im.data, r, m.as_deref()))
            .collect()
    }
}

/// The relative residual of the kept iterate (1-based `kept` of `history`) when the method
/// diverged: above 1, an empty volume's, so that the volume fits the images worse than none,
/// and above the lowest residual before it, so that the iterations made it worse. A method that
/// starts from ones (MLEM, MART) may stand above 1 after its first iterations while it
/// improves; that is not divergence.
fn diverged(history: &[f64], kept: usize) -> Option<f64> {
    let r = *history.get(kept.checked_sub(1)?)?;
    let lowest = history[..kept].iter().copied().fold(f64::INFINITY, f64::min);
    (r > 1.0 && r > 1.05 * lowest).then_some(r)
}

#[cfg(test)]
mod tests {
    use fluidnerf_classical::{Algorithm, ClassicalMethod, ProjectorConfig};

    use super::{diverged, fit_kept_footprints, fit_row_cache};

    /// Divergence is a kept residual above an empty volume's and above the run's lowest; a
    /// start from ones that stands above 1 while it improves is not.
    #[test]
    fn divergence_is_a_residual_above_one_that_grew() {
        assert_eq!(diverged(&[1.38, 1.76, 1.03, 1.49], 4), Some(1.49));
        assert_eq!(diverged(&[14.1, 3.2, 1.4], 3), None);
        assert_eq!(diverged(&[0.5, 0.9, 0.95], 3), None);
        // The kept iterate, not the last, is judged.
        assert_eq!(diverged(&[0.5, 0.4, 2.0], 2), None);
        assert_eq!(diverged(&[0.5, 0.4, 2.0], 0), None);
        assert_eq!(diverged(&[], 1), None);
    }

    const MIB: u64 = 1 << 20;

    /// A run that needs 100 MiB without kept rows, and 1 MiB more per MiB kept.
    fn estimate(m: &ClassicalMethod) -> u64 {
        100 * MIB + m.row_cache_mib().unwrap_or(0) * MIB
    }

    /// Kept rows shrink to half the free memory under the limit, never below zero, so the run
    /// itself still fits; they stay as asked when there is room; other methods are untouched.
    #[test]
    fn kept_rows_take_at_most_half_the_free_memory() {
        let mart = ClassicalMethod::default_for(Algorithm::Mart);
        let cache = |limit: u64| {
            let mut m = mart.clone();
            fit_row_cache(&mut m, limit, estimate);
            let kept = m.row_cache_mib().expect("MART keeps rows");
            assert!(estimate(&m) <= limit.max(100 * MIB), "{kept} MiB kept under {limit} bytes");
            kept
        };
        assert_eq!(cache(u64::MAX), 1024);
        assert_eq!(cache(300 * MIB), 100);
        assert_eq!(cache(101 * MIB), 0);
        assert_eq!(cache(50 * MIB), 0);
        let mut sart = ClassicalMethod::default_for(Algorithm::Sart);
        let before = sart.clone();
        fit_row_cache(&mut sart, 50 * MIB, estimate);
        assert_eq!(sart, before);
    }

    /// Kept footprints shrink the same way for the methods that back-project every iteration,
    /// and are dropped for ART and MART, which work on rows.
    #[test]
    fn kept_footprints_take_at_most_half_the_free_memory() {
        let fitted = |algorithm: Algorithm, limit: u64| {
            let mut p = ProjectorConfig { kept_footprints_mib: 1024, ..ProjectorConfig::default() };
            fit_kept_footprints(&ClassicalMethod::default_for(algorithm), &mut p, limit, |p| {
                assert_eq!(p.kept_footprints_mib, 0, "estimated without the footprints");
                100 * MIB
            });
            p.kept_footprints_mib
        };
        assert_eq!(fitted(Algorithm::Asart, u64::MAX), 1024);
        assert_eq!(fitted(Algorithm::Mlem, 300 * MIB), 100);
        assert_eq!(fitted(Algorithm::Tv, 50 * MIB), 0);
        assert_eq!(fitted(Algorithm::Art, u64::MAX), 0);
        assert_eq!(fitted(Algorithm::Mart, u64::MAX), 0);
    }
}
