//! `fluidnerf reconstruct --method asart|art|sart|mart|smart|mlem|tv|tikhonov`: classical
//! voxel tomography of a scene's training views (held-out frames are not used).
//!
//! Writes into OUT:
//! - `volume.npy` / `volume.vti`: the voxel grid (`--resolution` voxels along the box's longest
//!   side, cubic cells), in the units of the emission field (the scene's `intensity_scale` is
//!   part of the projector);
//! - `config.json`: resolved settings (method, projector, every method's parameters, seed,
//!   version): rerun with `--config`;
//! - `report.json`: iterations, why it stopped, residual history, time, memory (estimated and
//!   peak), and, when the scene has ground truth, volume NRMSE / PSNR / SSIM (global and per
//!   region) and `nrmse_history: [{iteration, train_time_s, nrmse}]`, the time-to-accuracy
//!   curve in the same form as the neural methods' (`fluidnerf compare` draws them together).
//!
//! The NRMSE curve is evaluated over the same subset of the truth's voxel centres as the neural
//! methods' ([`TruthSample`], the volume sampled trilinearly), after every iteration by default:
//! a classical run has tens to hundreds of costly iterations, so `--eval-every` at its default
//! (100, sized for neural runs of thousands of cheap iterations) means every iteration here;
//! any other N evaluates every N-th iteration, and 0 only the last. `train_time_s` is the
//! solver's time up to that iteration with the evaluations taken out (they are reported as
//! `eval_s`), so `solve_s` is the solver's time alone.
//!
//! The memory a run needs is estimated before anything large is allocated, and a run that will
//! not fit (default limit: the memory available now) is refused with the estimate. Ctrl-C stops
//! after the current iteration; the volume of that iteration is written as usual.

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use fluidnerf_classical::{
    art, asart, estimate_memory, mart, mlem, sart, sart_tikhonov, sart_tv, smart, visual_hull, Algorithm, ArtParams,
    AsartParams, Grid, IterState, MartParams, MemoryEstimate, MlemParams, Plateau, Problem, Projector, ProjectorKind,
    RayProjector, Report, SartParams, SmartParams, SplatProjector, StopReason, Stopping, TikhonovParams, TvParams,
    DEFAULT_HULL_THRESHOLD,
};
use fluidnerf_core::Image;
use serde::{Deserialize, Serialize};

use super::reconstruct::Method;
use crate::output::{read_json, write_json};
use crate::process::{cpu_seconds, proc_kib};
use crate::truth_sample::{NrmsePoint, TruthSample};

/// Options of the classical methods.
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Classical methods")]
pub struct Args {
    /// Relaxation factor μ of the chosen method [default: asart 0.5, art/sart/mart/smart/tv 1].
    #[arg(long, value_name = "MU")]
    pub relaxation: Option<f64>,
    /// Projector: `splat` (voxel-driven bilinear splat, the dissertation's) or `ray` (ray-driven
    /// trilinear line integrals; closer to the imaging model, slower) [default: splat].
    #[arg(long, value_enum)]
    pub projector: Option<ProjectorArg>,
    /// Splat projector only: split each voxel into N³ sub-voxels so that voxels imaging larger
    /// than a pixel leave no gaps; 1 is the dissertation's splat, 0 chooses N from the voxel's
    /// image size (⌈pixels / 1.5⌉) [default: 0].
    #[arg(long, value_name = "N")]
    pub splat_subdivisions: Option<usize>,
    /// Ray projector only: sampling step along each ray, in voxel sides [default: 0.5].
    #[arg(long, value_name = "VOXELS")]
    pub ray_step: Option<f64>,
    /// Hold voxels at zero whose centre projects onto a dark pixel in any view (visual hull).
    #[arg(long)]
    pub visual_hull: bool,
    /// Dark threshold of --visual-hull, as a fraction of each image's maximum [default: 0.02].
    #[arg(long, value_name = "FRACTION")]
    pub hull_threshold: Option<f64>,
    /// Method tv: size of each total-variation step relative to the SART step [default: 0.2].
    #[arg(long, value_name = "WEIGHT")]
    pub tv_weight: Option<f64>,
    /// Method tv: total-variation descent steps per iteration [default: 20].
    #[arg(long, value_name = "N")]
    pub tv_steps: Option<usize>,
    /// Method tikhonov: weight λ of the smoothness penalty λ‖∇²g‖² (Eq. 2.35, Laplacian in
    /// voxel units, so λ is dimensionless): after each SART sweep the volume takes the step
    /// −μλ∇⁴g. Larger is smoother; 0 is plain SART. It pays off with noisy images: on the demo
    /// jet (15 views, 64³ voxels) the default lowered SART's NRMSE from 0.381 to 0.326 with 10 %
    /// noise (λ 0.01: 0.310) and from 0.256 to 0.247 with 5 %, but raised it from 0.177 to 0.204
    /// without noise. Smooth fields take larger λ (0.1 for Gaussian blobs) [default: 0.003].
    #[arg(long, value_name = "LAMBDA")]
    pub tikhonov_weight: Option<f64>,
    /// Stop when the residual (sliding mean of 4) varies by less than this fraction over 20
    /// iterations; 0 runs to the iteration cap [default: 0.02].
    #[arg(long, value_name = "FRACTION")]
    pub plateau_tolerance: Option<f64>,
    /// Refuse runs whose estimated memory exceeds this many GiB [default: the memory available
    /// when the run starts].
    #[arg(long, value_name = "GIB")]
    pub memory_limit: Option<f64>,
}

/// `--projector` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ProjectorArg {
    Splat,
    Ray,
}

/// The classical settings, as written to and read from `config.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClassicalConfig {
    pub projector: ProjectorKind,
    /// Sub-voxels per axis of the splat; 0 = automatic.
    pub splat_subdivisions: usize,
    /// Ray step in voxel sides (ray projector).
    pub ray_step: f64,
    pub visual_hull: bool,
    pub hull_threshold: f64,
    pub asart: AsartParams,
    pub art: ArtParams,
    pub sart: SartParams,
    pub mart: MartParams,
    pub smart: SmartParams,
    pub mlem: MlemParams,
    pub tv: TvParams,
    pub tikhonov: TikhonovParams,
}

impl Default for ClassicalConfig {
    fn default() -> Self {
        ClassicalConfig {
            projector: ProjectorKind::Splat,
            splat_subdivisions: 0,
            ray_step: 0.5,
            visual_hull: false,
            hull_threshold: DEFAULT_HULL_THRESHOLD,
            asart: AsartParams::default(),
            art: ArtParams::default(),
            sart: SartParams::default(),
            mart: MartParams::default(),
            smart: SmartParams::default(),
            mlem: MlemParams::default(),
            tv: TvParams::default(),
            tikhonov: TikhonovParams::default(),
        }
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
    classical: ClassicalConfig,
}

/// `report.json`.
#[derive(Serialize)]
struct RunReport {
    method: Method,
    version: String,
    projector: ProjectorKind,
    /// Sub-voxels per axis of the splat (splat projector).
    splat_subdivisions: Option<usize>,
    dims: [usize; 3],
    voxel_size: [f64; 3],
    views: usize,
    pixels: usize,
    iterations: usize,
    stop_reason: StopReason,
    final_residual: Option<f64>,
    residual_history: Vec<f64>,
    /// Voxels the visual hull kept, when used.
    hull_voxels: Option<usize>,
    setup_s: f64,
    solve_s: f64,
    seconds_per_iteration: f64,
    /// CPU seconds of the whole process (user + system), to read timings on a busy machine.
    cpu_s: Option<f64>,
    /// The reconstruction's part of the estimate.
    memory_estimate: MemoryEstimate,
    /// The whole estimate checked against the limit: reconstruction plus ground-truth scoring.
    memory_estimate_bytes: u64,
    /// Peak resident memory of the process (Linux).
    peak_rss_bytes: Option<u64>,
    /// Against the scene's ground truth (first step), when it has one.
    truth_metrics: Option<fluidnerf_metrics::StepMetrics>,
    /// Volume NRMSE over all of the truth's voxel centres (`truth_metrics.global.nrmse`).
    final_nrmse: Option<f64>,
    /// NRMSE over a subset of the truth's voxel centres during the run (see the module docs).
    nrmse_history: Vec<NrmsePoint>,
    /// Iterations between points of `nrmse_history` (0: only the last).
    eval_every: usize,
    /// Seconds spent on the evaluations of `nrmse_history` (not part of `solve_s`).
    eval_s: f64,
}

fn algorithm(method: Method) -> anyhow::Result<Algorithm> {
    Ok(match method {
        Method::Asart => Algorithm::Asart,
        Method::Art => Algorithm::Art,
        Method::Sart => Algorithm::Sart,
        Method::Mart => Algorithm::Mart,
        Method::Smart => Algorithm::Smart,
        Method::Mlem => Algorithm::Mlem,
        Method::Tv => Algorithm::Tv,
        Method::Tikhonov => Algorithm::Tikhonov,
        other => bail!("{other:?} is not a classical method"),
    })
}

/// The stopping rule and relaxation of the chosen method, for applying overrides.
fn method_knobs(cfg: &mut ClassicalConfig, alg: Algorithm) -> (&mut Stopping, Option<&mut f64>) {
    match alg {
        Algorithm::Asart => (&mut cfg.asart.stopping, Some(&mut cfg.asart.relaxation)),
        Algorithm::Art => (&mut cfg.art.stopping, Some(&mut cfg.art.relaxation)),
        Algorithm::Sart => (&mut cfg.sart.stopping, Some(&mut cfg.sart.relaxation)),
        Algorithm::Mart => (&mut cfg.mart.stopping, Some(&mut cfg.mart.relaxation)),
        Algorithm::Smart => (&mut cfg.smart.stopping, Some(&mut cfg.smart.relaxation)),
        Algorithm::Mlem => (&mut cfg.mlem.stopping, None),
        Algorithm::Tv => (&mut cfg.tv.stopping, Some(&mut cfg.tv.relaxation)),
        Algorithm::Tikhonov => (&mut cfg.tikhonov.stopping, Some(&mut cfg.tikhonov.relaxation)),
    }
}

/// Settings of this run: `--config` (if given) or the defaults, then the options given on the
/// command line. `--resolution` and `--seed` have clap defaults, so with `--config` a value
/// equal to the default counts as not given.
fn resolve(args: &super::reconstruct::Args, alg: Algorithm) -> anyhow::Result<(ClassicalConfig, usize, u64)> {
    let c = &args.classical;
    let (mut cfg, mut resolution, mut seed) = match &args.config {
        Some(path) => {
            let run: RunConfig = read_json(path, "a classical run configuration")?;
            if run.method != args.method {
                bail!(
                    "{} was written by --method {:?}; pass --method {:?} to rerun it",
                    path.display(),
                    run.method,
                    run.method
                );
            }
            (run.classical, run.resolution, run.seed)
        }
        None => (ClassicalConfig::default(), args.resolution, args.seed),
    };
    if args.resolution != 128 {
        resolution = args.resolution;
    }
    if args.seed != 0 {
        seed = args.seed;
    }
    if let Some(p) = c.projector {
        cfg.projector = match p {
            ProjectorArg::Splat => ProjectorKind::Splat,
            ProjectorArg::Ray => ProjectorKind::Ray,
        };
    }
    if let Some(n) = c.splat_subdivisions {
        cfg.splat_subdivisions = n;
    }
    if let Some(s) = c.ray_step {
        cfg.ray_step = s;
    }
    if c.visual_hull {
        cfg.visual_hull = true;
    }
    if let Some(t) = c.hull_threshold {
        cfg.hull_threshold = t;
    }
    if let Some(w) = c.tv_weight {
        cfg.tv.tv_weight = w;
    }
    if let Some(n) = c.tv_steps {
        cfg.tv.tv_steps = n;
    }
    if let Some(w) = c.tikhonov_weight {
        cfg.tikhonov.weight = w;
        if alg != Algorithm::Tikhonov {
            log::warn!("--tikhonov-weight has no effect on {alg:?}");
        }
    }
    cfg.art.seed = seed;
    cfg.mart.seed = seed;
    let (stopping, relaxation) = method_knobs(&mut cfg, alg);
    if let Some(m) = args.max_iterations {
        stopping.max_iterations = m;
    }
    if let Some(tol) = c.plateau_tolerance {
        stopping.plateau = if tol > 0.0 { Some(Plateau { tolerance: tol, ..Plateau::default() }) } else { None };
    }
    if let (Some(mu), Some(r)) = (c.relaxation, relaxation) {
        *r = mu;
    } else if c.relaxation.is_some() {
        log::warn!("--relaxation has no effect on {alg:?}");
    }
    validate(&cfg, alg, resolution)?;
    Ok((cfg, resolution, seed))
}

fn validate(cfg: &ClassicalConfig, alg: Algorithm, resolution: usize) -> anyhow::Result<()> {
    if !(1..=4096).contains(&resolution) {
        bail!("--resolution must be between 1 and 4096, got {resolution}");
    }
    if cfg.splat_subdivisions > 16 {
        bail!("--splat-subdivisions must be at most 16, got {}", cfg.splat_subdivisions);
    }
    if !(cfg.ray_step > 0.0 && cfg.ray_step <= 4.0) {
        bail!("--ray-step must be in (0, 4] voxel sides, got {}", cfg.ray_step);
    }
    if !(cfg.hull_threshold >= 0.0 && cfg.hull_threshold < 1.0) {
        bail!("--hull-threshold must be in [0, 1), got {}", cfg.hull_threshold);
    }
    if !(cfg.tv.tv_weight >= 0.0 && cfg.tv.tv_weight.is_finite()) {
        bail!("--tv-weight must be non-negative, got {}", cfg.tv.tv_weight);
    }
    if !(cfg.tikhonov.weight >= 0.0 && cfg.tikhonov.weight.is_finite()) {
        bail!("--tikhonov-weight must be non-negative, got {}", cfg.tikhonov.weight);
    }
    let mut c = cfg.clone();
    let (stopping, relaxation) = method_knobs(&mut c, alg);
    if stopping.max_iterations == 0 {
        bail!("--max-iterations must be at least 1");
    }
    if let Some(p) = stopping.plateau {
        if !(p.tolerance > 0.0 && p.tolerance.is_finite() && p.window > 0 && p.smoothing > 0) {
            bail!("invalid plateau rule {p:?}");
        }
    }
    if let Some(&mut mu) = relaxation {
        let upper = if matches!(alg, Algorithm::Mart | Algorithm::Smart) { 1.0 } else { 2.0 };
        if !(mu > 0.0 && mu <= upper) {
            bail!("--relaxation for {alg:?} must be in (0, {upper}], got {mu}");
        }
    }
    Ok(())
}

const GIB: f64 = (1u64 << 30) as f64;

pub fn run(args: &super::reconstruct::Args) -> anyhow::Result<()> {
    let t_start = Instant::now();
    let alg = algorithm(args.method)?;
    let (cfg, resolution, seed) = resolve(args, alg)?;
    let out = &args.out;
    let has_results = out.join("volume.npy").exists() || out.join("report.json").exists();
    if has_results && !args.force {
        bail!("{} already holds results; use --force to overwrite", out.display());
    }
    if args.resume {
        log::warn!("--resume applies to neural methods; a classical run starts afresh");
    }

    let scene = fluidnerf_io::scene::load_scene(&args.scene)
        .with_context(|| format!("loading scene {}", args.scene.display()))?;
    if scene.times().len() > 1 {
        log::warn!(
            "the scene has {} time steps; a classical reconstruction mixes them into one volume",
            scene.times().len()
        );
    }
    let grid = Grid::with_resolution(scene.aabb, resolution);
    let (cameras, sizes): (Vec<_>, Vec<_>) =
        scene.training_frames().map(|(_, f)| (f.camera.clone(), (f.camera.width(), f.camera.height()))).unzip();
    if cameras.is_empty() {
        bail!("{}: every frame is held out; nothing to reconstruct from", args.scene.display());
    }
    let threads = rayon::current_num_threads();
    let subdivisions = match cfg.splat_subdivisions {
        0 => SplatProjector::auto_subdivisions(&grid, &cameras),
        n => n,
    };
    let estimate = estimate_memory(alg, cfg.projector, &grid, &sizes, threads, subdivisions);
    // Scoring against the truth holds it, a copy resampled to its grid and temporaries; the
    // NRMSE curve adds a copy of the working volume to sample from.
    let truth_bytes: u64 = scene
        .truth
        .first()
        .and_then(|t| std::fs::metadata(scene.resolve(&t.file_path)).ok())
        .map_or(0, |m| 3 * m.len() + 4 * grid.len() as u64);
    let needed = estimate.total() + truth_bytes;
    let limit = match args.classical.memory_limit {
        Some(gib) => (gib * GIB) as u64,
        None => proc_kib("/proc/meminfo", "MemAvailable:").unwrap_or(24 << 30),
    };
    log::info!(
        "{alg:?} on {:?} voxels from {} views: about {:.2} GiB ({:.2} GiB allowed)",
        grid.dims,
        cameras.len(),
        needed as f64 / GIB,
        limit as f64 / GIB
    );
    if needed > limit {
        bail!(
            "{alg:?} at {:?} voxels with {} views of {:?} needs about {:.2} GiB (volumes {:.2}, images {:.2}, projector \
             {:.2}, ground truth {:.2}) but only {:.2} GiB are allowed; lower --resolution, use --projector splat, or \
             raise --memory-limit",
            grid.dims,
            cameras.len(),
            sizes.first().copied().unwrap_or_default(),
            needed as f64 / GIB,
            estimate.volumes as f64 / GIB,
            estimate.images as f64 / GIB,
            estimate.projector as f64 / GIB,
            truth_bytes as f64 / GIB,
            limit as f64 / GIB
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;

    let all_images = fluidnerf_io::scene::load_images(&scene)
        .with_context(|| format!("loading the images of {}", args.scene.display()))?;
    let images: Vec<Image> =
        scene.frames.iter().zip(all_images).filter(|(f, _)| !f.holdout).map(|(_, im)| im).collect();
    let projector: Box<dyn Projector> = match cfg.projector {
        ProjectorKind::Splat => {
            Box::new(SplatProjector::new(grid, &cameras, scene.intensity_scale)?.with_subdivisions(subdivisions))
        }
        ProjectorKind::Ray => Box::new(RayProjector::new(grid, &cameras, scene.intensity_scale, cfg.ray_step)?),
    };
    let voxel = grid.spacing();
    let footprint_px = voxel_footprint_px(&cameras, &grid);
    if cfg.projector == ProjectorKind::Splat && footprint_px / subdivisions as f64 > 2.0 {
        log::warn!(
            "voxels cover about {footprint_px:.1} pixels and are split into only {subdivisions}³: the splat leaves \
             gaps; raise --splat-subdivisions (0: automatic) or use --projector ray"
        );
    }
    let hull = cfg.visual_hull.then(|| visual_hull(&grid, &cameras, &images, cfg.hull_threshold));
    let hull_voxels = hull.as_ref().map(|h| h.iter().filter(|&&b| b).count());
    if let Some(kept) = hull_voxels {
        log::info!("visual hull keeps {kept} of {} voxels", grid.len());
    }
    let mut problem = Problem::new(projector.as_ref(), &images)?;
    if let Some(h) = &hull {
        problem = problem.with_support(h);
    }

    let run_config = RunConfig {
        method: args.method,
        scene: args.scene.clone(),
        seed,
        resolution,
        version: env!("CARGO_PKG_VERSION").to_string(),
        classical: cfg.clone(),
    };
    write_json(&out.join("config.json"), &run_config)?;
    let setup_s = t_start.elapsed().as_secs_f64();

    let truth = match fluidnerf_io::scene::load_truth(&scene) {
        Ok(t) => t.into_iter().next(),
        Err(e) => {
            log::warn!("ground truth not used: {e}");
            None
        }
    };
    let eval_every = args.neural.eval_every.unwrap_or(1);
    let mut curve = truth.as_ref().map(|(_, t)| Curve::new(t, grid, eval_every));

    let mut knobs = cfg.clone();
    let cap = method_knobs(&mut knobs, alg).0.max_iterations;
    let bar = crate::progress::bar(cap as u64, &format!("{alg:?}").to_lowercase());
    let t_solve = Instant::now();
    let on_iter = |s: &IterState| {
        if let Some(c) = curve.as_mut() {
            c.record(s, t_solve);
        }
        bar.set_position(s.iteration as u64);
        let nrmse = curve.as_ref().and_then(|c| c.points.last()).map(|p| format!(", NRMSE {:.4}", p.nrmse));
        bar.set_message(format!("residual {:.4}{}", s.residual, nrmse.unwrap_or_default()));
        if crate::interrupt::requested() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    };
    let report: Report = match alg {
        Algorithm::Asart => asart(&problem, None, &cfg.asart, on_iter),
        Algorithm::Art => art(&problem, None, &cfg.art, on_iter),
        Algorithm::Sart => sart(&problem, None, &cfg.sart, on_iter),
        Algorithm::Mart => mart(&problem, None, &cfg.mart, on_iter),
        Algorithm::Smart => smart(&problem, None, &cfg.smart, on_iter),
        Algorithm::Mlem => mlem(&problem, None, &cfg.mlem, on_iter),
        Algorithm::Tv => sart_tv(&problem, None, &cfg.tv, on_iter),
        Algorithm::Tikhonov => sart_tikhonov(&problem, None, &cfg.tikhonov, on_iter),
    }
    .with_context(|| format!("reconstructing with {alg:?}"))?;
    let eval_s = curve.as_ref().map_or(0.0, |c| c.eval_s);
    let solve_s = t_solve.elapsed().as_secs_f64() - eval_s;
    bar.finish_and_clear();

    let volume = grid.volume(report.volume);
    let npy = out.join("volume.npy");
    fluidnerf_io::volume::write_npy(&npy, &volume).with_context(|| format!("writing {}", npy.display()))?;
    let vti = out.join("volume.vti");
    fluidnerf_io::volume::write_vti(&vti, &volume).with_context(|| format!("writing {}", vti.display()))?;

    let truth_metrics = match &truth {
        Some((time, truth)) => Some(
            fluidnerf_metrics::report::evaluate_volume(&volume, truth, *time, &Default::default())
                .context("scoring against the ground truth")?,
        ),
        None => None,
    };
    let iterations = report.iterations;
    let nrmse_history = match curve {
        Some(mut c) => {
            if c.points.last().is_none_or(|p| p.iteration != iterations) {
                c.push(iterations, solve_s, &volume.data);
            }
            c.points
        }
        None => Vec::new(),
    };
    let run_report = RunReport {
        method: args.method,
        version: env!("CARGO_PKG_VERSION").to_string(),
        projector: cfg.projector,
        splat_subdivisions: (cfg.projector == ProjectorKind::Splat).then_some(subdivisions),
        dims: grid.dims,
        voxel_size: [voxel.x, voxel.y, voxel.z],
        views: cameras.len(),
        pixels: sizes.iter().map(|&(w, h)| w * h).sum(),
        iterations,
        stop_reason: report.stop_reason,
        final_residual: report.residual_history.last().copied(),
        residual_history: report.residual_history,
        hull_voxels,
        setup_s,
        solve_s,
        seconds_per_iteration: solve_s / iterations.max(1) as f64,
        cpu_s: cpu_seconds(),
        memory_estimate: estimate,
        memory_estimate_bytes: needed,
        peak_rss_bytes: proc_kib("/proc/self/status", "VmHWM:"),
        final_nrmse: truth_metrics.as_ref().map(|m| m.global.nrmse),
        truth_metrics,
        nrmse_history,
        eval_every,
        eval_s,
    };
    write_json(&out.join("report.json"), &run_report)?;

    let stop = match run_report.stop_reason {
        StopReason::Converged => "converged",
        StopReason::MaxIterations => "iteration cap",
        StopReason::Interrupted => "interrupted",
    };
    let mut line = format!(
        "{}: {iterations} iterations ({stop}), residual {:.4}, {solve_s:.1} s",
        format!("{alg:?}").to_lowercase(),
        run_report.final_residual.unwrap_or(f64::NAN)
    );
    if let Some(m) = &run_report.truth_metrics {
        line += &format!(", NRMSE {:.4}, SSIM {:.4}", m.global.nrmse, m.global.ssim_global);
    }
    #[allow(clippy::print_stdout)]
    {
        println!("{line}");
        println!("wrote {} ({:?} voxels), {}, config.json, report.json", npy.display(), grid.dims, vti.display());
    }
    Ok(())
}

/// The NRMSE curve of a run: evaluations over a [`TruthSample`] every `every` iterations, their
/// time kept apart from the solver's.
struct Curve {
    sample: TruthSample,
    /// The solver's volume, copied for trilinear sampling at the truth's voxel centres.
    scratch: fluidnerf_core::Volume,
    every: usize,
    points: Vec<NrmsePoint>,
    eval_s: f64,
}

impl Curve {
    fn new(truth: &fluidnerf_core::Volume, grid: Grid, every: usize) -> Self {
        Curve {
            sample: TruthSample::new(truth),
            scratch: grid.volume(vec![0.0; grid.len()]),
            every,
            points: Vec::new(),
            eval_s: 0.0,
        }
    }

    /// Evaluates after an iteration when due; `t_solve` is when the solver started.
    fn record(&mut self, s: &IterState, t_solve: Instant) {
        if self.every > 0 && s.iteration % self.every == 0 {
            let train_time_s = t_solve.elapsed().as_secs_f64() - self.eval_s;
            self.push(s.iteration, train_time_s, s.volume);
        }
    }

    fn push(&mut self, iteration: usize, train_time_s: f64, volume: &[f32]) {
        let t0 = Instant::now();
        self.scratch.data.copy_from_slice(volume);
        let nrmse = self.sample.nrmse(&self.scratch);
        self.points.push(NrmsePoint { iteration, train_time_s, nrmse });
        self.eval_s += t0.elapsed().as_secs_f64();
    }
}

/// Largest side of a voxel's image, in pixels, over the views (at the box centre).
fn voxel_footprint_px(cameras: &[fluidnerf_core::Camera], grid: &Grid) -> f64 {
    let side = grid.spacing().max_element();
    cameras
        .iter()
        .map(|c| {
            let depth = (grid.aabb.centre() - c.centre()).dot(c.forward()).max(1e-9);
            side * c.intrinsics.fx.max(c.intrinsics.fy) / depth
        })
        .fold(0.0, f64::max)
}
