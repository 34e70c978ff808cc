//! OpenCV and COLMAP calibrations: agreement with `cv2.projectPoints` (fixtures recorded by
//! `fixtures/make_opencv_projections.py`), reading files written by `cv::FileStorage`, round
//! trips OpenCV → scene → OpenCV, and a hand-made COLMAP model.

use std::path::{Path, PathBuf};

use fluidnerf_core::glam::{DMat3, DVec2, DVec3};
use fluidnerf_core::{Aabb, Camera, Distortion, Frame, Intrinsics, Scene};
use fluidnerf_io::calib::{read_colmap, read_opencv, rodrigues_to_matrix, world_from_camera_of, write_opencv};
use fluidnerf_io::scene::{load_scene, save_scene};
use serde_json::Value;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

fn cases() -> Vec<Value> {
    let text = std::fs::read_to_string(fixtures().join("opencv_projections.json")).expect("fixture");
    let v: Value = serde_json::from_str(&text).expect("json");
    v["cases"].as_array().expect("cases").clone()
}

fn f64s(v: &Value) -> Vec<f64> {
    let mut out = Vec::new();
    match v {
        Value::Array(a) => a.iter().for_each(|x| out.extend(f64s(x))),
        Value::Number(n) => out.push(n.as_f64().expect("f64")),
        _ => panic!("not numeric: {v}"),
    }
    out
}

fn v3(v: &[f64]) -> DVec3 {
    DVec3::new(v[0], v[1], v[2])
}

/// The camera of a fixture case, built from K, the distortion vector and rvec/tvec.
fn case_camera(c: &Value) -> Camera {
    let k = f64s(&c["camera_matrix"]);
    let intrinsics = Intrinsics {
        width: c["width"].as_u64().expect("w") as u32,
        height: c["height"].as_u64().expect("h") as u32,
        fx: k[0],
        fy: k[4],
        cx: k[2],
        cy: k[5],
        skew: k[1],
    };
    let distortion = Distortion::from_opencv(&f64s(&c["distortion_coefficients"])).expect("distortion");
    let pose = world_from_camera_of(rodrigues_to_matrix(v3(&f64s(&c["rvec"]))), v3(&f64s(&c["tvec"])));
    Camera { intrinsics, distortion, world_from_camera: pose, lens: None }
}

fn worst_projection_error(c: &Value, cam: &Camera) -> f64 {
    let pts = f64s(&c["points_world"]);
    let pix = f64s(&c["pixels"]);
    let mut worst = 0.0f64;
    for (p, uv) in pts.chunks(3).zip(pix.chunks(2)) {
        let ours = cam.project(v3(p)).expect("in front");
        worst = worst.max((ours - DVec2::new(uv[0], uv[1])).length());
    }
    worst
}

#[test]
fn projections_agree_with_cv2_project_points() {
    for c in cases() {
        let cam = case_camera(&c);
        let worst = worst_projection_error(&c, &cam);
        assert!(worst < 1e-3, "case {}: worst error {worst:.2e} px", c["name"]);
        // Our Rodrigues conversion matches cv2.Rodrigues.
        let r = f64s(&c["R"]);
        let ours = rodrigues_to_matrix(v3(&f64s(&c["rvec"])));
        let cv = DMat3::from_cols_array(&[r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]]);
        assert!((ours - cv).to_cols_array().iter().all(|e| e.abs() < 1e-12), "case {}", c["name"]);
    }
}

#[test]
fn reads_files_written_by_cv_file_storage() {
    let cases = cases();
    for ext in ["yml", "json"] {
        let cams = read_opencv(&fixtures().join(format!("opencv_two_cameras.{ext}"))).expect("reads");
        let names: Vec<&str> = cams.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["four", "five"], "{ext}");
        for ((_, cam), c) in cams.iter().zip(&cases[1..3]) {
            let expected = case_camera(c);
            assert_eq!(cam.intrinsics, expected.intrinsics);
            assert_eq!(cam.distortion, expected.distortion);
            assert!(worst_projection_error(c, cam) < 1e-3);
        }
    }
    // One camera, unsuffixed keys, R/T pose: named after the file.
    let cams = read_opencv(&fixtures().join("cam_single.yml")).expect("reads");
    assert_eq!(cams.len(), 1);
    assert_eq!(cams[0].0, "cam_single");
    assert!(worst_projection_error(&cases[3], &cams[0].1) < 1e-3);
}

/// A multi-camera file whose keys spell a camera's suffix in other letter cases reads as the
/// file with one spelling; two cameras whose names differ only in letter case keep their own.
#[test]
fn suffixes_in_another_letter_case_name_the_same_camera() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(fixtures().join("opencv_two_cameras.json")).expect("read");
    let mixed = text.replace("\"rvec_four\"", "\"rvec_Four\"").replace("\"tvec_four\"", "\"TVEC_FOUR\"");
    assert_ne!(mixed, text);
    std::fs::write(dir.path().join("mixed.json"), &mixed).expect("write");
    let read = read_opencv(&dir.path().join("mixed.json")).expect("reads");
    assert_same_cameras(&read, &read_opencv(&fixtures().join("opencv_two_cameras.json")).expect("reads"));
    // With a camera `Four` beside `four` each name takes its own spelling only, so `four`,
    // whose pose is spelled `_FOUR`, has none.
    let twins = text
        .replace("_five\"", "_Four\"")
        .replace("\"rvec_four\"", "\"rvec_FOUR\"")
        .replace("\"tvec_four\"", "\"tvec_FOUR\"");
    std::fs::write(dir.path().join("twins.json"), &twins).expect("write");
    let err = read_opencv(&dir.path().join("twins.json")).expect_err("no pose for four").to_string();
    assert!(err.contains("camera `four`") && err.contains("no pose"), "{err}");
}

#[test]
fn reads_a_folder_of_calibration_files() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::copy(fixtures().join("cam_single.yml"), dir.path().join("cam_single.yml")).expect("copy");
    std::fs::copy(fixtures().join("opencv_two_cameras.json"), dir.path().join("pair.json")).expect("copy");
    std::fs::write(dir.path().join("notes.txt"), "ignored").expect("write");
    let names: Vec<String> = read_opencv(dir.path()).expect("reads").into_iter().map(|(n, _)| n).collect();
    assert_eq!(names, ["cam_single", "four", "five"]);
    // The same camera twice is an error naming it.
    std::fs::copy(fixtures().join("cam_single.yml"), dir.path().join("pair.yml")).expect("copy");
    std::fs::copy(fixtures().join("cam_single.yml"), dir.path().join("z.yml")).expect("copy");
    std::fs::write(
        dir.path().join("z.yml"),
        std::fs::read_to_string(dir.path().join("pair.yml"))
            .expect("read")
            .replace("camera_matrix:", "camera_matrix_four:"),
    )
    .expect("write");
    let err = read_opencv(dir.path()).expect_err("broken").to_string();
    assert!(err.contains("z.yml"), "{err}");
}

fn assert_same_cameras(a: &[(String, Camera)], b: &[(String, Camera)]) {
    assert_eq!(a.len(), b.len());
    for ((na, ca), (nb, cb)) in a.iter().zip(b) {
        assert_eq!(na, nb);
        assert_eq!(ca.intrinsics, cb.intrinsics, "{na}");
        assert_eq!(ca.distortion, cb.distortion, "{na}");
        let (pa, pb) = (ca.camera_from_world(), cb.camera_from_world());
        let dr = (pa.matrix3 - pb.matrix3).to_cols_array().iter().fold(0.0f64, |m, e| m.max(e.abs()));
        let dt = (pa.translation - pb.translation).length() / pa.translation.length().max(1.0);
        assert!(dr < 1e-14 && dt < 1e-14, "{na}: rotation differs by {dr:.1e}, translation by {dt:.1e}");
    }
}

/// OpenCV file → scene (transforms.json, written and read back) → OpenCV file: same cameras,
/// and the files written before and after the trip are identical up to the last bit of the
/// pose (the world ↔ camera inversions round).
#[test]
fn opencv_scene_opencv_round_trip() {
    let dir = tempfile::tempdir().expect("tempdir");
    for ext in ["yml", "json"] {
        let original = read_opencv(&fixtures().join(format!("opencv_two_cameras.{ext}"))).expect("reads");
        let first = dir.path().join(format!("first.{ext}"));
        write_opencv(&first, &original).expect("writes");
        let cams = read_opencv(&first).expect("reads ours");
        assert_same_cameras(&original, &cams);

        // Through a scene. The box: around the recorded points, which every camera sees.
        let pts = f64s(&cases()[1]["points_world"]);
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in pts.chunks(3) {
            lo = lo.min(v3(p));
            hi = hi.max(v3(p));
        }
        let scene = Scene {
            root: dir.path().to_path_buf(),
            aabb: Aabb::new(lo, hi),
            units: "mm".into(),
            intensity_scale: 1.0,
            frames: cams
                .iter()
                .map(|(n, c)| Frame {
                    camera: c.clone(),
                    file_path: format!("{n}.png").into(),
                    time: None,
                    camera_name: Some(n.clone()),
                    holdout: false,
                })
                .collect(),
            truth: vec![],
        };
        let scene_dir = dir.path().join(format!("scene_{ext}"));
        save_scene(&scene, &scene_dir).expect("saves scene");
        let back = load_scene(&scene_dir).expect("loads scene");
        let from_scene: Vec<(String, Camera)> =
            back.frames.iter().map(|f| (f.camera_name.clone().expect("name"), f.camera.clone())).collect();
        assert_same_cameras(&original, &from_scene);
        let second = dir.path().join(format!("second.{ext}"));
        write_opencv(&second, &from_scene).expect("writes");
        let again = read_opencv(&second).expect("reads");
        assert_same_cameras(&original, &again);
        let (t1, t2) = (std::fs::read_to_string(&first).expect("r"), std::fs::read_to_string(&second).expect("r"));
        assert_eq!(t1.lines().count(), t2.lines().count());
        // Everything but the pose is bit-identical text.
        let non_pose = |t: &str| -> Vec<String> {
            t.lines().filter(|l| !l.contains("data") && !l.contains('.')).map(str::to_string).collect()
        };
        assert_eq!(non_pose(&t1), non_pose(&t2));
    }
}

#[test]
fn single_camera_named_after_the_file_uses_plain_keys() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cams = read_opencv(&fixtures().join("cam_single.yml")).expect("reads");
    let out = dir.path().join("cam_single.yml");
    write_opencv(&out, &cams).expect("writes");
    let text = std::fs::read_to_string(&out).expect("read");
    assert!(text.starts_with("%YAML:1.0\n---\n") && text.contains("\ncamera_matrix: !!opencv-matrix\n"), "{text}");
    assert_same_cameras(&cams, &read_opencv(&out).expect("reads"));
    // Under another name the keys get the camera's suffix.
    let out = dir.path().join("rig.yml");
    write_opencv(&out, &cams).expect("writes");
    assert!(std::fs::read_to_string(&out).expect("read").contains("camera_matrix_cam_single:"));
    assert_same_cameras(&cams, &read_opencv(&out).expect("reads"));
}

#[test]
fn opencv_errors_name_the_file_and_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("bad.yml");
    let base = std::fs::read_to_string(fixtures().join("cam_single.yml")).expect("read");
    let check = |text: &str, needles: &[&str]| {
        std::fs::write(&p, text).expect("write");
        let err = read_opencv(&p).expect_err("must fail").to_string();
        assert!(err.contains("bad.yml"), "{err}");
        for n in needles {
            assert!(err.contains(n), "{err} should mention {n}");
        }
    };
    check(&base.replace("image_width: 640\n", ""), &["image_width"]);
    check(
        &base.replace("R:", "Q:").replace("T:", "U:"),
        &["camera `bad`", "no pose", "`rvec` and `tvec` or `R` and `T`"],
    );
    check(&base.replace("rows: 1\n   cols: 8", "rows: 1\n   cols: 7"), &["distortion_coefficients", "1 × 7"]);
    check("camera_matrix: [1, 2\n", &["malformed YAML"]);
}

#[test]
fn colmap_model_centres_and_half_pixel_shift() {
    let cams = read_colmap(&fixtures().join("colmap")).expect("reads");
    let names: Vec<&str> = cams.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["front.png", "side.png", "radial.png"]);
    let front = &cams[0].1;
    assert!((front.centre() - DVec3::new(0.0, 0.0, -10.0)).length() < 1e-12);
    // COLMAP's (37, 14) is our (36.5, 13.5): pixel centres at +0.5 there, at integers here.
    let uv = front.project(DVec3::new(1.0, -2.0, 0.0)).expect("in front");
    assert!((uv - DVec2::new(36.5, 13.5)).length() < 1e-12, "{uv}");
    assert_eq!((front.intrinsics.cx, front.intrinsics.cy), (31.5, 23.5));

    // side.png: the camera centre is −Rᵀt with R = R_y(90°), t = (1, 2, 3).
    let side = &cams[1].1;
    let r = DMat3::from_cols(DVec3::new(0.0, 0.0, -1.0), DVec3::Y, DVec3::X);
    let t = DVec3::new(1.0, 2.0, 3.0);
    let expected = -(r.transpose() * t);
    assert!((expected - DVec3::new(3.0, -2.0, -1.0)).length() < 1e-12);
    assert!((side.centre() - expected).length() < 1e-12, "{}", side.centre());
    assert!((side.camera_from_world().matrix3 - r).to_cols_array().iter().all(|e| e.abs() < 1e-12));

    let radial = &cams[2].1;
    assert_eq!(radial.distortion.k1, -0.1);
    assert_eq!((radial.intrinsics.fx, radial.intrinsics.fy, radial.intrinsics.cx), (60.0, 60.0, 31.0));
}

#[test]
fn colmap_errors_name_the_file_and_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::copy(fixtures().join("colmap/images.txt"), dir.path().join("images.txt")).expect("copy");
    std::fs::write(
        dir.path().join("cameras.txt"),
        "1 PINHOLE 64 48 50 50 32 24\n2 OPENCV_FISHEYE 64 48 1 1 1 1 0 0 0 0\n",
    )
    .expect("write");
    let err = read_colmap(dir.path()).expect_err("fisheye").to_string();
    assert!(err.contains("cameras.txt") && err.contains("line 2") && err.contains("OPENCV_FISHEYE"), "{err}");
    std::fs::write(dir.path().join("cameras.txt"), "1 PINHOLE 64 48 50 50 32 24\n").expect("write");
    let err = read_colmap(dir.path()).expect_err("camera 2 missing").to_string();
    assert!(err.contains("images.txt") && err.contains("radial.png") && err.contains("camera id 2"), "{err}");
    // One image name twice: two poses for one picture.
    let text = std::fs::read_to_string(fixtures().join("colmap/images.txt")).expect("read");
    std::fs::write(dir.path().join("images.txt"), text.replace("side.png", "front.png")).expect("write");
    std::fs::write(dir.path().join("cameras.txt"), "1 PINHOLE 64 48 50 50 32 24\n2 PINHOLE 64 48 50 50 32 24\n")
        .expect("write");
    let err = read_colmap(dir.path()).expect_err("front.png twice").to_string();
    assert!(err.contains("images.txt") && err.contains("front.png is listed twice"), "{err}");
    // One image id twice, under two names: COLMAP's key of an image, so a file of two models
    // pasted together, whose poses were read as one model's.
    std::fs::write(dir.path().join("images.txt"), text.replace("2 0.7071", "1 0.7071")).expect("write");
    let err = read_colmap(dir.path()).expect_err("image id 1 twice").to_string();
    assert!(err.contains("images.txt: line 8: image id 1 appears twice (first on line 5)"), "{err}");
    // A negative or huge size was said not to be an integer.
    std::fs::write(dir.path().join("images.txt"), &text).expect("write");
    for (size, says) in [("-64 48", "width `-64`"), ("64 99999999999", "height `99999999999`")] {
        let line = format!("1 PINHOLE {size} 50 50 32 24\n2 PINHOLE 64 48 50 50 32 24\n");
        std::fs::write(dir.path().join("cameras.txt"), line).expect("write");
        let err = read_colmap(dir.path()).expect_err("bad size").to_string();
        assert!(
            err.contains("cameras.txt: line 1")
                && err.contains(&format!("{says} is not a positive whole number of pixels")),
            "{err}"
        );
    }
    // A huge quaternion was printed with all of its three hundred digits.
    std::fs::write(dir.path().join("cameras.txt"), "1 PINHOLE 64 48 50 50 32 24\n2 PINHOLE 64 48 50 50 32 24\n")
        .expect("write");
    std::fs::write(
        dir.path().join("images.txt"),
        text.replacen("1 1 0 0 0 0 0 10 1 front.png", "1 1e300 0 0 0 0 0 10 1 front.png", 1),
    )
    .expect("write");
    let err = read_colmap(dir.path()).expect_err("not a unit quaternion").to_string();
    assert!(err.contains("images.txt: line") && err.contains("= (1e300, 0, 0, 0) is not a unit quaternion"), "{err}");
}

/// A radial term of `SIMPLE_RADIAL` or `RADIAL` was copied as read, so a `nan` or `inf` in
/// `cameras.txt` passed and showed only as an undistortion that did not converge, blamed on
/// the scene being imported rather than on the model's line.
#[test]
fn colmap_parameters_that_are_not_finite_are_refused_naming_the_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::copy(fixtures().join("colmap/images.txt"), dir.path().join("images.txt")).expect("copy");
    for (camera, says) in [
        ("SIMPLE_RADIAL 64 48 50 32 24 nan", "SIMPLE_RADIAL parameter 4 of 4 is NaN"),
        ("RADIAL 64 48 50 32 24 0.1 inf", "RADIAL parameter 5 of 5 is inf"),
        ("PINHOLE 64 48 50 -inf 32 24", "PINHOLE parameter 2 of 4 is -inf"),
    ] {
        let text = format!("1 PINHOLE 64 48 50 50 32 24\n2 {camera}\n");
        std::fs::write(dir.path().join("cameras.txt"), text).expect("write");
        let err = read_colmap(dir.path()).expect_err(camera).to_string();
        assert!(err.contains("cameras.txt: line 2: ") && err.contains(says), "{camera}: {err}");
    }
}

/// COLMAP writes an image name with spaces as it is: its first word alone was looked up as the
/// image (`side` finds `side.png` by its stem), another image than the pose's, without a word.
#[test]
fn a_colmap_image_name_with_spaces_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("cameras.txt"), "1 PINHOLE 64 48 50 50 32 24\n2 PINHOLE 64 48 50 50 32 24\n")
        .expect("write");
    let text = std::fs::read_to_string(fixtures().join("colmap/images.txt")).expect("read");
    std::fs::write(dir.path().join("images.txt"), text.replace("1 side.png", "1 side view.png")).expect("write");
    let err = read_colmap(dir.path()).expect_err("a name with a space").to_string();
    assert!(
        err.contains("images.txt: line 8: the image name `side` is followed by `view.png`")
            && err.contains("cannot hold spaces"),
        "{err}"
    );
}

/// Bytes of a COLMAP binary model built by hand from the documented layout
/// (`read_write_model.py`: cameras `<iiQQ` + params `<d`, images `<idddddddi` + name + NUL +
/// `<Q` points + 24 bytes per point).
fn colmap_bin_by_hand(dir: &Path) {
    let mut cams = Vec::new();
    cams.extend(2u64.to_le_bytes());
    // Camera 7: PINHOLE (model 1), 64 x 48, fx 50 fy 52 cx 32 cy 24.
    cams.extend(7i32.to_le_bytes());
    cams.extend(1i32.to_le_bytes());
    cams.extend(64u64.to_le_bytes());
    cams.extend(48u64.to_le_bytes());
    [50.0f64, 52.0, 32.0, 24.0].iter().for_each(|v| cams.extend(v.to_le_bytes()));
    // Camera 9: SIMPLE_RADIAL (model 2), f 60, cx 31.5, cy 23.5, k -0.1.
    cams.extend(9i32.to_le_bytes());
    cams.extend(2i32.to_le_bytes());
    cams.extend(64u64.to_le_bytes());
    cams.extend(48u64.to_le_bytes());
    [60.0f64, 31.5, 23.5, -0.1].iter().for_each(|v| cams.extend(v.to_le_bytes()));
    std::fs::write(dir.join("cameras.bin"), cams).expect("write");

    let mut imgs = Vec::new();
    imgs.extend(2u64.to_le_bytes());
    let h = std::f64::consts::FRAC_1_SQRT_2;
    for (id, q, t, cam, name, points) in [
        (1i32, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 10.0], 7i32, "front.jpg", 2u64),
        (2, [h, 0.0, h, 0.0], [1.0, 2.0, 3.0], 9, "side.jpg", 0),
    ] {
        imgs.extend(id.to_le_bytes());
        q.iter().chain(t.iter()).for_each(|v: &f64| imgs.extend(v.to_le_bytes()));
        imgs.extend(cam.to_le_bytes());
        imgs.extend(name.as_bytes());
        imgs.push(0);
        imgs.extend(points.to_le_bytes());
        for p in 0..points {
            imgs.extend((p as f64).to_le_bytes());
            imgs.extend(1.5f64.to_le_bytes());
            imgs.extend((p as i64 - 1).to_le_bytes());
        }
    }
    std::fs::write(dir.join("images.bin"), imgs).expect("write");
}

#[test]
fn colmap_binary_model_projects_as_colmap_documents() {
    let dir = tempfile::tempdir().expect("tempdir");
    colmap_bin_by_hand(dir.path());
    let cams = read_colmap(dir.path()).expect("reads");
    assert_eq!(cams.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(), ["front.jpg", "side.jpg"]);
    // COLMAP: X_cam = R(q) X + t; x = f X/Z + c with the image corner at (0, 0), so a pixel
    // centre at index + ½; fluidnerf's coordinate is x − ½.
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let r_side = DMat3::from_quat(fluidnerf_core::glam::DQuat::from_xyzw(0.0, h, 0.0, h));
    for p in [DVec3::new(1.0, -2.0, 0.0), DVec3::new(-0.5, 0.7, 1.2)] {
        let q = p + DVec3::new(0.0, 0.0, 10.0);
        let by_hand = DVec2::new(50.0 * q.x / q.z + 32.0 - 0.5, 52.0 * q.y / q.z + 24.0 - 0.5);
        let ours = cams[0].1.project(p).expect("in front");
        assert!((ours - by_hand).length() < 1e-12, "front {p}: {ours} vs {by_hand}");

        let q = r_side * p + DVec3::new(1.0, 2.0, 3.0);
        let (x, y) = (q.x / q.z, q.y / q.z);
        let radial = 1.0 - 0.1 * (x * x + y * y);
        let by_hand = DVec2::new(60.0 * x * radial + 31.5 - 0.5, 60.0 * y * radial + 23.5 - 0.5);
        let ours = cams[1].1.project(p).expect("in front");
        assert!((ours - by_hand).length() < 1e-12, "side {p}: {ours} vs {by_hand}");
    }
    // The same model written by the library reads back identically.
    let again = tempfile::tempdir().expect("tempdir");
    fluidnerf_io::calib::write_colmap_bin(again.path(), &cams).expect("writes");
    for ((na, a), (nb, b)) in cams.iter().zip(read_colmap(again.path()).expect("reads back")) {
        assert_eq!(na, &nb);
        assert_eq!(a.intrinsics, b.intrinsics);
        assert_eq!(a.distortion, b.distortion);
        assert!((a.centre() - b.centre()).length() < 1e-12);
    }
    // A camera with skew, which no COLMAP model holds, is refused by name (it was an assertion
    // that aborted the program).
    let mut skewed = cams.clone();
    skewed[1].1.intrinsics.skew = 0.5;
    let e = fluidnerf_io::calib::write_colmap_bin(again.path(), &skewed).expect_err("skew").to_string();
    assert!(e.contains("cameras.bin") && e.contains(&format!("image {} has skew 0.5", skewed[1].0)), "{e}");
}

#[test]
fn colmap_binary_errors_name_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    colmap_bin_by_hand(dir.path());
    let bytes = std::fs::read(dir.path().join("images.bin")).expect("read");
    std::fs::write(dir.path().join("images.bin"), &bytes[..bytes.len() - 30]).expect("write");
    let err = read_colmap(dir.path()).expect_err("truncated").to_string();
    assert!(err.contains("images.bin") && err.contains("truncated"), "{err}");
    // A count too small for the records that follow (here: one image of two) loses none silently.
    let mut fewer = bytes.clone();
    fewer[..8].copy_from_slice(&1u64.to_le_bytes());
    std::fs::write(dir.path().join("images.bin"), &fewer).expect("write");
    let err = read_colmap(dir.path()).expect_err("trailing records").to_string();
    assert!(err.contains("images.bin") && err.contains("bytes follow the last of the 1 images"), "{err}");
    // The second image with the first one's id: after the count, the first image's id, pose,
    // camera id, name with its NUL, point count and two points of 24 bytes.
    let mut twice = bytes.clone();
    let second = 8 + 4 + 7 * 8 + 4 + "front.jpg".len() + 1 + 8 + 2 * 24;
    assert_eq!(twice[second..second + 4], 2i32.to_le_bytes());
    twice[second..second + 4].copy_from_slice(&1i32.to_le_bytes());
    std::fs::write(dir.path().join("images.bin"), &twice).expect("write");
    let err = read_colmap(dir.path()).expect_err("image id 1 twice").to_string();
    assert!(err.contains("images.bin") && err.contains("image id 1 (side.jpg) appears twice"), "{err}");
    let mut cams = std::fs::read(dir.path().join("cameras.bin")).expect("read");
    cams.extend_from_slice(&[0; 5]);
    std::fs::write(dir.path().join("images.bin"), &bytes).expect("write");
    std::fs::write(dir.path().join("cameras.bin"), &cams).expect("write");
    let err = read_colmap(dir.path()).expect_err("trailing bytes").to_string();
    assert!(err.contains("cameras.bin") && err.contains("5 bytes follow"), "{err}");
    cams.truncate(cams.len() - 5);
    std::fs::write(dir.path().join("cameras.bin"), &cams).expect("write");
    cams[12..16].copy_from_slice(&5i32.to_le_bytes());
    std::fs::write(dir.path().join("cameras.bin"), &cams).expect("write");
    let err = read_colmap(dir.path()).expect_err("fisheye").to_string();
    assert!(err.contains("cameras.bin") && err.contains("camera id 7") && err.contains("OPENCV_FISHEYE"), "{err}");
    cams[12..16].copy_from_slice(&99i32.to_le_bytes());
    std::fs::write(dir.path().join("cameras.bin"), &cams).expect("write");
    let err = read_colmap(dir.path()).expect_err("unknown model").to_string();
    assert!(err.contains("camera id 7") && err.contains("unknown model id 99"), "{err}");
}

/// The file OpenCV's calibration sample writes (`out_camera_data.yml`, as in the tutorial
/// "Camera calibration With OpenCV"), intrinsics only.
const OPENCV_SAMPLE: &str = "%YAML:1.0
calibration_Time: \"08/19/11 20:44:38\"
nrOfFrames: 8
image_Width: 640
image_Height: 480
board_Width: 9
board_Height: 6
square_Size: 50.
FixAspectRatio: 1.
# flags:  +fix_aspectRatio +fix_principal_point +zero_tangent_dist
flagValue: 14
Camera_Matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 6.5746697810243404e+002, 0., 3.1950000000000000e+002, 0.,
       6.5746697810243404e+002, 2.3950000000000000e+002, 0., 0., 1. ]
Distortion_Coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -4.1802327018241026e-001, 5.0715243805833121e-001, 0., 0.,
       -5.7843596847939704e-001 ]
Avg_Reprojection_Error: 3.8441346462381665e-001
Per_View_Reprojection_Errors: !!opencv-matrix
   rows: 2
   cols: 1
   dt: f
   data: [ 5.04999518e-001, 4.22946453e-001 ]
";

/// OpenCV: `x = K (R X + t)`, then `(x/z, y/z)` through the distortion, pixel centres at
/// integers; here with k1, k2, k3 only (p1 = p2 = 0).
fn opencv_by_hand(k: [f64; 4], d: [f64; 3], r: DMat3, t: DVec3, p: DVec3) -> DVec2 {
    let q = r * p + t;
    let (x, y) = (q.x / q.z, q.y / q.z);
    let r2 = x * x + y * y;
    let s = 1.0 + d[0] * r2 + d[1] * r2 * r2 + d[2] * r2 * r2 * r2;
    DVec2::new(k[0] * x * s + k[2], k[1] * y * s + k[3])
}

#[test]
#[allow(clippy::excessive_precision)] // The sample file's digits, verbatim.
fn opencv_calibration_sample_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("out_camera_data.yml");
    std::fs::write(&file, OPENCV_SAMPLE).expect("write");
    let err = read_opencv(&file).expect_err("no pose").to_string();
    assert!(err.contains("out_camera_data.yml") && err.contains("camera `out_camera_data`"), "{err}");
    assert!(err.contains("no pose") && err.contains("`rvec` and `tvec` or `R` and `T`"), "{err}");

    // With a pose appended (as one would from an extrinsic calibration).
    let mut text = OPENCV_SAMPLE.to_string();
    text += "rvec: [0.1, -0.2, 0.05]\ntvec: [10.0, -20.0, 900.0]\n";
    std::fs::write(&file, text).expect("write");
    let cams = read_opencv(&file).expect("reads");
    assert_eq!(cams.len(), 1);
    let (name, cam) = &cams[0];
    assert_eq!(name, "out_camera_data");
    assert_eq!((cam.intrinsics.width, cam.intrinsics.height), (640, 480));
    let k = [6.5746697810243404e2, 6.5746697810243404e2, 319.5, 239.5];
    let d = [-4.1802327018241026e-1, 5.0715243805833121e-1, -5.7843596847939704e-1];
    let r = rodrigues_to_matrix(DVec3::new(0.1, -0.2, 0.05));
    for p in [DVec3::ZERO, DVec3::new(30.0, -40.0, 10.0), DVec3::new(-100.0, 80.0, -50.0)] {
        let by_hand = opencv_by_hand(k, d, r, DVec3::new(10.0, -20.0, 900.0), p);
        let ours = cam.project(p).expect("in front");
        assert!((ours - by_hand).length() < 1e-9, "{p}: {ours} vs {by_hand}");
    }
}

/// Several cameras as one mapping each, with `R`/`T`; a missing node is named with its camera.
#[test]
fn opencv_multi_camera_mappings_with_r_and_t() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("rig.yml");
    let text = "%YAML:1.0
left:
   image_width: 64
   image_height: 48
   camera_matrix: !!opencv-matrix
      rows: 3
      cols: 3
      dt: d
      data: [ 80., 0., 31.5, 0., 82., 23.5, 0., 0., 1. ]
   R: !!opencv-matrix
      rows: 3
      cols: 3
      dt: d
      data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]
   T: [ 0., 0., 100. ]
right:
   image_width: 64
   image_height: 48
   Camera_Matrix: !!opencv-matrix
      rows: 3
      cols: 3
      dt: d
      data: [ 70., 0., 30., 0., 71., 22., 0., 0., 1. ]
   Distortion_Coefficients: [ -0.05, 0.01, 0., 0., 0. ]
   R: !!opencv-matrix
      rows: 3
      cols: 3
      dt: d
      data: [ 0., 0., -1., 0., 1., 0., 1., 0., 0. ]
   T: [ 5., -3., 120. ]
";
    std::fs::write(&file, text).expect("write");
    let cams = read_opencv(&file).expect("reads");
    assert_eq!(cams.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(), ["left", "right"]);
    // R rows [0 0 −1; 0 1 0; 1 0 0].
    let r_right = DMat3::from_cols(DVec3::new(0.0, 0.0, 1.0), DVec3::Y, DVec3::new(-1.0, 0.0, 0.0));
    for p in [DVec3::ZERO, DVec3::new(3.0, -4.0, 5.0)] {
        let ours = cams[0].1.project(p).expect("in front");
        let by_hand =
            opencv_by_hand([80.0, 82.0, 31.5, 23.5], [0.0; 3], DMat3::IDENTITY, DVec3::new(0.0, 0.0, 100.0), p);
        assert!((ours - by_hand).length() < 1e-9, "left {p}: {ours} vs {by_hand}");
        let ours = cams[1].1.project(p).expect("in front");
        let by_hand =
            opencv_by_hand([70.0, 71.0, 30.0, 22.0], [-0.05, 0.01, 0.0], r_right, DVec3::new(5.0, -3.0, 120.0), p);
        assert!((ours - by_hand).length() < 1e-9, "right {p}: {ours} vs {by_hand}");
    }
    std::fs::write(&file, text.replace("   T: [ 5., -3., 120. ]\n", "")).expect("write");
    let err = read_opencv(&file).expect_err("no T").to_string();
    assert!(err.contains("rig.yml") && err.contains("camera `right`") && err.contains("missing the node `T`"), "{err}");
    std::fs::write(&file, text.replace("   T: [ 0., 0., 100. ]\n", "   Tx: [ 0., 0., 100. ]\n")).expect("write");
    let err = read_opencv(&file).expect_err("no T").to_string();
    assert!(err.contains("camera `left`") && err.contains("missing the node `T`"), "{err}");
}

/// OpenCV's calibration sample written as XML (`out_camera_data.xml`, its default), the same
/// values as the YAML sample above.
const OPENCV_SAMPLE_XML: &str = r#"<?xml version="1.0"?>
<opencv_storage>
<calibration_Time>"Thu 26 Nov 2026 10:00:00 AM CET"</calibration_Time>
<nrOfFrames>2</nrOfFrames>
<image_Width>640</image_Width>
<image_Height>480</image_Height>
<board_Width>9</board_Width>
<board_Height>6</board_Height>
<square_Size>50.</square_Size>
<flags>6158</flags>
<Camera_Matrix type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    6.5746697810243404e+02 0. 3.1950000000000000e+02 0.
    6.5746697810243404e+02 2.3950000000000000e+02 0. 0. 1.</data></Camera_Matrix>
<Distortion_Coefficients type_id="opencv-matrix">
  <rows>5</rows>
  <cols>1</cols>
  <dt>d</dt>
  <data>
    -4.1802327018241026e-01 5.0715243805833121e-01 0. 0.
    -5.7843596847939704e-01</data></Distortion_Coefficients>
<Avg_Reprojection_Error>3.9259109564281437e-01</Avg_Reprojection_Error>
<Extrinsic_Parameters type_id="opencv-matrix">
  <rows>2</rows>
  <cols>6</cols>
  <dt>d</dt>
  <data>
    1.2e-01 -3.1e-02 1.5e+00 -1.1e+02 -8.4e+01 5.1e+02 9.8e-02 4.4e-02 1.4e+00
    -9.7e+01 -7.9e+01 4.8e+02</data></Extrinsic_Parameters>
<Per_View_Reprojection_Errors type_id="opencv-matrix">
  <rows>2</rows>
  <cols>1</cols>
  <dt>f</dt>
  <data>
    5.04999518e-01 4.22946453e-01</data></Per_View_Reprojection_Errors>
</opencv_storage>
"#;

#[test]
#[allow(clippy::excessive_precision)] // The sample file's digits, verbatim.
fn opencv_calibration_sample_xml() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("out_camera_data.xml");
    std::fs::write(&file, OPENCV_SAMPLE_XML).expect("write");
    let err = read_opencv(&file).expect_err("no pose").to_string();
    assert!(err.contains("out_camera_data.xml") && err.contains("camera `out_camera_data`"), "{err}");
    assert!(err.contains("no pose"), "{err}");
    assert!(err.contains("`Extrinsic_Parameters` are the calibration board's poses"), "{err}");

    let posed = OPENCV_SAMPLE_XML.replace(
        "</opencv_storage>",
        "<rvec>0.1 -0.2 0.05</rvec>\n<tvec>\n  <_>10.</_><_>-20.</_><_>900.</_></tvec>\n</opencv_storage>",
    );
    std::fs::write(&file, posed).expect("write");
    let cams = read_opencv(&file).expect("reads");
    let (name, cam) = &cams[0];
    assert_eq!(name, "out_camera_data");
    assert_eq!((cam.intrinsics.width, cam.intrinsics.height), (640, 480));
    let k = [6.5746697810243404e2, 6.5746697810243404e2, 319.5, 239.5];
    let d = [-4.1802327018241026e-1, 5.0715243805833121e-1, -5.7843596847939704e-1];
    let r = rodrigues_to_matrix(DVec3::new(0.1, -0.2, 0.05));
    for p in [DVec3::ZERO, DVec3::new(30.0, -40.0, 10.0), DVec3::new(-100.0, 80.0, -50.0)] {
        let by_hand = opencv_by_hand(k, d, r, DVec3::new(10.0, -20.0, 900.0), p);
        let ours = cam.project(p).expect("in front");
        assert!((ours - by_hand).length() < 1e-9, "{p}: {ours} vs {by_hand}");
    }
}

/// Several cameras in one XML file, one element each with `R`/`T`.
#[test]
fn opencv_multi_camera_xml() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("rig.xml");
    let cam = |k: &str, r: &str, t: &str| {
        format!(
            "<image_width>64</image_width><image_height>48</image_height>\
             <camera_matrix type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>d</dt><data>{k}</data></camera_matrix>\
             <R type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>d</dt><data>{r}</data></R>\
             <T type_id=\"opencv-matrix\"><rows>3</rows><cols>1</cols><dt>d</dt><data>{t}</data></T>"
        )
    };
    let text = format!(
        "<?xml version=\"1.0\"?>\n<opencv_storage>\n<left>{}</left>\n<right>{}</right>\n</opencv_storage>\n",
        cam("80. 0. 31.5 0. 82. 23.5 0. 0. 1.", "1. 0. 0. 0. 1. 0. 0. 0. 1.", "0. 0. 100."),
        cam("70. 0. 30. 0. 71. 22. 0. 0. 1.", "0. 0. -1. 0. 1. 0. 1. 0. 0.", "5. -3. 120.")
    );
    std::fs::write(&file, text).expect("write");
    let cams = read_opencv(&file).expect("reads");
    assert_eq!(cams.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(), ["left", "right"]);
    let r_right = DMat3::from_cols(DVec3::new(0.0, 0.0, 1.0), DVec3::Y, DVec3::new(-1.0, 0.0, 0.0));
    for p in [DVec3::ZERO, DVec3::new(3.0, -4.0, 5.0)] {
        let by_hand =
            opencv_by_hand([80.0, 82.0, 31.5, 23.5], [0.0; 3], DMat3::IDENTITY, DVec3::new(0.0, 0.0, 100.0), p);
        assert!((cams[0].1.project(p).expect("in front") - by_hand).length() < 1e-9);
        let by_hand = opencv_by_hand([70.0, 71.0, 30.0, 22.0], [0.0; 3], r_right, DVec3::new(5.0, -3.0, 120.0), p);
        assert!((cams[1].1.project(p).expect("in front") - by_hand).length() < 1e-9);
    }
}

const STEREO_INTRINSICS: &str = "%YAML:1.0
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 500., 0., 319.5, 0., 502., 239.5, 0., 0., 1. ]
D1: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.1, 0.02, 0., 0., 0.003 ]
M2: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 510., 0., 320., 0., 511., 240., 0., 0., 1. ]
D2: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.12, 0.03, 0., 0., 0. ]
";

const STEREO_EXTRINSICS_XML: &str = r#"<?xml version="1.0"?>
<opencv_storage>
<R type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>
  <data>0.9950041652780258 0. -0.09983341664682815 0. 1. 0. 0.09983341664682815 0. 0.9950041652780258</data></R>
<T type_id="opencv-matrix"><rows>3</rows><cols>1</cols><dt>d</dt><data>-120. 1.5 4.</data></T>
<R1 type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt><data>1. 0. 0. 0. 1. 0. 0. 0. 1.</data></R1>
<Q type_id="opencv-matrix"><rows>4</rows><cols>4</cols><dt>d</dt><data>1. 0. 0. 0. 0. 1. 0. 0. 0. 0. 0. 1. 0. 0. 1. 0.</data></Q>
</opencv_storage>
"#;

/// Checks a stereo pair against OpenCV's projection by hand: camera 1 is the world frame,
/// camera 2 sees `R x + T`.
fn check_stereo(cams: &[(String, fluidnerf_core::Camera)]) {
    assert_eq!(cams.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(), ["cam1", "cam2"]);
    assert_eq!((cams[1].1.intrinsics.width, cams[1].1.intrinsics.height), (640, 480));
    // R is a rotation of 0.1 rad about y: rows [c 0 −s; 0 1 0; s 0 c].
    let (s, c) = 0.1f64.sin_cos();
    let r = DMat3::from_cols(DVec3::new(c, 0.0, s), DVec3::Y, DVec3::new(-s, 0.0, c));
    for p in [DVec3::new(0.0, 0.0, 800.0), DVec3::new(60.0, -40.0, 1000.0)] {
        let one = opencv_by_hand([500.0, 502.0, 319.5, 239.5], [-0.1, 0.02, 0.003], DMat3::IDENTITY, DVec3::ZERO, p);
        assert!((cams[0].1.project(p).expect("in front") - one).length() < 1e-9, "cam1 {p}");
        let two = opencv_by_hand([510.0, 511.0, 320.0, 240.0], [-0.12, 0.03, 0.0], r, DVec3::new(-120.0, 1.5, 4.0), p);
        assert!((cams[1].1.project(p).expect("in front") - two).length() < 1e-9, "cam2 {p}");
    }
}

/// A stereo calibration (`M1 D1 M2 D2 R T`) in one file, and as intrinsics + extrinsics files
/// side by side (here YAML + XML), given as the intrinsics file or as the folder.
#[test]
fn opencv_stereo_calibrations() {
    let dir = tempfile::tempdir().expect("tempdir");
    let one = dir.path().join("stereo.yml");
    let extr_yaml = "R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 0.9950041652780258, 0., -0.09983341664682815, 0., 1., 0., 0.09983341664682815, 0., 0.9950041652780258 ]\nT: [ -120., 1.5, 4. ]\n";
    std::fs::write(&one, format!("{STEREO_INTRINSICS}imageSize: [ 640, 480 ]\n{extr_yaml}")).expect("write");
    check_stereo(&read_opencv(&one).expect("reads one file"));

    let pair = dir.path().join("pair");
    std::fs::create_dir(&pair).expect("mkdir");
    let intr = pair.join("intrinsics.yml");
    std::fs::write(&intr, format!("{STEREO_INTRINSICS}image_width: 640\nimage_height: 480\n")).expect("write");
    let err = read_opencv(&intr).expect_err("no extrinsics yet").to_string();
    assert!(err.contains("intrinsics.yml") && err.contains("`R` and `T`") && err.contains("extrinsics.yml"), "{err}");
    std::fs::write(pair.join("extrinsics.xml"), STEREO_EXTRINSICS_XML).expect("write");
    check_stereo(&read_opencv(&intr).expect("reads the pair"));
    check_stereo(&read_opencv(&pair).expect("reads the folder"));

    // Without an image size; with a distortion of a count OpenCV never writes.
    std::fs::write(&intr, STEREO_INTRINSICS).expect("write");
    let err = read_opencv(&intr).expect_err("no size").to_string();
    assert!(err.contains("image size") && err.contains("imageSize"), "{err}");
    let bad = STEREO_INTRINSICS.replace(
        "cols: 5\n   dt: d\n   data: [ -0.12, 0.03, 0., 0., 0. ]",
        "cols: 3\n   dt: d\n   data: [ -0.12, 0.03, 0. ]",
    );
    assert_ne!(bad, STEREO_INTRINSICS);
    std::fs::write(&intr, format!("{bad}imageSize: [ 640, 480 ]\n")).expect("write");
    let err = read_opencv(&intr).expect_err("3 coefficients").to_string();
    assert!(err.contains("intrinsics.yml") && err.contains("camera `cam2`") && err.contains("`D2`"), "{err}");
}

/// Malformed XML is refused with the file and the problem.
#[test]
fn opencv_xml_errors_name_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cases = [
        ("broken.xml", "<?xml version=\"1.0\"?>\n<opencv_storage><camera_matrix>1 2</opencv_storage>", "malformed XML"),
        ("root.xml", "<?xml version=\"1.0\"?>\n<calibration><a>1</a></calibration>", "<opencv_storage>"),
        (
            "dup.xml",
            "<?xml version=\"1.0\"?>\n<opencv_storage><cam><R>1</R><R>2</R></cam></opencv_storage>",
            "appears twice",
        ),
        (
            "size.xml",
            "<?xml version=\"1.0\"?>\n<opencv_storage><camera_matrix type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols>\
             <dt>d</dt><data>1 0 0 0 1 0 0 0</data></camera_matrix></opencv_storage>",
            "rows × cols = 3 × 3 but 8 values",
        ),
        (
            "text.xml",
            "<?xml version=\"1.0\"?>\n<opencv_storage><camera_matrix>one two</camera_matrix><image_width>4</image_width>\
             <image_height>4</image_height><rvec>0 0 0</rvec><tvec>0 0 1</tvec></opencv_storage>",
            "camera_matrix",
        ),
    ];
    for (name, text, want) in cases {
        let file = dir.path().join(name);
        std::fs::write(&file, text).expect("write");
        let err = read_opencv(&file).expect_err(name).to_string();
        assert!(err.contains(name) && err.contains(want), "{name}: {err}");
    }
}

/// OpenCV's `projectPoints` written out, on plain arrays (row-major K and R):
/// `(x, y, z) = R X + t`, `(x', y') = (x/z, y/z)`, `r² = x'² + y'²`,
/// `radial = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)`,
/// `x'' = x' radial + 2 p1 x'y' + p2 (r² + 2x'²)`, `y'' = y' radial + p1 (r² + 2y'²) + 2 p2 x'y'`,
/// `u = fx x'' + s y'' + cx`, `v = fy y'' + cy`. `d` is in OpenCV's order, missing terms zero.
fn project_by_hand(k: [f64; 9], d: &[f64], r: [f64; 9], t: [f64; 3], p: [f64; 3]) -> [f64; 2] {
    let q: Vec<f64> = (0..3).map(|i| r[3 * i] * p[0] + r[3 * i + 1] * p[1] + r[3 * i + 2] * p[2] + t[i]).collect();
    let (x, y) = (q[0] / q[2], q[1] / q[2]);
    let c = |i: usize| d.get(i).copied().unwrap_or(0.0);
    let (k1, k2, p1, p2, k3, k4, k5, k6) = (c(0), c(1), c(2), c(3), c(4), c(5), c(6), c(7));
    let r2 = x * x + y * y;
    let radial =
        (1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2) / (1.0 + k4 * r2 + k5 * r2 * r2 + k6 * r2 * r2 * r2);
    let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    [k[0] * xd + k[1] * yd + k[2], k[4] * yd + k[5]]
}

/// `a b` for row-major 3 × 3 matrices.
fn mat_mul(a: [f64; 9], b: [f64; 9]) -> [f64; 9] {
    let mut out = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            out[3 * i + j] = (0..3).map(|l| a[3 * i + l] * b[3 * l + j]).sum();
        }
    }
    out
}

fn assert_projects_as(cam: &Camera, k: [f64; 9], d: &[f64], r: [f64; 9], t: [f64; 3], what: &str) {
    for p in [[1.0, 2.0, 300.0], [40.0, -30.0, 320.0], [-60.0, 45.0, 280.0]] {
        let by_hand = project_by_hand(k, d, r, t, p);
        let ours = cam.project(DVec3::from_array(p)).expect("in front");
        let err = (ours - DVec2::from_array(by_hand)).length();
        assert!(err < 1e-9, "{what} {p:?}: ours {ours}, by hand {by_hand:?}");
    }
}

/// Rows of the rotation about y by 90° (the Rodrigues vector `(0, π/2, 0)`), and about z by
/// 90°, written out.
const R_Y90: [f64; 9] = [0.0, 0.0, 1.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0];
const R_Z90: [f64; 9] = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];

/// A list of cameras (`cameras: [{name: ..., camera_matrix: ..., rvec: ..., tvec: ...}]`), in
/// YAML and in XML (`<_>` entries); an entry without `name` is `cam<index>`.
#[test]
fn opencv_camera_list() {
    let dir = tempfile::tempdir().expect("tempdir");
    let k_a = [400.0, 0.5, 63.5, 0.0, 410.0, 47.5, 0.0, 0.0, 1.0];
    let d_a = [-0.2, 0.05, 0.001, -0.002, 0.01, 0.003, -0.001, 0.0005];
    let k_b = [380.0, 0.0, 60.0, 0.0, 380.0, 50.0, 0.0, 0.0, 1.0];
    let d_b = [0.1, -0.02, 0.0005, 0.0007];
    let yaml = "%YAML:1.0
cameras:
   - name: top
     image_width: 128
     image_height: 96
     camera_matrix: !!opencv-matrix
        rows: 3
        cols: 3
        dt: d
        data: [ 400., 0.5, 63.5, 0., 410., 47.5, 0., 0., 1. ]
     distortion_coefficients: [ -0.2, 0.05, 0.001, -0.002, 0.01, 0.003, -0.001, 0.0005 ]
     rvec: [ 0., 1.5707963267948966, 0. ]
     tvec: [ 1., 2., 200. ]
   - image_width: 128
     image_height: 96
     Camera_Matrix: [ 380., 0., 60., 0., 380., 50., 0., 0., 1. ]
     Distortion_Coefficients: [ 0.1, -0.02, 0.0005, 0.0007 ]
     R: !!opencv-matrix
        rows: 3
        cols: 3
        dt: d
        data: [ 0., -1., 0., 1., 0., 0., 0., 0., 1. ]
     T: [ -3., 0.5, 150. ]
";
    let file = dir.path().join("rig.yml");
    std::fs::write(&file, yaml).expect("write");
    let check = |cams: &[(String, Camera)], what: &str| {
        assert_eq!(cams.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(), ["top", "cam1"], "{what}");
        assert_projects_as(&cams[0].1, k_a, &d_a, R_Y90, [1.0, 2.0, 200.0], what);
        assert_projects_as(&cams[1].1, k_b, &d_b, R_Z90, [-3.0, 0.5, 150.0], what);
    };
    check(&read_opencv(&file).expect("reads YAML"), "YAML");

    let xml = r#"<?xml version="1.0"?>
<opencv_storage>
<cameras>
  <_>
    <name>"top"</name>
    <image_width>128</image_width>
    <image_height>96</image_height>
    <camera_matrix type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>
      <data>400. 0.5 63.5 0. 410. 47.5 0. 0. 1.</data></camera_matrix>
    <distortion_coefficients type_id="opencv-matrix"><rows>8</rows><cols>1</cols><dt>d</dt>
      <data>-0.2 0.05 0.001 -0.002 0.01 0.003 -0.001 0.0005</data></distortion_coefficients>
    <rvec>0. 1.5707963267948966 0.</rvec>
    <tvec><_>1.</_><_>2.</_><_>200.</_></tvec></_>
  <_>
    <image_width>128</image_width>
    <image_height>96</image_height>
    <camera_matrix>380. 0. 60. 0. 380. 50. 0. 0. 1.</camera_matrix>
    <distortion_coefficients>0.1 -0.02 0.0005 0.0007</distortion_coefficients>
    <R type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt><data>0. -1. 0. 1. 0. 0. 0. 0. 1.</data></R>
    <T>-3. 0.5 150.</T></_>
</cameras>
</opencv_storage>
"#;
    let file = dir.path().join("rig.xml");
    std::fs::write(&file, xml).expect("write");
    check(&read_opencv(&file).expect("reads XML"), "XML");

    // An entry that is not a camera, and a name given twice.
    std::fs::write(
        &file,
        xml.replace("<camera_matrix>380.", "<camera_matrices>380.").replace(
            "1.</camera_matrix>\n    <distortion_coefficients>0.1",
            "1.</camera_matrices>\n    <distortion_coefficients>0.1",
        ),
    )
    .expect("write");
    let err = read_opencv(&file).expect_err("not a camera").to_string();
    assert!(err.contains("rig.xml") && err.contains("`cameras[1]`: not a camera"), "{err}");
    std::fs::write(&file, xml.replace("<_>\n    <image_width>", "<_>\n    <name>top</name><image_width>"))
        .expect("write");
    let err = read_opencv(&file).expect_err("twice").to_string();
    assert!(err.contains("rig.xml") && err.contains("camera name `top` appears twice"), "{err}");
    std::fs::write(&file, xml.replace("<name>\"top\"</name>", "<name>\"\"</name>")).expect("write");
    let err = read_opencv(&file).expect_err("empty name").to_string();
    assert!(err.contains("rig.xml") && err.contains("`cameras[0]`: `name` is empty"), "{err}");
}

/// A stereo calibration in one XML file with camera 1's world pose (`rvec1`/`tvec1`) and an
/// image size per camera: camera 2's pose is `R R₁`, `R t₁ + T`, composed here by hand.
#[test]
fn opencv_stereo_with_a_world_pose_and_sizes_per_camera() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("stereo.xml");
    let m1 = [500.0, 0.0, 159.5, 0.0, 505.0, 119.5, 0.0, 0.0, 1.0];
    let d1 = [-0.1, 0.02, 0.001, 0.002, 0.003];
    let m2 = [520.0, 0.0, 200.0, 0.0, 521.0, 150.0, 0.0, 0.0, 1.0];
    let d2 = [-0.12, 0.03, -0.001, 0.0, 0.0, 0.01, 0.0, 0.0];
    let (r1, t1) = (R_Y90, [5.0, -10.0, 400.0]);
    let (r, t) = (R_Z90, [-100.0, 2.0, 8.0]);
    let xml = r#"<?xml version="1.0"?>
<opencv_storage>
<imageSize1>320 240</imageSize1>
<image_width2>400</image_width2>
<image_height2>300</image_height2>
<M1 type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>
  <data>500. 0. 159.5 0. 505. 119.5 0. 0. 1.</data></M1>
<D1 type_id="opencv-matrix"><rows>1</rows><cols>5</cols><dt>d</dt>
  <data>-0.1 0.02 0.001 0.002 0.003</data></D1>
<M2 type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>
  <data>520. 0. 200. 0. 521. 150. 0. 0. 1.</data></M2>
<D2 type_id="opencv-matrix"><rows>1</rows><cols>8</cols><dt>d</dt>
  <data>-0.12 0.03 -0.001 0. 0. 0.01 0. 0.</data></D2>
<R type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>
  <data>0. -1. 0. 1. 0. 0. 0. 0. 1.</data></R>
<T type_id="opencv-matrix"><rows>3</rows><cols>1</cols><dt>d</dt>
  <data>-100. 2. 8.</data></T>
<rvec1>0. 1.5707963267948966 0.</rvec1>
<tvec1>5. -10. 400.</tvec1>
<P1 type_id="opencv-matrix"><rows>3</rows><cols>4</cols><dt>d</dt>
  <data>1. 0. 0. 0. 0. 1. 0. 0. 0. 0. 1. 0.</data></P1>
</opencv_storage>
"#;
    std::fs::write(&file, xml).expect("write");
    let cams = read_opencv(&file).expect("reads");
    assert_eq!(cams.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(), ["cam1", "cam2"]);
    let sizes: Vec<(u32, u32)> = cams.iter().map(|c| (c.1.intrinsics.width, c.1.intrinsics.height)).collect();
    assert_eq!(sizes, [(320, 240), (400, 300)]);
    assert_projects_as(&cams[0].1, m1, &d1, r1, t1, "cam1");
    let rt1: Vec<f64> = (0..3).map(|i| r[3 * i] * t1[0] + r[3 * i + 1] * t1[1] + r[3 * i + 2] * t1[2] + t[i]).collect();
    assert_projects_as(&cams[1].1, m2, &d2, mat_mul(r, r1), [rt1[0], rt1[1], rt1[2]], "cam2");

    // Without the world pose camera 1 is the world frame.
    let plain = xml.replace("<rvec1>0. 1.5707963267948966 0.</rvec1>\n<tvec1>5. -10. 400.</tvec1>\n", "");
    assert_ne!(plain, xml);
    std::fs::write(&file, &plain).expect("write");
    let cams = read_opencv(&file).expect("reads");
    assert_projects_as(&cams[0].1, m1, &d1, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], [0.0; 3], "cam1");
    assert_projects_as(&cams[1].1, m2, &d2, r, t, "cam2");

    // A world rotation without its translation.
    std::fs::write(&file, xml.replace("<tvec1>5. -10. 400.</tvec1>\n", "")).expect("write");
    let err = read_opencv(&file).expect_err("no tvec1").to_string();
    assert!(err.contains("stereo.xml: camera `cam1`: missing the node `tvec1`"), "{err}");
    // Camera 2 without an image size of its own or a shared one.
    std::fs::write(&file, xml.replace("<image_width2>400</image_width2>\n", "")).expect("write");
    let err = read_opencv(&file).expect_err("no size").to_string();
    assert!(
        err.contains("stereo.xml: camera `cam2`: no image size")
            && err.contains("`image_width2` and `image_height2`")
            && err.contains("`imageSize`"),
        "{err}"
    );
}

/// The two-file form given as its extrinsics file finds the intrinsics beside it; a bad node
/// of the extrinsics is reported with that file.
#[test]
fn opencv_stereo_from_the_extrinsics_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let intr = dir.path().join("intrinsics.yml");
    let extr = dir.path().join("extrinsics.xml");
    std::fs::write(&intr, format!("{STEREO_INTRINSICS}imageSize: [ 640, 480 ]\n")).expect("write");
    std::fs::write(&extr, STEREO_EXTRINSICS_XML).expect("write");
    check_stereo(&read_opencv(&extr).expect("reads the pair from the extrinsics"));
    std::fs::write(
        &extr,
        STEREO_EXTRINSICS_XML.replace(
            "<rows>3</rows><cols>1</cols><dt>d</dt><data>-120. 1.5 4.",
            "<rows>2</rows><cols>1</cols><dt>d</dt><data>-120. 1.5",
        ),
    )
    .expect("write");
    let err = read_opencv(&intr).expect_err("T has 2 values").to_string();
    assert!(err.contains("extrinsics.xml: camera `cam2`: `T` has 2 values; expected 3"), "{err}");
    // Alone, the extrinsics say what they lack.
    std::fs::remove_file(&intr).expect("rm");
    std::fs::write(&extr, STEREO_EXTRINSICS_XML).expect("write");
    let err = read_opencv(&extr).expect_err("no intrinsics").to_string();
    assert!(err.contains("extrinsics.xml: no camera matrix") && err.contains("`M1` and `M2`"), "{err}");
}

/// Malformed nodes: each message names the file, the camera and the node as the file spells it.
#[test]
fn opencv_malformed_nodes_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let stereo = format!(
        "{STEREO_INTRINSICS}imageSize: [ 640, 480 ]\nR: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\nT: [ -120., 0., 0. ]\n"
    );
    let d2 = "cols: 5\n   dt: d\n   data: [ -0.12, 0.03, 0., 0., 0. ]";
    let m1 = "data: [ 500., 0., 319.5, 0., 502., 239.5, 0., 0., 1. ]";
    let sample_k = "6.5746697810243404e+02 0. 3.1950000000000000e+02 0.\n    6.5746697810243404e+02 2.3950000000000000e+02 0. 0. 1.";
    let cases: [(&str, String, &str); 19] = [
        ("calib.yml", stereo.replace(d2, "cols: 3\n   dt: d\n   data: [ -0.12, 0.03, 0. ]"), "calib.yml: camera `cam2`: `D2` has 3 values; expected 4, 5, 8, 12 or 14"),
        ("calib.yml", stereo.replace(d2, "cols: 9\n   dt: d\n   data: [ -0.12, 0.03, 0., 0., 0., 0., 0., 0., 0. ]"), "`D2` has 9 values"),
        ("calib.yml", stereo.replace(m1, "data: [ 500., 0., 319.5, 0., 502., 239.5 ]").replace("rows: 3\n   cols: 3\n   dt: d\n   data: [ 500.,", "rows: 2\n   cols: 3\n   dt: d\n   data: [ 500.,"), "camera `cam1`: `M1` has 6 values; expected 9 (3 × 3)"),
        ("calib.yml", stereo.replace(m1, "data: [ 500., 0., 319.5, 0., abc, 239.5, 0., 0., 1. ]"), "camera `cam1`: `M1`: matrix data must be numbers"),
        ("calib.yml", stereo.replace(m1, "data: [ -500., 0., 319.5, 0., 502., 239.5, 0., 0., 1. ]"), "camera `cam1`: `M1`: invalid intrinsics: focal lengths must be positive"),
        ("calib.yml", stereo.replace("R: [ 1., 0., 0.,", "R: [ 2., 0., 0.,"), "camera `cam2`: `R`: invalid camera pose: rotation is not a proper rotation"),
        ("calib.yml", stereo.replace("R: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]", "R: [ 0., 0., 0., 0., 0., 0., 0., 0., 0. ]"), "camera `cam2`: `R` is singular (determinant 0), not a rotation"),
        ("calib.yml", stereo.replace("imageSize: [ 640, 480 ]", "imageSize: [ 640.5, 480 ]"), "camera `cam1`: `imageSize`: expected [width, height] as two positive integers"),
        ("calib.yml", stereo.replace("imageSize: [ 640, 480 ]", "imageSize: [ 640, 480, 3 ]"), "`imageSize`: expected [width, height]"),
        ("calib.yml", stereo.replace("   rows: 3\n   cols: 3\n   dt: d\n   data: [ 510.", "   rows: 4294967296\n   cols: 4294967296\n   dt: d\n   data: [ 510."), "camera `cam2`: `M2`: rows × cols = 4294967296 × 4294967296 but 9 values"),
        ("calib.yml", stereo.replace("   rows: 3\n   cols: 3\n   dt: d\n   data: [ 510.", "   rows: -3\n   cols: 3\n   dt: d\n   data: [ 510."), "camera `cam2`: `M2`: `rows` must be a non-negative integer"),
        ("out_camera_data.xml", OPENCV_SAMPLE_XML.replace(sample_k, "1 0 3 0 1 2 0 0"), "out_camera_data.xml: camera `out_camera_data`: `Camera_Matrix`: rows × cols = 3 × 3 but 8 values"),
        ("out_camera_data.xml", OPENCV_SAMPLE_XML.replace("<image_Width>640</image_Width>", "<image_Width>wide</image_Width>"), "camera `out_camera_data`: `image_Width` must be a positive integer"),
        ("out_camera_data.xml", OPENCV_SAMPLE_XML.replace("<rows>5</rows>\n  <cols>1</cols>", "<rows>3</rows>\n  <cols>1</cols>").replace("0. 0.\n    -5.7843596847939704e-01</data>", "0.</data>"),
            "`Distortion_Coefficients` has 3 values; expected 4, 5, 8, 12 or 14"),
        ("rig.xml", "<?xml version=\"1.0\"?>\n<opencv_storage><cam><camera_matrix>1 0 1 0 1 1 0 0 1</camera_matrix></cam>".into(), "rig.xml: malformed XML"),
        ("rig.xml", "<?xml version=\"1.0\"?>\n<opencv_storage>\n</opencv_storage>\n".into(), "rig.xml: no camera matrix"),
        ("rig.xml", "<?xml version=\"1.0\"?>\n<opencv_storage><left><camera_matrix>1 0 1 0 1 1 0 0 1</camera_matrix><image_width>8</image_width><image_height>8</image_height><R>1 0 0 0 1 0 0 0 1</R></left></opencv_storage>".into(), "rig.xml: camera `left`: missing the node `T`"),
        ("rig.yml", "%YAML:1.0\nimage_width_a: 8\nimage_height_a: 8\nCamera_Matrix_a: [ 1, 0, 1, 0, 1, 1, 0, 0, 1 ]\nrvec_a: [ 0, 0 ]\ntvec_a: [ 0, 0, 1 ]\n".into(), "rig.yml: camera `a`: `rvec_a` has 2 values; expected 3"),
        ("rig.yml", "%YAML:1.0\nimage_width_a: 8\nimage_height_a: 8\nCamera_Matrix_a: [ 1, 0, 1, 0, 1, 1, 0, 0, 1 ]\nrvec_a: [ 1e300, 1e300, 1e300 ]\ntvec_a: [ 0, 0, 1 ]\n".into(), "rig.yml: camera `a`: `rvec_a`: does not give a rotation"),
    ];
    for (name, text, want) in cases {
        let file = dir.path().join(name);
        std::fs::write(&file, &text).expect("write");
        let err = read_opencv(&file).expect_err(want).to_string();
        assert!(err.contains(want), "{err}\nshould contain\n{want}");
    }
}

/// A camera of OpenCV's fisheye model (its calibration sample's `fisheye_model: 1`, a
/// `distortion_model` naming it, per camera or in a camera's mapping) is refused: its four
/// coefficients are the equidistant model's and were read as k1 k2 p1 p2, a wrong camera
/// without a word. `fisheye_model: 0` is the standard model and is read.
#[test]
fn opencv_fisheye_calibrations_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mapping =
        "%YAML:1.0\nleft:\n  camera_matrix: [ 1, 0, 1, 0, 1, 1, 0, 0, 1 ]\n  image_width: 8\n  image_height: 8\n  \
                   R: [ 1, 0, 0, 0, 1, 0, 0, 0, 1 ]\n  T: [ 0, 0, 5 ]\n  distortion_model: Fisheye\n";
    let sample = format!("{OPENCV_SAMPLE}rvec: [ 0, 0, 0 ]\ntvec: [ 0, 0, 5 ]\n");
    let cases: [(&str, String, Option<&str>); 5] = [
        (
            "sample.yml",
            format!("{sample}fisheye_model: 1\n"),
            Some("`fisheye_model: 1` marks a camera of OpenCV's fisheye model"),
        ),
        ("sample.yml", format!("{sample}distortion_model: equidistant\n"), Some("`distortion_model: \"equidistant\"`")),
        ("sample.yml", format!("{sample}Fisheye_Model_cam0: \"true\"\n"), Some("`Fisheye_Model_cam0: \"true\"`")),
        ("rig.yml", mapping.to_string(), Some("rig.yml: `distortion_model: \"Fisheye\"`")),
        ("sample.yml", format!("{sample}fisheye_model: 0\n"), None),
    ];
    for (name, text, want) in cases {
        let file = dir.path().join(name);
        std::fs::write(&file, &text).expect("write");
        match want {
            Some(want) => {
                let err = read_opencv(&file).expect_err(want).to_string();
                assert!(err.contains(want) && err.contains("cv::fisheye"), "{err}\nshould contain\n{want}");
            }
            None => assert_eq!(read_opencv(&file).expect("the standard model").len(), 1),
        }
    }
}

/// An `R` written with four decimals is a rotation only up to their rounding, which the
/// camera's check refused: the nearest rotation is taken, within the rounding of the exact one.
#[test]
fn opencv_rotation_written_with_few_digits_is_taken_to_the_nearest_rotation() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (s, c) = (0.5f64, 0.75f64.sqrt());
    let stereo = format!(
        "{STEREO_INTRINSICS}imageSize: [ 640, 480 ]\nR: [ {c:.4}, 0., {s:.4}, 0., 1., 0., {:.4}, 0., {c:.4} ]\nT: [ -120., \
         0., 0. ]\n",
        -s
    );
    let file = dir.path().join("calib.yml");
    std::fs::write(&file, &stereo).expect("write");
    let cams = read_opencv(&file).expect("a rounded rotation reads");
    // R maps world to camera; the pose holds its transpose.
    let exact = DMat3::from_cols_array(&[c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c]);
    let read = cams[1].1.world_from_camera.matrix3;
    let off = (read - exact).to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(off < 1e-4, "{off} from the exact rotation: {read}");
    assert!(fluidnerf_core::camera::orthonormality_error(read) < 1e-12);
}

/// `write_opencv` writes FileStorage XML for `.xml`: the cameras read back the same, with
/// suffixed keys for a rig and plain keys for one camera named after the file.
#[test]
fn opencv_xml_is_written_and_read_back() {
    let dir = tempfile::tempdir().expect("tempdir");
    let original = read_opencv(&fixtures().join("opencv_two_cameras.yml")).expect("reads");
    let file = dir.path().join("rig.xml");
    write_opencv(&file, &original).expect("writes");
    let text = std::fs::read_to_string(&file).expect("read");
    assert!(text.starts_with("<?xml version=\"1.0\"?>\n<opencv_storage>\n"), "{text}");
    assert!(text.contains("<camera_matrix_four type_id=\"opencv-matrix\">"), "{text}");
    let back = read_opencv(&file).expect("reads ours");
    assert_same_cameras(&original, &back);
    for ((_, cam), c) in back.iter().zip(&cases()[1..3]) {
        assert!(worst_projection_error(c, cam) < 1e-3);
    }
    let single = read_opencv(&fixtures().join("cam_single.yml")).expect("reads");
    let file = dir.path().join("cam_single.xml");
    write_opencv(&file, &single).expect("writes");
    assert!(std::fs::read_to_string(&file).expect("read").contains("\n<camera_matrix type_id="));
    assert_same_cameras(&single, &read_opencv(&file).expect("reads"));
}

/// `images.txt` gives each image two lines, the second listing its 2D points (empty when it
/// has none). A file without the points lines is refused at the first image line found where
/// a points line belongs, rather than read as every other image; real files (comments, empty
/// and filled points lines) read as before.
#[test]
fn colmap_images_txt_without_points2d_lines_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("cameras.txt"), "# Camera list\n1 PINHOLE 64 48 50 50 32 24\n").expect("write");
    let lines = [
        "1 1 0 0 0 0 0 10 1 a.png",
        "2 1 0 0 0 0 0 11 1 b.png",
        "3 1 0 0 0 0 0 12 1 c.png",
        "4 1 0 0 0 0 0 13 1 d.png",
    ];
    std::fs::write(dir.path().join("images.txt"), format!("# Image list\n{}\n", lines.join("\n"))).expect("write");
    let err = read_colmap(dir.path()).expect_err("no POINTS2D lines").to_string();
    assert!(
        err.contains("images.txt: line 3: expected the POINTS2D line of image 1 (X Y POINT3D_ID triples), got `2 1 0"),
        "{err}"
    );
    // Points lines that are not whole triples of numbers are refused too.
    for bad in ["1 2", "1 2 x", "1.5 2 0.5"] {
        std::fs::write(dir.path().join("images.txt"), format!("{}\n{bad}\n", lines[0])).expect("write");
        let err = read_colmap(dir.path()).expect_err(bad).to_string();
        assert!(err.contains("line 2: expected the POINTS2D line of image 1"), "{bad}: {err}");
    }
    // Comments, empty and filled points lines, and a last image without its points line read.
    let text = format!(
        "# Image list\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n{}\n\n{}\n# a comment\n37 14 1 10.5 20.25 -1\n{}\n   \n{}\n",
        lines[0], lines[1], lines[2], lines[3]
    );
    std::fs::write(dir.path().join("images.txt"), text).expect("write");
    let cams = read_colmap(dir.path()).expect("reads");
    assert_eq!(cams.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(), ["a.png", "b.png", "c.png", "d.png"]);
}

/// An image without a name (which no image file can match) is refused, naming the image.
#[test]
fn colmap_images_with_an_empty_name_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    colmap_bin_by_hand(dir.path());
    let mut imgs = Vec::new();
    imgs.extend(1u64.to_le_bytes());
    imgs.extend(1i32.to_le_bytes());
    [1.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 10.0].iter().for_each(|v| imgs.extend(v.to_le_bytes()));
    imgs.extend(7i32.to_le_bytes());
    imgs.push(0);
    imgs.extend(0u64.to_le_bytes());
    std::fs::write(dir.path().join("images.bin"), imgs).expect("write");
    let err = read_colmap(dir.path()).expect_err("empty name").to_string();
    assert!(err.contains("images.bin: image id 1 has an empty name"), "{err}");

    let text_dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(text_dir.path().join("cameras.txt"), "1 PINHOLE 64 48 50 50 32 24\n").expect("write");
    std::fs::write(text_dir.path().join("images.txt"), "# Image list\n1 1 0 0 0 0 0 10 1\n\n").expect("write");
    let err = read_colmap(text_dir.path()).expect_err("empty name").to_string();
    assert!(err.contains("images.txt: line 2: image id 1 has an empty name"), "{err}");
}

/// A camera of a multi-camera file whose other nodes are there without its camera matrix is
/// named with the node it lacks, as a camera missing its `T` is, instead of being left out.
#[test]
fn opencv_camera_without_its_camera_matrix_is_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("rig.yml");
    let (k, r) = ("[ 10, 0, 4, 0, 10, 4, 0, 0, 1 ]", "[ 1, 0, 0, 0, 1, 0, 0, 0, 1 ]");
    let suffixed = format!(
        "%YAML:1.0\nimage_width_a: 8\nimage_height_a: 8\ncamera_matrix_a: {k}\nR_a: {r}\nT_a: [ 0, 0, 5 ]\n\
         image_width_b: 8\nimage_height_b: 8\ndistortion_coefficients_b: [ 0, 0, 0, 0, 0 ]\nR_b: {r}\nT_b: [ 0, 0, 6 ]\n"
    );
    std::fs::write(&file, &suffixed).expect("write");
    let err = read_opencv(&file).expect_err("camera b has no camera matrix").to_string();
    assert!(err.contains("rig.yml: camera `b`: missing the node `camera_matrix_b`"), "{err}");
    // Complete, and with a suffix in another letter case (the same camera, not another one).
    let complete = format!("{suffixed}camera_matrix_b: {k}\n").replace("T_a:", "T_A:");
    std::fs::write(&file, complete).expect("write");
    let names: Vec<String> = read_opencv(&file).expect("reads").into_iter().map(|c| c.0).collect();
    assert_eq!(names, ["a", "b"]);
    // A lone node with a suffix of its own is not taken for a camera.
    let with_world = format!("{suffixed}camera_matrix_b: {k}\nT_world: [ 0, 0, 1 ]\n");
    std::fs::write(&file, with_world).expect("write");
    let names: Vec<String> = read_opencv(&file).expect("reads").into_iter().map(|c| c.0).collect();
    assert_eq!(names, ["a", "b"]);

    // One mapping per camera.
    let nested = format!(
        "%YAML:1.0\na:\n   image_width: 8\n   image_height: 8\n   camera_matrix: {k}\n   R: {r}\n   T: [ 0, 0, 5 ]\n\
         b:\n   image_width: 8\n   image_height: 8\n   R: {r}\n   T: [ 0, 0, 6 ]\nnotes:\n   by: me\n"
    );
    std::fs::write(&file, nested).expect("write");
    let err = read_opencv(&file).expect_err("camera b has no camera matrix").to_string();
    assert!(err.contains("rig.yml: camera `b`: missing the node `camera_matrix`"), "{err}");
}

/// A JSON calibration that gives a node twice is refused, as a YAML or XML one is: the last of
/// the two was taken without a word.
#[test]
fn a_json_node_given_twice_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(fixtures().join("opencv_two_cameras.json")).expect("read");
    let twice = text.replacen("\"image_width_four\": 800,", "\"image_width_four\": 640, \"image_width_four\": 800,", 1);
    assert_ne!(twice, text);
    std::fs::write(dir.path().join("twice.json"), &twice).expect("write");
    let err = read_opencv(&dir.path().join("twice.json")).expect_err("a node given twice").to_string();
    assert!(err.contains("twice.json") && err.contains("`image_width_four` is given twice"), "{err}");
    // Nested too.
    let nested = text.replacen("\"rows\": 3,", "\"rows\": 3, \"rows\": 3,", 1);
    std::fs::write(dir.path().join("nested.json"), &nested).expect("write");
    let err = read_opencv(&dir.path().join("nested.json")).expect_err("a node given twice").to_string();
    assert!(err.contains("nested.json") && err.contains("`rows` is given twice"), "{err}");
}

/// A folder without a whole model was refused as missing `cameras.txt` even when it held
/// `cameras.bin` (and `images.txt`), and a COLMAP project given for its model as missing
/// `cameras.txt`. The refusal now says which files the folder holds, and where the model is.
#[test]
fn a_folder_without_a_whole_colmap_model_says_what_it_holds_and_where_the_model_is() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    colmap_bin_by_hand(d);
    std::fs::remove_file(d.join("images.bin")).expect("rm");
    std::fs::copy(fixtures().join("colmap/images.txt"), d.join("images.txt")).expect("copy");
    let err = read_colmap(d).expect_err("cameras.bin with images.txt").to_string();
    assert!(
        err.contains("holds cameras.bin and images.txt alone") && err.contains("cameras.bin with images.bin"),
        "{err}"
    );
    // A COLMAP project: the model is in sparse/0.
    let model = d.join("project/sparse/0");
    std::fs::create_dir_all(&model).expect("mkdir");
    for f in ["cameras.txt", "images.txt"] {
        std::fs::copy(fixtures().join("colmap").join(f), model.join(f)).expect("copy");
    }
    let err = read_colmap(&d.join("project")).expect_err("the project").to_string();
    assert!(err.contains("holds no COLMAP model file") && err.contains("project/sparse/0: give that folder"), "{err}");
    let err = read_colmap(&d.join("project/sparse")).expect_err("sparse").to_string();
    assert!(err.contains("sparse/0: give that folder"), "{err}");
    let err = read_colmap(&d.join("nowhere")).expect_err("missing").to_string();
    assert!(err.contains("nowhere: does not exist"), "{err}");
    assert_eq!(read_colmap(&model).expect("the model").len(), 3);
}

/// Files saved by Windows editors begin with a UTF-8 byte-order mark: an OpenCV YAML file was
/// "not a mapping of named nodes", a COLMAP model's first camera id and a projection matrix's
/// first entry were "not" numbers. The mark is now skipped.
#[test]
fn text_calibrations_with_a_byte_order_mark_are_read() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let bom = |from: &Path, to: &Path| {
        let text = std::fs::read_to_string(from).expect("read");
        std::fs::write(to, format!("\u{feff}{text}")).expect("write");
    };
    bom(&fixtures().join("cam_single.yml"), &d.join("cam_single.yml"));
    let plain = read_opencv(&fixtures().join("cam_single.yml")).expect("reads");
    assert_same_cameras(&read_opencv(&d.join("cam_single.yml")).expect("YAML with a mark"), &plain);
    let model = d.join("colmap");
    std::fs::create_dir_all(&model).expect("mkdir");
    for f in ["cameras.txt", "images.txt"] {
        bom(&fixtures().join("colmap").join(f), &model.join(f));
    }
    std::fs::write(model.join("cameras.txt"), "\u{feff}1 PINHOLE 64 48 50 50 32 24\n2 PINHOLE 64 48 60 60 31.5 23.5\n")
        .expect("write");
    assert_eq!(read_colmap(&model).expect("COLMAP text with a mark").len(), 3);
    let p = d.join("p.txt");
    std::fs::write(&p, "\u{feff}700 0 320 0\n0 700 240 0\n0 0 1 500\n").expect("write");
    let cams = fluidnerf_io::calib::read_projection(&p).expect("a matrix with a mark");
    assert_eq!(cams.len(), 1);
}

/// Each COLMAP camera model's parameters land in their own fields (by hand from COLMAP's
/// `models.h`): one focal length for the SIMPLE models and RADIAL, the principal point moved
/// by −½, the radial and tangential terms in OpenCV's order.
#[test]
fn every_colmap_text_model_maps_its_parameters_to_their_fields() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(
        dir.path().join("cameras.txt"),
        "# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]\n\
         1 SIMPLE_PINHOLE 64 48 50 32 24\n\
         2 PINHOLE 64 48 50 51 30 20\n\
         3 RADIAL 64 48 52 33 25 -0.1 0.02\n\
         4 OPENCV 64 48 53 54 31 21 -0.2 0.03 0.001 -0.002\n\
         5 FULL_OPENCV 64 48 55 56 29 22 -0.3 0.04 0.003 -0.004 0.005 0.1 0.01 0.001\n",
    )
    .expect("write");
    let images: String = (1..=5).map(|i| format!("{i} 1 0 0 0 0 0 10 {i} m{i}.png\n\n")).collect();
    std::fs::write(dir.path().join("images.txt"), images).expect("write");
    let cams = read_colmap(dir.path()).expect("reads");
    let k: Vec<[f64; 4]> =
        cams.iter().map(|(_, c)| [c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy]).collect();
    assert_eq!(
        k,
        [
            [50.0, 50.0, 31.5, 23.5],
            [50.0, 51.0, 29.5, 19.5],
            [52.0, 52.0, 32.5, 24.5],
            [53.0, 54.0, 30.5, 20.5],
            [55.0, 56.0, 28.5, 21.5]
        ]
    );
    let d: Vec<[f64; 8]> = cams
        .iter()
        .map(|(_, c)| {
            let d = c.distortion;
            [d.k1, d.k2, d.p1, d.p2, d.k3, d.k4, d.k5, d.k6]
        })
        .collect();
    assert_eq!(d[0], [0.0; 8]);
    assert_eq!(d[1], [0.0; 8]);
    assert_eq!(d[2], [-0.1, 0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    assert_eq!(d[3], [-0.2, 0.03, 0.001, -0.002, 0.0, 0.0, 0.0, 0.0]);
    assert_eq!(d[4], [-0.3, 0.04, 0.003, -0.004, 0.005, 0.1, 0.01, 0.001]);
    assert!(cams.iter().all(|(_, c)| (c.intrinsics.width, c.intrinsics.height, c.intrinsics.skew) == (64, 48, 0.0)));
    // A model given too few or too many parameters is refused naming how many it takes.
    std::fs::write(dir.path().join("cameras.txt"), "1 RADIAL 64 48 52 33 25 -0.1\n").expect("write");
    std::fs::write(dir.path().join("images.txt"), "1 1 0 0 0 0 0 10 1 m1.png\n\n").expect("write");
    let e = read_colmap(dir.path()).expect_err("too few").to_string();
    assert!(e.contains("cameras.txt: line 1: RADIAL takes 5 parameters, got 4"), "{e}");
}
