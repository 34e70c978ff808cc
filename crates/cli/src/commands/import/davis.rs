//! A DaVis recording as `--images`: a folder of `.im7`/`.imx` files (`B00001.im7`, …), one per
//! recorded instant, each holding a frame of every camera (two of each in a double-frame
//! recording). Each file is split into the cameras' images at import.
//!
//! Calibrated cameras are matched to DaVis cameras by number: DaVis names frame k of a file
//! in its attribute `CameraName<k>` (`1A: Imager Intense …` is camera 1, exposure A); without
//! such names frame k is camera k + 1. A calibrated camera's number is the one its name ends
//! with (`cam1`, `Camera_2`, `3`), leading zeros ignored. Matching by number, not by the order
//! of a calibration file, keeps a renamed or reordered calibration from swapping images.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use fluidnerf_core::{Camera, Frame};
use fluidnerf_io::davis::{read_davis, DavisFile, FrameLabel};
use fluidnerf_io::image::SampleKind;
use serde::Serialize;

/// How the frames of a recording's files map to calibrated cameras.
pub(super) struct Recording {
    /// The files in name order: file n is instant n (n·E + e for exposure e of E).
    pub files: Vec<PathBuf>,
    /// For each frame of a file: the index of its frame in the scene's frames of file 0 (the
    /// frames of file n follow at `n · per_file + index`), or None for a DaVis camera left out.
    slots: Vec<Option<usize>>,
    /// The labels of a file's frames, which every file must repeat.
    labels: Vec<FrameLabel>,
    /// What `import.json` records.
    pub record: Vec<CameraRecord>,
}

/// Which DaVis camera a calibrated camera took its images from, for `import.json`.
#[derive(Serialize, Clone)]
pub(super) struct CameraRecord {
    pub camera: String,
    pub davis_camera: u32,
    /// The exposures' letters of a multi-frame recording, in the order of their instants.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub exposures: Vec<char>,
}

/// The number a camera's name ends with: `cam01` is 1; None when it ends with no digit.
fn trailing_number(name: &str) -> Option<u32> {
    let digits = name.len() - name.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    name[name.len() - digits..].parse().ok()
}

/// The recording in `images`, when it is one: it holds DaVis files and no calibrated camera
/// has an entry of its own there (`NAME.*` or a folder `NAME/`). Returns the frames (their
/// `file_path` the DaVis file until [`split`] writes the cameras' images) and the files used.
pub(super) fn recording(
    cameras: &[(String, Camera)],
    images: &Path,
    entries: &[PathBuf],
    skip_uncalibrated: bool,
) -> anyhow::Result<Option<(Recording, Vec<Frame>)>> {
    let files: Vec<PathBuf> =
        entries.iter().filter(|p| p.is_file() && fluidnerf_io::davis::is_davis_path(p)).cloned().collect();
    let own_entry =
        |name: &str| images.join(name).is_dir() || entries.iter().any(|p| p.file_stem().is_some_and(|s| s == name));
    if files.is_empty() || cameras.iter().any(|(name, _)| own_entry(name)) {
        return Ok(None);
    }
    let first = read_davis(&files[0]).context("reading the DaVis recording's first file")?;
    let labels = labels_of(&first, &files[0])?;
    let mut sorted = labels.clone();
    sorted.sort();
    if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
        bail!("{}: two frames of the DaVis recording are both camera {}", files[0].display(), w[0]);
    }
    // The exposures of each DaVis camera, which must be the same letters for all.
    let mut by_camera: BTreeMap<u32, Vec<Option<char>>> = BTreeMap::new();
    for l in &labels {
        by_camera.entry(l.camera).or_default().push(l.exposure);
    }
    let mut exposures: Vec<Option<char>> = by_camera.values().next().cloned().unwrap_or_default();
    exposures.sort();
    for (camera, own) in &by_camera {
        let mut own = own.clone();
        own.sort();
        if own != exposures {
            bail!(
                "{}: the DaVis cameras recorded different exposures (camera {} {}, camera {camera} {}); fluidnerf \
                 needs every camera at every instant",
                files[0].display(),
                by_camera.keys().next().copied().unwrap_or(0),
                letters(&exposures),
                letters(&own)
            );
        }
    }
    let davis_list = by_camera.keys().map(u32::to_string).collect::<Vec<_>>().join(", ");
    let mut numbers: BTreeMap<u32, &str> = BTreeMap::new();
    for (name, _) in cameras {
        let Some(number) = trailing_number(name) else {
            bail!(
                "{} is a DaVis recording (each file holds the frames of DaVis cameras {davis_list}), matched to \
                 calibrated cameras by number, but camera `{name}` has no number at the end of its name: name \
                 the calibrated cameras by their DaVis numbers (cam1, cam2, …)",
                images.display()
            );
        };
        if let Some(other) = numbers.insert(number, name) {
            bail!("calibrated cameras `{other}` and `{name}` both end with the number {number}, so both would be DaVis camera {number}");
        }
        if !by_camera.contains_key(&number) {
            bail!(
                "calibrated camera `{name}` is DaVis camera {number} by its name, but the files of {} hold DaVis \
                 cameras {davis_list} only",
                images.display()
            );
        }
    }
    let left_out: Vec<String> =
        by_camera.keys().filter(|c| !numbers.contains_key(c)).map(|c| format!("camera {c}")).collect();
    if !left_out.is_empty() {
        if !skip_uncalibrated {
            bail!(
                "no calibrated camera for DaVis {} of the recording in {} (calibrated cameras are matched by the \
                 number their name ends with; pass --skip-uncalibrated to leave them out)",
                left_out.join(", "),
                images.display()
            );
        }
        log::warn!("left out DaVis {} of the recording: no calibrated camera", left_out.join(", "));
    }
    // Frames: per calibrated camera, per file, per exposure; `slots` places file 0's.
    let per_file = cameras.len() * exposures.len();
    let single = files.len() == 1 && exposures.len() == 1;
    let mut frames = Vec::with_capacity(per_file * files.len());
    let mut record = Vec::new();
    for n in 0..files.len() {
        for (name, camera) in cameras {
            for e in 0..exposures.len() {
                let time = n * exposures.len() + e;
                frames.push(Frame {
                    camera: camera.clone(),
                    file_path: files[n].clone(),
                    time: (!single).then_some(time as f64),
                    camera_name: Some(name.clone()),
                    holdout: false,
                });
            }
        }
    }
    let slots = labels
        .iter()
        .map(|l| {
            let c = cameras.iter().position(|(name, _)| trailing_number(name) == Some(l.camera))?;
            let e = exposures.iter().position(|&x| x == l.exposure)?;
            Some(c * exposures.len() + e)
        })
        .collect();
    for (name, _) in cameras {
        let number = trailing_number(name).unwrap_or_default();
        record.push(CameraRecord {
            camera: name.clone(),
            davis_camera: number,
            exposures: exposures.iter().flatten().copied().collect(),
        });
    }
    log::info!(
        "{}: a DaVis recording of {} file(s), {} frame(s) each; {}",
        images.display(),
        files.len(),
        labels.len(),
        cameras
            .iter()
            .map(|(name, _)| format!("{name} is DaVis camera {}", trailing_number(name).unwrap_or_default()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    if exposures.len() > 1 {
        log::warn!(
            "a multi-frame DaVis recording: exposures {} of each file become consecutive instants (file n's \
             exposure e is instant {}·n + e); edit the times in transforms.json if they are physical",
            letters(&exposures),
            exposures.len()
        );
    }
    Ok(Some((Recording { files, slots, labels, record }, frames)))
}

fn letters(exposures: &[Option<char>]) -> String {
    exposures.iter().map(|e| e.map_or_else(|| "-".to_owned(), String::from)).collect::<Vec<_>>().join("/")
}

/// The cameras and exposures of `file`'s frames ([`DavisFile::frame_labels`]), refused when
/// some frames name their camera and others do not.
fn labels_of(davis: &DavisFile, file: &Path) -> anyhow::Result<Vec<FrameLabel>> {
    davis.frame_labels().map_err(|k| {
        anyhow::anyhow!(
            "{}: frame {k} of the DaVis recording names no camera (its attribute CameraName{k} is missing or not \
             like `1A: …`) while others do, so its camera is unknown",
            file.display()
        )
    })
}

/// Writes every camera's frame of every file of `recording` into `staging/frames/<camera>/`,
/// as the file's stem (plus the exposure's letter) `.png` (16-bit counts, exact) or, for float
/// pixels, `.tif`, and points `frames` at them; they go to `out/frames/<camera>/` when the
/// import is committed, where a file of the same name is replaced only with `force`. Returns
/// the files' paths in `out` (`frames/<camera>/<name>`), for `import.json`: a later import
/// into `out` removes those it does not write again.
pub(super) fn split(
    recording: &Recording,
    frames: &mut [Frame],
    out: &Path,
    staging: &Path,
    force: bool,
) -> anyhow::Result<Vec<String>> {
    let mut written = Vec::with_capacity(frames.len());
    let per_file = frames.len() / recording.files.len();
    let mut warned_scale = false;
    for (n, file) in recording.files.iter().enumerate() {
        let davis = read_davis(file).context("reading the DaVis recording")?;
        let labels = labels_of(&davis, file)?;
        if labels != recording.labels {
            bail!(
                "{}: its frames are DaVis cameras {}, those of {} are {}: every file of a recording must hold the \
                 same cameras",
                file.display(),
                labels.iter().map(FrameLabel::to_string).collect::<Vec<_>>().join(", "),
                recording.files[0].display(),
                recording.labels.iter().map(FrameLabel::to_string).collect::<Vec<_>>().join(", ")
            );
        }
        if let Some((factor, offset, unit)) = davis.intensity_scale().filter(|s| (s.0, s.1) != (1.0, 0.0)) {
            if !warned_scale {
                log::warn!(
                    "{}: DaVis shows its pixels as {factor} × stored + {offset} {unit}; fluidnerf reads the stored \
                     counts (scale with --intensity-scale if needed)",
                    file.display()
                );
                warned_scale = true;
            }
        }
        let stem = file.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        for ((image, label), slot) in davis.frames.iter().zip(&labels).zip(&recording.slots) {
            let Some(slot) = slot else { continue };
            let frame = &mut frames[n * per_file + slot];
            let camera = frame.camera_name.clone().unwrap_or_default();
            if let Some(problem) = super::decoded_size_problem(&frame.camera, image.width, image.height) {
                bail!("camera {camera}: {}: its frame of DaVis camera {label} is {problem}", file.display());
            }
            let dir = staging.join("frames").join(&camera);
            std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
            let exposure = label.exposure.map(String::from).unwrap_or_default();
            let ext = if davis.kind == SampleKind::Float { "tif" } else { "png" };
            let name = format!("{stem}{exposure}.{ext}");
            let target = out.join("frames").join(&camera).join(&name);
            if target.exists() && !force {
                bail!("{} exists (from an earlier import); pass --force to overwrite it", target.display());
            }
            let path = dir.join(&name);
            if davis.kind == SampleKind::Float {
                fluidnerf_io::image::write_tiff_f32(&path, image)?;
            } else {
                fluidnerf_io::image::write_png16_counts(&path, image)?;
            }
            frame.file_path = path;
            written.push(format!("frames/{camera}/{name}"));
        }
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_numbers_end_names() {
        assert_eq!(trailing_number("cam1"), Some(1));
        assert_eq!(trailing_number("Camera_02"), Some(2));
        assert_eq!(trailing_number("3"), Some(3));
        assert_eq!(trailing_number("left"), None);
        assert_eq!(trailing_number(""), None);
    }
}
