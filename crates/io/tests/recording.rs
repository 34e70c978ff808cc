//! The preprocessing keys of a scene file (`background`, `mask_path`, `flow_axis`): read,
//! applied by `load_preprocessed`, written back, and refused with the file, frame and key named.

use std::path::Path;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Camera, Frame, Image, Intrinsics, Scene};
use fluidnerf_io::image::{write_png16_counts, Linearisation};
use fluidnerf_io::scene::{
    load_preprocessed, load_scene, recorded, save_scene_recording, Background, FrameRecording, Recording,
};

const W: usize = 6;
const H: usize = 4;

fn image(f: impl Fn(usize) -> f32) -> Image {
    Image::from_vec(W, H, (0..W * H).map(f).collect())
}

/// Two cameras looking at the origin; camera 0 with three background frames and a mask,
/// camera 1 with a constant background; the flow along −y.
fn scene(dir: &Path) -> (Scene, Recording) {
    let k = Intrinsics { width: W as u32, height: H as u32, fx: 8.0, fy: 8.0, cx: 2.5, cy: 1.5, skew: 0.0 };
    let frames: Vec<Frame> = (0..2)
        .map(|c| Frame {
            camera: Camera::look_at(k, DVec3::new(0.0, 0.0, 10.0 + c as f64), DVec3::ZERO, DVec3::Y),
            file_path: format!("images/c{c}.png").into(),
            time: None,
            camera_name: Some(format!("c{c}")),
            holdout: false,
        })
        .collect();
    write_png16_counts(&dir.join("images/c0.png"), &image(|i| 100.0 + i as f32)).expect("write");
    write_png16_counts(&dir.join("images/c1.png"), &image(|_| 50.0)).expect("write");
    // Background frames 10, 30 and 20 + pixel: the median is 20 (+ pixel where it exceeds it).
    for (b, level) in [10.0f32, 30.0, 20.0].into_iter().enumerate() {
        let f = move |i: usize| if b == 2 { level + i as f32 } else { level };
        write_png16_counts(&dir.join(format!("bg/c0_{b}.png")), &image(f)).expect("write");
    }
    // Mask: the first row is not used.
    write_png16_counts(&dir.join("masks/c0.png"), &image(|i| if i < W { 0.0 } else { 255.0 })).expect("write");
    let scene = Scene {
        root: dir.to_path_buf(),
        aabb: Aabb::cube(DVec3::ZERO, 2.0),
        units: "mm".into(),
        intensity_scale: 1.0,
        frames,
        truth: Vec::new(),
    };
    let recording = Recording {
        linearisation: Linearisation::Linear,
        frames: vec![
            FrameRecording {
                background: Background::Frames((0..3).map(|b| format!("bg/c0_{b}.png").into()).collect()),
                mask_path: Some("masks/c0.png".into()),
            },
            FrameRecording { background: Background::Constant(60.0), mask_path: None },
        ],
        flow_axis: Some(DVec3::new(0.0, -2.0, 0.0)),
    };
    (scene, recording)
}

#[test]
fn background_median_clipping_and_masks_are_applied_and_round_trip() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (scene, recording) = scene(dir.path());
    save_scene_recording(&scene, dir.path(), &recording, false).expect("save");
    let loaded = load_scene(dir.path()).expect("load");
    let read = recorded(&loaded).expect("recorded");
    assert_eq!(read.frames, recording.frames);
    assert_eq!(read.flow_axis, Some(DVec3::new(0.0, -1.0, 0.0)), "the flow axis is normalised");
    let pre = load_preprocessed(&loaded).expect("preprocess");
    // Camera 0: (100 + i) − median(10, 30, 20 + i) = 100 + i − 20 − min(i, 10)... the median of
    // {10, 30, 20 + i} is 20 + i while 20 + i ≤ 30, else 30.
    for i in 0..W * H {
        let median = (20.0 + i as f32).min(30.0);
        assert_eq!(pre.images[0].data[i], 100.0 + i as f32 - median, "pixel {i}");
    }
    // Camera 1: 50 − 60 < 0 everywhere: clipped and counted.
    assert!(pre.images[1].data.iter().all(|&v| v == 0.0));
    assert_eq!(pre.clipped, W * H);
    let mask = pre.masks[0].as_ref().expect("mask");
    assert_eq!(mask.iter().filter(|&&k| !k).count(), W);
    assert!(mask[W..].iter().all(|&k| k));
    assert!(pre.masks[1].is_none());
    let text = pre.recording.describe();
    assert!(text.contains("median of 3 background frames (1 frames)") && text.contains("masks: 1"), "{text}");
    // Pixels at the 16-bit full scale are counted as saturated, before any subtraction.
    assert_eq!(pre.saturated, 0);
    let mut bright = image(|i| 100.0 + i as f32);
    bright.data[3] = 65535.0;
    bright.data[7] = 65535.0;
    write_png16_counts(&dir.path().join("images/c0.png"), &bright).expect("write");
    assert_eq!(load_preprocessed(&loaded).expect("preprocess").saturated, 2);
}

#[test]
fn bad_backgrounds_and_masks_name_the_file_frame_and_camera() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (scene, mut recording) = scene(dir.path());
    // A background frame of the wrong size.
    write_png16_counts(&dir.path().join("bg/small.png"), &Image::zeros(3, 3)).expect("write");
    recording.frames[0].background = Background::Frames(vec!["bg/small.png".into()]);
    save_scene_recording(&scene, dir.path(), &recording, false).expect("save");
    let e = load_preprocessed(&load_scene(dir.path()).expect("load")).unwrap_err().to_string();
    assert!(e.contains("small.png") && e.contains("3x3") && e.contains("camera c0"), "{e}");
    // A background frame stored otherwise than the images (floats among 16-bit counts).
    fluidnerf_io::image::write_tiff_f32(&dir.path().join("bg/float.tif"), &image(|_| 20.0)).expect("write");
    recording.frames[0].background = Background::Frames(vec!["bg/float.tif".into()]);
    save_scene_recording(&scene, dir.path(), &recording, false).expect("save");
    let e = load_preprocessed(&load_scene(dir.path()).expect("load")).unwrap_err().to_string();
    assert!(e.contains("float.tif") && e.contains("not on one scale"), "{e}");
    // A missing background frame.
    recording.frames[0].background = Background::Frames(vec!["bg/none.png".into()]);
    save_scene_recording(&scene, dir.path(), &recording, false).expect("save");
    let e = load_preprocessed(&load_scene(dir.path()).expect("load")).unwrap_err().to_string();
    assert!(e.contains("frame 0") && e.contains("camera c0") && e.contains("none.png"), "{e}");
    // A mask that uses no pixel.
    write_png16_counts(&dir.path().join("masks/zero.png"), &image(|_| 0.0)).expect("write");
    recording.frames[0].background = Background::None;
    recording.frames[0].mask_path = Some("masks/zero.png".into());
    save_scene_recording(&scene, dir.path(), &recording, false).expect("save");
    let e = load_preprocessed(&load_scene(dir.path()).expect("load")).unwrap_err().to_string();
    assert!(e.contains("zero.png") && e.contains("all zero"), "{e}");
    // Malformed keys in the file.
    let file = dir.path().join("transforms.json");
    let text = std::fs::read_to_string(&file).expect("read");
    std::fs::write(&file, text.replace("\"mask_path\": \"masks/zero.png\"", "\"background\": []")).expect("write");
    let e = load_scene(dir.path()).unwrap_err().to_string();
    assert!(e.contains("frame 0") && e.contains("`background` is an empty list"), "{e}");
    let text = std::fs::read_to_string(&file).expect("read");
    let v: serde_json::Value = serde_json::from_str(&text).expect("json");
    let mut v = v;
    v["flow_axis"] = serde_json::json!([0, 0, 0]);
    v["frames"][0]["background"] = serde_json::json!(5.0);
    std::fs::write(&file, serde_json::to_string(&v).expect("json")).expect("write");
    let e = load_scene(dir.path()).unwrap_err().to_string();
    assert!(e.contains("flow_axis") && e.contains("non-zero"), "{e}");
    // A negative constant would add light, not remove it.
    v["flow_axis"] = serde_json::json!([0, 1, 0]);
    v["frames"][0]["background"] = serde_json::json!(-100.0);
    std::fs::write(&file, serde_json::to_string(&v).expect("json")).expect("write");
    let e = load_scene(dir.path()).unwrap_err().to_string();
    assert!(e.contains("frame 0") && e.contains("at least 0"), "{e}");
    // One path alone is read as a list of one (here of a missing file) ...
    v["frames"][0]["background"] = serde_json::json!("bg/none.png");
    std::fs::write(&file, serde_json::to_string(&v).expect("json")).expect("write");
    let loaded = load_scene(dir.path()).expect("a path alone is a background");
    let e = load_preprocessed(&loaded).unwrap_err().to_string();
    assert!(e.contains("frame 0") && e.contains("none.png"), "{e}");
    // ... and anything else is told what `background` may be.
    v["frames"][0]["background"] = serde_json::json!(true);
    std::fs::write(&file, serde_json::to_string(&v).expect("json")).expect("write");
    let e = load_scene(dir.path()).unwrap_err().to_string();
    assert!(e.contains("background") && e.contains("an image's path or a list of images' paths"), "{e}");
}
