//! `fluidnerf demo`: the whole pipeline on a small built-in example. It runs the same
//! subcommands a user would (synth → reconstruct × 2 → eval), then compares the two
//! reconstructions in one table, one slice figure, one convergence plot and one HTML report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Parser;

use crate::run_report::{self, RunSummary};

/// Run the whole pipeline on a built-in example and compare FluidNeRF with ASART.
///
/// Synthesises a small turbulent-jet scene, reconstructs it with FluidNeRF (the fast grid
/// field) and with ASART (the classical baseline), scores both against the known truth, and
/// writes pictures and a self-contained report.html.
///
/// Everything lands in OUT: `scene/` (the synthetic data set), `fluidnerf/` and `asart/` (one
/// run directory each, with volumes, settings and reports), `slices.png`, `convergence.png`,
/// `comparison.json` and `report.html`. Takes a minute or two on a 2-core machine.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output directory.
    #[arg(short, long, default_value = "fluidnerf-demo")]
    pub out: PathBuf,
    /// Synthetic scene preset (see `fluidnerf synth --list-presets`).
    #[arg(long, default_value = "demo")]
    pub preset: String,
    /// Voxels along the longest side of the reconstructed volumes.
    #[arg(long, default_value_t = 96)]
    pub resolution: usize,
    /// Gaussian image noise, as a fraction of each image's maximum. FluidNeRF's advantage over
    /// ASART grows with noise (dissertation §7.1); 0 gives noiseless images.
    #[arg(long, default_value_t = 0.025)]
    pub noise: f64,
    /// Camera held out of both reconstructions and used to score their reprojections.
    #[arg(long, default_value_t = 7)]
    pub holdout: usize,
    /// FluidNeRF training iterations. On noisy images a grid field starts to fit the noise
    /// after a few hundred iterations; the demo keeps the field whose held-out camera loss was
    /// lowest (`--keep-best-holdout`), which needs no ground truth.
    #[arg(long, default_value_t = 300)]
    pub iterations: usize,
    /// Seed of the synthetic noise and of training.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Replace the results of an earlier demo in OUT.
    #[arg(long)]
    pub force: bool,
}

/// Runs one subcommand line in-process, exactly as the user would type it.
fn fluidnerf(line: &[String]) -> anyhow::Result<()> {
    let mut argv = vec!["fluidnerf".to_string()];
    argv.extend(line.iter().cloned());
    let cli = crate::Cli::try_parse_from(&argv).map_err(|e| anyhow::anyhow!("{e}"))?;
    super::run(cli.command)
}

fn words(s: &str) -> Vec<String> {
    s.split_whitespace().map(str::to_string).collect()
}

fn path(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let out = &args.out;
    if out.join("report.html").exists() && !args.force {
        anyhow::bail!("{} already holds a demo; pass --force to replace it", out.display());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let force = if args.force { vec!["--force".to_string()] } else { Vec::new() };
    let start = Instant::now();
    let scene_dir = out.join("scene");
    #[allow(clippy::print_stdout)]
    let say = |what: &str| println!("\n== demo: {what}");

    say("synthesising the scene");
    let mut line = words(&format!(
        "synth --preset {} --seed {} --noise {} --holdout {} -o",
        args.preset, args.seed, args.noise, args.holdout
    ));
    line.push(path(&scene_dir));
    line.extend(force.clone());
    fluidnerf(&line)?;

    let methods = [("fluidnerf", "fast", "FluidNeRF (fast field)"), ("asart", "asart", "ASART")];
    let mut wall = Vec::new();
    for (dir, method, label) in methods {
        say(&format!("reconstructing with {label}"));
        let t = Instant::now();
        let mut line = vec!["reconstruct".to_string(), path(&scene_dir), "-o".into(), path(&out.join(dir))];
        line.extend(words(&format!("--method {method} --resolution {} --seed {}", args.resolution, args.seed)));
        if method == "fast" {
            line.extend(words(&format!("--max-iterations {} --keep-best-holdout", args.iterations)));
        }
        line.extend(force.clone());
        fluidnerf(&line)?;
        wall.push(t.elapsed().as_secs_f64());
    }

    say("evaluating");
    for (dir, _, _) in methods {
        let run_dir = out.join(dir);
        let mut line = vec!["eval".to_string(), path(&run_dir), "--scene".into(), path(&scene_dir)];
        line.extend([
            "--json".into(),
            path(&run_dir.join("metrics.json")),
            "--csv".into(),
            path(&run_dir.join("metrics.csv")),
        ]);
        fluidnerf(&line)?;
    }

    let scene = fluidnerf_io::scene::load_scene(&scene_dir)?;
    let truth = fluidnerf_io::scene::load_truth(&scene)?.into_iter().next().map(|(_, v)| v);
    let runs: Vec<RunSummary> = methods
        .iter()
        .map(|(dir, _, label)| run_report::summarise(&out.join(dir), label, truth.as_ref(), &scene))
        .collect::<anyhow::Result<_>>()?;
    let refs: Vec<&RunSummary> = runs.iter().collect();

    let report = run_report::build_report(
        "fluidnerf demo: FluidNeRF and ASART on a synthetic jet",
        &scene,
        truth.as_ref(),
        &refs,
    )?;
    let slices = run_report::slice_figure(truth.as_ref(), &refs, &scene.units)?;
    fluidnerf_io::atomic_write(&out.join("slices.png"), |w| w.write_all(&slices))?;
    let histories: Vec<_> = runs.iter().map(|r| r.history.clone()).collect();
    fluidnerf_viz::write_plots(&out.join("convergence.png"), &fluidnerf_viz::convergence_plots(&histories), 2)?;
    fluidnerf_viz::report::write_report_html(&out.join("report.html"), &report)?;

    let comparison: Vec<serde_json::Value> = runs
        .iter()
        .zip(&wall)
        .map(|(r, w)| {
            serde_json::json!({
                "method": r.label,
                "run_dir": r.dir,
                "wall_s": w,
                "compute_s": r.compute_s,
                "iterations": r.iterations,
                "result_bytes": r.result_bytes,
                "metrics": r.metrics,
            })
        })
        .collect();
    let text = serde_json::to_string_pretty(&comparison)?;
    fluidnerf_io::atomic_write(&out.join("comparison.json"), |w| w.write_all(text.as_bytes()))?;

    print_table(&runs, &wall);
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

#[allow(clippy::print_stdout)]
fn print_table(runs: &[RunSummary], wall: &[f64]) {
    let Some(first) = runs.iter().find_map(|r| r.metrics.as_ref()) else { return };
    println!("\nvolume metrics against the truth; held-out = reprojection NRMSE of the held-out camera");
    print!("\n{:<24} {:>7} {:>8} {:>8} {:>8}", "method", "NRMSE", "SSIM", "SSIM-w", "PSNR");
    for r in &first.regions {
        print!(" {:>11}", format!("NRMSE-{}", &r.region.name[..r.region.name.len().min(5)]));
    }
    println!(" {:>9} {:>8} {:>11}", "held-out", "wall [s]", "result");
    for (r, w) in runs.iter().zip(wall) {
        let Some(m) = &r.metrics else { continue };
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
        println!(" {:>9} {:>8.1} {:>11}", held_out, w, run_report::bytes(r.result_bytes));
    }
}
