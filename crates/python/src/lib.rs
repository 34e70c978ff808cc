//! `fluidnerf._fluidnerf`: the Python extension module of fluidnerf. The pure-Python package
//! `fluidnerf` (in `python/fluidnerf/`) wraps it with the documented API; this module is its
//! engine and keeps to arrays, paths and JSON text.
//!
//! Every call converts errors of the library (and any panic) into `fluidnerf.FluidNerfError`
//! (a `ValueError`) with the library's message; long calls release the GIL.

use std::ops::ControlFlow;

use numpy::{PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

mod ops;
mod run;
mod scene;

// Named in the module it is documented in, `fluidnerf`: as `_fluidnerf.FluidNerfError` (no
// module Python can import) it could not be pickled, so an error raised in a Dask task (or a
// process pool) reached the caller as another class, which `except fluidnerf.FluidNerfError`
// did not catch.
pyo3::create_exception!(
    fluidnerf,
    FluidNerfError,
    PyValueError,
    "An error of fluidnerf: bad input (naming the file, key or camera) or a failed run."
);

/// A `FluidNerfError` with `message`.
pub(crate) fn err(message: impl Into<String>) -> PyErr {
    FluidNerfError::new_err(message.into())
}

/// Runs `f`, turning a panic into a `FluidNerfError` instead of letting it cross into Python.
pub(crate) fn guard<T>(f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            Err(err(format!("internal error (please report): {what}")))
        }
    }
}

/// A volume as a `(nz, ny, nx)` float32 array (its buffer moved, not copied).
pub(crate) fn volume_to_py(py: Python<'_>, v: fluidnerf_core::Volume) -> PyResult<Bound<'_, PyArray3<f32>>> {
    let [nx, ny, nz] = v.dims;
    PyArray1::from_vec(py, v.data).reshape([nz, ny, nx])
}

/// A `(nz, ny, nx)` array filling `aabb` as a volume.
/// `value` as a flag: True or False (NumPy's booleans too); anything else (`1`, `"no"`) is a
/// `TypeError` naming `name`, where pyo3's own ("'int' object cannot be converted to
/// 'PyBool'") names no argument.
pub(crate) fn flag(value: &Bound<'_, PyAny>, name: &str) -> PyResult<bool> {
    value.extract::<bool>().map_err(|_| {
        let shown = value.repr().map(|r| r.to_string()).unwrap_or_else(|_| "?".into());
        let kind = value.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
        pyo3::exceptions::PyTypeError::new_err(format!("{name}: expected True or False, got {kind} {shown}"))
    })
}

pub(crate) fn volume_from_py(
    a: &PyReadonlyArray3<'_, f32>,
    aabb: fluidnerf_core::Aabb,
) -> PyResult<fluidnerf_core::Volume> {
    let shape = a.as_array().shape().to_vec();
    // `as_slice` also hands out a Fortran-ordered array's memory, which read as C order is
    // the volume transposed: only a C-contiguous array is copied whole.
    let data: Vec<f32> = match a.as_slice() {
        Ok(s) if a.is_c_contiguous() => s.to_vec(),
        _ => a.as_array().iter().copied().collect(),
    };
    if shape.contains(&0) {
        return Err(err(format!("volume: empty array of shape {shape:?}")));
    }
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(err(format!("volume: voxel {i} (flat index, C order) is not finite ({})", data[i])));
    }
    Ok(fluidnerf_core::Volume::from_vec([shape[2], shape[1], shape[0]], aabb, data))
}

/// Refuses a volume whose images times `scale` would overflow 32-bit floats (see
/// `fluidnerf_core::render::integrals_overflow`): they came back full of infinities and NaN.
pub(crate) fn check_integrals(v: &fluidnerf_core::Volume, scale: f64) -> PyResult<()> {
    match fluidnerf_core::render::integrals_overflow(v, scale) {
        Some(problem) => Err(err(format!("volume: {problem}"))),
        None => Ok(()),
    }
}

/// A `(2, 3)` box as an `Aabb`.
pub(crate) fn aabb_arg(a: &PyReadonlyArray2<'_, f64>) -> PyResult<fluidnerf_core::Aabb> {
    scene::aabb_from(a)
}

/// The window plan of `n_frames` frames in windows of `window` frames overlapping by
/// `overlap` (`fluidnerf_neural::window::plan_windows`): a list of `(first, end)` frame
/// ranges, `end` exclusive.
#[pyfunction]
fn plan_windows(n_frames: usize, window: usize, overlap: usize) -> PyResult<Vec<(usize, usize)>> {
    if window > 0 && window < n_frames && overlap >= window {
        return Err(err(format!("overlap: {overlap} frames must be fewer than the window's {window}")));
    }
    // As a run refuses it: one window holds every frame, and the overlap would be ignored.
    if overlap > 0 && window == 0 {
        return Err(err(format!(
            "overlap: {overlap} frames, but windows of 0 frames are one window holding every frame, so there are \
             no windows to overlap; give a window of fewer frames, or an overlap of 0"
        )));
    }
    if overlap > 0 && n_frames < 2 {
        return Err(err(format!(
            "overlap: {overlap} frames, but {n_frames} frame(s) make one window at most, so there are no windows \
             to overlap; give an overlap of 0"
        )));
    }
    if overlap > 0 && window >= n_frames {
        return Err(err(format!(
            "overlap: {overlap} frames, but windows of {window} frames hold all {n_frames} frames in one window, so \
             there are no windows to overlap; give a window below {n_frames}, or an overlap of 0"
        )));
    }
    // Each window is a field trained on its own: a plan of more than a million is a mistake,
    // and listing one of 10¹² would exhaust the memory before saying so.
    const MAX_WINDOWS: usize = 1_000_000;
    let count = if window == 0 || window >= n_frames { 1 } else { (n_frames - window).div_ceil(window - overlap) + 1 };
    if count > MAX_WINDOWS {
        return Err(err(format!(
            "n_frames: {n_frames} frames in windows of {window} overlapping by {overlap} make {count} windows; \
             at most {MAX_WINDOWS} are planned"
        )));
    }
    Ok(fluidnerf_neural::window::plan_windows(n_frames, window, overlap)
        .into_iter()
        .map(|r| (r.start, r.end))
        .collect())
}

/// The names and one-line descriptions of the reconstruction methods.
#[pyfunction]
fn methods() -> Vec<(&'static str, &'static str)> {
    fluidnerf_pipeline::Method::ALL.iter().map(|m| (m.name(), m.summary())).collect()
}

/// The synthetic presets `(name, description)`.
#[pyfunction]
fn synth_presets() -> Vec<(&'static str, &'static str)> {
    fluidnerf_synth::presets()
}

/// Keeps the run's callback and the first Python error it raised (or a Ctrl-C).
pub(crate) struct Callback {
    pub callback: Option<PyObject>,
    pub error: Option<PyErr>,
    /// When the GIL was last taken to look for signals (without a callback).
    last_check: Option<std::time::Instant>,
}

/// How often a run without a callback takes the GIL to look for Ctrl-C. Taking it at every
/// event (thousands per second for small problems) can starve Python threads waiting for it,
/// a timer that would send the very signal among them.
const SIGNAL_CHECK_INTERVAL: std::time::Duration = std::time::Duration::from_millis(50);

impl Callback {
    pub fn new(callback: Option<PyObject>) -> Self {
        Callback { callback, error: None, last_check: None }
    }

    /// Looks for Ctrl-C (at most every [`SIGNAL_CHECK_INTERVAL`]), for work without events of
    /// a run (a synthesis); keeps the `KeyboardInterrupt` and stops.
    pub fn check_signals(&mut self) -> ControlFlow<()> {
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        let now = std::time::Instant::now();
        if self.last_check.is_some_and(|t| now.duration_since(t) < SIGNAL_CHECK_INTERVAL) {
            return ControlFlow::Continue(());
        }
        self.last_check = Some(now);
        Python::with_gil(|py| match py.check_signals() {
            Ok(()) => ControlFlow::Continue(()),
            Err(e) => {
                self.error = Some(e);
                ControlFlow::Break(())
            }
        })
    }

    /// Delivers a run event to Python; stops the run on Ctrl-C or an exception in the callback.
    pub fn on_event(&mut self, event: &fluidnerf_pipeline::RunEvent) -> ControlFlow<()> {
        if self.callback.is_none() {
            return self.check_signals();
        }
        if self.error.is_some() {
            return ControlFlow::Break(());
        }
        Python::with_gil(|py| {
            if let Err(e) = py.check_signals() {
                self.error = Some(e);
                return ControlFlow::Break(());
            }
            let Some(cb) = &self.callback else { return ControlFlow::Continue(()) };
            let result = run::event_dict(py, event).and_then(|d| cb.call1(py, (d,)));
            match result {
                // Returning exactly False stops the run (its results are still written).
                Ok(v) if v.bind(py).downcast::<pyo3::types::PyBool>().is_ok_and(|b| !b.is_true()) => {
                    ControlFlow::Break(())
                }
                Ok(_) => ControlFlow::Continue(()),
                Err(e) => {
                    self.error = Some(e);
                    ControlFlow::Break(())
                }
            }
        })
    }
}

#[pymodule]
fn _fluidnerf(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("FluidNerfError", m.py().get_type::<FluidNerfError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<scene::PyScene>()?;
    m.add_class::<run::PyRun>()?;
    m.add_class::<run::PySceneAside>()?;
    m.add_function(wrap_pyfunction!(scene::read_transforms, m)?)?;
    m.add_function(wrap_pyfunction!(scene::read_opencv, m)?)?;
    m.add_function(wrap_pyfunction!(scene::read_colmap, m)?)?;
    m.add_function(wrap_pyfunction!(scene::read_metashape, m)?)?;
    m.add_function(wrap_pyfunction!(scene::read_projection, m)?)?;
    m.add_function(wrap_pyfunction!(scene::read_video, m)?)?;
    m.add_function(wrap_pyfunction!(scene::read_davis, m)?)?;
    m.add_function(wrap_pyfunction!(run::default_config, m)?)?;
    m.add_function(wrap_pyfunction!(run::check_config, m)?)?;
    m.add_function(wrap_pyfunction!(run::other_file_kind, m)?)?;
    m.add_function(wrap_pyfunction!(run::check_run_folder, m)?)?;
    m.add_function(wrap_pyfunction!(run::check_window_folder, m)?)?;
    m.add_function(wrap_pyfunction!(run::reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(run::window_plan, m)?)?;
    m.add_function(wrap_pyfunction!(run::check_given_windows, m)?)?;
    m.add_function(wrap_pyfunction!(run::reconstruct_windows, m)?)?;
    m.add_function(wrap_pyfunction!(run::finish_windows, m)?)?;
    m.add_function(wrap_pyfunction!(run::open_run, m)?)?;
    m.add_function(wrap_pyfunction!(ops::forward_project, m)?)?;
    m.add_function(wrap_pyfunction!(ops::back_project, m)?)?;
    m.add_function(wrap_pyfunction!(ops::render, m)?)?;
    m.add_function(wrap_pyfunction!(ops::nrmse, m)?)?;
    m.add_function(wrap_pyfunction!(ops::psnr, m)?)?;
    m.add_function(wrap_pyfunction!(ops::ssim, m)?)?;
    m.add_function(wrap_pyfunction!(ops::synth, m)?)?;
    m.add_function(wrap_pyfunction!(plan_windows, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(synth_presets, m)?)?;
    Ok(())
}
