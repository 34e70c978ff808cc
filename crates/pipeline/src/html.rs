//! The `report.html` of a run and the comparison of several runs (the demo's): tables, slice
//! panels and convergence plots drawn from the typed [`RunReport`]s, so a figure in the HTML
//! is the figure in `report.json` and in the terminal.

use std::path::{Path, PathBuf};

use fluidnerf_core::{Image, Scene, Volume};
use fluidnerf_metrics::{MetricsReport, StepMetrics};
use fluidnerf_viz::report::{Figure, ImageData, Report, Table};
use fluidnerf_viz::{Axis, PanelGroup, PanelStyle, RunHistory, Trace};

use crate::load::LoadedRun;
use crate::{bytes, LossKind, PipelineError, RunReport, RunStatus, StopReason};

/// What a run produced, as the HTML report and the demo show it.
pub struct RunSummary {
    pub dir: PathBuf,
    /// Legend and table label, e.g. "ASART".
    pub label: String,
    pub settings: Option<serde_json::Value>,
    pub report: RunReport,
    /// The (first) volume written.
    pub volume: Volume,
    pub history: RunHistory,
    /// Mean reprojection NRMSE over the held-out frames, from `metrics.json` when
    /// `fluidnerf eval` has scored the run.
    pub holdout_nrmse: Option<f64>,
}

impl RunSummary {
    /// Metrics of the first volume against the truth, as recorded in the report.
    pub fn metrics(&self) -> Option<&StepMetrics> {
        self.report.volumes.first().and_then(|v| v.metrics.as_ref())
    }
}

/// The convergence traces of a report.
pub fn history(report: &RunReport, label: &str) -> RunHistory {
    let n = report.history.loss.len();
    let loss = Trace {
        iteration: (1..=n).map(|i| i as f64).collect(),
        time_s: loss_times(recorded_times(&report.history), report.train_time_s, n),
        value: report.history.loss.clone(),
    };
    let points = &report.history.nrmse;
    let nrmse = (!points.is_empty()).then(|| Trace {
        iteration: points.iter().map(|p| p.iteration as f64).collect(),
        time_s: points.iter().map(|p| p.train_time_s).collect(),
        value: points.iter().map(|p| p.nrmse).collect(),
    });
    let loss_label = match report.history.loss_kind {
        Some(LossKind::TrainingMse) => "training loss (MSE)",
        Some(LossKind::RelativeResidual) => "relative residual",
        None => "loss",
    };
    let kept = report.kept_before_end().map(|k| k as f64);
    RunHistory { label: label.to_string(), loss_label: loss_label.to_string(), loss, nrmse, ssim: None, kept }
}

/// The (iteration, training time) pairs a report's histories record: its NRMSE points, which
/// need a ground truth, and its held-out evaluations, which need a held-out camera.
fn recorded_times(history: &crate::report::History) -> impl Iterator<Item = (usize, f64)> + '_ {
    let nrmse = history.nrmse.iter().map(|p| (p.iteration, p.train_time_s));
    nrmse.chain(history.holdout.iter().filter_map(|p| Some((p.iteration, p.train_time_s?))))
}

/// The time of each of the `n` iterations of the loss trace: through the times the report
/// records (`recorded`, and the run's end), linearly between them, and before the first at the
/// rate up to the next. A run that started from another reconstruction (the hybrid) counts
/// that start in its time, so its loss curve starts where its NRMSE curve does; with the end
/// alone, at the run's mean rate.
fn loss_times(recorded: impl IntoIterator<Item = (usize, f64)>, end_s: f64, n: usize) -> Vec<f64> {
    let mut anchors: Vec<(f64, f64)> = recorded
        .into_iter()
        .filter(|&(i, t)| (1..n).contains(&i) && t.is_finite())
        .map(|(i, t)| (i as f64, t))
        .collect();
    anchors.push((n as f64, end_s));
    anchors.sort_by(|a, b| a.0.total_cmp(&b.0));
    anchors.dedup_by(|later, earlier| later.0 == earlier.0);
    let rate = |a: (f64, f64), b: (f64, f64)| (b.1 - a.1) / (b.0 - a.0);
    let mut next = 0;
    (1..=n)
        .map(|i| {
            let i = i as f64;
            while next + 1 < anchors.len() && anchors[next].0 < i {
                next += 1;
            }
            let b = anchors[next];
            let t = match next {
                0 if anchors.len() == 1 => b.1 * i / b.0,
                0 => b.1 - (b.0 - i) * rate(b, anchors[1]),
                _ => {
                    let a = anchors[next - 1];
                    a.1 + (i - a.0) * rate(a, b)
                }
            };
            t.max(0.0)
        })
        .collect()
}

/// Reads a finished run folder.
pub fn summarise(dir: &Path, label: &str) -> Result<RunSummary, PipelineError> {
    let run = LoadedRun::open(dir, None)?;
    let volume = run.first_volume()?;
    let holdout_nrmse = holdout_nrmse(&dir.join("metrics.json"));
    let settings = run.config.as_ref().and_then(|c| serde_json::to_value(c).ok());
    let report = run.report.ok_or_else(|| PipelineError::RunDir {
        path: dir.to_path_buf(),
        why: "holds no report.json (not a run of `fluidnerf reconstruct`)".into(),
    })?;
    Ok(RunSummary {
        dir: dir.to_path_buf(),
        label: label.to_string(),
        settings,
        history: history(&report, label),
        report,
        volume,
        holdout_nrmse,
    })
}

/// The mean held-out reprojection NRMSE of an `eval` result, if there is one.
fn holdout_nrmse(path: &Path) -> Option<f64> {
    let m: MetricsReport = crate::rundir::read_json(path).ok()?;
    crate::mean(m.reprojection.iter().map(|r| r.nrmse))
}

/// The stopping policy of a run, or the one that every one of several runs shares (as
/// `study` and the demo run them), in words: their table then states it once and says what
/// ended each run, where each row repeated the whole policy.
fn shared_policy(runs: &[&RunSummary]) -> Option<String> {
    let first = &runs.first()?.report;
    match runs {
        [_] => Some(format!("stopped by {}", first.stopping_rule)),
        _ => runs
            .iter()
            .all(|r| r.report.stopping == first.stopping)
            .then(|| format!("every method stopped by {}", first.stopping.describe_rule())),
    }
}

/// What ended a run, in words: "held-out rule (every 25 iterations)".
fn ended_by(report: &RunReport) -> String {
    let words = report.stop_reason.words();
    match report.stop_reason {
        StopReason::HeldOutPatience => {
            format!("{words} (every {} iterations)", report.stopping.holdout_interval(report.method.family()))
        }
        _ => words.into(),
    }
}

/// The metrics table of several runs: global figures, then NRMSE per region.
pub fn metrics_table(runs: &[&RunSummary]) -> Option<Table> {
    let first = runs.iter().find_map(|r| r.metrics())?;
    let shared = shared_policy(runs);
    let mut header: Vec<String> =
        ["method", "NRMSE", "SSIM (global)", "SSIM (windowed)", "PSNR [dB]"].iter().map(|s| s.to_string()).collect();
    header.extend(first.regions.iter().map(|r| format!("NRMSE {}", r.region.name)));
    // Filled from `eval`'s scores: a run's own report.html is written before any, and its
    // held-out views' reprojections are in the preprocessing table.
    let scored = runs.iter().any(|r| r.holdout_nrmse.is_some());
    if scored {
        header.push("held-out view NRMSE".into());
    }
    let stopping = if shared.is_some() { "ended by" } else { "stopping" };
    header.extend([stopping, "kept / iterations", "time [s]", "result size"].map(String::from));
    let header_refs: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut caption = "Volume metrics against the ground truth (lower NRMSE, higher SSIM/PSNR are better)".to_string();
    if let Some(policy) = &shared {
        caption += &format!("; {policy}");
    }
    let mut table = Table::new(&caption, &header_refs);
    for r in runs {
        let Some(m) = r.metrics() else { continue };
        let f = fluidnerf_viz::report::format_value;
        let mut row = vec![
            r.label.clone(),
            f(m.global.nrmse),
            f(m.global.ssim_global),
            m.global.ssim_windowed.map_or("–".into(), f),
            f(m.global.psnr_db),
        ];
        row.extend(m.regions.iter().map(|g| f(g.metrics.nrmse)));
        if scored {
            row.push(r.holdout_nrmse.map_or("–".into(), f));
        }
        row.extend([
            if shared.is_some() { ended_by(&r.report) } else { r.report.stopping_rule.clone() },
            format!("{} / {}", r.report.kept_iteration, r.report.iterations),
            format!("{:.1}", r.report.train_time_s),
            bytes(r.report.result_bytes),
        ]);
        table.push_row(row);
    }
    Some(table)
}

/// Slice panels: for each plane, truth (if any) and every run side by side on one colour
/// scale, then each run's difference from the truth on a diverging scale (beside them for one
/// or two runs, below them for more). PNG bytes.
pub fn slice_figure(truth: Option<&Volume>, runs: &[&RunSummary], units: &str) -> Result<Vec<u8>, PipelineError> {
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
            // Resampled onto the reference grid so panels and differences line up.
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
    // The differences beside the values while a row stays a few panels wide; for more runs
    // below them, so that the report's page does not shrink nine panels into one row.
    let per_row = if truth.is_some() && runs.len() <= 2 { 2 } else { 1 };
    let rows: Vec<Vec<u8>> = groups.chunks(per_row).map(fluidnerf_viz::encode_panels_png).collect::<Result<_, _>>()?;
    // A row of differences is one panel (the truth's) narrower than the values above it:
    // aligned right, each run's difference stands under its own slice.
    stack_pngs(&rows, true)
}

/// Stacks PNG pictures vertically on a white background, each against the left edge, or the
/// right one with `right`.
fn stack_pngs(pngs: &[Vec<u8>], right: bool) -> Result<Vec<u8>, PipelineError> {
    let err = |e: image::ImageError| PipelineError::invalid("figure", e.to_string());
    let imgs: Vec<image::RgbImage> = pngs
        .iter()
        .map(|b| Ok(image::load_from_memory(b).map_err(err)?.to_rgb8()))
        .collect::<Result<_, PipelineError>>()?;
    let w = imgs.iter().map(|i| i.width()).max().unwrap_or(1);
    let h = imgs.iter().map(|i| i.height()).sum::<u32>().max(1);
    let mut out = image::RgbImage::from_pixel(w, h, image::Rgb([255, 255, 255]));
    let mut y = 0;
    for i in &imgs {
        let x = if right { w - i.width() } else { 0 };
        image::imageops::replace(&mut out, i, i64::from(x), y as i64);
        y += i.height();
    }
    let mut buf = Vec::new();
    out.write_to(&mut std::io::Cursor::new(&mut buf), image::ImageFormat::Png).map_err(err)?;
    Ok(buf)
}

/// The HTML report of a set of runs on one scene.
pub fn build_report(
    title: &str,
    scene: &Scene,
    truth: Option<&Volume>,
    runs: &[&RunSummary],
) -> Result<Report, PipelineError> {
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
    // Several runs under one policy: the title and the table state it.
    let shared = runs.len() > 1 && shared_policy(runs).is_some();
    for r in runs {
        let rep = &r.report;
        let mut facts = format!("method {}, {} iterations", rep.method, rep.iterations);
        if rep.kept_iteration != rep.iterations {
            facts += &format!(" (iteration {} kept)", rep.kept_iteration);
        }
        if shared {
            facts += &format!(", {:.1} s, ended by {}", rep.train_time_s, ended_by(rep));
        } else {
            facts += &format!(", {:.1} s, stopped by {}", rep.train_time_s, rep.stopping_rule);
        }
        if rep.status == RunStatus::Interrupted {
            facts += ", INTERRUPTED";
        }
        facts += &format!(", grid {:?}, result {}", r.volume.dims, bytes(rep.result_bytes));
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
        let caption = if histories.iter().any(|h| h.kept.is_some()) {
            "Convergence. A dot marks the iterate a run kept where it is not its last."
        } else {
            "Convergence."
        };
        report.figures.push(Figure { caption: caption.into(), image: ImageData::Png(png) });
    }
    if runs.iter().any(|r| r.report.status == RunStatus::Interrupted) {
        report.notes.push("Interrupted runs show the results and curves up to where they were stopped.".into());
    }
    if runs.len() == 1 {
        report.settings = runs[0].settings.clone();
    }
    Ok(report)
}

/// The `report.html` of a run whose results are in `dir` and whose report is `report` (about
/// to be written as `report.json`); None for a run without volumes.
pub(crate) fn run_html(
    dir: &crate::RunDir,
    scene: &Scene,
    report: &RunReport,
    truth: &[(Option<f64>, Volume)],
    preprocessed: Option<&[Image]>,
) -> Result<Option<Report>, PipelineError> {
    let Some(first) = report.volumes.first() else { return Ok(None) };
    let volume = fluidnerf_io::volume::read_npy(&dir.path(&first.file), scene.aabb)?;
    let label = report.method.label();
    let config = crate::RunConfig::read(&dir.config()).ok();
    let run = RunSummary {
        dir: dir.root().to_path_buf(),
        label: label.to_string(),
        settings: config.and_then(|c| serde_json::to_value(c).ok()),
        report: report.clone(),
        volume,
        history: history(report, label),
        holdout_nrmse: None,
    };
    let truth_volume = match first.time {
        Some(t) => truth.iter().find(|(tt, _)| tt.is_some_and(|tt| (tt - t).abs() < 1e-9)).or(truth.first()),
        None => truth.first(),
    };
    let mut html = build_report(&format!("{label} reconstruction"), scene, truth_volume.map(|(_, v)| v), &[&run])?;
    html.summary.extend(report.warnings.iter().map(|w| ("warning".to_string(), w.clone())));
    if let Some(p) = &report.preprocessing {
        let mut table = Table::new(
            format!(
                "Preprocessing: {}; {} pixels clipped at 0, {} saturated, {} masked{}; gains {}{}",
                p.scene,
                p.clipped_pixels,
                p.saturated_pixels,
                p.masked_pixels,
                p.flat_field_text(),
                p.gains.mode,
                p.gains_auto.as_ref().map(|why| format!(" (auto: {why})")).unwrap_or_default()
            ),
            &[
                "frame",
                "camera",
                "held out",
                "gain",
                "offset",
                "reprojection NRMSE (raw)",
                "after best-fit gain",
                "best-fit gain",
            ],
        );
        let f = fluidnerf_viz::report::format_value;
        for g in &p.frames {
            let s = g.holdout_scores.as_ref();
            table.push_row(vec![
                g.frame.to_string(),
                g.camera.clone(),
                if g.holdout { "yes".into() } else { String::new() },
                f(g.gain),
                f(g.offset),
                s.map_or("–".into(), |s| f(s.nrmse_raw)),
                s.map_or("–".into(), |s| f(s.nrmse_fitted)),
                s.map_or("–".into(), |s| f(s.fitted_gain)),
            ]);
        }
        html.tables.push(table);
    }
    if report.volumes.len() == 1 {
        match camera_figure(scene, report, &run.volume, preprocessed) {
            Ok(png) => html.figures.push(Figure {
                caption: format!(
                    "Every camera (at most {CAMERA_FIGURE_FRAMES}): the image as preprocessed, the reconstruction's \
                     reprojection (× the camera's gain, + its offset) and their difference. Held-out cameras are \
                     marked."
                ),
                image: ImageData::Png(png),
            }),
            Err(e) => log::warn!("report.html: no camera figure: {e}"),
        }
    }
    Ok(Some(html))
}

/// Frames shown in the camera figure of `report.html`.
pub(crate) const CAMERA_FIGURE_FRAMES: usize = 24;

/// One row per camera: measured image, reprojection, difference (thumbnails). `preprocessed`:
/// the images as the run read them (at least the figure's frames); without them they are read
/// again, and whatever that reading warns of is said a second time.
fn camera_figure(
    scene: &Scene,
    report: &RunReport,
    volume: &Volume,
    preprocessed: Option<&[Image]>,
) -> Result<Vec<u8>, PipelineError> {
    let loaded;
    let images = match preprocessed {
        Some(images) => images,
        None => {
            loaded = fluidnerf_io::scene::load_preprocessed(scene)?.images;
            &loaded
        }
    };
    let spacing = volume.spacing().min_element();
    let mut rows = Vec::new();
    for (i, (frame, measured)) in scene.frames.iter().zip(images).enumerate().take(CAMERA_FIGURE_FRAMES) {
        let (gain, offset) = report
            .preprocessing
            .as_ref()
            .and_then(|p| p.frames.iter().find(|g| g.frame == i))
            .map_or((1.0, 0.0), |g| (g.gain, g.offset));
        let settings = fluidnerf_core::RenderSettings {
            step: Some(spacing),
            supersample: 1,
            time: frame.time.unwrap_or(0.0),
            scale: scene.intensity_scale * gain,
        };
        let mut model = fluidnerf_core::render_image(volume, &frame.camera, &scene.aabb, &settings)
            .map_err(|e| PipelineError::invalid("camera figure", e.to_string()))?;
        model.data.iter_mut().for_each(|v| *v += offset as f32);
        let name = crate::measured::frame_label(scene, i);
        let held = if frame.holdout { " (held out)" } else { "" };
        let measured_panel = fluidnerf_viz::Panel::from_image(measured).with_title(format!("{name}{held}: image"));
        let model_panel = fluidnerf_viz::Panel::from_image(&model).with_title("reprojection");
        let mut diff = measured_panel.difference(&model_panel);
        diff.title = "reprojection − image".into();
        let style = PanelStyle { plot_size_px: 140, colorbar_label: "pixel".into(), ..PanelStyle::default() };
        let groups = [
            PanelGroup { panels: vec![measured_panel, model_panel], style: style.clone() },
            PanelGroup {
                panels: vec![diff],
                style: PanelStyle {
                    colormap: fluidnerf_viz::Colormap::Diverging,
                    colorbar_label: "Δ pixel".into(),
                    ..style
                },
            },
        ];
        rows.push(fluidnerf_viz::encode_panels_png(&groups)?);
    }
    stack_pngs(&rows, false)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_metrics::NrmsePoint;

    fn point(iteration: usize, train_time_s: f64) -> NrmsePoint {
        NrmsePoint { iteration, train_time_s, nrmse: 0.5 }
    }

    /// Stacked rows keep their own width: against the right edge with `right` (a row of
    /// differences under the values it belongs to), else the left.
    #[test]
    fn narrower_rows_stack_against_the_edge_asked_for() {
        let png = |w: u32, c: u8| {
            let img = image::RgbImage::from_pixel(w, 2, image::Rgb([c, c, c]));
            let mut buf = Vec::new();
            img.write_to(&mut std::io::Cursor::new(&mut buf), image::ImageFormat::Png).expect("encodes");
            buf
        };
        let rows = [png(10, 0), png(6, 100)];
        for (right, (blank, drawn)) in [(true, (0, 9)), (false, (9, 0))] {
            let out = image::load_from_memory(&stack_pngs(&rows, right).expect("stacks")).expect("png").to_rgb8();
            assert_eq!((out.width(), out.height()), (10, 4));
            assert_eq!(out.get_pixel(blank, 3).0, [255; 3], "right = {right}");
            assert_eq!(out.get_pixel(drawn, 3).0, [100; 3], "right = {right}");
        }
    }

    /// The loss curve's times go through the times the report records: the mean rate with the
    /// end alone; through the NRMSE points, and back from the first at the next one's rate, so
    /// that a run whose first 9 s went to its start begins there, as its NRMSE curve does.
    #[test]
    fn the_loss_curve_keeps_the_recorded_times() {
        assert_eq!(loss_times([], 8.0, 4), [2.0, 4.0, 6.0, 8.0]);
        let t = loss_times([(2, 9.0), (4, 10.0)], 12.0, 6);
        assert_eq!(t, [8.5, 9.0, 9.5, 10.0, 11.0, 12.0]);
        // Points past the loss trace (another run's curve) or not finite are left out.
        assert_eq!(loss_times([(9, 1.0), (1, f64::NAN)], 8.0, 4), [2.0, 4.0, 6.0, 8.0]);
        // Never before 0.
        assert_eq!(loss_times([(3, 0.1), (4, 1.1)], 2.0, 4), [0.0, 0.0, 0.1, 2.0]);
    }

    /// A run without a ground truth records no NRMSE points; its held-out evaluations carry
    /// the times instead, and one that records both is placed by both (the same iteration
    /// once). Held-out points of reports written before they had times are left out.
    #[test]
    fn held_out_evaluations_place_the_loss_curve_of_a_run_without_a_truth() {
        let held = |iteration, t| crate::HoldoutPoint { iteration, loss: 0.1, train_time_s: t };
        let mut history = crate::History { holdout: vec![held(2, Some(9.0)), held(3, None)], ..Default::default() };
        let times = |h: &crate::History| loss_times(recorded_times(h), 12.0, 6);
        assert_eq!(times(&history), [8.25, 9.0, 9.75, 10.5, 11.25, 12.0]);
        history.nrmse = vec![point(2, 9.0), point(4, 10.0)];
        history.holdout.push(held(4, Some(10.0)));
        assert_eq!(times(&history), [8.5, 9.0, 9.5, 10.0, 11.0, 12.0]);
    }
}
