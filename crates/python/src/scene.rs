//! `Scene`: a calibrated recording, loaded from a folder or built from NumPy arrays.
//!
//! Conventions (those of `fluidnerf-core`): intrinsics `K` with pixel centres at integer
//! coordinates (OpenCV), poses `world_from_camera` (camera to world, 4 × 4) with OpenCV camera
//! axes (x right, y down, z forward), distortion in OpenCV order `(k1, k2, p1, p2, k3, k4, k5,
//! k6)`, images `(N, H, W)` float32 linear values, the box `[[xmin, ymin, zmin], [xmax, ymax,
//! zmax]]` in world units.

use std::path::{Path, PathBuf};

use fluidnerf_core::glam::{DAffine3, DMat3, DVec3};
use fluidnerf_core::{Aabb, Camera, Distortion, Frame, Image, Intrinsics, TruthRef};
use fluidnerf_io::scene::Recording;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::prelude::*;

use crate::{err, guard};

/// A calibrated recording: frames (camera, image, time), a reconstruction box, and optional
/// ground truth. `root` is the folder it lives in, or None for a scene built from arrays and
/// not saved yet.
#[pyclass(module = "fluidnerf._fluidnerf", name = "Scene")]
#[derive(Clone)]
pub struct PyScene {
    pub inner: fluidnerf_core::Scene,
    /// Images held in memory (scenes built from arrays); None: read from the files.
    pub images: Option<Vec<Image>>,
    /// The scene is on disk at `inner.root`.
    pub saved: bool,
}

/// The files `synth` and `import` write beside a scene file: their settings, and `synth`'s
/// preview picture. They describe the scene they were written with.
const SCENE_RECORDS: [&str; 3] = ["synth.json", "import.json", "preview.png"];

/// Writes the files of `scene` (saved into `folder`) into `stage`: its images, masks, truth and
/// transforms.json. Returns the files other than transforms.json, relative to the folder.
fn write_staged(
    stage: &Path,
    scene: &fluidnerf_core::Scene,
    recording: &Recording,
    images: &[Image],
    masks: &[Option<Vec<bool>>],
    truth: &[(Option<f64>, fluidnerf_core::Volume)],
) -> Result<Vec<PathBuf>, fluidnerf_io::IoError> {
    std::fs::create_dir_all(stage).map_err(|e| fluidnerf_io::IoError::io(stage, "folder", e))?;
    let mut files = Vec::new();
    for ((frame, image), (rec, keep)) in scene.frames.iter().zip(images).zip(recording.frames.iter().zip(masks)) {
        fluidnerf_io::image::write_tiff_f32(&stage.join(&frame.file_path), image)?;
        files.push(frame.file_path.clone());
        if let (Some(path), Some(keep)) = (&rec.mask_path, keep) {
            let mask =
                Image::from_vec(image.width, image.height, keep.iter().map(|&k| f32::from(u8::from(k))).collect());
            fluidnerf_io::image::write_png16(&stage.join(path), &mask, 1.0)?;
            files.push(path.clone());
        }
    }
    for (entry, (_, volume)) in scene.truth.iter().zip(truth) {
        fluidnerf_io::volume::write_npy(&stage.join(&entry.file_path), volume)?;
        files.push(entry.file_path.clone());
    }
    fluidnerf_io::scene::save_scene_recording(scene, stage, recording, false)?;
    Ok(files)
}

/// Moves the files written into `stage` into `folder`, transforms.json last. An earlier scene's
/// transforms.json goes first, so that a move that fails leaves no scene naming images of two.
///
/// With `drop_records`, the records written with the scene the folder held ([`SCENE_RECORDS`])
/// are removed with its scene file.
fn install_staged(
    stage: &Path,
    folder: &Path,
    files: &[PathBuf],
    drop_records: bool,
) -> Result<(), fluidnerf_io::IoError> {
    let scene_file = Path::new(fluidnerf_io::scene::SCENE_FILE);
    let earlier = folder.join(scene_file);
    if earlier.exists() {
        std::fs::remove_file(&earlier).map_err(|e| fluidnerf_io::IoError::io(&earlier, "earlier scene file", e))?;
    }
    for record in SCENE_RECORDS.iter().filter(|_| drop_records).map(|name| folder.join(name)) {
        if record.is_file() {
            std::fs::remove_file(&record)
                .map_err(|e| fluidnerf_io::IoError::io(&record, "record of the earlier scene", e))?;
        }
    }
    for rel in files.iter().map(PathBuf::as_path).chain([scene_file]) {
        let to = folder.join(rel);
        if let Some(dir) = to.parent() {
            std::fs::create_dir_all(dir).map_err(|e| fluidnerf_io::IoError::io(dir, "folder", e))?;
        }
        std::fs::rename(stage.join(rel), &to).map_err(|e| fluidnerf_io::IoError::io(&to, "scene file", e))?;
    }
    Ok(())
}

impl PyScene {
    /// The scene, for a run that records its folder: an error for a scene that has none, or
    /// whose folder no longer holds it. A run reads the folder's images and records the folder
    /// in its config.json, which a rerun reads: a scene edited on disk after it was loaded
    /// made a run of the old box and cameras that named the new ones, unnoticed.
    pub fn require_saved(&self, what: &str) -> PyResult<&fluidnerf_core::Scene> {
        if !self.saved {
            return Err(err(format!("{what} needs a scene on disk: call scene.save(folder) first")));
        }
        let root = &self.inner.root;
        let now = fluidnerf_io::scene::load_scene(root).map_err(|e| {
            err(format!("{what}: the scene's folder {} no longer reads as this scene: {e}", root.display()))
        })?;
        if now != self.inner {
            return Err(err(format!(
                "{what}: the scene in {} has changed on disk since this Scene was loaded (its box, cameras, frames \
                 or truth differ); load it again with fluidnerf.load_scene",
                root.display()
            )));
        }
        Ok(&self.inner)
    }

    /// Every frame's image, in frame order.
    pub fn images_vec(&self) -> PyResult<Vec<Image>> {
        match &self.images {
            Some(v) => Ok(v.clone()),
            None => fluidnerf_io::scene::load_images(&self.inner).map_err(|e| err(e.to_string())),
        }
    }

    pub fn cameras(&self) -> Vec<Camera> {
        self.inner.frames.iter().map(|f| f.camera.clone()).collect()
    }

    /// Writes the scene into `folder` (see `save`) and returns it as read back from there.
    fn save_into(self, folder: &Path, force: bool) -> PyResult<fluidnerf_core::Scene> {
        // Never among a run's (or an export's, ...) files, as `synth` and `import` refuse.
        use fluidnerf_pipeline::rundir::{refuse_other_kind, FolderKind};
        refuse_other_kind(folder, FolderKind::Scene, "Scene.save").map_err(|e| err(e.to_string()))?;
        let file = fluidnerf_io::scene::scene_file_path(folder);
        // Even with force=True it could not be written, and would fail as "Is a directory".
        if file.is_dir() {
            return Err(err(format!(
                "{}: is a folder, where the scene file goes; move it away or save elsewhere",
                file.display()
            )));
        }
        if file.exists() && !force {
            return Err(err(format!("{} already holds a scene; pass force=True to overwrite it", folder.display())));
        }
        // As `synth` refuses: the images, masks and truth written have fixed names
        // (images/frame_0000.tiff, ...), which would replace a user's files of those names.
        if !force && std::fs::read_dir(folder).is_ok_and(|mut d| d.next().is_some()) {
            return Err(err(format!(
                "{} is not empty; save the scene into a new or empty folder, or pass force=True",
                folder.display()
            )));
        }
        // The images as preprocessed (linear, background subtracted, flat-field corrected);
        // their masks and the flow axis go with them, or the copy would use the pixels its
        // recording left out.
        let (images, masks, flow_axis) = match self.images {
            Some(images) => {
                let none = vec![None; images.len()];
                (images, none, None)
            }
            None => {
                let p = fluidnerf_io::scene::load_preprocessed(&self.inner).map_err(|e| err(e.to_string()))?;
                (p.images, p.masks, p.recording.flow_axis)
            }
        };
        // A scene read from a file keeps its truth, saved or not (one from arrays has none).
        let truth = fluidnerf_io::scene::load_truth(&self.inner).map_err(|e| err(e.to_string()))?;
        // The records of a scene replaced by another describe a scene no longer there (a
        // synth.json naming a phantom and truth of another scene, which `fluidnerf study` took
        // for its cell's scene): they go with it. A scene saved over its own folder keeps them.
        let own_folder = self.saved
            && std::fs::canonicalize(&self.inner.root)
                .ok()
                .is_some_and(|root| std::fs::canonicalize(folder).is_ok_and(|f| f == root));
        let drop_records = file.exists() && !own_folder;
        let mut scene = self.inner;
        scene.root = folder.to_path_buf();
        let mut recording = Recording { flow_axis, ..Recording::plain(scene.frames.len()) };
        for (i, frame) in scene.frames.iter_mut().enumerate() {
            frame.file_path = PathBuf::from(format!("images/frame_{i:04}.tiff"));
            if masks[i].is_some() {
                recording.frames[i].mask_path = Some(PathBuf::from(format!("masks/frame_{i:04}.png")));
            }
        }
        scene.truth = (0..truth.len())
            .map(|k| TruthRef { time: truth[k].0, file_path: PathBuf::from(format!("truth/truth_{k:02}.npy")) })
            .collect();
        // Written into a folder of its own inside `folder` and moved into place when whole,
        // transforms.json last (as Run.save copies beside its destination): a save that failed
        // part way (a full disk) left a half-written folder, which a second attempt refused
        // as not empty, and over an earlier scene that scene's transforms.json naming the
        // images written before the failure.
        let made: Vec<PathBuf> = std::path::absolute(folder)
            .map_err(|e| err(format!("{}: {e}", folder.display())))?
            .ancestors()
            .take_while(|p| !p.exists())
            .map(Path::to_path_buf)
            .collect();
        let stage = folder.join(format!(".fluidnerf-save-{}", std::process::id()));
        let written = write_staged(&stage, &scene, &recording, &images, &masks, &truth)
            .and_then(|files| install_staged(&stage, folder, &files, drop_records));
        // The staged files left (all of them after a failure), and what a failed save created.
        let _ = std::fs::remove_dir_all(&stage);
        if let Err(e) = written {
            if let Some((own, parents)) = made.split_first() {
                let _ = std::fs::remove_dir_all(own);
                parents.iter().for_each(|p| drop(std::fs::remove_dir(p)));
            }
            return Err(err(format!("{}: cannot save the scene there: {e}", folder.display())));
        }
        fluidnerf_io::scene::load_scene(folder).map_err(|e| err(e.to_string()))
    }
}

pub fn aabb_from(a: &PyReadonlyArray2<'_, f64>) -> PyResult<Aabb> {
    let v = a.as_array();
    if v.shape() != [2, 3] {
        return Err(err(format!(
            "aabb: expected shape (2, 3) [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {:?}",
            v.shape()
        )));
    }
    // Not `Aabb::new`, which asserts: an inverted box from the caller is an error, not a panic.
    let aabb =
        Aabb { min: DVec3::new(v[[0, 0]], v[[0, 1]], v[[0, 2]]), max: DVec3::new(v[[1, 0]], v[[1, 1]], v[[1, 2]]) };
    aabb.validate().map_err(|e| err(format!("aabb: {e}")))?;
    Ok(aabb)
}

fn aabb_array<'py>(py: Python<'py>, aabb: &Aabb) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let v = vec![aabb.min.x, aabb.min.y, aabb.min.z, aabb.max.x, aabb.max.y, aabb.max.z];
    PyArray1::from_vec(py, v).reshape([2, 3])
}

/// A `(rows, cols)` matrix as nested rows.
fn affine_from_rows(m: &[[f64; 4]; 4]) -> DAffine3 {
    DAffine3 {
        matrix3: DMat3::from_cols(
            DVec3::new(m[0][0], m[1][0], m[2][0]),
            DVec3::new(m[0][1], m[1][1], m[2][1]),
            DVec3::new(m[0][2], m[1][2], m[2][2]),
        ),
        translation: DVec3::new(m[0][3], m[1][3], m[2][3]),
    }
}

fn affine_rows(a: &DAffine3) -> [f64; 16] {
    let (m, t) = (a.matrix3, a.translation);
    [
        m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x, m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y, m.x_axis.z, m.y_axis.z,
        m.z_axis.z, t.z, 0.0, 0.0, 0.0, 1.0,
    ]
}

/// The camera arrays of a list of cameras: K `(N, 3, 3)`, world_from_camera `(N, 4, 4)`,
/// distortion `(N, 8)`, sizes `(N, 2)` as (width, height).
pub type CameraArrays<'py> =
    (Bound<'py, PyArray3<f64>>, Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<u32>>);

pub fn camera_arrays<'py>(py: Python<'py>, cameras: &[&Camera]) -> PyResult<CameraArrays<'py>> {
    let n = cameras.len();
    let mut k = Vec::with_capacity(n * 9);
    let mut pose = Vec::with_capacity(n * 16);
    let mut dist = Vec::with_capacity(n * 8);
    let mut sizes = Vec::with_capacity(n * 2);
    for c in cameras {
        k.extend(c.intrinsics.k_rows().iter().flatten());
        pose.extend(affine_rows(&c.world_from_camera));
        let d = c.distortion;
        dist.extend([d.k1, d.k2, d.p1, d.p2, d.k3, d.k4, d.k5, d.k6]);
        sizes.extend([c.intrinsics.width, c.intrinsics.height]);
    }
    Ok((
        PyArray1::from_vec(py, k).reshape([n, 3, 3])?,
        PyArray1::from_vec(py, pose).reshape([n, 4, 4])?,
        PyArray1::from_vec(py, dist).reshape([n, 8])?,
        PyArray1::from_vec(py, sizes).reshape([n, 2])?,
    ))
}

/// Images `(N, H, W)` as one array (all of one size) or a list of `(H, W)` arrays.
pub fn images_to_py(py: Python<'_>, images: Vec<Image>) -> PyResult<PyObject> {
    let same = images.windows(2).all(|w| (w[0].width, w[0].height) == (w[1].width, w[1].height));
    if same && !images.is_empty() {
        let (w, h, n) = (images[0].width, images[0].height, images.len());
        let mut data = Vec::with_capacity(n * w * h);
        for img in images {
            data.extend_from_slice(&img.data);
        }
        return Ok(PyArray1::from_vec(py, data).reshape([n, h, w])?.into_any().unbind());
    }
    let list: Vec<PyObject> = images
        .into_iter()
        .map(|img| Ok(PyArray1::from_vec(py, img.data).reshape([img.height, img.width])?.into_any().unbind()))
        .collect::<PyResult<_>>()?;
    Ok(pyo3::types::PyList::new(py, list)?.into_any().unbind())
}

#[pymethods]
impl PyScene {
    /// Reads the scene in `folder` (a folder holding `transforms.json`, or the file itself)
    /// and validates it.
    #[staticmethod]
    fn load(py: Python<'_>, folder: PathBuf) -> PyResult<Self> {
        py.allow_threads(|| {
            guard(|| {
                let inner = fluidnerf_io::scene::load_scene(&folder).map_err(|e| err(e.to_string()))?;
                Ok(PyScene { inner, images: None, saved: true })
            })
        })
    }

    /// Builds a scene from arrays (see the module docs for conventions). `K` `(N, 3, 3)`,
    /// `world_from_camera` `(N, 4, 4)`, `images` `(N, H, W)`, `aabb` `(2, 3)`, `times` `(N,)`
    /// or None, `distortion` `(N, 4|5|8)` or None, `holdout` `(N,)` bools or None, `names` a
    /// list of N camera names or None.
    #[staticmethod]
    #[pyo3(signature = (k, world_from_camera, images, aabb, times=None, distortion=None, holdout=None, names=None, units="mm".to_string(), intensity_scale=1.0))]
    #[allow(clippy::too_many_arguments)]
    fn from_arrays(
        k: PyReadonlyArray3<'_, f64>,
        world_from_camera: PyReadonlyArray3<'_, f64>,
        images: PyReadonlyArray3<'_, f32>,
        aabb: PyReadonlyArray2<'_, f64>,
        times: Option<PyReadonlyArray1<'_, f64>>,
        distortion: Option<PyReadonlyArray2<'_, f64>>,
        holdout: Option<Vec<bool>>,
        names: Option<Vec<Option<String>>>,
        units: String,
        intensity_scale: f64,
    ) -> PyResult<Self> {
        guard(|| {
            let (k, pose, imgs) = (k.as_array(), world_from_camera.as_array(), images.as_array());
            let n = imgs.shape()[0];
            let (h, w) = (imgs.shape()[1], imgs.shape()[2]);
            if n == 0 {
                return Err(err(format!(
                    "images: a scene needs at least one frame, got an array of shape (0, {h}, {w})"
                )));
            }
            if k.shape() != [n, 3, 3] {
                return Err(err(format!("K: expected shape ({n}, 3, 3) for {n} images, got {:?}", k.shape())));
            }
            if pose.shape() != [n, 4, 4] {
                return Err(err(format!(
                    "world_from_camera: expected shape ({n}, 4, 4) for {n} images, got {:?}",
                    pose.shape()
                )));
            }
            fluidnerf_io::scene::check_units(&units).map_err(|e| err(format!("units: {e}")))?;
            let aabb = aabb_from(&aabb)?;
            let times: Option<Vec<f64>> = times.map(|t| t.as_array().to_vec());
            if let Some(t) = &times {
                if t.len() != n {
                    return Err(err(format!("times: expected {n} values, got {}", t.len())));
                }
                if let Some(i) = t.iter().position(|v| !v.is_finite()) {
                    return Err(err(format!("times: frame {i} has the time {}", t[i])));
                }
            }
            let dist = distortion.map(|d| d.as_array().to_owned());
            if let Some(d) = &dist {
                if d.shape()[0] != n {
                    return Err(err(format!("distortion: expected {n} rows, got {}", d.shape()[0])));
                }
            }
            for (what, len) in [("holdout", holdout.as_ref().map(Vec::len)), ("names", names.as_ref().map(Vec::len))] {
                if let Some(len) = len.filter(|&l| l != n) {
                    return Err(err(format!("{what}: expected {n} entries, got {len}")));
                }
            }
            if !(intensity_scale > 0.0 && intensity_scale.is_finite()) {
                return Err(err(format!(
                    "intensity_scale: must be positive, got {}",
                    fluidnerf_core::num(intensity_scale)
                )));
            }
            let mut frames = Vec::with_capacity(n);
            let mut images_out = Vec::with_capacity(n);
            for i in 0..n {
                let kk = |r: usize, c: usize| k[[i, r, c]];
                if kk(1, 0) != 0.0 || kk(2, 0) != 0.0 || kk(2, 1) != 0.0 || kk(2, 2) != 1.0 {
                    return Err(err(format!("K[{i}]: the last row must be [0, 0, 1] and K[1][0] zero")));
                }
                let intrinsics = Intrinsics {
                    width: w as u32,
                    height: h as u32,
                    fx: kk(0, 0),
                    fy: kk(1, 1),
                    cx: kk(0, 2),
                    cy: kk(1, 2),
                    skew: kk(0, 1),
                };
                let mut rows = [[0.0; 4]; 4];
                for (r, row) in rows.iter_mut().enumerate() {
                    for (c, v) in row.iter_mut().enumerate() {
                        *v = pose[[i, r, c]];
                    }
                }
                if rows[3] != [0.0, 0.0, 0.0, 1.0] {
                    return Err(err(format!("world_from_camera[{i}]: the last row must be [0, 0, 0, 1]")));
                }
                let distortion = match &dist {
                    Some(d) => {
                        Distortion::from_opencv(&d.row(i).to_vec()).map_err(|e| err(format!("distortion[{i}]: {e}")))?
                    }
                    None => Distortion::default(),
                };
                let camera = Camera { intrinsics, distortion, world_from_camera: affine_from_rows(&rows), lens: None };
                camera.validate().map_err(|e| err(format!("camera {i}: {e}")))?;
                let data: Vec<f32> = imgs.index_axis(numpy::ndarray::Axis(0), i).iter().copied().collect();
                let image = Image::from_vec(w, h, data);
                if let Some((c, r)) = image.first_non_finite() {
                    return Err(err(format!("images[{i}]: pixel (row {r}, column {c}) is not finite")));
                }
                if let Some(p) = image.data.iter().position(|&v| v < 0.0) {
                    return Err(err(format!(
                        "images[{i}]: pixel (row {}, column {}) is negative ({}); images are emitted light",
                        p / w,
                        p % w,
                        image.data[p]
                    )));
                }
                // The largest pixel a scene's images may hold (`fluidnerf_io::scene::MAX_PIXEL`):
                // a larger one was accepted here and refused by every run, naming the image file
                // the run had saved into its own folder, which the caller never wrote.
                let max = fluidnerf_io::scene::MAX_PIXEL;
                if let Some(p) = image.data.iter().position(|&v| v > max) {
                    return Err(err(format!(
                        "images[{i}]: pixel (row {}, column {}) is {:e}, above {max:e}, where 32-bit arithmetic \
                         overflows: a corrupt or hot pixel, or values that need rescaling (intensity_scale takes \
                         the units)",
                        p / w,
                        p % w,
                        image.data[p]
                    )));
                }
                images_out.push(image);
                frames.push(Frame {
                    camera,
                    file_path: PathBuf::from(format!("images/frame_{i:04}.tiff")),
                    time: times.as_ref().map(|t| t[i]),
                    camera_name: names.as_ref().and_then(|v| v[i].clone()),
                    holdout: holdout.as_ref().is_some_and(|v| v[i]),
                });
            }
            let inner = fluidnerf_core::Scene {
                root: PathBuf::new(),
                aabb,
                units,
                intensity_scale,
                frames,
                truth: Vec::<TruthRef>::new(),
            };
            // The checks of a scene read from a file (a camera inside the box or blind to it, a
            // camera named twice at one instant, ...): found only when the scene was saved, they
            // named a transforms.json the caller never wrote, and left it half-written.
            fluidnerf_io::scene::validate_scene(&inner, Path::new("scene_from_arrays"))
                .map_err(|e| err(e.to_string()))?;
            Ok(PyScene { inner, images: Some(images_out), saved: false })
        })
    }

    /// Writes the scene into `folder`: `transforms.json` (with the flow axis), every image as a
    /// float32 TIFF under `images/` as it is reconstructed from (linear, background subtracted,
    /// divided by its flat field), the frames' masks under `masks/` and the ground-truth volumes
    /// under `truth/`. Afterwards
    /// the scene lives there. A folder that is not empty is refused without `force`; a scene
    /// saved over another takes its records (`synth.json`, `import.json`, `preview.png`) away.
    /// The files are written with the GIL released (the images and truth of a large scene take
    /// seconds): the scene is read first, and becomes the saved one once it is written.
    #[pyo3(signature = (folder, force=None))]
    fn save(slf: &Bound<'_, Self>, folder: PathBuf, force: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let force = force.map(|f| crate::flag(f, "force")).transpose()?.unwrap_or(false);
        if folder.as_os_str().is_empty() {
            // Refused as "cannot make an empty path absolute", which named no argument.
            return Err(err("folder: the path is empty; name a folder ('.' for the current folder)"));
        }
        let given = slf.borrow().clone();
        let saved = slf.py().allow_threads(|| guard(|| given.save_into(&folder, force)))?;
        // Another thread may be reading the scene with the GIL released (images(), truth()):
        // the files are written, so the scene waits for it rather than fail.
        let mut this = loop {
            match slf.try_borrow_mut() {
                Ok(this) => break this,
                Err(_) => slf.py().allow_threads(|| std::thread::sleep(std::time::Duration::from_millis(1))),
            }
        };
        this.inner = saved;
        this.images = None;
        this.saved = true;
        Ok(())
    }

    /// A copy of the scene, images and all (for `reconstruct`, to put back a scene it saved
    /// into a run folder that was then refused).
    fn _copy(&self) -> PyScene {
        self.clone()
    }

    /// Becomes `other` again (see [`PyScene::_copy`]).
    fn _restore(&mut self, other: PyRef<'_, PyScene>) {
        *self = other.clone();
    }

    /// The folder the scene lives in, or None before it is saved.
    #[getter]
    fn root(&self) -> Option<PathBuf> {
        self.saved.then(|| absolute(&self.inner.root))
    }

    /// The reconstruction box `[[xmin, ymin, zmin], [xmax, ymax, zmax]]`, world units.
    #[getter]
    fn aabb<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        aabb_array(py, &self.inner.aabb)
    }

    #[getter]
    fn units(&self) -> String {
        self.inner.units.clone()
    }

    /// Pixel value = intensity_scale × ∫E ds (world units).
    #[getter]
    fn intensity_scale(&self) -> f64 {
        self.inner.intensity_scale
    }

    fn __len__(&self) -> usize {
        self.inner.frames.len()
    }

    fn __repr__(&self) -> String {
        let times = match self.inner.times().len() {
            0 => "static".to_string(),
            1 => "1 time".to_string(),
            n => format!("{n} times"),
        };
        format!(
            "Scene({} frames, {times}, box {:?}..{:?} {}, {})",
            self.inner.frames.len(),
            self.inner.aabb.min.to_array(),
            self.inner.aabb.max.to_array(),
            self.inner.units,
            if self.saved { format!("in {}", self.inner.root.display()) } else { "in memory".to_string() }
        )
    }

    /// Every frame's time (None for static frames).
    #[getter]
    fn times(&self) -> Vec<Option<f64>> {
        self.inner.frames.iter().map(|f| f.time).collect()
    }

    /// Whether each frame is held out of training.
    #[getter]
    fn holdout(&self) -> Vec<bool> {
        self.inner.frames.iter().map(|f| f.holdout).collect()
    }

    /// Each frame's camera name (None when not given).
    #[getter]
    fn names(&self) -> Vec<Option<String>> {
        self.inner.frames.iter().map(|f| f.camera_name.clone()).collect()
    }

    /// The cameras as arrays: `(K (N, 3, 3), world_from_camera (N, 4, 4), distortion (N, 8),
    /// sizes (N, 2) as (width, height))`.
    fn camera_arrays<'py>(&self, py: Python<'py>) -> PyResult<CameraArrays<'py>> {
        let cams: Vec<&Camera> = self.inner.frames.iter().map(|f| &f.camera).collect();
        camera_arrays(py, &cams)
    }

    /// Every frame's image, linear float32: one `(N, H, W)` array when all have one size,
    /// else a list of `(H, W)` arrays.
    fn images(&self, py: Python<'_>) -> PyResult<PyObject> {
        let images = py.allow_threads(|| guard(|| self.images_vec()))?;
        images_to_py(py, images)
    }

    /// The ground-truth volumes `(time or None, (nz, ny, nx) array)` of a scene on disk.
    fn truth(&self, py: Python<'_>) -> PyResult<Vec<(Option<f64>, PyObject)>> {
        if self.inner.truth.is_empty() {
            return Ok(Vec::new());
        }
        let truth = py
            .allow_threads(|| guard(|| fluidnerf_io::scene::load_truth(&self.inner).map_err(|e| err(e.to_string()))))?;
        truth.into_iter().map(|(t, v)| Ok((t, crate::volume_to_py(py, v)?.into_any().unbind()))).collect()
    }
}

fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

/// Reads a `transforms.json` written by any NeRF tool (or its folder) as a scene, with the
/// box `aabb` `(2, 3)` when the file has none.
#[pyfunction]
#[pyo3(signature = (path, aabb=None))]
pub fn read_transforms(path: PathBuf, aabb: Option<PyReadonlyArray2<'_, f64>>) -> PyResult<PyScene> {
    guard(|| {
        let draft = fluidnerf_io::scene::read_scene_draft(&path).map_err(|e| err(e.to_string()))?;
        let file = draft.file.clone();
        let own = draft.aabb;
        let aabb = match (aabb, own) {
            (Some(a), _) => aabb_from(&a)?,
            (None, Some(a)) => a,
            (None, None) => {
                return Err(err(format!(
                    "{}: no `aabb` in the file; pass aabb=[[xmin, ymin, zmin], [xmax, ymax, zmax]]",
                    file.display()
                )))
            }
        };
        // A truth volume fills the file's box: in another it would stand where the flow is not.
        if let (Some(own), Some(truth)) = (own, draft.truth.first()) {
            if own != aabb {
                return Err(err(format!(
                    "aabb: the truth volume(s) of {} ({}) fill its box {:?}..{:?}; in another box they would stand \
                     in the wrong place: leave aabb out, or remove the truth entries from the file",
                    file.display(),
                    truth.file_path.display(),
                    own.min.to_array(),
                    own.max.to_array()
                )));
            }
        }
        let inner = draft.into_scene(aabb);
        fluidnerf_io::scene::validate_scene(&inner, &file).map_err(|e| err(e.to_string()))?;
        // A box the file does not hold makes a scene of its own, which lives in memory until it
        // is saved (a run saves it into its folder): the file, reloaded, would not be it, and a
        // run's config.json naming the file would not rerun.
        Ok(PyScene { inner, images: None, saved: own == Some(aabb) })
    })
}

/// Named cameras `(name, K, world_from_camera, distortion, (width, height))` of a calibration.
type NamedCamera<'py> = (String, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>, Vec<f64>, (u32, u32));

fn named_cameras<'py>(py: Python<'py>, cams: Vec<(String, Camera)>) -> PyResult<Vec<NamedCamera<'py>>> {
    cams.into_iter()
        .map(|(name, c)| {
            let k: Vec<f64> = c.intrinsics.k_rows().iter().flatten().copied().collect();
            Ok((
                name,
                PyArray1::from_vec(py, k).reshape([3, 3])?,
                PyArray1::from_vec(py, affine_rows(&c.world_from_camera).to_vec()).reshape([4, 4])?,
                c.distortion.to_opencv(),
                (c.intrinsics.width, c.intrinsics.height),
            ))
        })
        .collect()
}

/// The cameras of an OpenCV calibration (`cv::FileStorage` YAML/JSON file or a folder of them).
#[pyfunction]
pub fn read_opencv(py: Python<'_>, path: PathBuf) -> PyResult<Vec<NamedCamera<'_>>> {
    let cams = guard(|| fluidnerf_io::calib::read_opencv(&path).map_err(|e| err(e.to_string())))?;
    named_cameras(py, cams)
}

/// The images of a COLMAP model (text or binary) as cameras, named by image file name.
#[pyfunction]
pub fn read_colmap(py: Python<'_>, folder: PathBuf) -> PyResult<Vec<NamedCamera<'_>>> {
    let cams = guard(|| fluidnerf_io::calib::read_colmap(&folder).map_err(|e| err(e.to_string())))?;
    named_cameras(py, cams)
}

/// The cameras of projection matrices or DLT coefficients (`fluidnerf_io::calib::read_projection`),
/// each for the image size `sizes` gives it by name, else `size`; with `bottom_left_origin`,
/// v counted up from the bottom is turned round first.
#[pyfunction]
#[pyo3(signature = (path, size, sizes, bottom_left_origin))]
pub fn read_projection(
    py: Python<'_>,
    path: PathBuf,
    size: Option<(u32, u32)>,
    sizes: std::collections::BTreeMap<String, (u32, u32)>,
    bottom_left_origin: bool,
) -> PyResult<Vec<NamedCamera<'_>>> {
    let read = guard(|| fluidnerf_io::calib::read_projection(&path).map_err(|e| err(e.to_string())))?;
    if let Some(name) = sizes.keys().find(|k| !read.iter().any(|c| &c.name == *k)) {
        let names: Vec<&str> = read.iter().map(|c| c.name.as_str()).collect();
        return Err(err(format!(
            "image_size names camera `{name}`, which {} does not hold (its cameras: {})",
            path.display(),
            names.join(", ")
        )));
    }
    let mut cameras = Vec::with_capacity(read.len());
    for p in &read {
        let Some((width, height)) = sizes.get(&p.name).copied().or(size) else {
            return Err(err(format!(
                "{}: camera `{}`: a projection matrix holds no image size; give image_size=(width, height), or a \
                 dict with an entry for every camera",
                p.file.display(),
                p.name
            )));
        };
        let cam = p.camera(width, height, bottom_left_origin).map_err(|e| err(e.to_string()))?;
        cameras.push((p.name.clone(), cam));
    }
    named_cameras(py, cameras)
}

/// A DaVis file for Python: frames `(n, height, width)`, each frame's camera and exposure
/// label (`"1A"`, or None), and its attributes in file order.
type DecodedDavis<'py> = (Bound<'py, PyArray3<f32>>, Vec<Option<String>>, Vec<(String, String)>);

/// Every frame of a LaVision DaVis image (`.im7`, `.imx`; `fluidnerf_io::davis`), the counts
/// as stored, row 0 at the top, with each frame's label from its `CameraName<k>` attribute
/// and the file's attributes.
#[pyfunction]
pub fn read_davis(py: Python<'_>, path: PathBuf) -> PyResult<DecodedDavis<'_>> {
    let file = py.allow_threads(|| guard(|| fluidnerf_io::davis::read_davis(&path).map_err(|e| err(e.to_string()))))?;
    let labels = (0..file.frames.len()).map(|k| file.frame_label(k).map(|l| l.to_string())).collect();
    let (n, h, w) = (file.frames.len(), file.height, file.width);
    let mut data = Vec::with_capacity(n * h * w);
    for frame in &file.frames {
        data.extend_from_slice(&frame.data);
    }
    Ok((PyArray1::from_vec(py, data).reshape([n, h, w])?, labels, file.attributes))
}

/// The enabled, aligned cameras of an Agisoft Metashape camera export, named by label, as
/// `import --metashape` reads them. Cameras the file has not aligned are refused, named,
/// unless `skip_unaligned`; disabled cameras are left out.
#[pyfunction]
#[pyo3(signature = (path, skip_unaligned = false))]
pub fn read_metashape(py: Python<'_>, path: PathBuf, skip_unaligned: bool) -> PyResult<Vec<NamedCamera<'_>>> {
    let read = guard(|| fluidnerf_io::calib::read_metashape(&path).map_err(|e| err(e.to_string())))?;
    if !read.unaligned.is_empty() && !skip_unaligned {
        return Err(err(format!(
            "{}: {} camera(s) have no pose (not aligned in Metashape): {}; align them, disable them, or pass \
             skip_unaligned=True to leave them out",
            path.display(),
            read.unaligned.len(),
            read.unaligned.join(", ")
        )));
    }
    named_cameras(py, read.cameras)
}

/// A decoded recording for Python: frames `(n, height, width)`, times, how it was read (JSON).
type DecodedVideo<'py> = (Bound<'py, PyArray3<f32>>, Bound<'py, PyArray1<f64>>, String);

/// The frames of a camera's recording (`fluidnerf_io::video`: MJPEG AVI, Phantom cine and
/// Photron MRAW directly, other formats through ffmpeg), as `import` decodes them: the frames
/// kept (`start`, `end`, every `every`-th) as an array `(n, height, width)` of float32, their
/// times in seconds (plus `time_offset`), and how the file was read as JSON text.
#[pyfunction]
#[pyo3(signature = (path, start, end, every, time_offset, range, linearisation))]
#[allow(clippy::too_many_arguments)]
pub fn read_video<'py>(
    py: Python<'py>,
    path: PathBuf,
    start: usize,
    end: Option<usize>,
    every: usize,
    time_offset: f64,
    range: &str,
    linearisation: &str,
) -> PyResult<DecodedVideo<'py>> {
    let range: fluidnerf_io::video::VideoRange = range.parse().map_err(|e: String| err(format!("range: {e}")))?;
    let asked_linearisation = linearisation;
    let linearisation: fluidnerf_io::image::Linearisation =
        linearisation.parse().map_err(|e: String| err(format!("linearisation: {e}")))?;
    let opts =
        fluidnerf_io::video::VideoOptions { range, start, end, every, time_offset_s: time_offset, linearisation };
    // A cine's or MRAW's frames are the sensor's linear counts, read as they are: a range or a
    // linearisation asked of them would be ignored, and the frames returned as if it had been
    // applied. Refused before any frame is decoded.
    if fluidnerf_io::video::is_raw_recording(&path) {
        let what = |asked: &str| {
            format!(
                "{asked} does not apply to {}, a raw recording of the sensor's linear counts, which are read as they \
                 are: leave it out",
                path.display()
            )
        };
        if opts.range == fluidnerf_io::video::VideoRange::Limited {
            return Err(err(format!("range: {}", what("the limited range"))));
        }
        if opts.linearisation != fluidnerf_io::image::Linearisation::Linear {
            return Err(err(format!("linearisation: {}", what(&format!("`{asked_linearisation}`")))));
        }
    }
    // The frames go straight into the array's buffer as they are decoded: one copy of the
    // recording in memory, not a list of frames and then the array.
    let (mut data, mut times) = (Vec::<f32>::new(), Vec::<f64>::new());
    let mut size = None;
    let info = py.allow_threads(|| {
        guard(|| {
            fluidnerf_io::video::read_video_frames(&path, &opts, |frame| {
                let (w, h) = *size.get_or_insert((frame.image.width, frame.image.height));
                if (frame.image.width, frame.image.height) != (w, h) {
                    return Err(fluidnerf_io::IoError::invalid(
                        &path,
                        format!(
                            "frame {} is {}×{} pixels, not {w}×{h}",
                            frame.index, frame.image.width, frame.image.height
                        ),
                    ));
                }
                data.extend_from_slice(&frame.image.data);
                times.push(frame.time_s);
                Ok(())
            })
            .map_err(|e| err(e.to_string()))
        })
    })?;
    let (w, h) = size.unwrap_or((info.width as usize, info.height as usize));
    let n = times.len();
    let info = serde_json::to_string(&info).map_err(|e| err(e.to_string()))?;
    Ok((PyArray1::from_vec(py, data).reshape([n, h, w])?, PyArray1::from_vec(py, times), info))
}
