//! `fluidnerf reconstruct --method asart|art|sart|mart|smart|mlem|tv|tikhonov` end to end on a
//! tiny generated scene: the files it writes, accuracy against the truth, refusal to overwrite,
//! rerunning from `config.json`, every method and option, the NRMSE curve, and the memory
//! refusal.

use std::process::Command;

use crate::common;
use common::*;

#[test]
fn classical_runs_write_results_refuse_overwrite_and_rerun_from_config() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 7, 40, 24, &["--holdout", "1"]);
    let asart = ["reconstruct", "scene", "-o", "run", "--method", "asart", "--resolution", "20", "-q"];
    let out = fluidnerf(d, &asart);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("asart:"), "summary on stdout");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("wrote run (config.json, report.json, report.html, volume.npy, volume.vti)\n"), "{text}");
    let dir = d.join("run");
    for f in ["volume.npy", "volume.vti", "config.json", "report.json"] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    let r = report(&dir);
    assert_eq!(r["volumes"][0]["dims"], serde_json::json!([20, 20, 20]));
    assert_eq!(r["classical"]["views"], 6, "the held-out frame is not used");
    let iterations = r["iterations"].as_u64().expect("iterations") as usize;
    let history: Vec<f64> =
        r["history"]["loss"].as_array().expect("history").iter().map(|v| v.as_f64().expect("number")).collect();
    assert_eq!(history.len(), iterations);
    assert!((1..=250).contains(&iterations));
    assert!(history[iterations - 1] < history[0], "residual must fall: {history:?}");
    assert!(r["memory_estimate_bytes"].as_u64().expect("estimate") > 20 * 20 * 20 * 4);
    // Ground truth in the scene: measured NRMSE 0.123 for this setup.
    let nrmse = r["volumes"][0]["metrics"]["global"]["nrmse"].as_f64().expect("nrmse");
    assert!(nrmse < 0.15, "ASART NRMSE {nrmse}");

    // Existing results are kept unless --force.
    let again = fluidnerf(d, &asart);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));

    // The resolved settings rerun to the same volume.
    ok(&fluidnerf(
        d,
        &["reconstruct", "scene", "-o", "rerun", "--method", "asart", "--config", "run/config.json", "-q"],
    ));
    let a = std::fs::read(dir.join("volume.npy")).expect("volume");
    let b = std::fs::read(d.join("rerun/volume.npy")).expect("volume");
    assert_eq!(a, b, "rerun from config.json differs");
    // A config of another method is refused with a hint.
    let wrong = fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "sart", "--config", "run/config.json"]);
    assert!(!wrong.status.success());
    assert!(String::from_utf8_lossy(&wrong.stderr).contains("--method"));
}

/// The warning of a SART-TV run inside a visual hull.
const HULL_TV: &str = "SART-TV inside a visual hull";

#[test]
fn every_method_and_option_runs_and_memory_is_checked() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 5, 32, 16, &[]);
    for method in ["art", "sart", "mart", "smart", "mlem", "tv", "tikhonov"] {
        let out = format!("run-{method}");
        let run = fluidnerf(
            d,
            &["reconstruct", "scene", "-o", &out, "--method", method, "--resolution", "12", "--max-iterations", "3"],
        );
        ok(&run);
        assert!(!String::from_utf8_lossy(&run.stderr).contains(HULL_TV), "{method}: no hull, no warning");
        let r = report(&d.join(&out));
        assert_eq!(r["warnings"], serde_json::json!([]), "{method}");
        assert_eq!(r["iterations"], 3, "{method}");
    }
    // Ray projector, visual hull, TV weight, no plateau rule. TV inside a hull with the data
    // step rule is warned of, also in report.json and report.html, where a quiet run (-q) still
    // records it.
    let run = fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "ray",
            "--method",
            "tv",
            "--resolution",
            "12",
            "--projector",
            "ray",
            "--ray-step",
            "0.7",
            "--visual-hull",
            "--tv-weight",
            "0.1",
            "--tv-step-rule",
            "data",
            "--plateau-tolerance",
            "0",
            "--max-iterations",
            "4",
            "-q",
        ],
    );
    ok(&run);
    assert!(!String::from_utf8_lossy(&run.stderr).contains(HULL_TV), "-q prints only errors");
    let r = report(&d.join("ray"));
    let warnings = r["warnings"].as_array().expect("warnings");
    assert!(warnings.len() == 1 && warnings[0].as_str().is_some_and(|w| w.starts_with(HULL_TV)), "{warnings:?}");
    let html = std::fs::read_to_string(d.join("ray/report.html")).expect("report.html");
    assert!(html.contains(HULL_TV), "report.html shows the warning");
    assert_eq!(r["classical"]["projector"], "ray");
    assert_eq!(r["iterations"], 4);
    let kept = r["classical"]["hull_voxels"].as_u64().expect("hull used");
    assert!(kept > 0 && kept < 12 * 12 * 12, "hull keeps {kept}");
    let cfg: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("ray/config.json")).expect("config")).expect("json");
    assert_eq!(cfg["method"]["params"]["tv_weight"], 0.1);
    assert_eq!(cfg["method"]["params"]["step_rule"], "data");
    // With the default rule, balanced inside a hull, there is nothing to warn of.
    let run = fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "hull-auto",
            "--method",
            "tv",
            "--resolution",
            "12",
            "--visual-hull",
            "--max-iterations",
            "2",
        ],
    );
    ok(&run);
    assert!(!String::from_utf8_lossy(&run.stderr).contains(HULL_TV), "the balanced rule is not warned of");
    assert_eq!(report(&d.join("hull-auto"))["warnings"], serde_json::json!([]));
    assert_eq!(cfg["method"]["params"]["stopping"]["plateau"], serde_json::Value::Null);

    // Too little memory: refused before any work, with the estimate.
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "big", "--method", "sart", "--memory-limit", "0.00001"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("needs about") && err.contains("allowed"), "{err}");
    assert!(!d.join("big").exists(), "nothing written for a refused run");
    // Bad values are rejected early.
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "bad", "--method", "mart", "--relaxation", "1.5"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("relaxation"));
}

/// A visual hull that carves every voxel (here a box in a corner of the scene's, where every
/// view is dark) held the whole volume at zero: the run wrote it and reported success. It is
/// refused before any work, naming the hull and what to change, and writes nothing.
#[test]
fn an_empty_visual_hull_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    edit_json(&d.join("scene/transforms.json"), |v| v["aabb"] = serde_json::json!([[12, 12, 12], [20, 20, 20]]));
    let run = ["reconstruct", "scene", "--resolution", "8", "--max-iterations", "2", "--visual-hull", "-q"];
    for method in ["sart", "mart", "mlem"] {
        let out = fluidnerf(d, &[&run[..], &["-o", method, "--method", method]].concat());
        refused(&out, "the visual hull is empty");
        refused(&out, "--hull-threshold");
        assert!(!d.join(method).exists(), "{method}: a refused run leaves nothing");
    }
    // Without the hull the same box runs.
    ok(&fluidnerf(d, &[&run[..6], &["-q", "-o", "free", "--method", "sart"]].concat()));
}

/// ART and MART inside the visual hull are as accurate as without it. ART's rows, cut to the
/// hull, divided a grazing ray's residual by the norm of the few voxels left of it: on this
/// scene its NRMSE went from 0.20 to 0.89, with a relative residual above 1.
#[test]
fn art_and_mart_inside_the_visual_hull_are_as_accurate_as_without_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 8, 32, 16, &[]);
    for method in ["art", "mart"] {
        let run = ["reconstruct", "scene", "--resolution", "16", "--method", method, "-q"];
        ok(&fluidnerf(d, &[&run[..], &["-o", "free"], &["--force"]].concat()));
        ok(&fluidnerf(d, &[&run[..], &["-o", "hull", "--visual-hull", "--force"]].concat()));
        let nrmse = |r: &str| report(&d.join(r))["final_nrmse"].as_f64().expect("truth was used");
        let (free, hull) = (nrmse("free"), nrmse("hull"));
        assert!(hull < 1.05 * free, "{method}: in the hull {hull:.4}, without {free:.4}");
        assert_eq!(report(&d.join("hull"))["warnings"], serde_json::json!([]), "{method}");
    }
}

/// Ctrl-C (SIGINT) stops after the current iteration and still writes a usable result.
#[cfg(unix)]
#[test]
fn interrupt_writes_the_last_finished_iteration() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 24, 12, &[]);
    let mut child = Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .current_dir(d)
        .args([
            "reconstruct",
            "scene",
            "-o",
            "run",
            "--method",
            "sart",
            "--resolution",
            "10",
            "--max-iterations",
            "10000000",
            "--plateau-tolerance",
            "0",
            "-q",
        ])
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("starts");
    // config.json is written after the handler is installed, just before iterating.
    let start = std::time::Instant::now();
    while !d.join("run/config.json").exists() {
        assert!(start.elapsed().as_secs() < 60, "run did not start");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    // A second run into the same folder is refused while the first holds it, even with --force.
    let second = fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "asart", "--force", "-q"]);
    assert!(!second.status.success());
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(err.contains("in use by another run") && err.contains(&child.id().to_string()), "{err}");
    let killed = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill runs");
    assert!(killed.success());
    let status = child.wait().expect("waits");
    assert_eq!(status.code(), Some(130), "an interrupted run exits with 130 after writing its results");
    let r = report(&d.join("run"));
    assert_eq!(r["stop_reason"], "interrupted");
    assert_eq!(r["status"], "interrupted");
    let iterations = r["iterations"].as_u64().expect("iterations");
    assert!((1..10_000_000).contains(&iterations));
    assert!(d.join("run/volume.npy").is_file() && d.join("run/volume.vti").is_file());
}

/// With ground truth, a classical run records the NRMSE curve every iteration (or every
/// --eval-every N), with times that exclude the evaluations; --tikhonov-weight reaches the
/// config.
#[test]
fn nrmse_history_and_tikhonov_weight() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 6, 32, 16, &["--noise", "0.05"]);
    let base =
        ["reconstruct", "scene", "--resolution", "16", "--max-iterations", "20", "--plateau-tolerance", "0", "-q"];
    let mut tik = base.to_vec();
    tik.extend(["-o", "tik", "--method", "tikhonov", "--tikhonov-weight", "0.04"]);
    ok(&fluidnerf(d, &tik));
    let r = report(&d.join("tik"));
    assert_eq!(r["method"], "tikhonov");
    assert_eq!(json(&d.join("tik/config.json"))["method"]["params"]["weight"], 0.04);
    let history = r["history"]["nrmse"].as_array().expect("history");
    assert_eq!(history.len(), 20, "one point per iteration by default");
    let mut last_time = 0.0;
    for (k, p) in history.iter().enumerate() {
        assert_eq!(p["iteration"], k + 1);
        let t = p["train_time_s"].as_f64().expect("time");
        assert!(t > last_time, "times must grow: {history:?}");
        last_time = t;
        assert!(p["nrmse"].as_f64().expect("nrmse") > 0.0);
    }
    let solve_s = r["train_time_s"].as_f64().expect("solve time");
    assert!(last_time <= solve_s + 1e-9, "curve time {last_time} beyond the solver's {solve_s}");
    // The truth lies on the solver's grid: the curve's last point is the final NRMSE (up to the
    // order of the sums, the solver's axes being the scene's renamed).
    let last = history[19]["nrmse"].as_f64().expect("nrmse");
    let fin = r["final_nrmse"].as_f64().expect("final");
    assert!((last - fin).abs() <= 1e-9 * fin, "last curve point {last} vs final {fin}");

    // Every third iteration, and the last one.
    let mut sart = base.to_vec();
    sart.extend(["-o", "sart", "--method", "sart", "--eval-every", "3"]);
    ok(&fluidnerf(d, &sart));
    let r = report(&d.join("sart"));
    let iterations: Vec<u64> = r["history"]["nrmse"]
        .as_array()
        .expect("history")
        .iter()
        .map(|p| p["iteration"].as_u64().expect("n"))
        .collect();
    assert_eq!(iterations, [3, 6, 9, 12, 15, 18, 20]);
    assert_eq!(r["history"]["eval_every"], 3);
    // With 5 % noise the smoothness prior wins: measured NRMSE 0.235 against 0.288 after 20
    // iterations.
    let e_sart = r["final_nrmse"].as_f64().expect("final");
    assert!(fin < e_sart, "Tikhonov {fin} vs SART {e_sart}");

    let bad = fluidnerf(d, &["reconstruct", "scene", "-o", "bad", "--method", "tikhonov", "--tikhonov-weight=-1"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("weight"));
}

/// A ring of cameras around `y` (the CFD phantoms') is solved on axes renamed so that `y`
/// becomes the grid's `x`, where the footprint projector shares its rows' footprints. The
/// volume comes back on the scene's axes: it matches the ray projector's reconstruction,
/// which renames nothing (RMS difference 0.7 % of the peak here; 12 % with the axes left
/// renamed), and the truth.
#[test]
fn a_ring_around_y_comes_back_on_the_scenes_axes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = ["synth", "--preset", "plume15", "--cameras", "6", "--pixels", "40", "--resolution", "24"];
    ok(&fluidnerf(d, &[&synth[..], &["-o", "scene", "-q"]].concat()));
    let run = |name: &str, projector: &str| {
        let args = ["reconstruct", "scene", "-o", name, "--method", "asart", "--projector", projector];
        ok(&fluidnerf(
            d,
            &[&args[..], &["--stop", "budget", "--max-iterations", "15", "--resolution", "24", "-q"]].concat(),
        ));
        let r = report(&d.join(name));
        let nrmse = r["final_nrmse"].as_f64().expect("nrmse");
        let dims = r["volumes"][0]["dims"].clone();
        let aabb = fluidnerf_core::Aabb::cube(Default::default(), 1.0);
        let v = fluidnerf_io::volume::read_npy(&d.join(name).join("volume.npy"), aabb).expect("volume");
        (nrmse, dims, v.data)
    };
    let (footprint, dims_f, a) = run("footprint", "footprint");
    let (ray, dims_r, b) = run("ray", "ray");
    assert_eq!(dims_f, dims_r);
    assert_eq!(dims_f[1], 24, "the plume's box is tallest along y: {dims_f}");
    let peak = b.iter().fold(0f32, |m, &v| m.max(v)) as f64;
    let rms = (a.iter().zip(&b).map(|(p, q)| ((p - q) as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
    assert!(rms < 0.05 * peak, "footprint and ray volumes differ by {rms} RMS (peak {peak})");
    assert!(footprint < 0.4 && footprint < 1.3 * ray, "NRMSE footprint {footprint}, ray {ray}");
}

/// An option of a projector the run does not use, or of the visual hull without it, changed
/// nothing and was taken without a word; it is refused naming the option, whether the
/// projector comes from the command line or from --config.
#[test]
fn projector_and_hull_options_the_run_does_not_use_are_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    let run = ["reconstruct", "scene", "-o", "run", "--method", "sart", "--resolution", "8", "-q"];
    for (extra, says) in [
        (&["--projector", "splat", "--ray-step", "0.1"][..], "--ray-step sets the ray projector's step"),
        (&["--projector", "footprint", "--ray-step", "0.1"][..], "uses the footprint projector, which casts no rays"),
        (&["--projector", "ray", "--splat-subdivisions", "2"][..], "--splat-subdivisions sets the splat projector"),
        (&["--splat-subdivisions", "2"][..], "but this run uses the auto projector"),
        (&["--hull-threshold", "0.1"][..], "--hull-threshold sets the visual hull, which this run does not use"),
        (&["--hull-dilation", "2", "--hull-noise-sigmas", "3"][..], "--hull-noise-sigmas, --hull-dilation set"),
    ] {
        refused(&fluidnerf(d, &[&run[..], extra].concat()), says);
        assert!(!d.join("run").exists(), "{extra:?} started a run");
    }
    // Where they apply they are taken, the projector and hull also from a configuration.
    ok(&fluidnerf(d, &[&run[..], &["--projector", "ray", "--ray-step", "0.7", "--visual-hull"]].concat()));
    let again = ["reconstruct", "--config", "run/config.json", "-o", "again", "-q"];
    ok(&fluidnerf(d, &[&again[..], &["--ray-step", "0.6", "--hull-threshold", "0.05"]].concat()));
    refused(&fluidnerf(d, &[&again[..], &["--force", "--splat-subdivisions", "2"]].concat()), "the ray projector");
}

/// The same settings in a --config file, set away from their defaults for a projector the run
/// does not use or for the hull without it, are refused by their keys; a file the program wrote
/// (every key at its default) and an older one without the hull's later keys are taken.
#[test]
fn projector_and_hull_settings_a_config_does_not_use_are_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    let run = ["reconstruct", "scene", "-o", "run", "--method", "sart", "--resolution", "8", "-q"];
    ok(&fluidnerf(d, &[&run[..], &["--projector", "footprint", "--max-iterations", "1"]].concat()));
    let again = ["reconstruct", "--config", "cfg.json", "-o", "again", "-q"];
    let saved = json(&d.join("run/config.json"));
    for (key, value, says) in [
        ("ray_step", serde_json::json!(0.3), "0.3 sets the ray projector's step, but kind is footprint"),
        ("splat_subdivisions", serde_json::json!(2), "2 sets the splat projector's sub-voxels, but kind is footprint"),
        ("hull_threshold", serde_json::json!(0.1), "0.1 sets the visual hull, which visual_hull false leaves unused"),
        ("hull_noise_sigmas", serde_json::json!(2), "2 sets the visual hull"),
        ("hull_dilation", serde_json::json!(3), "3 sets the visual hull"),
    ] {
        let mut c = saved.clone();
        c["method"]["projector"][key] = value;
        std::fs::write(d.join("cfg.json"), c.to_string()).expect("writes");
        refused(&fluidnerf(d, &again), &format!("the settings of cfg.json: method.projector.{key}: {says}"));
        assert!(!d.join("again").exists(), "{key}: started a run");
    }
    // Without the hull's later keys a configuration reads them as 0, as it was run.
    let mut c = saved.clone();
    for key in ["hull_noise_sigmas", "hull_dilation"] {
        c["method"]["projector"].as_object_mut().expect("an object").remove(key);
    }
    std::fs::write(d.join("cfg.json"), c.to_string()).expect("writes");
    ok(&fluidnerf(d, &again));
    ok(&fluidnerf(d, &["reconstruct", "--config", "run/config.json", "-o", "rerun", "-q"]));
}

/// A frame that its background leaves black is warned of once per command: a run's report
/// draws its camera figure from the images the run read, rather than reading (and warning
/// about) them again. `info` also lists it among the scene's warnings, above its summary.
#[test]
fn a_frame_left_black_by_its_background_is_warned_of_once() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    edit_json(&d.join("scene/transforms.json"), |v| v["frames"][0]["background"] = serde_json::json!(1e9));
    let warning = "nothing is left after its background is subtracted";
    let count = |args: &[&str]| {
        let out = fluidnerf(d, args);
        ok(&out);
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        (err.matches(warning).count(), err)
    };
    let quick = ["--resolution", "8", "--max-iterations", "2"];
    for (method, out) in [("sart", "voxels"), ("fast", "field")] {
        let (n, err) = count(&[&["reconstruct", "scene", "-o", out, "--method", method][..], &quick].concat());
        assert_eq!(n, 1, "{method}: {err}");
        assert!(d.join(out).join("report.html").is_file(), "{method}: the report has its figure");
    }
    let (n, err) = count(&["info", "scene"]);
    assert_eq!(n, 1, "info: {err}");
    // `info` lists it among the scene's warnings too, which its summary follows.
    let out = String::from_utf8_lossy(&fluidnerf(d, &["info", "scene"]).stdout).into_owned();
    assert!(out.contains("warning: frame 0 (") && out.contains(warning), "{out}");
}

/// A ground truth that is zero throughout was taken by `reconstruct` (which `info` and `eval`
/// refuse): a static run printed "volume NRMSE NaN", and a time-resolved run's headline averaged
/// its NRMSE over the other times and its SSIM over all. Refused now, naming the file.
#[test]
fn a_truth_zero_throughout_is_refused_naming_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 8, &[]);
    let truth = d.join("scene/truth/truth.npy");
    let v = fluidnerf_io::volume::read_npy(&truth, fluidnerf_core::Aabb::cube(Default::default(), 1.0))
        .expect("reads truth");
    let zero = fluidnerf_core::Volume::zeros(v.dims, v.aabb);
    fluidnerf_io::volume::write_npy(&truth, &zero).expect("writes truth");
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "asart", "--resolution", "8", "-q"]);
    refused(&out, "truth/truth.npy: every voxel of the ground truth is zero, so the NRMSE against it");
    assert!(!d.join("run/report.json").exists());
}

/// A finished run whose volume was removed was said to have stopped before its first
/// checkpoint or result (config.json only), though its report.json is there.
#[test]
fn a_finished_run_whose_result_was_removed_says_so() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 8, &[]);
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "asart", "--resolution", "8", "-q"]));
    std::fs::remove_file(d.join("run/volume.npy")).expect("removes the volume");
    for args in [&["eval", "run"][..], &["export", "run", "-o", "ex", "--npy"], &["render", "run", "-o", "views"]] {
        refused(&fluidnerf(d, args), "run: holds a run's report.json but none of its results");
    }
}
