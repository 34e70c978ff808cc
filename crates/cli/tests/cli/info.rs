//! End-to-end tests of `fluidnerf info` on tiny scenes written in a temporary directory: a
//! good scene is described, and each kind of broken scene gives a clear error naming the file
//! and the problem, a non-zero exit and no panic.

use std::path::Path;
use std::process::{Command, Output};

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Camera, Frame, Image, Intrinsics, Scene, ThinLens, TruthRef, Volume};
use fluidnerf_io::image::{write_png16_counts, write_tiff_f32};

/// Four cameras on a ring around a 20 mm cube, 32 × 24 px, two time steps, the last frame held
/// out, 16-bit PNG images and one truth volume.
fn good_scene(dir: &Path) -> Scene {
    let aabb = Aabb::cube(DVec3::ZERO, 20.0);
    let k = Intrinsics { width: 32, height: 24, fx: 40.0, fy: 40.0, cx: 15.5, cy: 11.5, skew: 0.0 };
    let mut frames = Vec::new();
    for c in 0..4 {
        let a = c as f64 / 4.0 * std::f64::consts::TAU;
        let mut camera = Camera::look_at(k, DVec3::new(80.0 * a.cos(), 80.0 * a.sin(), 10.0), DVec3::ZERO, DVec3::Z);
        if c == 0 {
            camera.lens = Some(ThinLens::from_f_number(60.0, 3.5, -0.2, 0.01));
        }
        let file = format!("images/c{c}.png");
        let img = Image::from_vec(32, 24, (0..32 * 24).map(|i| (i % 97 + 100 * c) as f32).collect());
        write_png16_counts(&dir.join(&file), &img).expect("writes image");
        frames.push(Frame {
            camera,
            file_path: file.into(),
            time: Some((c % 2) as f64 * 0.5),
            camera_name: Some(format!("cam{}", c / 2)),
            holdout: c == 3,
        });
    }
    let vol = Volume::from_fn([8, 8, 8], aabb, |p| (p.x + 10.0) as f32);
    fluidnerf_io::volume::write_npy(&dir.join("truth/t0.npy"), &vol).expect("writes truth");
    let scene = Scene {
        root: dir.to_path_buf(),
        aabb,
        units: "mm".into(),
        intensity_scale: 1.0,
        frames,
        truth: vec![TruthRef { time: Some(0.0), file_path: "truth/t0.npy".into() }],
    };
    fluidnerf_io::scene::save_scene(&scene, dir).expect("writes scene");
    scene
}

fn info(scene: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .arg("info")
        .arg(scene)
        .env("RUST_LOG", "warn")
        .output()
        .expect("runs fluidnerf")
}

fn text(o: &Output) -> (String, String) {
    (String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

/// A failed run: non-zero exit, no panic, and stderr naming every `needle`.
fn assert_fails_with(o: &Output, needles: &[&str]) {
    let (stdout, stderr) = text(o);
    assert_eq!(o.status.code(), Some(1), "must exit with 1\nstdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(!stderr.contains("panicked"), "panic:\n{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "stderr must mention {n:?}:\n{stderr}\nstdout:\n{stdout}");
    }
}

#[test]
fn good_scene_is_described() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    for needle in [
        "4 frames, 2 named cameras, 2 time steps, 1 held out",
        "frame 0: images/c0.png  camera cam0  time 0",
        "frame 3: images/c3.png  camera cam1  time 0.5  [held out]",
        "centre (80.000, 0.000, 10.000) mm",
        "intrinsics 32x24 px, fx 40 fy 40, cx 15.5 cy 11.5",
        "distortion: none",
        "thin lens: f 60 mm, f/3.500",
        "sees 100.0% of the box",
        "image 32x24 16-bit, values 300 .. 396",
        // Ramps: no noise, and so the automatic settings' clean choice.
        "noise 0.00 % of the range",
        "training images' noise (median of the estimates): 0.00 % of their range, clean",
        // Two instants: tr-fast by default, which starts from no voxel run.
        "clean: automatic settings draw rays over each pixel's area (a --start-method auto run per instant",
        "8-bit images: linear",
        "time steps: 0, 0.5",
        "held-out frames: 3",
        "8x8x8 voxels",
        "no problems found",
    ] {
        assert!(stdout.contains(needle), "stdout must contain {needle:?}:\n{stdout}");
    }
}

/// A run reads the noise of the images it trains on, after the scene's background: a real-like
/// recording's background frames hold the dark noise over a raised floor, which read from the
/// raw images came out at 1.03 % (clean, ASART) where the run measured 1.72 % and started from
/// SART-TV.
#[test]
fn the_noise_is_read_after_the_background_as_a_run_reads_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = dir.path().join("scene");
    let o = Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .args(["synth", "-q", "-p", "real-like-small", "--pixels", "32", "--resolution", "24"])
        .args(["--dark-noise", "0.007", "-o"])
        .arg(&scene)
        .output()
        .expect("runs fluidnerf");
    assert!(o.status.success(), "{}", text(&o).1);
    let o = info(&scene);
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("noisy: automatic settings start from SART-TV, one ray per pixel"), "{stdout}");
}

#[test]
fn camera_missing_the_box_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    // Turn camera 2 around: it looks away from the box.
    let cam = &mut scene.frames[2].camera;
    let centre = cam.centre();
    *cam = Camera::look_at(cam.intrinsics, centre, 2.0 * centre, DVec3::Z);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    assert_fails_with(
        &info(dir.path()),
        &["transforms.json", "frame 2", "images/c2.png", "does not see the reconstruction box"],
    );
}

/// A camera of very short focal length has a very wide view: it images the box a fraction of a
/// pixel across, and sees it as long as a pixel's ray crosses the box. Where the box falls
/// between pixel centres, the error says so rather than that the camera does not see it.
#[test]
fn a_camera_with_a_short_focal_length_sees_the_box() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    let cam = &mut scene.frames[2].camera;
    let centre = cam.centre();
    let k = Intrinsics { fx: 0.5, fy: 0.5, cx: 16.0, cy: 12.0, ..cam.intrinsics };
    *cam = Camera::look_at(k, centre, DVec3::ZERO, DVec3::Z);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("frame 2: images/c2.png"), "{stdout}");

    let cam = &mut scene.frames[2].camera;
    let k = Intrinsics { cx: 15.5, cy: 11.5, ..cam.intrinsics };
    *cam = Camera::look_at(k, centre, DVec3::ZERO, DVec3::Z);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    assert_fails_with(
        &info(dir.path()),
        &["transforms.json", "frame 2", "images/c2.png", "in the camera's view", "falls between pixel centres"],
    );
    // A box imaged large, but sheared past the image, is not said to fall between pixel centres.
    let cam = &mut scene.frames[2].camera;
    let k = Intrinsics { fx: 40.0, fy: 40.0, skew: 1e9, ..cam.intrinsics };
    *cam = Camera::look_at(k, centre, DVec3::ZERO, DVec3::Z);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    assert_fails_with(&o, &["frame 2", "images/c2.png", "does not see the reconstruction box"]);
    assert!(!text(&o).1.contains("between pixel centres"), "{}", text(&o).1);
}

/// Coefficients far from any lens's, that the scene still allows, are described in short:
/// `{}` wrote a distortion coefficient of 1e-300 as 302 digits.
#[test]
fn extreme_coefficients_are_described_in_short() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    scene.frames[1].camera.distortion.k2 = 1e-300;
    scene.frames[1].camera.distortion.p1 = -2.5e-200;
    scene.frames[1].camera.intrinsics.skew = 1e-250;
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("skew 1e-250"), "{stdout}");
    assert!(stdout.contains("k2 1e-300 p1 -2.5e-200 p2 0"), "{stdout}");
    // The description's lines (warnings are sentences, and as long as they need).
    assert!(stdout.lines().filter(|l| !l.starts_with("warning:")).all(|l| l.chars().count() < 200), "{stdout}");
}

/// A camera whose focal length was mistyped saw the scene's light where its rays miss the box;
/// `info` said only that its image held 23 times the median's light, and found no problem.
#[test]
fn light_where_a_cameras_rays_miss_the_box_is_warned_of_naming_the_frame() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    crate::common::demo_scene(d, "jet", 6, 32, 24, &[]);
    let clean = info(&d.join("scene"));
    let (stdout, _) = text(&clean);
    assert!(clean.status.success() && !stdout.contains("lies on pixels whose rays miss the box"), "{stdout}");
    assert!(stdout.contains("light on pixels whose rays miss the box: at most 0.0% of an image's"), "{stdout}");
    crate::common::edit_json(&d.join("scene/transforms.json"), |t| {
        let frame = &mut t["frames"][1];
        frame["fl_x"] = 60.0.into();
        frame["fl_y"] = 60.0.into();
    });
    let o = info(&d.join("scene"));
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    let warned: Vec<&str> = stdout.lines().filter(|l| l.contains("lies on pixels whose rays miss the box")).collect();
    assert_eq!(warned.len(), 1, "{stdout}");
    assert!(warned[0].starts_with("warning: frame 1 (images/cam001.png): "), "{stdout}");
    assert!(warned[0].contains("the camera's calibration (focal length, pose) or the box may be wrong"), "{stdout}");
}

/// A distortion that cannot be inverted at the image's edges stopped every method after the
/// scene was taken, with an error that named no camera; the scene is refused, naming the frame.
#[test]
fn a_distortion_not_invertible_at_the_image_edges_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    scene.frames[1].camera.distortion.k1 = 1e300;
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    assert_fails_with(
        &o,
        &["transforms.json", "frame 1", "images/c1.png", "lens undistortion did not converge for pixel"],
    );
}

/// A scene whose every frame is held out leaves every run nothing to reconstruct from: each
/// refuses it, and so does `info`, which found no problem in it.
#[test]
fn a_scene_with_every_frame_held_out_is_a_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    scene.frames.iter_mut().for_each(|f| f.holdout = true);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    assert_fails_with(&o, &["transforms.json", "every frame is held out"]);
    assert!(!text(&o).0.contains("no problems found"), "{}", text(&o).0);
}

#[test]
fn image_size_disagreeing_with_intrinsics_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    write_png16_counts(&dir.path().join("images/c1.png"), &Image::zeros(30, 24)).expect("writes image");
    let o = info(dir.path());
    assert_fails_with(&o, &["c1.png", "30x24", "32x24"]);
}

#[test]
fn missing_image_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    std::fs::remove_file(dir.path().join("images/c3.png")).expect("removes");
    assert_fails_with(&info(dir.path()), &["image file not found", "c3.png"]);
}

#[test]
fn nan_pixel_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    let mut img = Image::zeros(32, 24);
    img.set(7, 5, f32::NAN);
    write_tiff_f32(&dir.path().join("images/c0.tif"), &img).expect("writes image");
    scene.frames[0].file_path = "images/c0.tif".into();
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    assert_fails_with(&info(dir.path()), &["c0.tif", "(col 7, row 5)", "NaN"]);
}

#[test]
fn malformed_json_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    let file = dir.path().join("transforms.json");
    let mut s = std::fs::read_to_string(&file).expect("reads");
    s.truncate(s.len() / 2);
    std::fs::write(&file, s).expect("writes");
    assert_fails_with(&info(&file), &["transforms.json", "malformed JSON", "line"]);
}

#[test]
fn missing_scene_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    assert_fails_with(&info(&dir.path().join("nothing")), &["scene file not found", "nothing"]);
}

fn info_with_log(scene: &Path, level: &str) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .arg("info")
        .arg(scene)
        .env("RUST_LOG", level)
        .output()
        .expect("runs fluidnerf")
}

/// Keys NeRF tools write in every frame give one summary line each for the routine and the
/// unknown ones, never one line per frame.
#[test]
fn unknown_keys_are_summarised_in_one_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    let file = dir.path().join("transforms.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("reads")).expect("json");
    v["ply_file_path"] = serde_json::json!("points.ply");
    v["my_setting"] = serde_json::json!(1);
    for i in 0..4 {
        v["frames"][i]["colmap_im_id"] = serde_json::json!(i);
        v["frames"][i]["exposure_note"] = serde_json::json!("f/8");
    }
    std::fs::write(&file, v.to_string()).expect("writes");
    let o = info_with_log(dir.path(), "info");
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    let lines = |needle: &str| stderr.lines().filter(|l| l.contains(needle)).count();
    assert_eq!(lines("exposure_note"), 1, "{stderr}");
    assert_eq!(lines("colmap_im_id"), 1, "{stderr}");
    assert!(
        stderr.contains("ignoring unknown key(s) \"exposure_note\" (in 4 frames), \"my_setting\" (top level)"),
        "{stderr}"
    );
    assert!(stderr.contains("not used by fluidnerf: \"colmap_im_id\" (in 4 frames)"), "{stderr}");
    // Routine keys are not worth a warning.
    let o = info_with_log(dir.path(), "warn");
    assert!(!text(&o).1.contains("colmap_im_id"), "{}", text(&o).1);
}

/// A pinhole camera_model with distortion coefficients, both at the top level, gave one
/// warning per frame (hundreds for a long recording); it is one line for the file.
#[test]
fn a_pinhole_model_with_distortion_is_warned_about_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    let file = dir.path().join("transforms.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("reads")).expect("json");
    v["camera_model"] = serde_json::json!("PINHOLE");
    v["k1"] = serde_json::json!(0.01);
    std::fs::write(&file, v.to_string()).expect("writes");
    let o = info_with_log(dir.path(), "warn");
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| l.contains("with distortion coefficients")).collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(lines[0].contains("4 frame(s) (the first: frame 0) have camera_model PINHOLE"), "{stderr}");
}

#[test]
fn an_8_bit_image_among_16_bit_ones_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    image::GrayImage::from_raw(32, 24, vec![9; 32 * 24])
        .expect("buffer")
        .save(dir.path().join("images/c2.png"))
        .expect("saves");
    assert_fails_with(&info(dir.path()), &["frame 2", "c2.png", "8-bit image among 16-bit ones", "257"]);
}

/// Writes a 16-bit grey TIFF of 32 × 24 px with one extra sample per pixel of the kind `extra`:
/// all counts 500, the extra sample at its largest value but for the first pixel's, `first`.
fn grey_with_extra_sample(path: &Path, extra: tiff::tags::ExtraSamples, first: u16) {
    use tiff::encoder::{colortype::Gray16, TiffEncoder};
    let file = std::fs::File::create(path).expect("creates");
    let mut enc = TiffEncoder::new(std::io::BufWriter::new(file)).expect("encoder");
    let mut image = enc.new_image::<Gray16>(32, 24).expect("image");
    image.extra_samples(&[extra]).expect("extra sample");
    let mut data: Vec<u16> = (0..32 * 24).flat_map(|_| [500, u16::MAX]).collect();
    data[1] = first;
    image.write_data(&data).expect("writes");
}

/// A TIFF's alpha (ExtraSamples 1 or 2) that is not fully opaque is warned of, as a PNG's is: it
/// often marks pixels to leave out, which a mask does, while fluidnerf reads every pixel. An
/// extra sample of no stated meaning is not alpha, and opaque alpha says nothing: both are
/// dropped without a word.
#[test]
fn a_tiffs_translucent_alpha_is_warned_of() {
    use tiff::tags::ExtraSamples;
    for (extra, first, warned) in [
        (ExtraSamples::UnassociatedAlpha, 0, true),
        (ExtraSamples::AssociatedAlpha, 0, true),
        (ExtraSamples::Unspecified, 0, false),
        (ExtraSamples::UnassociatedAlpha, u16::MAX, false),
    ] {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut scene = good_scene(dir.path());
        scene.frames[1].file_path = "images/c1.tif".into();
        grey_with_extra_sample(&dir.path().join("images/c1.tif"), extra, first);
        fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
        let o = info_with_log(dir.path(), "warn");
        let (stdout, stderr) = text(&o);
        assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
        let said = stderr.contains("c1.tif: its alpha channel is not fully opaque (1 of 768 pixels)");
        assert_eq!(said, warned, "{extra:?}, first alpha {first}: {stderr}");
        assert_eq!(stderr.contains("mask_path"), warned, "{stderr}");
    }
}

#[test]
fn negative_pixel_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    for (c, f) in scene.frames.iter_mut().enumerate() {
        let mut img = Image::from_vec(32, 24, vec![1.0; 32 * 24]);
        if c == 1 {
            img.set(3, 2, -0.25);
        }
        f.file_path = format!("images/c{c}.tif").into();
        write_tiff_f32(&dir.path().join(&f.file_path), &img).expect("writes image");
    }
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    assert_fails_with(&info(dir.path()), &["frame 1", "c1.tif", "pixel (col 3, row 2) is -0.25", "negative"]);
}

#[test]
fn two_frames_on_one_image_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    scene.frames[2].file_path = "./images/c0.png".into();
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    assert_fails_with(&info(dir.path()), &["frames 0 and 2 both use the image", "c0.png"]);
}

#[test]
fn the_same_image_spelled_otherwise_is_found() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    scene.frames[2].file_path = dir.path().join("images/c0.png");
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(dir.path().join("images/c1.png"), dir.path().join("images/link.png")).expect("link");
        assert_fails_with(&info(dir.path()), &["frames 0 and 2 both use the image"]);
        scene.frames[2].file_path = "images/link.png".into();
        fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
        assert_fails_with(&info(dir.path()), &["frames 1 and 2 both use the image", "link.png"]);
    }
}

#[test]
fn black_and_saturated_images_are_flagged() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    write_png16_counts(&dir.path().join("images/c1.png"), &Image::zeros(32, 24)).expect("writes image");
    let mut bright = Image::from_vec(32, 24, vec![1000.0; 32 * 24]);
    bright.set(4, 5, 65535.0);
    bright.set(6, 5, 65535.0);
    write_png16_counts(&dir.path().join("images/c2.png"), &bright).expect("writes image");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    assert!(stdout.contains("warning: frame 1 (images/c1.png): the image is black"), "{stdout}");
    assert!(stdout.contains("warning: frame 2 (images/c2.png): 2 pixel(s) at the 16-bit full scale"), "{stdout}");
}

#[test]
fn masks_are_checked_as_a_run_reads_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    write_png16_counts(&dir.path().join("masks/m.png"), &Image::from_vec(8, 8, vec![255.0; 64])).expect("writes");
    let file = dir.path().join("transforms.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("reads")).expect("json");
    v["frames"][1]["mask_path"] = serde_json::json!("masks/m.png");
    std::fs::write(&file, v.to_string()).expect("writes");
    assert_fails_with(&info(dir.path()), &["m.png", "8x8"]);
}

/// What preprocessing the scene asks for is said, and its flat fields are read as a run reads
/// them: their range once normalised, or the problem with the file and frame named.
#[test]
fn flat_fields_are_described_and_checked_as_a_run_reads_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    let o = info(dir.path());
    let (stdout, _) = text(&o);
    assert!(stdout.contains("preprocessing: background: none; flat field: none; masks: 0 frame(s)"), "{stdout}");
    let ramp = Image::from_vec(32, 24, (0..32 * 24).map(|i| 400.0 + 20.0 * (i % 32) as f32).collect());
    write_png16_counts(&dir.path().join("flat/f.png"), &ramp).expect("writes");
    let file = dir.path().join("transforms.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).expect("reads")).expect("json");
    v["flat_field"] = serde_json::json!("flat/f.png");
    std::fs::write(&file, v.to_string()).expect("writes");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("flat field: one flat frame (4 frames)"), "{stdout}");
    // The ramp 400 … 1020 has mean 710: 0.563 … 1.437.
    assert!(stdout.contains("flat fields (normalised to mean 1 over the used pixels): 0.563 .. 1.437"), "{stdout}");
    let mut dark = ramp.clone();
    dark.set(3, 4, 0.0);
    write_png16_counts(&dir.path().join("flat/f.png"), &dark).expect("writes");
    assert_fails_with(
        &info(dir.path()),
        &[
            "frame 0 (images/c0.png, camera cam0), `flat_field`",
            "flat/f.png",
            "has 1 of its 768 used pixel(s) at or below 5 %",
            "(col 3, row 4)",
        ],
    );
}

#[test]
fn cameras_inside_or_near_the_box() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    // 0.5 mm outside the box face x = 10, still looking at its centre.
    let k = scene.frames[1].camera.intrinsics;
    scene.frames[1].camera = Camera::look_at(k, DVec3::new(10.5, 0.0, 0.0), DVec3::new(-1.0, 0.0, 0.0), DVec3::Z);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("warning: frame 1 (images/c1.png): the camera is only 0.500 mm from the box"), "{stdout}");
    scene.frames[1].camera = Camera::look_at(k, DVec3::new(9.5, 0.0, 0.0), DVec3::new(-1.0, 0.0, 0.0), DVec3::Z);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    assert_fails_with(&info(dir.path()), &["frame 1", "c1.png", "inside the reconstruction box"]);
}

/// Two cameras of one instant at one place (a calibration copied from one camera to another)
/// are warned about; one camera at the same place at two instants is not.
#[test]
fn two_cameras_at_one_place_are_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    scene.frames[1].camera = scene.frames[0].camera.clone();
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let (stdout, stderr) = text(&info(dir.path()));
    assert!(!stdout.contains("one place") && !stderr.contains("one place"), "{stdout}\n{stderr}");
    scene.frames[2].camera = scene.frames[0].camera.clone();
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stdout.contains(
            "warning: frame 0 (images/c0.png, camera cam0) and frame 2 (images/c2.png, camera cam1) stand at one place"
        ) && stdout.contains("at time 0")
            && stdout.contains("calibration is most likely the other's copied"),
        "{stdout}"
    );
}

#[test]
fn truth_of_another_grid_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    let other = Volume::from_fn([8, 8, 4], scene.aabb, |_| 1.0);
    fluidnerf_io::volume::write_npy(&dir.path().join("truth/t1.npy"), &other).expect("writes truth");
    scene.truth.push(TruthRef { time: Some(0.5), file_path: "truth/t1.npy".into() });
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    assert_fails_with(&info(dir.path()), &["t1.npy", "8x8x4 voxels", "8x8x8"]);
}

/// Ground truth at a time no frame has is never scored by a time-resolved run: a warning.
#[test]
fn truth_at_a_time_no_frame_has_is_flagged() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scene = good_scene(dir.path());
    scene.truth[0].time = Some(-0.5);
    fluidnerf_io::scene::save_scene(&scene, dir.path()).expect("writes scene");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stdout.contains("warning: ground truth at time -0.5 matches no frame's time (frames at 0, 0.5)"),
        "{stdout}"
    );
}

/// A truth with negative voxels is warned of, with their count and the lowest value (it was
/// listed as "values -5 .. 1" without a word, while negative image pixels are flagged).
#[test]
fn truth_with_negative_values_is_flagged() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = good_scene(dir.path());
    let negative = Volume::from_fn([8, 8, 8], scene.aabb, |p| if p.x < 0.0 { -0.25 } else { 1.0 });
    fluidnerf_io::volume::write_npy(&dir.path().join("truth/t0.npy"), &negative).expect("writes truth");
    let o = info(dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    assert!(stdout.contains("t0.npy: 256 voxel(s) are negative (down to -0.25)"), "{stdout}");
}

/// A truth that is zero throughout is a problem: eval refuses it and a run's NRMSE against it
/// is NaN, yet info found no problem.
#[test]
fn truth_that_is_zero_throughout_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene = good_scene(dir.path());
    let zero = Volume::from_fn([8, 8, 8], scene.aabb, |_| 0.0);
    fluidnerf_io::volume::write_npy(&dir.path().join("truth/t0.npy"), &zero).expect("writes truth");
    assert_fails_with(&info(dir.path()), &["truth", "t0.npy", "every voxel is zero", "NRMSE"]);
}

/// A frame naming `c1.jpg` read `c1.png` without a word; a name without an extension (as NeRF
/// datasets write them) is matched as before, quietly.
#[test]
fn an_image_read_by_another_extension_than_named_is_warned_of() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    let path = dir.path().join("transforms.json");
    let original = std::fs::read_to_string(&path).expect("reads");
    std::fs::write(&path, original.replace("images/c1.png", "images/c1.jpg")).expect("writes");
    let o = info(dir.path());
    let (_, stderr) = text(&o);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("1 frame(s) name an image file that does not exist, and read the one image"), "{stderr}");
    assert!(stderr.contains("images/c1.jpg → images/c1.png"), "{stderr}");
    std::fs::write(&path, original.replace("images/c1.png", "images/c1")).expect("writes");
    let o = info(dir.path());
    let (_, stderr) = text(&o);
    assert!(o.status.success() && !stderr.contains("does not exist"), "{stderr}");
}

/// Training images that are each one value throughout, which every run refuses, passed `info`
/// with "no problems found".
#[test]
fn training_images_of_one_value_each_are_a_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    for c in 0..3 {
        let flat = Image::from_vec(32, 24, vec![1000.0; 32 * 24]);
        write_png16_counts(&dir.path().join(format!("images/c{c}.png")), &flat).expect("writes image");
    }
    assert_fails_with(&info(dir.path()), &["every training image is one value throughout", "1000 at every pixel"]);
    // One image of varied values among them, and the images carry something.
    let varied = Image::from_vec(32, 24, (0..32 * 24).map(|i| (i % 7) as f32).collect());
    write_png16_counts(&dir.path().join("images/c1.png"), &varied).expect("writes image");
    let o = info(dir.path());
    assert!(!text(&o).1.contains("one value throughout"), "{}", text(&o).1);
}

/// With several masks that fail, `info` named one of them at random (the thread that met its
/// failure first); now the first in frame order, with the others counted.
#[test]
fn several_failing_masks_are_named_in_frame_order() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    for (name, w) in [("m0.png", 32), ("m2.png", 16)] {
        let zero = Image::from_vec(w, 24, vec![0.0; w * 24]);
        write_png16_counts(&dir.path().join(name), &zero).expect("writes mask");
    }
    crate::common::edit_json(&dir.path().join("transforms.json"), |t| {
        t["frames"][0]["mask_path"] = "m0.png".into();
        t["frames"][2]["mask_path"] = "m2.png".into();
    });
    for _ in 0..3 {
        assert_fails_with(
            &info(dir.path()),
            &["m0.png: the mask of frame 0", "is all zero", "(the masks of frames 0, 2 fail; this is the first)"],
        );
    }
}

/// Colour images are reduced to luminance, so a channel clipped at full scale (a red dye or
/// flame at R = 255) read as a luminance of 54 and was never reported as saturated.
#[test]
fn a_colour_channel_at_full_scale_is_warned_of() {
    let dir = tempfile::tempdir().expect("tempdir");
    good_scene(dir.path());
    for c in 0..4 {
        let rgb = image::ImageBuffer::from_fn(32, 24, |x, y| {
            let v = ((x + 32 * y) % 97 + 100 * c) as u16;
            image::Rgb([if x < 3 { u16::MAX } else { v }, v, v])
        });
        image::DynamicImage::ImageRgb16(rgb).save(dir.path().join(format!("images/c{c}.png"))).expect("saves");
    }
    let (_, stderr) = text(&info(dir.path()));
    assert!(stderr.contains("72 pixel(s) have a colour channel at full scale, clipped in that channel"), "{stderr}");
}
