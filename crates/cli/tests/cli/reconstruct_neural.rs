//! `fluidnerf reconstruct --method fast|fluidnerf` end to end on a tiny generated scene: the
//! files it writes, refusal to overwrite, resume, and a trained field loadable by the library.

use crate::common;
use common::*;

/// Resuming a run continues it as if it had not stopped:
/// - a field started from a voxel run (`hybrid`) ends where the run without a break ends, to
///   the bit (its resumed part trained at 4× the start's rate, and ended 12 % worse);
/// - a `config.json` edited after the checkpoint was written (another seed) is refused, naming
///   the setting (it trained the rest with the edited settings and recorded them for all);
/// - a time budget the checkpoint has already spent is refused (it trained the whole budget
///   again, and `config.json` did not rerun the run).
#[test]
fn a_resumed_run_continues_the_run_it_holds() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 5, 24, 16, &["--holdout", "1"]);
    let run = |out: &str, iterations: &str, extra: &[&str]| {
        let mut args = vec!["reconstruct", "scene", "-o", out, "--method", "hybrid", "--resolution", "16"];
        args.extend(["--max-iterations", iterations, "--stop", "budget", "--rays-per-image", "128"]);
        args.extend(["--start-fit-steps", "20", "-q"]);
        args.extend_from_slice(extra);
        fluidnerf(d, &args)
    };
    ok(&run("whole", "60", &[]));
    ok(&run("parts", "30", &[]));
    ok(&run("parts", "60", &["--resume"]));
    assert_eq!(report(&d.join("parts"))["iterations"], 60);
    assert_eq!(report(&d.join("whole"))["final_nrmse"], report(&d.join("parts"))["final_nrmse"]);
    let volume = |dir: &str| std::fs::read(d.join(dir).join("volume.npy")).expect("volume");
    assert!(volume("whole") == volume("parts"), "the resumed run's volume differs");

    edit_json(&d.join("parts/config.json"), |v| v["seed"] = serde_json::json!(7));
    let o = fluidnerf(d, &["reconstruct", "-o", "parts", "--resume", "--max-iterations", "90", "-q"]);
    refused(&o, "checkpoint.safetensors: was written by a run trained with other settings");
    refused(&o, "`seed`: 0 → 7");
    edit_json(&d.join("parts/config.json"), |v| v["seed"] = serde_json::json!(0));

    let spent = report(&d.join("parts"))["train_time_s"].as_f64().expect("train time");
    let budget = format!("{}", spent / 2.0);
    let o =
        fluidnerf(d, &["reconstruct", "-o", "parts", "--resume", "--max-iterations", "90", "--time-budget", &budget]);
    refused(&o, "the whole time budget of");
    assert_eq!(report(&d.join("parts"))["iterations"], 60, "a refused resume changed the run");
}

/// A resume of a finished run that dies on the way (killed; a full disk did the same) leaves a
/// stopped run, not an unfinished one: its report was removed as the resume began, so `eval`,
/// `export` and `render` refused the folder, and a second resume lost the run's histories.
#[test]
fn a_killed_resume_of_a_finished_run_leaves_a_stopped_run() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 5, 24, 16, &["--holdout", "1"]);
    let run = ["reconstruct", "scene", "-o", "run", "--method", "fast", "--resolution", "16", "-q"];
    ok(&fluidnerf(d, &[&run[..], &["--max-iterations", "40", "--stop", "budget"]].concat()));
    let losses = report(&d.join("run"))["history"]["loss"].as_array().map(Vec::len);
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .current_dir(d)
        .args(["reconstruct", "-o", "run", "--resume", "--max-iterations", "1000000", "-q"])
        .spawn()
        .expect("starts");
    // The resume rewrites config.json with its cap once the checkpoint has loaded.
    let start = std::time::Instant::now();
    while !std::fs::read_to_string(d.join("run/config.json")).is_ok_and(|c| c.contains("1000000")) {
        assert!(start.elapsed().as_secs() < 60, "the resume did not start");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let killed = std::process::Command::new("kill").args(["-KILL", &child.id().to_string()]).status().expect("kill");
    assert!(killed.success());
    child.wait().expect("waits");
    let r = report(&d.join("run"));
    assert_eq!((r["status"].as_str(), r["iterations"].as_u64()), (Some("interrupted"), Some(40)), "{r}");
    ok(&fluidnerf(d, &["eval", "run", "-q"]));
    // Continued, it keeps the earlier run's curves.
    ok(&fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--max-iterations", "60", "-q"]));
    let r = report(&d.join("run"));
    assert_eq!(r["iterations"], 60);
    assert!(r["history"]["loss"].as_array().map(Vec::len) > losses, "{r}");
}

/// A run aborted before it wrote its results (a second Ctrl-C, a kill) holds its config.json
/// and checkpoint only: `eval`, `export` and `render` say to continue it with `--resume`, as
/// for an unfinished time-resolved run, rather than that the folder holds no reconstruction.
#[test]
fn a_run_aborted_before_its_results_is_named_as_resumable() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "fast", "--max-iterations", "5", "-q"]));
    for entry in std::fs::read_dir(d.join("run")).expect("lists") {
        let path = entry.expect("entry").path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
        if !["config.json", "checkpoint.safetensors"].contains(&name.as_str()) && path.is_file() {
            std::fs::remove_file(&path).expect("removes");
        }
    }
    for args in [&["eval", "run"][..], &["export", "run", "-o", "x", "--npy"], &["render", "run", "-o", "r"]] {
        refused(&fluidnerf(d, args), "holds a run stopped before it wrote its results");
        refused(&fluidnerf(d, args), "reconstruct -o run --resume");
    }
    ok(&fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "-q"]));
}

/// A run under way is named as such by `eval`, not as an unfinished run to continue with
/// `--resume` (which its lock would refuse); killed before its first checkpoint, as one with
/// nothing to continue, not as a folder without a reconstruction.
#[test]
fn a_run_under_way_is_named_as_one() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .current_dir(d)
        .args(["reconstruct", "scene", "-o", "run", "--method", "fast", "--max-iterations", "1000000", "-q"])
        .args(["--stop", "budget", "--checkpoint-every", "1000000"])
        .spawn()
        .expect("starts");
    let start = std::time::Instant::now();
    while !(d.join("run/config.json").is_file() && d.join("run/.lock").is_file()) {
        assert!(start.elapsed().as_secs() < 60, "the run did not start");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let o = fluidnerf(d, &["eval", "run"]);
    let killed = std::process::Command::new("kill").args(["-KILL", &child.id().to_string()]).status().expect("kill");
    assert!(killed.success());
    child.wait().expect("waits");
    refused(&o, &format!("holds a run under way (process {})", child.id()));
    // Killed before its first checkpoint: nothing to continue.
    refused(&fluidnerf(d, &["eval", "run"]), "holds a run stopped before its first checkpoint or result");
}

/// A run's weights or checkpoint replaced by a folder is named as such: the weights were said
/// to hold 4096 bytes (the folder's size), the checkpoint to be missing.
#[test]
fn a_folder_in_place_of_the_weights_or_the_checkpoint_is_named() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "fast", "--max-iterations", "5", "-q"]));
    for (file, args, says) in [
        ("weights.safetensors", &["eval", "run", "--force"][..], "run/weights.safetensors: is a folder"),
        (
            "checkpoint.safetensors",
            &["reconstruct", "-o", "run", "--resume"],
            "run/checkpoint.safetensors: is a folder",
        ),
    ] {
        let path = d.join("run").join(file);
        let kept = std::fs::read(&path).expect("reads");
        std::fs::remove_file(&path).expect("removes");
        std::fs::create_dir(&path).expect("mkdir");
        refused(&fluidnerf(d, args), says);
        std::fs::remove_dir(&path).expect("rmdir");
        std::fs::write(&path, kept).expect("restores");
    }
}

#[test]
fn dense_and_mlp_runs_write_resume_and_load() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 6, 32, 24, &["--holdout", "1"]);
    // Dense voxel grid with empty-space skipping: fast enough for a real convergence check.
    let run = [
        "reconstruct",
        "scene",
        "-o",
        "run",
        "--method",
        "fast",
        "--preset",
        "dense",
        "--max-iterations",
        "150",
        "--resolution",
        "16",
        "--eval-every",
        "50",
        "--rays-per-image",
        "256",
        "--checkpoint-every",
        "100",
        "-q",
    ];
    ok(&fluidnerf(d, &run));
    let dir = d.join("run");
    for f in ["weights.safetensors", "checkpoint.safetensors", "model.json", "config.json", "volume.npy", "volume.vti"]
    {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    let r = report(&dir);
    assert_eq!(r["iterations"], 150);
    assert_eq!(r["history"]["loss"].as_array().map(Vec::len), Some(150));
    assert_eq!(r["history"]["nrmse"].as_array().map(Vec::len), Some(3));
    let nrmse = r["final_nrmse"].as_f64().expect("truth was used");
    assert!(nrmse < 0.9, "NRMSE {nrmse}");
    assert!(r["neural"]["occupied_fraction"].as_f64().expect("fraction") < 0.8);
    assert!(!r["history"]["holdout"].as_array().expect("holdout").is_empty(), "held-out camera not evaluated");

    // Refuses to overwrite; resumes to a higher cap.
    let again = fluidnerf(d, &run);
    assert!(!again.status.success(), "overwrote results without --force");
    // A resume that would change the field is refused up front; one whose checkpoint does not
    // load (here a damaged copy) leaves the finished run as it was.
    let resumed_with = |k: usize, value: &'static str| {
        let mut args: Vec<&str> = run.to_vec();
        args[k] = value;
        args.push("--resume");
        fluidnerf(d, &args)
    };
    refused(&resumed_with(7, "fast"), "change the field");
    // So is one that would train on with other settings: the run's config.json, which records
    // the new ones, would not rerun it.
    let config_before = std::fs::read(dir.join("config.json")).expect("readable");
    refused(
        &resumed_with(15, "128"),
        "run/config.json: cannot resume: the run was trained with other settings (`method.train.rays_per_image`: \
         256 → 128)",
    );
    assert!(std::fs::read(dir.join("config.json")).expect("readable") == config_before, "the refusal changed it");
    let damaged = d.join("damaged");
    std::fs::create_dir(&damaged).expect("mkdir");
    for e in std::fs::read_dir(&dir).expect("lists") {
        let p = e.expect("entry").path();
        std::fs::copy(&p, damaged.join(p.file_name().expect("name"))).expect("copies");
    }
    let ckpt = damaged.join("checkpoint.safetensors");
    std::fs::write(&ckpt, &std::fs::read(&ckpt).expect("readable")[..5000]).expect("truncates");
    let kept = |f: &str| std::fs::read(damaged.join(f)).expect("readable");
    let (report_before, config_before) = (kept("report.json"), kept("config.json"));
    let truncated = fluidnerf(d, &["reconstruct", "scene", "-o", "damaged", "--resume", "-q"]);
    refused(&truncated, "checkpoint.safetensors: the file is truncated");
    std::fs::write(&ckpt, &std::fs::read(&ckpt).expect("readable")[..6]).expect("truncates");
    let truncated = fluidnerf(d, &["reconstruct", "scene", "-o", "damaged", "--resume", "-q"]);
    // read_exact's "failed to fill whole buffer" said nothing of the file.
    refused(&truncated, "checkpoint.safetensors: the file is truncated: it ends inside its safetensors header");
    assert!(kept("report.json") == report_before, "a refused resume changed report.json");
    assert!(kept("config.json") == config_before, "a refused resume changed config.json");
    // A resume to a cap below the checkpoint's iteration kept the 150-iteration result and
    // recorded the cap of 100 in config.json, which reruns to another volume.
    let (report_before, config_before) = (
        std::fs::read(dir.join("report.json")).expect("report"),
        std::fs::read(dir.join("config.json")).expect("config"),
    );
    refused(&resumed_with(9, "100"), "is at iteration 150, beyond the cap of 100");
    assert!(std::fs::read(dir.join("report.json")).expect("report") == report_before, "a refused resume wrote");
    assert!(std::fs::read(dir.join("config.json")).expect("config") == config_before, "a refused resume wrote");
    // Nor does one continue on another scene, or without the settings it ran with; and a
    // folder whose field is gone is not read as its volume alone.
    let synth = ["synth", "-q", "--preset", "demo", "--cameras", "3", "--pixels", "8", "--resolution", "8", "-o"];
    ok(&fluidnerf(d, &[&synth[..], &["other"]].concat()));
    refused(&resumed_with(1, "other"), "holds a run of the scene");
    let bare = d.join("bare");
    std::fs::create_dir(&bare).expect("mkdir");
    for f in ["checkpoint.safetensors", "report.json", "volume.npy", "weights.safetensors"] {
        std::fs::copy(dir.join(f), bare.join(f)).expect("copies");
    }
    refused(&fluidnerf(d, &["reconstruct", "scene", "-o", "bare", "--resume"]), "no config.json");
    std::fs::copy(dir.join("config.json"), bare.join("config.json")).expect("copies");
    refused(&fluidnerf(d, &["eval", "bare", "--scene", "scene", "--json", "bare.json"]), "model.json is missing");
    let mut resume: Vec<&str> = run.to_vec();
    resume[9] = "200";
    resume.push("--resume");
    ok(&fluidnerf(d, &resume));
    let r2 = report(&dir);
    assert_eq!(r2["iterations"], 200);
    assert_eq!(r2["history"]["loss"].as_array().map(Vec::len), Some(200));
    let l1 = r["history"]["loss"].as_array().expect("history");
    let l2 = r2["history"]["loss"].as_array().expect("history");
    assert_eq!(l1[..], l2[..150], "resume rewrote the history");
    let (c1, c2) =
        (r["history"]["nrmse"].as_array().expect("curve"), r2["history"]["nrmse"].as_array().expect("curve"));
    assert_eq!(c1[..], c2[..c1.len()], "the resumed curve continues the first");
    assert_eq!(c2.last().map(|p| &p["iteration"]), Some(&serde_json::json!(200)));

    // The trained field reads back through the library and matches the written volume.
    let (field, aabb) = fluidnerf_neural::trained::load_trained(&dir).expect("loads");
    let vol = fluidnerf_io::volume::read_npy(&dir.join("volume.npy"), aabb).expect("volume");
    let again = fluidnerf_core::Volume::from_field(vol.dims, aabb, field.as_ref(), 0.0);
    assert_eq!(again.data, vol.data);

    // The faithful network runs through the same command (a few iterations, tiny settings),
    // and its config.json reruns, here with empty-space skipping added.
    ok(&fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "mlp",
            "--method",
            "fluidnerf",
            "--preset",
            "ch7",
            "--max-iterations",
            "2",
            "--rays-per-image",
            "32",
            "--coarse-samples",
            "16",
            "--fine-samples",
            "16",
            "--resolution",
            "8",
            "-q",
        ],
    ));
    assert_eq!(report(&d.join("mlp"))["iterations"], 2);
    ok(&fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "mlp2",
            "--method",
            "fluidnerf",
            "--config",
            "mlp/config.json",
            "--resolution",
            "8",
            "--skip-empty",
            "-q",
        ],
    ));
    assert_eq!(report(&d.join("mlp2"))["iterations"], 2);
    // The dissertation's presets train on the whole box; --skip-empty carves it.
    assert_eq!(report(&d.join("mlp"))["neural"]["occupied_fraction"].as_f64(), Some(1.0));
    let carved = report(&d.join("mlp2"))["neural"]["occupied_fraction"].as_f64().expect("fraction");
    assert!(carved < 0.8, "--skip-empty kept {carved} of the box");
    assert!(json(&d.join("mlp2/config.json"))["method"]["train"]["occupancy"].is_object());
}

/// `--keep-best-holdout` writes the field of the evaluation with the lowest held-out loss. By
/// default the NRMSE curve is evaluated where the held-out loss is, so it holds the kept
/// iterate, at the NRMSE the run reports for it.
#[test]
fn keep_best_holdout_writes_the_best_evaluated_field() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = "synth --preset demo --phantom ball --cameras 6 --pixels 32 --resolution 24 --holdout 1 --noise 0.1 -o scene -q";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    let run = "reconstruct scene -o run --method fast --preset dense --max-iterations 200 --resolution 24 --keep-best-holdout --patience 0 -q";
    ok(&fluidnerf(d, &run.split_whitespace().collect::<Vec<_>>()));
    let r = report(&d.join("run"));
    // A history of the report as (iteration, value) pairs.
    let points = |key: &str, value: &str| -> Vec<(u64, f64)> {
        let h = r["history"][key].as_array().unwrap_or_else(|| panic!("{key} history"));
        h.iter().map(|p| (p["iteration"].as_u64().expect("iteration"), p[value].as_f64().expect("value"))).collect()
    };
    let history = points("holdout", "loss");
    assert!(history.len() >= 2, "held-out loss evaluated several times: {history:?}");
    let best = history.iter().copied().fold((0, f64::INFINITY), |b, p| if p.1 < b.1 { p } else { b });
    assert_eq!(r["kept_iteration"].as_u64(), Some(best.0), "history {history:?}");
    let curve = points("nrmse", "nrmse");
    let at = |h: &[(u64, f64)]| h.iter().map(|p| p.0).collect::<Vec<_>>();
    assert_eq!(at(&curve), at(&history), "NRMSE evaluated where the held-out loss is");
    let kept = curve.iter().find(|p| p.0 == best.0).expect("the kept iterate on the curve").1;
    let reported = r["final_nrmse"].as_f64().expect("final NRMSE");
    assert!((kept - reported).abs() <= 1e-12 * reported, "curve {kept} at the kept iterate, reported {reported}");
}

/// The voxel baseline recovers a known phantom: a grid at the output resolution, trained
/// through the same renderer and optimiser as the fields, with its TV prior on.
#[test]
fn voxel_baseline_recovers_blobs() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 8, 32, 16, &[]);
    let run = "reconstruct scene -o vox --method voxel --resolution 16 --max-iterations 400 --rays-per-image 512 -q";
    ok(&fluidnerf(d, &run.split_whitespace().collect::<Vec<_>>()));
    let r = report(&d.join("vox"));
    assert_eq!(r["method"], "voxel");
    let cfg = json(&d.join("vox/config.json"));
    assert_eq!(cfg["method"]["name"], "voxel");
    assert!(cfg["method"]["train"]["prior"]["tv"].as_f64().is_some_and(|w| w > 0.0));
    assert_eq!(r["volumes"][0]["dims"], serde_json::json!([16, 16, 16]));
    let nrmse = r["final_nrmse"].as_f64().expect("truth was used");
    // Measured 0.234 (a uniform field scores about 0.7 here; ASART 0.096, fast 0.152).
    assert!(nrmse < 0.3, "voxel baseline NRMSE {nrmse}");
    // The grid field takes the prior on random points, recorded in its config; a negative
    // weight is refused, naming the key.
    let args = ["reconstruct", "scene", "-o", "f", "--method", "fast", "--tv-prior", "0.01", "--max-iterations", "2"];
    ok(&fluidnerf(d, &args));
    assert_eq!(json(&d.join("f/config.json"))["method"]["train"]["prior"]["tv"], serde_json::json!(0.01));
    refused(
        &fluidnerf(
            d,
            &["reconstruct", "scene", "-o", "x", "--method", "fast", "--tv-prior=-1", "--max-iterations", "2"],
        ),
        "prior.tv",
    );
}

/// `--resume` continues a run with its own settings (OUT/config.json, options given override
/// them) and the held-out rule's state: a run stopped at an iteration cap and resumed to a
/// higher one keeps the same iterate and writes the same volume as a run that went on
/// uninterrupted. A different method for the run in OUT is refused.
#[test]
fn a_resumed_run_keeps_its_settings_and_its_held_out_best() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    // Noisy images, so that the held-out loss turns within a hundred iterations.
    demo_scene(d, "ball", 6, 32, 24, &["--holdout", "1", "--noise", "0.05"]);
    let run = |args: &str| ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let common = "--method fast --resolution 16 --rays-per-image 64 --stop held-out --holdout-every 10 \
                  --patience 4 -q";
    run(&format!("reconstruct scene -o whole --max-iterations 400 {common}"));
    let whole = report(&d.join("whole"));
    let kept = whole["kept_iteration"].as_u64().expect("kept");
    let cut = kept + 15;
    assert!(whole["iterations"].as_u64().expect("iterations") > cut, "{whole}");
    run(&format!("reconstruct scene -o cut --max-iterations {cut} {common}"));
    // No scene, no method: those of the run in `cut`.
    run("reconstruct -o cut --resume --max-iterations 400 -q");
    let resumed = report(&d.join("cut"));
    assert_eq!(resumed["method"], "fast");
    assert_eq!(resumed["kept_iteration"], whole["kept_iteration"], "{resumed}");
    assert_eq!(resumed["iterations"], whole["iterations"], "{resumed}");
    let volume = |run: &str| std::fs::read(d.join(run).join("volume.npy")).expect("volume");
    assert!(volume("cut") == volume("whole"), "the resumed run wrote another volume");
    refused(&fluidnerf(d, &["reconstruct", "-o", "cut", "--resume", "--method", "asart"]), "holds a --method fast run");
}

/// `--method hybrid`, the default method, runs a voxel method into `start/` of its folder
/// (ASART on these clean images, SART-TV on noisy ones), fits the field to that volume and
/// trains on from there:
/// after a few iterations the field is about as accurate as that volume, where the field
/// started from a uniform value is not. `--start-from` does the same from a run given by the
/// user, and only static neural methods take it.
#[test]
fn hybrid_starts_the_field_from_its_own_voxel_run() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 8, 32, 16, &[]);
    let run = |args: &str| ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    // No --method: the default, hybrid.
    run("reconstruct scene -o h --resolution 16 --max-iterations 30 -q");
    let start = report(&d.join("h/start"));
    assert_eq!(start["method"], "asart");
    // The voxel run keeps its own cap and rule: the field's cap is not its.
    let start_cfg = json(&d.join("h/start/config.json"));
    assert_eq!(start_cfg["stopping"]["max_iterations"], serde_json::Value::Null, "{start_cfg}");
    assert_eq!(start_cfg["stopping"]["rule"], "own", "{start_cfg}");
    let cfg = json(&d.join("h/config.json"));
    assert_eq!(cfg["method"]["name"], "hybrid");
    assert_eq!(cfg["method"]["start"]["learning_rate_scale"], serde_json::json!(0.25));
    assert_eq!(cfg["method"]["start"]["method"], "auto");
    assert_eq!(cfg["method"]["train"]["pixel_supersample"], "auto");
    let voxel = start["final_nrmse"].as_f64().expect("truth was used");
    let hybrid = report(&d.join("h"))["final_nrmse"].as_f64().expect("truth was used");
    run("reconstruct scene -o f --method fast --resolution 16 --max-iterations 30 -q");
    let fresh = report(&d.join("f"))["final_nrmse"].as_f64().expect("truth was used");
    // The preset asks for bfloat16 products; the report and the summary line say whether this
    // CPU ran them.
    assert_eq!(json(&d.join("f/config.json"))["method"]["field"]["hash-grid"]["mlp_precision"], "bf16");
    let bf16 = fluidnerf_neural::bf16_products_available();
    assert_eq!(report(&d.join("f"))["neural"]["train"]["bf16_products"], bf16);
    let out = fluidnerf(
        d,
        &["reconstruct", "scene", "-o", "f1", "--method", "fast", "--resolution", "16", "--max-iterations", "2"],
    );
    ok(&out);
    let said = String::from_utf8_lossy(&out.stdout).contains("decoder trained with bfloat16 products");
    assert_eq!(said, bf16, "{}", String::from_utf8_lossy(&out.stdout));
    assert!(
        hybrid < 1.15 * voxel && hybrid < 0.7 * fresh,
        "hybrid {hybrid}, its ASART start {voxel}, fresh field {fresh}"
    );
    // A rerun from the saved configuration repeats the voxel run, the fit and the training.
    run("reconstruct --config h/config.json -o h2 -q");
    assert_eq!(report(&d.join("h2"))["final_nrmse"].as_f64(), Some(hybrid), "the rerun differs");
    // The same start from a run the user names; its config records it and reruns from it.
    run("reconstruct scene -o s --method fast --start-from h/start --resolution 16 --max-iterations 30 -q");
    let cfg = json(&d.join("s/config.json"));
    let recorded = cfg["method"]["start"]["run"].as_str().map(std::path::PathBuf::from);
    assert!(recorded.as_ref().is_some_and(|p| p.is_absolute() && p.ends_with("h/start")), "{cfg}");
    let from_run = report(&d.join("s"))["final_nrmse"].as_f64().expect("truth was used");
    assert!(from_run < 1.15 * voxel, "started from h/start: {from_run}, ASART {voxel}");
    // With 5 % noise the same start is SART-TV, and a method named on the command line wins.
    let noisy = d.join("noisy");
    std::fs::create_dir(&noisy).expect("mkdir");
    demo_scene(&noisy, "blobs", 8, 32, 16, &["--noise", "0.05"]);
    let run_noisy = |args: &str| ok(&fluidnerf(&noisy, &args.split_whitespace().collect::<Vec<_>>()));
    // (Short fits to the start: only the start is checked.)
    run_noisy("reconstruct scene -o h --method hybrid --resolution 16 --max-iterations 2 --start-fit-steps 20 -q");
    assert_eq!(report(&noisy.join("h/start"))["method"], "tv");
    run_noisy(
        "reconstruct scene -o m --method hybrid --start-method mlem --resolution 16 --max-iterations 2 \
         --start-fit-steps 20 -q",
    );
    assert_eq!(report(&noisy.join("m/start"))["method"], "mlem");
    assert_eq!(json(&noisy.join("m/config.json"))["method"]["start"]["method"], "mlem");
    assert_eq!(json(&noisy.join("m/config.json"))["method"]["start"]["fit"]["iterations"], 20);
    // The fit's steps are for runs with a start, and at least one.
    for (args, says) in [
        ("--method fast --start-fit-steps 20", "--start-fit-steps: the run has no start to fit the field to"),
        ("--method asart --start-fit-steps 20", "--start-fit-steps"),
        ("--method hybrid --start-fit-steps 0", "--start-fit-steps"),
    ] {
        let line = format!("reconstruct scene -o x {args}");
        refused(&fluidnerf(d, &line.split_whitespace().collect::<Vec<_>>()), says);
        assert!(!d.join("x").exists(), "{args}: left an output folder");
    }
    refused(
        &fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "hybrid", "--start-method", "fast"]),
        "not a voxel method",
    );
    refused(
        &fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "asart", "--start-from", "h/start"]),
        "--start-from",
    );
    refused(
        &fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "fast", "--start-from", "nowhere"]),
        "nowhere",
    );
}

/// Ctrl-C during the hybrid's voxel start stops the start, and the run after it, at once. The
/// start's events were dropped, so it ran all its iterations (up to 250, seconds at 48³) with no
/// progress shown and only then did the run stop.
///
/// The run's volume is then of a field that never trained, and the report says so. A resume
/// runs the start again and ends where a run without a break ends. Before, the volume was
/// reported like any stopped run's, and a resume trained the unfitted field from its
/// checkpoint at the start's lower rate: another run than its `config.json` describes.
#[test]
fn ctrl_c_during_the_hybrids_voxel_start_stops_the_start() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 8, 32, 16, &[]);
    let args = [
        "reconstruct",
        "scene",
        "-o",
        "h",
        "--resolution",
        "48",
        "--max-iterations",
        "3",
        "--start-fit-steps",
        "20",
        "-q",
    ];
    let out = interrupted_once_made(d, &args, "h/start");
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    let start = report(&d.join("h/start"));
    assert_eq!(start["stop_reason"], "interrupted", "{start}");
    assert!(start["iterations"].as_u64().is_some_and(|n| n < 250), "{start}");
    let r = report(&d.join("h"));
    assert_eq!(r["status"], "interrupted");
    let warnings = r["warnings"].to_string();
    assert!(warnings.contains("before it trained: volume.npy is the field before training"), "{warnings}");

    let resumed = fluidnerf(d, &["reconstruct", "-o", "h", "--resume"]);
    ok(&resumed);
    assert!(String::from_utf8_lossy(&resumed.stderr).contains("the run starts again from its start"));
    assert_eq!(report(&d.join("h/start"))["status"], "finished");
    let mut whole = args.to_vec();
    whole[3] = "whole";
    ok(&fluidnerf(d, &whole));
    same_files(&d.join("h"), &d.join("whole"), &["volume.npy", "weights.safetensors"]);
    assert!(!report(&d.join("h"))["warnings"].to_string().contains("before it trained"));
}

/// Ctrl-C while the hybrid fits its field to the voxel start stops the fit and the run at
/// once. The fit delivered no events, so a stop there waited for all its steps (seconds in any
/// run; here 4000 steps, a minute), with no progress shown.
#[test]
fn ctrl_c_during_the_fit_to_the_start_stops_the_run() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 8, &[]);
    let args = "reconstruct scene -o h0 --method hybrid --resolution 8 --max-iterations 2 --start-fit-steps 20 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    edit_json(&d.join("h0/config.json"), |c| c["method"]["start"]["fit"]["iterations"] = serde_json::json!(4000));
    let started = std::time::Instant::now();
    let out =
        interrupted_once_made(d, &["reconstruct", "--config", "h0/config.json", "-o", "h"], "h/start/report.json");
    let seconds = started.elapsed().as_secs_f64();
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(report(&d.join("h/start"))["status"], "finished");
    let r = report(&d.join("h"));
    assert_eq!(r["status"], "interrupted", "{r}");
    assert!(r["iterations"].as_u64().is_some_and(|n| n <= 1), "{r}");
    // Half a second after the start's report, then the stop: far from the fit's minute.
    assert!(seconds < 15.0, "the run took {seconds:.1} s to stop");
}

/// The hybrid's fit of the field to its voxel start is part of the run's work: it ends with the
/// time budget, as the voxel start and the field do. A fit of thousands of steps ran whole
/// whatever the budget, so a study cell stated "at most 0.5 s" for a run that took seconds.
#[test]
fn the_hybrids_fit_to_its_start_ends_with_the_time_budget() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 8, &[]);
    let args = "reconstruct scene -o h --method hybrid --resolution 8 --max-iterations 2 --start-fit-steps 20 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    edit_json(&d.join("h/config.json"), |c| {
        c["method"]["start"]["fit"]["iterations"] = serde_json::json!(5000);
        c["stopping"]["time_budget_s"] = serde_json::json!(0.5);
    });
    ok(&fluidnerf(d, &["reconstruct", "--config", "h/config.json", "-o", "short", "-q"]));
    let r = report(&d.join("short"));
    let seconds = r["train_time_s"].as_f64().expect("a time");
    assert!(seconds < 2.0, "a 0.5 s budget took {seconds} s");
    let warnings = r["warnings"].to_string();
    assert!(
        warnings.contains("the time budget ended the fit to the start after") && warnings.contains("of its 5000 steps"),
        "{warnings}"
    );
}

/// A run that cannot be started from is named by its option and key, whatever is wrong with it:
/// a path that is no run said only "nowhere: is not a folder", naming neither.
#[test]
fn a_start_run_that_cannot_be_used_is_named_by_its_option() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 3, 12, 8, &[]);
    let small = ["--preset", "demo", "--phantom", "ball", "--cameras", "3", "--pixels", "12", "--resolution", "8"];
    ok(&fluidnerf(d, &[&["synth", "-q", "-o", "other", "--aabb=-10,-10,-10,10,10,10"][..], &small[..]].concat()));
    ok(&fluidnerf(d, &["reconstruct", "other", "-o", "a", "--method", "asart", "--resolution", "8", "-q"]));
    for (start, says) in [
        ("nowhere", "nowhere: is not a folder"),
        ("scene", "scene: holds no reconstruction"),
        ("a", "a: its box [-10.0, -10.0, -10.0]–[10.0, 10.0, 10.0] is not the scene's"),
    ] {
        let o = fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "fast", "--start-from", start]);
        refused(&o, &format!("--start-from on the command line: method.start.run: {}", d.join(says).display()));
        assert!(!d.join("x").exists(), "{start}: left an output folder");
    }
    // A start that holds no light is refused naming the run it was read from.
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "dark", "--method", "asart", "--resolution", "8", "-q"]));
    let path = d.join("dark/volume.npy");
    let mut volume =
        fluidnerf_io::volume::read_npy(&path, fluidnerf_core::Aabb::cube(fluidnerf_core::glam::DVec3::ZERO, 40.0))
            .expect("volume");
    volume.data.fill(0.0);
    fluidnerf_io::volume::write_npy(&path, &volume).expect("written");
    let o = fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "fast", "--start-from", "dark", "-q"]);
    refused(&o, &format!("{}: the starting field is zero", d.join("dark").display()));
}

#[test]
fn a_resume_after_the_box_changed_and_a_failed_run_are_handled() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 16, &[]);
    let run = |out: &str, extra: &[&str]| {
        let mut args = vec!["reconstruct", "scene", "-o", out, "--method", "fast", "--preset", "dense"];
        args.extend(["--resolution", "16", "--rays-per-image", "64", "-q"]);
        args.extend_from_slice(extra);
        fluidnerf(d, &args)
    };
    ok(&run("run", &["--max-iterations", "10"]));
    // The field's coordinates are the box's: a scene whose aabb changed cannot continue it.
    let scene = d.join("scene/transforms.json");
    let original = std::fs::read_to_string(&scene).expect("reads the scene");
    let mut edited: serde_json::Value = serde_json::from_str(&original).expect("JSON");
    let half: Vec<Vec<f64>> = edited["aabb"]
        .as_array()
        .expect("aabb")
        .iter()
        .map(|c| c.as_array().expect("corner").iter().map(|v| v.as_f64().expect("number") / 2.0).collect())
        .collect();
    edited["aabb"] = serde_json::json!(half);
    std::fs::write(&scene, serde_json::to_string(&edited).expect("JSON")).expect("writes");
    let report_before = std::fs::read(d.join("run/report.json")).expect("report");
    refused(&run("run", &["--max-iterations", "20", "--resume"]), "box");
    assert_eq!(std::fs::read(d.join("run/report.json")).expect("report"), report_before, "a refused resume wrote");
    std::fs::write(&scene, &original).expect("restores the scene");
    ok(&run("run", &["--max-iterations", "20", "--resume"]));
    assert_eq!(report(&d.join("run"))["iterations"], 20);
    // Nor on other images: one pixel of one image changed.
    let image = d.join("scene/images/cam000.png");
    let bytes = std::fs::read(&image).expect("reads the image");
    let mut pixels = image::load_from_memory(&bytes).expect("decodes").to_luma16();
    let (w, h) = pixels.dimensions();
    pixels.get_pixel_mut(w / 2, h / 2).0[0] ^= 0x0100;
    pixels.save(&image).expect("writes the image");
    let report_before = std::fs::read(d.join("run/report.json")).expect("report");
    refused(
        &run("run", &["--max-iterations", "30", "--resume"]),
        "was trained on other images or cameras than the scene's now",
    );
    assert_eq!(std::fs::read(d.join("run/report.json")).expect("report"), report_before, "a refused resume wrote");
    std::fs::write(&image, &bytes).expect("restores the image");
    ok(&run("run", &["--max-iterations", "30", "--resume"]));
    assert_eq!(report(&d.join("run"))["iterations"], 30);

    // A fresh run that fails before any checkpoint leaves no unfinished run behind: the same
    // command with a sane rate then runs without --force or --resume.
    let diverged = run("new", &["--max-iterations", "5", "--learning-rate", "1e30"]);
    assert!(!diverged.status.success(), "a rate of 1e30 trained");
    assert!(!d.join("new").exists(), "the failed run left {:?}", std::fs::read_dir(d.join("new")).map(|r| r.count()));
    ok(&run("new", &["--max-iterations", "5"]));
    // Nor does a hybrid run that fails after its voxel start: the start goes with it.
    let hybrid = |extra: &[&str]| {
        let mut args = vec!["reconstruct", "scene", "-o", "hyb", "--method", "hybrid", "--resolution", "16"];
        args.extend(["--rays-per-image", "64", "--max-iterations", "5", "-q"]);
        args.extend_from_slice(extra);
        fluidnerf(d, &args)
    };
    let diverged = hybrid(&["--learning-rate", "1e30"]);
    assert!(!diverged.status.success(), "a rate of 1e30 trained");
    assert!(
        !d.join("hyb").exists(),
        "the failed hybrid run left {:?}",
        std::fs::read_dir(d.join("hyb")).map(|r| r.count())
    );
    ok(&hybrid(&[]));
    assert!(d.join("hyb/start/config.json").is_file(), "the hybrid run kept no start");
    // A run killed outright before its first checkpoint leaves its configuration alone: the
    // rerun is told to replace it, and --resume that there is nothing to resume.
    std::fs::create_dir(d.join("dead")).expect("mkdir");
    std::fs::copy(d.join("new/config.json"), d.join("dead/config.json")).expect("copies");
    refused(&run("dead", &["--max-iterations", "5"]), "stopped before its first checkpoint");
    refused(&run("dead", &["--max-iterations", "5", "--resume"]), "use --force to replace it");
    ok(&run("dead", &["--max-iterations", "5", "--force"]));
}

/// A checkpoint continues only the field it was trained as: a config.json edited to another
/// field of the same tensor shapes (here the decoder's activation) is refused on --resume,
/// naming the setting, instead of training the saved parameters as another network. (A
/// --preset or option given with --resume is refused before; the file itself only here.)
#[test]
fn a_resume_of_a_config_edited_to_another_field_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 16, &[]);
    let args = ["reconstruct", "scene", "-o", "run", "--method", "fast", "--resolution", "16"];
    ok(&fluidnerf(d, &[&args[..], &["--rays-per-image", "64", "--max-iterations", "5", "-q"]].concat()));
    let config = d.join("run/config.json");
    fn activation(v: &mut serde_json::Value) -> &mut serde_json::Value {
        &mut v["method"]["field"]["hash-grid"]["activation"]
    }
    edit_json(&config, |v| {
        assert_eq!(*activation(v), "relu");
        *activation(v) = "swish".into();
    });
    let resume = ["reconstruct", "-o", "run", "--resume", "--max-iterations", "10", "-q"];
    let report_before = std::fs::read(d.join("run/report.json")).expect("report");
    refused(&fluidnerf(d, &resume), r#"checkpoint.safetensors: was trained as another field"#);
    refused(&fluidnerf(d, &resume), r#"`hash-grid.activation`: "relu" → "swish""#);
    assert_eq!(std::fs::read(d.join("run/report.json")).expect("report"), report_before, "a refused resume wrote");
    edit_json(&config, |v| *activation(v) = "relu".into());
    ok(&fluidnerf(d, &resume));
    assert_eq!(report(&d.join("run"))["iterations"], 10);
}

/// `--start-from` a run in the output folder itself, or inside it (a hybrid run's `start/`),
/// with --force: the folder's run was removed before the start was read, so the user's run was
/// deleted and the new one refused as starting from a folder that "holds no reconstruction".
/// It is refused before anything is removed.
#[test]
fn a_start_run_inside_the_folder_force_replaces_is_refused_before_it_is_removed() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 3, 12, 8, &[]);
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "a", "--method", "asart", "--resolution", "8", "-q"]));
    let before = std::fs::read(d.join("a/volume.npy")).expect("volume");
    let args = ["reconstruct", "scene", "-o", "a", "--method", "fast", "--force", "--max-iterations", "2"];
    for start in ["a", "a/start"] {
        std::fs::create_dir_all(d.join("a/start")).expect("mkdir");
        let o = fluidnerf(d, &[&args[..], &["--start-from", start]].concat());
        refused(&o, &format!("method.start.run: {start} is the run in the output folder a or one of its start runs"));
        assert_eq!(std::fs::read(d.join("a/volume.npy")).expect("the run is kept"), before, "{start}");
    }
    ok(&fluidnerf(d, &["eval", "a", "--json", "m.json", "-q"]));
}

/// An `image_scale` that would put the brightest pixel out of range is refused once the images
/// are read, named by its full key as the checks before the run name every other setting.
#[test]
fn an_image_scale_far_from_the_pixels_is_named_by_its_key() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 16, &[]);
    let args = ["reconstruct", "scene", "-o", "run", "--method", "fast", "--resolution", "16"];
    ok(&fluidnerf(d, &[&args[..], &["--rays-per-image", "64", "--max-iterations", "2", "-q"]].concat()));
    edit_json(&d.join("run/config.json"), |v| v["method"]["train"]["image_scale"] = serde_json::json!(1e-30));
    let out = fluidnerf(d, &["reconstruct", "--config", "run/config.json", "-o", "again", "-q"]);
    refused(&out, "method.train.image_scale: 1e-30 puts the largest training pixel");
    assert!(!d.join("again/config.json").exists(), "a refused run wrote its settings");
}

/// A learning rate too large for the field drives it to zero everywhere; the run says so, and
/// names the setting, instead of ending as if it had converged with an empty volume.
#[test]
fn a_field_driven_to_zero_by_its_learning_rate_is_reported() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 24, 16, &[]);
    let run = |out: &str, rate: &str| {
        let args = ["reconstruct", "scene", "-o", out, "--method", "fast", "--resolution", "16"];
        ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "60", "--learning-rate", rate, "-q"]].concat()));
        report(&d.join(out))["warnings"].as_array().expect("warnings").clone()
    };
    let collapsed = run("collapsed", "0.5");
    assert!(
        collapsed.iter().any(|w| {
            let w = w.as_str().unwrap_or("");
            w.contains("the reconstruction is empty") && w.contains("method.train.schedule.initial is 0.5")
        }),
        "{collapsed:?}"
    );
    let trained = run("trained", "0.02");
    assert!(!trained.iter().any(|w| w.as_str().unwrap_or("").contains("empty")), "{trained:?}");
}

/// Masks that hide most of each view left the skip-empty grid empty: the hidden pixels were
/// set to the image's brightest value, which then was its median, so every pixel read as dark
/// and every cell was carved; the run was refused as "no camera sees the reconstruction box",
/// though every camera sees it and the pixels kept are bright. It trains now.
#[test]
fn masks_hiding_most_of_each_view_keep_the_hull_of_the_pixels_they_use() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 3, 16, 8, &[]);
    // The central 4 × 4 pixels of every view, on the ball.
    let mut mask = fluidnerf_core::Image::from_vec(16, 16, vec![0.0; 256]);
    for row in 6..10 {
        for col in 6..10 {
            mask.data[row * 16 + col] = 1.0;
        }
    }
    fluidnerf_io::image::write_png16(&d.join("scene/mask.png"), &mask, 1.0).expect("writes the mask");
    edit_json(&d.join("scene/transforms.json"), |v| {
        for f in v["frames"].as_array_mut().expect("frames") {
            f["mask_path"] = "mask.png".into();
        }
    });
    let run = ["reconstruct", "scene", "-o", "run", "--method", "fast", "--resolution", "8", "--max-iterations", "2"];
    let o = fluidnerf(d, &run);
    ok(&o);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("no camera sees"));
}

/// A held-out run killed right after its checkpoint at its best held-out loss (no report, no
/// kept weights) was resumed with the rule started afresh: it kept a later field and stopped
/// elsewhere than the run without a break. The rule is now replayed from the checkpoint's own
/// held-out losses, and the resumed run ends as the uninterrupted one, byte for byte.
#[test]
fn a_held_out_run_killed_at_its_best_checkpoint_resumes_to_the_same_result() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 5, 16, 8, &["--holdout", "4", "--noise", "0.05"]);
    let run = |out: &str, cap: &str| {
        let args =
            ["reconstruct", "scene", "-o", out, "--method", "fast", "--stop", "held-out", "--max-iterations", cap];
        let more = ["--holdout-every", "10", "--patience", "3", "--checkpoint-every", "10", "--resolution", "8", "-q"];
        ok(&fluidnerf(d, &[&args[..], &more].concat()));
    };
    run("whole", "300");
    let whole = report(&d.join("whole"));
    let kept = whole["kept_iteration"].as_u64().expect("kept");
    assert!(kept < whole["iterations"].as_u64().expect("iterations"), "the rule stopped it after its best");
    // The same run up to its best evaluation, then killed after the checkpoint there: only the
    // configuration and the checkpoint are left.
    run("killed", &kept.to_string());
    for entry in std::fs::read_dir(d.join("killed")).expect("folder") {
        let path = entry.expect("entry").path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("").to_string();
        if !["config.json", "checkpoint.safetensors", "scene"].contains(&name.as_str()) {
            if path.is_dir() {
                std::fs::remove_dir_all(&path).expect("removes");
            } else {
                std::fs::remove_file(&path).expect("removes");
            }
        }
    }
    ok(&fluidnerf(d, &["reconstruct", "-o", "killed", "--resume", "--max-iterations", "300", "-q"]));
    let resumed = report(&d.join("killed"));
    assert_eq!(resumed["kept_iteration"], whole["kept_iteration"]);
    assert_eq!(resumed["iterations"], whole["iterations"]);
    let volume = |run: &str| std::fs::read(d.join(run).join("volume.npy")).expect("volume");
    assert!(volume("killed") == volume("whole"), "the resumed run's volume differs");
}

/// SIGTERM (a batch scheduler's time limit; Slurm sends it before SIGKILL) stopped a run at once,
/// without its results, and one before its first checkpoint could not be resumed. It is now
/// taken as Ctrl-C: the run stops after the iteration under way and writes what it has.
#[test]
fn sigterm_stops_a_run_as_ctrl_c_does() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let args = ["reconstruct", "scene", "-o", "run", "--method", "fast", "--stop", "budget", "--max-iterations"];
    let out = terminated_once_made(d, &[&args[..], &["100000", "--resolution", "8", "-q"]].concat(), "run/config.json");
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    let r = report(&d.join("run"));
    assert_eq!(r["status"], "interrupted", "{r}");
    assert!(d.join("run/volume.npy").is_file() && d.join("run/weights.safetensors").is_file());
    ok(&fluidnerf(
        d,
        &["reconstruct", "-o", "run", "--resume", "--max-iterations", "200000", "--time-budget", "1", "-q"],
    ));
}
