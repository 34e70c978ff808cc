//! Faithful reruns: a run's `config.json` alone reproduces its volume bit for bit, for voxel,
//! static neural and time-resolved methods; an option given explicitly overrides the config
//! even when it equals the default; and one run's figures agree in the terminal,
//! `report.json` and `report.html`.

use crate::common;
use common::*;

/// Runs `args`, then reruns from the written `config.json` with no other option than the
/// output folder, and compares the volume files byte for byte.
fn rerun_is_identical(d: &std::path::Path, name: &str, args: &[&str], volume: &str) {
    let mut first = vec!["reconstruct", "scene", "-o", name, "-q"];
    first.extend_from_slice(args);
    ok(&fluidnerf(d, &first));
    let config = format!("{name}/config.json");
    let again = format!("{name}-again");
    ok(&fluidnerf(d, &["reconstruct", "--config", &config, "-o", &again, "-q"]));
    let a = std::fs::read(d.join(name).join(volume)).expect("first volume");
    let b = std::fs::read(d.join(&again).join(volume)).expect("rerun volume");
    assert!(a == b, "{name}: the rerun from config.json differs");
    assert_eq!(json(&d.join(name).join("config.json")), json(&d.join(&again).join("config.json")), "{name}");
}

#[test]
fn config_json_alone_reruns_every_family_bit_for_bit() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 5, 24, 12, &["--holdout", "1"]);
    // Non-default settings everywhere, so a rerun that fell back to a default would differ.
    rerun_is_identical(
        d,
        "asart",
        &["--method", "asart", "--resolution", "14", "--relaxation", "0.7", "--max-iterations", "6", "--seed", "3"],
        "volume.npy",
    );
    rerun_is_identical(
        d,
        "fast",
        &["--method", "fast", "--resolution", "14", "--max-iterations", "30", "--seed", "5", "--rays-per-image", "64"],
        "volume.npy",
    );
    rerun_is_identical(
        d,
        "nerf",
        &[
            "--method",
            "fluidnerf",
            "--preset",
            "experimental",
            "--resolution",
            "10",
            "--max-iterations",
            "2",
            "--seed",
            "2",
            "--rays-per-image",
            "16",
            "--coarse-samples",
            "8",
            "--fine-samples",
            "8",
            "--keep-best-holdout",
            "--holdout-every",
            "1",
        ],
        "volume.npy",
    );
    // The held-out rule is recorded in the config and in the report.
    let cfg = json(&d.join("nerf/config.json"));
    assert_eq!(cfg["stopping"]["rule"], "held-out");
    let r = report(&d.join("nerf-again"));
    assert_eq!(r["stopping"]["rule"], "held-out");
    assert!(r["kept_iteration"].as_u64().is_some_and(|k| (1..=2).contains(&k)));
}

#[test]
fn config_json_alone_reruns_a_time_resolved_run_bit_for_bit() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth =
        "synth -q --preset jet-tr60 --cameras 4 --pixels 16 --resolution 12 --model pinhole --times 14,15,16,17 -o scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    rerun_is_identical(
        d,
        "tr",
        &[
            "--method",
            "tr-fast",
            "--resolution",
            "10",
            "--max-iterations",
            "6",
            "--window",
            "2",
            "--overlap",
            "1",
            "--rays-per-image",
            "32",
            "--coarse-samples",
            "12",
            "--holdout-times",
            "15",
            "--seed",
            "9",
            "--checkpoint-every",
            "0",
        ],
        "frames/volume_002.npy",
    );
}

#[test]
fn an_explicit_option_overrides_the_config_even_at_its_default() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 12, &[]);
    ok(&fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "a",
            "--method",
            "sart",
            "--seed",
            "4",
            "--resolution",
            "10",
            "--max-iterations",
            "2",
            "-q",
        ],
    ));
    // --seed 0 and --resolution 128 are the defaults; given explicitly they still win.
    ok(&fluidnerf(
        d,
        &[
            "reconstruct",
            "--config",
            "a/config.json",
            "-o",
            "b",
            "--seed",
            "0",
            "--resolution",
            "128",
            "--max-iterations",
            "1",
            "--memory-limit",
            "4",
            "-q",
        ],
    ));
    let cfg = json(&d.join("b/config.json"));
    assert_eq!(cfg["seed"], 0);
    assert_eq!(cfg["resolution"], 128);
    assert_eq!(report(&d.join("b"))["volumes"][0]["dims"], serde_json::json!([128, 128, 128]));
    // Options that do not apply to the method are refused, not ignored.
    let out = fluidnerf(d, &["reconstruct", "--config", "a/config.json", "-o", "c", "--rays-per-image", "8"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--rays-per-image"));
    assert!(!d.join("c").exists());
}

#[test]
fn terminal_report_json_and_report_html_agree() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 5, 24, 16, &[]);
    let out = fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "run",
            "--method",
            "fast",
            "--resolution",
            "12",
            "--max-iterations",
            "40",
            "--rays-per-image",
            "64",
        ],
    );
    ok(&out);
    let r = report(&d.join("run"));
    assert_eq!(r["format"], 1);
    let nrmse = r["final_nrmse"].as_f64().expect("truth was used");
    assert_eq!(nrmse, r["volumes"][0]["metrics"]["global"]["nrmse"].as_f64().expect("metrics"));
    // The figure as the terminal and the HTML print it.
    let shown = fluidnerf_viz::report::format_value(nrmse);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains(&format!("volume NRMSE {shown}")), "terminal: {stdout} (report {nrmse})");
    let html = std::fs::read_to_string(d.join("run/report.html")).expect("html");
    assert!(html.contains(&format!(">{shown}<")), "report.html does not show NRMSE {shown}");
}

/// `--preset` with `--config` takes the preset's field and training but keeps what no preset
/// sets: the configured start (before, the hybrid's voxel method fell back to `auto`, and a
/// time-resolved run's start was dropped).
#[test]
fn a_preset_given_with_a_config_keeps_the_configured_start() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let tiny =
        ["--resolution", "8", "--max-iterations", "2", "--rays-per-image", "16", "--start-fit-steps", "20", "-q"];
    let mut first = vec!["reconstruct", "scene", "-o", "a", "--method", "hybrid", "--start-method", "sart"];
    first.extend(tiny);
    ok(&fluidnerf(d, &first));
    let mut again = vec!["reconstruct", "--config", "a/config.json", "-o", "b", "--preset", "dense"];
    again.extend(tiny);
    ok(&fluidnerf(d, &again));
    let cfg = json(&d.join("b/config.json"));
    assert_eq!(cfg["method"]["preset"], "dense", "the preset given is taken");
    assert_eq!(cfg["method"]["start"]["method"], "sart", "the configured start is kept");
    assert_eq!(report(&d.join("b/start"))["method"], "sart");
}

/// `--gains none` (or `balance`) overrides a configuration that fitted gains, as any option
/// overrides it: the fit's offset and refit interval go with the fit. Before, the run was
/// refused, blaming the configuration's `gains.offset`, with no option to turn it off.
#[test]
fn a_gain_mode_given_over_a_config_that_fitted_gains_replaces_the_fit() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let tiny = ["--method", "sart", "--resolution", "8", "--max-iterations", "2", "-q"];
    let fit = ["--gains", "fit", "--gain-offset", "--gain-every", "1", "--gain-rounds", "2"];
    ok(&fluidnerf(d, &[&["reconstruct", "scene", "-o", "a"][..], &tiny, &fit].concat()));
    for mode in ["none", "balance"] {
        let out = format!("b-{mode}");
        ok(&fluidnerf(d, &["reconstruct", "--config", "a/config.json", "-o", &out, "--gains", mode, "-q"]));
        let gains = &json(&d.join(&out).join("config.json"))["gains"];
        assert_eq!(gains, &serde_json::json!({"mode": mode, "offset": false, "every": null, "rounds": 4}));
    }
    // The fit's options are still refused beside a mode that fits nothing.
    let out =
        fluidnerf(d, &["reconstruct", "--config", "a/config.json", "-o", "c", "--gains", "none", "--gain-offset"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--gain-offset applies only to fitted gains"));
}

/// A switch a configuration turned on can be turned off from the command line, as every other
/// setting can be overridden: `--visual-hull false`, `--gain-offset false`, and
/// `--no-warm-start false` for windows.
#[test]
fn a_switch_a_config_turned_on_can_be_turned_off() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let tiny = ["--method", "sart", "--resolution", "8", "--max-iterations", "2", "-q"];
    let on = ["--visual-hull", "--gains", "fit", "--gain-offset"];
    ok(&fluidnerf(d, &[&["reconstruct", "scene", "-o", "a"][..], &tiny, &on].concat()));
    let a = json(&d.join("a/config.json"));
    assert_eq!((&a["method"]["projector"]["visual_hull"], &a["gains"]["offset"]), (&true.into(), &true.into()));
    let off = ["--visual-hull", "false", "--gain-offset", "false", "-q"];
    ok(&fluidnerf(d, &[&["reconstruct", "--config", "a/config.json", "-o", "b"][..], &off].concat()));
    let b = json(&d.join("b/config.json"));
    assert_eq!((&b["method"]["projector"]["visual_hull"], &b["gains"]["offset"]), (&false.into(), &false.into()));
    assert_eq!(b["gains"]["mode"], "fit", "only the offset is turned off");

    let synth = "synth -q --preset jet-tr60 --cameras 4 --pixels 16 --resolution 12 --model pinhole --times 14,15,16 \
                 -o tr-scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    let tr = "reconstruct tr-scene -o tr -q --method tr-fast --resolution 8 --max-iterations 2 --window 2 --overlap 1 \
              --rays-per-image 16 --coarse-samples 8 --no-warm-start";
    ok(&fluidnerf(d, &tr.split_whitespace().collect::<Vec<_>>()));
    assert_eq!(json(&d.join("tr/config.json"))["method"]["windows"]["warm_start"], false);
    ok(&fluidnerf(d, &["reconstruct", "--config", "tr/config.json", "-o", "tr2", "--no-warm-start", "false", "-q"]));
    assert_eq!(json(&d.join("tr2/config.json"))["method"]["windows"]["warm_start"], true);
}

/// A switch given over a configuration takes the settings that went with the old choice along:
/// `--visual-hull false` over a hull of another threshold, `--projector ray` over a splat of
/// 2 sub-voxels, and `--stop` over another rule's plateau or patience. The first two were
/// refused (only hand-editing the file helped), the last ones kept and ignored; and a value
/// given on the command line was blamed on the configuration file.
#[test]
fn a_switch_over_a_config_takes_the_old_choices_settings_along() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &["--holdout", "1"]);
    let run = |args: &str| fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>());
    ok(&run("reconstruct scene -o hull -q --method asart --resolution 8 --stop budget --max-iterations 2 \
             --visual-hull --hull-threshold 0.05 --projector splat --splat-subdivisions 2"));
    ok(&run("reconstruct --config hull/config.json -o off -q --visual-hull false --projector ray"));
    let projector = json(&d.join("off/config.json"))["method"]["projector"].clone();
    assert_eq!((projector["visual_hull"].as_bool(), projector["kind"].as_str()), (Some(false), Some("ray")));
    assert_eq!((projector["hull_threshold"].as_f64(), projector["splat_subdivisions"].as_u64()), (Some(0.02), Some(0)));
    // Given beside the switch that leaves them idle, they are still refused.
    let out = run("reconstruct --config hull/config.json -o off2 --visual-hull false --hull-threshold 0.05");
    refused(&out, "--hull-threshold sets the visual hull, which this run does not use");

    ok(&run("reconstruct scene -o own -q --method sart --resolution 8 --stop own --plateau-tolerance 0.05 \
             --max-iterations 4"));
    ok(&run("reconstruct --config own/config.json -o budget -q --stop budget"));
    let plateau = json(&d.join("budget/config.json"))["method"]["params"]["stopping"]["plateau"].clone();
    assert_eq!(plateau["tolerance"].as_f64(), Some(0.02), "{plateau}");
    ok(&run("reconstruct scene -o held -q --method fast --resolution 8 --max-iterations 4 --stop held-out \
             --holdout-every 2 --patience 2 --rays-per-image 16 --checkpoint-every 0"));
    ok(&run("reconstruct --config held/config.json -o own2 -q --stop own"));
    let stopping = json(&d.join("own2/config.json"))["stopping"].clone();
    assert_eq!((stopping["holdout_every"].is_null(), stopping["patience"].as_u64()), (true, Some(10)), "{stopping}");

    // A value from the command line is named as the option, not as the file's.
    let synth = "synth -q --preset jet-tr60 --cameras 4 --pixels 16 --resolution 12 --model pinhole --times 14,15 \
                 -o tr-scene";
    ok(&run(synth));
    ok(&run("reconstruct tr-scene -o tr -q --method tr-fast --resolution 8 --max-iterations 2 --gains balance \
             --checkpoint-every 0"));
    refused(&run("reconstruct --config tr/config.json -o tr2 --gains fit"), "--gains on the command line: gains.mode");
}

/// A start names a run to start from or a voxel method to run first, never both: `--start-from`
/// over a configuration that ran a voxel method first replaces it, and a configuration that
/// names both is refused by the key, not run with one of them ignored.
#[test]
fn a_start_from_a_run_replaces_a_configured_start_method() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 4, 16, 8, &[]);
    let tiny =
        ["--resolution", "8", "--max-iterations", "2", "--rays-per-image", "16", "--start-fit-steps", "20", "-q"];
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "s", "--method", "sart", "--resolution", "8", "-q"]));
    let hybrid = ["reconstruct", "scene", "-o", "h", "--method", "hybrid", "--start-method", "sart"];
    ok(&fluidnerf(d, &[&hybrid[..], &tiny].concat()));
    assert_eq!(json(&d.join("h/config.json"))["method"]["start"]["method"], "sart");
    ok(&fluidnerf(
        d,
        &[&["reconstruct", "--config", "h/config.json", "-o", "h2", "--start-from", "s"][..], &tiny].concat(),
    ));
    let start = &json(&d.join("h2/config.json"))["method"]["start"];
    assert_eq!((&start["method"], start["run"].as_str().is_some()), (&"auto".into(), true), "{start}");

    let mut both = json(&d.join("h2/config.json"));
    both["method"]["start"]["method"] = "sart".into();
    std::fs::write(d.join("both.json"), serde_json::to_string(&both).expect("json")).expect("writes");
    let out = fluidnerf(d, &["reconstruct", "--config", "both.json", "-o", "h3"]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && e.contains("method.start.method") && e.contains("give one"), "{e}");
    assert!(!d.join("h3").exists(), "nothing written");
}
