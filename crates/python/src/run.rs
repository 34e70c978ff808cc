//! Runs: configuration (JSON text of `RunConfig`), `reconstruct` through the library
//! pipeline, the window-by-window path of time-resolved runs, and reading run folders.

use std::path::{Path, PathBuf};

use fluidnerf_core::glam::Vec3;
use fluidnerf_core::ScalarField;
use fluidnerf_pipeline::load::LoadedRun;
use fluidnerf_pipeline::{DirState, Method, MethodConfig, Overwrite, RunConfig, RunDir, RunEvent, RunKind};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::scene::PyScene;
use crate::{err, guard, volume_to_py, Callback};

fn to_json<T: serde::Serialize>(value: &T) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| err(format!("cannot write JSON: {e}")))
}

/// Parses and validates a `RunConfig` from JSON text, with the messages of `config.json`. The
/// version recorded is this one, as `reconstruct --config` records it: a configuration of an
/// earlier run (`run.config`) or a version given kept its own, and the new run's config.json
/// named a version that did not write it.
fn parse_config(text: &str) -> PyResult<RunConfig> {
    let value: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| err(format!("configuration: {}", fluidnerf_io::json::describe_error(text, &e))))?;
    let mut config: RunConfig = fluidnerf_pipeline::rundir::from_json_value(value).map_err(|e| err(e.to_string()))?;
    config.fluidnerf_version = env!("CARGO_PKG_VERSION").to_string();
    if config.format != fluidnerf_pipeline::CONFIG_FORMAT {
        return Err(err(format!(
            "format: configuration format {} is not the format {} this version reads",
            config.format,
            fluidnerf_pipeline::CONFIG_FORMAT
        )));
    }
    config.validate().map_err(|e| err(e.to_string()))?;
    Ok(config)
}

/// The default configuration (JSON text) of `method` on the scene `scene`, from `preset` for
/// neural methods when given.
#[pyfunction]
#[pyo3(signature = (scene, method, preset=None))]
pub fn default_config(scene: PathBuf, method: &str, preset: Option<&str>) -> PyResult<String> {
    guard(|| {
        let method: Method = method.parse().map_err(|e: fluidnerf_pipeline::PipelineError| err(e.to_string()))?;
        let mut config = RunConfig::new(scene, method);
        if let Some(p) = preset {
            config.method = MethodConfig::with_preset(method, p).map_err(|e| err(e.to_string()))?;
        }
        to_json(&config)
    })
}

/// Checks a configuration (JSON text) as `config.json` is checked; returns it normalised.
#[pyfunction]
pub fn check_config(config: &str) -> PyResult<String> {
    guard(|| to_json(&parse_config(config)?))
}

/// What other fluidnerf file than a run's configuration the JSON text is, in words (as
/// `--config` names a synth.json or a transforms.json given for one), or None.
#[pyfunction]
pub fn other_file_kind(text: &str) -> Option<&'static str> {
    use fluidnerf_pipeline::rundir::JsonFileKind;
    let value: serde_json::Value = serde_json::from_str(text).ok()?;
    JsonFileKind::of(&value).filter(|k| *k != JsonFileKind::RunConfig).map(JsonFileKind::describe)
}

/// An event as a dict: `{"kind": ..., ...}`.
pub(crate) fn event_dict<'py>(py: Python<'py>, event: &RunEvent) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let window = |d: &Bound<'py, PyDict>, w: &Option<fluidnerf_pipeline::WindowPos>| -> PyResult<()> {
        match w {
            Some(w) => {
                d.set_item("window", w.index)?;
                d.set_item("windows", w.count)
            }
            None => d.set_item("window", py.None()),
        }
    };
    match event {
        RunEvent::Started { method, max_iterations, windows, start_iteration } => {
            d.set_item("kind", "started")?;
            d.set_item("method", method.name())?;
            d.set_item("max_iterations", max_iterations)?;
            d.set_item("windows", windows)?;
            d.set_item("start_iteration", start_iteration)?;
        }
        RunEvent::StartFit { step, steps } => {
            d.set_item("kind", "start_fit")?;
            d.set_item("step", step)?;
            d.set_item("steps", steps)?;
        }
        RunEvent::Iteration { window: w, iteration, loss, smoothed, train_time_s } => {
            d.set_item("kind", "iteration")?;
            window(&d, w)?;
            d.set_item("iteration", iteration)?;
            d.set_item("loss", loss)?;
            d.set_item("smoothed", smoothed)?;
            d.set_item("train_time_s", train_time_s)?;
        }
        RunEvent::Evaluation { window: w, iteration, nrmse, holdout } => {
            d.set_item("kind", "evaluation")?;
            window(&d, w)?;
            d.set_item("iteration", iteration)?;
            d.set_item("nrmse", nrmse)?;
            d.set_item("holdout", holdout)?;
        }
        RunEvent::Estimate { seconds_per_iteration, iterations_left, seconds_left, budget_limited } => {
            d.set_item("kind", "estimate")?;
            d.set_item("seconds_per_iteration", seconds_per_iteration)?;
            d.set_item("iterations_left", iterations_left)?;
            d.set_item("seconds_left", seconds_left)?;
            d.set_item("budget_limited", budget_limited)?;
            d.set_item("message", event.describe_estimate())?;
        }
        RunEvent::Checkpoint { path } => {
            d.set_item("kind", "checkpoint")?;
            d.set_item("path", path.to_path_buf())?;
        }
        RunEvent::WindowFinished(w) => {
            d.set_item("kind", "window_finished")?;
            window(&d, &Some(*w))?;
        }
        RunEvent::Warning(message) => {
            d.set_item("kind", "warning")?;
            d.set_item("message", *message)?;
        }
        RunEvent::Writing => d.set_item("kind", "writing")?,
    }
    Ok(d)
}

fn overwrite_of(s: &str) -> PyResult<Overwrite> {
    match s {
        "refuse" => Ok(Overwrite::Refuse),
        "force" => Ok(Overwrite::Force),
        "resume" => Ok(Overwrite::Resume),
        other => Err(err(format!("overwrite: expected 'refuse', 'force' or 'resume', got {other:?}"))),
    }
}

/// Refuses `out` as a run folder for `overwrite` as `reconstruct` would, without writing
/// anything: checked before a scene built from arrays is saved into `out/scene`.
#[pyfunction]
#[pyo3(signature = (out, overwrite="refuse"))]
pub fn check_run_folder(out: PathBuf, overwrite: &str) -> PyResult<()> {
    let overwrite = overwrite_of(overwrite)?;
    guard(|| RunDir::check(&out, overwrite).map_err(|e| err(e.to_string())))
}

/// A run folder's own scene (`out/scene`) set aside under the folder's scene lock while a
/// scene built from arrays is saved in its place (`fluidnerf_pipeline::rundir::SceneAside`):
/// made before the scene is saved, then `finish()` once the run has written its configuration
/// or `take_back()` when it was refused before. Dropped otherwise (the process killed), the
/// next call or reader of the folder puts the scene back or discards it by whether the run
/// wrote its configuration.
#[pyclass(module = "fluidnerf._fluidnerf", name = "SceneAside")]
pub struct PySceneAside {
    inner: Option<fluidnerf_pipeline::rundir::SceneAside>,
}

#[pymethods]
impl PySceneAside {
    /// Takes the scene lock of `out` (made if missing), settles a scene an earlier call left
    /// aside and, with `replace`, moves the folder's own scene aside.
    #[new]
    fn new(out: PathBuf, replace: bool) -> PyResult<Self> {
        guard(|| {
            let inner = fluidnerf_pipeline::rundir::SceneAside::begin(&out, replace).map_err(|e| err(e.to_string()))?;
            Ok(PySceneAside { inner: Some(inner) })
        })
    }

    /// Whether the run has written its configuration since the scene went aside.
    fn written(&self) -> bool {
        self.inner.as_ref().is_some_and(fluidnerf_pipeline::rundir::SceneAside::written)
    }

    /// The run was refused before it wrote: the saved scene goes, the one set aside comes back
    /// (once it has written: as `finish`). Releases the lock; later calls do nothing.
    fn take_back(&mut self) -> PyResult<()> {
        match self.inner.take() {
            Some(inner) => guard(|| inner.take_back().map_err(|e| err(e.to_string()))),
            None => Ok(()),
        }
    }

    /// The run has started on the saved scene: the one set aside goes. Releases the lock;
    /// later calls do nothing.
    fn finish(&mut self) -> PyResult<()> {
        match self.inner.take() {
            Some(inner) => guard(|| inner.finish().map_err(|e| err(e.to_string()))),
            None => Ok(()),
        }
    }

    /// Releases the lock and leaves any scene aside for the next call to settle.
    fn release(&mut self) {
        self.inner = None;
    }
}

/// Refuses `out` as the folder of a time-resolved run trained window by window as
/// `reconstruct_windows` would, without writing anything: checked before a scene built from
/// arrays is saved into `out/scene`.
#[pyfunction]
pub fn check_window_folder(out: PathBuf) -> PyResult<()> {
    guard(|| RunDir::check_windows(&out, None).map_err(|e| err(e.to_string())))
}

/// Runs the configuration (JSON text) on the saved `scene` into `out` with the GIL released;
/// returns `report.json`'s text. `callback(event: dict)` sees every event; Ctrl-C (and an
/// exception in the callback) stops the run, which writes its results, and is raised after.
#[pyfunction]
#[pyo3(signature = (scene, config, out, overwrite="refuse", callback=None))]
pub fn reconstruct(
    py: Python<'_>,
    scene: &PyScene,
    config: &str,
    out: PathBuf,
    overwrite: &str,
    callback: Option<PyObject>,
) -> PyResult<String> {
    let config = guard(|| parse_config(config))?;
    let overwrite = overwrite_of(overwrite)?;
    let scene = scene.require_saved("reconstruct")?.clone();
    let mut cb = Callback::new(callback);
    let result = py.allow_threads(|| {
        guard(|| {
            fluidnerf_pipeline::rundir::check_start_outside(&config, &out, overwrite)
                .map_err(|e| err(e.to_string()))?;
            let dir = RunDir::create(&out, overwrite, Some(&scene.root)).map_err(|e| err(e.to_string()))?;
            let report = fluidnerf_pipeline::reconstruct(&scene, &config, &dir, |e| cb.on_event(e))
                .map_err(|e| err(e.to_string()))?;
            to_json(&report)
        })
    });
    if let Some(e) = cb.error {
        return Err(e);
    }
    result
}

/// The window plan of a time-resolved configuration on `scene`, as JSON text
/// (`{"frame_times": [...], "windows": [[a, b], ...], "warm_start": bool}`).
#[pyfunction]
pub fn window_plan(scene: &PyScene, config: &str) -> PyResult<String> {
    guard(|| {
        let config = parse_config(config)?;
        let plan = fluidnerf_pipeline::window_plan(&scene.inner, &config).map_err(|e| err(e.to_string()))?;
        to_json(&plan)
    })
}

/// Refuses the window settings given in `method` (`windows.frames` and `windows.overlap`, None
/// when not given) of the configuration `config` (JSON text, the given settings merged in) of a
/// run of `scene`, as the command line refuses its `--window` and `--overlap`
/// (`fluidnerf_pipeline::check_given_windows`): an overlap the run would record and ignore, or a
/// window shorter than the overlap it takes from `overlap_from` ("the preset's" or "the
/// configuration's"). Settings out of range otherwise are left to the configuration's check.
#[pyfunction]
#[pyo3(signature = (scene, config, frames=None, overlap=None, overlap_from="the preset's"))]
pub fn check_given_windows(
    scene: &PyScene,
    config: &str,
    frames: Option<usize>,
    overlap: Option<usize>,
    overlap_from: &str,
) -> PyResult<()> {
    guard(|| {
        let value: serde_json::Value = serde_json::from_str(config)
            .map_err(|e| err(format!("configuration: {}", fluidnerf_io::json::describe_error(config, &e))))?;
        let config: RunConfig = fluidnerf_pipeline::rundir::from_json_value(value).map_err(|e| err(e.to_string()))?;
        let given = fluidnerf_pipeline::GivenWindows {
            frames,
            overlap,
            frames_name: "method.windows.frames",
            overlap_name: "method.windows.overlap",
            overlap_from,
        };
        let check = |scene| fluidnerf_pipeline::check_given_windows(&config, scene, &given);
        check(None).map_err(|e| err(e.to_string()))?;
        // The scene's frames are planned over by a configuration that passes its own check.
        if config.validate().is_ok() {
            check(Some(&scene.inner)).map_err(|e| err(e.to_string()))?;
        }
        Ok(())
    })
}

/// Refuses to train or finish windows of `scene` with a configuration that names another
/// scene: the run's config.json would name a scene its windows were not trained on, and
/// windows trained on either could be stitched into one run.
fn check_scene_named(config: &RunConfig, scene: &fluidnerf_core::Scene) -> PyResult<()> {
    let file = |p: &std::path::Path| {
        let f = fluidnerf_io::scene::scene_file_path(p);
        f.canonicalize().unwrap_or_else(|_| std::path::absolute(&f).unwrap_or(f))
    };
    let (named, given) = (file(&config.scene), file(&scene.root));
    if named != given {
        return Err(err(format!(
            "scene: the configuration names the scene {}, not the one given ({}); give the scene it names, or \
             a configuration made for this one",
            named.display(),
            given.display()
        )));
    }
    Ok(())
}

/// Refuses to finish a run in `out` when no window of it has been trained there (the folder
/// holds none of a run's files, or does not exist). The library refuses it as a resume with
/// nothing to resume, naming `--resume` and `overwrite="resume"`, which the caller of
/// `finish` never used. A folder refused for its place (a file, the scene's folder, a folder
/// of another kind) is refused as the library refuses it.
fn refuse_untrained(out: &Path, scene_root: &Path) -> PyResult<()> {
    fluidnerf_pipeline::rundir::check_new_run_folder(out, Some(scene_root)).map_err(|e| err(e.to_string()))?;
    let untrained = !out.exists() || RunDir::open(out).is_ok_and(|dir| dir.state() == DirState::Empty);
    if untrained {
        return Err(err(format!(
            "{}: no window of the run has been trained in this folder yet, so there is nothing to finish; train \
             its windows first (fluidnerf.dask.train_window, one task per window), then finish",
            out.display()
        )));
    }
    Ok(())
}

/// Trains windows `start..end` of a time-resolved run into `out`
/// (`fluidnerf_pipeline::reconstruct_windows`); returns the outcomes as JSON text.
#[pyfunction]
#[pyo3(signature = (scene, config, out, start, end, callback=None))]
pub fn reconstruct_windows(
    py: Python<'_>,
    scene: &PyScene,
    config: &str,
    out: PathBuf,
    start: usize,
    end: usize,
    callback: Option<PyObject>,
) -> PyResult<String> {
    let config = guard(|| parse_config(config))?;
    let scene = scene.require_saved("reconstruct_windows")?.clone();
    check_scene_named(&config, &scene)?;
    let mut cb = Callback::new(callback);
    let result = py.allow_threads(|| {
        guard(|| {
            let outcomes =
                fluidnerf_pipeline::reconstruct_windows(&scene, &config, &out, start..end, |e| cb.on_event(e))
                    .map_err(|e| err(e.to_string()))?;
            to_json(&outcomes)
        })
    });
    if let Some(e) = cb.error {
        return Err(e);
    }
    result
}

/// Stitches a run whose windows have all finished and writes its results
/// (`fluidnerf_pipeline::finish_windows`); returns `report.json`'s text.
#[pyfunction]
#[pyo3(signature = (scene, config, out, callback=None))]
pub fn finish_windows(
    py: Python<'_>,
    scene: &PyScene,
    config: &str,
    out: PathBuf,
    callback: Option<PyObject>,
) -> PyResult<String> {
    let config = guard(|| parse_config(config))?;
    let scene = scene.require_saved("finish_windows")?.clone();
    check_scene_named(&config, &scene)?;
    let mut cb = Callback::new(callback);
    let result = py.allow_threads(|| {
        guard(|| {
            refuse_untrained(&out, &scene.root)?;
            let report = fluidnerf_pipeline::finish_windows(&scene, &config, &out, |e| cb.on_event(e))
                .map_err(|e| err(e.to_string()))?;
            to_json(&report)
        })
    });
    if let Some(e) = cb.error {
        return Err(e);
    }
    result
}

/// A finished run folder, read back (`fluidnerf_pipeline::load::LoadedRun`).
#[pyclass(module = "fluidnerf._fluidnerf", name = "RunFolder")]
pub struct PyRun {
    run: LoadedRun,
    /// The trained field, loaded on first use. A `OnceLock`, not a field behind `&mut self`:
    /// `field` works with the GIL released, and a second thread calling it meanwhile was
    /// refused with pyo3's "RuntimeError: Already borrowed".
    field: std::sync::OnceLock<Box<dyn ScalarField + Send + Sync>>,
    /// The run's files as they were when the run was opened ([`stamps`]): the field, report and
    /// configuration are read once and the volumes on each call, so a run whose files changed
    /// since mixed the old run's with the new.
    stamps: Vec<(PathBuf, Option<(u64, std::time::SystemTime)>)>,
}

/// The result files, report and configuration of the run in `folder`, each with its length and
/// modification time (None: absent).
fn stamps(folder: &std::path::Path) -> Vec<(PathBuf, Option<(u64, std::time::SystemTime)>)> {
    ["volume.npy", "weights.safetensors", "model.json", "temporal.json", "report.json", "config.json"]
        .iter()
        .map(|name| {
            let path = folder.join(name);
            let stamp = std::fs::metadata(&path).ok().and_then(|m| Some((m.len(), m.modified().ok()?)));
            (path, stamp)
        })
        .collect()
}

/// Opens the run in `folder`; `aabb` `(2, 3)` places a bare `volume.npy` that has no report.
#[pyfunction]
#[pyo3(signature = (folder, aabb=None))]
pub fn open_run(folder: PathBuf, aabb: Option<PyReadonlyArray2<'_, f64>>) -> PyResult<PyRun> {
    let hint = aabb.map(|a| crate::aabb_arg(&a)).transpose()?;
    // Made absolute now: the files are read again on later calls, and a relative folder would
    // then be found from whatever the working directory has become (another run's folder of
    // the same name, or none).
    let folder = std::path::absolute(&folder).unwrap_or(folder);
    guard(|| {
        let run = LoadedRun::open(&folder, hint).map_err(|e| err(e.to_string()))?;
        // A run that records its box (its report, or a field's model.json) fills that box, not
        // the one given: placing it there was left unsaid.
        let own = run.report.is_some() || run.kind == RunKind::Field;
        if let Some(given) = hint.filter(|&h| own && h != run.aabb) {
            return Err(err(format!(
                "aabb: {} records the box its results fill, {:?}..{:?}, not the one given ({:?}..{:?}); leave \
                 aabb out (it places only a bare volume.npy)",
                folder.display(),
                run.aabb.min.to_array(),
                run.aabb.max.to_array(),
                given.min.to_array(),
                given.max.to_array()
            )));
        }
        let stamps = stamps(&run.dir);
        Ok(PyRun { run, field: std::sync::OnceLock::new(), stamps })
    })
}

#[pymethods]
impl PyRun {
    /// Refuses `what` when a file of the run ([`stamps`]) has changed (or come or gone) since
    /// the run was opened: what it read then is another run's than the folder's.
    fn check_unchanged(&self, what: &str) -> PyResult<()> {
        if !self.run.dir.is_dir() {
            return Err(err(format!(
                "{what}: the run folder {} no longer exists (moved or removed since the run was opened)",
                self.run.dir.display()
            )));
        }
        let now = stamps(&self.run.dir);
        match self.stamps.iter().zip(&now).find(|(then, now)| then.1 != now.1) {
            Some(((path, then), (_, now))) => {
                let how = match (then, now) {
                    (Some(_), None) => "has been removed",
                    (None, Some(_)) => "has appeared",
                    _ => "has changed on disk",
                };
                Err(err(format!(
                    "{what}: {} {how} since the run was opened; open it again with fluidnerf.open_run",
                    path.display()
                )))
            }
            None => Ok(()),
        }
    }

    /// The run folder.
    #[getter]
    fn path(&self) -> PathBuf {
        self.run.dir.clone()
    }

    /// `"volume"` (a voxel method), `"field"` (a static neural field) or `"temporal"`.
    #[getter]
    fn kind(&self) -> &'static str {
        match self.run.kind {
            RunKind::Volume => "volume",
            RunKind::Field => "field",
            RunKind::Temporal => "temporal",
        }
    }

    /// `report.json` as JSON text, as read when the run was opened (None for folders not
    /// written by `reconstruct`); refused once the run's files have changed.
    #[getter]
    fn report_json(&self) -> PyResult<Option<String>> {
        self.check_unchanged("report")?;
        self.run.report.as_ref().map(to_json).transpose()
    }

    /// `config.json` as JSON text, as read when the run was opened (None for folders not
    /// written by `reconstruct`); refused once the run's files have changed.
    #[getter]
    fn config_json(&self) -> PyResult<Option<String>> {
        self.check_unchanged("config")?;
        self.run.config.as_ref().map(to_json).transpose()
    }

    /// The box the results fill, `(2, 3)`.
    #[getter]
    fn aabb<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
        let a = self.run.aabb;
        PyArray1::from_vec(py, vec![a.min.x, a.min.y, a.min.z, a.max.x, a.max.y, a.max.z]).reshape([2, 3])
    }

    /// The first (for static runs the only) volume, `(nz, ny, nx)` float32.
    fn volume<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray3<f32>>> {
        self.check_unchanged("volume")?;
        let v = py.allow_threads(|| guard(|| self.run.first_volume().map_err(|e| err(e.to_string()))))?;
        volume_to_py(py, v)
    }

    /// Every volume with its time: `[(time or None, (nz, ny, nx) array)]`.
    fn volumes(&self, py: Python<'_>) -> PyResult<Vec<(Option<f64>, PyObject)>> {
        self.check_unchanged("volumes")?;
        let vs = py.allow_threads(|| guard(|| self.run.volumes().map_err(|e| err(e.to_string()))))?;
        vs.into_iter().map(|(t, v)| Ok((t, volume_to_py(py, v)?.into_any().unbind()))).collect()
    }

    /// Scores the run on the frames the saved `scene` holds out, as `fluidnerf eval` does
    /// (`fluidnerf_pipeline::score::score_held_out`: each image as the run fitted the others,
    /// divided by the gain the run recorded for it, against the result rendered from its camera
    /// with `supersample` × `supersample` rays per pixel; a neural run's trained field, or with
    /// `use_volume` the volume it wrote of the frame's instant, as `eval --use-volume`); returns
    /// the rows as JSON text. The run is first checked against the scene as eval checks it
    /// (`fluidnerf_pipeline::score::check_run_on_scene`): `warn(message)` is called with each
    /// warning as it arises (an exception it raises is raised), and a held-out frame the run
    /// cannot be scored at is refused.
    #[pyo3(signature = (scene, supersample=2, use_volume=false, warn=None))]
    fn score_held_out(
        &self,
        py: Python<'_>,
        scene: &PyScene,
        supersample: usize,
        use_volume: bool,
        warn: Option<PyObject>,
    ) -> PyResult<String> {
        use fluidnerf_pipeline::score::{check_run_on_scene, volume_at};
        self.check_unchanged("score_held_out")?;
        let scene = scene.require_saved("score_held_out")?.clone();
        let max = fluidnerf_core::render::MAX_SUPERSAMPLE;
        if !(1..=max).contains(&supersample) {
            return Err(err(format!(
                "supersample: must be between 1 and {max} rays per pixel along each axis, got {supersample}"
            )));
        }
        if scene.holdout_frames().next().is_none() {
            return Err(err(format!(
                "scene: {} holds no frame out (`\"holdout\": true`), so there is nothing to score the run on",
                scene.root.display()
            )));
        }
        let held: Vec<(Option<f64>, String)> = scene
            .holdout_frames()
            .map(|(_, f)| (f.time, format!("the scene's held-out frame {}", f.file_path.display())))
            .collect();
        // Warned of with the GIL held, as they arise: one a warnings filter turns into an error
        // stops the call there.
        let mut warned: PyResult<()> = Ok(());
        let checked = guard(|| {
            check_run_on_scene(&self.run, &scene, use_volume, held.iter().cloned(), |message| {
                if let (Ok(()), Some(w)) = (&warned, &warn) {
                    warned = w.call1(py, (message,)).map(drop);
                }
            })
            .map_err(|e| err(e.to_string()))
        });
        warned?;
        checked?;
        let gains = match &self.run.report {
            Some(report) => fluidnerf_pipeline::score::recorded_gains(report, &self.run.dir.join("report.json"))
                .map_err(|e| err(e.to_string()))?,
            None => Vec::new(),
        };
        let options = fluidnerf_metrics::ReprojectionOptions { supersample, ..Default::default() };
        let scores: Vec<fluidnerf_metrics::ReprojectionMetrics> = py.allow_threads(|| {
            guard(|| {
                let scored = if self.run.kind == RunKind::Volume || use_volume {
                    let volumes = self.run.volumes().map_err(|e| err(e.to_string()))?;
                    // Each held-out frame's volume is found before any is rendered: the
                    // scoring gives the rendering the frame's time only, and cannot refuse.
                    for (time, what) in &held {
                        volume_at(&self.run.dir, &volumes, *time, what).map_err(|e| err(e.to_string()))?;
                    }
                    let first = &volumes
                        .first()
                        .ok_or_else(|| err(format!("{}: holds no volume to score", self.run.dir.display())))?
                        .1;
                    // Every held-out frame's time was matched above.
                    let at = |time: Option<f64>| -> &dyn ScalarField {
                        volume_at(&self.run.dir, &volumes, time, "").unwrap_or(first)
                    };
                    fluidnerf_pipeline::score::score_held_out(&scene, &gains, at, &options, || {})
                } else {
                    if self.field.get().is_none() {
                        let _ = self.field.set(self.run.field().map_err(|e| err(e.to_string()))?);
                    }
                    let field =
                        self.field.get().map(|f| f.as_ref()).ok_or_else(|| err("the field could not be loaded"))?;
                    let field: &dyn ScalarField = field;
                    fluidnerf_pipeline::score::score_held_out(&scene, &gains, |_| field, &options, || {})
                };
                scored.map_err(|e| err(e.to_string()))
            })
        })?;
        to_json(&scores)
    }

    /// What a reader sampling a time-resolved run at `time` should be told: the run's held-out
    /// instant outside its trained ones, where its field repeats the nearest trained instant
    /// (as the command line warns). None otherwise.
    fn held_note(&self, time: f64) -> PyResult<Option<String>> {
        let span = self.run.time_span().map_err(|e| err(e.to_string()))?;
        Ok(span.and_then(|s| s.held_note([time])))
    }

    /// The result evaluated at world points `(N, 3)` (x, y, z) at `time`: the trained field
    /// of neural runs, the volume sampled trilinearly for voxel runs. Returns `(N,)` float32.
    /// For a time-resolved run `time` must lie between its first and last instants (a stopped
    /// run: the last it trained; default: the first); static results ignore it.
    #[pyo3(signature = (points, time=None))]
    fn field<'py>(
        &self,
        py: Python<'py>,
        points: PyReadonlyArray2<'py, f32>,
        time: Option<f64>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        self.check_unchanged("field")?;
        let span = self.run.time_span().map_err(|e| err(e.to_string()))?;
        let time =
            fluidnerf_pipeline::load::sample_time(span.as_ref(), time, "time").map_err(|e| err(e.to_string()))?;
        let p = points.as_array();
        if p.ncols() != 3 {
            return Err(err(format!("points: expected shape (N, 3), got {:?}", p.shape())));
        }
        let pts: Vec<Vec3> = p.rows().into_iter().map(|r| Vec3::new(r[0], r[1], r[2])).collect();
        if let Some(i) = pts.iter().position(|v| !v.is_finite()) {
            return Err(err(format!("points: point {i} is not finite")));
        }
        if self.field.get().is_none() {
            let f = py.allow_threads(|| guard(|| self.run.field().map_err(|e| err(e.to_string()))))?;
            // Another thread may have loaded it meanwhile: either is the same field.
            let _ = self.field.set(f);
        }
        let field = self.field.get().map(|f| f.as_ref()).ok_or_else(|| err("the field could not be loaded"))?;
        let out = py.allow_threads(|| {
            guard(|| {
                use rayon::prelude::*;
                let mut out = vec![0f32; pts.len()];
                out.par_chunks_mut(16_384).zip(pts.par_chunks(16_384)).for_each(|(o, p)| field.eval(p, time, o));
                Ok(out)
            })
        })?;
        Ok(PyArray1::from_vec(py, out))
    }
}
