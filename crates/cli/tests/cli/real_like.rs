//! A real-like recording end to end: `synth --preset real-like-small` (camera gains ±30 %, a 5 %
//! background with dark noise, one background frame per camera, 8-bit sRGB JPEG) reconstructed
//! with background subtraction and fitted gains comes close to the same jet recorded as clean
//! linear images, and clearly closer than without them; the fitted gains match the drawn ones.
//! By default (gains auto) a run fits them because the images' totals differ as differing gains
//! make them, and a run told to take the images as they are warns of it.

use crate::common;
use common::*;

const SMALL: [&str; 8] = ["--pixels", "40", "--resolution", "40", "--cameras", "8", "--holdout", "cam003"];

/// `synth --preset real-like-small` at the small size of these tests into `d/out`, with `extra`.
fn synth_small(d: &std::path::Path, out: &str, extra: &[&str]) {
    let mut args = vec!["synth", "--preset", "real-like-small", "-o", out];
    args.extend_from_slice(&SMALL);
    args.extend_from_slice(extra);
    ok(&fluidnerf(d, &args));
}

fn nrmse(r: &serde_json::Value) -> f64 {
    r["final_nrmse"].as_f64().expect("final_nrmse")
}

/// The gain mode a run took, as its report records it.
fn pre_mode(r: &serde_json::Value) -> String {
    r["preprocessing"]["gains"]["mode"].as_str().expect("gains mode").to_owned()
}

#[test]
fn background_subtraction_and_gain_fitting_recover_the_clean_result() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = |out: &str, extra: &[&str]| synth_small(d, out, extra);
    synth("real", &[]);
    synth("clean", &["--real-like", "false"]);
    assert!(d.join("real/images/cam000.jpg").is_file() && d.join("real/background/cam000_b0.jpg").is_file());
    let scene = json(&d.join("real/transforms.json"));
    assert_eq!(scene["linearisation"], "srgb");
    assert_eq!(scene["frames"][0]["background"], serde_json::json!(["background/cam000_b0.jpg"]));
    // The same recording with its background keys removed: nothing subtracted.
    std::fs::create_dir_all(d.join("raw")).expect("mkdir");
    let mut raw = scene.clone();
    for f in raw["frames"].as_array_mut().expect("frames") {
        f.as_object_mut().expect("frame").remove("background");
    }
    std::fs::write(d.join("raw/transforms.json"), raw.to_string().replace("\"images/", "\"../real/images/"))
        .expect("write");
    std::fs::create_dir_all(d.join("raw/truth")).expect("mkdir");
    std::fs::copy(d.join("real/truth/truth.npy"), d.join("raw/truth/truth.npy")).expect("copy");

    // `gains` None: the default (auto).
    let run_with = |scene: &str, out: &str, gains: Option<&str>| {
        let mut args = vec!["reconstruct", scene, "-o", out, "-m", "asart", "--resolution", "40", "-q"];
        args.extend(gains.iter().flat_map(|g| ["--gains", *g]));
        let o = fluidnerf(d, &args);
        ok(&o);
        (report(&d.join(out)), String::from_utf8_lossy(&o.stdout).to_string())
    };
    let run = |scene: &str, out: &str, gains: &str| run_with(scene, out, Some(gains));
    let (fitted, stdout) = run("real", "run-fit", "fit");
    let (clean, _) = run("clean", "run-clean", "none");
    let (bare, _) = run("raw", "run-raw", "none");
    // Measured: clean 0.245, fitted 0.266, without background or gains 0.353.
    let (f, c, b) = (nrmse(&fitted), nrmse(&clean), nrmse(&bare));
    assert!(f < 1.15 * c, "with background subtraction and gains {f}, clean {c}");
    assert!(b > 1.3 * c && b > 1.2 * f, "without them {b}, with them {f}, clean {c}");

    // The fitted gains are the drawn ones (training cameras average 1 in both).
    let drawn = json(&d.join("real/synth.json"))["camera_gains"].clone();
    let pre = &fitted["preprocessing"];
    assert_eq!(pre["gains"]["mode"], "fit");
    assert!(pre["clipped_pixels"].as_u64().expect("clipped") > 0, "noise below the background is clipped");
    for f in pre["frames"].as_array().expect("frames") {
        let name = f["camera"].as_str().expect("camera");
        let truth = drawn[name].as_f64().expect("drawn gain");
        if f["holdout"].as_bool().expect("holdout") {
            // A held-out camera's gain is unknown to the run; its best-fit gain is reported and
            // removes most of the misfit.
            let s = &f["holdout_scores"];
            assert!(s["nrmse_fitted"].as_f64().expect("fitted") <= s["nrmse_raw"].as_f64().expect("raw"));
        } else {
            let gain = f["gain"].as_f64().expect("gain");
            assert!((gain / truth - 1.0).abs() < 0.05, "{name}: fitted {gain}, drawn {truth}");
        }
    }
    assert!(stdout.contains("camera gains: cam000") && stdout.contains("held-out cam003"), "{stdout}");

    // `eval` scores the held-out camera on its image as the run saw it (linearised, background
    // subtracted, divided by the gain the run recorded), as the run's own score does; on the
    // raw 8-bit sRGB pixels with their background it read 0.7 where the run read 0.06.
    ok(&fluidnerf(d, &["eval", "run-fit", "--scene", "real", "--json", "ev.json", "-q"]));
    let scored = json(&d.join("ev.json"))["reprojection"][0]["nrmse"].as_f64().expect("eval's NRMSE");
    let held = pre["frames"].as_array().expect("frames").iter().find(|f| f["holdout"] == true).expect("held out");
    let own = held["holdout_scores"]["nrmse_raw"].as_f64().expect("the run's score");
    assert!((scored / own - 1.0).abs() < 0.3, "eval {scored}, the run's own score {own}");

    // By default (gains auto) a run fits the gains where the images' totals ask for it, to the
    // same result as --gains fit, and says why; on the clean recording it takes the images as
    // they are, as --gains none does.
    let (auto, stdout) = run_with("real", "run-auto", None);
    assert_eq!(json(&d.join("run-auto/config.json"))["gains"]["mode"], "auto");
    assert_eq!(pre_mode(&auto), "fit");
    assert_eq!(nrmse(&auto), f);
    let why = auto["preprocessing"]["gains_auto"].as_str().expect("the reason auto fitted");
    assert!(why.contains("the median total of its time"), "{why}");
    assert!(stdout.contains("gains: fit (auto: cam"), "{stdout}");
    let (clean_auto, _) = run_with("clean", "run-clean-auto", None);
    assert_eq!((pre_mode(&clean_auto), nrmse(&clean_auto)), ("none".to_owned(), c));
    assert!(clean_auto["preprocessing"].get("gains_auto").is_none());

    // Without gains, the drawn gains show in the images' totals and the run says so; the clean
    // recording's cameras agree and draw no such warning, nor does a run that fits the gains.
    let hint = |r: &serde_json::Value| {
        r["warnings"]
            .as_array()
            .expect("warnings")
            .iter()
            .any(|w| w.as_str().is_some_and(|w| w.contains("--gains fit")))
    };
    assert!(hint(&bare), "{}", bare["warnings"]);
    assert!(!hint(&clean) && !hint(&fitted), "{} / {}", clean["warnings"], fitted["warnings"]);
    // `info` says it before any run.
    let said = |scene: &str| {
        let o = fluidnerf(d, &["info", scene]);
        ok(&o);
        let text = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
        text.contains("differ between cameras") && text.contains("gains auto")
    };
    assert!(said("real") && !said("clean"));
}

/// A time-resolved run fits no gains: by default (auto) it balances images whose totals differ
/// as differing gains make them, to the result of --gains balance, and says so; with --gains
/// none it warns and suggests balance; the fit's settings are refused for it.
#[test]
fn a_time_resolved_run_balances_differing_gains_and_says_so() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = [
        "synth",
        "--preset",
        "real-like-small",
        "--phantom",
        "jet-tr",
        "--times",
        "14,15,16",
        "--pixels",
        "32",
        "--resolution",
        "24",
        "--cameras",
        "6",
        "-o",
        "tr",
    ];
    ok(&fluidnerf(d, &synth));
    let run = ["reconstruct", "tr", "-o", "run", "-m", "tr-fast", "--stop", "budget", "--max-iterations", "2", "-q"];
    let with = |out: &str, gains: &str| {
        let mut args = run.to_vec();
        args[3] = out;
        args.extend(["--gains", gains]);
        ok(&fluidnerf(d, &args));
        report(&d.join(out))
    };
    ok(&fluidnerf(d, &run));
    let said = |r: &serde_json::Value, words: &str| {
        r["warnings"]
            .as_array()
            .expect("warnings")
            .iter()
            .filter_map(|w| w.as_str())
            .any(|w| w.contains("differ between cameras") && w.contains(words))
    };
    let auto = report(&d.join("run"));
    assert!(said(&auto, "a time-resolved run fits no gains, so the images are balanced"), "{}", auto["warnings"]);
    // The report records the mode taken, why, and each frame's gain, as a static run's does
    // (it had no preprocessing record: the mode showed only in the warning).
    let pre = &auto["preprocessing"];
    assert_eq!(pre_mode(&auto), "balance");
    let why = pre["gains_auto"].as_str().expect("why auto balanced");
    assert!(why.contains("the median total of its time"), "{why}");
    let frames = pre["frames"].as_array().expect("a gain per frame");
    assert_eq!(frames.len(), 18, "6 cameras at 3 times");
    let gains: Vec<f64> = frames.iter().map(|f| f["gain"].as_f64().expect("gain")).collect();
    assert!(gains.iter().any(|&g| (g - 1.0).abs() > 0.05), "{gains:?}");
    assert!(frames.iter().all(|f| f["offset"] == 0.0 && f["holdout_scores"].is_null()));
    let html = std::fs::read_to_string(d.join("run/report.html")).expect("report.html");
    assert!(html.contains("Preprocessing:") && html.contains("gains balance (auto:"), "no preprocessing table");
    assert_eq!(nrmse(&auto), nrmse(&with("balanced", "balance")));
    let none = with("as-they-are", "none");
    assert!(said(&none, "--gains balance"), "{}", none["warnings"]);
    assert_eq!(pre_mode(&none), "none");
    assert_ne!(nrmse(&none), nrmse(&auto));
    let mut refits = run.to_vec();
    refits.extend(["--gain-every", "5", "--force"]);
    let o = fluidnerf(d, &refits);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("gains.every") && err.contains("fits none"), "{err}");
}

/// A real-like recording through vignetting (`synth --vignetting 0.8`: each camera's
/// sensitivity falls by 80 % from an off-centre optical centre to the farthest corner, scaled to
/// mean 1) with one flat-field frame per camera: reconstructed with its `flat_field` it comes
/// back to the recording without vignetting, volume and held-out camera alike, and its fitted
/// gains to the drawn ones; with the flat-field keys removed it is clearly worse.
#[test]
fn a_flat_field_undoes_vignetting() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = |out: &str, extra: &[&str]| synth_small(d, out, extra);
    synth("plain", &[]);
    let o = fluidnerf(d, &["synth", "--preset", "real-like-small", "-o", "vignetted", "--vignetting", "0.8"]);
    ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains("1 background frame(s) and 1 flat-field frame(s) (vignetting 0.8) per camera"), "{said}");
    assert!(said.contains("files     transforms.json, images/, background/, flat/, truth/"), "{said}");
    synth("vignetted", &["--vignetting", "0.8", "--force"]);
    let scene = json(&d.join("vignetted/transforms.json"));
    assert_eq!(scene["frames"][0]["flat_field"], serde_json::json!(["flat/cam000_f0.jpg"]));
    assert!(d.join("vignetted/flat/cam007_f0.jpg").is_file());
    assert_eq!(json(&d.join("vignetted/synth.json"))["settings"]["real"]["vignetting"], 0.8);
    // The same recording with its flat-field keys removed.
    std::fs::create_dir_all(d.join("uncorrected/truth")).expect("mkdir");
    let mut raw = scene.clone();
    for f in raw["frames"].as_array_mut().expect("frames") {
        f.as_object_mut().expect("frame").remove("flat_field");
    }
    let text = raw.to_string().replace("\"images/", "\"../vignetted/images/");
    std::fs::write(d.join("uncorrected/transforms.json"), text.replace("\"background/", "\"../vignetted/background/"))
        .expect("write");
    std::fs::copy(d.join("vignetted/truth/truth.npy"), d.join("uncorrected/truth/truth.npy")).expect("copy");

    let run = |scene: &str| {
        let out = format!("run-{scene}");
        ok(&fluidnerf(d, &["reconstruct", scene, "-o", &out, "-m", "asart", "--resolution", "40", "-q"]));
        report(&d.join(out))
    };
    let (plain, flat, bare) = (run("plain"), run("vignetted"), run("uncorrected"));
    let held = |r: &serde_json::Value| {
        let frames = r["preprocessing"]["frames"].as_array().expect("frames").clone();
        let f = frames.into_iter().find(|f| f["holdout"] == true).expect("a held-out frame");
        f["holdout_scores"]["nrmse_raw"].as_f64().expect("held-out NRMSE")
    };
    // Measured: volume NRMSE 0.2501 without vignetting, 0.2507 with it and its flat field,
    // 0.2689 without the flat field; held-out camera 0.0586, 0.0555, 0.0718.
    let (p, f, b) = (nrmse(&plain), nrmse(&flat), nrmse(&bare));
    assert!(f < 1.02 * p, "with the flat field {f}, without vignetting {p}");
    assert!(b > 1.05 * p && b > 1.05 * f, "without the flat field {b}, with it {f}, without vignetting {p}");
    let (hp, hf, hb) = (held(&plain), held(&flat), held(&bare));
    assert!(hf < 1.05 * hp && hb > 1.15 * hp && hb > 1.15 * hf, "held out: {hp} / {hf} / {hb}");

    // The report records the flat fields and their range; the fitted gains are the drawn ones.
    let pre = &flat["preprocessing"];
    assert!(pre["scene"].as_str().expect("scene").contains("flat field: one flat frame (8 frames)"), "{pre}");
    let range = pre["flat_field_range"].as_array().expect("the flats' range");
    let (lo, hi) = (range[0].as_f64().expect("lo"), range[1].as_f64().expect("hi"));
    assert!(lo > 0.05 && lo < 0.5 && hi > 1.2 && hi < 1.6, "{lo} .. {hi}");
    assert!(bare["preprocessing"].get("flat_field_range").is_none());
    let drawn = json(&d.join("vignetted/synth.json"))["camera_gains"].clone();
    for f in pre["frames"].as_array().expect("frames").iter().filter(|f| f["holdout"] == false) {
        let name = f["camera"].as_str().expect("camera");
        let (gain, truth) = (f["gain"].as_f64().expect("gain"), drawn[name].as_f64().expect("drawn"));
        assert!((gain / truth - 1.0).abs() < 0.02, "{name}: fitted {gain}, drawn {truth}");
    }
    let html = std::fs::read_to_string(d.join("run-vignetted/report.html")).expect("report.html");
    assert!(html.contains("flat field: one flat frame (8 frames)") && html.contains("divided by flat fields of"));
    let o = fluidnerf(d, &["info", "vignetted"]);
    ok(&o);
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains("flat field: one flat frame (8 frames)") && said.contains("flat fields (normalised"),
        "{said}"
    );

    // Synthesised again without vignetting, the scene has no flat fields and their folder goes.
    synth("vignetted", &["--force"]);
    assert!(json(&d.join("vignetted/transforms.json"))["frames"][0].get("flat_field").is_none());
    assert!(!d.join("vignetted/flat").exists());
    let o = fluidnerf(d, &["synth", "--preset", "real-like-small", "-o", "x", "--flat-frames", "2"]);
    refused(&o, "--flat-frames: flat-field frames are recorded only with vignetting");
}

/// Settings of the gain fit given to a run whose gains auto then fits none (the cameras agree)
/// are named as unused; without them no such warning is given. They were dropped unannounced.
#[test]
fn gain_fit_settings_that_auto_leaves_unused_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    demo_scene(d, "blobs", 4, 24, 12, &[]);
    let run = |out: &str, extra: &[&str]| {
        let mut args = vec!["reconstruct", "scene", "-o", out, "--method", "asart", "--resolution", "12"];
        args.extend(["--max-iterations", "2", "-q"]);
        args.extend_from_slice(extra);
        ok(&fluidnerf(d, &args));
        let report = report(&d.join(out));
        assert_eq!(pre_mode(&report), "none");
        report["warnings"].as_array().expect("warnings").iter().filter_map(|w| w.as_str().map(String::from)).collect()
    };
    let warned: Vec<String> = run("with", &["--gain-rounds", "3", "--gain-offset"]);
    let unused = warned.iter().find(|w| w.contains("set how gains are fitted")).expect("the unused settings named");
    assert!(
        unused.starts_with("gains.offset (--gain-offset), gains.rounds (--gain-rounds) set")
            && unused.contains("gains auto fits none")
            && unused.contains("--gains fit"),
        "{unused}"
    );
    let plain: Vec<String> = run("without", &[]);
    assert!(!plain.iter().any(|w| w.contains("set how gains are fitted")), "{plain:?}");
}

/// A camera whose image holds no light while the others see the flow (off, covered, or the
/// wrong file) is named in a warning. Its dark total no longer reads as a camera of another
/// gain (gains auto fitted gains for it), and gains fitted by request average 1 over the
/// cameras that have one, so the dark camera does not rescale the others and the volume.
#[test]
fn a_dark_camera_among_lit_ones_is_named_and_rescales_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 5, 24, 12, &[]);
    let black = fluidnerf_core::Image { width: 24, height: 24, data: vec![0.0; 24 * 24] };
    fluidnerf_io::image::write_png16_counts(&d.join("scene/images/cam002.png"), &black).expect("writes");
    let run = |out: &str, extra: &[&str]| {
        let mut args = vec!["reconstruct", "scene", "-o", out, "--method", "asart", "--resolution", "12"];
        args.extend(["--max-iterations", "4", "-q"]);
        args.extend_from_slice(extra);
        ok(&fluidnerf(d, &args));
        report(&d.join(out))
    };
    let warnings = |r: &serde_json::Value| -> Vec<String> {
        r["warnings"].as_array().expect("warnings").iter().filter_map(|w| w.as_str().map(String::from)).collect()
    };
    let auto = run("auto", &[]);
    let said = warnings(&auto);
    let dark = said.iter().find(|w| w.contains("dark at every pixel")).expect("the dark camera named");
    assert!(dark.starts_with("cam002 (images/cam002.png) is dark") && dark.contains("remove that frame"), "{dark}");
    assert!(!said.iter().any(|w| w.contains("differ between cameras")), "{said:?}");
    assert_eq!(pre_mode(&auto), "none");
    let fit = run("fit", &["--gains", "fit", "--gain-every", "2"]);
    assert!(warnings(&fit).iter().any(|w| w.contains("cam002 (images/cam002.png) is dark")));
    let frames = fit["preprocessing"]["frames"].as_array().expect("a gain per frame").clone();
    let lit: Vec<f64> = frames
        .iter()
        .filter(|f| f["camera"] != "cam002" && f["holdout"] == false)
        .map(|f| f["gain"].as_f64().expect("gain"))
        .collect();
    assert_eq!(lit.len(), 4);
    let mean = lit.iter().sum::<f64>() / lit.len() as f64;
    // Balanced totals and fitted gains each average 1 over the lit cameras; their products
    // nearly so (a dark camera in either mean made them 1.25 here).
    assert!((mean - 1.0).abs() < 0.02, "the lit cameras' gains average {mean}: {lit:?}");
}

/// Training images each of one value throughout (every pixel saturated, or all at one level)
/// are refused: the run warned, then "succeeded" with a field as flat as they are. One
/// saturated camera among good ones is still only warned about.
#[test]
fn training_images_that_are_each_one_value_are_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 3, 16, 8, &[]);
    let write = |cam: usize, counts: f32| {
        let image = fluidnerf_core::Image { width: 16, height: 16, data: vec![counts; 256] };
        let path = d.join(format!("scene/images/cam{cam:03}.png"));
        fluidnerf_io::image::write_png16_counts(&path, &image).expect("writes");
    };
    let run =
        |out: &str| fluidnerf(d, &["reconstruct", "scene", "-o", out, "--method", "asart", "--max-iterations", "1"]);
    write(0, 65535.0);
    ok(&run("run"));
    for (cam, counts) in [(1, 65535.0), (2, 65535.0), (0, 1000.0), (1, 1000.0), (2, 1000.0)] {
        write(cam, counts);
    }
    let o = run("again");
    refused(&o, "transforms.json: every training image is one value throughout (cam000");
    refused(&o, "carry no information about the field");
    assert!(!d.join("again").exists(), "left an output folder");
}
