//! `fluidnerf compare` end to end: a classical and a neural run on a tiny scene with ground
//! truth, plus a report file from another tool, drawn and tabulated together; and the errors
//! for runs that cannot be compared.

use crate::common;
use common::*;

#[test]
fn compares_classical_neural_and_external_runs() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 6, 32, 16, &[]);
    ok(&fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "sart",
            "--method",
            "sart",
            "--resolution",
            "16",
            "--max-iterations",
            "8",
            "--plateau-tolerance",
            "0",
            "-q",
        ],
    ));
    ok(&fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "dense",
            "--method",
            "fast",
            "--preset",
            "dense",
            "--max-iterations",
            "100",
            "--resolution",
            "16",
            "--eval-every",
            "25",
            "--rays-per-image",
            "256",
            "--checkpoint-every",
            "0",
            "-q",
        ],
    ));
    // A report from another implementation: only the fields compare needs, and one more.
    let external = serde_json::json!({
        "method": "pytorch-fluidnerf",
        "preset": "ch7",
        "nrmse_history": [
            {"iteration": 10, "train_time_s": 0.5, "nrmse": 0.9},
            {"iteration": 20, "train_time_s": 5.0, "nrmse": 0.6},
            {"iteration": 30, "train_time_s": 50.0, "nrmse": 0.45},
        ],
        "torch_version": "2.5",
    });
    std::fs::write(d.join("torch.json"), external.to_string()).expect("writes");

    let out = fluidnerf(
        d,
        &[
            "compare",
            "sart",
            "dense",
            "torch.json",
            "-o",
            "cmp",
            "--reference",
            "dense",
            "--thresholds",
            "0.8,0.5",
            "-q",
        ],
    );
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    for label in ["fast/dense (dense) *", "pytorch-fluidnerf/ch7 (torch)", "t(≤0.8)", "t(≤0.5)"] {
        assert!(stdout.contains(label), "{label:?} missing from\n{stdout}");
    }
    // A folder named after its method is not named twice.
    assert!(stdout.lines().any(|l| l.starts_with("sart ")) && !stdout.contains("(sart)"), "{stdout}");
    assert!(stdout.contains("1.00x"), "the reference against itself:\n{stdout}");
    for f in ["time_to_accuracy.png", "time_to_accuracy.svg", "time_to_accuracy.csv", "compare.json"] {
        assert!(d.join("cmp").join(f).is_file(), "{f} missing");
    }
    let svg = std::fs::read_to_string(d.join("cmp/time_to_accuracy.svg")).expect("svg");
    assert!(svg.contains("pytorch-fluidnerf/ch7 (torch)") && svg.contains("training wall time [s]"));

    // The CSV holds every point of every curve.
    let csv = std::fs::read_to_string(d.join("cmp/time_to_accuracy.csv")).expect("csv");
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], "run,method,preset,iteration,train_time_s,nrmse");
    let (sart_n, dense_n) = (
        report(&d.join("sart"))["history"]["nrmse"].as_array().map(Vec::len).expect("sart history"),
        report(&d.join("dense"))["history"]["nrmse"].as_array().map(Vec::len).expect("dense history"),
    );
    assert_eq!(sart_n, 8);
    assert!(dense_n >= 4);
    assert_eq!(lines.len(), 1 + sart_n + dense_n + 3);
    assert!(lines.iter().any(|l| l.starts_with("pytorch-fluidnerf/ch7 (torch),pytorch-fluidnerf,ch7,20,5,0.6")));

    // compare.json: settings and the table; the numbers follow from the curves.
    let c = json(&d.join("cmp/compare.json"));
    assert_eq!(c["thresholds"], serde_json::json!([0.8, 0.5]));
    let runs = c["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 3);
    let torch = &runs[2];
    assert_eq!(torch["best_nrmse"], 0.45);
    assert_eq!(torch["wall_time_s"], 50.0);
    assert_eq!(torch["time_to_threshold_s"], serde_json::json!([5.0, 50.0]));
    assert_eq!(runs[1]["speedup"], 1.0);

    // Existing results need --force.
    let again = fluidnerf(d, &["compare", "sart", "dense", "-o", "cmp", "-q"]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
    // The reference given as a report file of a listed run directory is that run, not a new one.
    ok(&fluidnerf(
        d,
        &[
            "compare",
            "sart",
            "dense",
            "-o",
            "cmp",
            "--force",
            "--linear-time",
            "--reference",
            "dense/report.json",
            "-q",
        ],
    ));
    let c = json(&d.join("cmp/compare.json"));
    assert_eq!(c["runs"].as_array().map(Vec::len), Some(2));
    assert_eq!(c["runs"][1]["speedup"], 1.0);

    // Runs of different scenes are refused, naming each run and its scene, unless asked for.
    let same = fluidnerf(d, &["compare", "sart", "dense", "-o", "cmp2"]);
    ok(&same);
    assert!(!String::from_utf8_lossy(&same.stderr).contains("different scenes"));
    std::fs::create_dir(d.join("elsewhere")).expect("mkdir");
    for f in ["report.json", "config.json"] {
        std::fs::copy(d.join("sart").join(f), d.join("elsewhere").join(f)).expect("copies");
    }
    let mut config = json(&d.join("elsewhere/config.json"));
    config["scene"] = serde_json::json!(d.join("cmp").to_string_lossy());
    std::fs::write(d.join("elsewhere/config.json"), config.to_string()).expect("writes");
    let other = fluidnerf(d, &["compare", "sart", "elsewhere", "-o", "cmp3"]);
    let scene = std::fs::canonicalize(d.join("scene")).expect("scene");
    let cmp = std::fs::canonicalize(d.join("cmp")).expect("cmp");
    refused(
        &other,
        &format!(
            "the runs were made from 2 different scenes: run sart from the scene {}; run elsewhere from the scene {}",
            scene.display(),
            cmp.display()
        ),
    );
    refused(&other, "--allow-different-scenes");
    assert!(!d.join("cmp3").exists(), "nothing written");
    let other = fluidnerf(d, &["compare", "sart", "elsewhere", "-o", "cmp3", "--allow-different-scenes", "-q"]);
    ok(&other);
    let err = String::from_utf8_lossy(&other.stdout);
    assert!(err.contains("2 different scenes") && err.contains("run elsewhere from"), "{err}");
    // Runs in folders of one name are told apart by their paths.
    std::fs::create_dir_all(d.join("copy/sart")).expect("mkdir");
    std::fs::copy(d.join("sart/report.json"), d.join("copy/sart/report.json")).expect("copies");
    let twins = fluidnerf(d, &["compare", "sart", "copy/sart", "-o", "cmp4", "-q"]);
    ok(&twins);
    let stdout = String::from_utf8_lossy(&twins.stdout);
    assert!(stdout.contains("sart [sart]") && stdout.contains("sart [copy/sart]"), "{stdout}");
    // A report without its configuration names no scene: compared, with a warning that says so.
    // Under the table, which -q keeps, and in compare.json: the log alone lost it under -q.
    let bare = fluidnerf(d, &["compare", "sart", "copy/sart", "-o", "cmp5", "-q"]);
    ok(&bare);
    let err = String::from_utf8_lossy(&bare.stdout);
    assert!(err.contains("! copy/sart: no config.json beside the report to name the scene"), "{err}");
    let warnings = json(&d.join("cmp5/compare.json"))["warnings"].clone();
    assert!(warnings[0].as_str().is_some_and(|w| w.starts_with("copy/sart: no config.json")), "{warnings}");
}

#[test]
fn runs_that_cannot_be_compared_are_named() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    std::fs::create_dir(d.join("empty")).expect("mkdir");
    let out = fluidnerf(d, &["compare", "empty", "-o", "cmp", "-q"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("empty") && err.contains("no report.json"), "{err}");

    std::fs::create_dir(d.join("notruth")).expect("mkdir");
    std::fs::write(d.join("notruth/report.json"), r#"{"method": "sart", "nrmse_history": []}"#).expect("writes");
    let out = fluidnerf(d, &["compare", "notruth", "-o", "cmp", "-q"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("notruth/report.json") && err.contains("--eval-every") && err.contains("ground truth"),
        "{err}"
    );

    std::fs::write(d.join("broken.json"), "{").expect("writes");
    let out = fluidnerf(d, &["compare", "broken.json", "-o", "cmp", "-q"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("broken.json"));
    assert!(!d.join("cmp").exists(), "nothing written for failed comparisons");

    let out = fluidnerf(d, &["compare", "missing", "-o", "cmp", "--thresholds", "0", "-q"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--thresholds"));

    // A history that goes back in time would give wrong times to the thresholds.
    let point = |i: u32, t: f64, n: &str| format!(r#"{{"iteration": {i}, "train_time_s": {t}, "nrmse": {n}}}"#);
    let history = |points: &[String]| format!(r#"{{"method": "sart", "nrmse_history": [{}]}}"#, points.join(", "));
    std::fs::write(d.join("back.json"), history(&[point(1, 0.5, "0.9"), point(2, 0.2, "0.5")])).expect("writes");
    let out = fluidnerf(d, &["compare", "back.json", "-o", "cmp", "-q"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("back.json: NRMSE history point 1 (iteration 2, 0.2 s) comes before point 0"), "{err}");
    std::fs::write(d.join("nan.json"), history(&[point(1, 0.5, "-1")])).expect("writes");
    let out = fluidnerf(d, &["compare", "nan.json", "-o", "cmp", "-q"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("point 0 (iteration 1) has a negative or non-finite value: time 0.5 s, NRMSE -1"), "{err}");
    // So are a final NRMSE and a run time that no run writes: the table printed them as results.
    let curve = |extra: &str| format!(r#"{{"method": "sart", "nrmse_history": [{}]{extra}}}"#, point(1, 0.5, "0.9"));
    std::fs::write(d.join("final.json"), curve(r#", "final_nrmse": -3"#)).expect("writes");
    let out = fluidnerf(d, &["compare", "final.json", "-o", "cmp", "-q"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("final.json: `final_nrmse` is -3"), "{err}");
    std::fs::write(d.join("time.json"), curve(r#", "train": {"train_time_s": -1}"#)).expect("writes");
    let out = fluidnerf(d, &["compare", "time.json", "-o", "cmp", "-q"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("time.json: `train_time_s` of the run is -1 s"), "{err}");
    assert!(!d.join("cmp").exists(), "nothing written for failed comparisons");
}

/// A run folder whose run never finished (its config.json, no report.json) is named as such:
/// it was asked whether it was a run folder at all.
#[test]
fn an_unfinished_run_is_named_as_such() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    std::fs::create_dir(d.join("run")).expect("mkdir");
    std::fs::write(d.join("run/config.json"), "{}").expect("writes");
    let out = fluidnerf(d, &["compare", "run", "-o", "cmp", "-q"]);
    refused(&out, "run: holds an unfinished run (config.json but no report.json)");
    assert!(String::from_utf8_lossy(&out.stderr).contains("reconstruct --resume"));
    assert!(!d.join("cmp").exists(), "nothing written for failed comparisons");
}

/// A run's config.json given in place of its report is named as such: it was read as a report
/// and refused for an unknown variant of `method`.
#[test]
fn a_runs_configuration_given_as_its_report_is_named_as_such() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 3, 16, 8, &[]);
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "sart", "--max-iterations", "1", "-q"]));
    let out = fluidnerf(d, &["compare", "run/config.json", "-o", "cmp", "-q"]);
    refused(
        &out,
        "run/config.json: is a run's configuration, not its report; give the run folder run or its report.json",
    );
    assert!(!d.join("cmp").exists(), "nothing written for failed comparisons");
}

/// Times and ratios no run gives, read from a report, are tabled in scientific notation: a
/// `train_time_s` of 1e308 was printed as 309 digits, which broke the table's columns.
#[test]
fn huge_times_keep_the_table_narrow() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let curve = |time: f64| {
        serde_json::json!({
            "method": "sart",
            "nrmse_history": [{"iteration": 1, "train_time_s": 0.5, "nrmse": 0.4}],
            "train": {"train_time_s": time},
        })
    };
    std::fs::write(d.join("slow.json"), curve(1e308).to_string()).expect("writes");
    std::fs::write(d.join("quick.json"), curve(1.0).to_string()).expect("writes");
    let out = fluidnerf(d, &["compare", "slow.json", "quick.json", "-o", "cmp", "-q"]);
    ok(&out);
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("1.0e308"), "{table}");
    assert!(table.lines().all(|l| l.chars().count() < 120), "{table}");
}

/// A curve file holding both a report's `history.nrmse` and a curve's `nrmse_history` had one
/// read and the other passed over, and one that repeats an iteration was taken as two
/// evaluations; both are refused naming the file and the key.
#[test]
fn a_curve_with_two_histories_or_a_repeated_iteration_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let point = |i: u32, t: f64, n: f64| serde_json::json!({ "iteration": i, "train_time_s": t, "nrmse": n });
    let both = serde_json::json!({
        "method": "sart",
        "nrmse_history": [point(1, 0.1, 0.9)],
        "history": { "nrmse": [point(1, 0.1, 0.5)] },
    });
    std::fs::write(d.join("both.json"), both.to_string()).expect("writes");
    refused(
        &fluidnerf(d, &["compare", "both.json", "-o", "cmp", "-q"]),
        "both.json: holds both `history.nrmse` (a run report's NRMSE history) and `nrmse_history`",
    );
    let repeat = serde_json::json!({ "method": "sart", "nrmse_history": [point(1, 0.1, 0.9), point(2, 0.2, 0.6), point(1, 0.3, 0.5)] });
    std::fs::write(d.join("repeat.json"), repeat.to_string()).expect("writes");
    refused(
        &fluidnerf(d, &["compare", "repeat.json", "-o", "cmp", "-q"]),
        "repeat.json: `nrmse_history` point 2 repeats iteration 1 of point 0",
    );
    let backwards = serde_json::json!({ "method": "sart", "nrmse_history": [point(5, 0.1, 0.9), point(1, 0.2, 0.6)] });
    std::fs::write(d.join("backwards.json"), backwards.to_string()).expect("writes");
    refused(
        &fluidnerf(d, &["compare", "backwards.json", "-o", "cmp", "-q"]),
        "backwards.json: NRMSE history point 1 (iteration 1) comes after point 0 (iteration 5)",
    );
    assert!(!d.join("cmp").exists(), "nothing written for refused curves");
}

/// A time-resolved run's NRMSE is the mean over the recording's instants; a static run of the
/// same scene mixes them into one volume, scored against the first instant only. Drawn side
/// by side they were tabled as if one were many times faster: compare refuses them, naming
/// each run's instants, and still compares static runs of that scene with each other.
#[test]
fn runs_scored_over_different_instants_are_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15"]);
    let reconstruct = |out: &str, method: &str| {
        let args = ["reconstruct", "scene", "-o", out, "--method", method, "--resolution", "8"];
        ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "3", "-q"]].concat()));
    };
    reconstruct("tr", "tr-fast");
    reconstruct("asart", "asart");
    reconstruct("sart", "sart");
    let out = fluidnerf(d, &["compare", "tr", "asart", "-o", "cmp", "-q"]);
    refused(&out, "the runs' NRMSE are over different instants of the truth: tr (tr-fast): the mean over t = 14, 15");
    refused(&out, "asart (asart): t = 14 only");
    assert!(!d.join("cmp").exists(), "nothing written for a refused comparison");
    ok(&fluidnerf(d, &["compare", "asart", "sart", "-o", "cmp", "-q"]));
}

/// Runs reconstructed at different resolutions are scored on grids of different voxels: the
/// comparison says so instead of drawing them as one problem's curves.
#[test]
fn runs_on_grids_of_different_voxels_are_named() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let reconstruct = |out: &str, resolution: &str| {
        let args = ["reconstruct", "scene", "-o", out, "--method", "sart", "--resolution", resolution];
        ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "3", "-q"]].concat()));
    };
    reconstruct("r8", "8");
    reconstruct("r12", "12");
    reconstruct("again8", "8");
    let out = fluidnerf(d, &["compare", "r8", "r12", "-o", "cmp", "-q"]);
    ok(&out);
    let err = String::from_utf8_lossy(&out.stdout);
    assert!(err.contains("the runs' volumes are on grids of different voxels (r8 8×8×8, r12 12×12×12)"), "{err}");
    let out = fluidnerf(d, &["compare", "r8", "again8", "-o", "cmp2"]);
    ok(&out);
    assert!(!String::from_utf8_lossy(&out.stdout).contains("different voxels"));
    assert_eq!(json(&d.join("cmp2/compare.json"))["warnings"], serde_json::json!([]));
}

/// A run stopped by Ctrl-C is compared with a warning that its curve was cut short, and
/// compare.json records it: it was drawn and tabled as a run its stopping rule had ended.
#[test]
fn a_run_stopped_by_ctrl_c_is_named_as_cut_short() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    for out in ["whole", "cut"] {
        let args = ["reconstruct", "scene", "-o", out, "--method", "sart", "--resolution", "8"];
        ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "3", "-q"]].concat()));
    }
    // What Ctrl-C leaves: the report of the iterations made, with the status of a stop.
    edit_json(&d.join("cut/report.json"), |r| {
        r["status"] = "interrupted".into();
        r["stop_reason"] = "interrupted".into();
    });
    let out = fluidnerf(d, &["compare", "whole", "cut", "-o", "cmp", "-q"]);
    ok(&out);
    let err = String::from_utf8_lossy(&out.stdout);
    assert!(err.contains("the sart run was stopped by Ctrl-C after 3 iterations"), "{err}");
    assert!(!err.contains("whole/report.json"), "{err}");
    let record = json(&d.join("cmp/compare.json"));
    assert_eq!(record["runs"][0]["interrupted"], false);
    assert_eq!(record["runs"][1]["interrupted"], true);
}

/// The iterate a run kept, where it is not its last (held-out early stopping), is marked on
/// its curve: one dot more than the curve's own markers.
#[test]
fn the_kept_iterate_is_marked_on_the_curve() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 6, 32, 16, &[]);
    let run = "reconstruct scene -o dense --method fast --preset dense --max-iterations 100 --resolution 16 \
               --eval-every 25 --rays-per-image 256 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &run.split_whitespace().collect::<Vec<_>>()));
    let circles = |dir: &str| {
        std::fs::read_to_string(d.join(dir).join("time_to_accuracy.svg")).expect("svg").matches("<circle").count()
    };
    ok(&fluidnerf(d, &["compare", "dense/report.json", "-o", "last", "-q"]));
    assert_eq!(circles("last"), 4, "the four evaluations' markers, the last kept");
    // The same report, as if the held-out rule had kept iteration 50.
    let mut r = report(&d.join("dense"));
    r["kept_iteration"] = 50.into();
    std::fs::write(d.join("kept.json"), r.to_string()).expect("writes");
    ok(&fluidnerf(d, &["compare", "kept.json", "-o", "kept", "-q"]));
    assert_eq!(circles("kept"), 5, "and a dot on the kept iterate");
}

/// A field is scored at the truth's voxel centres and a voxel run through its volume: on a truth
/// finer than the voxel run's grid the two rules differ (on the real-like recording, 0.56× the
/// best voxel method one way and 1.01× the other), and the comparison says so.
#[test]
fn fields_and_voxel_runs_scored_by_different_rules_are_named() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 16, &[]);
    let run = |out: &str, method: &str, resolution: &str| {
        let args = ["reconstruct", "scene", "-o", out, "--method", method, "--resolution", resolution];
        ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "4", "--eval-every", "2", "-q"]].concat()));
    };
    run("coarse", "sart", "8");
    run("fine", "sart", "16");
    run("field", "fast", "8");
    let says =
        "are scored at the truth's voxel centres and the voxel runs through their volumes on grids of other voxels";
    let out = fluidnerf(d, &["compare", "field", "coarse", "-o", "cmp", "-q"]);
    ok(&out);
    let err = String::from_utf8_lossy(&out.stdout);
    assert!(err.contains(says) && err.contains("coarse 8×8×8 against the truth's 16×16×16"), "{err}");
    // On the truth's own grid the rules agree.
    let out = fluidnerf(d, &["compare", "field", "fine", "-o", "cmp2"]);
    ok(&out);
    assert!(!String::from_utf8_lossy(&out.stdout).contains(says));
}
