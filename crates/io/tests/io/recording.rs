//! The preprocessing keys of a scene file (`background`, `flat_field`, `mask_path`, `flow_axis`): read,
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
                flat_field: Vec::new(),
                mask_path: Some("masks/c0.png".into()),
            },
            FrameRecording { background: Background::Constant(60.0), flat_field: Vec::new(), mask_path: None },
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

/// The scene of [`scene`] with flat fields: camera 0 has `flat/c0.png`, camera 1 the top
/// level's `flat/top.png`; no backgrounds or masks unless a test sets them.
fn flat_scene(dir: &Path, c0: &Image, top: &Image) -> (Scene, Recording) {
    let (scene, mut recording) = scene(dir);
    write_png16_counts(&dir.join("flat/c0.png"), c0).expect("write");
    write_png16_counts(&dir.join("flat/top.png"), top).expect("write");
    for f in &mut recording.frames {
        *f = FrameRecording::default();
    }
    recording.frames[0].flat_field = vec!["flat/c0.png".into()];
    recording.frames[1].flat_field = vec!["flat/top.png".into()];
    (scene, recording)
}

/// Writes `recording` and reads the scene's images back as a run does.
fn preprocess(dir: &Path, scene: &Scene, recording: &Recording) -> Result<fluidnerf_io::scene::Preprocessed, String> {
    save_scene_recording(scene, dir, recording, false).expect("save");
    let loaded = load_scene(dir).map_err(|e| e.to_string())?;
    load_preprocessed(&loaded).map_err(|e| e.to_string())
}

/// The ramp 0.5 … 1.5 across the columns (mean 1).
fn ramp(col: usize) -> f32 {
    0.5 + col as f32 / (W - 1) as f32
}

#[test]
fn a_uniform_flat_changes_nothing_and_a_ramped_one_corrects_a_ramped_image_exactly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    // A flat of all 2s is 1 everywhere once normalised: the images stay as they are.
    let (scene, recording) = flat_scene(d, &image(|_| 2.0), &image(|_| 2.0));
    let pre = preprocess(d, &scene, &recording).expect("uniform flats");
    for i in 0..W * H {
        assert_eq!(pre.images[0].data[i], 100.0 + i as f32, "pixel {i}");
        assert_eq!(pre.images[1].data[i], 50.0);
    }
    assert_eq!(pre.flat_range, Some((1.0, 1.0)));
    let text = pre.recording.describe();
    assert!(text.contains("flat field: one flat frame (2 frames)"), "{text}");

    // Camera 0 sees a uniform 400 through a sensitivity ramp, over a background of 20 counts;
    // its flat is the same ramp times 1000 over the same background. (raw − 20) / F is the
    // uniform 400 again: the ramp's mean is 1, so the scale is kept.
    let flat = image(|i| 1000.0 * ramp(i % W) + 20.0);
    let (scene, mut recording) = flat_scene(d, &flat, &image(|_| 2.0));
    write_png16_counts(&d.join("images/c0.png"), &image(|i| 400.0 * ramp(i % W) + 20.0)).expect("write");
    recording.frames[0].background = Background::Constant(20.0);
    let pre = preprocess(d, &scene, &recording).expect("ramped flat");
    for (i, v) in pre.images[0].data.iter().enumerate() {
        assert!((v - 400.0).abs() < 1e-3, "pixel {i}: {v}");
    }
    let (lo, hi) = pre.flat_range.expect("flat fields");
    assert!((lo - 0.5).abs() < 1e-6 && (hi - 1.5).abs() < 1e-6, "{lo} .. {hi}");
    // Without the flat the ramp stays in the image.
    recording.frames[0].flat_field.clear();
    let pre = preprocess(d, &scene, &recording).expect("no flat");
    assert_eq!(pre.images[0].data[0], 200.0);

    // The flat's dark level is the frame's background: the median of its background frames
    // is subtracted from the flat as from the image. Background frames of 20 and 40 + a
    // column ramp (median: their mean), the flat 1000 × ramp over the same background.
    let dark = |i: usize| 30.0 + 10.0 * (i % W) as f32;
    write_png16_counts(&d.join("bg/a.png"), &image(|i| dark(i) - 10.0)).expect("write");
    write_png16_counts(&d.join("bg/b.png"), &image(|i| dark(i) + 10.0)).expect("write");
    write_png16_counts(&d.join("images/c0.png"), &image(|i| 400.0 * ramp(i % W) + dark(i))).expect("write");
    write_png16_counts(&d.join("flat/c0.png"), &image(|i| 1000.0 * ramp(i % W) + dark(i))).expect("write");
    recording.frames[0].background = Background::Frames(vec!["bg/a.png".into(), "bg/b.png".into()]);
    recording.frames[0].flat_field = vec!["flat/c0.png".into()];
    let pre = preprocess(d, &scene, &recording).expect("flat with background frames");
    assert!(pre.images[0].data.iter().all(|v| (v - 400.0).abs() < 1e-3), "{:?}", pre.images[0].data);

    // With a mask, the flat averages 1 over the pixels the mask uses: the first row is left
    // out, and it holds a dark flat (too little light to divide by) that is then not refused.
    let mut masked = image(|i| 1000.0 * ramp(i % W) + dark(i));
    (0..W).for_each(|c| masked.data[c] = dark(c));
    write_png16_counts(&d.join("flat/c0.png"), &masked).expect("write");
    recording.frames[0].mask_path = Some("masks/c0.png".into());
    let pre = preprocess(d, &scene, &recording).expect("masked flat");
    assert!(pre.images[0].data[W..].iter().all(|v| (v - 400.0).abs() < 1e-3), "{:?}", pre.images[0].data);
    // Left out by the mask and too dark to divide by: left as it is after the background.
    assert!((pre.images[0].data[0] - 200.0).abs() < 1e-3, "{}", pre.images[0].data[0]);
}

#[test]
fn several_flat_frames_give_their_median_and_the_keys_round_trip() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (scene, mut recording) = flat_scene(d, &image(|_| 2.0), &image(|_| 2.0));
    // Three flats of camera 0: two say the ramp, one (a dust speck passing) says 50 at pixel 7:
    // the median keeps the ramp.
    for k in 0..3 {
        let mut f = image(|i| 1000.0 * ramp(i % W));
        if k == 1 {
            f.data[7] = 50.0;
        }
        write_png16_counts(&d.join(format!("flat/c0_{k}.png")), &f).expect("write");
    }
    write_png16_counts(&d.join("images/c0.png"), &image(|i| 300.0 * ramp(i % W))).expect("write");
    recording.frames[0].flat_field = (0..3).map(|k| format!("flat/c0_{k}.png").into()).collect();
    let pre = preprocess(d, &scene, &recording).expect("median flat");
    assert!(pre.images[0].data.iter().all(|v| (v - 300.0).abs() < 1e-3), "{:?}", pre.images[0].data);
    assert!(pre.recording.describe().contains("median of 3 flat frames (1 frames), one flat frame (1 frames)"));
    let read = recorded(&load_scene(d).expect("load")).expect("recorded");
    assert_eq!(read.frames, recording.frames);

    // A top-level key (one path alone) is every frame's, and a frame's own key wins.
    let file = d.join("transforms.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("read")).expect("json");
    v["flat_field"] = serde_json::json!("flat/top.png");
    v["frames"][1].as_object_mut().expect("frame").remove("flat_field");
    std::fs::write(&file, v.to_string()).expect("write");
    let read = recorded(&load_scene(d).expect("load")).expect("recorded");
    assert_eq!(read.frames[0].flat_field.len(), 3);
    assert_eq!(read.frames[1].flat_field, vec![std::path::PathBuf::from("flat/top.png")]);
}

/// Every bad flat field is refused naming the file, the frame (and its key) and the problem.
#[test]
fn bad_flat_fields_are_refused_naming_the_file_frame_and_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (scene, recording) = flat_scene(d, &image(|_| 2.0), &image(|_| 2.0));
    let refused = |recording: &Recording| preprocess(d, &scene, recording).expect_err("must be refused");
    let with_flat = |flat: &str| {
        let mut r = recording.clone();
        r.frames[0].flat_field = vec![flat.into()];
        r
    };

    // Another size than the frame's image.
    write_png16_counts(&d.join("flat/small.png"), &Image::zeros(3, 3)).expect("write");
    let e = refused(&with_flat("flat/small.png"));
    assert!(e.contains("small.png") && e.contains("3x3") && e.contains("frame 0") && e.contains("6x4"), "{e}");

    // A missing (or unreadable) file.
    let e = refused(&with_flat("flat/none.png"));
    assert!(e.contains("frame 0 (images/c0.png, camera c0): `flat_field` image") && e.contains("none.png"), "{e}");
    std::fs::write(d.join("flat/garbage.png"), b"not a png").expect("write");
    let e = refused(&with_flat("flat/garbage.png"));
    assert!(e.contains("`flat_field`") && e.contains("garbage.png"), "{e}");

    // Pixels at or below 5 % of the mean once the background is subtracted: counted, the
    // first named and the box that holds them; zeros the same.
    let mut dim = image(|_| 1000.0);
    dim.data[W + 2] = 60.0; // 40 above the background of 20: 4 % of the mean.
    dim.data[2 * W + 4] = 20.0; // nothing above it
    write_png16_counts(&d.join("flat/dim.png"), &dim).expect("write");
    let mut r = with_flat("flat/dim.png");
    r.frames[0].background = Background::Constant(20.0);
    let e = refused(&r);
    for want in [
        "transforms.json",
        "frame 0 (images/c0.png, camera c0), `flat_field`: the flat-field image flat/dim.png",
        "has 2 of its 24 used pixel(s) at or below 5 % of its mean (900) once",
        "the first at (col 2, row 1) with 40",
        "cols 2..=4, rows 1..=2",
        "mask_path",
    ] {
        assert!(e.contains(want), "{want:?} in {e}");
    }
    // A flat no brighter than the background holds no light.
    write_png16_counts(&d.join("flat/dark.png"), &image(|_| 15.0)).expect("write");
    let mut r = with_flat("flat/dark.png");
    r.frames[0].background = Background::Constant(20.0);
    let e = refused(&r);
    assert!(e.contains("flat/dark.png") && e.contains("holds no light"), "{e}");

    // Non-finite and negative pixels (a float flat: taken without a background, which would
    // put the flat on the images' scale).
    let mut nan = image(|_| 1.0);
    nan.data[5] = f32::NAN;
    fluidnerf_io::image::write_tiff_f32(&d.join("flat/nan.tif"), &nan).expect("write");
    let e = refused(&with_flat("flat/nan.tif"));
    assert!(e.contains("nan.tif") && e.contains("col 5, row 0") && e.contains("NaN"), "{e}");
    fluidnerf_io::image::write_tiff_f32(&d.join("flat/float.tif"), &image(|i| 0.5 * ramp(i % W))).expect("write");
    write_png16_counts(&d.join("images/c0.png"), &image(|i| 300.0 * ramp(i % W))).expect("write");
    let pre = preprocess(d, &scene, &with_flat("flat/float.tif")).expect("a float flat without a background");
    assert!(pre.images[0].data.iter().all(|v| (v - 300.0).abs() < 1e-3), "{:?}", pre.images[0].data);
    let mut r = with_flat("flat/float.tif");
    r.frames[0].background = Background::Constant(1.0);
    let e = refused(&r);
    assert!(e.contains("float.tif") && e.contains("not on one scale"), "{e}");

    // The frame's own image, also written another way, and the frame's background images.
    let e = refused(&with_flat("images/../images/c0.png"));
    assert!(e.contains("frames[0].flat_field") && e.contains("the frame's own image"), "{e}");
    let e = refused(&with_flat("./images//c0.png"));
    assert!(e.contains("frames[0].flat_field") && e.contains("the frame's own image"), "{e}");
    let abs = d.canonicalize().expect("canonical").join("images/c0.png");
    let e = refused(&with_flat(abs.to_str().expect("utf-8")));
    assert!(e.contains("frame 0") && e.contains("`flat_field`") && e.contains("the frame's own image"), "{e}");
    write_png16_counts(&d.join("bg/c0.png"), &image(|_| 10.0)).expect("write");
    let mut r = with_flat("bg/c0.png");
    r.frames[0].background = Background::Frames(vec!["bg/c0.png".into()]);
    let e = refused(&r);
    assert!(e.contains("frame 0") && e.contains("names the frame's background images"), "{e}");

    // Malformed keys in the file: an empty list, a blank path, a number; the top level's
    // key naming a frame's image.
    save_scene_recording(&scene, d, &recording, false).expect("save");
    let file = d.join("transforms.json");
    let good: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("read")).expect("json");
    let load = |v: &serde_json::Value| {
        std::fs::write(&file, v.to_string()).expect("write");
        load_scene(d).expect_err("must be refused").to_string()
    };
    let mut v = good.clone();
    v["frames"][1]["flat_field"] = serde_json::json!([]);
    let e = load(&v);
    assert!(e.contains("frame 1 (images/c1.png), key `frames[1].flat_field`: is an empty list"), "{e}");
    v["frames"][1]["flat_field"] = serde_json::json!(["flat/top.png", " "]);
    let e = load(&v);
    assert!(e.contains("`frames[1].flat_field`: entry 1 is \" \", which names no image"), "{e}");
    v["frames"][1]["flat_field"] = serde_json::json!(2.0);
    let e = load(&v);
    assert!(e.contains("frames[1].flat_field") && e.contains("an image's path or a list of images' paths"), "{e}");
    let mut v = good.clone();
    v["flat_field"] = serde_json::json!([]);
    let e = load(&v);
    assert!(e.contains("top level, key `flat_field`: is an empty list"), "{e}");
    v["flat_field"] = serde_json::json!("images/c1.png");
    v["frames"][1].as_object_mut().expect("frame").remove("flat_field");
    let e = load(&v);
    assert!(e.contains("frame 1 (images/c1.png), key `flat_field` (top level): names images/c1.png"), "{e}");

    // A background or a mask that is the frame's own image (the frame was subtracted to black
    // and passed), and a blank background path (read as the scene's folder, and blamed on
    // frame 0 although the key was the top level's).
    let mut v = good.clone();
    v["frames"][1]["background"] = serde_json::json!("./images/c1.png");
    let e = load(&v);
    assert!(
        e.contains("frame 1 (images/c1.png), key `frames[1].background`: names ./images/c1.png, the frame's own"),
        "{e}"
    );
    let mut v = good.clone();
    v["background"] = serde_json::json!(["bg/c0.png", "images/c1.png"]);
    let e = load(&v);
    assert!(e.contains("frame 1 (images/c1.png), key `background` (top level): names images/c1.png"), "{e}");
    let mut v = good.clone();
    v["frames"][1]["mask_path"] = serde_json::json!("images/c1.png");
    let e = load(&v);
    assert!(e.contains("key `frames[1].mask_path`: names images/c1.png, the frame's own image"), "{e}");
    let mut v = good.clone();
    v["background"] = serde_json::json!("");
    let e = load(&v);
    assert!(e.contains("top level: `background` names \"\", which is no image"), "{e}");
}
