//! A synthesised data set written as a scene folder, the same way for every front end (the
//! `fluidnerf synth` command and Python's `synth`): the images, the ground truth and
//! `transforms.json` with the preprocessing the recording needs.
//!
//! - A plain sensor's images are 16-bit PNG counts. When the sensor adds a dark offset, every
//!   frame records it as a constant `background`, so that a reconstruction subtracts it
//!   instead of reading it as light.
//! - A real-like recording's images, background frames and flat-field frames (with
//!   vignetting) are 8-bit sRGB JPEGs; every frame records its camera's background frames and
//!   flat-field frames (`flat_field`), and the scene its sRGB linearisation.
//! - The phantoms with a known flow direction record it (`flow_axis`), so that reports place
//!   the laminar, transition and turbulent thirds where the flow enters and leaves.
//!
//! The caller owns the folder: it checks that nothing is overwritten without being asked, then
//! writes the scene ([`write_synthesis`]) and the records beside it ([`write_records`]:
//! `preview.png` and `synth.json`).

use std::path::{Path, PathBuf};

use fluidnerf_core::{num, Aabb, Scene, Volume};
use fluidnerf_io::image::Linearisation;
use fluidnerf_io::scene::{Background, FrameRecording, Recording};
use fluidnerf_io::IoError;
use fluidnerf_synth::Synthesis;

use crate::PipelineError;

/// The preprocessing `syn`'s images need (module docs), one entry per frame.
pub fn recording(syn: &Synthesis) -> Recording {
    let flow_axis = syn.settings.phantom.kind.flow_direction();
    let background = |camera: usize| match &syn.real {
        Some(_) => Background::Frames(syn.background_paths(camera)),
        None if syn.settings.sensor.dark_offset > 0.0 => Background::Constant(syn.settings.sensor.dark_offset),
        None => Background::None,
    };
    Recording {
        linearisation: if syn.real.is_some() { Linearisation::Srgb } else { Linearisation::Linear },
        frames: syn
            .frames
            .iter()
            .map(|f| FrameRecording {
                background: background(f.camera),
                flat_field: syn.flat_paths(f.camera),
                mask_path: None,
            })
            .collect(),
        flow_axis,
    }
}

/// Refuses the truth volume `truth` (a file the synthesis reads) when it lies among the files a
/// scene written into `folder` writes or replaces: its folders (`images/`, `truth/`, ...) and
/// records. The scene's own truth given back was removed as a file of the earlier scene, or
/// written over in another precision. `option` names it in the message.
pub fn refuse_truth_among_outputs(truth: &Path, folder: &Path, option: &str) -> Result<(), IoError> {
    let Ok(read) = truth.canonicalize() else { return Ok(()) };
    let written =
        ["images", "background", "flat", "truth", fluidnerf_io::scene::SCENE_FILE, "preview.png", "synth.json"];
    match written.iter().filter_map(|n| folder.join(n).canonicalize().ok()).find(|w| read.starts_with(w)) {
        Some(place) => Err(IoError::invalid(
            truth,
            format!(
                "{option}: lies among the files of the scene written into {} ({}), which a new scene replaces; an \
                 input is never overwritten, even when asked to: copy it out of there first",
                folder.display(),
                place.display()
            ),
        )),
        None => Ok(()),
    }
}

/// Writes `syn` into `folder` (created if missing): images, background frames, flat-field
/// frames, truth volumes and `transforms.json`. Returns the scene as written. A synthetic scene already there (one
/// with `synth`'s `synth.json`) is replaced whole: its images, background frames and truth
/// volumes that `syn` has not are removed, so that none of its files stays beside the new ones.
pub fn write_synthesis(syn: &Synthesis, folder: &Path) -> Result<Scene, IoError> {
    let earlier = synthesised_files(folder);
    std::fs::create_dir_all(folder).map_err(|e| IoError::io(folder, "scene folder", e))?;
    // The scene file being replaced goes first: the new images replace its images one by one,
    // and a write that fails part way (a full disk) left it describing a mix of its own images
    // and new ones, which every command read as a valid scene.
    let scene_file = folder.join("transforms.json");
    if scene_file.is_file() {
        std::fs::remove_file(&scene_file).map_err(|e| IoError::io(&scene_file, "scene file", e))?;
    }
    for f in &syn.frames {
        let path = folder.join(syn.image_path(f));
        match &syn.real {
            None => fluidnerf_io::image::write_png16_counts(&path, &f.counts)?,
            Some(r) => fluidnerf_io::image::write_jpeg_srgb(&path, &f.counts, 255.0, r.jpeg_quality)?,
        }
    }
    if let Some(r) = &syn.real {
        for (c, frames) in r.backgrounds.iter().enumerate() {
            for (img, rel) in frames.iter().zip(syn.background_paths(c)) {
                fluidnerf_io::image::write_jpeg_srgb(&folder.join(rel), img, 255.0, r.jpeg_quality)?;
            }
        }
        for (c, frames) in r.flats.iter().enumerate() {
            for (img, rel) in frames.iter().zip(syn.flat_paths(c)) {
                fluidnerf_io::image::write_jpeg_srgb(&folder.join(rel), img, 255.0, r.jpeg_quality)?;
            }
        }
    }
    for (k, (_, vol)) in syn.truth.iter().enumerate() {
        fluidnerf_io::volume::write_npy(&folder.join(syn.truth_path(k)), vol)?;
    }
    let scene = syn.scene(folder.to_path_buf());
    fluidnerf_io::scene::save_scene_recording(
        &scene,
        &folder.join(fluidnerf_io::scene::SCENE_FILE),
        &recording(syn),
        false,
    )?;
    let written: std::collections::HashSet<PathBuf> = syn
        .frames
        .iter()
        .map(|f| syn.image_path(f))
        .chain((0..syn.cameras.len()).flat_map(|c| syn.background_paths(c)))
        .chain((0..syn.cameras.len()).flat_map(|c| syn.flat_paths(c)))
        .chain((0..syn.truth.len()).map(|k| syn.truth_path(k)))
        .collect();
    for stale in earlier.iter().filter(|p| !written.contains(*p)) {
        let path = folder.join(stale);
        if path.is_file() {
            std::fs::remove_file(&path).map_err(|e| IoError::io(&path, "file of the earlier scene", e))?;
        }
    }
    // A folder the new scene has no file in (the background frames of a real-like recording)
    // goes too, when nothing else is left in it.
    for dir in ["images", "background", "flat", "truth"] {
        if earlier.iter().any(|p| p.starts_with(dir)) && !written.iter().any(|p| p.starts_with(dir)) {
            let _ = std::fs::remove_dir(folder.join(dir));
        }
    }
    Ok(scene)
}

/// Writes the records of `syn` beside its scene in `folder` (after [`write_synthesis`]), as
/// every front end writes them: `preview.png`, a central slice of the truth (of the middle
/// time) beside one camera's image of it, and then `synth.json`, how the scene was made: the
/// settings (to make it again from, `synth --config`), the preset they started from (`preset`,
/// None for settings read from a file), the intensity scale and what the counts are, a
/// real-like recording's true camera gains (recorded nowhere else), a CFD phantom's note, the
/// work's statistics and the `seconds` the synthesis took.
pub fn write_records(syn: &Synthesis, folder: &Path, preset: Option<&str>, seconds: f64) -> Result<(), PipelineError> {
    let preview = folder.join("preview.png");
    write_preview(&preview, syn)
        .map_err(|e| PipelineError::file(&preview, format!("cannot write the preview: {e}")))?;
    let settings = &syn.settings;
    let record = serde_json::json!({
        "fluidnerf_version": env!("CARGO_PKG_VERSION"),
        "command": "synth",
        "preset": preset,
        "seed": settings.seed,
        "intensity_scale": syn.intensity_scale,
        "counts": if syn.real.is_some() {
            "linear pixel (srgb-decoded, 0..255) - background ≈ camera_gains[c] × intensity_scale × ∫E ds (mm)"
        } else {
            "counts - sensor.dark_offset ≈ intensity_scale × ∫E ds (mm)"
        },
        "camera_gains": syn.real.as_ref().map(|r| {
            syn.cameras.iter().zip(&r.gains).map(|(c, g)| (c.name.clone(), *g)).collect::<std::collections::BTreeMap<_, _>>()
        }),
        "phantom_note": settings.phantom.kind.cfd_case().map(fluidnerf_synth::phantom::cfd::note),
        "settings": settings,
        "stats": syn.stats,
        "seconds": seconds,
    });
    let path = folder.join("synth.json");
    let text = serde_json::to_string_pretty(&record).map_err(|e| PipelineError::file(&path, e))? + "\n";
    fluidnerf_io::atomic_write(&path, |w| w.write_all(text.as_bytes()))?;
    Ok(())
}

/// Draws `preview.png` of `syn` at `path`: the truth's central z slice at the middle time step,
/// beside the image of the first frame of that time (its counts).
fn write_preview(path: &Path, syn: &Synthesis) -> Result<(), fluidnerf_viz::VizError> {
    use fluidnerf_viz::{slice, write_panel_groups_png, Axis, Panel, PanelGroup, PanelStyle};
    let (time, truth) = &syn.truth[syn.truth.len() / 2];
    let z = Axis::Z.position_at(&truth.aabb, 0.5);
    let mut truth_panel = slice(truth, Axis::Z, z, "mm")?;
    if let Some(t) = time {
        let label = if syn.settings.phantom.kind.cfd_case().is_some() { "step" } else { "t*" };
        truth_panel.title = format!("truth, {}, {label} = {t}", truth_panel.title);
    } else {
        truth_panel.title = format!("truth, {}", truth_panel.title);
    }
    let frame_index = syn.frames.iter().position(|f| f.time == *time).unwrap_or(0);
    let frame = &syn.frames[frame_index];
    let image_panel =
        Panel::from_image(&frame.counts).with_title(format!("{} (counts)", syn.cameras[frame.camera].name));
    let groups = [
        PanelGroup {
            panels: vec![truth_panel],
            style: PanelStyle { colorbar_label: "E".into(), ..Default::default() },
        },
        PanelGroup {
            panels: vec![image_panel],
            style: PanelStyle {
                colormap: fluidnerf_viz::Colormap::Gray,
                colorbar_label: "counts".into(),
                ..Default::default()
            },
        },
    ];
    write_panel_groups_png(path, &groups)
}

/// The images, background frames, flat-field frames and truth volumes that the `transforms.json` of a scene
/// `synth` wrote into `folder` lists, relative to `folder`; none for a folder without one, or
/// whose scene was not synthesised (its images are a user's), and only paths inside the
/// folders `synth` writes.
fn synthesised_files(folder: &Path) -> Vec<PathBuf> {
    let read = |name: &str| -> Option<serde_json::Value> {
        serde_json::from_str(&std::fs::read_to_string(folder.join(name)).ok()?).ok()
    };
    let synthesised =
        read("synth.json").is_some_and(|r| r.get("command").and_then(serde_json::Value::as_str) == Some("synth"));
    let Some(scene) = read(fluidnerf_io::scene::SCENE_FILE).filter(|_| synthesised) else {
        return Vec::new();
    };
    let list = |key: &str| scene.get(key).and_then(serde_json::Value::as_array).cloned().unwrap_or_default();
    let mut paths: Vec<&str> = Vec::new();
    let (frames, truth) = (list("frames"), list("truth"));
    for entry in frames.iter().chain(&truth) {
        paths.extend(entry.get("file_path").and_then(serde_json::Value::as_str));
        for key in ["background", "flat_field"] {
            match entry.get(key) {
                Some(serde_json::Value::String(p)) => paths.push(p),
                Some(serde_json::Value::Array(ps)) => paths.extend(ps.iter().filter_map(serde_json::Value::as_str)),
                _ => {}
            }
        }
    }
    paths
        .into_iter()
        .map(PathBuf::from)
        .filter(|p| {
            let mut parts = p.components();
            matches!(parts.next(), Some(std::path::Component::Normal(d)) if ["images", "background", "flat", "truth"].iter().any(|s| d == *s))
                && parts.all(|c| matches!(c, std::path::Component::Normal(_)))
        })
        .collect()
}

/// The format of a ground-truth volume file by its extension: `"npy"`, `"vti"` or `"tif"`
/// (`.tif` or `.tiff`); any other file is refused.
pub fn truth_volume_format(path: &Path) -> Result<&'static str, PipelineError> {
    match path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase().as_str() {
        "npy" => Ok("npy"),
        "vti" => Ok("vti"),
        "tif" | "tiff" => Ok("tif"),
        _ => Err(PipelineError::file(path, "the ground truth must be a .npy, .vti or .tif volume")),
    }
}

/// Reads a user's volume to image as a synthetic scene's ground truth
/// (`phantom.kind = "volume"`, `phantom.volume_path`): a `.npy` fills `aabb`, a `.vti` and a
/// calibrated TIFF stack hold their own box, an uncalibrated stack fills `aabb`. Refused when a
/// voxel is not finite, when the line integrals through it would overflow 32-bit floats, or
/// when none is positive (every camera would image black). A calibrated
/// stack's box is converted to the scene's length `unit`.
pub fn read_truth_volume(path: &Path, aabb: Aabb, unit: &str) -> Result<Volume, PipelineError> {
    let volume = match truth_volume_format(path)? {
        "npy" => fluidnerf_io::volume::read_npy(path, aabb)?,
        "vti" => fluidnerf_io::volume::read_vti(path)?,
        _ => fluidnerf_io::volume::read_tiff_stack(path, Some(aabb), Some(unit))?,
    };
    if let Some(i) = volume.data.iter().position(|x| !x.is_finite()) {
        let [nx, ny, _] = volume.dims;
        let v = volume.data[i];
        let note = if v.is_infinite() {
            " (float64 values beyond float32's range, about ±3.4e38, read as infinite)"
        } else {
            ""
        };
        return Err(PipelineError::file(
            path,
            format!(
                "voxel (i {}, j {}, k {}) is {v}; the ground truth must be finite{note}",
                i % nx,
                (i / nx) % ny,
                i / (nx * ny)
            ),
        ));
    }
    // Finite values so large that the line integrals overflow make images of infinities, refused
    // only once imaged, as a camera's non-finite pixel that named neither the file nor the cause.
    if let Some(problem) = fluidnerf_core::render::integrals_overflow(&volume, 1.0) {
        return Err(PipelineError::file(path, problem));
    }
    // Every image of a field with no positive value is black: the scene could not be used.
    let top = volume.data.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    if top <= 0.0 {
        return Err(PipelineError::file(
            path,
            format!(
                "no voxel is positive (the largest value is {}): a field of emission with none images as black in \
                 every camera; give a volume whose glowing parts are positive",
                num(top)
            ),
        ));
    }
    // Emission is never negative. A few small negative voxels (a CFD solver's undershoots) do
    // little harm, but they are imaged as the signed field's integrals, which the sensor clips
    // at zero: a volume mostly below zero made black images, refused as cameras that did not
    // see the phantom.
    let negative = volume.data.iter().filter(|&&v| v < 0.0).count();
    if negative > 0 {
        let low = volume.data.iter().copied().fold(f32::INFINITY, f32::min);
        log::warn!(
            "{}: {negative} of the {} voxels are negative (down to {}, the largest value is {}): emission is never \
             negative, and the images integrate the signed field and clip it at zero; clamp the volume at zero if \
             that is not meant",
            path.display(),
            volume.data.len(),
            num(low),
            num(top)
        );
    }
    Ok(volume)
}

#[cfg(test)]
mod tests {
    use fluidnerf_io::scene::{load_preprocessed, load_scene};
    use fluidnerf_synth::generate::no_progress;
    use fluidnerf_synth::{generate, preset};

    use fluidnerf_core::glam::DVec3;

    use super::*;

    fn small(name: &str) -> fluidnerf_synth::SynthSettings {
        let mut s = preset(name).expect("preset");
        s.resolution = 16;
        s.lens.resolution = [24, 24];
        s.rig.layout = fluidnerf_synth::Layout::Ring {
            count: 4,
            arc_deg: 360.0,
            start_deg: 0.0,
            axis: fluidnerf_synth::RingAxis::X,
        };
        s.rig.holdout = vec![];
        s
    }

    /// A truth volume inside the scene's folders or among its records is refused; one beside
    /// them, or in a folder not written yet, is not.
    #[test]
    fn a_truth_volume_among_a_scenes_files_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let folder = dir.path().join("scene");
        let truth = folder.join("truth/truth_t00.npy");
        assert!(refuse_truth_among_outputs(&truth, &folder, "t").is_ok(), "nothing there yet");
        std::fs::create_dir_all(truth.parent().expect("parent")).expect("mkdir");
        std::fs::write(&truth, "v").expect("write");
        let err = refuse_truth_among_outputs(&folder.join("./truth/../truth/truth_t00.npy"), &folder, "t")
            .expect_err("inside truth/")
            .to_string();
        assert!(err.contains("t: lies among the files of the scene"), "{err}");
        std::fs::write(folder.join("mine.npy"), "v").expect("write");
        assert!(refuse_truth_among_outputs(&folder.join("mine.npy"), &folder, "t").is_ok(), "beside them");
    }

    #[test]
    fn a_sensors_dark_offset_is_subtracted_when_the_scene_is_read() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut plain = small("demo");
        let clean = generate(&plain, None, no_progress).expect("generate");
        plain.sensor.dark_offset = 500.0;
        let offset = generate(&plain, None, no_progress).expect("generate");
        // The stored counts carry the offset…
        let (a, b) = (&clean.frames[0].counts, &offset.frames[0].counts);
        assert!(a.data.iter().zip(&b.data).all(|(x, y)| (y - x - 500.0).abs() < 1e-3), "offset in the counts");
        write_synthesis(&offset, dir.path()).expect("write");
        let scene = load_scene(dir.path()).expect("scene");
        assert_eq!(scene.frames.len(), 4);
        // …and reading the scene takes it off again, pixel for pixel.
        let read = load_preprocessed(&scene).expect("preprocessed");
        for (img, f) in read.images.iter().zip(&clean.frames) {
            assert_eq!(img.data, f.counts.data, "counts after the dark offset's subtraction");
        }
        assert_eq!(read.recording.flow_axis, Some(DVec3::X));
    }

    #[test]
    fn a_real_like_recording_keeps_its_background_frames_and_linearisation() {
        let dir = tempfile::tempdir().expect("tempdir");
        let syn = generate(&small("real-like-small"), None, no_progress).expect("generate");
        write_synthesis(&syn, dir.path()).expect("write");
        let read = load_preprocessed(&load_scene(dir.path()).expect("scene")).expect("preprocessed");
        assert_eq!(read.recording.linearisation, Linearisation::Srgb);
        assert!(read.recording.frames.iter().all(|f| matches!(f.background, Background::Frames(_))));
        // The background is subtracted: the dark corners read near zero, not at the
        // background's level (5 % of the brightest pixel).
        let peak = read.images.iter().flat_map(|i| i.data.iter().copied()).fold(0f32, f32::max);
        let corner = read.images[0].get(0, 0);
        assert!(corner < 0.03 * peak, "corner {corner} of peak {peak}");
    }
}
