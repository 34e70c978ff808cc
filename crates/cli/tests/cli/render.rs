//! End-to-end tests of `fluidnerf render` on a tiny scene generated in a temporary directory.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{render_image, Aabb, Camera, Frame, Intrinsics, RenderSettings, Scene, Volume};

const SCALE: f64 = 2.0;

fn fluidnerf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf")).args(args).output().expect("runs the binary")
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The `render.json` a render wrote into `out`.
/// A path as a command-line argument.
fn d(p: &Path) -> String {
    p.to_str().expect("utf-8").to_string()
}

fn render_json(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("render.json")).expect("render.json")).expect("JSON")
}

/// A Gaussian blob in a 3 × 2 × 2 box, three cameras on a ring about x (images not needed).
fn make_scene(dir: &Path) -> (Scene, Volume) {
    let aabb = Aabb::new(DVec3::new(-1.5, -1.0, -1.0), DVec3::new(1.5, 1.0, 1.0));
    let vol =
        Volume::from_fn([24, 16, 16], aabb, |p| (-(p - DVec3::new(0.3, 0.1, 0.0)).length_squared() * 3.0).exp() as f32);
    fluidnerf_io::volume::write_npy(&dir.join("recon.npy"), &vol).expect("writes");
    let k = Intrinsics { width: 24, height: 20, fx: 30.0, fy: 30.0, cx: 11.5, cy: 9.5, skew: 0.0 };
    let frames = (0..3)
        .map(|c| {
            let a = c as f64 / 3.0 * std::f64::consts::TAU + 0.3;
            Frame {
                camera: Camera::look_at(k, DVec3::new(0.0, 7.0 * a.cos(), 7.0 * a.sin()), DVec3::ZERO, DVec3::X),
                file_path: format!("images/c{c}.tif").into(),
                time: None,
                camera_name: Some(format!("cam{c}")),
                holdout: false,
            }
        })
        .collect();
    let scene =
        Scene { root: dir.to_path_buf(), aabb, units: "mm".into(), intensity_scale: SCALE, frames, truth: vec![] };
    fluidnerf_io::scene::save_scene(&scene, &dir.join("transforms.json")).expect("writes the scene");
    (scene, vol)
}

#[test]
fn scene_camera_renders_match_the_reference_renderer() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (scene, vol) = make_scene(dir.path());
    let out = dir.path().join("views");
    let o = fluidnerf(&[
        "render",
        &d(&dir.path().join("recon.npy")),
        "--scene",
        &d(dir.path()),
        "--out",
        &d(&out),
        "--camera",
        "1",
        "--format",
        "tiff",
        "--projector",
        "rays",
    ]);
    ok(&o);
    let img = fluidnerf_io::image::read_image(&out.join("view_001.tif")).expect("reads");
    // The default step for a volume: half its voxel (0.125 mm here).
    let settings = RenderSettings { scale: SCALE, step: Some(0.0625), ..Default::default() };
    let want = render_image(&vol, &scene.frames[1].camera, &scene.aabb, &settings).expect("renders");
    assert_eq!((img.width, img.height), (24, 20));
    let peak = want.min_max().1;
    assert!(peak > 0.1);
    for (a, b) in img.data.iter().zip(&want.data) {
        assert!((a - b).abs() <= 1e-5 * peak, "{a} vs {b}");
    }
    // 16-bit PNG of every camera, with the scale in render.json.
    let out16 = dir.path().join("views16");
    ok(&fluidnerf(&[
        "render",
        &d(&dir.path().join("recon.npy")),
        "--scene",
        &d(dir.path()),
        "--out",
        &d(&out16),
        "--projector",
        "rays",
    ]));
    let full_scale = render_json(&out16)["full_scale"].as_f64().expect("full_scale");
    // The views are the cameras' own size: no orbit width (once recorded as 320 px) is.
    assert_eq!(render_json(&out16).get("width"), None, "{}", render_json(&out16));
    let counts = fluidnerf_io::image::read_image(&out16.join("view_001.png")).expect("reads");
    for (c, b) in counts.data.iter().zip(&want.data) {
        let value = *c as f64 * full_scale / 65535.0;
        assert!((value - *b as f64).abs() <= 1e-4 * full_scale + 1e-6, "{value} vs {b}");
    }
    assert!(out16.join("view_002.png").exists());
}

#[test]
fn orbit_writes_views_and_a_turntable() {
    let dir = tempfile::tempdir().expect("tempdir");
    make_scene(dir.path());
    let out = dir.path().join("orbit");
    let (recon, scene) = (d(&dir.path().join("recon.npy")), d(dir.path()));
    // `render recon.npy --scene DIR --out OUT` and `extra`.
    let render = |out: &Path, extra: &[&str]| {
        let out = d(out);
        let mut args = vec!["render", recon.as_str(), "--scene", scene.as_str(), "--out", out.as_str()];
        args.extend_from_slice(extra);
        fluidnerf(&args)
    };
    ok(&render(&out, &["--orbit", "6", "--width", "48", "--supersample", "1"]));
    for k in 0..6 {
        assert!(out.join(format!("orbit_{k:03}.png")).exists());
    }
    let gif = std::fs::read(out.join("turntable.gif")).expect("a turntable");
    assert!(gif.starts_with(b"GIF89a"));
    assert_eq!(render_json(&out)["frame_ms"], 80, "the GIF's display time is recorded");
    assert_eq!(render_json(&out)["width"], 48, "the orbit views' width is recorded");
    // A display time a GIF cannot hold is refused, not clamped.
    for ms in ["0", "9", "655351", "4294967295"] {
        let o = render(&dir.path().join("slow"), &["--orbit", "2", "--frame-ms", ms]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("--frame-ms"), "--frame-ms {ms}: {err}");
    }
    let bad = render(&out, &["--camera", "7", "--force"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("3 frames"));
    // Rendered again over it with fewer views: the earlier views the new render.json does not
    // list are removed, not left to pass for this render's; other files stay.
    std::fs::write(out.join("notes.png"), "mine").expect("writes");
    ok(&render(&out, &["--orbit", "2", "--width", "48", "--force"]));
    let mut files: Vec<String> = std::fs::read_dir(&out)
        .expect("lists")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    assert_eq!(files, ["notes.png", "orbit_000.png", "orbit_001.png", "render.json", "turntable.gif"]);
    assert_eq!(render_json(&out)["outputs"].as_array().expect("a list").len(), 3);
    // --bake samples trained fields; on a volume it did nothing without a word.
    let baked = render(&dir.path().join("baked"), &["--camera", "0", "--bake", "32"]);
    ok(&baked);
    let err = String::from_utf8_lossy(&baked.stderr);
    assert!(err.contains("--bake has no effect") && err.contains("recon.npy is a volume"), "{err}");
}

/// A hash-grid field written as a run folder (model.json and weights), with smooth random
/// tables and an occupancy hull that leaves one corner of the box empty.
fn write_trained(dir: &Path, aabb: Aabb) {
    use fluidnerf_neural::occupancy::OccupancyGrid;
    use fluidnerf_neural::train::FieldMeta;
    use fluidnerf_neural::trained::{FieldConfig, ModelRecord};
    use fluidnerf_neural::{HashGridConfig, HashGridField, TrainableField};
    let cfg = HashGridConfig {
        levels: 4,
        log2_table_size: 12,
        base_resolution: 4,
        max_resolution: 16,
        init_scale: 0.0,
        ..HashGridConfig::default()
    };
    let mut field = HashGridField::new(&cfg, 3, 1).expect("valid config");
    let grid = field.grid_params();
    for (i, p) in field.params_mut()[..grid].iter_mut().enumerate() {
        *p = 0.4 * ((i as f32 * 0.37).sin() + (i as f32 * 0.011).cos());
    }
    let cells = (0..8 * 8 * 8).map(|i| !(i % 8 < 3 && (i / 8) % 8 < 3)).collect();
    let hull = OccupancyGrid::from_cells([8, 8, 8], cells).expect("8³ cells");
    let meta = FieldMeta { aabb, value_scale: 1.0, time_step: 1.0, occupancy: Some(hull.to_record()) };
    let record = ModelRecord { field: FieldConfig::HashGrid(cfg), input_dim: 3, meta };
    std::fs::create_dir_all(dir).expect("mkdir");
    std::fs::write(dir.join("model.json"), serde_json::to_string(&record).expect("json")).expect("writes");
    let bytes = fluidnerf_neural::weights::weights_bytes(&field).expect("weights");
    std::fs::write(dir.join("weights.safetensors"), bytes).expect("writes");
}

/// A scene of [`make_scene`] in a new folder, and a trained field of its box in `run/` there.
fn scene_and_trained_run() -> (tempfile::TempDir, Scene, PathBuf) {
    let dir = tempfile::tempdir().expect("tempdir");
    let (scene, _) = make_scene(dir.path());
    let run = dir.path().join("run");
    write_trained(&run, scene.aabb);
    (dir, scene, run)
}

/// `--bake off` renders a trained field exactly (the reference renderer on the loaded field);
/// `auto` bakes it on twice its finest level when the views' samples inside its hull
/// outnumber twice the grid's vertices there, and the baked images stay within 2 % NRMSE of
/// the exact ones; with a quarter of the rays it renders exactly; `render.json` records which
/// was done.
#[test]
fn trained_fields_render_exactly_or_baked() {
    let (dir, scene, run) = scene_and_trained_run();
    let render = |bake: &str, ss: usize| {
        let out = dir.path().join(format!("views-{bake}-{ss}"));
        let o = fluidnerf(
            &["render", &d(&run), "--scene", &d(dir.path()), "--out", &d(&out), "--format", "tiff", "-q"]
                .into_iter()
                .chain(["--projector", "rays", "--bake", bake, "--supersample", &ss.to_string()])
                .collect::<Vec<_>>(),
        );
        ok(&o);
        let images: Vec<Vec<f32>> = (0..3)
            .map(|c| fluidnerf_io::image::read_image(&out.join(format!("view_{c:03}.tif"))).expect("reads").data)
            .collect();
        (render_json(&out)["baked"].clone(), images)
    };
    let (field, _) = fluidnerf_neural::trained::load_trained(&run).expect("loads");
    let reference = |ss: usize| -> Vec<Vec<f32>> {
        let s = RenderSettings { scale: SCALE, supersample: ss, ..Default::default() };
        (0..3)
            .map(|c| render_image(field.as_ref(), &scene.frames[c].camera, &scene.aabb, &s).expect("renders").data)
            .collect()
    };
    let close = |a: &[Vec<f32>], b: &[Vec<f32>]| {
        a.iter().flatten().zip(b.iter().flatten()).all(|(a, b)| (a - b).abs() <= 1e-5 * b.abs().max(1.0))
    };
    let (exact_json, exact) = render("off", 2);
    assert!(exact_json.is_null());
    assert!(close(&exact, &reference(2)));
    let (auto_json, baked) = render("auto", 2);
    assert_eq!(auto_json, serde_json::json!([32, 32, 32]), "twice the finest level (16)");
    let (mut se, mut ss) = (0.0f64, 0.0f64);
    for (a, b) in baked.iter().flatten().zip(exact.iter().flatten()) {
        se += ((a - b) as f64).powi(2);
        ss += (*b as f64).powi(2);
    }
    let nrmse = (se / ss).sqrt();
    assert!(ss > 0.0 && nrmse < 0.02, "baked vs exact NRMSE {nrmse}");
    // One ray per pixel: 61 k samples inside the hull, against twice its 31 k vertices.
    let (few_json, few) = render("auto", 1);
    assert!(few_json.is_null(), "too few samples to bake: {few_json}");
    assert!(close(&few, &reference(1)));
}

fn nrmse(x: &[f32], reference: &[f32]) -> f64 {
    let (mut se, mut ss) = (0.0f64, 0.0f64);
    for (a, b) in x.iter().zip(reference) {
        se += ((a - b) as f64).powi(2);
        ss += (*b as f64).powi(2);
    }
    assert!(ss > 0.0, "an empty reference");
    (se / ss).sqrt()
}

/// `--projector footprint` renders a volume with the footprint projector exactly as the
/// classical methods project it, close to the ray renderer's images with many rays per pixel;
/// a trained field is sampled on twice its finest level first; options that only apply to
/// rays, `--bake off`, and voxels too wide for the projector are refused before anything is
/// written.
#[test]
fn footprint_renders_match_the_projector_and_the_ray_renderer() {
    use fluidnerf_classical::projector::{FootprintProjector, Grid, Projector};
    let dir = tempfile::tempdir().expect("tempdir");
    let (scene, vol) = make_scene(dir.path());
    let render = |recon: &Path, name: &str, extra: &[&str]| -> Output {
        let out = dir.path().join(name);
        let args = ["render", &d(recon), "--scene", &d(dir.path()), "--out", &d(&out), "--format", "tiff"];
        fluidnerf(&args.iter().copied().chain(extra.iter().copied()).collect::<Vec<_>>())
    };
    let read = |name: &str, c: usize| {
        fluidnerf_io::image::read_image(&dir.path().join(name).join(format!("view_{c:03}.tif"))).expect("reads").data
    };
    let cameras: Vec<Camera> = scene.frames.iter().map(|f| f.camera.clone()).collect();

    ok(&render(&dir.path().join("recon.npy"), "fp", &["--projector", "footprint"]));
    let p = FootprintProjector::new(Grid::new(vol.dims, vol.aabb), &cameras, SCALE).expect("projector");
    for (c, camera) in cameras.iter().enumerate() {
        let mut want = vec![0f32; camera.width() * camera.height()];
        p.forward(c, &vol.data, &mut want);
        assert_eq!(read("fp", c), want, "camera {c}: the projector's image");
        let s = RenderSettings { scale: SCALE, supersample: 4, ..Default::default() };
        let rays = render_image(&vol, camera, &scene.aabb, &s).expect("renders");
        let e = nrmse(&want, &rays.data);
        assert!(e < 0.02, "camera {c}: footprint against 4 × 4 rays per pixel, NRMSE {e}");
    }
    assert_eq!(render_json(&dir.path().join("fp"))["projector"], "footprint");

    let run = dir.path().join("run");
    write_trained(&run, scene.aabb);
    ok(&render(&run, "fp-field", &["--projector", "footprint"]));
    ok(&render(&run, "rays-field", &["--bake", "off", "--supersample", "4"]));
    assert_eq!(
        render_json(&dir.path().join("fp-field"))["baked"],
        serde_json::json!([32, 32, 32]),
        "twice the finest level (16)"
    );
    for c in 0..3 {
        let e = nrmse(&read("fp-field", c), &read("rays-field", c));
        assert!(e < 0.015, "camera {c}: the field's footprint render against 4 × 4 exact rays, NRMSE {e}");
    }

    for (extra, says) in [
        (&["--projector", "footprint", "--supersample", "2"][..], "--supersample"),
        (&["--projector", "footprint", "--step", "0.1"][..], "--step"),
        (&["--projector", "footprint", "--bake", "off"][..], "--bake"),
        (&["--projector", "footprint", "--orbit", "2", "--width", "4000"][..], "63 pixels"),
    ] {
        let o = render(&run, "refused", extra);
        assert!(!o.status.success(), "{extra:?} should be refused");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(says), "{extra:?}: {err}");
    }
    assert!(!dir.path().join("refused").exists(), "refused before anything is written");
}

/// `--projector auto` (the default) takes the footprint projector where the cells image at
/// most 1.5 px wide: the scene cameras here, for a volume (the same images as
/// `--projector footprint`) and for a field (sampled on its finest level's own cells, within
/// 2 % NRMSE of 4 × 4 exact rays per pixel). For a field whose finest cells image wider, it
/// samples a grid twice as fine where those cells image at most 1.5 px (a small orbit view,
/// within 2 % of exact rays too). It takes rays where the cells image wider (a large orbit
/// view) and where an option asks for rays. `render.json` records the choice.
#[test]
fn auto_takes_the_footprint_projector_where_pixels_span_the_cells() {
    let (dir, _, run) = scene_and_trained_run();
    let render = |recon: &Path, name: &str, extra: &[&str]| -> serde_json::Value {
        let out = dir.path().join(name);
        let args = ["render", &d(recon), "--scene", &d(dir.path()), "--out", &d(&out), "--format", "tiff", "-q"];
        ok(&fluidnerf(&args.iter().copied().chain(extra.iter().copied()).collect::<Vec<_>>()));
        render_json(&out)
    };
    let read = |name: &str, c: usize| {
        fluidnerf_io::image::read_image(&dir.path().join(name).join(format!("view_{c:03}.tif"))).expect("reads").data
    };
    let volume = dir.path().join("recon.npy");
    assert_eq!(render(&volume, "auto", &[])["projector"], "footprint");
    render(&volume, "fp", &["--projector", "footprint"]);
    for c in 0..3 {
        assert_eq!(read("auto", c), read("fp", c), "camera {c}");
    }
    assert_eq!(render(&volume, "ss", &["--supersample", "2"])["projector"], "rays");
    assert_eq!(render(&volume, "step", &["--step", "0.05"])["projector"], "rays");
    assert_eq!(render(&volume, "orbit", &["--orbit", "2", "--width", "400"])["projector"], "rays");

    let field = render(&run, "auto-field", &[]);
    assert_eq!(field["projector"], "footprint");
    assert_eq!(field["baked"], serde_json::json!([16, 16, 16]), "the finest level's own cells");
    render(&run, "exact", &["--bake", "off", "--supersample", "4"]);
    for c in 0..3 {
        let e = nrmse(&read("auto-field", c), &read("exact", c));
        assert!(e < 0.02, "camera {c}: the field's footprint render against 4 × 4 exact rays, NRMSE {e}");
    }
    let off = render(&run, "off", &["--bake", "off"]);
    assert_eq!(off["projector"], "rays");
    // The step the rays took, resolved: a field's was recorded as null.
    let aabb = fluidnerf_io::scene::load_scene(dir.path()).expect("the scene").aabb;
    assert_eq!(off["step"], aabb.size().min_element() / 256.0, "{off}");
    assert_eq!(field["step"], serde_json::Value::Null, "the footprint projector takes no steps");

    let orbit = |name: &str, width: &str, extra: &[&str]| {
        render(&run, name, &[&["--orbit", "2", "--width", width][..], extra].concat())
    };
    let small = orbit("small-orbit", "40", &[]);
    assert_eq!(small["projector"], "footprint", "{small}");
    assert_eq!(small["baked"], serde_json::json!([32, 32, 32]), "a grid twice as fine as the finest level");
    orbit("small-exact", "40", &["--bake", "off", "--supersample", "4"]);
    let read_orbit = |name: &str, k: usize| {
        fluidnerf_io::image::read_image(&dir.path().join(name).join(format!("orbit_{k:03}.tif"))).expect("reads").data
    };
    for k in 0..2 {
        let e = nrmse(&read_orbit("small-orbit", k), &read_orbit("small-exact", k));
        assert!(e < 0.02, "orbit view {k}: the field's footprint render against 4 × 4 exact rays, NRMSE {e}");
    }
    assert_eq!(orbit("large-orbit", "200", &[])["projector"], "rays");
}

/// Views too large to hold are refused before the projector and the bake are chosen: for a
/// field that choice walks every pixel's ray through its hull, which for 3600 orbit views of
/// 16384 px ran for minutes before the same refusal.
#[test]
fn a_field_rendered_into_views_too_large_to_hold_is_refused_first() {
    let (dir, _, run) = scene_and_trained_run();
    let out = dir.path().join("views");
    let o = fluidnerf(&[
        "render",
        &d(&run),
        "--scene",
        &d(dir.path()),
        "-o",
        &d(&out),
        "--orbit",
        "3600",
        "--width",
        "16384",
        "-q",
    ]);
    assert!(!o.status.success(), "rendered");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("rendering 3600 views of") && e.contains("needs about"), "{e}");
    assert!(!out.exists(), "wrote {}", out.display());
}

/// A step or supersampling that would never finish, or a step that integrates rays from one
/// sample, is refused, naming the option and what it allows, and leaves nothing behind.
#[test]
fn steps_and_supersampling_that_would_never_finish_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    make_scene(dir.path());
    let (recon, scene, out) = (d(&dir.path().join("recon.npy")), d(dir.path()), dir.path().join("views"));
    for (extra, says) in [
        (&["--step", "1e-300"][..], "give a step of at least"),
        (&["--step", "2.5"][..], "is longer than the box's thinnest side (2.0000"),
        (&["--supersample", "1000"][..], "--supersample must be between 1 and 64"),
        (&["--supersample", "0"][..], "--supersample must be between 1 and 64"),
    ] {
        let o = fluidnerf(&[&["render", &recon, "--scene", &scene, "-o", &d(&out), "-q"][..], extra].concat());
        assert!(!o.status.success(), "{extra:?} ran");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(says), "{extra:?}: {e}");
        assert!(!out.join("render.json").exists(), "{extra:?} wrote render.json");
    }
}

/// `--time` on a field of space alone changes nothing, and says so; the views are those
/// rendered without it, and render.json records no time.
#[test]
fn a_time_given_to_a_static_field_is_warned_of() {
    let (dir, _, run) = scene_and_trained_run();
    let render = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let o = fluidnerf(
            &["render", &d(&run), "--scene", &d(dir.path()), "--out", &d(&out), "--format", "tiff", "--camera", "0"]
                .into_iter()
                .chain(extra.iter().copied())
                .collect::<Vec<_>>(),
        );
        ok(&o);
        let image = fluidnerf_io::image::read_image(&out.join("view_000.tif")).expect("reads").data;
        (String::from_utf8_lossy(&o.stderr).into_owned(), image)
    };
    let (quiet, plain) = render("plain", &[]);
    assert!(!quiet.contains("has no effect"), "{quiet}");
    let (said, timed) = render("timed", &["--time", "3"]);
    assert!(said.contains("--time 3 has no effect") && said.contains("static field"), "{said}");
    assert_eq!(plain, timed);
    // render.json records the time used, which is none: not the 3 that changed nothing.
    assert_eq!(render_json(&dir.path().join("timed"))["time"], serde_json::Value::Null);
}

/// A `--time` that is no finite number is refused in one message: on a volume or a field of
/// space alone it was first warned of as having no effect, then refused.
#[test]
fn a_time_that_is_no_number_is_refused_in_one_message() {
    let (dir, _, run) = scene_and_trained_run();
    for recon in [dir.path().join("recon.npy"), run] {
        for (time, shown) in [("nan", "NaN"), ("inf", "inf")] {
            let out = dir.path().join("views");
            let o = fluidnerf(&[
                "render",
                &d(&recon),
                "--scene",
                &d(dir.path()),
                "--out",
                &d(&out),
                "--camera",
                "0",
                &format!("--time={time}"),
            ]);
            assert!(!o.status.success(), "{recon:?} --time {time} ran");
            assert_eq!(
                String::from_utf8_lossy(&o.stderr),
                format!("error: --time: the time must be a finite number, got {shown}\n"),
                "{recon:?}"
            );
            assert!(!out.exists(), "{recon:?} --time {time} wrote output");
        }
    }
}

/// A run rendered with a scene other than the one it was made from, or a reconstruction of
/// another box than the scene's, is warned about, as `eval` warns: both were rendered without
/// a word.
#[test]
fn a_run_of_another_scene_or_box_is_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    for (name, aabb) in [("scene", "-20,-20,-20,20,20,20"), ("other", "-10,-10,-10,10,10,10")] {
        let synth = ["synth", "--preset", "demo", "--phantom", "ball", "--cameras", "3", "--pixels", "16"];
        ok(&fluidnerf(&[&synth[..], &["--resolution", "8", "--aabb", aabb, "-o", &d(name), "-q"]].concat()));
    }
    ok(&fluidnerf(&["reconstruct", &d("scene"), "-o", &d("run"), "--method", "asart", "--max-iterations", "1", "-q"]));
    let o = fluidnerf(&["render", &d("run"), "-o", &d("own"), "--camera", "0"]);
    ok(&o);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!e.contains("was made from") && !e.contains("fills the box"), "{e}");
    let o = fluidnerf(&["render", &d("run"), "--scene", &d("other"), "-o", &d("views"), "--camera", "0"]);
    ok(&o);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("run was made from the scene") && e.contains("other; rendered from this one's cameras"), "{e}");
    assert!(e.contains("fills the box [-20, -20, -20] .. [20, 20, 20], not the scene's [-10, -10, -10]"), "{e}");
}

/// Negative pixels, which a 16-bit PNG cannot hold, are warned about: they were written as 0
/// without a word, so the PNG's counts no longer gave the rendered values.
#[test]
fn negative_pixels_written_as_zero_to_a_png_are_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, vol) = make_scene(dir.path());
    let negative = Volume { data: vol.data.iter().map(|v| v - 0.5).collect(), ..vol };
    fluidnerf_io::volume::write_npy(&dir.path().join("negative.npy"), &negative).expect("writes");
    let d = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let render = |recon: &str, out: &str, format: &str| {
        let o = fluidnerf(&["render", &d(recon), "--scene", &d(""), "-o", &d(out), "--format", format]);
        ok(&o);
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = render("negative.npy", "png", "png16");
    assert!(e.contains("pixel(s) of the views are negative") && e.contains("--format tiff keeps them"), "{e}");
    for (recon, out, format) in [("negative.npy", "tiff", "tiff"), ("recon.npy", "positive", "png16")] {
        let e = render(recon, out, format);
        assert!(!e.contains("negative"), "{recon} as {format}: {e}");
    }
}

/// Negative pixels of orbit views are warned about for the turntable too, whose colour map
/// starts at 0: they took the colour of 0 without a word, whatever the views' format.
#[test]
fn negative_pixels_shown_as_zero_in_a_turntable_are_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, vol) = make_scene(dir.path());
    let negative = Volume { data: vol.data.iter().map(|v| v - 0.5).collect(), ..vol };
    fluidnerf_io::volume::write_npy(&dir.path().join("negative.npy"), &negative).expect("writes");
    let d = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let render = |recon: &str, out: &str| {
        let o = fluidnerf(&[
            "render",
            &d(recon),
            "--scene",
            &d(""),
            "-o",
            &d(out),
            "--orbit",
            "2",
            "--width",
            "32",
            "--format",
            "tiff",
        ]);
        ok(&o);
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let e = render("negative.npy", "negative");
    let says = "pixel(s) of the orbit views are negative";
    assert!(e.contains(says) && e.contains("turntable.gif shows them as 0"), "{e}");
    assert_eq!(e.matches(says).count(), 1, "warned once: {e}");
    let e = render("recon.npy", "positive");
    assert!(!e.contains("negative"), "{e}");
}

/// A volume whose line integrals overflow 32-bit floats is refused before anything is written:
/// its views were written as TIFFs full of infinities and NaN, with "brightest pixel 0".
#[test]
fn a_volume_whose_views_overflow_floats_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, vol) = make_scene(dir.path());
    let huge = Volume { data: vol.data.iter().map(|v| v * 3e38).collect(), ..vol };
    fluidnerf_io::volume::write_npy(&dir.path().join("huge.npy"), &huge).expect("writes");
    let d = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    for projector in ["footprint", "rays"] {
        let o = fluidnerf(&[
            "render",
            &d("huge.npy"),
            "--scene",
            &d(""),
            "-o",
            &d("views"),
            "--format",
            "tiff",
            "--projector",
            projector,
        ]);
        assert!(!o.status.success(), "{projector}: rendered");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains("huge.npy: values up to 2.95") && e.contains("beyond the largest 32-bit float"), "{e}");
        assert!(!dir.path().join("views").exists(), "{projector}: made the output folder");
    }
}

/// A volume read from the render folder under a view's name is never written over, even with
/// --force: the view replaced the TIFF stack it was rendered from.
#[test]
fn a_volume_named_as_a_view_is_never_rendered_over() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, vol) = make_scene(dir.path());
    let views = dir.path().join("views");
    std::fs::create_dir_all(&views).expect("mkdir");
    let stack = views.join("view_000.tif");
    fluidnerf_io::volume::write_tiff_stack(&stack, &vol, "mm").expect("writes");
    let before = std::fs::read(&stack).expect("reads");
    let o =
        fluidnerf(&["render", &d(&stack), "--scene", &d(dir.path()), "-o", &d(&views), "--format", "tiff", "--force"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("is the reconstruction read; an input is never overwritten"), "{e}");
    assert_eq!(std::fs::read(&stack).expect("kept"), before);
}

/// A volume that is not empty but lies outside every view (its box shifted by a metre) is
/// refused, whether seen by the scene's cameras or an orbit: its black views were written and
/// the render reported success. An empty volume still renders, black as it is.
#[test]
fn a_volume_outside_every_view_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (_, vol) = make_scene(dir.path());
    let shift = DVec3::splat(1000.0);
    let away = Volume { aabb: Aabb::new(vol.aabb.min + shift, vol.aabb.max + shift), ..vol.clone() };
    fluidnerf_io::volume::write_vti(&dir.path().join("away.vti"), &away).expect("writes");
    let empty = Volume { data: vec![0.0; vol.data.len()], ..vol };
    fluidnerf_io::volume::write_npy(&dir.path().join("empty.npy"), &empty).expect("writes");
    let d = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    for (out, extra) in [("views", &[][..]), ("orbit", &["--orbit", "1", "--width", "16"][..])] {
        let o = fluidnerf(&[&["render", &d("away.vti"), "--scene", &d(""), "-o", &d(out)][..], extra].concat());
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{out}: rendered: {e}");
        assert!(
            e.contains("away.vti: every rendered view is black (all pixels 0), yet it is not empty (values up to 0.98"),
            "{e}"
        );
        assert!(e.contains("fills the box [998.5, 999, 999] .. [1001.5, 1001, 1001]"), "{e}");
        assert!(!dir.path().join(out).exists(), "{out}: left the output folder");
        let o = fluidnerf(&[&["render", &d("empty.npy"), "--scene", &d(""), "-o", &d(out)][..], extra].concat());
        ok(&o);
    }
}
