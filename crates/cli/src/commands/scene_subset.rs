//! A scene of fewer training cameras made from a scene of the user's, for `study --scene
//! --cameras`: how a recording's reconstructions change with the number of cameras. The subset
//! is a scene folder of its own holding only a `transforms.json` (the frames kept, every path
//! in it made absolute, so the images, masks, background and flat-field frames and the truth
//! are read where they are) and `subset.json` (where it came from and what it kept).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use fluidnerf_core::Scene;
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// The record of a subset scene, `subset.json` beside its `transforms.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SubsetRecord {
    /// The scene the subset was made from (its folder).
    pub source: PathBuf,
    /// The source's training frames kept, by index in its `frames`, increasing.
    pub training_frames: Vec<usize>,
    /// The source's held-out frames, all kept.
    pub held_out_frames: Vec<usize>,
}

/// The record's file name in a subset scene's folder.
pub const SUBSET_RECORD: &str = "subset.json";

/// The `count` training frames of `scene` whose viewing lines are furthest apart: from the
/// first training frame on, each next one the frame whose smallest angle to the lines chosen
/// so far is largest (the lowest index among equals). Angles are between lines, not
/// directions (a camera facing another sees the same line integrals mirrored), so four of a
/// ring of cameras over 360° are 45° apart, not 90° with two pairs facing each other. The
/// result is in frame order.
pub fn spread_cameras(scene: &Scene, count: usize) -> Vec<usize> {
    let training: Vec<(usize, fluidnerf_core::glam::DVec3)> =
        scene.training_frames().map(|(i, f)| (i, f.camera.forward().normalize_or_zero())).collect();
    let mut chosen: Vec<usize> = Vec::with_capacity(count);
    let mut nearest = vec![f64::INFINITY; training.len()];
    let mut next = 0;
    while chosen.len() < count.min(training.len()) {
        chosen.push(next);
        let axis = training[next].1;
        for (k, (_, d)) in training.iter().enumerate() {
            let angle = d.dot(axis).abs().min(1.0).acos();
            nearest[k] = nearest[k].min(angle);
        }
        // Never chosen twice; among the rest, strictly larger wins, so among equals (the
        // cameras facing chosen ones, once every line is taken) the first stays.
        nearest[next] = f64::NEG_INFINITY;
        next = (0..training.len()).fold(0, |best, k| if nearest[k] > nearest[best] { k } else { best });
    }
    let mut frames: Vec<usize> = chosen.into_iter().map(|k| training[k].0).collect();
    frames.sort_unstable();
    frames
}

/// Writes into `dir` the scene `source` (its folder, read as `scene`) with only the training
/// frames `training` and every held-out frame, and its `subset.json`.
pub fn write_subset(source: &Path, scene: &Scene, training: &[usize], dir: &Path) -> anyhow::Result<()> {
    let file = fluidnerf_io::scene::scene_file_path(source);
    let text = std::fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    let mut raw: Value = serde_json::from_str(&text).with_context(|| format!("reading {}", file.display()))?;
    let root = &scene.root;
    let Some(object) = raw.as_object_mut() else { bail!("{}: not a JSON object", file.display()) };
    for key in ["background", "flat_field"] {
        if let Some(v) = object.get_mut(key) {
            absolute(v, root);
        }
    }
    if let Some(Value::Array(truth)) = object.get_mut("truth") {
        for entry in truth {
            if let Some(v) = entry.get_mut("file_path") {
                absolute(v, root);
            }
        }
    }
    let held_out: Vec<usize> = scene.holdout_frames().map(|(i, _)| i).collect();
    let Some(Value::Array(frames)) = object.get_mut("frames") else { bail!("{}: holds no frames", file.display()) };
    if frames.len() != scene.frames.len() {
        bail!("{}: lists {} frames, but the scene read {}", file.display(), frames.len(), scene.frames.len());
    }
    let kept: Vec<Value> = std::mem::take(frames)
        .into_iter()
        .enumerate()
        .filter(|(i, _)| training.contains(i) || held_out.contains(i))
        .map(|(_, mut frame)| {
            for key in ["file_path", "mask_path", "background", "flat_field"] {
                if let Some(v) = frame.get_mut(key) {
                    absolute(v, root);
                }
            }
            frame
        })
        .collect();
    *frames = kept;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let record =
        SubsetRecord { source: source.to_path_buf(), training_frames: training.to_vec(), held_out_frames: held_out };
    // The record last: a subset without it is made again.
    let _ = std::fs::remove_file(dir.join(SUBSET_RECORD));
    fluidnerf_pipeline::rundir::write_json(&dir.join("transforms.json"), &raw)?;
    fluidnerf_pipeline::rundir::write_json(&dir.join(SUBSET_RECORD), &record)?;
    Ok(())
}

/// A path value (a string, or a list of them) made absolute against `root`; numbers (a
/// background level) and other values are left as they are.
fn absolute(value: &mut Value, root: &Path) {
    match value {
        Value::String(s) if Path::new(s.as_str()).is_relative() => {
            *s = root.join(s.as_str()).to_string_lossy().into_owned();
        }
        Value::Array(items) => items.iter_mut().for_each(|v| absolute(v, root)),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene of `n` training cameras evenly on a ring over 360° about z, looking at the
    /// origin, and one more held out halfway between the first two.
    fn ring(n: usize) -> Scene {
        use fluidnerf_core::glam::DVec3;
        let intrinsics =
            fluidnerf_core::Intrinsics { width: 8, height: 8, fx: 8.0, fy: 8.0, cx: 4.0, cy: 4.0, skew: 0.0 };
        let frames = (0..=n)
            .map(|i| {
                let step = if i == n { 0.5 } else { i as f64 };
                let a = std::f64::consts::TAU * step / n as f64;
                let centre = DVec3::new(10.0 * a.cos(), 10.0 * a.sin(), 0.0);
                fluidnerf_core::Frame {
                    camera: fluidnerf_core::Camera::look_at(intrinsics, centre, DVec3::ZERO, DVec3::Z),
                    file_path: format!("images/{i}.png").into(),
                    time: None,
                    camera_name: None,
                    holdout: i == n,
                }
            })
            .collect();
        Scene {
            root: PathBuf::from("/scene"),
            aabb: fluidnerf_core::Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0)),
            units: "mm".into(),
            intensity_scale: 1.0,
            frames,
            truth: Vec::new(),
        }
    }

    /// Four of sixteen cameras on a ring over 360° are four distinct lines 45° apart (0°, 45°,
    /// 90°, 135°), not two pairs of cameras facing each other; the held-out camera is never
    /// chosen, and asking for every training camera gives them all.
    #[test]
    fn cameras_are_spread_over_lines_not_directions() {
        let scene = ring(16);
        assert_eq!(spread_cameras(&scene, 4), vec![0, 2, 4, 6]);
        assert_eq!(spread_cameras(&scene, 2), vec![0, 4]);
        // Eight lines, one camera of each facing pair (camera i and i + 8 share a line).
        let eight = spread_cameras(&scene, 8);
        let lines: std::collections::BTreeSet<usize> = eight.iter().map(|i| i % 8).collect();
        assert_eq!((eight.len(), lines.len()), (8, 8), "{eight:?}");
        assert_eq!(spread_cameras(&scene, 16), (0..16).collect::<Vec<_>>());
        assert_eq!(spread_cameras(&scene, 40), (0..16).collect::<Vec<_>>());
    }

    /// The subset keeps the frames asked for and every held-out one, with every path made
    /// absolute against the source's folder (a background level stays a number).
    #[test]
    fn a_subset_keeps_its_frames_and_reads_the_sources_files() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let (source, out) = (tmp.path().join("rec"), tmp.path().join("sub"));
        std::fs::create_dir_all(&source).expect("source");
        let mut scene = ring(3);
        scene.root = source.clone();
        let frames: Vec<Value> = (0..4)
            .map(|i| {
                serde_json::json!({"file_path": format!("images/{i}.png"), "mask_path": format!("masks/{i}.png"),
                    "background": [format!("bg/{i}.png")], "holdout": i == 3})
            })
            .collect();
        let raw = serde_json::json!({"frames": frames, "background": 0.5, "flat_field": "flat.png",
            "truth": [{"file_path": "truth/t.npy"}]});
        std::fs::write(source.join("transforms.json"), raw.to_string()).expect("write");
        write_subset(&source, &scene, &[0, 2], &out).expect("subset");
        let sub: Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).expect("read")).expect("json");
        let at = |p: &str| source.join(p).to_string_lossy().into_owned();
        let kept: Vec<&str> =
            sub["frames"].as_array().expect("frames").iter().map(|f| f["file_path"].as_str().expect("path")).collect();
        assert_eq!(kept, [at("images/0.png"), at("images/2.png"), at("images/3.png")]);
        assert_eq!(sub["frames"][1]["mask_path"].as_str(), Some(at("masks/2.png").as_str()));
        assert_eq!(sub["frames"][1]["background"][0].as_str(), Some(at("bg/2.png").as_str()));
        assert_eq!(sub["frames"][2]["holdout"], true);
        assert_eq!(
            (sub["background"].as_f64(), sub["flat_field"].as_str()),
            (Some(0.5), Some(at("flat.png").as_str()))
        );
        assert_eq!(sub["truth"][0]["file_path"].as_str(), Some(at("truth/t.npy").as_str()));
        let record: SubsetRecord =
            serde_json::from_str(&std::fs::read_to_string(out.join(SUBSET_RECORD)).expect("read")).expect("record");
        assert_eq!(record, SubsetRecord { source, training_frames: vec![0, 2], held_out_frames: vec![3] });
    }
}
