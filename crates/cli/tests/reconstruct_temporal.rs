//! `fluidnerf reconstruct --method tr-fast|tr-fluidnerf|static-per-frame` end to end on a tiny
//! generated time-resolved scene: the volume series and its ParaView collection, per-frame
//! metrics (held-out time included), the stitched field loadable by the library, overwrite
//! refusal, and `fluidnerf eval` on the series.

mod common;
use common::*;

#[test]
fn time_resolved_runs_write_a_series_metrics_and_a_loadable_field() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    ok(&fluidnerf(
        d,
        &[
            "synth",
            "-q",
            "--preset",
            "jet-tr60",
            "--cameras",
            "6",
            "--pixels",
            "24",
            "--resolution",
            "16",
            "--model",
            "pinhole",
            "--times",
            "14,14.5,15,16",
            "-o",
            "scene",
        ],
    ));
    let common = ["-q", "--resolution", "12", "--holdout-times", "14.5", "--checkpoint-every", "0"];

    // The fast field in windows of 2 frames overlapping by 1: frames 14, 15, 16 are trained,
    // 14.5 is held out (no images used) but still reconstructed and scored.
    let mut args = vec!["reconstruct", "scene", "-o", "fast", "--method", "tr-fast", "--max-iterations", "12"];
    args.extend(["--window", "2", "--overlap", "1", "--rays-per-image", "64", "--coarse-samples", "16"]);
    args.extend(common);
    ok(&fluidnerf(d, &args));
    let run = d.join("fast");
    let report = json(&run.join("report.json"));
    assert_eq!(report["frames"], 3);
    assert_eq!(report["windows"], 2);
    let per_frame = report["per_frame"].as_array().expect("per-frame metrics");
    let times: Vec<f64> = per_frame.iter().map(|f| f["time"].as_f64().expect("time")).collect();
    assert_eq!(times, [14.0, 14.5, 15.0, 16.0]);
    assert_eq!(per_frame[1]["trained"], false);
    assert!(per_frame.iter().all(|f| f["nrmse"].as_f64().is_some_and(|e| e.is_finite())));
    for i in 0..4 {
        assert!(run.join(format!("frames/volume_{i:03}.npy")).exists());
        assert!(run.join(format!("frames/volume_{i:03}.vti")).exists());
    }
    let pvd = std::fs::read_to_string(run.join("volumes.pvd")).expect("pvd");
    assert_eq!(pvd.matches("<DataSet").count(), 4);
    assert!(pvd.contains("timestep=\"14.5\"") && pvd.contains("file=\"frames/volume_001.vti\""));
    let config = json(&run.join("config.json"));
    assert_eq!(config["temporal"]["windows"]["frames"], 2);
    assert!(config["version"].is_string() && config["seed"].is_u64());

    // The stitched field rebuilt from the run directory gives the written volumes.
    let field = fluidnerf_neural::temporal::load_temporal(&run).expect("loads");
    let scene = fluidnerf_io::scene::load_scene(&d.join("scene")).expect("scene");
    let vol = fluidnerf_io::volume::read_npy(&run.join("frames/volume_002.npy"), scene.aabb).expect("npy");
    let again = fluidnerf_core::Volume::from_field(vol.dims, vol.aabb, &field, 15.0);
    assert_eq!(vol.data, again.data);

    // Results are not overwritten without --force.
    let refused = fluidnerf(d, &args);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--force"));

    // `fluidnerf eval` scores the series against the truth, one volume per truth time step.
    let vols: Vec<String> = (0..4).map(|i| format!("fast/frames/volume_{i:03}.npy")).collect();
    let mut eval = vec!["eval", "--scene", "scene", "--no-reprojection", "--json", "eval.json"];
    eval.extend(vols.iter().map(String::as_str));
    ok(&fluidnerf(d, &eval));

    // The per-frame static baseline: one 3D field per training frame, the held-out time
    // interpolated linearly between its neighbours.
    let mut args = vec!["reconstruct", "scene", "-o", "static", "--method", "static-per-frame"];
    args.extend(["--preset", "static-small", "--max-iterations", "4", "--rays-per-image", "32"]);
    args.extend(common);
    ok(&fluidnerf(d, &args));
    let report = json(&d.join("static/report.json"));
    assert_eq!(report["windows"], 3);
    let temporal = json(&d.join("static/temporal.json"));
    assert_eq!(temporal["input_dim"], 3);

    // TR-FluidNeRF (the MLP), a few iterations.
    let mut args = vec!["reconstruct", "scene", "-o", "tr", "--method", "tr-fluidnerf", "--preset", "tr-small"];
    args.extend(["--max-iterations", "3", "--rays-per-image", "32"]);
    args.extend(common);
    ok(&fluidnerf(d, &args));
    let temporal = json(&d.join("tr/temporal.json"));
    assert_eq!(temporal["input_dim"], 4);
    assert_eq!(temporal["windows"].as_array().map(Vec::len), Some(1));
    assert!(d.join("tr/windows/w000.checkpoint.safetensors").exists());
}
