//! End-to-end tests of `fluidnerf eval` on tiny scenes generated in a temporary directory.

use std::path::Path;
use std::process::Command;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{render_image, Aabb, Camera, Frame, Intrinsics, RenderSettings, Scene, TruthRef, Volume};
use serde_json::Value;

const SCALE: f64 = 2.0;

fn blob(p: DVec3, t: f64) -> f32 {
    let c = DVec3::new(-0.3 + 0.2 * t, 0.1, 0.0);
    (-(p - c).length_squared() * 3.0).exp() as f32
}

/// A static (`times` empty) or time-resolved scene of a Gaussian blob: 4 cameras on a ring,
/// the last held out, 24 × 20 px, truth 18 × 12 × 12 voxels per time.
fn make_scene(dir: &Path, times: &[f64]) -> Scene {
    let aabb = Aabb::new(DVec3::new(-1.5, -1.0, -1.0), DVec3::new(1.5, 1.0, 1.0));
    let k = Intrinsics { width: 24, height: 20, fx: 30.0, fy: 30.0, cx: 11.5, cy: 9.5, skew: 0.0 };
    let steps: Vec<Option<f64>> = if times.is_empty() { vec![None] } else { times.iter().map(|&t| Some(t)).collect() };
    let mut frames = Vec::new();
    let mut truth = Vec::new();
    for (s, &time) in steps.iter().enumerate() {
        let vol = Volume::from_fn([18, 12, 12], aabb, |p| blob(p, time.unwrap_or(0.0)));
        let name = format!("truth_{s}.npy");
        fluidnerf_io::volume::write_npy(&dir.join(&name), &vol).expect("writes truth");
        truth.push(TruthRef { time, file_path: name.into() });
        for c in 0..4 {
            let a = c as f64 / 4.0 * std::f64::consts::TAU + 0.3;
            let camera = Camera::look_at(k, DVec3::new(0.0, 7.0 * a.cos(), 7.0 * a.sin()), DVec3::ZERO, DVec3::X);
            let settings =
                RenderSettings { scale: SCALE, time: time.unwrap_or(0.0), supersample: 2, ..Default::default() };
            let img = render_image(&vol, &camera, &aabb, &settings).expect("renders");
            let file = format!("images/t{s}_c{c}.tif");
            fluidnerf_io::image::write_tiff_f32(&dir.join(&file), &img).expect("writes image");
            frames.push(Frame {
                camera,
                file_path: file.into(),
                time,
                camera_name: Some(format!("cam{c}")),
                holdout: c == 3,
            });
        }
    }
    let scene = Scene { root: dir.to_path_buf(), aabb, units: "mm".into(), intensity_scale: SCALE, frames, truth };
    fluidnerf_io::scene::save_scene(&scene, dir).expect("writes scene");
    scene
}

fn fluidnerf(args: &[&str], cwd: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf")).args(args).current_dir(cwd).output().expect("runs fluidnerf")
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("reads json")).expect("valid json")
}

#[test]
fn scores_a_dimmed_volume_against_truth_and_held_out_view() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    // A reconstruction at 90 % intensity on a finer grid, in a run directory.
    let run = d.join("run");
    let recon = Volume::from_fn([36, 24, 24], scene.aabb, |p| 0.9 * blob(p, 0.0));
    fluidnerf_io::volume::write_npy(&run.join("volume.npy"), &recon).expect("writes recon");

    let out = fluidnerf(&["eval", "run", "--scene", "."], d);
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    for word in ["NRMSE", "laminar", "transition", "turbulent", "reprojection", "cam3"] {
        assert!(stdout.contains(word), "table lacks {word}:\n{stdout}");
    }

    let json = read_json(&run.join("metrics.json"));
    let steps = json["steps"].as_array().expect("steps");
    assert_eq!(steps.len(), 1);
    // Resampling the finer grid costs a little; the 10 % dimming dominates.
    let nrmse = steps[0]["global"]["nrmse"].as_f64().expect("nrmse");
    assert!((nrmse - 0.1).abs() < 0.02, "volume NRMSE {nrmse}");
    assert_eq!(steps[0]["regions"].as_array().expect("regions").len(), 3);
    let ssim = steps[0]["global"]["ssim_windowed"].as_f64().expect("ssim");
    assert!(ssim > 0.8 && ssim < 1.0, "windowed SSIM {ssim}");
    let rep = json["reprojection"].as_array().expect("reprojection");
    assert_eq!(rep.len(), 1, "one held-out frame");
    let rn = rep[0]["nrmse"].as_f64().expect("nrmse");
    assert!((rn - 0.1).abs() < 0.03, "reprojection NRMSE {rn}");
    assert_eq!(json["settings"]["version"].as_str(), Some(env!("CARGO_PKG_VERSION")));

    let csv = std::fs::read_to_string(run.join("metrics.csv")).expect("csv");
    assert_eq!(csv.lines().count(), 1 + 4 + 1, "header, all + 3 regions, 1 held-out view:\n{csv}");

    // Results are not overwritten without --force.
    let again = fluidnerf(&["eval", "run", "--scene", "."], d);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
    let forced = fluidnerf(&["eval", "run", "--scene", ".", "--force", "--no-reprojection", "--no-regions"], d);
    assert!(forced.status.success(), "{}", String::from_utf8_lossy(&forced.stderr));
    let json = read_json(&run.join("metrics.json"));
    assert!(json["reprojection"].as_array().expect("reprojection").is_empty());
    assert!(json["steps"][0]["regions"].as_array().expect("regions").is_empty());
}

#[test]
fn scores_each_time_step_and_custom_regions() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[0.0, 1.0]);
    // Step 0 perfect, step 1 off by 20 %.
    for (s, gain) in [(0, 1.0f32), (1, 0.8)] {
        let v = Volume::from_fn([18, 12, 12], scene.aabb, |p| gain * blob(p, s as f64));
        fluidnerf_io::volume::write_npy(&d.join(format!("r{s}.npy")), &v).expect("writes recon");
    }
    let out = fluidnerf(
        &[
            "eval",
            "r0.npy",
            "r1.npy",
            "--scene",
            ".",
            "--regions",
            "left:0:0.5,core:0.25:0.75:0.25:0.75:0.25:0.75",
            "--json",
            "m.json",
            "--csv",
            "m.csv",
        ],
        d,
    );
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
    let json = read_json(&d.join("m.json"));
    let steps = json["steps"].as_array().expect("steps");
    assert_eq!(steps.len(), 2);
    assert_eq!(steps[0]["time"].as_f64(), Some(0.0));
    assert_eq!(steps[0]["global"]["nrmse"].as_f64(), Some(0.0));
    let n1 = steps[1]["global"]["nrmse"].as_f64().expect("nrmse");
    assert!((n1 - 0.2).abs() < 1e-5, "step 1 NRMSE {n1}");
    let names: Vec<&str> = steps[1]["regions"]
        .as_array()
        .expect("regions")
        .iter()
        .map(|r| r["region"]["name"].as_str().expect("name"))
        .collect();
    assert_eq!(names, ["left", "core"]);
    // One held-out view per time step, each rendered from its own step's volume.
    let rep = json["reprojection"].as_array().expect("reprojection");
    assert_eq!(rep.len(), 2);
    assert!(rep[0]["nrmse"].as_f64().expect("nrmse") < 1e-5);
    assert!((rep[1]["nrmse"].as_f64().expect("nrmse") - 0.2).abs() < 1e-4);

    // A bad region is rejected before any work.
    let bad = fluidnerf(&["eval", "r0.npy", "r1.npy", "--scene", ".", "--regions", "x:0.7:0.2"], d);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("region"));
}

/// A region given that holds no voxel centre of the truth is refused by name: it was warned of
/// and left out of the scores, which then lacked a region that was asked for.
#[test]
fn a_region_holding_no_voxel_of_the_truth_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    let v = Volume::from_fn([18, 12, 12], scene.aabb, |p| blob(p, 0.0));
    fluidnerf_io::volume::write_npy(&d.join("r.npy"), &v).expect("writes recon");
    // Centres lie at (i + ½)/18 along x: none in 0.5 … 0.51.
    let out =
        fluidnerf(&["eval", "r.npy", "--scene", ".", "--regions", "left:0:0.5,thin:0.5:0.51", "--json", "m.json"], d);
    assert!(!out.status.success(), "an empty region was scored");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(
            "--regions: thin holds no voxel centre of the 18×12×12 truth grid (./truth_0.npy); widen it to hold one"
        ),
        "{err}"
    );
    assert!(!d.join("m.json").exists(), "a refused evaluation wrote its scores");
    ok_eval(&fluidnerf(&["eval", "r.npy", "--scene", ".", "--regions", "left:0:0.5,wide:0.5:0.6"], d));
}

fn ok_eval(out: &std::process::Output) {
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
}

/// Writes into `run` a neural run folder (weights and model.json, no config) of a dense-grid
/// field holding `initial` everywhere in the scene's box, with a value scale of 2.
fn write_dense_run(run: &Path, scene: &Scene, initial: f32) -> std::path::PathBuf {
    use fluidnerf_neural::trained::{build_field, AnyField, DenseConfig, FieldConfig, ModelRecord};
    let config = FieldConfig::Dense(DenseConfig { resolution: 8, initial });
    let AnyField::Dense(field) = build_field(&config, &scene.aabb, 3, 0).expect("builds") else {
        panic!("a dense config builds a dense field")
    };
    std::fs::create_dir_all(run).expect("mkdir");
    let weights = fluidnerf_neural::weights::weights_bytes(&field).expect("serialises");
    std::fs::write(run.join("weights.safetensors"), weights).expect("writes weights");
    let meta =
        fluidnerf_neural::train::FieldMeta { aabb: scene.aabb, value_scale: 2.0, time_step: 1.0, occupancy: None };
    let record = ModelRecord { field: config, input_dim: 3, meta };
    std::fs::write(run.join("model.json"), serde_json::to_string(&record).expect("json")).expect("writes model");
    run.to_path_buf()
}

/// A field whose weights are finite but whose values overflow 32-bit floats (a dense grid of
/// 3·10³⁸ with a value scale of 2) is refused by `eval`, `export` and `render` naming the run;
/// `eval` printed infinite metrics and `export` wrote infinite voxels, both with success.
#[test]
fn a_field_whose_values_overflow_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    let run = write_dense_run(&d.join("nerf"), &scene, 3e38);
    for (args, says) in [
        (&["eval", "nerf", "--scene", ".", "--no-regions", "--no-reprojection"][..], "nerf: the field is inf at"),
        (
            &["export", "nerf", "-o", "out.npy", "--resolution", "8"][..],
            "nerf: the field is inf at 200 of the 200 points it was sampled at on a 8×5×5 grid",
        ),
        (&["render", "nerf", "--scene", ".", "-o", "views", "--format", "tiff"][..], "nerf: view "),
    ] {
        let out = fluidnerf(args, d);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains(says) && e.contains("overflow 32-bit floats"), "{args:?}: {e}");
    }
    assert!(!d.join("out.npy").exists() && !d.join("views").exists(), "nothing written");
    assert!(!run.join("metrics.json").exists(), "no metrics written");

    // Values that are finite but whose line integrals overflow (10³⁸ × 2): `render` refused
    // them, while `eval` scored NRMSE 2.6e38, a windowed SSIM of 1.85e20 and reprojections of
    // inf and NaN.
    let big = write_dense_run(&d.join("big"), &scene, 1e38);
    let out = fluidnerf(&["eval", "big", "--scene", ".", "--no-regions"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("big: the field reaches 2.000e38 at the truth's voxel centres"), "{e}");
    // Without a truth, through the held-out view alone.
    let mut bare = scene.clone();
    bare.truth.clear();
    for f in &mut bare.frames {
        f.file_path = Path::new("..").join(&f.file_path);
    }
    fluidnerf_io::scene::save_scene(&bare, &d.join("bare")).expect("writes scene");
    let out = fluidnerf(&["eval", "big", "--scene", "bare"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("the view rendered for frame 3 is inf at pixel"), "{e}");
    assert!(!big.join("metrics.json").exists(), "no metrics written");
}

#[test]
fn scores_a_trained_field_run_directory_at_the_truth_voxel_centres() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    // A dense-grid field holding 0.25 everywhere in the box, with a value scale of 2: E = 0.5.
    let run = write_dense_run(&d.join("nerf"), &scene, 0.25);

    let out = fluidnerf(&["eval", "nerf", "--scene", ".", "--no-regions"], d);
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
    let json = read_json(&run.join("metrics.json"));
    let got = json["steps"][0]["global"]["nrmse"].as_f64().expect("nrmse");
    let truth = fluidnerf_io::volume::read_npy(&d.join("truth_0.npy"), scene.aabb).expect("truth");
    let constant = vec![0.5f32; truth.len()];
    let want = fluidnerf_metrics::nrmse(&constant, &truth.data);
    assert!((got - want).abs() < 1e-4, "NRMSE {got}, a constant 0.5 scores {want}");
    assert_eq!(json["reprojection"].as_array().expect("reprojection").len(), 1);

    // A hand-made run folder holding only a volume with a NaN voxel is refused, naming it.
    let vol = d.join("vol");
    std::fs::create_dir_all(&vol).expect("mkdir");
    let mut v = fluidnerf_core::Volume::zeros([4, 4, 4], scene.aabb);
    v.data[5] = f32::NAN;
    fluidnerf_io::volume::write_npy(&vol.join("volume.npy"), &v).expect("writes");
    let out = fluidnerf(&["eval", "vol", "--scene", ".", "--no-regions", "--no-reprojection"], d);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("volume.npy") && err.contains("voxel 5 is NaN"), "{err}");
}

#[test]
fn without_truth_only_held_out_views_are_scored() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let mut scene = make_scene(d, &[0.0, 1.0]);
    scene.truth.clear();
    fluidnerf_io::scene::save_scene(&scene, d).expect("rewrites scene");
    for s in 0..2 {
        let v = Volume::from_fn([18, 12, 12], scene.aabb, |p| blob(p, s as f64));
        fluidnerf_io::volume::write_npy(&d.join(format!("r{s}.npy")), &v).expect("writes recon");
    }
    let out = fluidnerf(&["eval", "r0.npy", "r1.npy", "--scene", ".", "--json", "m.json"], d);
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
    let json = read_json(&d.join("m.json"));
    assert!(json["steps"].as_array().expect("steps").is_empty());
    let rep = json["reprojection"].as_array().expect("reprojection");
    assert_eq!(rep.len(), 2);
    // Each held-out view is rendered from the volume of its own time step.
    for r in rep {
        assert!(r["nrmse"].as_f64().expect("nrmse") < 1e-5, "{r}");
    }
    // Neither truth nor held-out views: nothing to do.
    let none = fluidnerf(&["eval", "r0.npy", "r1.npy", "--scene", ".", "--no-reprojection"], d);
    assert!(!none.status.success());
    assert!(String::from_utf8_lossy(&none.stderr).contains("nothing to evaluate"));
}

/// Settings under which a metric would be undefined are refused, naming the file or option,
/// and nothing is written: an all-zero truth (NRMSE is relative to its norm), a 1-voxel SSIM
/// window (no sample variance) and no rays per pixel.
#[test]
fn undefined_metrics_are_refused_not_written_as_nan() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    let zero = Volume::from_fn([18, 12, 12], scene.aabb, |_| 0.0);
    fluidnerf_io::volume::write_npy(&d.join("zero.npy"), &zero).expect("writes");
    let recon = Volume::from_fn([18, 12, 12], scene.aabb, |p| blob(p, 0.0));
    fluidnerf_io::volume::write_npy(&d.join("run/volume.npy"), &recon).expect("writes");
    for (args, says) in [
        (&["--truth", "zero.npy", "--no-reprojection"][..], "zero.npy: every voxel of the ground truth is zero"),
        (&["--ssim-size", "1"][..], "--ssim-size must be odd and at least 3"),
        (&["--supersample", "0"][..], "--supersample must be between 1 and"),
    ] {
        let out = fluidnerf(&[&["eval", "run", "--scene", "."][..], args].concat(), d);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains(says), "{args:?}: {e}");
        assert!(!d.join("run/metrics.json").exists() && !d.join("run/metrics.csv").exists(), "{args:?}");
    }
    // The scene's own truth, all zero, is named too.
    fluidnerf_io::volume::write_npy(&d.join("truth_0.npy"), &zero).expect("writes");
    let out = fluidnerf(&["eval", "run", "--scene", ".", "--no-reprojection"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("truth_0.npy: every voxel"), "{e}");
}

/// A region where the truth is zero has no NRMSE (it divides by the truth's energy): the table
/// says `undefined` and why, the JSON holds null and the reason, never NaN.
#[test]
fn a_region_whose_truth_is_zero_has_an_undefined_nrmse_with_its_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    let half = Volume::from_fn([18, 12, 12], scene.aabb, |p| if p.x < 0.0 { 0.0 } else { blob(p, 0.0) });
    fluidnerf_io::volume::write_npy(&d.join("half.npy"), &half).expect("writes");
    let recon = Volume::from_fn([18, 12, 12], scene.aabb, |p| blob(p, 0.0));
    fluidnerf_io::volume::write_npy(&d.join("run/volume.npy"), &recon).expect("writes");
    let out = fluidnerf(
        &[
            "eval",
            "run",
            "--scene",
            ".",
            "--truth",
            "half.npy",
            "--no-reprojection",
            "--regions",
            "empty:0:0.4,full:0.6:1",
        ],
        d,
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(!table.to_lowercase().contains("nan"), "{table}");
    let row = table.lines().find(|l| l.contains(" empty ")).expect("a row for the region");
    assert!(row.contains("undefined"), "{table}");
    assert!(table.contains("NRMSE undefined for volume empty: the truth is zero throughout"), "{table}");
    let json = read_json(&d.join("run/metrics.json"));
    let regions = &json["steps"][0]["regions"];
    assert!(regions[0]["metrics"]["nrmse"].is_null(), "{regions}");
    assert!(regions[0]["metrics"]["nrmse_undefined"].as_str().is_some_and(|s| s.contains("truth is zero")));
    assert!(regions[1]["metrics"]["nrmse"].is_f64() && regions[1]["metrics"].get("nrmse_undefined").is_none());
}

/// A folder holding `scene` and a two-iteration ASART run of it, `run`.
fn scene_and_run() -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    std::fs::create_dir(d.join("scene")).expect("mkdir");
    make_scene(&d.join("scene"), &[]);
    let run = fluidnerf(&["reconstruct", "scene", "-o", "run", "--method", "asart", "--max-iterations", "2"], d);
    assert!(run.status.success(), "reconstruct failed: {}", String::from_utf8_lossy(&run.stderr));
    dir
}

#[test]
fn a_run_folder_names_its_own_scene_for_eval_and_render() {
    let dir = scene_and_run();
    let d = dir.path();

    // Without --scene the run's recorded scene is scored, and said to be: the same figures as
    // with it.
    let implicit = fluidnerf(&["eval", "run", "--no-regions"], d);
    assert!(implicit.status.success(), "eval failed: {}", String::from_utf8_lossy(&implicit.stderr));
    assert!(String::from_utf8_lossy(&implicit.stdout).contains("recorded in run/config.json"));
    let nrmse = |json: &Value| json["steps"][0]["global"]["nrmse"].as_f64().expect("nrmse");
    let without = nrmse(&read_json(&d.join("run/metrics.json")));
    let explicit = fluidnerf(&["eval", "run", "--scene", "scene", "--no-regions", "--force"], d);
    assert!(explicit.status.success(), "eval failed: {}", String::from_utf8_lossy(&explicit.stderr));
    assert_eq!(without, nrmse(&read_json(&d.join("run/metrics.json"))));

    let views = fluidnerf(&["render", "run", "-o", "views"], d);
    assert!(views.status.success(), "render failed: {}", String::from_utf8_lossy(&views.stderr));
    assert_eq!(std::fs::read_dir(d.join("views")).expect("views").count(), 4 + 1, "four views and render.json");

    // A volume file records no scene; a run whose scene is gone names the path it recorded.
    let bare = fluidnerf(&["eval", "run/volume.npy"], d);
    let err = String::from_utf8_lossy(&bare.stderr);
    assert!(!bare.status.success() && err.contains("--scene") && err.contains("run/volume.npy"), "{err}");
    // A path that is not there is said to be missing (it was said to record no scene).
    let missing = fluidnerf(&["eval", "run/volume-typo.npy"], d);
    let err = String::from_utf8_lossy(&missing.stderr);
    assert!(!missing.status.success() && err.contains("run/volume-typo.npy: no such file or directory"), "{err}");
    // Two run folders do record their scenes: what is refused is that there are two (it said
    // "2 volumes record no scene").
    let two = fluidnerf(&["eval", "run", "run/volume.npy"], d);
    let err = String::from_utf8_lossy(&two.stderr);
    assert!(!two.status.success() && err.contains("run: give one run folder, or volume files (with --scene)"), "{err}");
    // --use-volume changes nothing for a voxel run, and says so.
    let moot = fluidnerf(&["eval", "run", "--use-volume", "--no-regions", "--json", "moot.json"], d);
    assert!(moot.status.success(), "eval failed: {}", String::from_utf8_lossy(&moot.stderr));
    let err = String::from_utf8_lossy(&moot.stderr);
    assert!(err.contains("--use-volume has no effect: run is a voxel run, scored through its volume anyway"), "{err}");
    std::fs::rename(d.join("scene"), d.join("moved")).expect("moves the scene");
    let gone = fluidnerf(&["render", "run", "-o", "views2"], d);
    let err = String::from_utf8_lossy(&gone.stderr);
    assert!(!gone.status.success() && err.contains("which is not there") && err.contains("--scene"), "{err}");
    assert!(!d.join("views2").exists(), "nothing written");
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).expect("lists") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
            } else {
                files.push((path.clone(), std::fs::read(&path).expect("reads")));
            }
        }
    }
    files.sort();
    files
}

#[test]
fn never_overwrites_its_inputs_nor_the_scenes_or_the_runs_files() {
    let dir = scene_and_run();
    let d = dir.path();
    std::fs::write(d.join("scene/synth.json"), "{}").expect("writes a scene record");

    let score = |extra: &[&str]| {
        let mut args = vec!["eval", "run", "--no-regions", "--force"];
        args.extend_from_slice(extra);
        fluidnerf(&args, d)
    };
    let mut cases: Vec<(&[&str], &str)> = vec![
        (&["--json", "scene/transforms.json"], "scene/transforms.json: is the scene file"),
        (&["--csv", "scene/images/t0_c0.tif"], "as an image"),
        (&["--csv", "scene/images/../images/t0_c3.tif"], "as an image"),
        (&["--json", "scene/truth_0.npy"], "as ground truth"),
        (&["--json", "scene/synth.json"], "the scene's record synth.json"),
        (&["--json", "run/config.json"], "run/config.json: is the file config.json that the run in run wrote"),
        (&["--csv", "run/report.json"], "is the file report.json that the run"),
        (&["--csv", "run/report.html"], "is the file report.html that the run"),
        (&["--json", "./run/volume.npy"], "is the file volume.npy that the run"),
        (&["--json", "run/volume.vti", "--csv", "elsewhere.csv"], "--json: run/volume.vti"),
        (&["--json", "run/eval.json", "--csv", "run/volume.npy"], "--csv: run/volume.npy"),
        (&["--truth", "scene/truth_0.npy", "--json", "scene/truth_0.npy"], "as ground truth"),
    ];
    // The same files by another way there.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(d.join("scene"), d.join("alias")).expect("links");
        cases.push((&["--json", "alias/transforms.json"], "alias/transforms.json: is the scene file"));
        cases.push((&["--csv", "alias/images/t0_c1.tif"], "as an image"));
    }
    let before = snapshot(d);
    for (extra, needle) in cases {
        let out = score(extra);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains(needle) && e.contains("never overwritten"), "{extra:?}: {e}");
    }
    // A volume file given to score, and the truth given in its place.
    let out = fluidnerf(&["eval", "run/volume.npy", "--scene", "scene", "--csv", "run/volume.npy", "--force"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("a reconstruction volume being scored"), "{e}");
    std::fs::copy(d.join("scene/truth_0.npy"), d.join("truth.npy")).expect("copies the truth");
    let out = fluidnerf(&["eval", "run", "--truth", "truth.npy", "--json", "truth.npy", "--force"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("truth.npy: is the ground truth given with --truth"), "{e}");
    std::fs::remove_file(d.join("truth.npy")).expect("removes the copy");
    assert!(before == snapshot(d), "a refused evaluation changed a file");

    // Results go anywhere else: into the run folder by default (and again with --force), or
    // under new names, in the run's folder or the scene's.
    let out = fluidnerf(&["eval", "run", "--no-regions"], d);
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
    assert!(score(&[]).status.success());
    let out = score(&["--json", "run/eval.json", "--csv", "scene/eval.csv"]);
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
    assert!(d.join("run/metrics.json").is_file() && d.join("run/eval.json").is_file());
    assert!(d.join("scene/eval.csv").is_file());
    // With --force an earlier evaluation's files are replaced, files of another kind not:
    // another scene's transforms.json, or a table of the user's, named by mistake.
    std::fs::create_dir(d.join("other")).expect("mkdir");
    std::fs::copy(d.join("scene/transforms.json"), d.join("other/transforms.json")).expect("copies");
    std::fs::write(d.join("notes.csv"), "a,b\n1,2\n").expect("writes");
    let before = snapshot(d);
    for (extra, needle) in [
        (["--json", "other/transforms.json"], "--json other/transforms.json: exists and is not the JSON metrics"),
        (["--csv", "notes.csv"], "--csv notes.csv: exists and is not the CSV table of an earlier evaluation"),
    ] {
        let out = score(&extra);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains(needle), "{extra:?}: {e}");
    }
    assert!(before == snapshot(d), "a refused evaluation changed a file");
}

/// A run's report and `eval` place the default regions along the same flow axis (here the
/// scene's `flow_axis`, +y, not the +x of regions without one), so each region's name means
/// the same part of the box and scores the same in both.
#[test]
fn the_report_and_eval_score_the_same_regions() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    std::fs::create_dir(d.join("scene")).expect("mkdir");
    make_scene(&d.join("scene"), &[]);
    let file = d.join("scene/transforms.json");
    let mut scene = read_json(&file);
    scene["flow_axis"] = serde_json::json!([0.0, 1.0, 0.0]);
    std::fs::write(&file, serde_json::to_string_pretty(&scene).expect("json")).expect("writes scene");
    let run = fluidnerf(&["reconstruct", "scene", "-o", "run", "--method", "asart", "--max-iterations", "2"], d);
    assert!(run.status.success(), "reconstruct failed: {}", String::from_utf8_lossy(&run.stderr));
    let out = fluidnerf(&["eval", "run", "--no-reprojection"], d);
    assert!(out.status.success(), "eval failed: {}", String::from_utf8_lossy(&out.stderr));
    let report = read_json(&d.join("run/report.json"));
    let metrics = read_json(&d.join("run/metrics.json"));
    let by_name = |regions: &Value| -> Vec<(String, [f64; 2], Option<f64>)> {
        regions
            .as_array()
            .expect("regions")
            .iter()
            .map(|r| {
                let name = r["region"]["name"].as_str().expect("name").to_string();
                let y = [r["bounds"]["min"][1].as_f64().expect("min"), r["bounds"]["max"][1].as_f64().expect("max")];
                (name, y, r["metrics"]["nrmse"].as_f64())
            })
            .collect()
    };
    let reported = by_name(&report["volumes"][0]["metrics"]["regions"]);
    let evaluated = by_name(&metrics["steps"][0]["regions"]);
    assert_eq!(reported.len(), 3, "{reported:?}");
    assert!(reported.iter().all(|(_, y, _)| y[1] - y[0] < 1.0), "thirds along y (the box is 2 high): {reported:?}");
    for ((a, ya, na), (b, yb, nb)) in reported.iter().zip(&evaluated) {
        assert_eq!((a, ya), (b, yb), "region {a} of the report against {b} of eval");
        match (na, nb) {
            (Some(x), Some(y)) => assert!((x - y).abs() <= 1e-9 * x.abs(), "region {a}: NRMSE {x} against {y}"),
            _ => assert_eq!(na, nb, "region {a}"),
        }
    }
}

/// `--json` and `--csv` naming one file by two spellings are refused before any scoring: the
/// CSV, written second, replaced the JSON, and both were reported written.
#[test]
fn json_and_csv_naming_one_file_by_two_spellings_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    for (json, csv) in [("m.json", "./m.json"), ("m.json", "images/../m.json")] {
        let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--json", json, "--csv", csv], d);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains("name the same file"), "{json} and {csv}: {e}");
        assert!(e.contains(json) && e.contains(csv), "{e}");
        assert!(!d.join("m.json").exists(), "a refused evaluation wrote m.json");
    }
}

/// A folder given as `--json` or `--csv` is refused before any scoring, --force or not: it was
/// said to exist and to need --force, and with --force the write failed after the work.
#[test]
fn a_folder_given_for_the_metrics_is_refused_before_scoring() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    std::fs::create_dir(d.join("results")).expect("mkdir");
    for option in ["--json", "--csv"] {
        for force in [false, true] {
            let mut args = vec!["eval", "truth_0.npy", "--scene", ".", option, "results"];
            args.extend(force.then_some("--force"));
            let out = fluidnerf(&args, d);
            let e = String::from_utf8_lossy(&out.stderr);
            assert!(!out.status.success() && e.contains(&format!("{option} results: is a folder")), "{args:?}: {e}");
            assert!(out.stdout.is_empty(), "{args:?} scored before refusing: {}", String::from_utf8_lossy(&out.stdout));
        }
    }
    // A file where its folder should be is named as such, not as missing.
    std::fs::write(d.join("afile"), "x").expect("writes");
    let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--json", "afile/m.json"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("the folder afile is a file, not a folder"), "{e}");
}

/// A `--json` or `--csv` whose folder takes no new file is refused before any scoring, naming
/// the option and the folder: the write failed only after the work.
#[cfg(target_os = "linux")]
#[test]
fn an_unwritable_folder_for_the_metrics_is_refused_before_scoring() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    // sysfs takes no new file, root included.
    if !Path::new("/sys").is_dir() {
        return;
    }
    for (option, file) in [("--json", "/sys/m.json"), ("--csv", "/sys/m.csv")] {
        let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", option, file], d);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && e.contains(&format!("{option} {file}: cannot write into its folder /sys")),
            "{e}"
        );
        assert!(out.stdout.is_empty(), "{option} scored before refusing: {}", String::from_utf8_lossy(&out.stdout));
    }
}

/// An SSIM window wider than a held-out image is refused before any scoring, naming the option
/// and the frame: it failed only after the volumes were scored, without naming --ssim-size.
#[test]
fn an_ssim_window_wider_than_a_held_out_image_is_refused_before_scoring() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--json", "m.json", "--ssim-size", "21"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{e}");
    assert!(e.contains("--ssim-size 21") && e.contains("held-out frame 3") && e.contains("24x20 px"), "{e}");
    assert!(e.contains("--ssim-size 19 or less") && e.contains("--no-reprojection"), "{e}");
    assert!(out.stdout.is_empty(), "scored before refusing: {}", String::from_utf8_lossy(&out.stdout));
    // A window that fits the images (and the truth, 18x12x12 voxels).
    let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--json", "m.json", "--ssim-size", "11"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// An --ssim-size wider than the ground truth's grid is refused before scoring: the windowed
/// SSIM of the volume was left empty (`-`, `null`) without a word.
#[test]
fn an_ssim_window_wider_than_the_truth_is_refused_before_scoring() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    let args = ["eval", "truth_0.npy", "--scene", ".", "--json", "n.json", "--ssim-size", "13", "--no-reprojection"];
    let out = fluidnerf(&args, d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{e}");
    assert!(e.contains("--ssim-size 13: the ground truth") && e.contains("truth_0.npy is only 18x12x12 voxels"), "{e}");
    assert!(e.contains("give --ssim-size 11 or less"), "{e}");
    assert!(out.stdout.is_empty() && !d.join("n.json").exists(), "scored before refusing");
    let args = ["eval", "truth_0.npy", "--scene", ".", "--json", "n.json", "--ssim-size", "11", "--no-reprojection"];
    let out = fluidnerf(&args, d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(read_json(&d.join("n.json"))["steps"][0]["global"]["ssim_windowed"].is_f64());
}

/// A --data-range wider than any two float32 values differ by is refused: its square overflowed
/// the metrics' constants, and the PSNR was written as infinite and the SSIM as NaN.
#[test]
fn a_data_range_wider_than_float32_values_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--json", "m.json", "--data-range", "1e300"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{e}");
    assert!(e.contains("--data-range 1e300 is more than any two float32 values differ by"), "{e}");
    assert!(out.stdout.is_empty() && !d.join("m.json").exists(), "scored before refusing");
    let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--json", "m.json", "--data-range", "6e38"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // The truth scored against itself: a PSNR of infinity, but an SSIM of 1, not NaN.
    assert_eq!(read_json(&d.join("m.json"))["steps"][0]["global"]["ssim_global"], 1.0);
}

/// A --data-range so small that SSIM's constants (K R)² vanish in double precision wrote the
/// PSNR as -inf (its square underflowed) and the SSIM as NaN: it is refused before scoring. The
/// smallest range that keeps them scores, with a finite PSNR.
#[test]
fn a_data_range_whose_ssim_constants_vanish_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--json", "m.json", "--data-range", "1e-300"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{e}");
    assert!(e.contains("--data-range 1e-300 is so small that SSIM's constants (K₁ R)² and (K₂ R)² vanish"), "{e}");
    assert!(out.stdout.is_empty() && !d.join("m.json").exists(), "scored before refusing");
    let args =
        ["eval", "truth_0.npy", "--scene", ".", "--json", "m.json", "--data-range", "1e-70", "--no-reprojection"];
    let out = fluidnerf(&args, d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let global = &read_json(&d.join("m.json"))["steps"][0]["global"];
    assert_eq!(global["ssim_global"], 1.0);
    assert_eq!(global["data_range"], 1e-70);
}

/// A region named `all` is refused: its row read exactly as the whole volume's, twice `all` in
/// the table and the CSV.
#[test]
fn a_region_named_all_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    let out = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--csv", "m.csv", "--regions", "all:0:0.5"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("--regions: the name all is the whole volume's row"), "{e}");
    assert!(!d.join("m.csv").exists(), "a refused evaluation wrote m.csv");
}

/// A reconstruction volume given twice is refused, however it is spelled: the steps it was
/// given for were scored against it without a word, one of them against another step's volume.
#[test]
fn a_reconstruction_volume_given_twice_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[0.0, 1.0, 2.0]);
    let out =
        fluidnerf(&["eval", "truth_0.npy", "./truth_0.npy", "truth_2.npy", "--scene", ".", "--json", "m.json"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("is given twice (as truth_0.npy and ./truth_0.npy)"), "{e}");
    assert!(!d.join("m.json").exists(), "a refused evaluation wrote m.json");
    // --use-volume picks a run's volume over its field; with volume files it did nothing.
    let out = fluidnerf(&["eval", "truth_0.npy", "truth_1.npy", "truth_2.npy", "--scene", ".", "--use-volume"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("--use-volume applies to a run folder"), "{e}");
    let out = fluidnerf(&["eval", "truth_0.npy", "truth_1.npy", "truth_2.npy", "--scene", ".", "--json", "m.json"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// A `.vti` reconstruction or truth of another box than the scene's is warned about, as a run
/// of another box is: it was scored without a word, zero outside its own box.
#[test]
fn a_volume_or_truth_of_another_box_is_warned_about() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    let own = Volume::from_fn([18, 12, 12], scene.aabb, |p| blob(p, 0.0));
    fluidnerf_io::volume::write_vti(&d.join("own.vti"), &own).expect("writes");
    let half = Aabb::new(0.5 * scene.aabb.min, 0.5 * scene.aabb.max);
    let small = Volume::from_fn([18, 12, 12], half, |p| blob(p, 0.0));
    fluidnerf_io::volume::write_vti(&d.join("small.vti"), &small).expect("writes");
    let warning =
        "fills the box [-0.75, -0.5, -0.5] .. [0.75, 0.5, 0.5], not the scene's [-1.5, -1, -1] .. [1.5, 1, 1]";
    for (args, warned) in [
        (["eval", "own.vti", "--truth", "own.vti"], None),
        (["eval", "small.vti", "--truth", "own.vti"], Some("small.vti")),
        (["eval", "own.vti", "--truth", "small.vti"], Some("--truth small.vti")),
    ] {
        let out =
            fluidnerf(&[&args[..], &["--scene", ".", "--no-reprojection", "--json", "m.json", "--force"]].concat(), d);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?}: {e}");
        match warned {
            Some(what) => assert!(e.contains(&format!("{what} {warning}")), "{args:?}: {e}"),
            None => assert!(!e.contains("fills the box"), "{args:?}: {e}"),
        }
    }
}

/// A volume whose views overflow 32-bit floats is refused before scoring when it is reprojected:
/// its held-out views were rendered as infinities and their metrics written as infinite and NaN.
#[test]
fn a_volume_whose_held_out_views_overflow_floats_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    let aabb = Aabb::new(DVec3::new(-1.5, -1.0, -1.0), DVec3::new(1.5, 1.0, 1.0));
    let truth = fluidnerf_io::volume::read_npy(&d.join("truth_0.npy"), aabb).expect("reads");
    let huge = Volume { data: truth.data.iter().map(|v| v * 3e38).collect(), ..truth };
    fluidnerf_io::volume::write_npy(&d.join("huge.npy"), &huge).expect("writes");
    let out = fluidnerf(&["eval", "huge.npy", "--scene", ".", "--json", "m.json"], d);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{e}");
    assert!(e.contains("huge.npy: reprojected onto the held-out views: values up to"), "{e}");
    assert!(e.contains("beyond the largest 32-bit float") && e.contains("--no-reprojection"), "{e}");
    assert!(out.stdout.is_empty() && !d.join("m.json").exists(), "scored before refusing");
    let out = fluidnerf(&["eval", "huge.npy", "--scene", ".", "--json", "m.json", "--no-reprojection"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// A scene that holds no frame out gets only volume metrics; eval says so, and that a
/// --supersample given for the held-out views it would render changes nothing.
#[test]
fn a_scene_without_held_out_frames_is_warned_to_get_no_reprojection() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let mut scene = make_scene(d, &[]);
    let v = Volume::from_fn([18, 12, 12], scene.aabb, |p| blob(p, 0.0));
    fluidnerf_io::volume::write_npy(&d.join("r.npy"), &v).expect("writes recon");
    let with_holdout = fluidnerf(&["eval", "r.npy", "--scene", ".", "--json", "a.json", "--no-regions"], d);
    ok_eval(&with_holdout);
    assert!(!String::from_utf8_lossy(&with_holdout.stderr).contains("holds no frame out"));

    for frame in &mut scene.frames {
        frame.holdout = false;
    }
    fluidnerf_io::scene::save_scene(&scene, d).expect("rewrites scene");
    let out =
        fluidnerf(&["eval", "r.npy", "--scene", ".", "--json", "b.json", "--no-regions", "--supersample", "4"], d);
    ok_eval(&out);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("holds no frame out") && err.contains("--supersample 4 has no effect"), "{err}");
    assert!(read_json(&d.join("b.json"))["reprojection"].as_array().expect("reprojection").is_empty());
}

/// A truth (or a reconstruction) in a box that does not overlap the other's is refused naming
/// both boxes: the reconstruction is zero on every voxel of such a truth, and eval scored it,
/// reporting an NRMSE of 1 as the result. A box shared in part is still scored.
#[test]
fn a_truth_apart_from_the_reconstruction_is_refused_naming_both_boxes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let scene = make_scene(d, &[]);
    let shifted = |dx: f64| {
        let shift = DVec3::new(dx, 0.0, 0.0);
        let aabb = Aabb::new(scene.aabb.min + shift, scene.aabb.max + shift);
        Volume::from_fn([18, 12, 12], aabb, |p| blob(p - shift, 0.0))
    };
    fluidnerf_io::volume::write_vti(&d.join("far.vti"), &shifted(100.0)).expect("writes");
    fluidnerf_io::volume::write_vti(&d.join("near.vti"), &shifted(1.0)).expect("writes");
    let refused = |out: &std::process::Output, needle: &str| {
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{e}");
        assert!(e.contains(needle), "{e}");
        assert!(!e.contains("panicked") && out.stdout.is_empty() && !d.join("m.json").exists(), "{e}");
    };
    let o = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--truth", "far.vti", "--json", "m.json"], d);
    refused(&o, "--truth far.vti fills the box [98.5, -1, -1] .. [101.5, 1, 1], which does not overlap the box");
    let o = fluidnerf(&["eval", "far.vti", "--scene", ".", "--json", "m.json"], d);
    refused(&o, "does not overlap the box [98.5, -1, -1] .. [101.5, 1, 1] of far.vti");
    let o = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--truth", "near.vti", "--json", "m.json"], d);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A reconstruction or truth path that names nothing says so: it was refused as an "unknown
/// volume format", sending the user to convert a file that is not there.
#[test]
fn a_missing_reconstruction_or_truth_is_named_as_missing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    for args in [
        &["eval", "run_not_made", "--scene", ".", "--json", "m.json"][..],
        &["eval", "truth_0.npy", "--scene", ".", "--truth", "truth_typo", "--json", "m.json"][..],
    ] {
        let o = fluidnerf(args, d);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{e}");
        assert!(e.contains(": no such file or directory") && !e.contains("unknown volume format"), "{args:?}: {e}");
    }
}

/// A folder given as a volume (a synthetic scene's `truth/`) is named as a folder, with the
/// volume file inside it to give instead.
#[test]
fn a_folder_given_as_the_truth_names_the_volume_inside_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    make_scene(d, &[]);
    std::fs::create_dir(d.join("vols")).expect("mkdir");
    std::fs::copy(d.join("truth_0.npy"), d.join("vols/truth_0.npy")).expect("copy");
    let o = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--truth", "vols", "--json", "m.json"], d);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{e}");
    assert!(e.contains("vols: a folder, not a volume file") && e.contains("vols/truth_0.npy"), "{e}");
    // A scene folder: its own ground truth is named, which is what a user giving it means.
    std::fs::create_dir(d.join("empty")).expect("mkdir");
    let o = fluidnerf(&["eval", "truth_0.npy", "--scene", ".", "--truth", "empty/..", "--json", "m.json"], d);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{e}");
    assert!(e.contains("a folder, not a volume file; it is a scene; its ground truth is"), "{e}");
    assert!(e.contains("truth_0.npy"), "{e}");
    assert!(!d.join("m.json").exists(), "no report from a refused truth");
}
