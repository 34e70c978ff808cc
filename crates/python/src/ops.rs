//! Operators on NumPy arrays: the classical projectors (forward and adjoint), the reference
//! renderer, the metrics, and synthetic scenes.

use std::path::PathBuf;

use fluidnerf_classical::{Grid, ProjectorConfig};
// The reference renderer's limits, checked in `render` to name the Python arguments.
use fluidnerf_core::num;
use fluidnerf_core::render::MAX_SUPERSAMPLE;
use fluidnerf_core::{Image, RenderSettings};
use numpy::{PyArray1, PyArray3, PyArrayMethods, PyReadonlyArray3, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use crate::scene::{images_to_py, PyScene};

/// The most voxels a volume of the classical projectors holds (they index voxels in 32 bits).
pub const MAX_VOXELS: u64 = u32::MAX as u64;
use crate::{check_integrals, err, guard, volume_from_py, Callback};

/// The projector settings from JSON text (`fluidnerf_classical::ProjectorConfig`; unknown keys
/// are refused), validated. A projector here serves one call, so it keeps no footprints.
fn projector_config(text: &str) -> PyResult<ProjectorConfig> {
    let value: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| err(format!("projector: {}", fluidnerf_io::json::describe_error(text, &e))))?;
    // The visual hull holds a reconstruction's voxels at zero; a projection has none to hold.
    const HULL: [&str; 4] = ["visual_hull", "hull_threshold", "hull_noise_sigmas", "hull_dilation"];
    let given: Vec<&str> = HULL.into_iter().filter(|k| value.get(*k).is_some()).collect();
    if !given.is_empty() {
        return Err(err(format!(
            "projector: {} set(s) the visual hull of the voxel methods' reconstructions (a run's \
             method.projector), which a projection does not use; leave {} out",
            given.join(", "),
            if given.len() == 1 { "it" } else { "them" }
        )));
    }
    // Footprints are kept from one iteration of a reconstruction to the next; a projection
    // makes one pass, and the value given was set to 0 without a word.
    if value.get("kept_footprints_mib").is_some() {
        return Err(err(
            "projector: kept_footprints_mib sets the footprints the voxel methods keep between the iterations of a \
             reconstruction (a run's method.projector); a projection makes one pass and keeps none: leave it out",
        ));
    }
    let config: ProjectorConfig = serde_json::from_value(value).map_err(|e| err(format!("projector: {e}")))?;
    config.validate().map_err(|e| err(format!("projector: {e}")))?;
    Ok(ProjectorConfig { kept_footprints_mib: 0, ..config })
}

/// `A x`: the images the scene's cameras record of the volume `(nz, ny, nx)` filling the
/// scene's box, through the classical projector (`projector` JSON: `kind` "auto",
/// "footprint", "splat" or "ray", `splat_subdivisions`, `ray_step`), scaled by the scene's
/// `intensity_scale`. Every frame,
/// in frame order.
#[pyfunction]
#[pyo3(signature = (scene, volume, projector="{}"))]
pub fn forward_project(
    py: Python<'_>,
    scene: &PyScene,
    volume: PyReadonlyArray3<'_, f32>,
    projector: &str,
) -> PyResult<PyObject> {
    let config = projector_config(projector)?;
    let volume = volume_from_py(&volume, scene.inner.aabb)?;
    check_integrals(&volume, scene.inner.intensity_scale)?;
    let cameras = scene.cameras();
    let scale = scene.inner.intensity_scale;
    let images = py.allow_threads(|| {
        guard(|| {
            let grid = Grid::new(volume.dims, volume.aabb);
            // On axes where the grid rows share footprints, if the cameras ring `y` or `z`.
            let shift = config.row_shift(&grid, &cameras);
            let moved = shift.cameras(&cameras);
            let x = shift.data(grid.dims, &volume.data);
            let p = config.build(shift.grid(&grid), &moved, scale).map_err(|e| err(e.to_string()))?;
            let mut images: Vec<Image> = cameras.iter().map(|c| Image::zeros(c.width(), c.height())).collect();
            let views: Vec<usize> = (0..cameras.len()).collect();
            let mut outs: Vec<&mut [f32]> = images.iter_mut().map(|im| im.data.as_mut_slice()).collect();
            p.forward_views(&views, &x, &mut outs);
            Ok(images)
        })
    })?;
    images_to_py(py, images)
}

/// `Aᵀ y`: the adjoint of [`forward_project`], images (one per frame: an `(N, H, W)` array or
/// a list of `(H, W)` arrays) smeared back into a volume of `shape` `(nz, ny, nx)` filling the
/// scene's box.
#[pyfunction]
#[pyo3(signature = (scene, images, shape, projector="{}"))]
pub fn back_project<'py>(
    py: Python<'py>,
    scene: &PyScene,
    images: Vec<PyReadonlyArrayDyn<'py, f32>>,
    shape: (usize, usize, usize),
    projector: &str,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let config = projector_config(projector)?;
    let cameras = scene.cameras();
    if images.len() != cameras.len() {
        return Err(err(format!("images: expected {} images (one per frame), got {}", cameras.len(), images.len())));
    }
    let mut data = Vec::with_capacity(images.len());
    for (i, (img, c)) in images.iter().zip(&cameras).enumerate() {
        let a = img.as_array();
        if a.shape() != [c.height(), c.width()] {
            return Err(err(format!(
                "images[{i}]: expected shape ({}, {}) for frame {i}'s camera, got {:?}",
                c.height(),
                c.width(),
                a.shape()
            )));
        }
        let pixels: Vec<f32> = a.iter().copied().collect();
        if let Some(p) = pixels.iter().position(|v| !v.is_finite()) {
            return Err(err(format!(
                "images[{i}]: pixel (row {}, column {}) is not finite ({})",
                p / c.width(),
                p % c.width(),
                pixels[p]
            )));
        }
        data.push(pixels);
    }
    let (nz, ny, nx) = shape;
    if nx == 0 || ny == 0 || nz == 0 {
        return Err(err(format!("shape: every side must be positive, got {shape:?}")));
    }
    // The projectors index voxels in 32 bits: a larger grid, or one whose count overflows,
    // made the footprint projector panic ("chunk_size must not be zero").
    let count = [nx, ny, nz].iter().try_fold(1u64, |acc, &n| acc.checked_mul(n as u64));
    if count.is_none_or(|c| c > MAX_VOXELS) {
        return Err(err(format!(
            "shape: {shape:?} makes more voxels than the {MAX_VOXELS} (2^32 - 1) the projectors hold"
        )));
    }
    let scale = scene.inner.intensity_scale;
    let aabb = scene.inner.aabb;
    // A shape beyond the memory was allocated as it came: the process aborted ("memory
    // allocation of 13500000000 bytes failed"), taking the interpreter with it. The volume (and
    // its copy when the projector works on turned axes) is checked against what the system can
    // give, and allocated fallibly.
    let mib = |bytes: u64| bytes.div_ceil(1 << 20);
    let volume_bytes = count.unwrap_or(0) * 4;
    if let Some(available) = fluidnerf_pipeline::available_memory().filter(|&a| 2 * volume_bytes > a) {
        return Err(err(format!(
            "shape: a volume of {shape:?} voxels needs about {} MiB of memory (it and a copy), but only {} MiB are \
             available; give a smaller shape",
            mib(2 * volume_bytes),
            mib(available)
        )));
    }
    let out = py.allow_threads(|| {
        guard(|| {
            let grid = Grid::new([nx, ny, nz], aabb);
            let mut out = Vec::new();
            out.try_reserve_exact(grid.len()).map_err(|_| {
                err(format!(
                    "shape: a volume of {shape:?} voxels needs {} MiB of memory, which could not be allocated; give a \
                     smaller shape",
                    mib(volume_bytes)
                ))
            })?;
            out.resize(grid.len(), 0f32);
            let shift = config.row_shift(&grid, &cameras);
            let moved = shift.cameras(&cameras);
            let p = config.build(shift.grid(&grid), &moved, scale).map_err(|e| err(e.to_string()))?;
            let views: Vec<usize> = (0..data.len()).collect();
            let ys: Vec<&[f32]> = data.iter().map(Vec::as_slice).collect();
            p.back_add_views(&views, &ys, &mut out, None);
            Ok(shift.data_back(grid.dims, out))
        })
    })?;
    // The pixels are finite, so a voxel that is not overflowed: the volume came back as NaN.
    if out.iter().any(|v| !v.is_finite()) {
        let largest = data.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
        return Err(err(format!(
            "images: pixels up to {largest:.3e}, smeared back through the box times the intensity scale {}, sum to \
             voxels beyond the largest 32-bit float ({:.3e}): scale the images down",
            num(scale),
            f32::MAX
        )));
    }
    PyArray1::from_vec(py, out).reshape([nz, ny, nx])
}

/// Line integrals of the volume `(nz, ny, nx)` (trilinear, filling the scene's box) through
/// every pixel centre of the scene's cameras, times `intensity_scale`: the reference renderer
/// (`fluidnerf_core::render_image`). `step` is the quadrature step in world units (None: the
/// box's smallest side / 256; at most 2^20 steps along the box's diagonal), `supersample` rays
/// per pixel per axis (1 to 64).
#[pyfunction]
#[pyo3(signature = (scene, volume, step=None, supersample=1))]
pub fn render(
    py: Python<'_>,
    scene: &PyScene,
    volume: PyReadonlyArray3<'_, f32>,
    step: Option<f64>,
    supersample: usize,
) -> PyResult<PyObject> {
    if !(1..=MAX_SUPERSAMPLE).contains(&supersample) {
        return Err(err(format!(
            "supersample: rays per pixel along each axis must be between 1 and {MAX_SUPERSAMPLE}, got {supersample}"
        )));
    }
    if let Some(step) = step {
        if !(step > 0.0 && step.is_finite()) {
            return Err(err(format!("step: must be a positive number of world units, got {}", num(step))));
        }
        if let Some(problem) = fluidnerf_core::render::step_out_of_range(&scene.inner.aabb, step, &scene.inner.units) {
            return Err(err(format!("step: {problem}")));
        }
    }
    let volume = volume_from_py(&volume, scene.inner.aabb)?;
    check_integrals(&volume, scene.inner.intensity_scale)?;
    let cameras = scene.cameras();
    let settings = RenderSettings { step, supersample, time: 0.0, scale: scene.inner.intensity_scale };
    let aabb = scene.inner.aabb;
    let images = py.allow_threads(|| {
        guard(|| {
            cameras
                .iter()
                .enumerate()
                .map(|(i, c)| {
                    fluidnerf_core::render_image(&volume, c, &aabb, &settings)
                        .map_err(|e| err(format!("camera {i}: {e}")))
                })
                .collect::<PyResult<Vec<Image>>>()
        })
    })?;
    images_to_py(py, images)
}

/// Two arrays of one shape as flat f32 vectors, every value finite.
fn pair(
    a: &PyReadonlyArrayDyn<'_, f32>,
    b: &PyReadonlyArrayDyn<'_, f32>,
) -> PyResult<(Vec<f32>, Vec<f32>, Vec<usize>)> {
    let (x, y) = (a.as_array(), b.as_array());
    if x.shape() != y.shape() {
        return Err(err(format!("estimate and truth differ in shape: {:?} and {:?}", x.shape(), y.shape())));
    }
    if x.is_empty() {
        return Err(err("empty arrays"));
    }
    let (a, b): (Vec<f32>, Vec<f32>) = (x.iter().copied().collect(), y.iter().copied().collect());
    for (name, v) in [("estimate", &a), ("truth", &b)] {
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(err(format!("{name}: element {i} (flat index, C order) is not finite ({})", v[i])));
        }
    }
    Ok((a, b, x.shape().to_vec()))
}

/// The peak of PSNR and SSIM: `data_range`, else the truth's max − min, refused as the library
/// refuses it (`fluidnerf_metrics::data_range_problem`) for SSIM's constants `ks` (`[0, 0]` for
/// PSNR): a range beyond the largest difference of two float32 values, whose square overflowed
/// the metrics' constants (PSNR infinite, SSIM NaN), and for SSIM one so small that its
/// constants vanish (SSIM NaN), unannounced.
fn metric_range(data_range: Option<f64>, truth: &[f32], ks: [f64; 2]) -> PyResult<f64> {
    let range = data_range.unwrap_or_else(|| fluidnerf_metrics::data_range_of(truth));
    match fluidnerf_metrics::data_range_problem(range, ks) {
        Some(why) => Err(err(format!("data_range: {why}"))),
        None => Ok(range),
    }
}

/// NRMSE of `estimate` against `truth` (dissertation Eq. 6.18: RMS error over the truth's RMS).
#[pyfunction]
pub fn nrmse(
    py: Python<'_>,
    estimate: PyReadonlyArrayDyn<'_, f32>,
    truth: PyReadonlyArrayDyn<'_, f32>,
) -> PyResult<f64> {
    let (a, b, _) = pair(&estimate, &truth)?;
    if b.iter().all(|&v| v == 0.0) {
        return Err(err("truth: every element is zero, so the NRMSE (relative to the truth's norm) is undefined"));
    }
    py.allow_threads(|| guard(|| Ok(fluidnerf_metrics::nrmse(&a, &b))))
}

/// PSNR in dB with peak `data_range` (None: the truth's max − min, or 1 when the truth is constant).
#[pyfunction]
#[pyo3(signature = (estimate, truth, data_range=None))]
pub fn psnr(
    py: Python<'_>,
    estimate: PyReadonlyArrayDyn<'_, f32>,
    truth: PyReadonlyArrayDyn<'_, f32>,
    data_range: Option<f64>,
) -> PyResult<f64> {
    let (a, b, _) = pair(&estimate, &truth)?;
    // PSNR is finite for every positive range (`fluidnerf_metrics::psnr`): no constants to keep.
    let range = metric_range(data_range, &b, [0.0, 0.0])?;
    py.allow_threads(|| guard(|| Ok(fluidnerf_metrics::psnr(&a, &b, range))))
}

/// SSIM of `estimate` against `truth`: `window` "global" (one window over the whole array),
/// "uniform" (7-wide, skimage's default) or "gaussian" (σ 1.5), for 2D `(H, W)` and 3D
/// `(nz, ny, nx)` arrays. `data_range` None: the truth's max − min (1 when the truth is constant). The GIL is released while
/// it computes (seconds for a large volume).
#[pyfunction]
#[pyo3(signature = (estimate, truth, data_range=None, window="uniform"))]
pub fn ssim(
    py: Python<'_>,
    estimate: PyReadonlyArrayDyn<'_, f32>,
    truth: PyReadonlyArrayDyn<'_, f32>,
    data_range: Option<f64>,
    window: &str,
) -> PyResult<f64> {
    let (a, b, shape) = pair(&estimate, &truth)?;
    // The global SSIM takes the default constants too.
    let k = fluidnerf_metrics::SsimParams::default();
    let range = metric_range(data_range, &b, [k.k1, k.k2])?;
    let params = match window {
        "global" => return py.allow_threads(|| guard(|| Ok(fluidnerf_metrics::ssim_global(&a, &b, range)))),
        "uniform" => fluidnerf_metrics::SsimParams { data_range: Some(range), ..Default::default() },
        "gaussian" => {
            fluidnerf_metrics::SsimParams { data_range: Some(range), ..fluidnerf_metrics::SsimParams::gaussian() }
        }
        other => return Err(err(format!("window: expected 'global', 'uniform' or 'gaussian', got {other:?}"))),
    };
    let r = py.allow_threads(|| {
        guard(|| {
            Ok(match shape.as_slice() {
                [h, w] => fluidnerf_metrics::ssim_2d(&a, &b, *w, *h, &params),
                [nz, ny, nx] => fluidnerf_metrics::ssim_3d(&a, &b, [*nx, *ny, *nz], &params),
                s => return Err(err(format!("ssim: expected a 2D or 3D array, got shape {s:?}"))),
            })
        })
    })?;
    r.map_err(|e| match e {
        // The library gives the sides x first; the arrays were given (nz, ny, nx) or (H, W).
        fluidnerf_metrics::MetricsError::TooSmall { window: side, .. } => err(format!(
            "estimate and truth: shape {} has a side shorter than the {side}-wide SSIM window of \
             window={window:?}; give arrays at least {side} long on every axis, or window=\"global\"",
            shape_text(&shape)
        )),
        other => err(other.to_string()),
    })
}

/// A shape of two or three sides as Python writes it: `(1, 30, 30)`.
fn shape_text(shape: &[usize]) -> String {
    format!("({})", shape.iter().map(usize::to_string).collect::<Vec<_>>().join(", "))
}

/// Synthesises the scene of preset `preset` (settings overridden by the JSON object
/// `overrides`, merged key by key into the preset's settings; see `merge`) into `folder` as the
/// `synth` command writes it (`fluidnerf_pipeline::synthetic`): images, ground truth
/// (`truth/*.npy`), `transforms.json`, and its records `preview.png` and `synth.json`. Returns
/// the scene.
#[pyfunction]
#[pyo3(signature = (folder, preset, overrides="{}", force=false))]
pub fn synth(py: Python<'_>, folder: PathBuf, preset: &str, overrides: &str, force: bool) -> PyResult<PyScene> {
    let mut settings = guard(|| fluidnerf_synth::preset(preset).map_err(|e| err(e.to_string())))?;
    let patch: serde_json::Value = serde_json::from_str(overrides)
        .map_err(|e| err(format!("settings: {}", fluidnerf_io::json::describe_error(overrides, &e))))?;
    let overridden = |key: &str| patch.get(key).is_some();
    let (given_resolution, given_aabb) = (overridden("resolution"), overridden("aabb"));
    if patch.as_object().is_some_and(|o| !o.is_empty()) {
        let mut value = serde_json::to_value(&settings).map_err(|e| err(e.to_string()))?;
        merge(&mut value, patch);
        settings = fluidnerf_pipeline::rundir::from_json_value(value)
            .map_err(|e| err(e.to_string().replacen("configuration", "synth settings", 1)))?;
    }
    guard(|| settings.validate().map_err(|e| err(e.to_string())))?;
    // The frames are made in time order; the recorded times follow them.
    settings.times.sort_by(f64::total_cmp);
    // A volume of the user's is the truth as it is, on its own grid; a .vti or a calibrated
    // TIFF stack also brings its own box (as with `fluidnerf synth --truth-volume`).
    let volume = match (&settings.phantom.volume_path, settings.phantom.kind) {
        (Some(path), fluidnerf_synth::phantom::PhantomKind::Volume) => {
            let volume = guard(|| {
                fluidnerf_pipeline::synthetic::read_truth_volume(path, settings.aabb, fluidnerf_synth::UNITS)
                    .map_err(|e| err(e.to_string()))
            })?;
            if given_resolution {
                return Err(err(format!(
                    "resolution: the truth volume {} is imaged on its own grid; resample it first, or leave \
                     resolution out",
                    path.display()
                )));
            }
            if given_aabb && volume.aabb != settings.aabb {
                return Err(err(format!(
                    "aabb: the truth volume {} holds its own box; leave aabb out, or give the volume as a .npy, \
                     which fills the box given",
                    path.display()
                )));
            }
            Some(volume)
        }
        _ => None,
    };
    // The folder checks of `fluidnerf synth`: never among a run's (or an export's, ...) files,
    // and a user's files are not replaced by the scene's of the same name without force=True.
    use fluidnerf_pipeline::rundir::{refuse_other_kind, FolderKind};
    guard(|| refuse_other_kind(&folder, FolderKind::Scene, "synth").map_err(|e| err(e.to_string())))?;
    let scene_file = folder.join("transforms.json");
    // Even with force=True it could not be written, and would fail as "Is a directory".
    if scene_file.is_dir() {
        return Err(err(format!(
            "{}: is a folder, where the scene file goes; move it away or write elsewhere",
            scene_file.display()
        )));
    }
    if scene_file.exists() && !force {
        return Err(err(format!("{} already holds a scene; pass force=True to overwrite it", folder.display())));
    }
    if !force && std::fs::read_dir(&folder).is_ok_and(|mut d| d.next().is_some()) {
        return Err(err(format!(
            "{} is not empty; write the scene into a new or empty folder, or pass force=True",
            folder.display()
        )));
    }
    if let Some(path) = &settings.phantom.volume_path {
        guard(|| {
            fluidnerf_pipeline::synthetic::refuse_truth_among_outputs(path, &folder, "phantom.volume_path")
                .map_err(|e| err(e.to_string()))
        })?;
    }
    // Ctrl-C stops the synthesis between images (before anything is written): the images of a
    // large rig take minutes, and the GIL is released meanwhile.
    let mut signals = Callback::new(None);
    let scene = py.allow_threads(|| {
        guard(|| {
            let started = std::time::Instant::now();
            let syn = fluidnerf_synth::generate(&settings, volume, |_| signals.check_signals());
            if let Some(e) = signals.error.take() {
                return Err(e);
            }
            let syn = syn.map_err(|e| err(e.to_string()))?;
            let seconds = started.elapsed().as_secs_f64();
            let io = |e: fluidnerf_io::IoError| err(e.to_string());
            fluidnerf_pipeline::synthetic::write_synthesis(&syn, &folder).map_err(io)?;
            // The records follow the scene's files, as `fluidnerf synth` writes them. When they
            // cannot be written (a full disk), the scene file goes again: a folder synth failed
            // to finish must not load as a scene.
            if let Err(e) = fluidnerf_pipeline::synthetic::write_records(&syn, &folder, Some(preset), seconds) {
                let scene_file = folder.join(fluidnerf_io::scene::SCENE_FILE);
                let _ = std::fs::remove_file(&scene_file);
                return Err(err(format!(
                    "{e}; the scene in {} is unfinished, and its {} was removed",
                    folder.display(),
                    fluidnerf_io::scene::SCENE_FILE
                )));
            }
            fluidnerf_io::scene::load_scene(&folder).map_err(io)
        })
    })?;
    Ok(PyScene { inner: scene, images: None, saved: true })
}

/// Merges `patch` into `base` key by key (objects recursively; anything else replaces). An
/// object that changes the value of a string key of `base` (the tag of a settings variant such
/// as `"model": "pinhole"`) replaces the object whole, since the other variant has other keys.
fn merge(base: &mut serde_json::Value, patch: serde_json::Value) {
    let retagged = match (&*base, &patch) {
        (serde_json::Value::Object(b), serde_json::Value::Object(p)) => {
            p.iter().any(|(k, v)| v.is_string() && b.get(k).is_some_and(|old| old.is_string() && old != v))
        }
        _ => false,
    };
    match (base, patch) {
        (slot, v) if retagged => *slot = v,
        (serde_json::Value::Object(b), serde_json::Value::Object(p)) => {
            for (k, v) in p {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}
