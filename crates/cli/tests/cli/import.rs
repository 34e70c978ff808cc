//! End-to-end tests of `fluidnerf import` from OpenCV, COLMAP and Metashape calibrations, in a
//! temporary directory.

#[path = "../../../io/tests/common/metashape.rs"]
mod metashape_xml;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Camera, Distortion, Image, Intrinsics};
use fluidnerf_io::calib::write_opencv;
use fluidnerf_io::image::write_png16_counts;
use fluidnerf_io::scene::load_scene;

fn fluidnerf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf")).args(args).output().expect("runs fluidnerf")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Three cameras on a ring around the origin looking at a 20 mm box, with distortion.
fn rig() -> Vec<(String, Camera)> {
    let k = Intrinsics { width: 32, height: 24, fx: 40.0, fy: 40.5, cx: 15.25, cy: 11.5, skew: 0.0 };
    (0..3)
        .map(|c| {
            let a = c as f64 / 3.0 * std::f64::consts::TAU;
            let mut cam = Camera::look_at(k, DVec3::new(90.0 * a.cos(), 90.0 * a.sin(), 20.0), DVec3::ZERO, DVec3::Z);
            cam.distortion = Distortion { k1: -0.05 * c as f64, p1: 1e-4, ..Default::default() };
            (format!("cam{c}"), cam)
        })
        .collect()
}

/// [`rig`]'s calibration (`DIR/rig.yml`) and a still image of each camera (`DIR/images/NAME.png`).
fn rig_with_stills(dir: &Path) -> (PathBuf, PathBuf) {
    let calib = dir.join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let images = dir.join("images");
    for (n, _) in rig() {
        image(&images, &format!("{n}.png"));
    }
    (calib, images)
}

/// A 32 × 24 image of a few counts, not one value throughout (which `info` and every run refuse).
fn image(dir: &Path, name: &str) {
    let img = Image::from_vec(32, 24, (0..32 * 24).map(|i| (7 + i % 5) as f32).collect());
    write_png16_counts(&dir.join(name), &img).expect("writes image");
}

fn assert_same(a: &Camera, b: &Camera) {
    assert_eq!(a.intrinsics, b.intrinsics);
    assert_eq!(a.distortion, b.distortion);
    let d = (a.world_from_camera.matrix3 - b.world_from_camera.matrix3).to_cols_array();
    assert!(d.iter().all(|e| e.abs() < 1e-12));
    assert!((a.centre() - b.centre()).length() < 1e-9);
}

/// The fixture's MJPEG recording of four frames (32 × 24 px, 10 frames per second).
fn ramp_video() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video/ramp_mjpeg.avi")
}

/// `import --opencv calib --images videos --aabb … EXTRA… -o out`: the rig's recordings.
fn import_recordings(calib: &Path, videos: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["import", "--opencv", s(calib), "--images", s(videos), "--aabb", "-10,-10,-10,10,10,10"];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["-o", s(out)]);
    fluidnerf(&args)
}

/// [`video_rig`] with the ramp video as every camera's recording.
fn ramp_video_rig() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let (dir, calib, videos) = video_rig();
    for (n, _) in rig() {
        std::fs::copy(ramp_video(), videos.join(format!("{n}.avi"))).expect("copies the fixture");
    }
    (dir, calib, videos)
}

/// A temporary folder with the rig's calibration (`rig.yml`) and an empty `videos/` folder
/// for its cameras' recordings: the folder, the calibration and the videos' folder.
fn video_rig() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let videos = dir.path().join("videos");
    std::fs::create_dir_all(&videos).expect("mkdir");
    (dir, calib, videos)
}

#[test]
fn opencv_calibration_and_images_become_a_scene() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    let cams = rig();
    write_opencv(&calib, &cams).expect("writes calibration");
    let images = dir.path().join("scene/images");
    for (n, _) in &cams {
        image(&images, &format!("{n}.png"));
    }
    let out = dir.path().join("scene");
    let args =
        ["import", "--opencv", s(&calib), "--images", s(&images), "--aabb", "-10,-10,-10,10,10,10", "-o", s(&out)];
    let o = fluidnerf(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("imported 3 frames of 3 cameras"));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 3);
    for (f, (n, c)) in scene.frames.iter().zip(&cams) {
        assert_eq!(f.camera_name.as_deref(), Some(n.as_str()));
        assert_eq!(f.file_path, PathBuf::from(format!("images/{n}.png")), "relative to the scene");
        assert_same(&f.camera, c);
    }
    assert!(out.join("import.json").is_file());
    let info = fluidnerf(&["info", s(&out)]);
    assert!(info.status.success(), "{}", stderr(&info));

    // A second import into the same folder needs --force.
    let again = fluidnerf(&args);
    assert_eq!(again.status.code(), Some(1));
    assert!(stderr(&again).contains("--force"), "{}", stderr(&again));
    let mut forced = args.to_vec();
    forced.push("--force");
    assert!(fluidnerf(&forced).status.success());
    // So does one into a folder holding an import.json of the user's.
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).expect("mkdir");
    std::fs::write(other.join("import.json"), "mine").expect("writes");
    let mut into_other = args.to_vec();
    *into_other.last_mut().expect("out") = s(&other);
    let o = fluidnerf(&into_other);
    assert!(!o.status.success() && stderr(&o).contains("import.json"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(other.join("import.json")).expect("kept"), "mine");
}

#[test]
fn opencv_time_series_folders() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("calib");
    let cams = rig();
    for c in &cams {
        write_opencv(&calib.join(format!("{}.json", c.0)), std::slice::from_ref(c)).expect("writes calibration");
    }
    let images = dir.path().join("images");
    for (n, _) in &cams {
        for t in 0..2 {
            image(&images.join(n), &format!("t{t}.png"));
        }
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &images, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 6);
    assert_eq!(scene.times(), vec![0.0, 1.0]);
    assert!(scene.frames[0].file_path.is_absolute(), "images outside the scene folder keep absolute paths");
}

/// A time series numbered without leading zeros (`img_1`, `img_2`, …, `img_10`) is instant
/// n in the order of its numbers: text order gave `img_10` the second instant and `img_2` the
/// fourth, scrambling the recording's time without a word.
#[test]
fn a_time_series_numbered_without_leading_zeros_keeps_its_order() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let images = dir.path().join("images");
    for (n, _) in &rig() {
        for t in [1, 2, 3, 10, 11] {
            image(&images.join(n), &format!("img_{t}.png"));
        }
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &images, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let order = series_order(&out, "cam1");
    let want: Vec<(String, f64)> =
        [1, 2, 3, 10, 11].iter().enumerate().map(|(t, n)| (format!("img_{n}.png"), t as f64)).collect();
    assert_eq!(order, want);
}

/// The images of `camera` in the scene imported into `out`, by file name, with their instants.
fn series_order(out: &Path, camera: &str) -> Vec<(String, f64)> {
    let scene = load_scene(out).expect("loads");
    scene
        .frames
        .iter()
        .filter(|f| f.camera_name.as_deref() == Some(camera))
        .map(|f| (f.file_path.file_name().expect("a file").to_string_lossy().into_owned(), f.time.expect("timed")))
        .collect()
}

/// A time series named by decimal times (`t_1.25ms`, `t_1.5ms`) is instant n in the order of
/// those numbers: digit runs compared as integers put `t_1.5ms` (5) before `t_1.25ms` (25).
#[test]
fn a_time_series_named_by_decimal_times_keeps_its_order() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let images = dir.path().join("images");
    let names = ["t_0.75ms.png", "t_1ms.png", "t_1.25ms.png", "t_1.5ms.png", "t_2ms.png", "t_10ms.png"];
    for (n, _) in &rig() {
        for name in names {
            image(&images.join(n), name);
        }
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &images, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("minus sign"), "{}", stderr(&o));
    let order = series_order(&out, "cam2");
    let want: Vec<(String, f64)> = names.iter().enumerate().map(|(t, n)| (n.to_string(), t as f64)).collect();
    assert_eq!(order, want);
}

/// A '-' between a letter and a number (`t-1`) is read as a dash, not a minus sign (`cam-1`,
/// `frame-2` are names, not negative numbers): a series that also holds the same letters
/// before an unsigned number (`t0`, `t1`), where the '-' reads as a sign, would be put out of
/// time order without a word, so the import warns, naming the camera and the names.
#[test]
fn names_whose_dash_may_be_a_minus_sign_are_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let images = dir.path().join("images");
    for (n, _) in &rig() {
        for name in ["t-2.png", "t-1.png", "t0.png", "t1.png"] {
            image(&images.join(n), name);
        }
    }
    let o = import_recordings(&calib, &images, &dir.path().join("scene"), &[]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("cam0, cam1, cam2") && e.contains("t-1.png") && e.contains("t0.png"), "{e}");
    assert!(e.contains("minus sign"), "{e}");
    assert_eq!(e.matches("minus sign").count(), 1, "one warning for the cameras: {e}");

    // Only dashes (`frame-1`, `frame-2`, …) or signs after a separator (`t_-1`): no warning.
    for (k, names) in
        [["frame-1.png", "frame-2.png", "frame-10.png"], ["t_-1.png", "t_0.png", "t_1.png"]].iter().enumerate()
    {
        let images = dir.path().join(format!("images{k}"));
        for (n, _) in &rig() {
            for name in names {
                image(&images.join(n), name);
            }
        }
        let o = import_recordings(&calib, &images, &dir.path().join(format!("scene{k}")), &[]);
        assert!(o.status.success() && !stderr(&o).contains("minus sign"), "{names:?}: {}", stderr(&o));
    }
}

#[test]
fn unmatched_cameras_and_images_are_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.json");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let images = dir.path().join("images");
    image(&images, "cam0.png");
    image(&images, "cam1.png");
    let out = dir.path().join("scene");
    let run = |extra: &[&str]| {
        let mut a = vec!["import", "--opencv", s(&calib), "--images", s(&images), "--aabb", "-10,-10,-10,10,10,10"];
        a.extend_from_slice(&["-o", s(&out)]);
        a.extend_from_slice(extra);
        fluidnerf(&a)
    };
    let o = run(&[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("cam2") && stderr(&o).contains("no image found"), "{}", stderr(&o));
    // A folder named like the image is named as what it is.
    std::fs::create_dir(images.join("cam2.png")).expect("mkdir");
    let o = run(&[]);
    assert!(stderr(&o).contains("cam2.png is not a file"), "{}", stderr(&o));
    std::fs::remove_dir(images.join("cam2.png")).expect("rmdir");
    // Extensions match in any case, as cameras write them.
    image(&images, "cam2.PNG");
    image(&images, "stray.png");
    let o = run(&[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("stray.png") && stderr(&o).contains("--skip-uncalibrated"), "{}", stderr(&o));
    let o = run(&["--skip-uncalibrated"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // An image of the wrong size.
    write_png16_counts(&images.join("cam1.png"), &Image::zeros(16, 24)).expect("writes");
    let o = run(&["--skip-uncalibrated", "--force"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("cam1.png") && stderr(&o).contains("16x24"), "{}", stderr(&o));
    // A box no camera sees.
    let mut a = vec!["import", "--opencv", s(&calib), "--images", s(&images), "--aabb", "500,500,500,510,510,510"];
    a.extend_from_slice(&["-o", s(&out), "--force", "--skip-uncalibrated"]);
    let o = fluidnerf(&a);
    assert!(stderr(&o).contains("does not see the reconstruction box"), "{}", stderr(&o));
}

#[test]
fn colmap_model_becomes_a_scene() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/colmap");
    let images = dir.path().join("images");
    for n in ["front.png", "side.png", "radial.png"] {
        write_png16_counts(&images.join(n), &Image::zeros(64, 48)).expect("writes");
    }
    let out = dir.path().join("scene");
    let o = fluidnerf(&[
        "import",
        "--colmap",
        s(&model),
        "--images",
        s(&images),
        "--aabb",
        "-1,-1,-1,1,1,1",
        "--units",
        "m",
        "-o",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.units, "m");
    assert_eq!(scene.frames.len(), 3);
    assert!((scene.frames[0].camera.centre() - DVec3::new(0.0, 0.0, -10.0)).length() < 1e-12);
    assert_eq!(scene.frames[0].camera.intrinsics.cx, 31.5, "COLMAP's +0.5 pixel centres are converted");
    let text = std::fs::read_to_string(out.join("transforms.json")).expect("reads");
    assert!(text.contains("\"cx\": 32.0"), "transforms.json uses nerfstudio's (= COLMAP's) convention again");
    // A unit that cannot label an axis is refused before anything is written.
    let other = dir.path().join("other");
    let mut a = vec!["import", "--colmap", s(&model), "--images", s(&images), "--aabb", "-1,-1,-1,1,1,1"];
    a.extend_from_slice(&["--units", "", "-o", s(&other)]);
    let o = fluidnerf(&a);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--units") && stderr(&o).contains("must be named"), "{}", stderr(&o));
    assert!(!other.exists());
}

/// A NeRF-style `transforms.json` (field of view, no size, no extension, no box) of six
/// cameras around a glowing ball in 8-bit PNGs: import estimates a box holding the ball, prints
/// it, writes it, and records the linearisation.
#[test]
fn transforms_json_without_a_box_gets_an_estimated_one() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("nerf");
    let (ball, radius) = (DVec3::new(1.0, -0.5, 0.5), 1.5);
    let angle: f64 = 0.8;
    let (w, h) = (40usize, 30usize);
    let focal = 0.5 * w as f64 / (0.5 * angle).tan();
    let k = Intrinsics { width: 40, height: 30, fx: focal, fy: focal, cx: 19.5, cy: 14.5, skew: 0.0 };
    let mut frames = Vec::new();
    for c in 0..6 {
        let a = c as f64 / 6.0 * std::f64::consts::TAU;
        let eye = DVec3::new(25.0 * a.cos(), 25.0 * a.sin(), if c % 2 == 0 { 8.0 } else { -6.0 });
        let cam = Camera::look_at(k, eye, DVec3::ZERO, DVec3::Z);
        let mut pixels = vec![3u8; w * h];
        for row in 0..h {
            for col in 0..w {
                let ray = cam.pixel_ray(col as f64, row as f64).expect("ray");
                if (ray.at((ball - ray.origin).dot(ray.dir)) - ball).length() < radius {
                    pixels[row * w + col] = 200;
                }
            }
        }
        std::fs::create_dir_all(src.join("train")).expect("mkdir");
        image::GrayImage::from_raw(w as u32, h as u32, pixels)
            .expect("buffer")
            .save(src.join(format!("train/r_{c}.png")))
            .expect("saves");
        let m = fluidnerf_io::scene::world_from_camera_to_opengl_c2w(&cam.world_from_camera);
        frames.push(serde_json::json!({"file_path": format!("./train/r_{c}"), "rotation": 0.1, "transform_matrix": m}));
    }
    let file = src.join("transforms.json");
    let v = serde_json::json!({"camera_angle_x": angle, "frames": frames});
    std::fs::write(&file, v.to_string()).expect("writes");

    // Loading it as a scene says how to get a box.
    let info = fluidnerf(&["info", s(&src)]);
    assert_eq!(info.status.code(), Some(1));
    assert!(stderr(&info).contains("no `aabb`") && stderr(&info).contains("--transforms"), "{}", stderr(&info));

    let out = dir.path().join("scene");
    let o = fluidnerf(&["import", "--transforms", s(&file), "--linearisation", "srgb", "-o", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(stdout.contains("estimated the box from the bright pixels seen by every camera: --aabb "), "{stdout}");
    assert!(stdout.contains("imported 6 frames"), "{stdout}");
    let scene = load_scene(&out).expect("loads");
    for a in 0..3 {
        let (lo, hi) = (scene.aabb.min[a], scene.aabb.max[a]);
        assert!(lo <= ball[a] - radius && hi >= ball[a] + radius, "axis {a}: {lo} .. {hi} must hold the ball");
        assert!(hi - lo < 4.0 * radius, "axis {a}: {lo} .. {hi} is far larger than the ball");
    }
    assert_eq!(scene.frames[0].file_path, PathBuf::from(s(&src.join("train/r_0.png"))));
    assert_eq!(scene.frames[0].camera.intrinsics.width, 40);
    let text = std::fs::read_to_string(out.join("transforms.json")).expect("reads");
    assert!(text.contains("\"linearisation\": \"srgb\""), "{text}");
    assert!(fluidnerf(&["info", s(&out)]).status.success());

    // A given box wins.
    let o = fluidnerf(&["import", "--transforms", s(&file), "--aabb", "-3,-3,-3,3,3,3", "-o", s(&out), "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(load_scene(&out).expect("loads").aabb.max, DVec3::splat(3.0));
    assert!(stderr(&o).contains("--linearisation srgb"), "8-bit images without a choice are warned about");

    // nerfstudio's mask_path, a background and a flat field are carried over (paths from the
    // new scene);
    // --holdout takes image names (these frames name no camera); an unknown name is refused.
    let mask = image::GrayImage::from_pixel(w as u32, h as u32, image::Luma([255u8]));
    mask.save(src.join("mask_0.png")).expect("saves");
    let mut v = v;
    v["frames"][0]["mask_path"] = serde_json::json!("mask_0.png");
    v["background"] = serde_json::json!(2.0);
    image::GrayImage::from_pixel(w as u32, h as u32, image::Luma([200u8])).save(src.join("flat.png")).expect("saves");
    v["flat_field"] = serde_json::json!("flat.png");
    std::fs::write(&file, v.to_string()).expect("writes");
    let o = fluidnerf(&["import", "--transforms", s(&file), "--holdout", "r_3", "-o", s(&out), "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert!(scene.frames[3].holdout && !scene.frames[2].holdout);
    let rec = fluidnerf_io::scene::recorded(&scene).expect("recorded");
    assert_eq!(rec.frames[0].mask_path.as_deref(), Some(src.join("mask_0.png").as_path()));
    assert_eq!(rec.frames[5].background, fluidnerf_io::scene::Background::Constant(2.0));
    assert_eq!(rec.frames[5].flat_field, vec![src.join("flat.png")]);
    assert!(fluidnerf_io::scene::load_preprocessed(&scene).expect("preprocesses").masks[0].is_some());
    let o = fluidnerf(&["import", "--transforms", s(&file), "--holdout", "r_9", "-o", s(&out), "--force"]);
    assert!(!o.status.success() && stderr(&o).contains("no camera or image named `r_9`"), "{}", stderr(&o));
}

/// A binary COLMAP model whose image names say `.jpg` while the folder holds `.png` files.
#[test]
fn colmap_binary_model_with_other_extensions() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = dir.path().join("sparse/0");
    let cams: Vec<(String, Camera)> = rig().into_iter().map(|(n, c)| (format!("{n}.jpg"), c)).collect();
    std::fs::create_dir_all(&model).expect("mkdir");
    fluidnerf_io::calib::write_colmap_bin(&model, &cams).expect("writes model");
    let images = dir.path().join("images");
    for (n, _) in rig() {
        image(&images, &format!("{n}.png"));
    }
    let out = dir.path().join("scene");
    let o = fluidnerf(&[
        "import",
        "--colmap",
        s(&model),
        "--images",
        s(&images),
        "--aabb",
        "-10,-10,-10,10,10,10",
        "-o",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 3);
    for (f, (_, c)) in scene.frames.iter().zip(&cams) {
        assert!(f.file_path.to_string_lossy().ends_with(".png"), "{}", f.file_path.display());
        assert_eq!(f.camera.intrinsics, c.intrinsics);
        assert!((f.camera.centre() - c.centre()).length() < 1e-9);
    }
    // An image missing under every extension is named.
    std::fs::remove_file(images.join("cam1.png")).expect("removes");
    let o = fluidnerf(&[
        "import",
        "--colmap",
        s(&model),
        "--images",
        s(&images),
        "--aabb",
        "-10,-10,-10,10,10,10",
        "-o",
        s(&out),
        "--force",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("cam1.jpg") && stderr(&o).contains("other extensions"), "{}", stderr(&o));
}

/// A COLMAP model whose images sit in a folder per camera (`left/0001.png`, as COLMAP's
/// `single_camera_per_folder` reads them): the folders are not taken for uncalibrated entries,
/// an image in them that the model lacks is, and a name through `..` is the image it names.
#[test]
fn colmap_model_with_images_in_subfolders() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = dir.path().join("sparse/0");
    let names = ["left/a.png", "left/b.png", "../images/right/c.png"];
    let cams: Vec<(String, Camera)> = rig().into_iter().zip(names).map(|((_, c), n)| (n.to_string(), c)).collect();
    std::fs::create_dir_all(&model).expect("mkdir");
    fluidnerf_io::calib::write_colmap_bin(&model, &cams).expect("writes model");
    let images = dir.path().join("images");
    for sub in ["left", "right"] {
        std::fs::create_dir_all(images.join(sub)).expect("mkdir");
    }
    for n in ["left/a.png", "left/b.png", "right/c.png"] {
        image(&images, n);
    }
    let out = dir.path().join("scene");
    let import = |force: bool| {
        let mut a = vec!["import", "--colmap", s(&model), "--images", s(&images), "--aabb", "-10,-10,-10,10,10,10"];
        a.extend(["-o", s(&out)]);
        if force {
            a.push("--force");
        }
        fluidnerf(&a)
    };
    let o = import(false);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(load_scene(&out).expect("loads").frames.len(), 3);
    image(&images, "left/extra.png");
    let o = import(true);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(err.contains("no calibrated camera for 1 entr(ies)") && err.contains("left/extra.png"), "{err}");
    std::fs::remove_file(images.join("left/extra.png")).expect("removes");

    // A name that leads out of the images folder was followed there (an absolute path, or one
    // that climbs out): refused, naming it.
    let elsewhere = dir.path().join("elsewhere");
    std::fs::create_dir_all(&elsewhere).expect("mkdir");
    image(&elsewhere, "c.png");
    let outside = elsewhere.join("c.png").display().to_string();
    for name in ["../elsewhere/c.png", outside.as_str()] {
        let cams: Vec<(String, Camera)> =
            rig().into_iter().zip(["left/a.png", "left/b.png", name]).map(|((_, c), n)| (n.to_string(), c)).collect();
        fluidnerf_io::calib::write_colmap_bin(&model, &cams).expect("writes model");
        let o = import(true);
        assert_eq!(o.status.code(), Some(1), "{name}");
        let err = stderr(&o);
        assert!(err.contains(&format!("the name {name:?} leads out of the images folder")), "{err}");
    }
}

/// A transforms.json whose frames are videos: each video's mask goes with every frame decoded
/// from it, and the file's other keys (`flow_axis`) are kept.
#[test]
fn transforms_json_of_videos_keeps_masks_and_keys() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("rig");
    std::fs::create_dir_all(&src).expect("mkdir");
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video");
    let mut frames = Vec::new();
    for (n, cam) in rig() {
        std::fs::copy(fixtures.join("ramp_mjpeg.avi"), src.join(format!("{n}.avi"))).expect("copies the fixture");
        let m = fluidnerf_io::scene::world_from_camera_to_opengl_c2w(&cam.world_from_camera);
        let mut f = serde_json::json!({"file_path": format!("{n}.avi"), "camera": n, "transform_matrix": m});
        if n == "cam1" {
            f["mask_path"] = "mask.png".into();
        }
        frames.push(f);
    }
    image::GrayImage::from_fn(32, 24, |x, _| image::Luma([if x < 16 { 255 } else { 0 }]))
        .save(src.join("mask.png"))
        .expect("saves");
    let v = serde_json::json!({
        "w": 32, "h": 24, "fl_x": 40.0, "fl_y": 40.5, "cx": 15.25, "cy": 11.5,
        "aabb": [[-10, -10, -10], [10, 10, 10]], "flow_axis": [0, 0, 1], "frames": frames,
    });
    std::fs::write(src.join("transforms.json"), v.to_string()).expect("writes");
    let out = dir.path().join("scene");
    let o = fluidnerf(&["import", "--transforms", s(&src), "--video-frames", "0..2", "-o", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 6, "two frames of three videos");
    let recording = fluidnerf_io::scene::recorded(&scene).expect("reads the keys");
    assert_eq!(recording.flow_axis, Some(DVec3::Z));
    for (f, r) in scene.frames.iter().zip(&recording.frames) {
        let masked = f.camera_name.as_deref() == Some("cam1");
        assert_eq!(r.mask_path.is_some(), masked, "{}", f.file_path.display());
    }
}

/// A transforms.json whose frames name one video twice is refused (both cameras would get the
/// same pictures, as two frames of one image would, which a scene refuses), and a frame's own
/// `time` beside a video, replaced by the recording's times, is warned of.
#[test]
fn transforms_json_of_videos_refuses_a_shared_video_and_warns_of_a_frames_time() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("rig");
    std::fs::create_dir_all(&src).expect("mkdir");
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video");
    let write = |edit: &dyn Fn(&mut Vec<serde_json::Value>)| {
        let mut frames = Vec::new();
        for (n, cam) in rig() {
            std::fs::copy(fixtures.join("ramp_mjpeg.avi"), src.join(format!("{n}.avi"))).expect("copies the fixture");
            let m = fluidnerf_io::scene::world_from_camera_to_opengl_c2w(&cam.world_from_camera);
            frames.push(serde_json::json!({"file_path": format!("{n}.avi"), "camera": n, "transform_matrix": m}));
        }
        edit(&mut frames);
        let v = serde_json::json!({
            "w": 32, "h": 24, "fl_x": 40.0, "fl_y": 40.5, "cx": 15.25, "cy": 11.5,
            "aabb": [[-10, -10, -10], [10, 10, 10]], "frames": frames,
        });
        std::fs::write(src.join("transforms.json"), v.to_string()).expect("writes");
    };
    let out = dir.path().join("scene");
    let import = || fluidnerf(&["import", "--transforms", s(&src), "--video-frames", "0..2", "-o", s(&out), "--force"]);
    write(&|frames| frames[1]["file_path"] = frames[0]["file_path"].clone());
    let o = import();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("camera cam0 and camera cam1 both name the video") && err.contains("cam0.avi"), "{err}");
    write(&|frames| frames[2]["time"] = 3.0.into());
    let o = import();
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("camera cam2 (") && err.contains("its `time` 3 is not used"), "{err}");
    assert!(load_scene(&out).expect("loads").frames.iter().all(|f| f.time.is_some_and(|t| t < 3.0)));
}

/// One video per camera (two full-range MJPEG AVIs, one limited-range): each kept frame
/// becomes a float TIFF in `frames/<camera>/` with its time; `--video-frames`,
/// `--video-every` and `--video-time-offset` select and shift; `import.json` records how each
/// video was read.
#[test]
fn opencv_cameras_with_videos() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    let cams = rig();
    write_opencv(&calib, &cams).expect("writes calibration");
    let images = dir.path().join("videos");
    std::fs::create_dir_all(&images).expect("mkdir");
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video");
    for (n, _) in &cams {
        let video = if n == "cam2" { "ramp_mjpeg_limited.avi" } else { "ramp_mjpeg.avi" };
        std::fs::copy(fixtures.join(video), images.join(format!("{n}.avi"))).expect("copies the fixture");
    }
    let out = dir.path().join("scene");
    let o = import_recordings(
        &calib,
        &images,
        &out,
        &["--video-frames", "1..", "--video-every", "2", "--video-time-offset", "-0.1"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 6, "frames 1 and 3 of three cameras");
    let times = scene.times();
    assert_eq!(times.len(), 2, "{times:?}");
    assert!((times[0] - 0.0).abs() < 1e-9 && (times[1] - 0.2).abs() < 1e-9, "{times:?}");
    for cam in ["cam1", "cam2"] {
        let f = scene
            .frames
            .iter()
            .find(|f| f.camera_name.as_deref() == Some(cam) && f.time.is_some_and(|t| (t - 0.2).abs() < 1e-9))
            .expect("the camera's second kept frame");
        assert_eq!(f.file_path, PathBuf::from(format!("frames/{cam}/000001.tif")));
        let img = fluidnerf_io::image::read_image(&out.join(&f.file_path)).expect("reads the frame");
        // Pixel (x, y) of frame 3 is 20 + 4x + 3y + 30, within JPEG error (and, for the
        // limited-range video, its 255/219 stretch).
        let want = 20.0 + 4.0 * 5.0 + 3.0 * 7.0 + 30.0;
        assert!((img.get(5, 7) - want).abs() <= 4.0, "{cam}: {} for {want}", img.get(5, 7));
    }
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("import.json")).expect("import.json"))
            .expect("import.json is JSON");
    let videos = record["videos"].as_array().expect("videos recorded");
    assert_eq!(videos.len(), 3);
    for v in videos {
        let limited = v["camera"] == "cam2";
        assert_eq!(v["decoder"], "mjpeg-avi");
        assert_eq!(v["range"], if limited { "limited" } else { "full" }, "{v}");
        assert_eq!(v["range_source"], if limited { "file" } else { "jpeg-default" }, "{v}");
        assert_eq!((v["frames_in_file"].as_u64(), v["frames_kept"].as_u64()), (Some(4), Some(2)), "{v}");
        assert_eq!(v["clipped_pixels"], 0, "{v}");
    }
    assert_eq!(record["video_time_offset"], -0.1);

    // Flags are checked before any work; a broken video names its camera and file.
    let bad = fluidnerf(&[
        "import",
        "--opencv",
        s(&calib),
        "--images",
        s(&images),
        "--video-frames",
        "3..2",
        "-o",
        s(&dir.path().join("x")),
    ]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(stderr(&bad).contains("--video-frames 3..2"), "{}", stderr(&bad));
    let bad =
        fluidnerf(&["import", "--opencv", s(&calib), "--images", s(&images), "--video-range", "tv-ish", "-o", "x"]);
    assert!(!bad.status.success() && stderr(&bad).contains("expected auto, full or limited"), "{}", stderr(&bad));
    std::fs::write(images.join("cam1.avi"), "not a video").expect("write");
    let bad = import_recordings(&calib, &images, &dir.path().join("y"), &[]);
    assert_eq!(bad.status.code(), Some(1));
    let err = stderr(&bad);
    assert!(err.contains("camera cam1") && err.contains("cam1.avi") && err.contains("not a video file"), "{err}");
}

/// A YAML calibration whose nested aliases would expand to millions of nodes is refused at
/// once, naming the file, instead of filling the memory.
#[test]
fn a_yaml_alias_bomb_is_refused_quickly() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let mut text = String::from("%YAML 1.2\n---\na: &a [x]\n");
    // About 10⁶ nodes once expanded; each level more multiplies that by 9.
    for i in 0..6 {
        let prev = if i == 0 { "a".to_string() } else { format!("l{}", i - 1) };
        text.push_str(&format!("l{i}: &l{i} [{}]\n", vec![format!("*{prev}"); 9].join(",")));
    }
    let bomb = tmp.path().join("bomb.yml");
    std::fs::write(&bomb, text).expect("writes");
    let images = tmp.path().join("images");
    std::fs::create_dir_all(&images).expect("mkdir");
    let out = tmp.path().join("out");
    let started = std::time::Instant::now();
    let o = fluidnerf(&[
        "import",
        "--opencv",
        s(&bomb),
        "--images",
        s(&images),
        "-o",
        s(&out),
        "--aabb",
        "-20,-20,-20,20,20,20",
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("bomb.yml") && e.contains("aliases"), "{e}");
    assert!(started.elapsed().as_secs_f64() < 20.0, "took {:?}", started.elapsed());
    assert!(!out.join("transforms.json").exists());
}

/// A camera with both an image and a folder of images is refused as matching several inputs,
/// naming both, rather than blaming the image on no camera.
#[test]
fn a_camera_with_an_image_and_a_folder_matches_several_inputs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let images = dir.path().join("images");
    for n in ["cam0.png", "cam1.png", "cam2.png", "cam2/t0.png"] {
        image(&images, n);
    }
    let out = dir.path().join("scene");
    let o = import_opencv(&calib, &images, &out);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(err.contains("camera cam2 matches several inputs"), "{err}");
    let folder = format!("the folder {} and", images.join("cam2").display());
    assert!(err.contains(&folder) && err.contains(s(&images.join("cam2.png"))), "{err}");
    assert!(!err.contains("no calibrated camera"), "{err}");
    assert!(!out.exists(), "nothing is created for a refused import");
}

/// A failed import leaves nothing it created: the decoded frames of the cameras read before a
/// broken video are removed (with OUT, when the import made it), so the rerun after the fix
/// needs no --force; a folder that existed keeps what was in it.
#[test]
fn a_failed_import_leaves_nothing_behind() {
    let (dir, calib, videos) = video_rig();
    let bytes = std::fs::read(ramp_video()).expect("reads the fixture");
    for n in ["cam0", "cam1"] {
        std::fs::write(videos.join(format!("{n}.avi")), &bytes).expect("writes");
    }
    // cam2's video is cut short: cam0's and cam1's frames are written before it fails.
    std::fs::write(videos.join("cam2.avi"), &bytes[..3000]).expect("writes");
    let run = |out: &Path| import_recordings(&calib, &videos, out, &[]);
    let out = dir.path().join("new/scene");
    let o = run(&out);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("camera cam2"), "{}", stderr(&o));
    assert!(!dir.path().join("new").exists(), "the folders the import made are removed");

    // Into a folder of the user's: it and its file stay, the frames go.
    let mine = dir.path().join("mine");
    std::fs::create_dir_all(mine.join("frames")).expect("mkdir");
    std::fs::write(mine.join("notes.txt"), "keep me").expect("writes");
    let o = run(&mine);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::read_to_string(mine.join("notes.txt")).expect("kept"), "keep me");
    assert!(mine.join("frames").is_dir(), "a folder that existed stays");
    let left: Vec<_> = std::fs::read_dir(mine.join("frames")).expect("lists").collect();
    assert!(left.is_empty(), "{left:?}");

    // With the video fixed, the same import succeeds without --force.
    std::fs::write(videos.join("cam2.avi"), &bytes).expect("writes");
    let o = run(&out);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(load_scene(&out).expect("loads").frames.len(), 12);

    // An early failure (an unknown --holdout) creates no folder either.
    let early = dir.path().join("early");
    let o = fluidnerf(&["import", "--opencv", s(&calib), "--images", s(&videos), "--holdout", "cam9", "-o", s(&early)]);
    assert!(!o.status.success() && stderr(&o).contains("no camera or image named `cam9`"), "{}", stderr(&o));
    assert!(!early.exists());
}

/// A transforms.json whose `fl_x` and `camera_angle_x` disagree is read with `fl_x`, with a
/// warning naming both (once for the top level, per frame for a frame's own keys); agreeing
/// keys give no warning.
#[test]
fn disagreeing_focal_length_and_field_of_view_are_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("src");
    let cams = rig();
    let mut frames = Vec::new();
    for (n, cam) in &cams {
        image(&src, &format!("{n}.png"));
        let m = fluidnerf_io::scene::world_from_camera_to_opengl_c2w(&cam.world_from_camera);
        frames.push(serde_json::json!({"file_path": format!("{n}.png"), "transform_matrix": m}));
    }
    let agreeing = 2.0 * (16.0f64 / 40.0).atan();
    let mut v = serde_json::json!({
        "w": 32, "h": 24, "fl_x": 40.0, "fl_y": 40.5, "cx": 15.75, "cy": 12.0,
        "aabb": [[-10, -10, -10], [10, 10, 10]], "camera_angle_x": 1.0, "frames": frames,
    });
    let file = src.join("transforms.json");
    let out = dir.path().join("scene");
    let import = |v: &serde_json::Value| {
        std::fs::write(&file, v.to_string()).expect("writes");
        let o = fluidnerf(&["import", "--transforms", s(&file), "-o", s(&out), "--force"]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert_eq!(load_scene(&out).expect("loads").frames[0].camera.intrinsics.fx, 40.0, "fl_x is used");
        stderr(&o)
    };
    let err = import(&v);
    let warning = "top level: `fl_x` 40 and `camera_angle_x` 1 disagree";
    assert_eq!(err.matches(warning).count(), 1, "{err}");
    assert!(err.contains("using `fl_x`") && err.contains("transforms.json"), "{err}");

    v["camera_angle_x"] = serde_json::json!(agreeing);
    let err = import(&v);
    assert!(!err.contains("disagree"), "{err}");

    v["frames"][1]["camera_angle_x"] = serde_json::json!(0.5);
    let err = import(&v);
    assert!(err.contains("frame 1 (cam1.png): `fl_x` 40 and `camera_angle_x` 0.5 disagree"), "{err}");
    assert_eq!(err.matches("disagree").count(), 1, "{err}");
}

/// One calibration file per camera of [`rig`] in `dir/calib`, and the folder `dir/images`.
fn rig_calibration(dir: &Path) -> (PathBuf, PathBuf) {
    let calib = dir.join("calib");
    for c in &rig() {
        write_opencv(&calib.join(format!("{}.json", c.0)), std::slice::from_ref(c)).expect("writes calibration");
    }
    (calib, dir.join("images"))
}

/// `import --opencv calib --images images -o out --force`, with a box.
fn import_opencv(calib: &Path, images: &Path, out: &Path) -> Output {
    import_recordings(calib, images, out, &["--force"])
}

/// The n-th image of every camera's folder is instant n: folders holding different numbers
/// of images, or different names where they share names, are refused (a camera lacking one
/// image saw every later instant one step early), naming the cameras, their counts and the
/// names each lacks.
#[test]
fn opencv_time_series_that_do_not_line_up_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (calib, images) = rig_calibration(dir.path());
    let out = dir.path().join("scene");
    let write = |files: &[(&str, &[&str])]| {
        let _ = std::fs::remove_dir_all(&images);
        for (camera, names) in files {
            for n in *names {
                image(&images.join(camera), n);
            }
        }
    };
    let all: &[&str] = &["t0.png", "t1.png", "t2.png", "t3.png"];
    write(&[("cam0", all), ("cam1", all), ("cam2", &["t0.png", "t1.png", "t3.png"])]);
    let err = stderr(&import_opencv(&calib, &images, &out));
    assert!(err.contains("hold different numbers of images (cam0, cam1: 4 image(s); cam2: 3 image(s))"), "{err}");
    assert!(err.contains("cam2 lack(s) t2.png;"), "{err}");
    assert!(!out.exists(), "nothing is created for a refused import");

    // As many images, under other names.
    write(&[("cam0", all), ("cam1", all), ("cam2", &["t0.png", "t1.png", "t3.png", "t4.png"])]);
    let err = stderr(&import_opencv(&calib, &images, &out));
    assert!(err.contains("hold different file names (cam0, cam1, cam2: 4 image(s))"), "{err}");
    assert!(err.contains("cam0, cam1 lack(s) t4.png; cam2 lack(s) t2.png;"), "{err}");

    // Names of each camera's own: the counts alone tell.
    write(&[("cam0", &["a0.png", "a1.png"]), ("cam1", &["b0.png", "b1.png"]), ("cam2", &["c0.png"])]);
    let err = stderr(&import_opencv(&calib, &images, &out));
    assert!(err.contains("(cam0, cam1: 2 image(s); cam2: 1 image(s))") && !err.contains("lack(s)"), "{err}");
    image(&images.join("cam2"), "c1.png");
    let o = import_opencv(&calib, &images, &out);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(load_scene(&out).expect("loads").times(), vec![0.0, 1.0]);

    // A folder named like an image is not skipped: the series would lack an instant.
    write(&[("cam0", all), ("cam1", all), ("cam2", &["t0.png", "t1.png", "t3.png"])]);
    std::fs::create_dir_all(images.join("cam2/t2.png")).expect("mkdir");
    let err = stderr(&import_opencv(&calib, &images, &out));
    let folder = images.join("cam2/t2.png");
    assert!(err.contains(&format!("{}: folder(s) named like images", folder.display())), "{err}");
}

/// A camera with a single image among cameras with time series belongs to no instant: refused
/// by name, rather than written with `"time": null`.
#[test]
fn a_single_image_among_time_series_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (calib, images) = rig_calibration(dir.path());
    for camera in ["cam0", "cam1"] {
        for n in ["t0.png", "t1.png"] {
            image(&images.join(camera), n);
        }
    }
    image(&images, "cam2.png");
    let out = dir.path().join("scene");
    let err = stderr(&import_opencv(&calib, &images, &out));
    let single = format!("camera(s) cam2 have a single image ({})", images.join("cam2.png").display());
    assert!(err.contains(&single) && err.contains("while camera(s) cam0, cam1 are recorded over time"), "{err}");
    assert!(!out.exists(), "nothing is created for a refused import");
}

/// Cameras recorded as image series and cameras recorded as videos cannot be matched instant
/// by instant: a series' n-th image is instant n, a video's frames carry their times in
/// seconds. Refused, naming the cameras of each kind, rather than mixing the two clocks.
#[test]
fn image_series_and_videos_together_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (calib, images) = rig_calibration(dir.path());
    // Floating-point images, as the videos' frames become: one scale, so only time tells.
    for camera in ["cam0", "cam1"] {
        std::fs::create_dir_all(images.join(camera)).expect("mkdir");
        for n in ["t0.tif", "t1.tif", "t2.tif", "t3.tif"] {
            let img = Image::from_vec(32, 24, vec![70.0; 32 * 24]);
            fluidnerf_io::image::write_tiff_f32(&images.join(camera).join(n), &img).expect("writes image");
        }
    }
    let fixture = ramp_video();
    std::fs::copy(fixture, images.join("cam2.avi")).expect("copies the fixture");
    let out = dir.path().join("scene");
    let o = import_opencv(&calib, &images, &out);
    let err = stderr(&o);
    assert!(
        !o.status.success(),
        "imported: {}",
        load_scene(&out).map(|s| format!("{:?}", s.times())).unwrap_or_default()
    );
    assert!(
        err.contains("camera(s) cam0, cam1 are series of images") && err.contains("camera(s) cam2 are videos"),
        "{err}"
    );
    assert!(!out.exists(), "nothing is created for a refused import");
}

/// A transforms.json whose image is missing, or that lists no frame, is refused naming the
/// file and the frame (the missing image was "cannot resolve PATH: No such file or directory").
#[test]
fn a_transforms_json_with_a_missing_image_or_no_frame_is_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("src");
    image(&src, "a.png");
    let frame = |name: &str| serde_json::json!({"file_path": name, "transform_matrix": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 90], [0, 0, 0, 1]]});
    let write = |frames: Vec<serde_json::Value>| {
        let doc =
            serde_json::json!({"fl_x": 40, "fl_y": 40, "cx": 15.5, "cy": 11.5, "w": 32, "h": 24, "frames": frames});
        std::fs::write(src.join("transforms.json"), doc.to_string()).expect("writes");
    };
    let out = dir.path().join("out");
    let import = || fluidnerf(&["import", "--transforms", s(&src), "--aabb", "-10,-10,-10,10,10,10", "-o", s(&out)]);
    write(vec![frame("a.png"), frame("images/b.png")]);
    let o = import();
    let e = stderr(&o);
    assert!(
        !o.status.success() && e.contains("transforms.json: frame 1's image") && e.contains("b.png does not exist"),
        "{e}"
    );
    assert!(!out.exists(), "a refused import wrote");
    write(Vec::new());
    let o = import();
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("transforms.json: lists no frames"), "{e}");
    assert!(!out.exists(), "a refused import wrote");
}

/// A truth volume fills its scene's box: imported with another box (given, or estimated for a
/// file without one) it stood where the flow is not, and every score against it was meaningless.
/// One that does not exist is named before anything is written.
#[test]
fn a_truth_volume_is_not_moved_into_another_box() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("synth");
    let o = fluidnerf(&[
        "synth",
        "-q",
        "--preset",
        "demo",
        "--cameras",
        "4",
        "--pixels",
        "16",
        "--resolution",
        "8",
        "-o",
        s(&src),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = dir.path().join("scene");
    let import = |extra: &[&str]| {
        let mut args = vec!["import", "--transforms", s(&src), "-o", s(&out), "--force"];
        args.extend_from_slice(extra);
        fluidnerf(&args)
    };
    // A truth volume that does not exist is named, not written with a path that resolves nowhere.
    let file = src.join("transforms.json");
    let text = std::fs::read_to_string(&file).expect("reads");
    std::fs::write(&file, text.replace("truth/truth.npy", "truth/missing.npy")).expect("writes");
    let o = import(&[]);
    let err = stderr(&o);
    assert!(
        !o.status.success()
            && err.contains("transforms.json: truth entry 0's volume")
            && err.contains("does not exist"),
        "{err}"
    );
    assert!(!out.exists(), "wrote the scene");
    std::fs::write(&file, text).expect("writes");
    let o = import(&["--aabb", "-10,-10,-10,10,10,10"]);
    let err = stderr(&o);
    assert!(!o.status.success(), "imported: {err}");
    assert!(err.contains("truth/truth.npy) fill its box -20.0000,-20.0000,-20.0000,20.0000,20.0000,20.0000"), "{err}");
    assert!(!out.exists(), "wrote the scene");
    // The box the truth fills, given again, is the same box.
    let o = import(&["--aabb", "-20,-20,-20,20,20,20"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = import(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(fluidnerf_io::scene::load_truth(&load_scene(&out).expect("loads")).expect("truth").len(), 1);
    // Without a box in the file, an estimated one is not the truth's.
    let file = src.join("transforms.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("reads")).expect("json");
    v.as_object_mut().expect("object").remove("aabb");
    std::fs::write(&file, v.to_string()).expect("writes");
    std::fs::remove_dir_all(&out).expect("removes");
    let o = import(&[]);
    let err = stderr(&o);
    assert!(!o.status.success() && err.contains("has truth volume(s) (") && err.contains("but no `aabb`"), "{err}");
    assert!(!out.exists(), "wrote the scene");
    assert!(import(&["--aabb", "-20,-20,-20,20,20,20"]).status.success());
}

/// A transforms.json's mask, background or flat-field image that does not exist is named with
/// its frame and key, before anything is written.
#[test]
fn a_transforms_json_with_a_missing_mask_or_background_is_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("src");
    image(&src, "a.png");
    let out = dir.path().join("out");
    for (key, value, want) in [
        ("mask_path", serde_json::json!("masks/a.png"), "transforms.json: frame 0's `mask_path`"),
        ("background", serde_json::json!(["dark/0.png"]), "transforms.json: frame 0's `background` image"),
        ("flat_field", serde_json::json!("flat/0.png"), "transforms.json: frame 0's `flat_field` image"),
    ] {
        let mut frame = serde_json::json!({"file_path": "a.png", "transform_matrix": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 90], [0, 0, 0, 1]]});
        frame[key] = value;
        let doc =
            serde_json::json!({"fl_x": 40, "fl_y": 40, "cx": 15.5, "cy": 11.5, "w": 32, "h": 24, "frames": [frame]});
        std::fs::write(src.join("transforms.json"), doc.to_string()).expect("writes");
        let o = fluidnerf(&["import", "--transforms", s(&src), "--aabb", "-10,-10,-10,10,10,10", "-o", s(&out)]);
        let e = stderr(&o);
        assert!(!o.status.success() && e.contains(want) && e.contains("does not exist"), "{e}");
        assert!(!out.exists(), "a refused import wrote");
    }
}

/// A transforms.json's mask, background or flat field of another size than its frame's image is
/// refused by the import, naming the file, rather than written into a scene every later command
/// refuses.
#[test]
fn a_transforms_json_whose_mask_or_background_does_not_fit_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("src");
    image(&src, "a.png");
    write_png16_counts(&src.join("small.png"), &Image::from_vec(16, 12, vec![1.0; 16 * 12])).expect("writes");
    let out = dir.path().join("out");
    for (key, value) in [
        ("mask_path", serde_json::json!("small.png")),
        ("background", serde_json::json!("small.png")),
        ("flat_field", serde_json::json!(["small.png"])),
    ] {
        let mut frame = serde_json::json!({"file_path": "a.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 90], [0, 0, 0, 1]]});
        frame[key] = value;
        let doc =
            serde_json::json!({"fl_x": 40, "fl_y": 40, "cx": 15.5, "cy": 11.5, "w": 32, "h": 24, "frames": [frame]});
        std::fs::write(src.join("transforms.json"), doc.to_string()).expect("writes");
        let o = fluidnerf(&["import", "--transforms", s(&src), "--aabb", "-10,-10,-10,10,10,10", "-o", s(&out)]);
        let e = stderr(&o);
        assert!(!o.status.success() && e.contains("small.png") && e.contains("is 16x12 pixels but"), "{key}: {e}");
        assert!(!out.exists(), "a refused import wrote");
    }
}

/// Videos of as many frames but another frame rate are not one recording: their n-th frames are
/// other instants, each of which one camera alone would see. They are refused, naming both
/// cameras, their times and their rates.
#[test]
fn videos_of_different_frame_rates_are_refused() {
    let (dir, calib, videos) = video_rig();
    let bytes = std::fs::read(ramp_video()).expect("reads the fixture");
    // The video stream header's dwRate (at 24 in `strh`'s data) doubled: 20 frames per second.
    let mut fast = bytes.clone();
    let rate = bytes.windows(4).position(|w| w == b"strh").expect("strh") + 8 + 24;
    let doubled = 2 * u32::from_le_bytes(bytes[rate..rate + 4].try_into().expect("4 bytes"));
    fast[rate..rate + 4].copy_from_slice(&doubled.to_le_bytes());
    let e = refused_videos(&dir, &calib, &videos, [&bytes, &fast, &bytes]);
    assert!(
        e.contains("the frame 1 kept of camera cam0 is at 0.1 s, that of camera cam1 at 0.05 s")
            && e.contains("frame rates 10 and 20 fps"),
        "{e}"
    );
}

/// Imports the rig's cameras `cam0`, `cam1`, `cam2` from the AVI files `data`, expecting a
/// refusal that writes nothing; its error output.
fn refused_videos(dir: &tempfile::TempDir, calib: &Path, videos: &Path, data: [&Vec<u8>; 3]) -> String {
    for (name, data) in ["cam0", "cam1", "cam2"].into_iter().zip(data) {
        std::fs::write(videos.join(format!("{name}.avi")), data).expect("writes");
    }
    let out = dir.path().join("scene");
    let o = import_recordings(calib, videos, &out, &[]);
    let e = stderr(&o);
    assert!(!o.status.success(), "imported: {e}");
    assert!(!out.exists(), "a refused import wrote");
    e
}

/// Videos whose times count from each file's start (not a high-speed camera's raw files, which
/// count from the trigger) and that hold different numbers of frames are refused, saying that
/// their lengths do not tell which frames were simultaneous: their first frames share times,
/// and the message said they shared none.
#[test]
fn videos_of_different_lengths_are_refused_saying_why() {
    let (dir, calib, videos) = video_rig();
    let bytes = std::fs::read(ramp_video()).expect("reads the fixture");
    // The last frame's chunk (before the index, which lists it again) renamed: three frames.
    let index = bytes.windows(4).position(|w| w == b"idx1").unwrap_or(bytes.len());
    let last = bytes[..index].windows(4).rposition(|w| w == b"00dc").expect("a frame chunk");
    let mut short = bytes.clone();
    short[last..last + 4].copy_from_slice(b"JUNK");
    let e = refused_videos(&dir, &calib, &videos, [&bytes, &short, &bytes]);
    assert!(
        e.contains("camera cam0 gives 4 frame(s), camera cam1 3")
            && e.contains("their times count from each file's start")
            && e.contains("--video-frames")
            && !e.contains("share no run"),
        "{e}"
    );
}

/// A calibration in metres imported without --units is read as millimetres: its cameras stand
/// within a millimetre of the box, which the import warns of, suggesting `--units m`; given
/// the unit, it says nothing.
#[test]
fn cameras_a_millimetre_from_the_box_suggest_a_calibration_in_metres() {
    let dir = tempfile::tempdir().expect("tempdir");
    let metres: Vec<(String, Camera)> = rig()
        .into_iter()
        .map(|(n, c)| {
            let k = c.intrinsics;
            let mut m = Camera::look_at(k, c.centre() / 1000.0, DVec3::ZERO, DVec3::Z);
            m.distortion = c.distortion;
            (n, m)
        })
        .collect();
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &metres).expect("writes calibration");
    let images = dir.path().join("images");
    for (n, _) in rig() {
        image(&images, &format!("{n}.png"));
    }
    let import = |out: &str, extra: &[&str]| {
        let mut args =
            vec!["import", "--opencv", s(&calib), "--images", s(&images), "--aabb", "-0.01,-0.01,-0.01,0.01,0.01,0.01"];
        args.extend_from_slice(extra);
        let out = dir.path().join(out);
        args.extend_from_slice(&["-o", s(&out)]);
        fluidnerf(&args)
    };
    let o = import("mm", &[]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("the cameras stand 0.092") && e.contains("is the calibration in metres") && e.contains("--units m"),
        "{e}"
    );
    let o = import("m", &["--units", "m"]);
    assert!(o.status.success() && !stderr(&o).contains("in metres"), "{}", stderr(&o));
}

/// A camera's distortion under a name the reader does not know (`dist_coeffs_cam1` for
/// `distortion_coefficients_cam1`) would leave it undistorted without a word: the import warns,
/// naming the camera, the node it read and the node to rename.
#[test]
fn distortion_under_an_unknown_name_is_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let text = std::fs::read_to_string(&calib).expect("reads");
    std::fs::write(&calib, text.replace("distortion_coefficients_cam1:", "dist_coeffs_cam1:")).expect("writes");
    let images = dir.path().join("images");
    for (n, _) in rig() {
        image(&images, &format!("{n}.png"));
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &images, &out, &[]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("camera `cam1` has no `distortion_coefficients_cam1` node")
            && e.contains("the file has `dist_coeffs_cam1`, which is not read"),
        "{e}"
    );
    assert!(!e.contains("camera `cam0`") && !e.contains("camera `cam2`"), "{e}");
}

/// A pose given twice, as `R`/`T` and `tvec`, is read from `R`/`T` with a warning, as when the
/// second pose has an `rvec`: a `tvec` beside `T` was left unread without a word.
#[test]
fn a_tvec_beside_r_and_t_is_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    let pose = rig()[1].1.camera_from_world();
    let (m, t) = (pose.matrix3, pose.translation);
    let r: Vec<String> = (0..3).flat_map(|i| (0..3).map(move |j| m.col(j)[i].to_string())).collect();
    let matrix = |key: &str, rows: usize, cols: usize, data: String| {
        format!("{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n")
    };
    let mut text = std::fs::read_to_string(&calib).expect("reads").replace("rvec_cam1:", "unused_cam1:");
    text += &matrix("R_cam1", 3, 3, r.join(", "));
    text += &matrix("T_cam1", 3, 1, format!("{}, {}, {}", t.x, t.y, t.z));
    std::fs::write(&calib, text).expect("writes");
    let images = dir.path().join("images");
    for (n, _) in rig() {
        image(&images, &format!("{n}.png"));
    }
    let o = import_recordings(&calib, &images, &dir.path().join("scene"), &[]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("camera cam1: both R_cam1/T_cam1 and tvec_cam1 given; using R/T"), "{e}");
}

/// Two videos of a transforms.json named alike (no `camera`, one file name in two folders) would
/// be decoded into one folder, the second over the first: refused before anything is decoded,
/// naming both files, not as frames "from an earlier import". So is a video whose camera name is
/// a path, whose frames would land outside OUT/frames.
#[test]
fn videos_that_would_share_a_frames_folder_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("rig");
    let fixture = ramp_video();
    let mut frames = Vec::new();
    for (folder, (_, cam)) in ["a", "b"].into_iter().zip(rig()) {
        std::fs::create_dir_all(src.join(folder)).expect("mkdir");
        std::fs::copy(&fixture, src.join(folder).join("cam.avi")).expect("copies the fixture");
        let m = fluidnerf_io::scene::world_from_camera_to_opengl_c2w(&cam.world_from_camera);
        frames.push(serde_json::json!({"file_path": format!("{folder}/cam.avi"), "transform_matrix": m}));
    }
    let v = serde_json::json!({
        "w": 32, "h": 24, "fl_x": 40.0, "fl_y": 40.5, "cx": 15.25, "cy": 11.5,
        "aabb": [[-10, -10, -10], [10, 10, 10]], "frames": frames,
    });
    std::fs::write(src.join("transforms.json"), v.to_string()).expect("writes");
    let out = dir.path().join("scene");
    let o = fluidnerf(&["import", "--transforms", s(&src), "-o", s(&out)]);
    let e = stderr(&o);
    assert!(!o.status.success(), "imported: {e}");
    assert!(e.contains("a/cam.avi and ") && e.contains("b/cam.avi both go by the name `cam`"), "{e}");
    assert!(!e.contains("earlier import"), "{e}");
    assert!(!out.exists(), "a refused import wrote");
    // A camera name that is a path would put the frames outside the scene's frames folder.
    let outside = dir.path().join("elsewhere");
    for name in ["../../elsewhere", s(&outside)] {
        let mut v = v.clone();
        v["frames"][0]["camera"] = name.into();
        std::fs::write(src.join("transforms.json"), v.to_string()).expect("writes");
        let o = fluidnerf(&["import", "--transforms", s(&src), "-o", s(&out)]);
        let e = stderr(&o);
        assert!(!o.status.success() && e.contains(&format!("goes by the name `{name}`, which cannot name")), "{e}");
        assert!(!outside.exists() && !out.exists(), "a refused import wrote");
    }
}

/// An --images that is a file is said to be one, not a folder that does not exist.
#[test]
fn images_given_as_a_file_are_named_as_such() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    write_opencv(&calib, &rig()).expect("writes calibration");
    image(dir.path(), "cam0.png");
    let file = dir.path().join("cam0.png");
    let out = dir.path().join("scene");
    let o = fluidnerf(&["import", "--opencv", s(&calib), "--images", s(&file), "-o", s(&out)]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains(&format!("--images {}: not a folder", file.display())), "{e}");
    let missing = dir.path().join("nothing");
    let o = fluidnerf(&["import", "--opencv", s(&calib), "--images", s(&missing), "-o", s(&out)]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains(&format!("--images {}: no such folder", missing.display())), "{e}");
}

/// --linearisation acts on 8-bit images only: given for 16-bit ones it would be recorded and
/// ignored without a word, so the import warns that it has no effect.
#[test]
fn a_linearisation_for_16_bit_images_is_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (calib, images) = rig_with_stills(dir.path());
    let out = dir.path().join("scene");
    let import = |linearisation: &str| {
        fluidnerf(&[
            "import",
            "--opencv",
            s(&calib),
            "--images",
            s(&images),
            "--aabb",
            "-10,-10,-10,10,10,10",
            "--linearisation",
            linearisation,
            "--force",
            "-o",
            s(&out),
        ])
    };
    let o = import("srgb");
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("--linearisation srgb has no effect: the images are 16-bit"), "{e}");
    let o = import("linear");
    assert!(o.status.success() && !stderr(&o).contains("no effect"), "{}", stderr(&o));
}

/// Intrinsics calibrated at another resolution than the images (here a larger sensor) put the
/// principal point outside the image: the import warns, naming the camera and its node.
#[test]
fn a_principal_point_outside_the_image_is_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = dir.path().join("rig.yml");
    let mut cams = rig();
    // The box still shows in the image's right part: without the warning, nothing would be said.
    cams[1].1.intrinsics.cx = 35.0;
    write_opencv(&calib, &cams).expect("writes calibration");
    let images = dir.path().join("images");
    for (n, _) in &cams {
        image(&images, &format!("{n}.png"));
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &images, &out, &[]);
    let e = stderr(&o);
    assert!(
        e.contains(
            "camera `cam1`: `camera_matrix_cam1`: the principal point (cx, cy) = (35, 11.5) lies outside the \
             32x24 image"
        ),
        "{e}"
    );
    assert!(!e.contains("camera `cam0`") && !e.contains("camera `cam2`"), "{e}");
}

/// A forced re-import that decodes fewer frames removes the earlier import's frames it does
/// not write again, which would otherwise sit beside the new ones as if they were the scene's;
/// a file of the user's in the frames' folder stays.
#[test]
fn a_forced_reimport_removes_the_frames_it_no_longer_writes() {
    let (dir, calib, videos) = video_rig();
    for n in ["cam0", "cam1", "cam2"] {
        std::fs::copy(ramp_video(), videos.join(format!("{n}.avi"))).expect("copies the fixture");
    }
    let out = dir.path().join("scene");
    let run = |extra: &[&str]| import_recordings(&calib, &videos, &out, extra);
    let o = run(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = |cam: &str| {
        let mut names: Vec<String> = std::fs::read_dir(out.join("frames").join(cam))
            .expect("lists")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    };
    assert_eq!(frames("cam1"), ["000000.tif", "000001.tif", "000002.tif", "000003.tif"]);
    std::fs::write(out.join("frames/cam1/notes.txt"), "keep me").expect("writes");

    let o = run(&["--video-frames", "1..3", "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(load_scene(&out).expect("loads").frames.len(), 6);
    assert_eq!(frames("cam0"), ["000000.tif", "000001.tif"]);
    assert_eq!(frames("cam1"), ["000000.tif", "000001.tif", "notes.txt"]);

    // Still images instead of videos: the frames go, and their folders when nothing else is in them.
    for n in ["cam0", "cam1", "cam2"] {
        std::fs::remove_file(videos.join(format!("{n}.avi"))).expect("removes");
        image(&videos, &format!("{n}.png"));
    }
    let o = run(&["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join("frames/cam0").exists() && !out.join("frames/cam2").exists());
    assert_eq!(frames("cam1"), ["notes.txt"]);
}

/// Every file and folder under `dir`, hidden ones too, by its path relative to `dir`: a file
/// with its bytes, a folder with none.
fn tree(dir: &Path) -> std::collections::BTreeMap<PathBuf, Option<Vec<u8>>> {
    fn walk(root: &Path, dir: &Path, out: &mut std::collections::BTreeMap<PathBuf, Option<Vec<u8>>>) {
        for entry in std::fs::read_dir(dir).expect("lists") {
            let p = entry.expect("entry").path();
            let rel = p.strip_prefix(root).expect("under the root").to_path_buf();
            if p.is_dir() {
                out.insert(rel, None);
                walk(root, &p, out);
            } else {
                out.insert(rel, Some(std::fs::read(&p).expect("reads")));
            }
        }
    }
    let mut out = std::collections::BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// The names in the folder `dir`, sorted.
fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("lists")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// A forced import of another recording that fails once its frames are decoded (a box no
/// camera sees) leaves the scene it was to replace byte for byte as it was: the new frames
/// had been written over the earlier ones in `frames/<camera>/`, so the folder held the new
/// recording's first frames, the earlier one's last frames and the earlier transforms.json,
/// and `info` found nothing wrong. The same import with a box succeeds and leaves the new
/// recording's frames only.
/// A second import into a folder while one writes into it took the first one's staging
/// folder for what a killed import left and removed it. One import into a folder at a time:
/// another is refused, naming the folder, and the scene there is left as it was.
#[test]
fn a_second_import_into_a_folder_while_one_writes_is_refused() {
    let (dir, calib, videos) = ramp_video_rig();
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let lock = out.join(".import.lock");
    assert!(!lock.exists(), "an import that ended holds no lock");
    // An import under way, as this process holds the lock, with its staging folder begun.
    let held = fluidnerf_pipeline::rundir::FileLock::take(&out, &lock).expect("takes the lock");
    let begun = out.join(".import-staging/frames/cam0/000000.tif");
    std::fs::create_dir_all(begun.parent().expect("a folder")).expect("mkdir");
    std::fs::write(&begun, b"half a frame").expect("writes");
    let before = tree(&out);
    let o = import_recordings(&calib, &videos, &out, &["--force"]);
    assert!(!o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("another import is writing into this folder"), "{}", stderr(&o));
    assert_eq!(tree(&out), before, "the folder and the other import's files as they were");
    drop(held);
    // Once it ends (here: killed, its staging folder left), the next import goes on.
    let o = import_recordings(&calib, &videos, &out, &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join(".import-staging").exists() && !lock.exists());
}

#[test]
fn a_failed_forced_import_of_videos_leaves_the_earlier_scene_as_it_was() {
    let (dir, calib, videos) = ramp_video_rig();
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = tree(&out);

    // Another recording (the limited-range fixture: other values), two frames of it.
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).expect("mkdir");
    let limited = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video/ramp_mjpeg_limited.avi");
    for (n, _) in rig() {
        std::fs::copy(&limited, other.join(format!("{n}.avi"))).expect("copies the fixture");
    }
    let import = |aabb: &str| {
        let args = ["import", "--opencv", s(&calib), "--images", s(&other), "--video-frames", "0..2", "--force"];
        fluidnerf(&[&args[..], &["--aabb", aabb, "-o", s(&out)]].concat())
    };
    let o = import("500,500,500,510,510,510");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("invalid"), "{}", stderr(&o));
    let after = tree(&out);
    assert_eq!(after.keys().collect::<Vec<_>>(), before.keys().collect::<Vec<_>>(), "the same files");
    for (path, content) in &before {
        assert!(after[path] == *content, "{} changed", path.display());
    }
    let info = fluidnerf(&["info", s(&out)]);
    assert!(info.status.success(), "{}", stderr(&info));

    let o = import("-10,-10,-10,10,10,10");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(load_scene(&out).expect("loads").frames.len(), 6);
    for (n, _) in rig() {
        assert_eq!(names_in(&out.join("frames").join(&n)), ["000000.tif", "000001.tif"], "{n}");
        let first = PathBuf::from(format!("frames/{n}/000000.tif"));
        assert!(std::fs::read(out.join(&first)).ok() != before[&first], "{n}: the new recording's frame");
    }
    assert_eq!(names_in(&out), ["frames", "import.json", "transforms.json"], "nothing else is left");
}

/// A DaVis recording imported with --force over an earlier one of more instants: a failure
/// after the split (a box no camera sees) leaves the earlier scene byte for byte, where the
/// new images had replaced the earlier ones of the same names; a success leaves the new
/// recording's images only.
#[test]
fn a_failed_forced_import_of_a_davis_recording_leaves_the_earlier_scene_as_it_was() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = davis_rig(dir.path());
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for n in 0..6u16 {
        davis_file(&a.join(format!("B{:05}.im7", n + 1)), &[100 + n, 200 + n, 300 + n], &["1", "2", "3"]);
    }
    for n in 0..4u16 {
        davis_file(&b.join(format!("B{:05}.im7", n + 1)), &[500 + n, 600 + n, 700 + n], &["1", "2", "3"]);
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &a, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = tree(&out);
    let import = |aabb: &str| {
        let args = ["import", "--opencv", s(&calib), "--images", s(&b), "--force", "--aabb", aabb];
        fluidnerf(&[&args[..], &["-o", s(&out)]].concat())
    };
    let o = import("500,500,500,510,510,510");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(tree(&out) == before, "the earlier scene changed");

    let o = import("-10,-10,-10,10,10,10");
    assert!(o.status.success(), "{}", stderr(&o));
    for c in 1..=3u16 {
        let folder = out.join(format!("frames/cam{c}"));
        assert_eq!(names_in(&folder), ["B00001.png", "B00002.png", "B00003.png", "B00004.png"], "cam{c}");
        let img = fluidnerf_io::image::read_image(&folder.join("B00004.png")).expect("reads");
        assert_eq!(img.data[0], f32::from(100 * c + 400 + 3), "cam{c}: the new recording's last instant");
    }
    assert_eq!(load_scene(&out).expect("loads").frames.len(), 12);
}

/// What an import killed while decoding leaves, its staging folder, is never taken for part
/// of the scene: `info` reads the scene as it was, and the next import into the folder
/// removes it.
#[test]
fn what_a_killed_import_left_is_removed_by_the_next_import() {
    let (dir, calib, videos) = ramp_video_rig();
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    // A frame half written when the import was killed.
    let left = out.join(".import-staging/frames/cam0/000000.tif");
    std::fs::create_dir_all(left.parent().expect("a folder")).expect("mkdir");
    std::fs::write(&left, b"II*\0").expect("writes");
    let info = fluidnerf(&["info", s(&out)]);
    assert!(info.status.success(), "{}", stderr(&info));
    let o = import_recordings(&calib, &videos, &out, &["--force", "--video-frames", "0..2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!out.join(".import-staging").exists());
    assert_eq!(names_in(&out.join("frames/cam0")), ["000000.tif", "000001.tif"]);
}

/// Phantom cine recordings, one per camera, import as videos do: each frame a float TIFF of
/// the sensor's counts above the black level, at the file's frame rate, with no word of gamma.
#[test]
fn phantom_cine_recordings_import_as_videos() {
    let (dir, calib, videos) = video_rig();
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video/ramp_16bit.cine");
    for n in ["cam0", "cam1", "cam2"] {
        std::fs::copy(&fixture, videos.join(format!("{n}.cine"))).expect("copies the fixture");
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &["--video-frames", "2.."]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("gamma"), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 6);
    assert_eq!(scene.times(), [0.002, 0.003]);
    let f = scene.frames.iter().find(|f| f.camera_name.as_deref() == Some("cam1") && f.time == Some(0.003));
    let img = fluidnerf_io::image::read_image(&out.join(&f.expect("cam1 at 3 ms").file_path)).expect("reads");
    assert_eq!(img.get(5, 7), 10.0 * (20.0 + 4.0 * 5.0 + 3.0 * 7.0 + 30.0));
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("import.json")).expect("import.json")).expect("JSON");
    assert_eq!(record["videos"][0]["decoder"], "cine");
    assert_eq!(record["videos"][0]["range_source"], "raw");

    // A camera whose file begins one image later than the others' (at 1 to 4 ms, theirs at 0
    // to 3 ms): the three instants all of them recorded, the others' first frames left out.
    let patched = |first_image: i32, rate: Option<u32>| {
        let mut bytes = std::fs::read(&fixture).expect("reads");
        bytes[16..20].copy_from_slice(&first_image.to_le_bytes());
        if let Some(r) = rate {
            bytes[84 + 768..84 + 772].copy_from_slice(&r.to_le_bytes());
        }
        std::fs::write(videos.join("cam2.cine"), bytes).expect("writes");
    };
    patched(1, None);
    let late = dir.path().join("late");
    let o = import_recordings(&calib, &videos, &late, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("camera cam0: 1 frame(s) before 0.001 s and 0 after 0.003 s"), "{e}");
    assert!(e.contains("camera cam2: 0 frame(s) before 0.001 s and 1 after 0.003 s"), "{e}");
    let scene = load_scene(&late).expect("loads");
    assert_eq!((scene.frames.len(), scene.times()), (9, vec![0.001, 0.002, 0.003]));
    for f in &scene.frames {
        let img = fluidnerf_io::image::read_image(&late.join(&f.file_path)).expect("reads");
        let k =
            (f.time.expect("a time") * 1000.0).round() as usize - usize::from(f.camera_name.as_deref() == Some("cam2"));
        assert_eq!(img.get(5, 7), 10.0 * (20.0 + 4.0 * 5.0 + 3.0 * 7.0 + 10.0 * k as f32), "{f:?}");
    }
    assert!(!late.join("frames/cam0/000000.tif").exists() && late.join("frames/cam0/000001.tif").exists());
    assert!(!late.join("frames/cam2/000003.tif").exists());
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(late.join("import.json")).expect("import.json")).expect("JSON");
    assert_eq!(
        (record["videos"][0]["frames_kept"].as_u64(), record["videos"][0]["first_time_s"].as_f64()),
        (Some(3), Some(0.001))
    );

    // Files that share no run of instants are refused: at half the frame rate, the common times
    // (0 and 2 ms) are every other frame of the others; a file of instants after theirs, none.
    for (first_image, rate, says) in [(0, Some(500), "camera cam2 at 0.002 s"), (10, None, "camera cam2 at 0.01 s")] {
        patched(first_image, rate);
        let o = import_recordings(&calib, &videos, &dir.path().join(format!("apart{first_image}")), &[]);
        assert!(!o.status.success(), "{}", stderr(&o));
        assert!(stderr(&o).contains("not synchronised") && stderr(&o).contains(says), "{}", stderr(&o));
    }
}

/// A recording with pixels at its sensor's full scale is warned about at import, naming the
/// camera and the file, and the count is kept in `import.json`: its frames become float
/// images, which the scene's own check of saturated pixels cannot judge.
#[test]
fn saturated_pixels_of_a_recording_are_warned_about() {
    let (dir, calib, videos) = video_rig();
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video/ramp_16bit.cine");
    for n in ["cam0", "cam1", "cam2"] {
        std::fs::copy(&fixture, videos.join(format!("{n}.cine"))).expect("copies the fixture");
    }
    // cam1's first image's first stored pixel at 4095, the largest count of 12 bits.
    let mut bytes = std::fs::read(&fixture).expect("reads");
    let first = u64::from_le_bytes(bytes[84 + 12432..84 + 12432 + 8].try_into().expect("8 bytes")) as usize;
    let annotation = u32::from_le_bytes(bytes[first..first + 4].try_into().expect("4 bytes")) as usize;
    bytes[first + annotation..first + annotation + 2].copy_from_slice(&4095u16.to_le_bytes());
    std::fs::write(videos.join("cam1.cine"), bytes).expect("writes");
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &[]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("camera cam1") && err.contains("cam1.cine: 1 pixel(s)") && err.contains("saturated"), "{err}");
    assert!(!err.contains("camera cam0:") && !err.contains("camera cam2:"), "{err}");
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("import.json")).expect("import.json")).expect("JSON");
    let counts: Vec<u64> = (0..3).map(|i| record["videos"][i]["saturated_pixels"].as_u64().expect("a count")).collect();
    assert_eq!(counts, [0, 1, 0]);
}

/// Photron MRAW recordings with their headers beside them import as videos; the headers are
/// not taken for uncalibrated entries.
#[test]
fn photron_mraw_recordings_import_as_videos() {
    let (dir, calib, videos) = video_rig();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video");
    for n in ["cam0", "cam1", "cam2"] {
        std::fs::copy(fixtures.join("ramp_12bit.mraw"), videos.join(format!("{n}.mraw"))).expect("copies");
        std::fs::copy(fixtures.join("ramp_12bit.cihx"), videos.join(format!("{n}.cihx"))).expect("copies");
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("gamma"), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 12);
    let f = scene.frames.iter().find(|f| f.camera_name.as_deref() == Some("cam2") && f.time == Some(0.001));
    let img = fluidnerf_io::image::read_image(&out.join(&f.expect("cam2 at 1 ms").file_path)).expect("reads");
    assert_eq!(img.get(5, 7), 64.0 + 10.0 * (20.0 + 4.0 * 5.0 + 3.0 * 7.0 + 10.0));
}

/// An MRAW header whose effective bits the counts exceed (pyMRAW writes `EffectiveBit Depth :
/// 12`, `EffectiveBit Side : Lower` into every 16-bit file) is warned about, naming the file,
/// the header's keys and the largest count, and the 16-bit full scale is used: counts of
/// 20000 were called saturated, with the advice to mask them.
#[test]
fn an_mraw_header_whose_effective_bits_the_counts_exceed_is_warned_about() {
    let (dir, calib, videos) = video_rig();
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../io/tests/fixtures/video");
    for n in ["cam0", "cam1", "cam2"] {
        std::fs::copy(fixtures.join("ramp_16bit.mraw"), videos.join(format!("{n}.mraw"))).expect("copies");
        std::fs::copy(fixtures.join("ramp_16bit.cih"), videos.join(format!("{n}.cih"))).expect("copies");
    }
    let mut bytes = std::fs::read(videos.join("cam1.mraw")).expect("reads");
    bytes[..4].copy_from_slice(&[20000u16.to_le_bytes(), 4095u16.to_le_bytes()].concat());
    std::fs::write(videos.join("cam1.mraw"), bytes).expect("writes");
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &[]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(e.contains(s(&videos.join("cam1.mraw"))) && e.contains("cam1.cih"), "{e}");
    assert!(e.contains("EffectiveBit Depth : 12") && e.contains("EffectiveBit Side : Lower"), "{e}");
    assert!(e.contains("20000") && e.contains("65535"), "{e}");
    assert_eq!(e.matches("EffectiveBit Depth").count(), 1, "once, for cam1's file: {e}");
    assert!(!e.contains("(saturated)") && !e.contains("mask them"), "{e}");
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("import.json")).expect("import.json")).expect("JSON");
    let counts: Vec<u64> = (0..3).map(|i| record["videos"][i]["saturated_pixels"].as_u64().expect("a count")).collect();
    assert_eq!(counts, [0, 0, 0]);
}

/// The video options act on video recordings only: given for still images the import warns,
/// naming each option given and its value (a shifted time, --video-time-offset, was warned
/// about only as one of "the --video-* options").
#[test]
fn video_options_for_still_images_are_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (calib, images) = rig_with_stills(dir.path());
    let out = dir.path().join("scene");
    let import = |extra: &[&str]| {
        let args = ["import", "--opencv", s(&calib), "--images", s(&images), "--aabb", "-10,-10,-10,10,10,10"];
        fluidnerf(&[&args[..], extra, &["--force", "-o", s(&out)]].concat())
    };
    for (extra, says) in [
        (&["--video-time-offset", "0.5"][..], "--video-time-offset 0.5 has no effect"),
        (&["--video-time-offset=-2"], "--video-time-offset -2 has no effect"),
        (&["--video-every", "2"], "--video-every 2 has no effect"),
        (&["--video-frames", "0..2"], "--video-frames 0..2 has no effect"),
        (
            &["--video-range", "full", "--video-time-offset", "1e-3"],
            "--video-time-offset 0.001, --video-range full have",
        ),
    ] {
        let o = import(extra);
        let e = stderr(&o);
        assert!(o.status.success(), "{extra:?}: {e}");
        assert!(e.contains(says) && e.contains("no camera's recording is a video file"), "{extra:?}: {e}");
    }
    let o = import(&[]);
    assert!(o.status.success() && !stderr(&o).contains("no effect"), "{}", stderr(&o));
}

/// A DaVis 7 image (uncompressed 16-bit words) of 32 × 24 frames, frame k filled with
/// `values[k]` and named by the attribute `CameraName<k> = labels[k]: …`.
fn davis_file(path: &Path, values: &[u16], labels: &[&str]) {
    let mut b = vec![0u8; 256];
    b[4..6].copy_from_slice(&(-4i16).to_le_bytes());
    for (at, v) in [(8, 32i32), (12, 24), (16, 1), (20, values.len() as i32)] {
        b[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    for v in values {
        b.extend(std::iter::repeat_n(v.to_le_bytes(), 32 * 24).flatten());
    }
    for (k, label) in labels.iter().enumerate() {
        let item = format!("CameraName{k}={label}: Imager (32 x 24 pixel)");
        b.extend(6i32.to_le_bytes());
        b.extend((item.len() as i32).to_le_bytes());
        b.extend(item.as_bytes());
    }
    b.extend([0u8; 8]);
    std::fs::create_dir_all(path.parent().expect("a folder")).expect("mkdir");
    std::fs::write(path, b).expect("writes DaVis file");
}

/// [`rig`] with its cameras numbered from 1, as DaVis numbers them: `cam1`, `cam2`, `cam3`.
fn davis_rig(dir: &Path) -> PathBuf {
    let calib = dir.join("rig.yml");
    let cams: Vec<(String, Camera)> =
        rig().into_iter().enumerate().map(|(i, (_, c))| (format!("cam{}", i + 1), c)).collect();
    write_opencv(&calib, &cams).expect("writes calibration");
    calib
}

/// A folder of DaVis files, each holding every camera's frame of one instant, is split into
/// the cameras' images by the camera names in its attributes, whatever their order in the
/// file; a double-frame recording's exposures become consecutive instants.
#[test]
fn a_davis_recording_is_split_into_the_cameras_images() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = davis_rig(dir.path());
    let rec = dir.path().join("rec");
    // Frames stored as cameras 2, 3, 1; DaVis camera c at instant n holds 100·c + n.
    for n in 0..2u16 {
        davis_file(&rec.join(format!("B{:05}.im7", n + 1)), &[200 + n, 300 + n, 100 + n], &["2", "3", "1"]);
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &rec, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 6);
    assert_eq!(scene.times(), vec![0.0, 1.0]);
    for f in &scene.frames {
        let camera: u16 = f.camera_name.as_deref().expect("named")[3..].parse().expect("numbered");
        let n = f.time.expect("timed") as u16;
        let name = format!("frames/{}/B{:05}.png", f.camera_name.as_deref().expect("named"), n + 1);
        assert_eq!(f.file_path, PathBuf::from(&name));
        let img = fluidnerf_io::image::read_image(&out.join(&name)).expect("reads");
        assert!(img.data.iter().all(|&v| v == f32::from(100 * camera + n)), "{name}: {}", img.data[0]);
    }
    let record = std::fs::read_to_string(out.join("import.json")).expect("import.json");
    assert!(record.contains("\"davis_camera\": 3"), "{record}");

    // Double-frame: exposures A and B of one file are instants 0 and 1.
    let rec2 = dir.path().join("rec2");
    davis_file(&rec2.join("B00001.im7"), &[10, 11, 20, 21, 30, 31], &["1A", "1B", "2A", "2B", "3A", "3B"]);
    let out2 = dir.path().join("scene2");
    let o = import_recordings(&calib, &rec2, &out2, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out2).expect("loads");
    assert_eq!((scene.frames.len(), scene.times()), (6, vec![0.0, 1.0]));
    let b = out2.join("frames/cam2/B00001B.png");
    assert_eq!(fluidnerf_io::image::read_image(&b).expect("reads").data[0], 21.0);

    // Cameras that name no DaVis camera are refused, saying how they are matched.
    let left = dir.path().join("left.yml");
    write_opencv(&left, &[("left".to_owned(), rig()[0].1.clone())]).expect("writes calibration");
    let o = import_recordings(&left, &rec, &dir.path().join("scene4"), &[]);
    let err = stderr(&o);
    assert!(
        !o.status.success() && err.contains("camera `left` has no number") && err.contains("cameras 1, 2, 3"),
        "{err}"
    );
    // A multi-frame file as one camera's image is refused naming its frames.
    let stills = dir.path().join("stills");
    davis_file(&stills.join("cam1.im7"), &[5], &["1"]);
    davis_file(&stills.join("cam2.im7"), &[6], &["2"]);
    davis_file(&stills.join("cam3.im7"), &[7, 8], &["3A", "3B"]);
    let o = import_recordings(&calib, &stills, &dir.path().join("scene5"), &[]);
    let err = stderr(&o);
    assert!(!o.status.success() && err.contains("cam3.im7") && err.contains("2 frames"), "{err}");
    davis_file(&stills.join("cam3.im7"), &[7], &["3"]);
    let o = import_recordings(&calib, &stills, &dir.path().join("scene5"), &[]);
    assert!(o.status.success(), "one frame per camera's file is its image: {}", stderr(&o));
}

/// Importing again into the same folder removes the images an earlier import split from a
/// DaVis recording that the new scene does not read (here the second instant of a recording
/// now one file long), and never those it reads, even when they are its images.
#[test]
fn a_davis_import_again_removes_the_earlier_split_images_it_does_not_use() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = davis_rig(dir.path());
    let rec = dir.path().join("rec");
    for n in 0..2u16 {
        davis_file(&rec.join(format!("B{:05}.im7", n + 1)), &[100 + n, 200 + n, 300 + n], &["1", "2", "3"]);
    }
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &rec, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("frames/cam3/B00002.png").is_file());

    // The recording is one file now (a folder of its first file only).
    let short = dir.path().join("short");
    davis_file(&short.join("B00001.im7"), &[100, 200, 300], &["1", "2", "3"]);
    let o = import_recordings(&calib, &short, &out, &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for c in 1..=3 {
        assert!(out.join(format!("frames/cam{c}/B00001.png")).is_file(), "cam{c}'s image of the new import");
        assert!(!out.join(format!("frames/cam{c}/B00002.png")).exists(), "cam{c}'s stale second instant");
    }
    let record = std::fs::read_to_string(out.join("import.json")).expect("import.json");
    assert!(record.contains("frames/cam2/B00001.png"), "{record}");
    assert_eq!(load_scene(&out).expect("loads").frames.len(), 3);

    // A file of the user's beside them stays, and so does its folder.
    std::fs::write(out.join("frames/cam1/notes.txt"), "mine").expect("writes");
    // The split images themselves as the images of a new import into the same folder: the
    // scene reads them, so none is removed.
    let o = import_recordings(&calib, &out.join("frames"), &out, &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 3);
    for f in &scene.frames {
        assert!(scene.resolve(&f.file_path).is_file(), "{} is read by the scene", f.file_path.display());
    }
    assert!(out.join("frames/cam1/notes.txt").is_file());
}

/// A recording whose frames are not of the size its camera is calibrated for is refused as
/// soon as its first frame is decoded, naming the camera and the file the user gave: the
/// check of the scene's images came only after every frame was written, and named a decoded
/// frame (`frames/cam0/000000.tif`) that the failed import had removed again.
#[test]
fn recordings_of_another_size_than_the_calibration_are_refused_naming_the_recording() {
    let dir = tempfile::tempdir().expect("tempdir");
    let wider: Vec<(String, Camera)> = rig()
        .into_iter()
        .enumerate()
        .map(|(i, (_, mut c))| {
            c.intrinsics.width = 40;
            (format!("cam{}", i + 1), c)
        })
        .collect();
    let calib = dir.path().join("wider.yml");
    write_opencv(&calib, &wider).expect("writes calibration");

    let videos = dir.path().join("videos");
    std::fs::create_dir_all(&videos).expect("mkdir");
    for n in ["cam1", "cam2", "cam3"] {
        std::fs::copy(ramp_video(), videos.join(format!("{n}.avi"))).expect("copies the fixture");
    }
    let o = import_recordings(&calib, &videos, &dir.path().join("from_videos"), &[]);
    let err = stderr(&o);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("camera cam1") && err.contains("cam1.avi: frame 0 is 32x24 pixels") && err.contains("for 40x24"),
        "{err}"
    );
    assert!(!err.contains("000000.tif"), "names a decoded frame, not the video: {err}");

    let rec = dir.path().join("rec");
    davis_file(&rec.join("B00001.im7"), &[100, 200, 300], &["1", "2", "3"]);
    let o = import_recordings(&calib, &rec, &dir.path().join("from_davis"), &[]);
    let err = stderr(&o);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("camera cam1") && err.contains("B00001.im7: its frame of DaVis camera 1 is 32x24 pixels"),
        "{err}"
    );
    assert!(!err.contains("B00001.png"), "names a split image, not the DaVis file: {err}");
}

/// `import --metashape FILE --images IMAGES --aabb … EXTRA… -o OUT`.
fn import_metashape(file: &Path, images: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["import", "--metashape", s(file), "--images", s(images), "--aabb", "-10,-10,-10,10,10,10"];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["-o", s(out)]);
    fluidnerf(&args)
}

/// The rig exported by Metashape, its chunk rotated, moved and scaled: the cameras imported
/// project every point where those of the rig's OpenCV calibration do, and the scene is in
/// metres, the unit of Metashape's chunk coordinates.
#[test]
fn a_metashape_export_imports_as_the_opencv_calibration_of_its_cameras() {
    use fluidnerf_core::glam::{DMat3, EulerRot};
    let dir = tempfile::tempdir().expect("tempdir");
    let (calib, images) = rig_with_stills(dir.path());
    let chunk = metashape_xml::ChunkTransform {
        rotation: DMat3::from_euler(EulerRot::XYZ, 0.4, -1.1, 2.5),
        translation: DVec3::new(300.0, -20.0, 7.0),
        scale: 0.5,
    };
    let xml = dir.path().join("cameras.xml");
    std::fs::write(&xml, metashape_xml::metashape_xml(&rig(), Some(&chunk))).expect("writes");
    let by_opencv = dir.path().join("opencv");
    let args = ["import", "--opencv", s(&calib), "--images", s(&images), "--aabb", "-10,-10,-10,10,10,10", "-o"];
    let o = fluidnerf(&[&args[..], &[s(&by_opencv)]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let out = dir.path().join("metashape");
    let o = import_metashape(&xml, &images, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("imported 3 frames"));
    let (ours, theirs) = (load_scene(&out).expect("loads"), load_scene(&by_opencv).expect("loads"));
    assert_eq!((ours.units.as_str(), theirs.units.as_str()), ("m", "mm"));
    let mut checked = 0;
    for (a, b) in ours.frames.iter().zip(&theirs.frames) {
        assert_eq!(a.file_path, b.file_path);
        for p in [DVec3::ZERO, DVec3::new(5.0, -3.0, 2.0), DVec3::new(-7.0, 6.0, -4.0), DVec3::new(9.0, 9.0, 9.0)] {
            let (u, v) = (a.camera.project(p).expect("in front"), b.camera.project(p).expect("in front"));
            assert!((u - v).length() <= 1e-6 * v.length(), "{}: {p}: {u} vs {v}", a.file_path.display());
            checked += 1;
        }
    }
    assert_eq!(checked, 12);
    let record = std::fs::read_to_string(out.join("import.json")).expect("import.json");
    assert!(record.contains("\"metashape\"") && record.contains("cameras.xml"), "{record}");
    // --units overrides the chunk's metres.
    let o = import_metashape(&xml, &images, &out, &["--units", "mm", "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(load_scene(&out).expect("loads").units, "mm");
}

/// A camera Metashape did not align is refused, named, unless --skip-uncalibrated leaves it and
/// its image out; a disabled camera is left out with its image, with a warning; a camera on a
/// sensor the file does not define is refused naming both, and the failed import leaves nothing.
#[test]
fn unaligned_disabled_and_malformed_metashape_cameras() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, images) = rig_with_stills(dir.path());
    let full = metashape_xml::metashape_xml(&rig(), None);
    let xml = dir.path().join("cameras.xml");
    let out = dir.path().join("scene");
    // cam1 without its transform.
    let start = full.find("<camera id=\"1\"").expect("cam1");
    let (from, to) =
        (start + full[start..].find("<transform>").expect("t"), start + full[start..].find("</transform>").expect("t"));
    let unaligned = format!("{}{}", &full[..from], &full[to + "</transform>".len()..]);
    std::fs::write(&xml, &unaligned).expect("writes");
    let o = import_metashape(&xml, &images, &out, &[]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("cameras.xml")
            && e.contains("not aligned")
            && e.contains("cam1")
            && e.contains("--skip-uncalibrated"),
        "{e}"
    );
    assert!(!out.exists(), "a failed import leaves nothing behind");
    let o = import_metashape(&xml, &images, &out, &["--skip-uncalibrated"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("without a pose") && stderr(&o).contains("cam1"), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 2);
    assert!(stderr(&o).contains("internal frame"), "no chunk transform: the scale is arbitrary");
    assert_eq!(scene.units, "mm", "without a chunk transform the units are the other importers' default");

    // cam2 disabled: left out without --skip-uncalibrated.
    std::fs::write(&xml, full.replace("label=\"cam2\"", "label=\"cam2\" enabled=\"false\"")).expect("writes");
    let o = import_metashape(&xml, &images, &out, &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("disabled") && stderr(&o).contains("cam2"), "{}", stderr(&o));
    let names: Vec<String> =
        load_scene(&out).expect("loads").frames.iter().map(|f| f.file_path.display().to_string()).collect();
    assert_eq!(names.len(), 2);
    assert!(names.iter().all(|n| !n.contains("cam2")), "{names:?}");

    // A camera on a sensor the file lacks, and a fisheye sensor.
    let other = dir.path().join("other");
    for (text, needles) in [
        (full.replace("sensor_id=\"1\"", "sensor_id=\"4\""), ["camera `cam1`", "sensor 4"]),
        (full.replace("type=\"frame\">", "type=\"fisheye\">"), ["sensor 0", "`fisheye`"]),
    ] {
        std::fs::write(&xml, text).expect("writes");
        let o = import_metashape(&xml, &images, &other, &[]);
        assert_eq!(o.status.code(), Some(1));
        let e = stderr(&o);
        assert!(e.contains("cameras.xml") && needles.iter().all(|n| e.contains(n)), "{e}");
        assert!(!other.exists());
    }
}

/// `a` and `b` are the same pinhole camera to rounding (a camera decomposed from its
/// projection matrix).
fn assert_close(a: &Camera, b: &Camera) {
    let (ka, kb) = (&a.intrinsics, &b.intrinsics);
    assert_eq!((ka.width, ka.height), (kb.width, kb.height));
    for (x, y) in [(ka.fx, kb.fx), (ka.fy, kb.fy), (ka.cx, kb.cx), (ka.cy, kb.cy), (ka.skew, kb.skew)] {
        assert!((x - y).abs() < 1e-9 * (1.0 + x.abs()), "{ka:?} against {kb:?}");
    }
    let d = (a.world_from_camera.matrix3 - b.world_from_camera.matrix3).to_cols_array();
    assert!(d.iter().all(|e| e.abs() < 1e-12), "{d:?}");
    assert!((a.centre() - b.centre()).length() < 1e-9);
}

/// Projection matrices (one file per camera) and DLT coefficients (one camera per column, v
/// counted up from the bottom, as DLTdv writes them) give back the cameras they were made from,
/// sized by their images, one of them a series.
#[test]
fn projection_matrices_and_dlt_coefficients_become_a_scene() {
    use fluidnerf_io::calib::{flip_v, projection_of};
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cams: Vec<(String, Camera)> = rig();
    for (k, (_, c)) in cams.iter_mut().enumerate() {
        c.distortion = Distortion::default();
        c.intrinsics.skew = 0.25 * k as f64;
    }
    let images = dir.path().join("images");
    // Every camera a series of two images; each camera's size is its first image's.
    for (n, _) in &cams {
        image(&images.join(n), "t000.png");
        image(&images.join(n), "t001.png");
    }
    let matrices = dir.path().join("matrices");
    std::fs::create_dir_all(&matrices).expect("mkdir");
    for (n, c) in &cams {
        let p = projection_of(c);
        let text: String = p.iter().map(|r| format!("{:e} {:e} {:e} {:e}\n", r[0], r[1], r[2], r[3])).collect();
        std::fs::write(matrices.join(format!("{n}.txt")), format!("# P of {n}\n{text}")).expect("writes");
    }
    let out = dir.path().join("scene");
    let aabb = "-10,-10,-10,10,10,10";
    let o = fluidnerf(&["import", "--projection", s(&matrices), "--images", s(&images), "--aabb", aabb, "-o", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out).expect("loads");
    assert_eq!(scene.frames.len(), 6);
    for f in &scene.frames {
        let name = f.camera_name.as_deref().expect("named");
        assert_close(&f.camera, &cams.iter().find(|(n, _)| n == name).expect("a camera").1);
    }

    // DLT coefficients, v up from the bottom, one camera per column.
    let columns: Vec<Vec<f64>> = cams
        .iter()
        .map(|(_, c)| {
            let p = flip_v(projection_of(c), c.intrinsics.height);
            p.iter().flatten().map(|v| v / p[2][3]).take(11).collect()
        })
        .collect();
    let csv: String =
        (0..11).map(|i| columns.iter().map(|c| format!("{:e}", c[i])).collect::<Vec<_>>().join(",") + "\n").collect();
    let dlt = dir.path().join("rig_dltCoefs.csv");
    std::fs::write(&dlt, format!("cam0,cam1,cam2\n{csv}")).expect("writes");
    let out2 = dir.path().join("scene2");
    let args = ["import", "--projection", s(&dlt), "--images", s(&images), "--aabb", aabb, "-o", s(&out2)];
    let o = fluidnerf(&[&args[..], &["--bottom-left-origin"]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let scene = load_scene(&out2).expect("loads");
    for f in &scene.frames {
        let name = f.camera_name.as_deref().expect("named");
        let c = &cams.iter().find(|(n, _)| n == name).expect("a camera").1;
        let k = (&f.camera.intrinsics, &c.intrinsics);
        assert!((k.0.cy - k.1.cy).abs() < 1e-6 && (k.0.fx - k.1.fx).abs() < 1e-6, "{k:?}");
    }
    // Read without the flip, the coefficients are a mirrored camera, which sees the box behind it.
    let out3 = dir.path().join("scene3");
    let o = fluidnerf(&["import", "--projection", s(&dlt), "--images", s(&images), "--aabb", aabb, "-o", s(&out3)]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("--bottom-left-origin"), "{e}");

    // A camera without images, and a matrix that is no camera, are refused by name.
    let out4 = dir.path().join("scene4");
    std::fs::write(matrices.join("cam9.txt"), "1 0 0 0\n0 1 0 0\n0 0 1 1\n").expect("writes");
    let o =
        fluidnerf(&["import", "--projection", s(&matrices), "--images", s(&images), "--aabb", aabb, "-o", s(&out4)]);
    assert!(!o.status.success() && stderr(&o).contains("for camera(s) cam9"), "{}", stderr(&o));
    std::fs::remove_file(matrices.join("cam9.txt")).expect("rm");
    std::fs::write(matrices.join("cam1.txt"), "1 2 3 4\n2 4 6 8\n0 0 1 1\n").expect("writes");
    let o =
        fluidnerf(&["import", "--projection", s(&matrices), "--images", s(&images), "--aabb", aabb, "-o", s(&out4)]);
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("cam1.txt") && e.contains("`cam1`") && e.contains("singular"), "{e}");
}

/// A re-import removes the frames an earlier import decoded that the new scene does not read,
/// but never one it reads as a background: a recording's first frames, before the flow, are
/// the usual dark frames.
#[test]
fn a_reimport_keeps_the_earlier_frames_it_reads_as_backgrounds() {
    let (dir, calib, videos) = ramp_video_rig();
    let out = dir.path().join("scene");
    let o = import_recordings(&calib, &videos, &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    // One instant of every camera, its first frame subtracted as the background.
    let mut t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("transforms.json")).expect("reads")).expect("json");
    let frames: Vec<serde_json::Value> = t["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .filter(|f| f["file_path"].as_str().is_some_and(|p| p.ends_with("000002.tif")))
        .map(|f| {
            let mut f = f.clone();
            let image = out.join(f["file_path"].as_str().expect("path"));
            f["file_path"] = s(&image).into();
            f["background"] = s(&image.with_file_name("000000.tif")).into();
            f.as_object_mut().expect("object").remove("time");
            f
        })
        .collect();
    assert_eq!(frames.len(), 3);
    t["frames"] = frames.into();
    let edited = dir.path().join("one-instant.json");
    std::fs::write(&edited, serde_json::to_string(&t).expect("json")).expect("writes");
    let o = fluidnerf(&["import", "--transforms", s(&edited), "-o", s(&out), "--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for (n, _) in rig() {
        let frames = out.join("frames").join(&n);
        assert!(frames.join("000000.tif").is_file(), "{n}: the background frame is kept");
        assert!(frames.join("000002.tif").is_file(), "{n}: the image is kept");
        assert!(!frames.join("000003.tif").exists(), "{n}: a frame no longer read is removed");
    }
    let scene = load_scene(&out).expect("the scene written loads");
    assert!(fluidnerf_io::scene::load_preprocessed(&scene).is_ok(), "its backgrounds are there");
}

/// A calibration imported into its own folder is refused, even with --force: the scene written
/// there replaced it (a nerfstudio `transforms.json` by the one made from it).
#[test]
fn a_calibration_is_never_replaced_by_the_scene_imported_from_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("src");
    let synth = ["synth", "-q", "--preset", "demo", "--cameras", "3", "--pixels", "16", "--resolution", "8", "-o"];
    assert!(fluidnerf(&[&synth[..], &[s(&src)]].concat()).status.success());
    let file = src.join("transforms.json");
    let before = std::fs::read(&file).expect("reads");
    let spelled = src.join("../src/./transforms.json");
    for given in [&file, &spelled] {
        let o = fluidnerf(&["import", "--transforms", s(given), "-o", s(&src), "--force"]);
        let e = stderr(&o);
        assert!(!o.status.success() && e.contains("an input is never overwritten, even with --force"), "{e}");
    }
    assert_eq!(std::fs::read(&file).expect("kept"), before);
    assert!(!src.join("import.json").exists());
}

/// --bottom-left-origin turns round the v of projection matrices only; given with another
/// calibration it was accepted and ignored.
#[test]
fn bottom_left_origin_without_projection_matrices_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (calib, images) = rig_with_stills(dir.path());
    let out = dir.path().join("scene");
    let args = ["import", "--opencv", s(&calib), "--images", s(&images), "--aabb", "-1,-1,-1,1,1,1", "-o", s(&out)];
    let o = fluidnerf(&[&args[..], &["--bottom-left-origin"]].concat());
    let e = stderr(&o);
    assert!(!o.status.success() && e.contains("--bottom-left-origin") && e.contains("--projection"), "{e}");
    assert!(!out.exists(), "a refused import creates nothing");
    assert!(fluidnerf(&args).status.success(), "the same import without the flag succeeds");
}
