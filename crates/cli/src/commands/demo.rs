//! `fluidnerf demo`: the whole pipeline on a small built-in example: synth, four
//! reconstructions through the run pipeline under one stopping policy, eval, then one table,
//! one slice figure, one convergence plot and one HTML report comparing them.

use std::path::{Path, PathBuf};
use std::time::Instant;

use fluidnerf_pipeline::html::{self, RunSummary};
use fluidnerf_pipeline::{Method, Overwrite, RunConfig, RunStatus, StopReason, StoppingPolicy};

use anyhow::Context;
use fluidnerf_pipeline::rundir::{folder_kind, FolderKind};

use super::reconstruct::StopArg;

/// The files a demo writes at the top of its folder, `comparison.json` (which marks a demo
/// folder) first.
const DEMO_FILES: [&str; 4] = ["comparison.json", "report.html", "slices.png", "convergence.png"];

/// The demo's image noise by default, as a fraction of each image's maximum.
const DEFAULT_NOISE: f64 = 0.025;

/// Run the whole pipeline on a built-in example and compare FluidNeRF with classical
/// tomography.
///
/// Synthesises a small turbulent-jet scene (or the scene of --preset), reconstructs it with FluidNeRF (the fast grid
/// field), with the hybrid (the same field started from a voxel reconstruction, its method
/// chosen by the images' noise), with ASART (the dissertation's classical baseline) and with
/// SART-TV (SART regularised by total variation, the classical method made for noisy
/// images) under the same stopping policy — held-out early stopping: each keeps the iterate
/// whose loss on the held-out camera was lowest, and stops after 10 evaluations without
/// improvement, or when the same time budget of its own work is spent; no method's own
/// iteration cap ends it, as in `study`, and no ground truth is used — scores them against
/// the known truth, and writes pictures and a self-contained report.html.
///
/// Everything lands in OUT: `scene/` (the synthetic data set), `fluidnerf/`, `hybrid/`,
/// `asart/` and `sart-tv/` (one run folder each, with volumes, settings and reports),
/// `slices.png`, `convergence.png`, `comparison.json` and `report.html`. OUT is a new folder or
/// an earlier demo's (replaced with --force); a scene, a run, a study or any other folder
/// holding files of those names is refused. Takes about a minute on a 2-core machine (53–65 s
/// on a 2-core AMD EPYC, build excluded).
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output directory.
    #[arg(short, long, default_value = "fluidnerf-demo")]
    pub out: PathBuf,
    /// Synthetic scene preset of one instant (see `fluidnerf synth --list-presets`); one of
    /// several instants is refused, as every method would mix them into one field.
    #[arg(long, default_value = "demo")]
    pub preset: String,
    /// Voxels along the longest side of the reconstructed volumes, 2 to 4096.
    #[arg(long, default_value_t = 96)]
    pub resolution: usize,
    /// Gaussian image noise, as a fraction of each image's maximum; 0 gives noiseless images
    /// [default: 0.025; none for the real-like presets, whose 8-bit images carry the recording's
    /// own dark noise and refuse this one].
    #[arg(long, allow_negative_numbers = true)]
    pub noise: Option<f64>,
    /// Camera held out of every reconstruction: it drives the early stopping and scores the
    /// reprojections.
    #[arg(long, default_value_t = 7)]
    pub holdout: usize,
    /// The stopping rule of every method.
    #[arg(long, value_enum, default_value = "held-out")]
    pub stop: StopArg,
    /// Iteration cap of every method [default: 1000000 under held-out and budget, so that the
    /// held-out rule or the time budget ends every run, not a method's own cap (SART-TV 50,
    /// ASART 250, the fields 2000); each method's own under own].
    #[arg(long, value_parser = super::parse_max_iterations)]
    pub max_iterations: Option<usize>,
    /// Seconds of work per run, the same for every method.
    #[arg(long, default_value_t = 60.0, allow_negative_numbers = true)]
    pub time_budget: f64,
    /// Seed of the synthetic noise and of training.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true, value_parser = super::parse_seed)]
    pub seed: u64,
    /// Replace the results of an earlier demo in OUT.
    #[arg(long)]
    pub force: bool,
}

fn words(s: &str) -> Vec<String> {
    s.split_whitespace().map(str::to_string).collect()
}

fn path(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// The demo stopped by Ctrl-C, and what it says: the command exits with 130, as a stopped
/// reconstruction does, not as one that failed.
#[derive(Debug)]
pub struct Interrupted(pub String);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Interrupted {}

pub fn run(args: Args) -> anyhow::Result<()> {
    let out = &args.out;
    if !(args.time_budget > 0.0 && args.time_budget.is_finite()) {
        anyhow::bail!(
            "--time-budget must be a positive, finite number of seconds, got {}",
            fluidnerf_core::number::num(args.time_budget)
        );
    }
    // Before the folder is made: synthesising a preset of several instants took minutes, then
    // every method mixed them into one field.
    super::static_preset("--preset", &args.preset, "the demo")?;
    // A demo writes its scene, its runs and the files of DEMO_FILES into OUT: never into another
    // kind of fluidnerf folder (a scene took a demo inside it, a study's report.html was
    // replaced), nor over files of those names in a folder that holds no demo.
    fluidnerf_pipeline::rundir::refuse_other_kind(out, FolderKind::Demo, "demo")?;
    let earlier = folder_kind(out) == Some(FolderKind::Demo);
    if earlier && !args.force {
        anyhow::bail!("{} already holds a demo; pass --force to replace it", out.display());
    }
    if !earlier {
        if let Some(file) = DEMO_FILES.into_iter().find(|f| out.join(f).exists()) {
            anyhow::bail!(
                "{} holds {file} but no comparison.json, so it is not a demo folder; a demo would overwrite it: \
                 choose another output folder",
                out.display()
            );
        }
    }
    let scene_dir = out.join("scene");
    let stopping = StoppingPolicy {
        rule: args.stop.into(),
        max_iterations: args.max_iterations.or(super::comparison_cap(args.stop)),
        time_budget_s: Some(args.time_budget),
        ..StoppingPolicy::default()
    };
    // SART-TV beside ASART: on noisy images it is the better classical method, and the
    // fields are measured against the best of them (docs/claims.md).
    let methods =
        [("fluidnerf", Method::Fast), ("hybrid", Method::Hybrid), ("asart", Method::Asart), ("sart-tv", Method::Tv)];
    let mut configs = Vec::with_capacity(methods.len());
    for (_, method) in methods {
        let mut config = RunConfig::new(std::path::absolute(&scene_dir)?, method);
        config.resolution = args.resolution;
        config.seed = args.seed;
        config.stopping = stopping;
        // Before the scene is made: a setting no run can use (--resolution 0) failed only at
        // the first run, leaving the scene behind.
        config.validate().map_err(|e| match &e {
            fluidnerf_pipeline::PipelineError::Invalid { key, why } if key == "resolution" => {
                anyhow::anyhow!("--resolution {}: {why}", args.resolution)
            }
            _ => anyhow::Error::new(e),
        })?;
        configs.push(config);
    }
    // A real-like preset's images carry their own noise: the default adds none to them (the
    // demo's 0.025 made `synth` refuse a --noise the user never gave).
    let real_like = fluidnerf_synth::preset(&args.preset).is_ok_and(|s| s.real.is_some());
    let noise = match (args.noise, real_like) {
        (Some(n), _) => format!(" --noise {n}"),
        (None, true) => String::new(),
        (None, false) => format!(" --noise {DEFAULT_NOISE}"),
    };
    let mut synth_line =
        words(&format!("synth --preset {} --seed {}{noise} --holdout {} -o", args.preset, args.seed, args.holdout));
    synth_line.push(path(&scene_dir));
    if args.force {
        synth_line.push("--force".into());
    }
    // The scene's settings too (--noise 2, --holdout 99): refused, they left an empty folder.
    {
        use clap::Parser;
        let argv = std::iter::once("fluidnerf".to_string()).chain(synth_line.iter().cloned());
        let super::Command::Synth(synth) =
            crate::Cli::try_parse_from(argv).map_err(|e| anyhow::anyhow!("{e}"))?.command
        else {
            anyhow::bail!("not a synth line: {}", synth_line.join(" "));
        };
        super::synth::resolve(&synth)?;
    }
    super::create_output_folder(out)?;
    let start = Instant::now();
    #[allow(clippy::print_stdout)]
    let say = |what: &str| println!("\n== demo: {what}");

    say("synthesising the scene");
    // A synthesis stopped by Ctrl-C writes nothing and returns no error: without this the
    // first run went on to look for the scene and failed, blaming a missing transforms.json.
    if super::run_line(&synth_line)? != std::process::ExitCode::SUCCESS {
        return Err(
            Interrupted("interrupted before the scene was made; rerun the same command to start again".into()).into()
        );
    }
    // The scene is replaced: an earlier demo's comparison and pictures would otherwise stand
    // beside this one's runs if it failed half way.
    for file in DEMO_FILES {
        let p = out.join(file);
        if p.is_file() {
            std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
        }
    }

    let mut wall = Vec::new();
    for ((dir, method), config) in methods.iter().zip(&configs) {
        say(&format!("reconstructing with {} ({})", method.label(), stopping.describe(method.family())));
        let t = Instant::now();
        let overwrite = if args.force { Overwrite::Force } else { Overwrite::Refuse };
        let report = super::reconstruct::run_config(config, &out.join(dir), overwrite)?;
        #[allow(clippy::print_stdout)]
        {
            println!("{}", report.summary_line());
        }
        if report.status == RunStatus::Interrupted {
            return Err(Interrupted(format!(
                "interrupted; the runs so far are in {}; rerun the command with --force to start again",
                out.display()
            ))
            .into());
        }
        wall.push(t.elapsed().as_secs_f64());
    }

    say("evaluating");
    for (dir, method) in methods {
        let run_dir = out.join(dir);
        let mut line = vec!["eval".to_string(), path(&run_dir), "--scene".into(), path(&scene_dir)];
        // Every method through the volume it wrote, as `study` scores them: the fields' held-out
        // views rendered from the field read better than the voxel methods' from their volumes.
        if method.is_field() {
            line.push("--use-volume".into());
        }
        line.extend([
            "--json".into(),
            path(&run_dir.join("metrics.json")),
            "--csv".into(),
            path(&run_dir.join("metrics.csv")),
            "--force".into(),
        ]);
        if super::run_line(&line)? != std::process::ExitCode::SUCCESS {
            anyhow::bail!("scoring {} did not finish", run_dir.display());
        }
    }

    let scene = fluidnerf_io::scene::load_scene(&scene_dir)?;
    let truth = fluidnerf_io::scene::load_truth(&scene)?.into_iter().next().map(|(_, v)| v);
    let runs: Vec<RunSummary> =
        methods.iter().map(|(dir, m)| html::summarise(&out.join(dir), m.label())).collect::<Result<_, _>>()?;
    let refs: Vec<&RunSummary> = runs.iter().collect();

    // The folder's marker first: a demo that fails below is still known for one.
    let comparison: Vec<serde_json::Value> = runs
        .iter()
        .zip(&wall)
        .map(|(r, w)| {
            serde_json::json!({
                "method": r.label,
                "run_dir": r.dir,
                "wall_s": w,
                "train_time_s": r.report.train_time_s,
                "iterations": r.report.iterations,
                "kept_iteration": r.report.kept_iteration,
                "stopping": r.report.stopping_rule,
                "result_bytes": r.report.result_bytes,
                "holdout_nrmse": r.holdout_nrmse,
                "metrics": r.metrics(),
            })
        })
        .collect();
    let text = serde_json::to_string_pretty(&comparison)?;
    fluidnerf_io::atomic_write(&out.join("comparison.json"), |w| w.write_all(text.as_bytes()))?;

    let against = against_best_voxel(&runs, &methods.map(|(_, m)| m));
    let mut report = html::build_report(
        &format!(
            "fluidnerf demo: FluidNeRF, the hybrid, ASART and SART-TV on the synthetic scene `{}`, all stopped by {}",
            args.preset,
            stopping.describe_rule()
        ),
        &scene,
        truth.as_ref(),
        &refs,
    )?;
    if let Some(line) = &against {
        report.summary.push(("fields".into(), line.clone()));
    }
    let slices = html::slice_figure(truth.as_ref(), &refs, &scene.units)?;
    fluidnerf_io::atomic_write(&out.join("slices.png"), |w| w.write_all(&slices))?;
    let histories: Vec<_> = runs.iter().map(|r| r.history.clone()).collect();
    fluidnerf_viz::write_plots(&out.join("convergence.png"), &fluidnerf_viz::convergence_plots(&histories), 2)?;
    fluidnerf_viz::report::write_report_html(&out.join("report.html"), &report)?;

    print_table(&runs, &wall, &stopping);
    if let Some(line) = against {
        #[allow(clippy::print_stdout)]
        {
            println!("{line}");
        }
    }
    #[allow(clippy::print_stdout)]
    {
        println!(
            "\ntotal {:.1} s; open {} in a browser",
            start.elapsed().as_secs_f64(),
            out.join("report.html").display()
        );
    }
    Ok(())
}

/// The fields' volume NRMSE as ratios to the best voxel method's (the project's measure of
/// accuracy; `study` gives it per cell), in one line: None without a truth.
fn against_best_voxel(runs: &[RunSummary], methods: &[Method]) -> Option<String> {
    let nrmse = |r: &RunSummary| r.metrics().map(|m| m.global.nrmse);
    let (best, best_nrmse) = runs
        .iter()
        .zip(methods)
        .filter(|(_, m)| !m.is_field())
        .filter_map(|(r, _)| nrmse(r).map(|v| (r, v)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let fields: Vec<String> = runs
        .iter()
        .zip(methods)
        .filter(|(_, m)| m.is_field())
        .filter_map(|(r, _)| nrmse(r).map(|v| format!("{} {:.2}×", r.label, v / best_nrmse)))
        .collect();
    (!fields.is_empty()).then(|| {
        format!(
            "against the best voxel method, {} (NRMSE {best_nrmse:.4}): {} (below 1 the field is the more accurate)",
            best.label,
            fields.join(", ")
        )
    })
}

#[allow(clippy::print_stdout)]
fn print_table(runs: &[RunSummary], wall: &[f64], stopping: &StoppingPolicy) {
    let Some(first) = runs.iter().find_map(|r| r.metrics()) else { return };
    println!("\nvolume metrics against the truth; held-out = reprojection NRMSE of the held-out camera");
    println!("every method stopped by {}", stopping.describe_rule());
    print!("\n{:<24} {:>7} {:>8} {:>8} {:>8}", "method", "NRMSE", "SSIM", "SSIM-w", "PSNR");
    for r in &first.regions {
        print!(" {:>11}", format!("NRMSE-{}", &r.region.name[..r.region.name.len().min(5)]));
    }
    println!(" {:>9} {:>11} {:>8} {:>11}", "held-out", "kept/iters", "wall [s]", "result");
    for (r, w) in runs.iter().zip(wall) {
        let Some(m) = r.metrics() else { continue };
        print!(
            "{:<24} {:>7.4} {:>8.4} {:>8} {:>8.2}",
            r.label,
            m.global.nrmse,
            m.global.ssim_global,
            m.global.ssim_windowed.map_or("–".into(), |s| format!("{s:.4}")),
            m.global.psnr_db
        );
        for g in &m.regions {
            print!(" {:>11.4}", g.metrics.nrmse);
        }
        let held_out = r.holdout_nrmse.map_or("–".into(), |v| format!("{v:.4}"));
        let capped = r.report.stop_reason.mark();
        let kept = format!("{}/{}{capped}", r.report.kept_iteration, r.report.iterations);
        println!(" {:>9} {:>11} {:>8.1} {:>11}", held_out, kept, w, fluidnerf_pipeline::bytes(r.report.result_bytes));
    }
    if runs.iter().any(|r| r.report.stop_reason == StopReason::IterationCap) {
        println!("* ended by the iteration cap (--max-iterations) before the held-out rule ended it");
    }
    if runs.iter().any(|r| r.report.stop_reason == StopReason::TimeBudget) {
        println!("t ended by the time budget (--time-budget) before the held-out rule ended it");
    }
}
