//! Reading a run folder of any kind — voxel, static neural, time-resolved — for the commands
//! that use runs (`eval`, `export`, `render`, `compare`) and for scripts.
//!
//! A folder written by `reconstruct` is read through its typed report and configuration, and
//! refused while unfinished (a `config.json` without `report.json`). A folder assembled by
//! hand or by another tool (no `config.json`) is read by what it holds: `model.json` with its
//! weights, or `volume.npy` on a box given by the caller.

use std::path::{Path, PathBuf};

use fluidnerf_core::num;
use fluidnerf_core::{Aabb, ScalarField, Scene, Volume};
use fluidnerf_neural::trained::ModelRecord;

use crate::{Family, PipelineError, RunConfig, RunDir, RunKind, RunReport};

/// The folder of the scene at `path` (the folder or its `transforms.json`), resolved to one
/// spelling; None when it does not exist.
pub fn scene_folder(path: &Path) -> Option<PathBuf> {
    let folder = if path.is_file() { path.parent().unwrap_or(path) } else { path };
    std::fs::canonicalize(folder).ok()
}

/// The warning for the run in `dir`, made from the scene `made_from` (as its `config.json`
/// records it), used with the scene `given` (`how` says how): a run of one scene with the
/// cameras, box or truth of another is seldom what was meant. None when the two are one scene,
/// or the recorded one is gone.
pub fn other_scene_note(dir: &Path, made_from: &Path, given: &Path, how: &str) -> Option<String> {
    let recorded = scene_folder(made_from);
    (recorded.is_some() && recorded != scene_folder(given)).then(|| {
        format!("{} was made from the scene {}, not {}; {how}", dir.display(), made_from.display(), given.display())
    })
}

/// The warning for `what` (a run, a volume file, the truth) filling `aabb`, used with `scene`
/// whose box is another: what is scored or rendered then is not what the scene's cameras saw
/// (`consequence` says how). A `.npy` fills the scene's box by definition; a `.vti` or `.raw`
/// and a run record their own. None when the boxes agree, up to the last bits in which a box
/// read back from a file's origin and spacing may differ.
pub fn other_box_note(what: &str, aabb: &Aabb, scene: &Scene, consequence: &str) -> Option<String> {
    let tolerance = 1e-9 * scene.aabb.size().max_element();
    let off = (aabb.min - scene.aabb.min).abs().max((aabb.max - scene.aabb.max).abs()).max_element();
    (off > tolerance).then(|| {
        format!(
            "{what} fills the box {} .. {}, not the scene's {} .. {}: {consequence}",
            num(aabb.min.to_array()),
            num(aabb.max.to_array()),
            num(scene.aabb.min.to_array()),
            num(scene.aabb.max.to_array())
        )
    })
}

/// The instants a time-resolved run's field stands for ([`LoadedRun::time_span`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TimeSpan {
    /// The first frame time its windows trained.
    pub first: f64,
    /// The last frame time its windows trained: outside `first … last` the field only repeats
    /// one of them.
    pub last: f64,
    /// The later instants of the recording (frame and held-out times, increasing) that the run
    /// was stopped before reaching; `reconstruct --resume` trains them. Empty for a run that
    /// reached every instant.
    pub not_reached: Vec<f64>,
    /// The held-out instants outside `first … last` whose volumes the run wrote and scored with
    /// its field held at the nearest trained instant (`reconstruct --holdout-times` at an end
    /// of the recording): sampled there as the run sampled them.
    pub held_at_ends: Vec<f64>,
}

impl TimeSpan {
    /// Whether `t` is one of the run's held-out instants outside its trained ones
    /// ([`TimeSpan::held_at_ends`]).
    pub fn holds_at_end(&self, t: f64) -> bool {
        self.held_at_ends.iter().any(|&h| fluidnerf_core::scene::same_time(h, t))
    }

    /// What a reader should be told when it samples the field at `times`, the scene's instants
    /// it reads: the run's held-out instants outside its trained ones among them, where the
    /// field repeats the nearest trained instant. None when there are none.
    pub fn held_note(&self, times: impl IntoIterator<Item = f64>) -> Option<String> {
        let mut held: Vec<f64> = times.into_iter().filter(|&t| self.holds_at_end(t)).collect();
        held.sort_by(f64::total_cmp);
        held.dedup_by(|a, b| fluidnerf_core::scene::same_time(*a, *b));
        if held.is_empty() {
            return None;
        }
        let list: Vec<String> = held.iter().map(|&t| num(t).to_string()).collect();
        Some(format!(
            "t = {} held out at an end of the recording: the run's field repeats its nearest trained instant there \
             ({} … {}), as its report scored it",
            list.join(", "),
            num(self.first),
            num(self.last)
        ))
    }
}

/// How far outside `first … last` a time still counts as inside: rounding in the times' text.
fn time_slack(first: f64, last: f64) -> f64 {
    1e-9 * first.abs().max(last.abs()).max(1.0)
}

/// The time at which to sample a result whose instants are `span` (None for a static one) for
/// `what` (an option or a frame, named in errors): `given`, refused when it is not finite or
/// lies outside a time-resolved run's instants (where its field only repeats its first or last
/// one, or, after a stopped run's last trained frame, was never trained) unless the run held
/// it out there ([`TimeSpan::held_at_ends`]); else the first instant, and 0 for static results.
pub fn sample_time(span: Option<&TimeSpan>, given: Option<f64>, what: &str) -> Result<f64, PipelineError> {
    let refuse = |why: String| PipelineError::invalid(what, why);
    if let Some(t) = given.filter(|t| !t.is_finite()) {
        return Err(refuse(format!("the time must be a finite number, got {}", num(t))));
    }
    let Some(span) = span else { return Ok(given.unwrap_or(0.0)) };
    let TimeSpan { first, last, ref not_reached, .. } = *span;
    let slack = time_slack(first, last);
    match given {
        None => Ok(first),
        // The run wrote and scored this held-out instant with its field held at the nearest end.
        Some(t) if span.holds_at_end(t) => Ok(t),
        Some(t) if t > last + slack && !not_reached.is_empty() => {
            let list: Vec<String> = not_reached.iter().map(|&t| num(t).to_string()).collect();
            Err(refuse(format!(
                "time {} was never trained: the run was stopped before it reached t = {} (its windows trained \
                 {} … {}); continue it with `reconstruct --resume` (`overwrite=\"resume\"` from Python)",
                num(t),
                list.join(", "),
                num(first),
                num(last)
            )))
        }
        Some(t) if t < first - slack || t > last + slack => Err(refuse(format!(
            "time {} lies outside the time-resolved run's instants {} … {}",
            num(t),
            num(first),
            num(last)
        ))),
        Some(t) => Ok(t),
    }
}

/// The refusal of a run's description `path` whose field (`described`) is not the one its
/// config.json configures (`configured`).
fn other_field<T: serde::Serialize>(path: &std::path::Path, configured: &T, described: &T) -> PipelineError {
    PipelineError::file(
        path,
        format!(
            "describes another field than the run's config.json configures ({}): the file is not this run's result \
             (copied from another run, or edited?); rerun the reconstruction or restore the file",
            crate::rundir::settings_differences(configured, described, 5)
        ),
    )
}

/// Refuses a run folder's `report` (read from `report_path`) and `config.json` that are not of
/// one run: both are written by the same run, and a report copied in from another would have
/// its scores, curves and volumes taken for this run's. Every reader of a run folder holds its
/// files to this ([`LoadedRun::open`], `compare`).
pub fn check_same_run(report_path: &Path, report: &RunReport, config: &RunConfig) -> Result<(), PipelineError> {
    if report.method != config.method() {
        return Err(PipelineError::file(
            report_path,
            format!(
                "reports a run of method {}, but the folder's config.json configures method {}: the two files are \
                 of different runs (one copied in from another folder?); rerun the reconstruction or restore the \
                 file",
                report.method,
                config.method()
            ),
        ));
    }
    Ok(())
}

/// Refuses a run's `model.json` or `temporal.json` that is not the run's own: one whose field
/// fills another box than its report records (the run's box is the report's: eval, render and
/// export would place the field there), another field than its config.json configures, or,
/// for a time-resolved run, other windows than its report lists. Copied in from another run or
/// edited, it would be read as this run's result in this run's box.
fn check_description(rd: &RunDir, kind: RunKind, config: &RunConfig, report: &RunReport) -> Result<(), PipelineError> {
    let boxes: Vec<(PathBuf, Aabb)> = match kind {
        RunKind::Field => {
            let path = rd.path("model.json");
            let record: ModelRecord = crate::rundir::read_json(&path)?;
            if let crate::MethodConfig::Neural(_, spec) = &config.method {
                if spec.field != record.field {
                    return Err(other_field(&path, &spec.field, &record.field));
                }
            }
            vec![(path, record.meta.aabb)]
        }
        RunKind::Temporal => {
            let path = rd.path("temporal.json");
            let record: fluidnerf_neural::temporal::TemporalRecord = crate::rundir::read_json(&path)?;
            // The report lists the windows the run trained; the field is stitched from these.
            let listed: Vec<[usize; 2]> = record.windows.iter().map(|w| w.frames).collect();
            let reported: Vec<[usize; 2]> = report.windows.iter().map(|w| w.frames).collect();
            if listed != reported {
                return Err(PipelineError::file(
                    &path,
                    format!(
                        "lists the windows {listed:?}, but the run's report.json records the windows {reported:?}: \
                         the file is not this run's (copied from another run, or edited?); rerun the reconstruction \
                         or restore the file"
                    ),
                ));
            }
            // Each window's field reads time from its origin, which the report records too: an
            // origin edited in one of them would shift that window's instants.
            let moved = record.windows.iter().zip(&report.windows).find(|(w, r)| w.time_origin != r.time_origin);
            if let Some((w, r)) = moved {
                return Err(PipelineError::file(
                    &path,
                    format!(
                        "window frames {:?} has the time origin {}, but the run's report.json records {}: the file \
                         is not this run's (copied from another run, or edited?); rerun the reconstruction or \
                         restore the file",
                        w.frames,
                        num(w.time_origin),
                        num(r.time_origin)
                    ),
                ));
            }
            // Every window's field is the configured one, given its time axis for the windows'
            // length (`field_for_window`), as the run built it.
            if let (crate::MethodConfig::Temporal(_, spec), Some(first)) = (&config.method, record.windows.first()) {
                let built =
                    fluidnerf_neural::temporal::field_for_window(&spec.field, first.frames[1] - first.frames[0]);
                if built != record.field {
                    return Err(other_field(&path, &built, &record.field));
                }
            }
            record.windows.iter().map(|w| (path.clone(), w.meta.aabb)).collect()
        }
        RunKind::Volume => Vec::new(),
    };
    let text = |a: &Aabb| format!("{} .. {}", num(a.min.to_array()), num(a.max.to_array()));
    if let Some((path, aabb)) = boxes.into_iter().find(|(_, aabb)| *aabb != report.aabb) {
        return Err(PipelineError::file(
            &path,
            format!(
                "describes a field in the box {}, but the run's report.json records the box {}: the file is not \
                 this run's result (copied from another run, or edited?); rerun the reconstruction or restore the \
                 file",
                text(&aabb),
                text(&report.aabb)
            ),
        ));
    }
    Ok(())
}

/// A run folder's results and, for runs of `reconstruct`, their configuration and report.
pub struct LoadedRun {
    pub dir: PathBuf,
    pub kind: RunKind,
    pub config: Option<RunConfig>,
    pub report: Option<RunReport>,
    /// The box the results fill.
    pub aabb: Aabb,
}

impl std::fmt::Debug for LoadedRun {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadedRun").field("dir", &self.dir).field("kind", &self.kind).finish()
    }
}

impl LoadedRun {
    /// Opens the run in `dir`. `box_hint` (the scene's box) places a bare `.npy` volume, which
    /// holds no box of its own.
    pub fn open(dir: &Path, box_hint: Option<Aabb>) -> Result<Self, PipelineError> {
        let rd = RunDir::open(dir)?;
        let refuse = |why: &str| PipelineError::RunDir { path: dir.to_path_buf(), why: why.into() };
        // A run under way (a resume of a finished run among them) writes its report last.
        if !rd.report().is_file() {
            if let Some(holder) = rd.running_holder() {
                return Err(refuse(&format!(
                    "holds a run under way ({holder}), which has not written its results yet; wait for it to finish"
                )));
            }
        }
        let Some(kind) = rd.kind() else {
            if rd.progress().is_file() {
                // A time-resolved run trained window by window (or stopped) writes its results
                // only when it is finished.
                return Err(refuse(&format!(
                    "holds a time-resolved run that is not finished (windows/progress.json, but no \
                     temporal.json yet): train its missing windows and finish it (fluidnerf reconstruct \
                     --finish -o {0}, or --resume -o {0} to train what is left)",
                    dir.display()
                )));
            }
            // A run aborted (a second Ctrl-C, a kill) before it wrote any result.
            if rd.config().is_file() && rd.checkpoint().is_file() {
                return Err(refuse(&format!(
                    "holds a run stopped before it wrote its results (config.json and checkpoint.safetensors, but \
                     no volume.npy, model.json or temporal.json): continue it from its checkpoint (fluidnerf \
                     reconstruct -o {} --resume)",
                    dir.display()
                )));
            }
            // A finished run whose result was removed is not one that never wrote it.
            if rd.report().is_file() {
                return Err(refuse(
                    "holds a run's report.json but none of its results (no volume.npy, model.json or \
                     temporal.json): they were removed or moved; restore them, or run it again (reconstruct --force)",
                ));
            }
            if rd.config().is_file() {
                return Err(refuse(
                    "holds a run stopped before its first checkpoint or result (config.json only): there is nothing \
                     to read or continue; run it again (reconstruct --force)",
                ));
            }
            return Err(refuse("holds no reconstruction (no volume.npy, model.json or temporal.json)"));
        };
        if rd.report().is_file() {
            let report = RunReport::read(&rd.report())?;
            let config = RunConfig::read(&rd.config())?;
            check_same_run(&rd.report(), &report, &config)?;
            // Every run writes a volume (a time-resolved one, one per instant it reached): a
            // report that lists none was edited, and its run would be scored, rendered and read
            // as holding no result at all.
            if report.volumes.is_empty() {
                return Err(PipelineError::file(
                    &rd.report(),
                    "`volumes` lists no volume, but every run writes at least one (volume.npy): the file was \
                     edited or is another run's; rerun the reconstruction or restore the file",
                ));
            }
            // What the method writes must be there: a field's volume alone is not the field.
            let (wanted, file) = match config.method().family() {
                Family::Neural => (RunKind::Field, "model.json"),
                Family::Temporal => (RunKind::Temporal, "temporal.json"),
                Family::Classical => (RunKind::Volume, "volume.npy"),
            };
            if !rd.path(file).is_file() {
                return Err(refuse(&format!("a {} run whose {file} is missing", config.method())));
            }
            // A description of another kind of result beside it is another run's: the folder
            // would be read as that kind (model.json before volume.npy), and the refusal would
            // say the run's own file is missing when it is there.
            let foreign = [("model.json", RunKind::Field), ("temporal.json", RunKind::Temporal)]
                .into_iter()
                .find(|&(name, k)| k != wanted && rd.path(name).is_file());
            if let Some((name, _)) = foreign {
                return Err(refuse(&format!(
                    "a {} run that holds {name}, which such a run does not write: it is another run's (copied in?); \
                     remove it, or rerun the reconstruction",
                    config.method()
                )));
            }
            let kind = wanted;
            check_description(&rd, kind, &config, &report)?;
            let aabb = report.aabb;
            return Ok(LoadedRun { dir: dir.to_path_buf(), kind, config: Some(config), report: Some(report), aabb });
        }
        if rd.config().is_file() {
            return Err(refuse(
                "holds an unfinished run (config.json but no report.json); continue it with `reconstruct --resume` \
                 or rerun it",
            ));
        }
        let aabb = match kind {
            RunKind::Field => {
                let record: ModelRecord = crate::rundir::read_json(&rd.path("model.json"))?;
                record.meta.aabb
            }
            _ => box_hint.ok_or_else(|| {
                refuse(
                    "holds no report.json to give the box its volume fills; give the box (the scene it was made from, \
                     --scene; aabb= from Python)",
                )
            })?,
        };
        Ok(LoadedRun { dir: dir.to_path_buf(), kind, config: None, report: None, aabb })
    }

    /// The result as a continuous field: the trained network (static or of space and time),
    /// or the volume (sampled trilinearly).
    pub fn field(&self) -> Result<Box<dyn ScalarField + Send + Sync>, PipelineError> {
        Ok(match self.kind {
            RunKind::Field => fluidnerf_neural::trained::load_trained(&self.dir)?.0,
            RunKind::Temporal => Box::new(fluidnerf_neural::temporal::load_temporal(&self.dir)?),
            RunKind::Volume => Box::new(self.first_volume()?),
        })
    }

    /// The instants of a time-resolved run (`temporal.json`, and `not_reached` of its report);
    /// None for static runs. Its field is clamped to its first and last trained frames
    /// outside them, so it stands for nothing there.
    pub fn time_span(&self) -> Result<Option<TimeSpan>, PipelineError> {
        if self.kind != RunKind::Temporal {
            return Ok(None);
        }
        let path = self.dir.join("temporal.json");
        let record: fluidnerf_neural::temporal::TemporalRecord = crate::rundir::read_json(&path)?;
        let times = &record.frame_times;
        if let Some(why) = fluidnerf_neural::temporal::frame_times_problem(times) {
            return Err(PipelineError::file(&path, why));
        }
        // A stopped run's windows cover its first frames only.
        let covered = record.windows.iter().map(|w| w.frames[1]).max().unwrap_or(0);
        if covered == 0 || covered > times.len() {
            return Err(PipelineError::file(
                &path,
                format!("its windows cover frames 0..{covered} of {}", times.len()),
            ));
        }
        let mut not_reached = times[covered..].to_vec();
        not_reached.extend(self.report.iter().flat_map(|r| r.not_reached.iter().copied()));
        not_reached.sort_by(f64::total_cmp);
        not_reached.dedup_by(|a, b| fluidnerf_core::scene::same_time(*a, *b));
        let (first, last) = (times[0], times[covered - 1]);
        let slack = time_slack(first, last);
        let held_at_ends = self
            .report
            .iter()
            .flat_map(|r| &r.volumes)
            .filter_map(|v| v.time.filter(|&t| !v.trained && (t < first - slack || t > last + slack)))
            .collect();
        Ok(Some(TimeSpan { first, last, not_reached, held_at_ends }))
    }

    /// Every volume written, with its time (None for static runs).
    pub fn volumes(&self) -> Result<Vec<(Option<f64>, Volume)>, PipelineError> {
        let files: Vec<(Option<f64>, String)> = match &self.report {
            Some(r) => r.volumes.iter().map(|v| (v.time, v.file.clone())).collect(),
            None if self.kind == RunKind::Temporal => {
                return Err(PipelineError::RunDir {
                    path: self.dir.clone(),
                    why: "a time-resolved run without report.json: its volumes' times are unknown".into(),
                })
            }
            None => vec![(None, "volume.npy".into())],
        };
        files.into_iter().map(|(t, f)| Ok((t, self.read_volume(&f)?))).collect()
    }

    /// The first (for static runs: the only) volume.
    pub fn first_volume(&self) -> Result<Volume, PipelineError> {
        let file = match &self.report {
            Some(r) => r
                .volumes
                .first()
                .map(|v| v.file.clone())
                .ok_or_else(|| PipelineError::file(&self.dir.join("report.json"), "lists no volume"))?,
            None => "volume.npy".into(),
        };
        self.read_volume(&file)
    }

    /// The run's volume file `name`, refused when it holds a value that is not finite, or a
    /// grid other than the one its report records (a volume copied in from another run would
    /// otherwise be scored, exported and rendered as this run's).
    fn read_volume(&self, name: &str) -> Result<Volume, PipelineError> {
        // A run writes its volumes inside its folder; a report naming one elsewhere (edited, or
        // copied with another run's paths) would have that file scored as this run's.
        if Path::new(name).components().any(|c| !matches!(c, std::path::Component::Normal(_))) {
            return Err(PipelineError::file(
                &self.dir.join("report.json"),
                format!("lists the volume {name}, which is not a file inside the run folder"),
            ));
        }
        let path = self.dir.join(name);
        let volume = fluidnerf_io::volume::read_npy(&path, self.aabb)?;
        let recorded = self.report.as_ref().and_then(|r| r.volumes.iter().find(|v| v.file == name));
        if let Some(record) = recorded.filter(|r| r.dims != volume.dims) {
            let grid = |d: [usize; 3]| format!("{}x{}x{}", d[0], d[1], d[2]);
            return Err(PipelineError::file(
                &path,
                format!(
                    "holds a {} volume, but the run's report.json records {}: the file is not this run's result \
                     (copied from another run?); rerun the reconstruction or restore the file",
                    grid(volume.dims),
                    grid(record.dims)
                ),
            ));
        }
        fluidnerf_io::volume::check_finite(&path, &volume)?;
        // The frames of a time-resolved run share one grid: one frame's volume copied over
        // another's was read as that frame's. Its digest tells them apart.
        if let Some(record) = recorded {
            let held = crate::volume_digest(&volume);
            if record.digest.as_ref().is_some_and(|d| *d != held) {
                let at = |t: Option<f64>| t.map(|t| format!(" at t = {}", num(t))).unwrap_or_default();
                let whose = self
                    .report
                    .iter()
                    .flat_map(|r| &r.volumes)
                    .find(|v| v.digest.as_deref() == Some(held.as_str()))
                    .map(|v| format!("it holds the run's volume {}{}", v.file, at(v.time)))
                    .unwrap_or_else(|| "it holds none of the run's volumes".to_string());
                return Err(PipelineError::file(
                    &path,
                    format!(
                        "holds other values than the run wrote there (its report.json records the volume{} with \
                         digest {}, the file's is {held}): {whose} (copied over?); restore it, or rerun the \
                         reconstruction",
                        at(record.time),
                        record.digest.as_deref().unwrap_or_default()
                    ),
                ));
            }
        }
        Ok(volume)
    }
}
