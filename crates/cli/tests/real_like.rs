//! A real-like recording end to end: `synth --preset real-like-small` (camera gains ±30 %, a 5 %
//! background with dark noise, one background frame per camera, 8-bit sRGB JPEG) reconstructed
//! with background subtraction and fitted gains comes close to the same jet recorded as clean
//! linear images, and clearly closer than without them; the fitted gains match the drawn ones,
//! and a run without gains warns that the images' totals differ as differing gains make them.

mod common;
use common::*;

const SMALL: [&str; 8] = ["--pixels", "40", "--resolution", "40", "--cameras", "8", "--holdout", "cam003"];

fn nrmse(r: &serde_json::Value) -> f64 {
    r["final_nrmse"].as_f64().expect("final_nrmse")
}

#[test]
fn background_subtraction_and_gain_fitting_recover_the_clean_result() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = |out: &str, extra: &[&str]| {
        let mut args = vec!["synth", "--preset", "real-like-small", "-o", out];
        args.extend_from_slice(&SMALL);
        args.extend_from_slice(extra);
        ok(&fluidnerf(d, &args));
    };
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

    let run = |scene: &str, out: &str, gains: &str| {
        let args = ["reconstruct", scene, "-o", out, "-m", "asart", "--resolution", "40", "--gains", gains, "-q"];
        let o = fluidnerf(d, &args);
        ok(&o);
        (report(&d.join(out)), String::from_utf8_lossy(&o.stdout).to_string())
    };
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
        text.contains("differ between cameras") && text.contains("--gains fit")
    };
    assert!(said("real") && !said("clean"));
}
