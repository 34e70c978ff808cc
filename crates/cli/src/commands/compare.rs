//! `fluidnerf compare RUN... -o OUT`: time-to-accuracy of several runs on the same scene.
//!
//! Reads each run's `nrmse_history: [{iteration, train_time_s, nrmse}]` (written by classical
//! and neural `fluidnerf reconstruct` runs on a scene with ground truth, and by any other tool
//! that writes the same fields, e.g. a reference implementation), draws NRMSE against training
//! wall time, and tabulates when each run first reached a few NRMSE thresholds and how much
//! faster or slower it was than a reference run.
//!
//! Conventions:
//! - Times are the runs' own `train_time_s`: the method's work with the NRMSE evaluations taken
//!   out, setup (loading, projector or ray tables) excluded. Runs measured on a busy machine
//!   compare only as well as their timings do.
//! - "Reached" means at an evaluation point, so a time to a threshold is resolved to the run's
//!   evaluation interval (`--eval-every`); nothing is interpolated.
//! - The speed-up of a run is `t_ref(a) / t_run(a)`, with `a` the best NRMSE the run reached and
//!   `t(a)` the first time a run's NRMSE was at or below `a`: above 1, the run got there
//!   faster than the reference. If the reference never got as accurate, the speed-up is at
//!   least its total time over the run's and is printed as `>X`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use fluidnerf_core::{fixed, num};
use fluidnerf_metrics::NrmsePoint;
use fluidnerf_pipeline::RunReport;
use fluidnerf_viz::{write_plots, LinePlot, Series};
use serde::{Deserialize, Serialize};

/// Compare runs by NRMSE against training wall time (time to accuracy).
///
/// Each RUN is a reconstruction run directory (its `report.json` is read, and refused when its
/// `config.json` is of another run) or a JSON file with
/// the same fields: `method`, optionally `preset`, and `nrmse_history`, a list of
/// `{iteration, train_time_s, nrmse}`, one point per iteration, forward in time (a file that
/// also holds a report's `history.nrmse` is refused). Runs record that history when their scene has ground
/// truth (neural runs every `--eval-every` iterations, classical runs every iteration). Runs of
/// different scenes are refused (see --allow-different-scenes), and so are runs whose NRMSE is
/// over different instants of the truth: a time-resolved run's is the mean over the
/// recording's instants, a static run's of such a scene is against the first instant only.
///
/// Writes into OUT: `time_to_accuracy.png` and `.svg` (NRMSE against wall time, one line per
/// run, log axes where the data span a decade), `time_to_accuracy.csv` (every point of every
/// curve) and `compare.json` (the settings, the table and its warnings). Prints a table per
/// run: final and best NRMSE, wall time, the time it first reached each threshold, and its
/// speed-up over the reference run at the best accuracy it reached; under it, each thing that
/// makes the rows less comparable than they look (a run cut short by Ctrl-C, grids of other
/// voxels, fields and voxel runs scored by other rules, a scene unchecked), marked `!`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Run directories (holding `report.json`) or report JSON files.
    #[arg(required = true, num_args = 1.., value_name = "RUN")]
    pub runs: Vec<PathBuf>,
    /// Output directory; created if missing. Existing results need --force.
    #[arg(short, long)]
    pub out: PathBuf,
    /// NRMSE thresholds for the time-to-accuracy columns, comma-separated; each must be in
    /// (0, 10).
    #[arg(long, value_delimiter = ',', default_value = "0.5,0.3,0.2", value_name = "NRMSE")]
    pub thresholds: Vec<f64>,
    /// The run the speed-ups are measured against (a directory or file, listed among the RUNs
    /// or not; if not, it is added to the plot) [default: the first RUN].
    #[arg(long, value_name = "RUN")]
    pub reference: Option<PathBuf>,
    /// Draw wall time on a linear axis instead of a logarithmic one.
    #[arg(long)]
    pub linear_time: bool,
    /// Compare runs made from different scenes (by their `config.json`) with a warning
    /// instead of refusing them: for copies of one scene in other folders.
    #[arg(long)]
    pub allow_different_scenes: bool,
    /// Overwrite results already in OUT.
    #[arg(long)]
    pub force: bool,
}

/// One point of a curve.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
struct Point {
    iteration: u64,
    train_time_s: f64,
    nrmse: f64,
}

/// One run read back.
#[derive(Clone, Debug, Serialize)]
struct Run {
    /// The directory or file given.
    path: PathBuf,
    /// The JSON file read.
    report: PathBuf,
    label: String,
    method: String,
    preset: Option<String>,
    #[serde(skip)]
    curve: Vec<Point>,
    /// `final_nrmse` (over all voxel centres) when the report has it, else the curve's last.
    final_nrmse: f64,
    best_nrmse: f64,
    /// The run's training (or solver) time, evaluations excluded.
    wall_time_s: f64,
    /// The truth instants its NRMSE is over (None each for a static scene's truth); None for a
    /// curve file, which does not say.
    #[serde(skip)]
    instants: Option<Vec<Option<f64>>>,
    /// Stopped by Ctrl-C before its stopping rule ended it: its curve ends where it was
    /// stopped.
    interrupted: bool,
    /// What a reader of its row must know (stopped by Ctrl-C): printed under the table and
    /// recorded in `compare.json`.
    #[serde(skip)]
    caveat: Option<String>,
    /// The voxels of the grid its volumes (and so its NRMSE) are on; None for a curve file,
    /// which does not say.
    #[serde(skip)]
    dims: Option<[usize; 3]>,
    /// The truth's grid its NRMSE is over, and whether it was scored as a continuous field (the
    /// field at the truth's voxel centres) rather than through its volume; None for a curve file
    /// or a run without truth.
    #[serde(skip)]
    scored: Option<([usize; 3], bool)>,
    /// The iteration whose result a run report kept, where it is not its last (held-out early
    /// stopping); None for a curve file.
    #[serde(skip)]
    kept: Option<u64>,
}

/// The table row of one run.
#[derive(Clone, Debug, Serialize)]
struct Row {
    #[serde(flatten)]
    run: Run,
    /// First time at or below each threshold, in the order of `thresholds` (None: never).
    time_to_threshold_s: Vec<Option<f64>>,
    /// Time the run first reached its best NRMSE.
    time_to_best_s: f64,
    /// Time the reference first reached this run's best NRMSE (None: never).
    reference_time_s: Option<f64>,
    /// `reference_time_s / time_to_best_s`; None when the reference never got there.
    speedup: Option<f64>,
    /// When the reference never got there: the speed-up is at least this.
    speedup_at_least: Option<f64>,
}

/// `compare.json`.
#[derive(Serialize)]
struct CompareRecord<'a> {
    version: &'static str,
    thresholds: &'a [f64],
    reference: &'a Path,
    linear_time: bool,
    runs: &'a [Row],
    /// What makes the rows less comparable than they look (runs cut short, on other grids,
    /// scored by other rules, of unchecked or other scenes), as printed under the table.
    warnings: &'a [String],
}

/// The file holding a run's report: `RUN/report.json` for a directory, RUN itself otherwise.
fn report_path(run: &Path) -> anyhow::Result<PathBuf> {
    if run.is_dir() {
        // A run a killed --force left aside is put back first, as every reader of a run does.
        fluidnerf_pipeline::rundir::RunDir::recover_replaced(run);
        let p = run.join("report.json");
        if !p.is_file() && run.join("config.json").is_file() {
            // A run writes its report last: one that was killed, or is still running, has none.
            bail!(
                "{}: holds an unfinished run (config.json but no report.json), which has no NRMSE history to \
                 compare yet; let it finish, continue it with `reconstruct --resume`, or leave it out",
                run.display()
            );
        }
        if !p.is_file() {
            use fluidnerf_pipeline::rundir::FolderKind;
            // A study's or a demo's folder holds runs: say where, not that it is none.
            let holds = match fluidnerf_pipeline::rundir::folder_kind(run) {
                Some(FolderKind::Study) => {
                    format!(
                        "a study, whose runs are its runs/CELL/METHOD folders (e.g. {})",
                        example_run(&run.join("runs"))
                    )
                }
                Some(FolderKind::Demo) => {
                    format!("the demo's results, whose runs are its folders (e.g. {})", example_run(run))
                }
                _ => String::new(),
            };
            if !holds.is_empty() {
                bail!("{}: holds {holds}; give those run folders", run.display());
            }
            bail!("{}: no report.json (is it a run directory of `fluidnerf reconstruct`?)", run.display());
        }
        Ok(p)
    } else if run.is_file() {
        // A report is a JSON object; say so for anything else (a volume, a picture) instead of
        // the JSON reader's complaint about its bytes.
        let mut head = [0u8; 256];
        let read = std::fs::File::open(run).and_then(|mut f| std::io::Read::read(&mut f, &mut head));
        if read.is_ok_and(|n| head[..n].iter().find(|b| !b.is_ascii_whitespace()) != Some(&b'{')) {
            bail!("{}: not a run directory or a report (a JSON object with the run's NRMSE history)", run.display());
        }
        Ok(run.to_path_buf())
    } else {
        bail!("{}: no such run directory or report file", run.display())
    }
}

/// The first run folder (holding `report.json`) found in `dir` or one level below it, for an
/// example; `dir` itself when there is none.
fn example_run(dir: &Path) -> String {
    let entries = |d: &Path| -> Vec<PathBuf> {
        let mut list: Vec<PathBuf> = std::fs::read_dir(d).into_iter().flatten().flatten().map(|e| e.path()).collect();
        list.sort();
        list
    };
    let first = entries(dir)
        .into_iter()
        .find_map(|p| std::iter::once(p.clone()).chain(entries(&p)).find(|q| q.join("report.json").is_file()));
    first.unwrap_or_else(|| dir.to_path_buf()).display().to_string()
}

/// A label that tells runs apart: method, preset, and the folder (or file) name, each left
/// out where it repeats the method (`fast` rather than `fast/fast (fast)`).
fn label_of(path: &Path, report: &Path, method: &str, preset: Option<&str>) -> String {
    let name = if path.is_dir() {
        path.file_name()
    } else if report.file_name().is_some_and(|n| n == "report.json") {
        report.parent().and_then(Path::file_name)
    } else {
        report.file_stem()
    };
    let name = name.map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| path.display().to_string());
    let mut label = method.to_string();
    if let Some(p) = preset.filter(|p| !p.is_empty() && *p != method) {
        label = format!("{label}/{p}");
    }
    if name != method {
        label = format!("{label} ({name})");
    }
    label
}

/// A curve written by another tool (e.g. a reference implementation): the fields `compare`
/// needs, in the layout of the command's help.
#[derive(Deserialize)]
struct CurveFile {
    method: String,
    #[serde(default)]
    preset: Option<String>,
    nrmse_history: Vec<NrmsePoint>,
    #[serde(default)]
    final_nrmse: Option<f64>,
    #[serde(default)]
    train: Option<CurveTrain>,
}

#[derive(Deserialize)]
struct CurveTrain {
    train_time_s: f64,
}

fn read_run(path: &Path) -> anyhow::Result<Run> {
    let report = report_path(path)?;
    #[derive(Deserialize)]
    struct Probe {
        format: Option<u32>,
        #[serde(default)]
        history: Option<serde_json::Value>,
        #[serde(default)]
        nrmse_history: Option<serde::de::IgnoredAny>,
    }
    let probe: Probe = fluidnerf_pipeline::rundir::read_json(&report)?;
    // A report's history is `history.nrmse`, a curve file's `nrmse_history`: a file holding
    // both would have one read and the other passed over, whichever the reader took it for.
    if probe.nrmse_history.is_some() && probe.history.as_ref().is_some_and(|h| h.get("nrmse").is_some()) {
        bail!(
            "{}: holds both `history.nrmse` (a run report's NRMSE history) and `nrmse_history` (a curve file's); \
             keep the one that is the run's and remove the other",
            report.display()
        );
    }
    let key = if probe.format.is_some() { "history.nrmse" } else { "nrmse_history" };
    let mut interrupted = false;
    let mut caveat = None;
    let mut scored = None;
    let (method, preset, history, final_nrmse, wall_time_s, instants, dims, kept) = if probe.format.is_some() {
        let r = match RunReport::read(&report) {
            Ok(r) => r,
            // A run's configuration has a `format` too: say what the file is, not what it lacks.
            Err(_) if fluidnerf_pipeline::RunConfig::read(&report).is_ok() => {
                let folder = report.parent().filter(|f| !f.as_os_str().is_empty()).unwrap_or(Path::new("."));
                bail!(
                    "{}: is a run's configuration, not its report; give the run folder {} or its report.json",
                    report.display(),
                    folder.display()
                );
            }
            Err(e) => return Err(e.into()),
        };
        // A time-resolved run stopped before its last instants scores only those it reached: its
        // NRMSE is a mean over other instants than a whole run's, not a point on the same curve.
        if !r.not_reached.is_empty() {
            let list: Vec<String> = r.not_reached.iter().map(|&t| num(t).to_string()).collect();
            bail!(
                "{}: the {} run was stopped before it reached t = {}, so its NRMSE is over the instants it reached \
                 only, not over the recording as a whole run's is; continue it with `reconstruct --resume` and \
                 compare it then, or leave it out",
                report.display(),
                r.method.name(),
                list.join(", ")
            );
        }
        // A report beside its run's config.json must be of that run, as eval and export hold it
        // to be: one copied in from another run had that run's curve drawn under this folder's
        // name.
        let config = report.with_file_name("config.json");
        if report.file_name().is_some_and(|n| n == "report.json") && config.is_file() {
            fluidnerf_pipeline::load::check_same_run(&report, &r, &fluidnerf_pipeline::RunConfig::read(&config)?)?;
        }
        let preset = r.neural.as_ref().and_then(|n| n.preset.clone());
        // Its NRMSE is the mean over the trained instants with truth (`final_nrmse`).
        let instants = r.volumes.iter().filter(|v| v.trained).filter_map(|v| v.metrics.as_ref().map(|m| m.time));
        // A report scoring no volume says nothing of its instants.
        let instants = Some(instants.collect::<Vec<_>>()).filter(|i| !i.is_empty());
        let dims = r.volumes.first().map(|v| v.dims);
        // A trained network is scored where the truth's voxels are; a dense grid (the voxel
        // baseline) samples as its volume does.
        let continuous = r.neural.is_some() && r.method != fluidnerf_pipeline::Method::Voxel;
        scored = r.volumes.first().and_then(|v| v.metrics.as_ref()).map(|m| (m.dims, continuous));
        if r.status == fluidnerf_pipeline::RunStatus::Interrupted {
            interrupted = true;
            caveat = Some(format!(
                "{}: the {} run was stopped by Ctrl-C after {} iterations, before its stopping rule ended it: its \
                 curve, best NRMSE and times are those of a run cut short; continue it with `reconstruct --resume` \
                 to compare it whole",
                report.display(),
                r.method.name(),
                r.iterations
            ));
        }
        // The iterate the run kept, where it is not its last: marked on its curve.
        let kept = r.kept_before_end().map(|k| k as u64);
        (
            r.method.name().to_string(),
            preset,
            r.history.nrmse,
            r.final_nrmse,
            Some(r.train_time_s),
            instants,
            dims,
            kept,
        )
    } else {
        let c: CurveFile = fluidnerf_pipeline::rundir::read_json(&report)
            .with_context(|| "neither a run report nor a curve file with `method` and `nrmse_history`")?;
        (c.method, c.preset, c.nrmse_history, c.final_nrmse, c.train.map(|t| t.train_time_s), None, None, None)
    };
    if history.is_empty() {
        bail!("{}: no NRMSE history; run it with --eval-every and a scene with ground truth", report.display());
    }
    let mut curve = Vec::with_capacity(history.len());
    let mut seen = std::collections::BTreeMap::new();
    for (k, p) in history.iter().enumerate() {
        // An iteration is evaluated once: a repeat is two curves joined, or a point copied.
        if let Some(j) = seen.insert(p.iteration, k) {
            bail!(
                "{}: `{key}` point {k} repeats iteration {} of point {j}; each iteration is evaluated once",
                report.display(),
                p.iteration
            );
        }
        if !(p.train_time_s.is_finite() && p.train_time_s >= 0.0 && p.nrmse.is_finite() && p.nrmse >= 0.0) {
            bail!(
                "{}: NRMSE history point {k} (iteration {}) has a negative or non-finite value: time {} s, NRMSE {}",
                report.display(),
                p.iteration,
                num(p.train_time_s),
                num(p.nrmse)
            );
        }
        let point = Point { iteration: p.iteration as u64, train_time_s: p.train_time_s, nrmse: p.nrmse };
        // Times to a threshold are read off the curve in order: one that goes back would give
        // wrong times and speed-ups.
        if let Some(prev) = curve.last().filter(|q: &&Point| point.train_time_s < q.train_time_s) {
            bail!(
                "{}: NRMSE history point {k} (iteration {}, {} s) comes before point {} (iteration {}, {} s) in \
                 time: the history must go forward in time",
                report.display(),
                point.iteration,
                num(point.train_time_s),
                k - 1,
                prev.iteration,
                num(prev.train_time_s)
            );
        }
        // Iterations count forward, as the time does: a point of an earlier iteration after a
        // later one is a history joined or reordered.
        if let Some(prev) = curve.last().filter(|q: &&Point| point.iteration < q.iteration) {
            bail!(
                "{}: NRMSE history point {k} (iteration {}) comes after point {} (iteration {}): the history must go \
                 forward in iterations",
                report.display(),
                point.iteration,
                k - 1,
                prev.iteration
            );
        }
        curve.push(point);
    }
    // The table prints the final NRMSE and the run's time as they are; a value no run writes
    // would be printed as a result.
    if let Some(v) = final_nrmse.filter(|v| !(v.is_finite() && *v >= 0.0)) {
        bail!(
            "{}: `final_nrmse` is {}; an NRMSE is a finite number ≥ 0 (or leave the key out)",
            report.display(),
            num(v)
        );
    }
    if let Some(v) = wall_time_s.filter(|v| !(v.is_finite() && *v >= 0.0)) {
        bail!("{}: `train_time_s` of the run is {} s; a time is a finite number ≥ 0", report.display(), num(v));
    }
    let last = curve[curve.len() - 1];
    let final_nrmse = final_nrmse.unwrap_or(last.nrmse);
    let best_nrmse = curve.iter().map(|p| p.nrmse).fold(f64::INFINITY, f64::min);
    let wall_time_s = wall_time_s.unwrap_or(last.train_time_s).max(last.train_time_s);
    Ok(Run {
        label: label_of(path, &report, &method, preset.as_deref()),
        path: path.to_path_buf(),
        report,
        method,
        preset,
        curve,
        final_nrmse,
        best_nrmse,
        wall_time_s,
        instants,
        interrupted,
        caveat,
        dims,
        scored,
        kept,
    })
}

/// Warns of runs whose volumes are on grids of different voxels (`reconstruct --resolution`):
/// each one's NRMSE is over its own grid's voxels and its time is that of its own grid's work,
/// so their curves are not those of one problem solved by different methods.
fn warn_of_other_grids(runs: &[Run], warnings: &mut Vec<String>) {
    let grids: Vec<(&Run, [usize; 3])> = runs.iter().filter_map(|r| r.dims.map(|d| (r, d))).collect();
    if grids.iter().all(|(_, d)| *d == grids[0].1) {
        return;
    }
    let list: Vec<String> =
        grids.iter().map(|(r, d)| format!("{} {}", r.path.display(), d.map(|n| n.to_string()).join("×"))).collect();
    warnings.push(format!(
        "the runs' volumes are on grids of different voxels ({}): each NRMSE is over its own grid and each time is \
         its own grid's work; for a comparison of methods, reconstruct them at one --resolution",
        list.join(", ")
    ));
}

/// Warns of runs whose NRMSE was scored once, at their end (time-resolved runs score their
/// frames only then; a static run with `--eval-every 0`): their time to any accuracy is their
/// whole run's, an upper bound.
fn warn_of_single_points(runs: &[Run], warnings: &mut Vec<String>) {
    // Of run reports (a grid: a curve file's points are what its maker chose to keep).
    let single: Vec<String> =
        runs.iter().filter(|r| r.curve.len() == 1 && r.dims.is_some()).map(|r| r.path.display().to_string()).collect();
    if single.is_empty() {
        return;
    }
    warnings.push(format!(
        "{} scored its NRMSE once, at its end (time-resolved runs score their frames only then): its time to an \
         accuracy is its whole run's time, an upper bound on when it reached it",
        single.join(", ")
    ));
}

/// Warns when fields and voxel runs are scored by different rules: a trained field's NRMSE is
/// the field at the truth's voxel centres, a voxel run's its volume resampled onto them, so on a
/// truth finer than a voxel run's grid the field's score is not bound by the output grid and the
/// voxel run's is. On the real-like recording at 64³ that rule put the fields at 0.56× the best
/// voxel method, and through the volumes they wrote at 1.01× (docs/real-data.md).
fn warn_of_scoring_rules(runs: &[Run], warnings: &mut Vec<String>) {
    let fields: Vec<String> =
        runs.iter().filter(|r| r.scored.is_some_and(|(_, f)| f)).map(|r| r.path.display().to_string()).collect();
    let coarser: Vec<String> = runs
        .iter()
        .filter_map(|r| match (r.scored, r.dims) {
            (Some((truth, false)), Some(grid)) if grid != truth => Some(format!(
                "{} {} against the truth's {}",
                r.path.display(),
                grid.map(|n| n.to_string()).join("×"),
                truth.map(|n| n.to_string()).join("×")
            )),
            _ => None,
        })
        .collect();
    if fields.is_empty() || coarser.is_empty() {
        return;
    }
    warnings.push(format!(
        "the fields ({}) are scored at the truth's voxel centres and the voxel runs through their volumes on grids \
         of other voxels ({}): the fields' NRMSE is not bound by an output grid, theirs is; `fluidnerf eval RUN \
         --use-volume` scores every run through the volume it wrote, on one grid",
        fields.join(", "),
        coarser.join(", ")
    ));
}

/// Refuses runs whose NRMSE is over different instants of the truth: a time-resolved run's is
/// the mean over the recording's instants, a static run's of a time-resolved scene is its one
/// volume (the instants mixed) against the first instant only, so their curves, thresholds and
/// speed-ups measure different things.
fn refuse_other_instants(runs: &[Run]) -> anyhow::Result<()> {
    let scored: Vec<(&Run, &Vec<Option<f64>>)> =
        runs.iter().filter_map(|r| r.instants.as_ref().map(|i| (r, i))).collect();
    let Some(&(_, first)) = scored.first() else { return Ok(()) };
    if scored.iter().all(|(_, i)| *i == first) {
        return Ok(());
    }
    let describe = |instants: &[Option<f64>]| match instants {
        [None] => "the static truth".to_string(),
        [Some(t)] => format!("t = {} only", num(*t)),
        _ => format!(
            "the mean over t = {}",
            instants.iter().map(|t| t.map_or("–".to_string(), |t| num(t).to_string())).collect::<Vec<_>>().join(", ")
        ),
    };
    let list: Vec<String> =
        scored.iter().map(|(r, i)| format!("{} ({}): {}", r.path.display(), r.method, describe(i))).collect();
    bail!(
        "the runs' NRMSE are over different instants of the truth: {}; their curves measure different things and \
         are not comparable (a static run of a time-resolved scene mixes its instants into one volume, scored \
         against the first); compare runs scored over the same instants",
        list.join("; ")
    )
}

/// Refuses runs made from different scenes (their `config.json`), whose NRMSE curves measure
/// different problems, naming each run and its scene; with `allow` (copies of one scene in
/// other folders, say a cluster's and this machine's) it only warns.
fn refuse_other_scenes(runs: &[Run], allow: bool, warnings: &mut Vec<String>) -> anyhow::Result<()> {
    let mut scenes: Vec<(PathBuf, Vec<String>)> = Vec::new();
    let mut unknown = Vec::new();
    for run in runs {
        let Ok(config) = fluidnerf_pipeline::RunConfig::read(&run.report.with_file_name("config.json")) else {
            unknown.push(run.path.display().to_string());
            continue;
        };
        let scene = super::scene_folder(&config.scene).unwrap_or(config.scene);
        let named = run.path.display().to_string();
        match scenes.iter_mut().find(|(s, _)| *s == scene) {
            Some((_, paths)) => paths.push(named),
            None => scenes.push((scene, vec![named])),
        }
    }
    // A report without its run's config.json (a copied report.json, a folder whose config was
    // removed) names no scene, and passed the check unannounced.
    if !unknown.is_empty() && !scenes.is_empty() {
        warnings.push(format!(
            "{}: no config.json beside the report to name the scene it was made from; compared with the others \
             without checking that it is the same scene",
            unknown.join(", ")
        ));
    }
    if scenes.len() < 2 {
        return Ok(());
    }
    let list: Vec<String> = scenes
        .iter()
        .map(|(s, paths)| {
            let runs = if paths.len() == 1 { "run" } else { "runs" };
            format!("{runs} {} from the scene {}", paths.join(", "), s.display())
        })
        .collect();
    let problem = format!(
        "the runs were made from {} different scenes: {}; their curves measure different problems",
        list.len(),
        list.join("; ")
    );
    if allow {
        warnings.push(format!("{problem} (compared as --allow-different-scenes asks)"));
        return Ok(());
    }
    bail!("{problem} and are not comparable; compare runs of one scene, or give --allow-different-scenes if the scenes are copies of one")
}

/// The first time `curve` was at or below `nrmse`.
fn time_to(curve: &[Point], nrmse: f64) -> Option<f64> {
    curve.iter().find(|p| p.nrmse <= nrmse).map(|p| p.train_time_s)
}

/// The table rows: thresholds and speed-ups against `runs[reference]`.
fn rows(runs: &[Run], reference: usize, thresholds: &[f64]) -> Vec<Row> {
    let r = &runs[reference];
    runs.iter()
        .map(|run| {
            let time_to_best_s = time_to(&run.curve, run.best_nrmse).unwrap_or(run.wall_time_s);
            let reference_time_s = time_to(&r.curve, run.best_nrmse);
            // A curve whose best point took no measured time gives no ratio.
            let timed = time_to_best_s > 0.0;
            let speedup = reference_time_s.filter(|_| timed).map(|t| t / time_to_best_s);
            let speedup_at_least = (reference_time_s.is_none() && timed).then(|| r.wall_time_s / time_to_best_s);
            Row {
                run: run.clone(),
                time_to_threshold_s: thresholds.iter().map(|&t| time_to(&run.curve, t)).collect(),
                time_to_best_s,
                reference_time_s,
                speedup,
                speedup_at_least,
            }
        })
        .collect()
}

/// A CSV field, quoted when it needs to be.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn curves_csv(runs: &[Run]) -> String {
    let mut text = String::from("run,method,preset,iteration,train_time_s,nrmse\n");
    for run in runs {
        for p in &run.curve {
            text += &format!(
                "{},{},{},{},{},{}\n",
                csv_field(&run.label),
                csv_field(&run.method),
                csv_field(run.preset.as_deref().unwrap_or("")),
                p.iteration,
                num(p.train_time_s),
                num(p.nrmse)
            );
        }
    }
    text
}

/// A time in seconds for the table, short whatever a report holds (a `train_time_s` of 1e308
/// took 309 digits and broke the table's columns).
fn seconds(t: Option<f64>) -> String {
    match t {
        Some(t) if t < 10.0 => fixed(t, 2),
        Some(t) => fixed(t, 1),
        None => "never".into(),
    }
}

/// A ratio with three significant digits (0.00452, 1.21, 38.5, 1250), in scientific notation
/// below 0.001 and from a million (1.00e308), where its digits would break the table.
fn ratio(r: f64) -> String {
    if !(r.is_finite() && r > 0.0) {
        return format!("{r}");
    }
    if !(1e-3..1e6).contains(&r) {
        return format!("{r:.2e}");
    }
    let decimals = (2 - r.log10().floor() as i32).max(0) as usize;
    format!("{r:.decimals$}")
}

/// The table printed to stdout, columns aligned.
fn table(rows: &[Row], reference: usize, thresholds: &[f64]) -> String {
    let mut header: Vec<String> =
        ["run", "final NRMSE", "best NRMSE", "wall time [s]"].iter().map(|s| s.to_string()).collect();
    header.extend(thresholds.iter().map(|t| format!("t(≤{t}) [s]")));
    header.push("speed-up vs reference".into());
    let mut cells: Vec<Vec<String>> = vec![header];
    for (k, r) in rows.iter().enumerate() {
        let mut line = vec![
            if k == reference { format!("{} *", r.run.label) } else { r.run.label.clone() },
            fixed(r.run.final_nrmse, 4),
            fixed(r.run.best_nrmse, 4),
            seconds(Some(r.run.wall_time_s)),
        ];
        line.extend(r.time_to_threshold_s.iter().map(|&t| seconds(t)));
        line.push(match (r.speedup, r.speedup_at_least) {
            (Some(s), _) => format!("{}x", ratio(s)),
            (None, Some(s)) => format!(">{}x", ratio(s)),
            (None, None) => "-".into(),
        });
        cells.push(line);
    }
    let widths: Vec<usize> =
        (0..cells[0].len()).map(|c| cells.iter().map(|l| l[c].chars().count()).max().unwrap_or(0)).collect();
    let mut text = String::new();
    for line in &cells {
        let padded: Vec<String> = line
            .iter()
            .zip(&widths)
            .enumerate()
            .map(|(c, (s, &w))| {
                let pad = " ".repeat(w - s.chars().count());
                if c == 0 {
                    format!("{s}{pad}")
                } else {
                    format!("{pad}{s}")
                }
            })
            .collect();
        text += padded.join("  ").trim_end();
        text.push('\n');
    }
    text
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.thresholds.is_empty() || args.thresholds.iter().any(|t| !(*t > 0.0 && *t < 10.0)) {
        bail!("--thresholds must be NRMSE values in (0, 10), got {:?}", args.thresholds);
    }
    super::given_once("--thresholds", &args.thresholds)?;
    let reference = args.reference.as_deref().map(|p| ("--reference", p));
    super::recordable("compare.json", args.runs.iter().map(|p| ("RUN", p.as_path())).chain(reference))?;
    let out = &args.out;
    fluidnerf_pipeline::rundir::refuse_other_kind(out, fluidnerf_pipeline::rundir::FolderKind::Compare, "compare")?;
    super::refuse_unwritable_output(out)?;
    let outputs = ["time_to_accuracy.png", "time_to_accuracy.svg", "time_to_accuracy.csv", "compare.json"];
    if !args.force && outputs.iter().any(|f| out.join(f).exists()) {
        bail!("{} already holds comparison results; use --force to overwrite", out.display());
    }
    let mut runs = args.runs.iter().map(|p| read_run(p)).collect::<anyhow::Result<Vec<Run>>>()?;
    // One run twice (as itself, through a link, or as its folder and its report file) would be
    // drawn and tabled twice, as if two runs had agreed.
    for (i, run) in runs.iter().enumerate() {
        if let Some(first) = runs[..i].iter().find(|r| same_file(&r.report, &run.report)) {
            bail!(
                "{} is given twice (as {} and {}); give each run once",
                run.report.display(),
                first.path.display(),
                run.path.display()
            );
        }
    }
    let reference = match &args.reference {
        None => 0,
        // A run given as its directory and as its report file is the same run.
        Some(r) => match runs.iter().position(|run| report_path(r).is_ok_and(|p| same_file(&run.report, &p))) {
            Some(k) => k,
            None => {
                runs.push(read_run(r).context("reading the --reference run")?);
                runs.len() - 1
            }
        },
    };
    let reference_path = runs[reference].path.clone();
    // What makes the rows less comparable than they look: under the table (standard output,
    // which -q keeps) and in compare.json, not only in the log.
    let mut warnings: Vec<String> = runs.iter().filter_map(|r| r.caveat.clone()).collect();
    refuse_other_scenes(&runs, args.allow_different_scenes, &mut warnings)?;
    refuse_other_instants(&runs)?;
    warn_of_other_grids(&runs, &mut warnings);
    warn_of_scoring_rules(&runs, &mut warnings);
    warn_of_single_points(&runs, &mut warnings);
    // Runs in folders of the same name are told apart by the path given.
    let labels: Vec<String> = runs.iter().map(|r| r.label.clone()).collect();
    for run in &mut runs {
        if labels.iter().filter(|l| **l == run.label).count() > 1 {
            run.label = format!("{} [{}]", run.label, run.path.display());
        }
    }

    let plot = LinePlot {
        title: "Volume NRMSE vs training time".into(),
        x_label: "training wall time [s]".into(),
        y_label: "volume NRMSE".into(),
        log_x: !args.linear_time,
        log_y: true,
        markers: runs.iter().any(|r| r.curve.len() < 12),
        integer_x: false,
        series: runs
            .iter()
            .map(|r| Series {
                label: r.label.clone(),
                x: r.curve.iter().map(|p| p.train_time_s).collect(),
                y: r.curve.iter().map(|p| p.nrmse).collect(),
                mark: r.kept.and_then(|k| r.curve.iter().find(|p| p.iteration == k)).map(|p| (p.train_time_s, p.nrmse)),
            })
            .collect(),
    };
    super::create_output_folder(out)?;
    for ext in ["png", "svg"] {
        let path = out.join(format!("time_to_accuracy.{ext}"));
        write_plots(&path, std::slice::from_ref(&plot), 1).with_context(|| format!("writing {}", path.display()))?;
    }
    let csv = out.join("time_to_accuracy.csv");
    fluidnerf_io::atomic_write(&csv, |w| w.write_all(curves_csv(&runs).as_bytes()))?;
    let rows = rows(&runs, reference, &args.thresholds);
    fluidnerf_pipeline::rundir::write_json(
        &out.join("compare.json"),
        &CompareRecord {
            version: env!("CARGO_PKG_VERSION"),
            thresholds: &args.thresholds,
            reference: &reference_path,
            linear_time: args.linear_time,
            runs: &rows,
            warnings: &warnings,
        },
    )?;
    #[allow(clippy::print_stdout)]
    {
        print!("{}", table(&rows, reference, &args.thresholds));
        println!(
            "* reference. Times exclude evaluations; speed-up = the reference's time to each run's best NRMSE over \
             the run's own."
        );
        for w in &warnings {
            println!("! {w}");
        }
        println!("wrote time_to_accuracy.png, .svg, .csv and compare.json in {}", out.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_label_leaves_out_what_repeats_the_method() {
        let label = |dir: &str, method, preset| label_of(Path::new(dir), Path::new(dir), method, preset);
        assert_eq!(label("runs/fluidnerf", "fast", Some("fast")), "fast (fluidnerf)");
        assert_eq!(label("runs/fast", "fast", Some("fast")), "fast");
        assert_eq!(label("runs/a", "tr-fast", Some("tr-small")), "tr-fast/tr-small (a)");
        assert_eq!(label("runs/asart", "asart", None), "asart");
        assert_eq!(label("runs/asart", "asart", Some("")), "asart");
        assert_eq!(label("curves/ref.json", "sirt", None), "sirt (ref)");
    }

    fn run(label: &str, points: &[(f64, f64)]) -> Run {
        let curve: Vec<Point> = points
            .iter()
            .enumerate()
            .map(|(k, &(t, e))| Point { iteration: k as u64 + 1, train_time_s: t, nrmse: e })
            .collect();
        Run {
            path: PathBuf::from(label),
            report: PathBuf::from(label),
            label: label.into(),
            method: "m".into(),
            preset: None,
            final_nrmse: curve[curve.len() - 1].nrmse,
            best_nrmse: curve.iter().map(|p| p.nrmse).fold(f64::INFINITY, f64::min),
            wall_time_s: curve[curve.len() - 1].train_time_s,
            curve,
            instants: None,
            interrupted: false,
            caveat: None,
            dims: None,
            scored: None,
            kept: None,
        }
    }

    /// Thresholds are read at evaluation points; the speed-up is the reference's time to the
    /// run's best accuracy over the run's, or a lower bound when the reference never got there.
    #[test]
    fn time_to_accuracy_and_speedups() {
        let reference = run("ref", &[(1.0, 0.6), (2.0, 0.4), (4.0, 0.25), (8.0, 0.22)]);
        let fast = run("fast", &[(0.5, 0.45), (1.0, 0.3), (2.0, 0.25)]);
        let better = run("better", &[(1.0, 0.3), (2.0, 0.18), (3.0, 0.2)]);
        let rows = rows(&[reference, fast, better], 0, &[0.5, 0.3, 0.2]);
        assert_eq!(rows[0].time_to_threshold_s, vec![Some(2.0), Some(4.0), None]);
        assert_eq!(rows[0].speedup, Some(1.0));
        assert_eq!(rows[1].time_to_threshold_s, vec![Some(0.5), Some(1.0), None]);
        assert_eq!(rows[1].speedup, Some(2.0), "ref reached 0.25 at 4 s, fast at 2 s");
        // Semi-convergent run: its best (0.18 at 2 s) counts, not its last point.
        assert_eq!(rows[2].time_to_best_s, 2.0);
        assert_eq!(rows[2].speedup, None);
        assert_eq!(rows[2].speedup_at_least, Some(4.0));
        let text = table(&rows, 0, &[0.5, 0.3, 0.2]);
        assert!(text.contains("ref *") && text.contains(">4.00x") && text.contains("never"), "{text}");
        assert_eq!(csv_field("a,b \"c\""), "\"a,b \"\"c\"\"\"");
        assert_eq!([ratio(0.004517), ratio(1.0), ratio(38.46), ratio(1250.2)], ["0.00452", "1.00", "38.5", "1250"]);
        // A curve without measured time (an external tool's at 0 s) gives no ratio, not 0x.
        let untimed = run("untimed", &[(0.0, 0.5), (0.0, 0.3)]);
        let rows = super::rows(&[untimed.clone(), untimed], 0, &[]);
        assert_eq!((rows[0].speedup, rows[0].speedup_at_least), (None, None));
    }
}
