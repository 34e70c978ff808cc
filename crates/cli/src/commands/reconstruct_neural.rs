//! `fluidnerf reconstruct --method fluidnerf|fast`: trains a neural field on a scene's images.
//!
//! Writes into OUT:
//! - `weights.safetensors` (the compact result) and `model.json` (field configuration, box,
//!   value scale, empty-space mask): together they are what `fluidnerf_neural::trained::
//!   load_trained` reads;
//! - `checkpoint.safetensors` (weights + Adam state + histories), every `--checkpoint-every`
//!   iterations and at the end (also after Ctrl-C, which stops after the current
//!   iteration), for `--resume`;
//! - `volume.npy` / `volume.vti`: the field sampled at `--resolution`;
//! - `config.json` (resolved settings, seed, version: rerun with `--config`);
//! - `report.json`: loss history, held-out loss, timing and, when the scene has ground truth,
//!   NRMSE against iteration and training time (the time-to-accuracy curve).

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use fluidnerf_core::{Aabb, Volume};
use fluidnerf_neural::occupancy::OccupancyConfig;
use fluidnerf_neural::train::{train, Learner, Prepared, Problem, TrainConfig, TrainReport, View};
use fluidnerf_neural::trained::{build_field, ModelRecord, NeuralConfig, WorldField, PRESETS};
use fluidnerf_neural::TrainableField;
use serde::Serialize;

use super::reconstruct::Method;
use crate::output::{read_json, write_bytes, write_checkpoint, write_json};
use crate::process::cpu_seconds;
use crate::truth_sample::{NrmsePoint, TruthSample};

/// Options of the neural methods.
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Neural methods")]
pub struct Args {
    /// Named configuration: faithful (Table 5.1: 8 × 256 MLP, L 8, ReLU, N_c = N_f = 128),
    /// ch7 (as faithful with N_c = N_f = 64), experimental (Table 8.3: L 2, Swish, 64/64),
    /// fast (hash grid + tiny MLP + empty-space skipping), dense (voxel grid + skipping).
    /// Default: faithful for --method fluidnerf, fast for --method fast.
    #[arg(long)]
    pub preset: Option<String>,
    /// Random pixels per training image per iteration (N_pix/img). Default: the preset's.
    #[arg(long)]
    pub rays_per_image: Option<usize>,
    /// Stratified samples per ray (N_c). Default: the preset's.
    #[arg(long)]
    pub coarse_samples: Option<usize>,
    /// Hierarchical feature samples per ray (N_f; 0 disables). Default: the preset's.
    #[arg(long)]
    pub fine_samples: Option<usize>,
    /// Initial learning rate (the schedule keeps its decay ratio). Default: the preset's.
    #[arg(long)]
    pub learning_rate: Option<f32>,
    /// Empty-space skipping: drop rays through dark pixels and never evaluate the field in
    /// space that some camera sees dark (a visual hull carved from the images). `true` makes
    /// the faithful MLP several times faster per iteration on jets and plumes, at the risk of
    /// cutting faint parts the threshold calls dark. Default: the preset's (on for fast and
    /// dense, off for the dissertation's presets).
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL")]
    pub skip_empty: Option<bool>,
    /// Write a resumable checkpoint every N iterations (0: only at the end and on Ctrl-C).
    #[arg(long, default_value_t = 500)]
    pub checkpoint_every: usize,
    /// Stop training after this many seconds (training time, evaluations excluded), counted
    /// from the start of this command: a resumed run gets the whole budget again.
    #[arg(long)]
    pub time_budget: Option<f64>,
    /// With ground truth: volume NRMSE every N iterations for the time-to-accuracy curve (over
    /// every k-th voxel centre of the truth, at most 64 per side; 0: only at the end; the time
    /// it takes is not counted as training time). Default: 100 for neural methods, every
    /// iteration for classical ones.
    #[arg(long)]
    pub eval_every: Option<usize>,
    /// Keep the field of the iteration with the lowest held-out loss instead of the last one
    /// (early stopping without ground truth; needs held-out frames in the scene). On noisy
    /// images a field eventually starts to fit the noise: the held-out loss then rises while
    /// the training loss still falls. The checkpoint keeps the last state for --resume.
    #[arg(long)]
    pub keep_best_holdout: bool,
}

/// `config.json`.
#[derive(Serialize, serde::Deserialize)]
struct RunConfig {
    method: Method,
    scene: PathBuf,
    seed: u64,
    resolution: usize,
    version: String,
    neural: NeuralConfig,
}

#[derive(Serialize)]
struct Report {
    method: Method,
    preset: Option<String>,
    version: String,
    num_params: usize,
    weights_bytes: usize,
    image_scale: f64,
    occupied_fraction: f64,
    rays_kept: usize,
    rays_on_box: usize,
    prepare_s: f64,
    /// CPU seconds of the training call (evaluations included), to read timings on a busy
    /// machine: on an idle one the training time would be about this divided by the cores.
    cpu_s: Option<f64>,
    train: TrainReport,
    /// Volume NRMSE and global SSIM over all of the truth's voxel centres.
    final_nrmse: Option<f64>,
    final_ssim_global: Option<f64>,
    nrmse_history: Vec<NrmsePoint>,
    loss_history: Vec<f32>,
    holdout_loss_history: Vec<(usize, f32)>,
    /// With --keep-best-holdout: the iteration whose field was written (None: the last).
    kept_iteration: Option<usize>,
}

/// Applies the training options given on the command line (they override the preset or the
/// rerun config). Shared by the static and the time-resolved neural methods.
pub(crate) fn apply_train_options(t: &mut TrainConfig, args: &super::reconstruct::Args) {
    let n = &args.neural;
    if let Some(v) = n.rays_per_image {
        t.rays_per_image = v;
    }
    if let Some(v) = n.coarse_samples {
        t.coarse_samples = v;
    }
    if let Some(v) = n.fine_samples {
        t.fine_samples = v;
    }
    if let Some(lr) = n.learning_rate {
        let ratio = t.schedule.at_decay_iters / t.schedule.initial;
        t.schedule.initial = lr;
        t.schedule.at_decay_iters = lr * ratio;
    }
    match n.skip_empty {
        Some(true) if t.occupancy.is_none() => t.occupancy = Some(OccupancyConfig::default()),
        Some(false) => t.occupancy = None,
        _ => {}
    }
    if let Some(m) = args.max_iterations {
        t.max_iterations = m;
    }
    if let Some(b) = n.time_budget {
        t.time_budget_s = Some(b);
    }
}

fn resolve_config(args: &super::reconstruct::Args) -> anyhow::Result<(NeuralConfig, Option<String>)> {
    let n = &args.neural;
    let default_preset = if args.method == Method::Fast { "fast" } else { "faithful" };
    let mut cfg = match (&args.config, &n.preset) {
        (Some(path), None) => {
            let run: RunConfig = read_json(path, "a neural run configuration")?;
            run.neural
        }
        (_, preset) => {
            let name = preset.as_deref().unwrap_or(default_preset);
            NeuralConfig::preset(name)
                .with_context(|| format!("unknown preset {name:?} (known: {})", PRESETS.join(", ")))?
        }
    };
    apply_train_options(&mut cfg.train, args);
    cfg.train.validate()?;
    Ok((cfg, n.preset.clone()))
}

/// The NRMSE curve of an earlier run's `report.json` up to `iteration` (empty when there is
/// none, e.g. after a crash before the report was written).
fn earlier_curve(report: &std::path::Path, iteration: usize) -> Vec<NrmsePoint> {
    #[derive(serde::Deserialize)]
    struct Curve {
        #[serde(default)]
        nrmse_history: Vec<NrmsePoint>,
    }
    let Ok(text) = std::fs::read_to_string(report) else { return Vec::new() };
    match serde_json::from_str::<Curve>(&text) {
        Ok(c) => c.nrmse_history.into_iter().filter(|p| p.iteration <= iteration).collect(),
        Err(e) => {
            log::warn!("{}: earlier NRMSE curve not read ({e})", report.display());
            Vec::new()
        }
    }
}

pub fn run(args: &super::reconstruct::Args) -> anyhow::Result<()> {
    let (cfg, preset) = resolve_config(args)?;
    let out = &args.out;
    let has_results = out.join("model.json").exists() || out.join("volume.npy").exists();
    if has_results && !args.force && !args.resume {
        bail!("{} already holds results; use --force to overwrite or --resume to continue", out.display());
    }
    if args.resume && !out.join("checkpoint.safetensors").exists() {
        bail!("--resume: no checkpoint.safetensors in {}", out.display());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;

    let scene = fluidnerf_io::scene::load_scene(&args.scene)
        .with_context(|| format!("loading scene {}", args.scene.display()))?;
    let images = fluidnerf_io::scene::load_images(&scene)
        .with_context(|| format!("loading the images of {}", args.scene.display()))?;
    if scene.times().len() > 1 {
        log::warn!("the scene has {} time steps; static training mixes them into one field", scene.times().len());
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
    let truth = match fluidnerf_io::scene::load_truth(&scene) {
        Ok(t) => t.into_iter().next().map(|(_, v)| v),
        Err(e) => {
            log::warn!("ground truth not used: {e}");
            None
        }
    };

    let t0 = Instant::now();
    let prep = Prepared::new(&problem, &cfg.train).context("preparing the training data")?;
    let prepare_s = t0.elapsed().as_secs_f64();
    let (rays_kept, rays_on_box) = prep.ray_counts();
    log::info!(
        "{} training views, {} held out; {rays_kept} of {rays_on_box} rays kept, {:.1} % of the box occupied",
        problem.views.len(),
        problem.holdout.len(),
        100.0 * prep.occupied_fraction()
    );

    let run_config = RunConfig {
        method: args.method,
        scene: args.scene.clone(),
        seed: args.seed,
        resolution: args.resolution,
        version: env!("CARGO_PKG_VERSION").to_string(),
        neural: cfg.clone(),
    };
    write_json(&out.join("config.json"), &run_config)?;

    let field = build_field(&cfg.field, &scene.aabb, 3, args.seed)?;
    let ctx = Ctx {
        args,
        cfg: &cfg,
        prep: &prep,
        truth: truth.as_ref(),
        preset,
        prepare_s,
        rays_kept,
        rays_on_box,
        aabb: scene.aabb,
    };
    fluidnerf_neural::with_field!(field, f => ctx.train_and_write(f))
}

struct Ctx<'a> {
    args: &'a super::reconstruct::Args,
    cfg: &'a NeuralConfig,
    prep: &'a Prepared,
    truth: Option<&'a Volume>,
    preset: Option<String>,
    prepare_s: f64,
    rays_kept: usize,
    rays_on_box: usize,
    aabb: Aabb,
}

impl Ctx<'_> {
    fn train_and_write<F: TrainableField>(&self, field: F) -> anyhow::Result<()> {
        let (args, out, prep) = (self.args, &self.args.out, self.prep);
        let train_cfg: &TrainConfig = &self.cfg.train;
        // A resumed run overwrites the fresh start with the checkpoint.
        let mut learner = Learner::fresh(field, prep, train_cfg);
        let ckpt = out.join("checkpoint.safetensors");
        if args.resume {
            fluidnerf_neural::weights::load_checkpoint(&ckpt, &mut learner)
                .with_context(|| format!("resuming from {}", ckpt.display()))?;
            log::info!("resuming at iteration {}", learner.iteration);
        }
        let curve = self.truth.map(TruthSample::new);
        let eval_every = args.neural.eval_every.unwrap_or(100);
        let nrmse_of = |field: &F, truth: &TruthSample| -> f64 {
            truth.nrmse(&WorldField { field, meta: &prep.meta, occupancy: prep.occupancy() })
        };
        let cpu0 = cpu_seconds();
        // A resumed run continues the curve of the run it resumes (up to the checkpoint).
        let mut nrmse_history =
            if args.resume { earlier_curve(&out.join("report.json"), learner.iteration) } else { Vec::new() };
        let bar = crate::progress::bar(train_cfg.max_iterations as u64, "training");
        bar.set_position(learner.iteration as u64);
        let mut last = (Instant::now(), learner.iteration);
        let mut rate = 0.0;
        let mut ckpt_error = None;
        // (iteration, held-out loss, parameters) of the best held-out evaluation so far.
        let mut best: Option<(usize, f32, Vec<f32>)> = None;
        let report = train(prep, &mut learner, train_cfg, args.seed, |s| {
            if let (true, Some(h)) = (args.neural.keep_best_holdout, s.holdout_loss) {
                if best.as_ref().is_none_or(|b| h < b.1) {
                    best = Some((s.iteration, h, s.field.params().to_vec()));
                }
            }
            bar.set_position(s.iteration as u64);
            if last.0.elapsed().as_secs_f64() > 1.0 {
                rate = (s.iteration - last.1) as f64 / last.0.elapsed().as_secs_f64();
                last = (Instant::now(), s.iteration);
            }
            let holdout = s.holdout_loss.map(|h| format!(" holdout {h:.3e}")).unwrap_or_default();
            bar.set_message(format!("loss {:.3e} (avg {:.3e}){holdout} {rate:.1} it/s", s.loss, s.smoothed_loss));
            if let (Some(t), true) = (&curve, eval_every > 0 && s.iteration % eval_every == 0) {
                nrmse_history.push(NrmsePoint {
                    iteration: s.iteration,
                    train_time_s: s.train_time_s,
                    nrmse: nrmse_of(s.field, t),
                });
            }
            if args.neural.checkpoint_every > 0 && s.iteration % args.neural.checkpoint_every == 0 {
                if let Err(e) = write_checkpoint(&ckpt, s.learner) {
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
        let cpu_s = cpu0.zip(cpu_seconds()).map(|(a, b)| b - a);
        if let Some(e) = ckpt_error {
            return Err(e.context("writing a checkpoint"));
        }
        // The checkpoint holds the last state, so --resume continues the run where it stopped.
        write_checkpoint(&ckpt, &learner)?;
        let mut kept_iteration = None;
        if args.neural.keep_best_holdout {
            match best {
                Some((iteration, loss, params)) => {
                    learner.field.params_mut().copy_from_slice(&params);
                    kept_iteration = Some(iteration);
                    log::info!("keeping the field of iteration {iteration} (held-out loss {loss:.3e})");
                }
                None => log::warn!("--keep-best-holdout: the scene has no held-out frames, so the last field is kept"),
            }
        }
        let weights = fluidnerf_neural::weights::weights_bytes(&learner.field)?;
        write_bytes(&out.join("weights.safetensors"), &weights)?;
        write_json(
            &out.join("model.json"),
            &ModelRecord {
                field: self.cfg.field.clone(),
                input_dim: learner.field.input_dim(),
                meta: prep.meta.clone(),
            },
        )?;

        let world = WorldField { field: &learner.field, meta: &prep.meta, occupancy: prep.occupancy() };
        let dims = Volume::dims_for(&self.aabb, args.resolution.max(1));
        let volume = Volume::from_field(dims, self.aabb, &world, 0.0);
        let npy = out.join("volume.npy");
        fluidnerf_io::volume::write_npy(&npy, &volume).with_context(|| format!("writing {}", npy.display()))?;
        let vti = out.join("volume.vti");
        fluidnerf_io::volume::write_vti(&vti, &volume).with_context(|| format!("writing {}", vti.display()))?;

        let (mut final_nrmse, mut final_ssim) = (None, None);
        if let Some(truth) = self.truth {
            // The written volume serves when it is on the truth's grid (--resolution = the truth's).
            let v = if volume.dims == truth.dims && volume.aabb == truth.aabb {
                volume
            } else {
                Volume::from_field(truth.dims, truth.aabb, &world, 0.0)
            };
            final_nrmse = Some(fluidnerf_metrics::nrmse(&v.data, &truth.data));
            let range = fluidnerf_metrics::data_range_of(&truth.data);
            if range > 0.0 {
                final_ssim = Some(fluidnerf_metrics::ssim_global(&v.data, &truth.data, range));
            }
            if kept_iteration.is_none() && nrmse_history.last().is_none_or(|p| p.iteration != learner.iteration) {
                if let Some(c) = &curve {
                    nrmse_history.push(NrmsePoint {
                        iteration: learner.iteration,
                        train_time_s: learner.train_time_s,
                        nrmse: nrmse_of(&learner.field, c),
                    });
                }
            }
        }
        let report_json = Report {
            method: args.method,
            preset: self.preset.clone(),
            version: env!("CARGO_PKG_VERSION").to_string(),
            num_params: learner.field.num_params(),
            weights_bytes: weights.len(),
            image_scale: prep.image_scale(),
            occupied_fraction: prep.occupied_fraction(),
            rays_kept: self.rays_kept,
            rays_on_box: self.rays_on_box,
            prepare_s: self.prepare_s,
            cpu_s,
            train: report.clone(),
            final_nrmse,
            final_ssim_global: final_ssim,
            nrmse_history,
            loss_history: learner.losses.clone(),
            holdout_loss_history: learner.holdout_losses.clone(),
            kept_iteration,
        };
        write_json(&out.join("report.json"), &report_json)?;
        #[allow(clippy::print_stdout)]
        {
            println!(
                "{:?}: {} iterations ({:?}) in {:.1} s ({:.1} ms/iteration, {:.2} M samples/s), loss {:.3e}",
                args.method,
                report.iterations,
                report.stop_reason,
                report.train_time_s,
                1e3 * report.seconds_per_iteration,
                report.samples_per_second / 1e6,
                report.smoothed_loss
            );
            if let (Some(n), Some(s)) = (final_nrmse, final_ssim) {
                println!("volume NRMSE {n:.4}, global SSIM {s:.4} (against the scene's ground truth)");
            }
            println!("wrote {}", out.display());
        }
        Ok(())
    }
}
