//! `transforms.json` as nerfstudio, instant-ngp and the Blender/NeRF-synthetic exporters write
//! it. Each camera read is checked against a projection computed by hand with that tool's
//! documented convention: OpenGL camera axes (x right, y up, looking along −z),
//! `fl = w / (2 tan(camera_angle_x / 2))`, pixel centres at `index + ½`.

use std::path::Path;

use fluidnerf_core::glam::{DMat3, DVec2, DVec3};
use fluidnerf_core::Camera;
use fluidnerf_io::scene::{load_scene, read_scene_draft};
use fluidnerf_io::IoError;
use serde_json::{json, Value};

/// An OpenGL camera-to-world matrix (rows) for a camera at `eye` looking at `target`, with
/// world `up` showing up in the image: columns right, up, back (−forward), eye.
fn c2w_gl(eye: DVec3, target: DVec3, up: DVec3) -> (DMat3, [[f64; 4]; 4]) {
    let f = (target - eye).normalize();
    let right = f.cross(up).normalize();
    let cam_up = right.cross(f);
    let r = DMat3::from_cols(right, cam_up, -f);
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        m[i] = [right[i], cam_up[i], -f[i], eye[i]];
    }
    m[3][3] = 1.0;
    (r, m)
}

/// The documented projection: camera coordinates `R_glᵀ (p − eye)`, then
/// `x = fx · X / (−Z) + cx`, `y = −fy · Y / (−Z) + cy` with the principal point measured from the
/// image corner, then −½ for fluidnerf's pixel centres at integers.
fn project_gl(r: DMat3, eye: DVec3, f: (f64, f64), c: (f64, f64), p: DVec3) -> DVec2 {
    let q = r.transpose() * (p - eye);
    DVec2::new(f.0 * q.x / -q.z + c.0 - 0.5, -f.1 * q.y / -q.z + c.1 - 0.5)
}

fn assert_projects_like(cam: &Camera, r: DMat3, eye: DVec3, f: (f64, f64), c: (f64, f64)) {
    for p in [DVec3::ZERO, DVec3::new(0.3, -0.2, 0.1), DVec3::new(-0.4, 0.25, -0.3)] {
        let ours = cam.project(p).expect("in front");
        let theirs = project_gl(r, eye, f, c, p);
        assert!((ours - theirs).length() < 1e-9, "{p}: ours {ours}, by hand {theirs}");
    }
}

fn write(dir: &Path, v: &Value) {
    std::fs::write(dir.join("transforms.json"), serde_json::to_string_pretty(v).expect("json")).expect("writes");
}

/// Blender/NeRF-synthetic: only `camera_angle_x`, no size (read from the image), `file_path`
/// without extension, a per-frame `rotation` key.
#[test]
fn blender_nerf_synthetic_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let angle: f64 = 0.6911112070083618;
    let eyes = [DVec3::new(0.0, -4.0, 1.0), DVec3::new(3.5, 1.0, -1.5)];
    let mut frames = Vec::new();
    for (i, eye) in eyes.iter().enumerate() {
        let (_, m) = c2w_gl(*eye, DVec3::ZERO, DVec3::Z);
        frames.push(json!({"file_path": format!("./train/r_{i}"), "rotation": 0.0125, "transform_matrix": m}));
        std::fs::create_dir_all(d.join("train")).expect("mkdir");
        image::RgbaImage::from_pixel(40, 30, image::Rgba([10, 20, 30, 255]))
            .save(d.join(format!("train/r_{i}.png")))
            .expect("saves");
    }
    write(d, &json!({"camera_angle_x": angle, "frames": frames, "aabb": [[-1, -1, -1], [1, 1, 1]]}));
    let scene = load_scene(d).expect("loads");
    let focal = 0.5 * 40.0 / (0.5 * angle).tan();
    for (i, eye) in eyes.iter().enumerate() {
        let f = &scene.frames[i];
        assert_eq!(f.file_path, Path::new(&format!("./train/r_{i}.png")), "matched by stem");
        assert_eq!((f.camera.intrinsics.width, f.camera.intrinsics.height), (40, 30), "size from the image");
        let (r, _) = c2w_gl(*eye, DVec3::ZERO, DVec3::Z);
        assert_projects_like(&f.camera, r, *eye, (focal, focal), (20.0, 15.0));
    }
}

/// instant-ngp: float `w`/`h`, `camera_angle_y`, per-frame intrinsics, `aabb_scale` and
/// `sharpness`, and no `aabb`.
#[test]
fn instant_ngp_file_without_a_box() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let eye0 = DVec3::new(0.2, -3.0, 0.5);
    let eye1 = DVec3::new(-3.0, 0.4, 0.3);
    let (r0, m0) = c2w_gl(eye0, DVec3::ZERO, DVec3::Z);
    let (r1, m1) = c2w_gl(eye1, DVec3::ZERO, DVec3::Z);
    let (ax, ay): (f64, f64) = (0.9, 0.7);
    write(
        d,
        &json!({
            "camera_angle_x": ax, "camera_angle_y": ay, "w": 64.0, "h": 48.0, "cx": 31.0, "cy": 25.5,
            "aabb_scale": 16, "k1": 0.0, "p1": 0.0,
            "frames": [
                {"file_path": "images/0001.jpg", "sharpness": 31.2, "transform_matrix": m0},
                {"file_path": "images/0002.jpg", "sharpness": 28.0, "transform_matrix": m1,
                 "fl_x": 70.0, "fl_y": 71.0, "w": 64, "h": 48}
            ]
        }),
    );
    let m = load_scene(d).expect_err("no box").to_string();
    assert!(m.contains("transforms.json") && m.contains("no `aabb`") && m.contains("--aabb"), "{m}");
    assert!(m.contains("fluidnerf import --transforms"), "{m}");

    let draft = read_scene_draft(d).expect("reads without a box");
    assert_eq!(draft.aabb, None);
    let fx = 32.0 / (0.5 * ax).tan();
    let fy = 24.0 / (0.5 * ay).tan();
    assert_projects_like(&draft.frames[0].camera, r0, eye0, (fx, fy), (31.0, 25.5));
    assert_projects_like(&draft.frames[1].camera, r1, eye1, (70.0, 71.0), (31.0, 25.5));
}

fn scene_error(d: &Path, v: &Value) -> IoError {
    write(d, v);
    load_scene(d).expect_err("must fail")
}

fn good(m: [[f64; 4]; 4]) -> Value {
    json!({
        "fl_x": 50.0, "fl_y": 50.0, "w": 32, "h": 24, "aabb": [[-1, -1, -1], [1, 1, 1]],
        "frames": [{"file_path": "a.png", "transform_matrix": m}, {"file_path": "b.png", "transform_matrix": m}]
    })
}

/// Errors name the key path and the frame, say in words what was expected, and never repeat
/// their cause.
#[test]
fn errors_name_the_key_and_the_frame() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (_, m) = c2w_gl(DVec3::new(0.0, -5.0, 0.0), DVec3::ZERO, DVec3::Z);
    let mut checked = Vec::new();
    let mut check = |v: Value, needles: &[&str]| {
        let e = scene_error(d, &v);
        let text = e.to_string();
        for n in needles {
            assert!(text.contains(n), "{n:?} missing from: {text}");
        }
        assert!(std::error::Error::source(&e).is_none(), "the cause is in the message, not repeated: {text}");
        checked.push(text);
    };

    let mut v = good(m);
    v["frames"][1]["transform_matrix"] = json!("identity");
    check(v, &["transforms.json", "frame 1 (b.png)", "`frames[1].transform_matrix`", "invalid type: string"]);

    let mut v = good(m);
    v["frames"][0]["transform_matrix"][2] = json!([0.0, 1.0, 0.0]);
    check(v, &["frame 0 (a.png)", "`frames[0].transform_matrix[2]`", "4"]);

    let mut v = good(m);
    v["frames"][1]["fl_x"] = json!("50");
    check(v, &["frame 1 (b.png)", "`frames[1].fl_x`"]);

    let mut v = good(m);
    v["w"] = json!(605.5);
    check(v, &["key `w`", "whole number of pixels, got 605.5"]);

    let mut v = good(m);
    v["frames"][1].as_object_mut().expect("object").remove("file_path");
    check(v, &["frame 1", "`frames[1]`", "missing field `file_path`"]);

    let mut v = good(m);
    v["frames"][0] = json!(7);
    check(v, &["frame 0", "expected an object with file_path and transform_matrix, found a number"]);

    check(json!([{"file_path": "a.png"}]), &["expected a JSON object with `frames`", "found an array of 1 element"]);

    let mut v = good(m);
    v["aabb"] = json!([[0, 0], [1, 1, 1]]);
    check(v, &["`aabb[0]`"]);

    let mut v = good(m);
    v["frames"] = json!({"a": 1});
    check(v, &["`frames`", "expected a sequence"]);

    let mut v = good(m);
    v["linearisation"] = json!("log");
    check(v, &["`linearisation`", "use linear, srgb or a positive gamma"]);

    for text in &checked {
        // No "X: X" repetition of any part of the message.
        let parts: Vec<&str> = text.split(": ").collect();
        for w in parts.windows(2) {
            assert_ne!(w[0], w[1], "repeated cause in: {text}");
        }
    }
}

/// `w`/`h` written as floats (`605.0`) read as integers; an angle outside (0, π) is refused.
#[test]
fn float_sizes_and_bad_angles() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (_, m) = c2w_gl(DVec3::new(0.0, -5.0, 0.0), DVec3::ZERO, DVec3::Z);
    let mut v = good(m);
    v["w"] = json!(32.0);
    v["h"] = json!(24.0);
    write(d, &v);
    let scene = load_scene(d).expect("loads");
    assert_eq!(scene.frames[1].camera.intrinsics.width, 32);
    let mut v = good(m);
    v.as_object_mut().expect("object").remove("fl_x");
    v.as_object_mut().expect("object").remove("fl_y");
    v["camera_angle_x"] = json!(4.0);
    let m = scene_error(d, &v).to_string();
    assert!(m.contains("frame 0 (a.png)") && m.contains("camera_angle_x") && m.contains("(0, π)"), "{m}");
}

/// A `transform_matrix` written with four decimals holds a rotation only up to their rounding
/// (orthonormality error about 10⁻⁴), which the camera's check refused: its nearest rotation
/// is taken, and projects within the rounding of the exact camera. A matrix off by more than
/// rounding is still refused.
#[test]
fn rotations_written_with_few_digits_are_taken_to_the_nearest_rotation() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let eye = DVec3::new(3.0, -4.0, 1.5);
    let (r, m) = c2w_gl(eye, DVec3::ZERO, DVec3::Z);
    let rounded = m.map(|row| [0, 1, 2, 3].map(|j| if j < 3 { (row[j] * 1e4).round() / 1e4 } else { row[j] }));
    write(d, &good(rounded));
    let scene = load_scene(d).expect("a rounded rotation loads");
    for f in &scene.frames {
        for p in [DVec3::ZERO, DVec3::new(0.3, -0.2, 0.1), DVec3::new(-0.4, 0.25, -0.3)] {
            let ours = f.camera.project(p).expect("in front");
            let exact = project_gl(r, eye, (50.0, 50.0), (16.0, 12.0), p);
            assert!((ours - exact).length() < 1e-2, "{p}: {ours} against {exact}");
        }
    }
    let mut scaled = m;
    for row in scaled.iter_mut().take(3) {
        row[0] *= 1.01;
    }
    let e = scene_error(d, &good(scaled)).to_string();
    assert!(e.contains("frame 0 (a.png)") && e.contains("not a proper rotation"), "{e}");
}
