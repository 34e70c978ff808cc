//! `fluidnerf study` end to end on its tiny grid: the table, plots and report it writes, every
//! run under the same stopping policy, and resuming without rerunning finished cells.

use crate::common;
use common::*;

#[test]
fn a_study_runs_every_cell_under_one_policy_and_resumes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = ["study", "--preset", "smoke", "--methods", "fast,sart", "-o", "st", "-q"];
    let first = fluidnerf(d, &args);
    ok(&first);
    // Quiet: a line per cell and the table, not each scene's synth summary.
    let stdout = String::from_utf8_lossy(&first.stdout);
    assert!(stdout.contains("[1/4]") && !stdout.contains("wrote ") && !stdout.contains("phantom "), "{stdout}");
    let st = d.join("st");
    for f in ["study.json", "study.csv", "report.html", "against_cameras.png"] {
        assert!(st.join(f).is_file(), "{f} missing");
    }
    let record = json(&st.join("study.json"));
    let rows = record["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 4, "2 camera counts × 2 methods");
    for r in rows {
        let run = st.join(r["run"].as_str().expect("run folder"));
        let cfg = json(&run.join("config.json"));
        assert_eq!(cfg["stopping"]["rule"], "held-out", "{run:?}");
        assert_eq!(cfg["stopping"]["max_iterations"], 20);
        let rep = report(&run);
        assert!(rep["classical"].is_object() || rep["neural"].is_object());
        // Each scene has one more camera than its count, held out of training.
        let views = rep["classical"]["views"].as_u64();
        if let Some(v) = views {
            assert_eq!(v, r["cameras"].as_u64().expect("cameras"));
        }
        assert!(r["nrmse"].as_f64().is_some_and(|n| n > 0.0 && n < 1.5));
        // Every method scores the held-out camera within the 20 iterations, the field too
        // (its own interval is 25).
        assert!(r["best_holdout_loss"].as_f64().is_some(), "{run:?} never scored the held-out camera");
        // The held-out camera's image rendered from every result, one measure for all methods:
        // the mean of `eval`'s reprojection rows, written into the run's metrics.json.
        let metrics = json(&run.join("metrics.json"));
        let views = metrics["reprojection"].as_array().expect("reprojection");
        assert_eq!(views.len(), 1, "{metrics}");
        // Scored through the volume it wrote, the field too; on the truth's own grid that is
        // what the run recorded for itself.
        assert_eq!(metrics["settings"]["use_volume"], r["method"] == "fast", "{metrics}");
        let own = rep["final_nrmse"].as_f64().expect("the run's own score");
        assert!((r["nrmse"].as_f64().expect("scored") - own).abs() < 1e-6, "{r} against {own}");
        assert_eq!(r["holdout_nrmse"].as_f64(), views[0]["nrmse"].as_f64(), "{run:?}");
        assert!(r["holdout_nrmse"].as_f64().is_some_and(|n| n > 0.0 && n < 1.5));
    }
    let csv = std::fs::read_to_string(st.join("study.csv")).expect("csv");
    assert_eq!(csv.lines().count(), 5);
    // The smoke grid's cap of 20 iterations ends every run before the held-out rule does: the
    // terminal's table marks them, the report's names it.
    assert!(rows.iter().all(|r| r["stop_reason"] == "iteration-cap"), "{record}");
    assert_eq!(stdout.matches("/20* ").count(), 4, "{stdout}");
    assert!(stdout.contains("* ended by the iteration cap (--max-iterations), not by the stopping rule"), "{stdout}");
    let html = std::fs::read_to_string(st.join("report.html")).expect("report");
    assert!(html.contains(">ended by<") && html.matches(">iteration cap<").count() == 4, "{html}");
    // The field against the best voxel method of each cell, the project's measure of accuracy:
    // in the record, the report and the terminal.
    let against = record["against_best_voxel"].as_array().expect("against_best_voxel");
    assert_eq!(against.len(), 2, "{record}");
    for a in against {
        let cell = |m: &str| {
            rows.iter()
                .find(|r| r["cameras"] == a["cameras"] && r["method"] == m)
                .and_then(|r| r["nrmse"].as_f64())
                .expect("scored")
        };
        assert_eq!((a["method"].as_str(), a["best_voxel_method"].as_str()), (Some("fast"), Some("sart")));
        let ratio = a["ratio"].as_f64().expect("ratio");
        assert!((ratio - cell("fast") / cell("sart")).abs() < 1e-12, "{a}");
    }
    assert!(html.contains("Each field against the best voxel method of its cell"), "{html}");
    assert!(stdout.contains("each field against the best voxel method of its cell:"), "{stdout}");

    // Rerunning the same command reads the finished cells back instead of running them.
    let stamp =
        |p: &std::path::Path| std::fs::metadata(p.join("report.json")).and_then(|m| m.modified()).expect("mtime");
    let first_run = st.join(rows[0]["run"].as_str().expect("run"));
    let scored = |p: &std::path::Path| std::fs::metadata(p.join("metrics.json")).and_then(|m| m.modified()).ok();
    let (before, score) = (stamp(&first_run), scored(&first_run));
    let out = fluidnerf(d, &args);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("done earlier"));
    assert_eq!(stamp(&first_run), before, "a finished cell was run again");
    // ... and its held-out score, made after its report, is not made again.
    assert_eq!(scored(&first_run), score, "a finished cell was scored again");
    assert_eq!(json(&st.join("study.json"))["rows"], record["rows"]);
    // Other settings in the same folder are refused.
    let other = fluidnerf(d, &["study", "--preset", "smoke", "--methods", "asart", "-o", "st", "-q"]);
    assert!(!other.status.success());
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(err.contains("--force") && err.contains(r#"`methods`: ["fast","sart"] → ["asart"]"#), "{err}");
    let hull =
        fluidnerf(d, &["study", "--preset", "smoke", "--methods", "fast,sart", "--visual-hull", "-o", "st", "-q"]);
    assert!(!hull.status.success(), "the same folder with the voxel methods' hull");
    assert!(String::from_utf8_lossy(&hull.stderr).contains("`visual_hull`: false → true"));
}

/// `--repeats` runs each method that uses its seed once per seed on the same scene, and the
/// voxel methods without randomness once; the record, table and report give each cell's mean
/// and the range of its runs. A study of another repeat count is not continued in its folder.
#[test]
fn repeats_run_the_seeded_methods_once_per_seed_and_give_their_mean() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = [
        "study",
        "--preset",
        "smoke",
        "--methods",
        "fast,sart,art",
        "--cameras",
        "4",
        "--repeats",
        "3",
        "--seed",
        "5",
        "-o",
        "st",
    ];
    let out = fluidnerf(d, &args);
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("[7/7]") && stdout.contains("· seed 7") && stdout.contains("NRMSE range"), "{stdout}");
    let st = d.join("st");
    let record = json(&st.join("study.json"));
    let rows = record["rows"].as_array().expect("rows");
    let seeds = |m: &str| -> Vec<u64> {
        rows.iter().filter(|r| r["method"] == m).map(|r| r["seed"].as_u64().expect("seed")).collect()
    };
    assert_eq!((seeds("fast"), seeds("art"), seeds("sart")), (vec![5, 6, 7], vec![5, 6, 7], vec![5]));
    // Each run is its own folder, run with its seed, on the one scene of the cell.
    let mut nrmse = std::collections::BTreeMap::<String, Vec<f64>>::new();
    for r in rows {
        let run = r["run"].as_str().expect("run");
        let cfg = json(&st.join(run).join("config.json"));
        assert_eq!(cfg["seed"], r["seed"], "{run}");
        assert!(cfg["scene"].as_str().expect("scene").ends_with("ring360-c04-n000"), "{run}");
        let method = r["method"].as_str().expect("method").to_string();
        nrmse.entry(method).or_default().push(r["nrmse"].as_f64().expect("nrmse"));
    }
    assert!(rows.iter().any(|r| r["run"] == "runs/ring360-c04-n000/fast-seed6"));
    assert!(rows.iter().any(|r| r["run"] == "runs/ring360-c04-n000/sart"));
    // The seeds draw different fields.
    let fast = &nrmse["fast"];
    assert!(fast[0] != fast[1] && fast[1] != fast[2], "{fast:?}");
    let means = record["means"].as_array().expect("means");
    assert_eq!(means.len(), 3);
    for m in means {
        let runs = &nrmse[m["method"].as_str().expect("method")];
        assert_eq!(m["runs"].as_u64(), Some(runs.len() as u64));
        let mean = runs.iter().sum::<f64>() / runs.len() as f64;
        assert!((m["nrmse"].as_f64().expect("mean") - mean).abs() < 1e-12, "{m}");
        let lo = runs.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = runs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert_eq!((m["nrmse_min"].as_f64(), m["nrmse_max"].as_f64()), (Some(lo), Some(hi)), "{m}");
    }
    let csv = std::fs::read_to_string(st.join("study.csv")).expect("csv");
    assert!(csv.starts_with("layout,cameras,noise,method,seed,nrmse,") && csv.lines().count() == 8, "{csv}");
    let html = std::fs::read_to_string(st.join("report.html")).expect("report");
    assert!(html.contains("mean over its runs with seeds 5 to 7"), "the report has no table of means");
    // Continued with another repeat count, the folder is refused.
    let mut more = args.to_vec();
    more[8] = "2";
    let other = fluidnerf(d, &more);
    assert!(!other.status.success());
    assert!(String::from_utf8_lossy(&other.stderr).contains("`repeats`: 3 → 2"));
    // Out of range.
    more[8] = "0";
    refused(&fluidnerf(d, &more), "--repeats");
}

/// `--visual-hull` holds every voxel method inside the images' visual hull; the runs without it
/// have none.
#[test]
fn a_study_can_give_the_voxel_methods_the_visual_hull() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    for (dir, flag) in [("without", None), ("with", Some("--visual-hull"))] {
        let mut args = vec!["study", "--preset", "smoke", "--methods", "sart,mlem", "--cameras", "4", "-o", dir, "-q"];
        args.extend(flag);
        ok(&fluidnerf(d, &args));
        let record = json(&d.join(dir).join("study.json"));
        assert_eq!(record["grid"]["visual_hull"], flag.is_some());
        let rows = record["rows"].as_array().expect("rows");
        assert_eq!(rows.len(), 2);
        for r in rows {
            let cfg = json(&d.join(dir).join(r["run"].as_str().expect("run")).join("config.json"));
            assert_eq!(cfg["method"]["projector"]["visual_hull"], flag.is_some(), "{dir}: {cfg}");
        }
    }
}

/// A time budget that is not a positive, finite number of seconds, and a scene preset of
/// several instants, are refused up front, naming the option, before any scene is
/// synthesised; `--force` removes nothing from a folder that is not a study.
#[test]
fn bad_budgets_are_refused_up_front_and_force_spares_other_folders() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    for budget in ["0", "inf", "NaN", "-5"] {
        let out = fluidnerf(d, &["study", "--preset", "smoke", &format!("--time-budget={budget}"), "-o", "st", "-q"]);
        refused(&out, "--time-budget must be a positive, finite number of seconds");
        assert!(!d.join("st").exists(), "{budget}: wrote output");
    }
    // A scene of several instants: every static method would mix them.
    let out =
        fluidnerf(d, &["study", "--preset", "smoke", "--scene-preset", "plume-tr", "--methods", "asart", "-o", "st"]);
    refused(&out, "--scene-preset: plume-tr holds 3 instants");
    assert!(!d.join("st").exists(), "a time-resolved scene preset wrote output");
    std::fs::create_dir_all(d.join("mine/runs")).expect("mkdir");
    std::fs::write(d.join("mine/runs/notes.txt"), "mine").expect("writes");
    refused(&fluidnerf(d, &["study", "--preset", "smoke", "--force", "-o", "mine", "-q"]), "not a study folder");
    assert!(d.join("mine/runs/notes.txt").is_file());
    // Nor is a study written into another kind of folder, or over a report of the user's: into
    // a run's folder it replaced the run's report.html.
    demo_scene(d, "blobs", 4, 16, 8, &[]);
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "sart", "--resolution", "8", "-q"]));
    let html = std::fs::read(d.join("run/report.html")).expect("the run's report");
    let study = |out: &str| fluidnerf(d, &["study", "--preset", "smoke", "--methods", "sart", "-o", out, "-q"]);
    refused(&study("run"), "is a reconstruction run folder");
    assert!(std::fs::read(d.join("run/report.html")).expect("kept") == html, "the run's report was replaced");
    assert!(!d.join("run/scenes").exists() && !d.join("run/study.json").exists(), "a refused study wrote");
    refused(&study("scene"), "is a scene folder");
    assert!(!d.join("scene/scenes").exists(), "a refused study wrote");
    std::fs::create_dir_all(d.join("notes")).expect("mkdir");
    std::fs::write(d.join("notes/report.html"), "mine").expect("writes");
    refused(&study("notes"), "holds report.html but no study.json");
    assert_eq!(std::fs::read_to_string(d.join("notes/report.html")).expect("kept"), "mine");
    assert!(!d.join("notes/scenes").exists(), "a refused study wrote");
}

/// `--visual-hull` without a voxel method is refused before anything is made: it changed no
/// run, while the grid and the report said the voxel methods had the hull.
#[test]
fn the_visual_hull_without_a_voxel_method_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let out = fluidnerf(d, &["study", "--preset", "smoke", "--methods", "fast,hybrid", "--visual-hull", "-o", "st"]);
    refused(
        &out,
        "--visual-hull applies to the voxel methods (asart, sart, tv, ...), and --methods fast,hybrid has none",
    );
    assert!(!d.join("st").exists(), "a refused study wrote output");
}

/// A noise level out of range beside a level of 0 is refused for being out of range: it was
/// refused as sharing the scene folder of 0, as if the two were merely too close.
#[test]
fn a_noise_level_out_of_range_is_named_as_such() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    for (levels, bad) in [("0,NaN", "NaN"), ("0,-0.5", "-0.5"), ("0.0001,-0.0002", "-0.0002")] {
        let out = fluidnerf(d, &["study", "--preset", "smoke", &format!("--noise={levels}"), "-o", "st"]);
        refused(&out, &format!("--noise: {bad} is not a fraction in [0, 1)"));
        assert!(!d.join("st").exists(), "{levels}: wrote output");
    }
    // A negative level after a space too: it was taken for an option ("unexpected argument").
    refused(
        &fluidnerf(d, &["study", "--preset", "smoke", "--noise", "-0.1", "-o", "st"]),
        "--noise: -0.1 is not a fraction",
    );
}

/// A camera count beyond what a rig can sensibly have is refused before anything is made:
/// it synthesised that many views, one cell after the others had run, without a word.
#[test]
fn a_camera_count_beyond_a_rig_is_refused_up_front() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    for counts in ["4,1000", "100000"] {
        let out = fluidnerf(d, &["study", "--preset", "smoke", "--methods", "asart", "--cameras", counts, "-o", "st"]);
        refused(
            &out,
            "training cameras (and the one held out) are more than a rig can sensibly have; give at most 999",
        );
        assert!(!d.join("st").exists(), "--cameras {counts}: a refused study wrote output");
    }
}

/// A cell whose run was stopped by Ctrl-C is run again when the study is continued: the rerun
/// that the interruption asks for read its report back as if the run had finished, and the
/// table showed the cut-short run beside runs that spent their whole budget.
#[test]
fn an_interrupted_cell_is_run_again_when_the_study_continues() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = ["study", "--preset", "smoke", "--methods", "asart", "--cameras", "2", "-o", "st", "-q"];
    ok(&fluidnerf(d, &args));
    let run = d.join("st/runs/ring360-c02-n000/asart");
    // What a run stopped by Ctrl-C leaves: its report, with the status and reason of a stop.
    edit_json(&run.join("report.json"), |r| {
        r["status"] = "interrupted".into();
        r["stop_reason"] = "interrupted".into();
    });
    let out = fluidnerf(d, &args);
    ok(&out);
    assert!(!String::from_utf8_lossy(&out.stdout).contains("done earlier"), "the interrupted cell was read back");
    assert_eq!(report(&run)["status"], "finished");
    let record = json(&d.join("st/study.json"));
    // The rows spell the reason as the runs' reports do (they wrote `IterationCap` for
    // `iteration-cap`).
    assert_ne!(record["rows"][0]["stop_reason"], "interrupted", "{record}");
    assert_eq!(record["rows"][0]["stop_reason"], report(&run)["stop_reason"], "{record}");

    // A finished cell whose volume has since gone is run again (the study failed on it, every
    // time it was continued, saying the run held no reconstruction).
    std::fs::remove_file(run.join("volume.npy")).expect("removes the volume");
    let out = fluidnerf(d, &args);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("its result is gone: run again"));
    assert!(run.join("volume.npy").is_file());
}

/// A study continued in a folder whose record is missing (the study was killed before it wrote
/// one) is checked against the scenes and runs there: other settings read back the cells made
/// with the earlier ones, and the table mixed the two studies under the new settings.
#[test]
fn a_continued_study_refuses_scenes_and_runs_made_with_other_settings() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = ["study", "--preset", "smoke", "--methods", "sart", "--cameras", "2", "-o", "st", "-q"];
    ok(&fluidnerf(d, &args));
    // What a study killed before its record leaves: its scenes and runs, no study.json.
    for f in ["study.json", "study.csv", "report.html"] {
        std::fs::remove_file(d.join("st").join(f)).expect("removes");
    }
    let with = |extra: &[&str]| fluidnerf(d, &[&args[..], extra].concat());
    refused(
        &with(&["--seed", "5"]),
        "holds a scene with other settings than this study's (st/scenes/ring360-c02-n000/synth.json: `seed`: 0 → 5)",
    );
    refused(
        &with(&["--max-iterations", "10"]),
        "holds a run with other settings than this study's (st/runs/ring360-c02-n000/sart/config.json: \
         `stopping.max_iterations`: 20 → 10)",
    );
    assert!(!d.join("st/study.json").exists(), "a refused study wrote its record");
    // The same settings continue it, reading the finished cell back.
    let out = fluidnerf(d, &args);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("done earlier"));
}

/// Runs swapped between two cells are refused when the study continues: each run's config.json
/// names its own cell's scene, and the table gave each cell the other's result.
#[test]
fn a_continued_study_refuses_runs_of_another_cells_scene() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = ["study", "--preset", "smoke", "--methods", "sart", "--cameras", "2,3", "-o", "st", "-q"];
    ok(&fluidnerf(d, &args));
    let runs = d.join("st/runs");
    let (a, b) = (runs.join("ring360-c02-n000/sart"), runs.join("ring360-c03-n000/sart"));
    std::fs::rename(&a, runs.join("swap")).expect("moves");
    std::fs::rename(&b, &a).expect("moves");
    std::fs::rename(runs.join("swap"), &b).expect("moves");
    refused(&fluidnerf(d, &args), "ring360-c02-n000/sart holds a run of another scene");
}

/// An image of a cell's scene changed after the cell's run was made is refused when the study
/// continues: the run, of the earlier image, was read back as this scene's result. The scene's
/// files were judged by their times: a scene the study made again (its folder removed), the
/// same to the byte, was refused on the rerun after, and so was an image only touched, while an
/// image removed passed. They are now judged by their contents, recorded beside the cell's
/// runs; a study written before that record is judged by the times as before.
#[test]
fn a_continued_study_refuses_runs_of_other_scene_files_by_contents() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = ["study", "--preset", "smoke", "--methods", "sart", "--cameras", "2", "-o", "st", "-q"];
    ok(&fluidnerf(d, &args));
    let scene = d.join("st/scenes/ring360-c02-n000");
    let images = scene.join("images");
    let image = std::fs::read_dir(&images).expect("lists").flatten().next().expect("an image").path();
    let touch = |path: &std::path::Path| {
        let file = std::fs::File::options().write(true).open(path).expect("opens");
        file.set_modified(std::time::SystemTime::now() + std::time::Duration::from_secs(60)).expect("touches");
    };
    // Made again, and touched: the same files.
    std::fs::remove_dir_all(&scene).expect("removes the scene");
    ok(&fluidnerf(d, &args));
    ok(&fluidnerf(d, &args));
    touch(&image);
    ok(&fluidnerf(d, &args));
    // Changed, or removed: refused, naming the file.
    let own = std::fs::read(&image).expect("reads");
    let mut other = own.clone();
    *other.last_mut().expect("bytes") ^= 1;
    std::fs::write(&image, &other).expect("writes");
    let name = image.file_name().expect("a name").to_string_lossy().to_string();
    refused(&fluidnerf(d, &args), &format!("images/{name}: changed after the runs in st/runs/ring360-c02-n000"));
    std::fs::remove_file(&image).expect("removes");
    refused(&fluidnerf(d, &args), "was removed after the runs in st/runs/ring360-c02-n000 were made from the scene");
    std::fs::write(&image, &own).expect("restores");
    ok(&fluidnerf(d, &args));
    // Without the record (a study written before it), a file newer than the run is refused.
    std::fs::remove_file(d.join("st/runs/ring360-c02-n000/scene-files.json")).expect("removes the record");
    touch(&image);
    refused(&fluidnerf(d, &args), "changed after the run");
    refused(&fluidnerf(d, &args), "ring360-c02-n000/sart was made from it");
    ok(&fluidnerf(d, &[&args[..], &["--force"]].concat()));
}

/// `--stop auto` is recorded as the rule it decides on, the held-out rule (every study scene
/// holds a camera out): recorded as `auto`, the grid differed from each finished run's
/// `held-out`, so the same command refused to continue its own study.
#[test]
fn a_study_under_the_auto_rule_continues_and_names_the_held_out_rule() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args =
        ["study", "--preset", "smoke", "--methods", "asart", "--cameras", "2", "--stop", "auto", "-o", "st", "-q"];
    let first = fluidnerf(d, &args);
    ok(&first);
    assert!(String::from_utf8_lossy(&first.stdout).contains("every method stopped by held-out early stopping ("));
    assert_eq!(json(&d.join("st/study.json"))["grid"]["stopping"]["rule"], "held-out");
    let again = fluidnerf(d, &args);
    ok(&again);
    assert!(String::from_utf8_lossy(&again.stdout).contains("done earlier"));
}

/// Ctrl-C while a cell's scene is being made stops the study as Ctrl-C in a run does: exit
/// code 130, the runs so far written, and the way to continue it. It ended with an error,
/// "cancelled", exit code 1, and no record.
#[cfg(unix)]
#[test]
fn a_study_interrupted_while_making_a_scene_says_how_to_continue() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    // A scene of 301 cameras of 256² px takes seconds to make.
    let args = ["study", "--preset", "smoke", "--methods", "asart", "--cameras", "300", "--pixels", "256"];
    // OUT is made just before the first scene.
    let o = interrupted_once_made(d, &[&args[..], &["--resolution", "128", "-o", "st", "-q"]].concat(), "st");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(String::from_utf8_lossy(&o.stdout).contains("rerun the same command to continue"));
    assert_eq!(json(&d.join("st/study.json"))["status"], "interrupted");
    assert!(!d.join("st/scenes/ring360-c300-n000/transforms.json").exists());
}

/// An output folder whose name starts with '-' holds the study: its scenes' synth lines read
/// it as options ("unexpected argument '-s' found") and the study failed after making it.
#[test]
fn a_folder_named_like_an_option_holds_the_study() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    ok(&fluidnerf(d, &["study", "--out=-st", "--preset", "smoke", "--methods", "asart", "--cameras", "2", "-q"]));
    assert!(d.join("-st/study.json").is_file() && d.join("-st/scenes/ring360-c02-n000/transforms.json").is_file());
}

/// A study started over (--force) with a grid that no longer sweeps the noise removes the
/// earlier study's noise plot: left in OUT, it looked like this study's.
#[test]
fn a_forced_study_removes_the_plots_it_no_longer_draws() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let base = ["study", "--preset", "smoke", "--methods", "asart", "-o", "st", "-q"];
    let mut noisy = base.to_vec();
    noisy.extend(["--cameras", "4", "--noise", "0,0.05"]);
    ok(&fluidnerf(d, &noisy));
    assert!(d.join("st/against_noise.png").is_file());
    let mut cameras = base.to_vec();
    cameras.extend(["--cameras", "4,6", "--force"]);
    ok(&fluidnerf(d, &cameras));
    assert!(d.join("st/against_cameras.png").is_file());
    assert!(!d.join("st/against_noise.png").exists(), "the earlier study's noise plot was left");
    // The earlier study's scenes and runs it no longer makes are gone...
    assert!(!d.join("st/scenes/ring360-c04-n050").exists() && !d.join("st/runs/ring360-c04-n050").exists());
    assert!(d.join("st/runs/ring360-c06-n000/asart/report.json").is_file());

    // ...but a forced study removes only what its study.json lists: a run and notes of the
    // user's under its scenes/ and runs/ were removed with them.
    let mine = d.join("st/runs/ring360-c04-n000/my-run");
    std::fs::create_dir_all(&mine).expect("mkdir");
    std::fs::write(mine.join("notes.txt"), "mine").expect("writes");
    std::fs::write(d.join("st/runs/notes.txt"), "mine").expect("writes");
    std::fs::create_dir_all(d.join("st/scenes/mine")).expect("mkdir");
    ok(&fluidnerf(d, &cameras));
    for kept in ["st/runs/ring360-c04-n000/my-run/notes.txt", "st/runs/notes.txt", "st/scenes/mine"] {
        assert!(d.join(kept).exists(), "{kept} was removed");
    }
    assert!(d.join("st/runs/ring360-c04-n000/asart/report.json").is_file(), "the study's own run is made again");
}

/// clap appends an option's `default_value` to its help, so a doc comment that also writes
/// "[default: ...]" shows it twice; every command's help states each default once.
#[test]
fn every_command_states_each_default_once_in_its_help() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    for command in ["demo", "info", "import", "reconstruct", "eval", "compare", "export", "render", "study", "synth"] {
        let out = fluidnerf(d, &[command, "--help"]);
        ok(&out);
        let help = String::from_utf8_lossy(&out.stdout);
        // An option's entry runs from its `-x`/`--name` line to the next one or to a heading.
        let mut entries: Vec<String> = Vec::new();
        for line in help.lines() {
            let indent = line.len() - line.trim_start().len();
            let option = line.trim_start().starts_with('-') && (2..=6).contains(&indent);
            let heading = indent == 0 && !line.is_empty();
            if option || heading {
                entries.push(String::new());
            }
            if let Some(entry) = entries.last_mut() {
                *entry += line;
                *entry += "\n";
            }
        }
        for entry in &entries {
            let defaults: Vec<&str> = entry
                .match_indices("[default: ")
                .map(|(i, _)| {
                    let rest = &entry[i..];
                    &rest[..rest.find(']').map_or(rest.len(), |j| j + 1)]
                })
                .collect();
            for (i, a) in defaults.iter().enumerate() {
                assert!(!defaults[i + 1..].contains(a), "{command} --help states {a} twice:\n{entry}");
            }
        }
    }
}

/// The files under `dir` with their contents, to show a folder was left as it was.
fn files_under(dir: &std::path::Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut files = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).expect("readable").flatten() {
            if e.path().is_dir() {
                todo.push(e.path());
            } else {
                files.push((e.path(), std::fs::read(e.path()).expect("readable")));
            }
        }
    }
    files.sort();
    files
}

/// `study --scene rec` of the grid field and SART in short runs into `st`, quietly, then `extra`.
fn scene_study<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut args =
        vec!["study", "--scene", "rec", "--methods", "fast,sart", "--resolution", "16", "--max-iterations", "50"];
    args.extend(["-o", "st", "-q"]);
    args.extend_from_slice(extra);
    args
}

/// A scene of the user's (here one without ground truth, as a recording is) is studied as one
/// cell: every method under the one policy its held-out camera drives, each scored on that
/// camera's image, the fields set against the best voxel method by it; the scene is only read,
/// and a rerun reads the runs back.
#[test]
fn a_scene_given_is_studied_by_its_held_out_camera() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = ["synth", "--preset", "demo", "--cameras", "5", "--holdout", "1", "--pixels", "24"];
    ok(&fluidnerf(d, &[&synth[..], &["--resolution", "16", "-o", "rec", "-q"]].concat()));
    edit_json(&d.join("rec/transforms.json"), |v| v.as_object_mut().expect("object").remove("truth"));
    let before = files_under(&d.join("rec"));
    let args = scene_study(&[]);
    let first = fluidnerf(d, &args);
    ok(&first);
    let stdout = String::from_utf8_lossy(&first.stdout);
    let record = json(&d.join("st/study.json"));
    assert_eq!(
        record["grid"]["scene"].as_str(),
        Some(d.join("rec").canonicalize().expect("rec").to_str().expect("utf-8"))
    );
    assert!(record["grid"].get("scene_preset").is_none() && record["grid"].get("preset").is_none(), "{record}");
    let rows = record["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 2);
    for r in rows {
        assert_eq!((r["layout"].as_str(), r["cameras"].as_u64()), (Some("scene"), Some(4)));
        assert!(r["nrmse"].is_null(), "no ground truth: {r}");
        assert!(r["holdout_nrmse"].as_f64().is_some_and(|n| n > 0.0 && n < 1.5), "{r}");
        let run = d.join("st").join(r["run"].as_str().expect("run"));
        assert!(run.starts_with(d.join("st/runs/scene")), "{run:?}");
    }
    let against = record["against_best_voxel"].as_array().expect("against_best_voxel");
    assert_eq!(against.len(), 1, "{record}");
    assert_eq!(
        (against[0]["measure"].as_str(), against[0]["best_voxel_method"].as_str()),
        (Some("held-out view"), Some("sart"))
    );
    let view =
        |m: &str| rows.iter().find(|r| r["method"] == m).and_then(|r| r["holdout_nrmse"].as_f64()).expect("scored");
    assert!((against[0]["ratio"].as_f64().expect("ratio") - view("fast") / view("sart")).abs() < 1e-12);
    assert!(stdout.contains("[1/2] scene · 4 cameras · FluidNeRF") && stdout.contains("held-out view"), "{stdout}");
    let html = std::fs::read_to_string(d.join("st/report.html")).expect("report");
    assert!(html.contains("fluidnerf study of the scene") && html.contains("4 training cameras, 1 held out"), "{html}");
    // Read, never written; a rerun reads the runs back, and --force keeps the scene too.
    assert_eq!(files_under(&d.join("rec")), before);
    let again = fluidnerf(d, &args);
    ok(&again);
    assert_eq!(String::from_utf8_lossy(&again.stdout).matches("(done earlier)").count(), 2);
    ok(&fluidnerf(d, &[&args[..], &["--force"]].concat()));
    assert_eq!(files_under(&d.join("rec")), before);
}

/// A scene that cannot be studied is refused before anything is made, naming the problem.
#[test]
fn a_scene_given_without_a_held_out_camera_or_with_a_grid_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    ok(&fluidnerf(
        d,
        &["synth", "--preset", "demo", "--cameras", "4", "--pixels", "16", "--resolution", "8", "-o", "rec", "-q"],
    ));
    let study = |extra: &[&str]| fluidnerf(d, &[&["study", "--scene", "rec", "--methods", "sart"][..], extra].concat());
    refused(&study(&["-o", "st"]), "holds no camera out, and a study stops every method by a held-out camera");
    refused(&study(&["-o", "st", "--noise", "0.05"]), "cannot be used with");
    edit_json(&d.join("rec/transforms.json"), |v| v["frames"][0]["holdout"] = serde_json::json!(true));
    refused(&study(&["-o", "rec/st"]), "is the scene's folder");
    assert!(!d.join("st").exists() && !d.join("rec/st").exists());
}

/// How many of a scene's cameras it takes: each count below its own is a subset of its
/// training cameras spread over their viewing lines, written as a scene of the study's that
/// reads the images where they are; the scene's own count is the scene itself.
#[test]
fn a_scene_given_is_studied_with_fewer_of_its_cameras() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = ["synth", "--preset", "demo", "--cameras", "5", "--holdout", "1", "--pixels", "24"];
    ok(&fluidnerf(d, &[&synth[..], &["--resolution", "16", "-o", "rec", "-q"]].concat()));
    let before = files_under(&d.join("rec"));
    let args = scene_study(&["--cameras", "2,4"]);
    ok(&fluidnerf(d, &args));
    let record = json(&d.join("st/study.json"));
    let rows = record["rows"].as_array().expect("rows");
    let cells: Vec<(u64, &str)> =
        rows.iter().map(|r| (r["cameras"].as_u64().expect("cameras"), r["run"].as_str().expect("run"))).collect();
    let runs = ["runs/scene-c02/fast", "runs/scene-c02/sart", "runs/scene/fast", "runs/scene/sart"];
    assert_eq!(cells, [(2, runs[0]), (2, runs[1]), (4, runs[2]), (4, runs[3])]);
    // Every method scored through the volume it wrote, on the one output grid: the field too.
    for r in rows {
        let metrics = json(&d.join("st").join(r["run"].as_str().expect("run")).join("metrics.json"));
        assert_eq!(metrics["settings"]["use_volume"], r["method"] == "fast", "{metrics}");
        assert_eq!(r["nrmse"], metrics["steps"][0]["global"]["nrmse"], "{r}");
    }
    let subset = json(&d.join("st/scenes/scene-c02/transforms.json"));
    let frames = subset["frames"].as_array().expect("frames");
    assert_eq!(frames.len(), 3, "two training cameras and the held-out one");
    assert_eq!(frames.iter().filter(|f| f["holdout"] == true).count(), 1);
    assert!(frames.iter().all(|f| std::path::Path::new(f["file_path"].as_str().expect("path")).is_absolute()));
    assert_eq!(report(&d.join("st/runs/scene-c02/sart"))["classical"]["views"], 2);
    assert_eq!(report(&d.join("st/runs/scene/sart"))["classical"]["views"], 4);
    for r in rows {
        assert!(r["nrmse"].as_f64().is_some() && r["holdout_nrmse"].as_f64().is_some(), "{r}");
    }
    // Read back when rerun; started over with --force, the subset is made again, the scene kept.
    let again = fluidnerf(d, &args);
    ok(&again);
    assert_eq!(String::from_utf8_lossy(&again.stdout).matches("(done earlier)").count(), 4);
    ok(&fluidnerf(d, &[&args[..], &["--force"]].concat()));
    assert!(d.join("st/scenes/scene-c02/subset.json").is_file());
    assert_eq!(files_under(&d.join("rec")), before);
    // A count the scene does not have is refused up front.
    let more = fluidnerf(d, &["study", "--scene", "rec", "--cameras", "5", "--methods", "sart", "-o", "st2"]);
    refused(&more, "--cameras: 5 is not a count of the 4 training cameras of the scene");
    assert!(!d.join("st2").exists());
}

/// A study killed before it wrote its results left scenes/ and runs/ but no study.json: the
/// same command said it held other settings and to use --force, and --force said it was no
/// study folder. And two studies could write into one folder at once, each its study.json over
/// the other's. The study now records itself as it starts, and holds a lock while it runs.
#[test]
fn a_killed_study_is_continued_or_started_over_and_one_study_writes_at_a_time() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = ["study", "--preset", "smoke", "--methods", "sart,asart", "-o", "st", "-q"];
    let killed = killed_once_made(d, &args, "st/runs");
    assert!(!killed.status.success());
    let record = json(&d.join("st/study.json"));
    assert_eq!(record["status"], "started", "recorded before its first cell");
    // While a study holds the folder, another is refused. The holder is this test, taking the
    // lock as a study does: a real study of the smoke preset may end before the other starts.
    let held = fluidnerf_pipeline::rundir::FileLock::take(&d.join("st"), &d.join("st/.study.lock")).expect("lock");
    let other = ["study", "--preset", "smoke", "--methods", "tv", "--noise", "0.05", "-o", "st", "-q"];
    refused(&fluidnerf(d, &other), "st: another study is writing into this folder");
    drop(held);
    ok(&fluidnerf(d, &args));
    assert_eq!(json(&d.join("st/study.json"))["status"], "finished");
    // Killed before its results, a study is also started over with --force.
    let again = ["study", "--preset", "smoke", "--methods", "sart,asart", "-o", "st2", "-q"];
    killed_once_made(d, &again, "st2/runs");
    ok(&fluidnerf(d, &[&again[..], &["--force"]].concat()));
    assert_eq!(json(&d.join("st2/study.json"))["status"], "finished");
}

/// A damaged study.json (cut short, edited) stopped the study, `--force` too, with the JSON
/// reader's complaint alone; and `compare` given a study folder said it was no run directory.
/// Both now say what to do.
#[test]
fn a_damaged_study_record_and_a_study_given_to_compare_say_what_to_do() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let args = ["study", "--preset", "smoke", "--methods", "sart", "--cameras", "2", "-o", "st", "-q"];
    ok(&fluidnerf(d, &args));
    refused(
        &fluidnerf(d, &["compare", "st", "-o", "cmp"]),
        "st: holds a study, whose runs are its runs/CELL/METHOD folders (e.g. st/runs/ring360-c02-n000/sart)",
    );
    std::fs::write(d.join("st/study.json"), "{bad").expect("damages the record");
    for force in [&[][..], &["--force"]] {
        let out = fluidnerf(d, &[&args[..], force].concat());
        refused(&out, "st/study.json is damaged, so the study's settings, scenes and runs cannot be read from it");
        refused(&out, "remove it with the study's scenes/ and runs/ in st, or write the study into another folder");
    }
}
