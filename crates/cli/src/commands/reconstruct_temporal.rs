//! `fluidnerf reconstruct --method tr-fluidnerf|tr-fast|static-per-frame`: time-resolved
//! reconstruction of a scene whose frames carry times (dissertation §5.2), and the per-frame
//! static baseline it is compared with.
//!
//! Writes into OUT:
//! - `frames/volume_NNN.npy` and `.vti`: the field sampled at `--resolution` at every training
//!   frame time and every `--holdout-times` time, in increasing time (the order `fluidnerf eval`
//!   expects when the scene's truth lists the same times), and `volumes.pvd`, the ParaView
//!   collection that opens them as one time series;
//! - `windows/wNNN.safetensors` (weights) and `windows/wNNN.checkpoint.safetensors` (weights,
//!   Adam state, histories) of every window, and `temporal.json`, from which
//!   `fluidnerf_neural::temporal::load_temporal` rebuilds the stitched field E(x, t);
//! - `windows/progress.json`: the window plan, field and seed of the run and the windows it has
//!   finished, written when a window finishes (its checkpoint first). With `--resume` finished
//!   windows are loaded from their checkpoints, the next one continues from its last checkpoint
//!   (every `--checkpoint-every` iterations and on Ctrl-C), later ones train as usual: the
//!   result equals an uninterrupted run's (same seed and thread count);
//! - `config.json` (resolved settings, seed, version: rerun with `--config`);
//! - `report.json`: per window the training report and loss history, and per output time the
//!   volume NRMSE (Eq. 6.18), global SSIM (Eq. 6.19, one window) and windowed 3D SSIM (7³
//!   uniform window, skimage's definition) against the scene's truth when it has one.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use fluidnerf_core::{ScalarField, Volume};
use fluidnerf_neural::temporal::{
    field_for_window, frame_times, infer_time_step, temporal_preset, train_windows, ResumeState, StitchedField,
    TemporalConfig, TemporalRecord, TemporalRun, TimeOrigin, WindowConfig, WindowEvent, WindowRecord, TEMPORAL_PRESETS,
};
use fluidnerf_neural::train::{Batching, Learner, Problem, TrainConfig, TrainReport, View};
use fluidnerf_neural::trained::{build_field, FieldConfig, NeuralConfig, PRESETS};
use fluidnerf_neural::window::plan_windows;
use fluidnerf_neural::TrainableField;
use serde::{Deserialize, Serialize};

use super::reconstruct::Method;
use crate::output::{read_json, write_bytes, write_checkpoint, write_json};
use crate::process::cpu_seconds;

/// Options of the time-resolved methods.
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Time-resolved methods (tr-fluidnerf, tr-fast, static-per-frame)")]
pub struct Args {
    /// Frames per sliding window (0: one field for all frames). Default: the preset's (all
    /// frames for tr-fluidnerf, 16 for tr-fast; always 1 for static-per-frame).
    #[arg(long)]
    pub window: Option<usize>,
    /// Frames shared by consecutive windows, cross-faded linearly in time. Default: the
    /// preset's (2 for tr-fluidnerf, 4 for tr-fast).
    #[arg(long)]
    pub overlap: Option<usize>,
    /// Train every window from scratch instead of from the previous window's weights.
    #[arg(long)]
    pub no_warm_start: bool,
    /// Frame times whose images are NOT trained on (comma separated, the scene's time unit);
    /// volumes and metrics are still produced there, from the continuous field (TR) or by
    /// linear interpolation of the neighbouring frames (static-per-frame).
    #[arg(long, value_delimiter = ',')]
    pub holdout_times: Vec<f64>,
    /// Frame spacing Δt of t' = (t − t₀)/Δt. Default: the smallest gap between training times.
    #[arg(long)]
    pub time_step: Option<f64>,
    /// Origin t₀ of each window's time t' = (t − t₀)/Δt: `window` (each window's first frame;
    /// the hash grid needs it, its time axis spans one window) or `recording` (the recording's
    /// first frame for every window, MLP only: a warm-started window then continues the
    /// previous one's function of time at the shared frames). Default: the preset's (window).
    #[arg(long, value_enum)]
    pub time_origin: Option<TimeOriginArg>,
}

/// `--time-origin` values.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum TimeOriginArg {
    Recording,
    Window,
}

/// `windows/progress.json`: what a run is and how far it got, for `--resume`.
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
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FinishedWindow {
    /// Checkpoint of the window as it finished, relative to the run directory.
    checkpoint: String,
    report: TrainReport,
}

impl Progress {
    /// Why a run with the settings of `self` cannot continue the run recorded in `saved`, if it
    /// cannot; a changed training configuration only warns (finished windows keep theirs).
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
        if saved.train != self.train {
            log::warn!("the training settings differ from the run being resumed; its finished windows keep theirs");
        }
        None
    }
}

/// `config.json`.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RunConfig {
    method: Method,
    scene: PathBuf,
    seed: u64,
    resolution: usize,
    version: String,
    holdout_times: Vec<f64>,
    time_step: f64,
    temporal: TemporalConfig,
}

#[derive(Serialize)]
struct WindowReport {
    frames: [usize; 2],
    time_origin: f64,
    occupied_fraction: f64,
    train: TrainReport,
    loss_history: Vec<f32>,
    holdout_loss_history: Vec<(usize, f32)>,
}

#[derive(Serialize)]
struct FrameMetrics {
    time: f64,
    /// Whether the images of this time were trained on.
    trained: bool,
    file: String,
    nrmse: Option<f64>,
    ssim_global: Option<f64>,
    ssim_windowed: Option<f64>,
}

#[derive(Serialize)]
struct Summary {
    /// Over trained frames with truth.
    mean_nrmse: Option<f64>,
    /// max − min of NRMSE over trained frames: the (non-)uniformity in time.
    nrmse_spread: Option<f64>,
    mean_ssim_global: Option<f64>,
}

#[derive(Serialize)]
struct Report {
    method: Method,
    preset: Option<String>,
    version: String,
    frames: usize,
    windows: usize,
    time_step: f64,
    num_params_per_window: usize,
    weights_bytes_per_window: usize,
    prepare_and_train_s: f64,
    /// CPU seconds (user + system) of preparing and training in this invocation (a resumed
    /// run counts only its own part), to read timings on a shared machine.
    cpu_s: Option<f64>,
    train_time_s: f64,
    train_time_per_frame_s: f64,
    interrupted: bool,
    summary: Summary,
    per_frame: Vec<FrameMetrics>,
    per_window: Vec<WindowReport>,
}

/// The preset (or `--config`) with the command-line overrides applied.
fn resolve_config(args: &super::reconstruct::Args) -> anyhow::Result<(TemporalConfig, Option<String>)> {
    let n = &args.neural;
    let t = &args.temporal;
    let default_preset = match args.method {
        Method::TrFast => "tr-fast",
        Method::StaticPerFrame => "static-swish",
        _ => "tr-faithful",
    };
    let mut cfg = match (&args.config, &n.preset) {
        (Some(path), None) => {
            let run: RunConfig = read_json(path, "a time-resolved run configuration")?;
            run.temporal
        }
        (_, preset) => {
            let name = preset.as_deref().unwrap_or(default_preset);
            match (temporal_preset(name), NeuralConfig::preset(name)) {
                (Some(c), _) => c,
                (None, Some(c)) => TemporalConfig { field: c.field, train: c.train, windows: WindowConfig::default() },
                (None, None) => bail!(
                    "unknown preset {name:?} (time-resolved: {}; static: {})",
                    TEMPORAL_PRESETS.join(", "),
                    PRESETS.join(", ")
                ),
            }
        }
    };
    super::reconstruct_neural::apply_train_options(&mut cfg.train, args);
    if let Some(w) = t.window {
        cfg.windows.frames = w;
    }
    if let Some(o) = t.overlap {
        cfg.windows.overlap = o;
    }
    if t.no_warm_start {
        cfg.windows.warm_start = false;
    }
    if let Some(o) = t.time_origin {
        cfg.windows.time_origin = match o {
            TimeOriginArg::Recording => TimeOrigin::Recording,
            TimeOriginArg::Window => TimeOrigin::Window,
        };
    }
    if args.method == Method::StaticPerFrame {
        cfg.windows = WindowConfig::per_frame();
        cfg.train.batching = Batching::AllViews;
    } else {
        cfg.train.batching = Batching::OneTimeStep;
    }
    cfg.validate()?;
    Ok((cfg, n.preset.clone()))
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

pub fn run(args: &super::reconstruct::Args) -> anyhow::Result<()> {
    let (cfg, preset) = resolve_config(args)?;
    let out = &args.out;
    let progress_path = out.join("windows/progress.json");
    let has_results = out.join("temporal.json").exists() || out.join("volumes.pvd").exists() || progress_path.exists();
    if has_results && !args.force && !args.resume {
        bail!("{} already holds results; use --force to overwrite or --resume to continue", out.display());
    }
    if args.resume && !progress_path.exists() {
        bail!("--resume: no windows/progress.json in {} (nothing to continue)", out.display());
    }
    let scene = fluidnerf_io::scene::load_scene(&args.scene)
        .with_context(|| format!("loading scene {}", args.scene.display()))?;
    let images = fluidnerf_io::scene::load_images(&scene)
        .with_context(|| format!("loading the images of {}", args.scene.display()))?;
    let holdout_times = &args.temporal.holdout_times;
    let is_held = |t: f64| holdout_times.iter().any(|&h| (h - t).abs() <= 1e-9 * (1.0 + t.abs()));
    let mut problem = Problem {
        aabb: scene.aabb,
        intensity_scale: scene.intensity_scale,
        views: Vec::new(),
        holdout: Vec::new(),
        time_step: 1.0,
    };
    for (frame, image) in scene.frames.iter().zip(images) {
        let time = frame.time.unwrap_or(0.0);
        if is_held(time) {
            continue;
        }
        let view = View { camera: frame.camera.clone(), image, time };
        if frame.holdout {
            problem.holdout.push(view);
        } else {
            problem.views.push(view);
        }
    }
    let times = frame_times(&problem);
    if times.is_empty() {
        bail!("{}: no training images left (all their times are in --holdout-times)", args.scene.display());
    }
    if times.len() < 2 && args.method != Method::StaticPerFrame {
        log::warn!("the scene has a single training time; a time-resolved field reduces to a static one");
    }
    problem.time_step = match args.temporal.time_step {
        Some(dt) if dt > 0.0 && dt.is_finite() => dt,
        Some(dt) => bail!("--time-step must be positive, got {dt}"),
        None => infer_time_step(&times),
    };
    for &h in holdout_times {
        if h < times[0] || h > times[times.len() - 1] {
            log::warn!("held-out time {h} lies outside the training times; the field is held at the nearest end");
        }
    }
    let truth: Vec<(Option<f64>, Volume)> = match fluidnerf_io::scene::load_truth(&scene) {
        Ok(t) => t,
        Err(e) => {
            log::warn!("ground truth not used: {e}");
            Vec::new()
        }
    };

    let plan = plan_windows(times.len(), cfg.windows.frames, cfg.windows.overlap);
    let window_len = plan.first().map_or(1, |r| r.len());
    let field_cfg = field_for_window(&cfg.field, window_len);
    let input_dim = if args.method == Method::StaticPerFrame { 3 } else { 4 };
    let mut progress = Progress {
        field: field_cfg.clone(),
        input_dim,
        frame_times: times.clone(),
        plan: plan.iter().map(|r| [r.start, r.end]).collect(),
        time_origin: cfg.windows.time_origin,
        warm_start: cfg.windows.warm_start,
        seed: args.seed,
        train: cfg.train.clone(),
        finished: Vec::new(),
    };
    if args.resume {
        let text =
            std::fs::read_to_string(&progress_path).with_context(|| format!("reading {}", progress_path.display()))?;
        let saved: Progress = serde_json::from_str(&text)
            .with_context(|| format!("{}: not the progress record of a time-resolved run", progress_path.display()))?;
        if let Some(why) = progress.mismatch(&saved) {
            bail!(
                "cannot resume from {}: {why}; rerun with its settings, or use --force to start over",
                progress_path.display()
            );
        }
        progress.finished = saved.finished;
    }
    if !args.resume && out.join("windows").exists() {
        // Checkpoints of an earlier run must not be taken for this run's by a later --resume.
        std::fs::remove_dir_all(out.join("windows"))
            .with_context(|| format!("removing the earlier run's {}/windows", out.display()))?;
    }
    std::fs::create_dir_all(out.join("frames")).with_context(|| format!("creating {}/frames", out.display()))?;
    std::fs::create_dir_all(out.join("windows")).with_context(|| format!("creating {}/windows", out.display()))?;
    let run_config = RunConfig {
        method: args.method,
        scene: args.scene.clone(),
        seed: args.seed,
        resolution: args.resolution,
        version: env!("CARGO_PKG_VERSION").to_string(),
        holdout_times: holdout_times.clone(),
        time_step: problem.time_step,
        temporal: cfg.clone(),
    };
    write_json(&out.join("config.json"), &run_config)?;
    if !args.resume {
        write_json(&progress_path, &progress)?;
    }
    let field = build_field(&field_cfg, &scene.aabb, input_dim, args.seed)?;
    log::info!(
        "{} frames at t = {:?}, Δt = {}, {} training views, window {} frames",
        times.len(),
        times,
        problem.time_step,
        problem.views.len(),
        window_len
    );
    let ctx = Ctx { args, cfg: &cfg, field_cfg: &field_cfg, input_dim, preset, problem: &problem, truth: &truth };
    fluidnerf_neural::with_field!(field, f => ctx.train_and_write(f, progress))
}

struct Ctx<'a> {
    args: &'a super::reconstruct::Args,
    cfg: &'a TemporalConfig,
    field_cfg: &'a fluidnerf_neural::trained::FieldConfig,
    input_dim: usize,
    preset: Option<String>,
    problem: &'a Problem,
    truth: &'a [(Option<f64>, Volume)],
}

/// The checkpoint of window `k`, relative to the run directory.
fn checkpoint_name(k: usize) -> String {
    format!("windows/w{k:03}.checkpoint.safetensors")
}

impl Ctx<'_> {
    /// The saved state of an interrupted run (`progress.finished` and the next window's
    /// checkpoint, if any), as learners of the field `init`.
    fn resume_state<F: TrainableField + Clone>(&self, init: &F, progress: &Progress) -> anyhow::Result<ResumeState<F>> {
        let out = &self.args.out;
        let load = |path: &std::path::Path| -> anyhow::Result<Learner<F>> {
            let mut learner = Learner::new(init.clone());
            fluidnerf_neural::weights::load_checkpoint(path, &mut learner)
                .with_context(|| format!("resuming from {}", path.display()))?;
            Ok(learner)
        };
        let mut state = ResumeState::default();
        for w in &progress.finished {
            state.finished.push((load(&out.join(&w.checkpoint))?, w.report.clone()));
        }
        let next = out.join(checkpoint_name(progress.finished.len()));
        if progress.finished.len() < progress.plan.len() && next.exists() {
            state.running = Some(load(&next)?);
        }
        log::info!(
            "resuming: {} of {} windows finished{}",
            state.finished.len(),
            progress.plan.len(),
            state.running.as_ref().map(|l| format!(", the next at iteration {}", l.iteration)).unwrap_or_default()
        );
        Ok(state)
    }

    fn train_and_write<F: TrainableField + Clone + 'static>(
        &self,
        init: F,
        mut progress: Progress,
    ) -> anyhow::Result<()> {
        let (args, out, cfg) = (self.args, &self.args.out, self.cfg);
        let n_windows = progress.plan.len().max(1);
        let resume = if args.resume { self.resume_state(&init, &progress)? } else { ResumeState::default() };
        let per_window = cfg.train.max_iterations as u64;
        let bar = crate::progress::bar(per_window * n_windows as u64, "training");
        let mut ckpt_error = None;
        let mut last = (Instant::now(), 0usize, usize::MAX);
        let mut rate = 0.0;
        let t_start = Instant::now();
        let cpu0 = cpu_seconds();
        let progress_path = out.join("windows/progress.json");
        let run: TemporalRun<F> =
            train_windows(self.problem, &cfg.train, &cfg.windows, init, args.seed, resume, |e| {
                let (w, s) = match e {
                    WindowEvent::Iteration(w, s) => (w, s),
                    WindowEvent::Finished(_, done) => {
                        // The checkpoint first: a window listed as finished always has its final one.
                        let name = checkpoint_name(progress.finished.len());
                        let saved = write_checkpoint(&out.join(&name), &done.learner).and_then(|()| {
                            progress.finished.push(FinishedWindow { checkpoint: name, report: done.report.clone() });
                            write_json(&progress_path, &progress)
                        });
                        return match saved {
                            Ok(()) => ControlFlow::Continue(()),
                            Err(e) => {
                                ckpt_error = Some(e);
                                ControlFlow::Break(())
                            }
                        };
                    }
                };
                bar.set_position(w.index as u64 * per_window + s.iteration as u64);
                if last.2 != w.index {
                    last = (Instant::now(), s.iteration, w.index);
                } else if last.0.elapsed().as_secs_f64() > 1.0 {
                    rate = (s.iteration - last.1) as f64 / last.0.elapsed().as_secs_f64();
                    last = (Instant::now(), s.iteration, w.index);
                }
                bar.set_message(format!(
                    "window {}/{} (frames {}–{}) loss {:.3e} (avg {:.3e}) {rate:.1} it/s",
                    w.index + 1,
                    w.count,
                    w.frames.start,
                    w.frames.end - 1,
                    s.loss,
                    s.smoothed_loss
                ));
                if args.neural.checkpoint_every > 0 && s.iteration % args.neural.checkpoint_every == 0 {
                    if let Err(e) = write_checkpoint(&out.join(checkpoint_name(w.index)), s.learner) {
                        ckpt_error = Some(e);
                        return ControlFlow::Break(());
                    }
                }
                if crate::interrupt::requested() {
                    return ControlFlow::Break(());
                }
                ControlFlow::Continue(())
            })?;
        bar.finish_and_clear();
        let wall_s = t_start.elapsed().as_secs_f64();
        let cpu_s = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
        if let Some(e) = ckpt_error {
            return Err(e.context("writing a checkpoint"));
        }

        // Weights, checkpoints and the description of the stitched field.
        let mut records = Vec::new();
        let mut weights_bytes = 0;
        for (k, w) in run.windows.iter().enumerate() {
            let name = format!("windows/w{k:03}.safetensors");
            let bytes = fluidnerf_neural::weights::weights_bytes(&w.learner.field)?;
            weights_bytes = bytes.len();
            write_bytes(&out.join(&name), &bytes)?;
            write_checkpoint(&out.join(checkpoint_name(k)), &w.learner)?;
            records.push(WindowRecord {
                frames: [w.frames.start, w.frames.end],
                time_origin: w.time_origin,
                meta: w.meta.clone(),
                weights: name,
            });
        }
        write_json(
            &out.join("temporal.json"),
            &TemporalRecord {
                field: self.field_cfg.clone(),
                input_dim: self.input_dim,
                frame_times: run.frame_times.clone(),
                windows: records,
            },
        )?;
        let stitched = StitchedField::from_run(&run)?;

        // Volumes at every training and held-out time, and their metrics.
        let mut out_times: Vec<(f64, bool)> = run.frame_times.iter().map(|&t| (t, true)).collect();
        out_times.extend(args.temporal.holdout_times.iter().map(|&t| (t, false)));
        out_times.sort_by(|a, b| a.0.total_cmp(&b.0));
        let dims = Volume::dims_for(&self.problem.aabb, args.resolution.max(1));
        let mut per_frame = Vec::new();
        let mut pvd_entries = Vec::new();
        for (i, &(t, trained)) in out_times.iter().enumerate() {
            let volume = Volume::from_field(dims, self.problem.aabb, &stitched, t);
            let stem = format!("frames/volume_{i:03}");
            let npy = out.join(format!("{stem}.npy"));
            fluidnerf_io::volume::write_npy(&npy, &volume).with_context(|| format!("writing {}", npy.display()))?;
            let vti = out.join(format!("{stem}.vti"));
            fluidnerf_io::volume::write_vti(&vti, &volume).with_context(|| format!("writing {}", vti.display()))?;
            pvd_entries.push((t, format!("{stem}.vti")));
            let truth = self
                .truth
                .iter()
                .find(|(tt, _)| tt.is_some_and(|tt| (tt - t).abs() <= 1e-9 * (1.0 + t.abs())))
                .or(if self.truth.len() == 1 && self.truth[0].0.is_none() { self.truth.first() } else { None });
            let (nrmse, ssim_global, ssim_windowed) = match truth {
                Some((_, tv)) => {
                    let v = Volume::from_field(tv.dims, tv.aabb, &stitched as &dyn ScalarField, t);
                    let range = fluidnerf_metrics::data_range_of(&tv.data);
                    let params = fluidnerf_metrics::SsimParams { data_range: Some(range), ..Default::default() };
                    (
                        Some(fluidnerf_metrics::nrmse(&v.data, &tv.data)),
                        (range > 0.0).then(|| fluidnerf_metrics::ssim_global(&v.data, &tv.data, range)),
                        fluidnerf_metrics::ssim_3d(&v.data, &tv.data, tv.dims, &params).ok(),
                    )
                }
                None => (None, None, None),
            };
            per_frame.push(FrameMetrics {
                time: t,
                trained,
                file: format!("{stem}.npy"),
                nrmse,
                ssim_global,
                ssim_windowed,
            });
        }
        write_bytes(&out.join("volumes.pvd"), pvd(&pvd_entries).as_bytes())?;

        let trained_nrmse: Vec<f64> = per_frame.iter().filter(|f| f.trained).filter_map(|f| f.nrmse).collect();
        let trained_ssim: Vec<f64> = per_frame.iter().filter(|f| f.trained).filter_map(|f| f.ssim_global).collect();
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        let summary = Summary {
            mean_nrmse: mean(&trained_nrmse),
            nrmse_spread: (!trained_nrmse.is_empty()).then(|| {
                trained_nrmse.iter().copied().fold(f64::MIN, f64::max)
                    - trained_nrmse.iter().copied().fold(f64::MAX, f64::min)
            }),
            mean_ssim_global: mean(&trained_ssim),
        };
        let train_time_s: f64 = run.windows.iter().map(|w| w.report.train_time_s).sum();
        let report = Report {
            method: args.method,
            preset: self.preset.clone(),
            version: env!("CARGO_PKG_VERSION").to_string(),
            frames: run.frame_times.len(),
            windows: run.windows.len(),
            time_step: self.problem.time_step,
            num_params_per_window: run.windows.first().map_or(0, |w| w.learner.field.num_params()),
            weights_bytes_per_window: weights_bytes,
            prepare_and_train_s: wall_s,
            cpu_s,
            train_time_s,
            train_time_per_frame_s: train_time_s / run.frame_times.len().max(1) as f64,
            interrupted: run.interrupted,
            summary,
            per_frame,
            per_window: run
                .windows
                .iter()
                .map(|w| WindowReport {
                    frames: [w.frames.start, w.frames.end],
                    time_origin: w.time_origin,
                    occupied_fraction: w.occupied_fraction,
                    train: w.report.clone(),
                    loss_history: w.learner.losses.clone(),
                    holdout_loss_history: w.learner.holdout_losses.clone(),
                })
                .collect(),
        };
        write_json(&out.join("report.json"), &report)?;
        #[allow(clippy::print_stdout)]
        {
            println!(
                "{:?}: {} frames in {} window(s), {:.1} s training ({:.2} s per frame){}",
                args.method,
                report.frames,
                report.windows,
                train_time_s,
                report.train_time_per_frame_s,
                if run.interrupted { ", interrupted" } else { "" }
            );
            if report.per_frame.iter().any(|f| f.nrmse.is_some()) {
                println!(
                    "{:>10} {:>8} {:>8} {:>12} {:>14}",
                    "time", "trained", "NRMSE", "SSIM global", "SSIM windowed"
                );
                for f in &report.per_frame {
                    let fmt = |x: Option<f64>| x.map_or("-".to_string(), |v| format!("{v:.4}"));
                    println!(
                        "{:>10} {:>8} {:>8} {:>12} {:>14}",
                        f.time,
                        if f.trained { "yes" } else { "held out" },
                        fmt(f.nrmse),
                        fmt(f.ssim_global),
                        fmt(f.ssim_windowed)
                    );
                }
            }
            println!("wrote {}", out.display());
        }
        Ok(())
    }
}
