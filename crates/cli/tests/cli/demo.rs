//! `fluidnerf demo` end to end, at a small output grid and a few iterations per method.

use crate::common;
use common::*;

/// The demo runs the grid field, the hybrid, ASART and SART-TV under the same stopping rule,
/// prints one table with all four, writes their runs and the comparison, and refuses to
/// replace an earlier demo unless asked.
#[test]
fn demo_compares_the_fields_with_both_classical_methods() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let d = tmp.path();
    let args = ["demo", "-o", "out", "--resolution", "16", "--max-iterations", "4", "-q"];
    let out = fluidnerf(d, &args);
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let labels = ["FluidNeRF (fast field)", "voxel start → grid field", "ASART", "SART-TV"];
    for label in labels {
        assert!(stdout.lines().any(|l| l.starts_with(label)), "no table row for {label}:\n{stdout}");
    }
    // Every run ended at the cap given, inside the same default budget: the table says so.
    let rule = stdout.lines().find(|l| l.starts_with("every method stopped by held-out early stopping"));
    assert!(rule.is_some_and(|l| l.ends_with(", at most 4 iterations, at most 60 s")), "{stdout}");
    assert!(stdout.contains("* ended by the iteration cap (--max-iterations)"), "{stdout}");
    // The fields against the better of the two voxel methods, in one line.
    let against = stdout.lines().find(|l| l.starts_with("against the best voxel method, ")).expect("ratios");
    assert!(against.contains("FluidNeRF (fast field) ") && against.contains("voxel start → grid field "), "{against}");
    assert!(against.contains(", ASART (NRMSE ") || against.contains(", SART-TV (NRMSE "), "{against}");
    let comparison = json(&d.join("out/comparison.json"));
    let rows = comparison.as_array().expect("a list of runs");
    assert_eq!(rows.len(), 4);
    for ((row, label), (dir, method)) in rows.iter().zip(labels).zip([
        ("fluidnerf", "fast"),
        ("hybrid", "hybrid"),
        ("asart", "asart"),
        ("sart-tv", "tv"),
    ]) {
        assert_eq!(row["method"], label);
        let stopping = row["stopping"].as_str().unwrap_or_default();
        assert!(
            stopping.starts_with("held-out early stopping") && stopping.ends_with("at most 4 iterations, at most 60 s"),
            "{row}"
        );
        assert_eq!(row["iterations"], 4);
        assert!(row["metrics"]["global"]["nrmse"].as_f64().is_some_and(f64::is_finite), "{row}");
        let report = report(&d.join("out").join(dir));
        assert_eq!(report["method"], method, "{dir}");
        // Scored through the volume it wrote, the fields too, as `study` scores them.
        let metrics = json(&d.join("out").join(dir).join("metrics.json"));
        assert_eq!(metrics["settings"]["use_volume"], matches!(method, "fast" | "hybrid"), "{dir}");
    }
    let nrmse = |i: usize| rows[i]["metrics"]["global"]["nrmse"].as_f64().expect("nrmse");
    let best = nrmse(2).min(nrmse(3));
    for (i, label) in labels[..2].iter().enumerate() {
        let said = format!("{label} {:.2}×", nrmse(i) / best);
        assert!(against.contains(&said), "{said} in {against}");
    }
    for file in ["slices.png", "convergence.png", "report.html"] {
        assert!(d.join("out").join(file).is_file(), "{file}");
    }
    // The report names the preset the scene was made from (it said "a synthetic jet" of any).
    let html = std::fs::read_to_string(d.join("out/report.html")).expect("report");
    assert!(
        html.contains("SART-TV on the synthetic scene `demo`, all stopped by"),
        "{}",
        &html[..html.len().min(2000)]
    );
    // The one policy is stated once above the table, whose rows say what ended each run.
    assert!(html.contains("every method stopped by held-out early stopping (patience 10), at most 4 iterations"));
    assert!(html.contains(">ended by<") && html.matches(">iteration cap<").count() == 4, "{html}");
    assert!(html.contains("against the best voxel method, "), "{html}");
    refused(&fluidnerf(d, &args), "already holds a demo; pass --force to replace it");
}

/// Without `--max-iterations` the demo lifts every method's own cap, as `study` does, so that
/// the held-out rule or the one time budget ends each run; a budget that is no number of
/// seconds, a scene preset that is unknown or of several instants, an output grid no run can
/// use and scene settings synth refuses are refused before anything is written.
#[test]
fn the_demo_lifts_every_methods_own_cap_and_refuses_a_bad_budget_or_preset() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let d = tmp.path();
    for budget in ["0", "-1", "inf", "nan"] {
        let out = fluidnerf(d, &["demo", "-o", "out", "--time-budget", budget, "-q"]);
        refused(&out, "--time-budget must be a positive, finite number of seconds");
        assert!(!d.join("out").exists(), "--time-budget {budget}: nothing is written");
    }
    // A preset of several instants took minutes to synthesise, then every method mixed them into
    // one field scored against the first instant only; an unknown one left OUT made.
    for (preset, why) in [("plume-tr", "--preset: plume-tr holds 3 instants"), ("nope", "--preset: unknown preset")] {
        refused(&fluidnerf(d, &["demo", "-o", "out", "--preset", preset, "-q"]), why);
        assert!(!d.join("out").exists(), "--preset {preset}: nothing is written");
    }
    // An output grid no run can use was refused only at the first run, after the scene was made.
    for resolution in ["0", "1", "5000"] {
        refused(
            &fluidnerf(d, &["demo", "-o", "out", "--resolution", resolution, "-q"]),
            &format!("--resolution {resolution}: must be between 2 and 4096 voxels"),
        );
        assert!(!d.join("out").exists(), "--resolution {resolution}: nothing is written");
    }
    // So are the scene's settings, which left an empty folder behind.
    for (option, value, why) in
        [("--holdout", "99", "camera 99 does not exist"), ("--noise", "2", "--noise on the command line")]
    {
        refused(&fluidnerf(d, &["demo", "-o", "out", option, value, "-q"]), why);
        assert!(!d.join("out").exists(), "{option} {value}: nothing is written");
    }
    let out = fluidnerf(d, &["demo", "--help"]);
    ok(&out);
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(help.contains("default: 1000000 under held-out and budget"), "{help}");
    // The command's description (a constant placed between it and the options took it away).
    assert!(help.contains("Synthesises a small turbulent-jet scene"), "{help}");
    // A real-like preset runs with the defaults: its images carry their own noise, and the
    // demo's default noise made synth refuse a --noise the user never gave.
    ok(&fluidnerf(
        d,
        &["demo", "-o", "real", "--preset", "real-like-small", "--resolution", "8", "--max-iterations", "2", "-q"],
    ));
    assert!(d.join("real/report.html").is_file());
}

/// A demo writes its scene, runs, pictures and report.html into OUT: a scene, a run or a study
/// folder is refused (the demo went inside a scene, and --force replaced a study's report), and
/// so is a folder holding a file of a demo's names but no demo, before anything is written.
#[test]
fn the_demo_refuses_folders_of_other_kinds_and_files_it_would_overwrite() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let quick = ["--resolution", "8", "--max-iterations", "2", "--time-budget", "1", "-q"];
    let demo = |out: &str, force: bool| {
        let mut args = vec!["demo", "-o", out];
        args.extend(quick);
        if force {
            args.push("--force");
        }
        fluidnerf(d, &args)
    };
    for force in [false, true] {
        refused(&demo("scene", force), "is a scene folder (it holds transforms.json); `demo` writes demo folders only");
        assert!(!d.join("scene/scene").exists() && !d.join("scene/report.html").exists());
    }
    std::fs::create_dir(d.join("study")).expect("folder");
    std::fs::write(d.join("study/study.json"), "{}").expect("writes");
    std::fs::write(d.join("study/report.html"), "the study's").expect("writes");
    refused(&demo("study", true), "is a study folder (it holds study.json)");
    assert_eq!(std::fs::read_to_string(d.join("study/report.html")).expect("kept"), "the study's");
    std::fs::create_dir(d.join("mine")).expect("folder");
    std::fs::write(d.join("mine/slices.png"), "mine").expect("writes");
    for force in [false, true] {
        refused(&demo("mine", force), "holds slices.png but no comparison.json, so it is not a demo folder");
        assert!(!d.join("mine/scene").exists());
        assert_eq!(std::fs::read_to_string(d.join("mine/slices.png")).expect("kept"), "mine");
    }
}

/// Ctrl-C while the demo synthesises its scene stops the demo there and says so: the synthesis
/// wrote nothing and returned no error, and the first run went on to fail for want of the
/// scene's transforms.json.
#[cfg(unix)]
#[test]
fn a_demo_interrupted_while_making_its_scene_says_so() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let d = tmp.path();
    // OUT is made just before the synthesis starts; planar60 takes many seconds to synthesise.
    let o = interrupted_once_made(d, &["demo", "-o", "out", "--preset", "planar60", "--resolution", "8", "-q"], "out");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "stopped as a run stopped by Ctrl-C is: {err}");
    assert!(err.contains("interrupted before the scene was made") && !err.contains("not found"), "{err}");
    assert!(!d.join("out/scene/transforms.json").exists());
}
