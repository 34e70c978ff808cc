//! The `report.html` every reconstruction run directory gets, and the run summaries the demo
//! compares. A run directory holds `config.json`, `report.json` (method-specific: loss or
//! residual history, timing), `volume.npy` on the scene's box, and for neural methods the
//! weights; this module reads them back, so it works for any method and for old runs.

use std::path::{Path, PathBuf};

use anyhow::Context;
use fluidnerf_core::{Scene, Volume};
use fluidnerf_metrics::{evaluate_volume, StepMetrics, VolumeMetricOptions};
use fluidnerf_viz::report::{Figure, ImageData, Report, Table};
use fluidnerf_viz::{Axis, PanelGroup, PanelStyle, RunHistory, Trace};
use serde_json::Value;

/// What a finished run produced, read back from its directory.
pub struct RunSummary {
    pub dir: PathBuf,
    /// Legend and table label, e.g. "ASART".
    pub label: String,
    pub config: Value,
    pub volume: Volume,
    /// Seconds the method reported for its own work (training or iterations).
    pub compute_s: Option<f64>,
    pub iterations: Option<usize>,
    /// Bytes of the compact result: the weights for neural fields, the volume otherwise.
    pub result_bytes: u64,
    pub history: RunHistory,
    /// Metrics against the scene's first truth volume, when it has one.
    pub metrics: Option<StepMetrics>,
    /// Mean reprojection NRMSE over the held-out frames, from `metrics.json` when
    /// `fluidnerf eval` has scored the run.
    pub holdout_nrmse: Option<f64>,
}

fn read_json(path: &Path) -> anyhow::Result<Value> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
}

/// Looks up the first of several dotted key paths that holds a number.
fn number(v: &Value, paths: &[&str]) -> Option<f64> {
    paths.iter().find_map(|p| p.split('.').try_fold(v, |v, k| v.get(k)).and_then(Value::as_f64))
}

fn numbers(v: &Value, key: &str) -> Option<Vec<f64>> {
    v.get(key)?.as_array().map(|a| a.iter().filter_map(Value::as_f64).collect())
}

/// Reads a run directory; `truth` (the scene's first truth volume) enables the metrics.
pub fn summarise(dir: &Path, label: &str, truth: Option<&Volume>, scene: &Scene) -> anyhow::Result<RunSummary> {
    let config = read_json(&dir.join("config.json")).unwrap_or(Value::Null);
    let report = read_json(&dir.join("report.json"))?;
    let volume_path = dir.join("volume.npy");
    let volume = fluidnerf_io::volume::read_npy(&volume_path, scene.aabb)?;
    let compute_s = number(&report, &["train.train_time_s", "solve_s"]);
    let iterations = number(&report, &["train.iterations", "iterations"]).map(|n| n as usize);

    let weights: u64 = std::fs::read_dir(dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .filter_map(Result::ok)
        .filter(|e| {
            e.path().extension().is_some_and(|x| x == "safetensors")
                && !e.path().to_string_lossy().contains("checkpoint")
        })
        .filter_map(|e| e.metadata().ok().map(|m| m.len()))
        .sum();
    let result_bytes =
        if weights > 0 { weights } else { std::fs::metadata(&volume_path).map(|m| m.len()).unwrap_or(0) };

    let (loss, loss_label) = match (numbers(&report, "loss_history"), numbers(&report, "residual_history")) {
        (Some(l), _) => (l, "training loss (MSE)"),
        (None, Some(r)) => (r, "relative residual"),
        (None, None) => (Vec::new(), "loss"),
    };
    let per_iter = match (compute_s, loss.len()) {
        (Some(t), n) if n > 0 => t / n as f64,
        _ => 0.0,
    };
    let trace = |values: Vec<f64>| Trace {
        iteration: (1..=values.len()).map(|i| i as f64).collect(),
        time_s: (1..=values.len()).map(|i| i as f64 * per_iter).collect(),
        value: values,
    };
    let nrmse = report.get("nrmse_history").and_then(Value::as_array).filter(|a| !a.is_empty()).map(|a| Trace {
        iteration: a.iter().filter_map(|p| number(p, &["iteration"])).collect(),
        time_s: a.iter().filter_map(|p| number(p, &["train_time_s", "time_s"])).collect(),
        value: a.iter().filter_map(|p| number(p, &["nrmse"])).collect(),
    });
    let nrmse = nrmse.or_else(|| numbers(&report, "nrmse_by_iteration").map(trace));
    let history = RunHistory {
        label: label.to_string(),
        loss_label: loss_label.to_string(),
        loss: trace(loss),
        nrmse,
        ssim: None,
    };
    let metrics = match truth {
        Some(t) => Some(evaluate_volume(&volume, t, None, &VolumeMetricOptions::default())?),
        None => None,
    };
    let holdout_nrmse = read_json(&dir.join("metrics.json")).ok().and_then(|m| {
        let values: Vec<f64> =
            m.get("reprojection")?.as_array()?.iter().filter_map(|r| number(r, &["nrmse"])).collect();
        (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
    });
    Ok(RunSummary {
        dir: dir.to_path_buf(),
        label: label.to_string(),
        config,
        volume,
        compute_s,
        iterations,
        result_bytes,
        history,
        metrics,
        holdout_nrmse,
    })
}

/// Human-readable byte count.
pub fn bytes(n: u64) -> String {
    match n {
        n if n >= 1 << 30 => format!("{:.2} GiB", n as f64 / (1u64 << 30) as f64),
        n if n >= 1 << 20 => format!("{:.2} MiB", n as f64 / (1u64 << 20) as f64),
        n if n >= 1 << 10 => format!("{:.1} KiB", n as f64 / 1024.0),
        n => format!("{n} B"),
    }
}

/// The metrics table of several runs: global figures, then NRMSE per region.
pub fn metrics_table(runs: &[&RunSummary]) -> Option<Table> {
    let first = runs.iter().find_map(|r| r.metrics.as_ref())?;
    let mut header: Vec<String> =
        ["method", "NRMSE", "SSIM (global)", "SSIM (windowed)", "PSNR [dB]"].iter().map(|s| s.to_string()).collect();
    header.extend(first.regions.iter().map(|r| format!("NRMSE {}", r.region.name)));
    header.extend(["held-out view NRMSE".to_string(), "time [s]".to_string(), "result size".to_string()]);
    let header_refs: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut table =
        Table::new("Volume metrics against the ground truth (lower NRMSE, higher SSIM/PSNR are better)", &header_refs);
    for r in runs {
        let Some(m) = &r.metrics else { continue };
        let f = fluidnerf_viz::report::format_value;
        let mut row = vec![
            r.label.clone(),
            f(m.global.nrmse),
            f(m.global.ssim_global),
            m.global.ssim_windowed.map_or("–".into(), f),
            f(m.global.psnr_db),
        ];
        row.extend(m.regions.iter().map(|g| f(g.metrics.nrmse)));
        row.extend([
            r.holdout_nrmse.map_or("–".into(), f),
            r.compute_s.map_or("–".into(), |t| format!("{t:.1}")),
            bytes(r.result_bytes),
        ]);
        table.push_row(row);
    }
    Some(table)
}

/// Slice panels: for each plane, truth (if any) and every run side by side on one colour
/// scale, then each run's difference from the truth on a diverging scale.
pub fn slice_figure(truth: Option<&Volume>, runs: &[&RunSummary], units: &str) -> anyhow::Result<Vec<u8>> {
    let reference = truth.unwrap_or(&runs[0].volume);
    let mut groups = Vec::new();
    for (axis, what) in [(Axis::Z, "central plane z = 0 (along the flow)"), (Axis::X, "cross-section at mid-box")] {
        let pos = axis.position_at(&reference.aabb, 0.5);
        let mut panels = Vec::new();
        let mut diffs = Vec::new();
        let truth_panel = match truth {
            Some(t) => Some(fluidnerf_viz::slice(t, axis, pos, units)?),
            None => None,
        };
        if let Some(tp) = &truth_panel {
            panels.push(fluidnerf_viz::Panel { title: format!("truth, {}", tp.title), ..tp.clone() });
        }
        for r in runs {
            // Resample onto the reference grid so panels and differences line up.
            let v = if r.volume.dims == reference.dims {
                r.volume.clone()
            } else {
                r.volume.resample(reference.dims, reference.aabb)
            };
            let p = fluidnerf_viz::slice(&v, axis, pos, units)?;
            if let Some(tp) = &truth_panel {
                let mut d = tp.difference(&p);
                d.title = format!("{} − truth", r.label);
                diffs.push(d);
            }
            panels.push(fluidnerf_viz::Panel { title: format!("{}, {}", r.label, p.title), ..p });
        }
        groups.push(PanelGroup {
            panels,
            style: PanelStyle {
                colorbar_label: "E".into(),
                figure_title: if groups.is_empty() { Some(format!("Slices: {what}")) } else { None },
                ..PanelStyle::default()
            },
        });
        if !diffs.is_empty() {
            groups.push(PanelGroup {
                panels: diffs,
                style: PanelStyle {
                    colormap: fluidnerf_viz::Colormap::Diverging,
                    colorbar_label: "Δ E".into(),
                    ..PanelStyle::default()
                },
            });
        }
    }
    // One row per plane: values then differences.
    let per_row = if truth.is_some() { 2 } else { 1 };
    let rows: Vec<Vec<u8>> = groups.chunks(per_row).map(fluidnerf_viz::encode_panels_png).collect::<Result<_, _>>()?;
    stack_pngs(&rows)
}

/// Stacks PNG pictures vertically on a white background.
fn stack_pngs(pngs: &[Vec<u8>]) -> anyhow::Result<Vec<u8>> {
    let imgs: Vec<image::RgbImage> =
        pngs.iter().map(|b| Ok(image::load_from_memory(b)?.to_rgb8())).collect::<anyhow::Result<_>>()?;
    let w = imgs.iter().map(|i| i.width()).max().unwrap_or(1);
    let h = imgs.iter().map(|i| i.height()).sum::<u32>().max(1);
    let mut out = image::RgbImage::from_pixel(w, h, image::Rgb([255, 255, 255]));
    let mut y = 0;
    for i in &imgs {
        image::imageops::replace(&mut out, i, 0, y as i64);
        y += i.height();
    }
    let mut buf = Vec::new();
    out.write_to(&mut std::io::Cursor::new(&mut buf), image::ImageFormat::Png)?;
    Ok(buf)
}

/// The report of a set of runs on one scene.
pub fn build_report(
    title: &str,
    scene: &Scene,
    truth: Option<&Volume>,
    runs: &[&RunSummary],
) -> anyhow::Result<Report> {
    let mut report = Report {
        title: title.to_string(),
        subtitle: format!(
            "scene {} · {} frames · box {:?}–{:?} {} · fluidnerf {}",
            scene.root.display(),
            scene.frames.len(),
            scene.aabb.min.to_array(),
            scene.aabb.max.to_array(),
            scene.units,
            env!("CARGO_PKG_VERSION")
        ),
        ..Report::default()
    };
    for r in runs {
        let method = r.config.get("method").and_then(Value::as_str).unwrap_or("?");
        let mut facts = format!("method {method}");
        if let Some(n) = r.iterations {
            facts += &format!(", {n} iterations");
        }
        if let Some(t) = r.compute_s {
            facts += &format!(", {t:.1} s");
        }
        facts += &format!(", grid {:?}, result {}", r.volume.dims, bytes(r.result_bytes));
        report.summary.push((r.label.clone(), facts));
    }
    if let Some(t) = metrics_table(runs) {
        report.tables.push(t);
    }
    let slices = slice_figure(truth, runs, &scene.units)?;
    report.figures.push(Figure {
        caption: "Slices of the reconstruction(s) and, where the truth is known, the differences.".into(),
        image: ImageData::Png(slices),
    });
    let histories: Vec<RunHistory> =
        runs.iter().map(|r| r.history.clone()).filter(|h| !h.loss.value.is_empty()).collect();
    if !histories.is_empty() {
        let plots = fluidnerf_viz::convergence_plots(&histories);
        let png = fluidnerf_viz::encode_plots_png(&plots, 2)?;
        report.figures.push(Figure { caption: "Convergence.".into(), image: ImageData::Png(png) });
    }
    if runs.len() == 1 {
        report.settings = Some(runs[0].config.clone());
    }
    Ok(report)
}

/// Writes `report.html` into a finished run directory.
pub fn write_run_report(dir: &Path, scene: &Scene, label: &str) -> anyhow::Result<PathBuf> {
    let truth = fluidnerf_io::scene::load_truth(scene)?.into_iter().next().map(|(_, v)| v);
    let run = summarise(dir, label, truth.as_ref(), scene)?;
    let report = build_report(&format!("{label} reconstruction"), scene, truth.as_ref(), &[&run])?;
    let path = dir.join("report.html");
    fluidnerf_viz::report::write_report_html(&path, &report)?;
    Ok(path)
}
