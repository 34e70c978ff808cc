//! `fluidnerf reconstruct --method tr-fast|tr-fluidnerf|static-per-frame` end to end on a tiny
//! generated time-resolved scene: the volume series and its ParaView collection, per-frame
//! metrics (held-out time included), the stitched field loadable by the library, overwrite
//! refusal, and `fluidnerf eval` on the series.

use crate::common;
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
    assert_eq!(report["windows"].as_array().map(Vec::len), Some(2));
    let per_frame = report["volumes"].as_array().expect("per-frame metrics");
    assert_eq!(per_frame.iter().filter(|f| f["trained"] == true).count(), 3);
    let times: Vec<f64> = per_frame.iter().map(|f| f["time"].as_f64().expect("time")).collect();
    assert_eq!(times, [14.0, 14.5, 15.0, 16.0]);
    assert_eq!(per_frame[1]["trained"], false);
    assert!(per_frame.iter().all(|f| f["metrics"]["global"]["nrmse"].as_f64().is_some_and(|e| e.is_finite())));
    for i in 0..4 {
        assert!(run.join(format!("frames/volume_{i:03}.npy")).exists());
        assert!(run.join(format!("frames/volume_{i:03}.vti")).exists());
    }
    let pvd = std::fs::read_to_string(run.join("volumes.pvd")).expect("pvd");
    assert_eq!(pvd.matches("<DataSet").count(), 4);
    assert!(pvd.contains("timestep=\"14.5\"") && pvd.contains("file=\"frames/volume_001.vti\""));
    let config = json(&run.join("config.json"));
    assert_eq!(config["method"]["windows"]["frames"], 2);
    assert!(config["fluidnerf_version"].is_string() && config["seed"].is_u64() && config["format"] == 1);

    // The stitched field rebuilt from the run directory gives the written volumes.
    let field = fluidnerf_neural::temporal::load_temporal(&run).expect("loads");
    let scene = fluidnerf_io::scene::load_scene(&d.join("scene")).expect("scene");
    let vol = fluidnerf_io::volume::read_npy(&run.join("frames/volume_002.npy"), scene.aabb).expect("npy");
    let again = fluidnerf_core::Volume::from_field(vol.dims, vol.aabb, &field, 15.0);
    assert_eq!(vol.data, again.data);
    // Its finest detail is its windows' finest grid level: what a bake must resolve.
    let finest = config["method"]["field"]["hash-grid"]["max_resolution"].as_u64().expect("max_resolution") as usize;
    assert_eq!(fluidnerf_core::ScalarField::detail_dims(&field), Some([finest; 3]));

    // Results are not overwritten without --force.
    let refused = fluidnerf(d, &args);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--force"));

    // `fluidnerf eval` scores the series against the truth, one volume per truth time step.
    let vols: Vec<String> = (0..4).map(|i| format!("fast/frames/volume_{i:03}.npy")).collect();
    let mut eval = vec!["eval", "--scene", "scene", "--no-reprojection", "--json", "eval.json"];
    eval.extend(vols.iter().map(String::as_str));
    ok(&fluidnerf(d, &eval));
    // ... and the run folder itself, through its field of space and time: the same truth
    // steps, scored at each step's time.
    ok(&fluidnerf(d, &["eval", "fast", "--scene", "scene", "--no-reprojection", "--json", "eval-run.json"]));
    let by_run = json(&d.join("eval-run.json"));
    let steps = by_run["steps"].as_array().expect("steps");
    assert_eq!(steps.len(), 4, "one per truth time");
    let written = json(&run.join("report.json"));
    for (step, v) in steps.iter().zip(written["volumes"].as_array().expect("volumes")) {
        assert_eq!(step["time"], v["time"]);
        let (a, b) = (
            step["global"]["nrmse"].as_f64().expect("nrmse"),
            v["metrics"]["global"]["nrmse"].as_f64().expect("nrmse"),
        );
        assert!((a - b).abs() < 1e-9, "eval {a} vs the run's own report {b}");
    }
    // export and render take the run folder too, at a chosen time.
    ok(&fluidnerf(
        d,
        &["export", "fast", "--scene", "scene", "--out", "exp", "--npy", "--time", "15", "--resolution", "12", "-q"],
    ));
    let exported = fluidnerf_io::volume::read_npy(&d.join("exp/volume.npy"), vol_box(d)).expect("npy");
    let written = fluidnerf_io::volume::read_npy(&run.join("frames/volume_002.npy"), vol_box(d)).expect("npy");
    assert_eq!(exported.data, written.data, "export at t = 15 is the run's frame at 15");
    // Without --time, its first instant; outside its instants, or not a number, refused (the
    // field would only repeat its first or last instant there).
    ok(&fluidnerf(d, &["export", "fast", "--out", "exp0", "--npy", "--resolution", "12", "-q"]));
    assert_eq!(json(&d.join("exp0/export.json"))["time"], 14.0);
    let first = fluidnerf_io::volume::read_npy(&run.join("frames/volume_000.npy"), vol_box(d)).expect("npy");
    let exported = fluidnerf_io::volume::read_npy(&d.join("exp0/volume.npy"), vol_box(d)).expect("npy");
    assert_eq!(exported.data, first.data, "export without --time is the run's first frame");
    for (time, needle) in [("16.5", "outside the time-resolved run's instants 14 … 16"), ("NaN", "finite")] {
        let t = format!("--time={time}");
        common::refused(&fluidnerf(d, &["export", "fast", "--out", "exp1", "--npy", &t, "-q"]), needle);
        common::refused(
            &fluidnerf(d, &["render", "fast", "--scene", "scene", "--out", "ren1", "--orbit", "1", &t]),
            needle,
        );
    }
    // A scene without times does not score it.
    ok(&fluidnerf(
        d,
        &["synth", "-q", "--preset", "demo", "--cameras", "3", "--pixels", "8", "--resolution", "8", "-o", "s3"],
    ));
    common::refused(
        &fluidnerf(d, &["eval", "fast", "--scene", "s3", "--no-reprojection", "--json", "e3.json"]),
        "has no time",
    );
    ok(&fluidnerf(d, &["render", "fast", "--scene", "scene", "--out", "ren", "--time", "15", "-q"]));
    // The footprint projector samples the stitched field on twice its finest level first.
    ok(&fluidnerf(
        d,
        &["render", "fast", "--scene", "scene", "--out", "ren-fp", "--time", "15", "--projector", "footprint", "-q"],
    ));
    assert_eq!(json(&d.join("ren-fp/render.json"))["baked"], serde_json::json!([2 * finest, 2 * finest, 2 * finest]));
    // compare takes it too: its curve is one point, the mean NRMSE over the trained times.
    ok(&fluidnerf(d, &["compare", "fast", "-o", "cmp", "-q"]));
    let c = json(&d.join("cmp/compare.json"));
    assert_eq!(c["runs"][0]["final_nrmse"], json(&run.join("report.json"))["final_nrmse"]);
    assert!(std::fs::read_dir(d.join("ren")).expect("rendered").count() > 0);

    // The per-frame static baseline: one 3D field per training frame, the held-out time
    // interpolated linearly between its neighbours.
    let mut args = vec!["reconstruct", "scene", "-o", "static", "--method", "static-per-frame"];
    args.extend(["--preset", "static-small", "--max-iterations", "4", "--rays-per-image", "32"]);
    args.extend(common);
    ok(&fluidnerf(d, &args));
    let report = json(&d.join("static/report.json"));
    assert_eq!(report["windows"].as_array().map(Vec::len), Some(3));
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

/// The bytes of every file of `dir/sub` whose name ends with `suffix`, sorted by name
/// (checkpoints left out: they also hold the training time).
fn files(dir: &std::path::Path, sub: &str, suffix: &str) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir.join(sub))
        .expect("readable")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.to_string_lossy().ends_with(suffix) && !p.to_string_lossy().contains("checkpoint"))
        .map(|p| (p.file_name().expect("name").to_string_lossy().into_owned(), std::fs::read(&p).expect("read")))
        .collect();
    out.sort();
    out
}

/// A run stopped by Ctrl-C inside its second window and then resumed writes exactly what an
/// uninterrupted run writes; a resume with another window plan, box or images is refused,
/// naming the file.
#[cfg(unix)]
#[test]
fn an_interrupted_windowed_run_resumes_to_the_same_result() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = "synth -q --preset jet-tr60 --cameras 6 --pixels 24 --resolution 16 --model pinhole --times 14,14.5,15,15.5,16 -o scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    let run = |out: &str| -> Vec<String> {
        let args = "reconstruct scene --method tr-fluidnerf --preset tr-small --window 3 --overlap 1 -q \
                    --max-iterations 40 --rays-per-image 32 --resolution 12 --checkpoint-every 1 -o";
        args.split_whitespace().chain([out]).map(String::from).collect()
    };
    let as_str = |v: &[String]| v.iter().map(String::as_str).collect::<Vec<_>>().join(" ");
    ok(&fluidnerf(d, &run("full").iter().map(String::as_str).collect::<Vec<_>>()));

    // Ctrl-C as soon as the second window has written its first checkpoint.
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .current_dir(d)
        .args(run("cut"))
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("starts");
    let second = d.join("cut/windows/w001.checkpoint.safetensors");
    while !second.exists() {
        assert!(
            child.try_wait().expect("waits").is_none(),
            "finished before its second window: {}",
            as_str(&run("cut"))
        );
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    let kill = std::process::Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill");
    assert!(kill.success());
    assert_eq!(child.wait().expect("waits").code(), Some(130), "an interrupted run writes its results, exits 130");
    let cut = report(&d.join("cut"));
    assert_eq!(cut["status"], "interrupted");
    assert_eq!(cut["windows"].as_array().map(Vec::len), Some(2));
    let progress = json(&d.join("cut/windows/progress.json"));
    assert_eq!(progress["finished"].as_array().map(Vec::len), Some(1));

    // Without --resume or --force the results are kept.
    let refused = fluidnerf(d, &run("cut").iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--resume"));

    // Another window plan cannot continue this run.
    let mut other = run("cut");
    other[7] = "2".into(); // --window 2
    other.push("--resume".into());
    let refused = fluidnerf(d, &other.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!refused.status.success(), "resumed with another window plan");
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains("progress.json") && err.contains("window plan"), "{err}");

    let mut resume = run("cut");
    resume.push("--resume".into());
    // Nor can a scene whose box changed: the fields' coordinates are the box's.
    let transforms = d.join("scene/transforms.json");
    let original = std::fs::read_to_string(&transforms).expect("reads the scene");
    let mut moved: serde_json::Value = serde_json::from_str(&original).expect("JSON");
    moved["aabb"][1][0] = serde_json::json!(moved["aabb"][1][0].as_f64().expect("a number") + 1.0);
    std::fs::write(&transforms, moved.to_string()).expect("writes");
    let refused = fluidnerf(d, &resume.iter().map(String::as_str).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("progress.json") && err.contains("box"), "{err}");
    std::fs::write(&transforms, &original).expect("restores the scene");
    // Nor other images: one pixel changed in an image of the finished window, then in one of
    // the window that was running only; each refusal names that window's checkpoint.
    for (image, checkpoint) in [("cam000_t00.png", "w000.checkpoint"), ("cam003_t04.png", "w001.checkpoint")] {
        let image = d.join("scene/images").join(image);
        let bytes = std::fs::read(&image).expect("reads the image");
        let mut pixels = image::load_from_memory(&bytes).expect("decodes").to_luma16();
        let (w, h) = pixels.dimensions();
        pixels.get_pixel_mut(w / 2, h / 2).0[0] ^= 0x0100;
        pixels.save(&image).expect("writes the image");
        let before = std::fs::read(d.join("cut/report.json")).expect("report");
        let refused = fluidnerf(d, &resume.iter().map(String::as_str).collect::<Vec<_>>());
        let err = String::from_utf8_lossy(&refused.stderr);
        assert!(
            !refused.status.success() && err.contains(checkpoint) && err.contains("other images or cameras"),
            "{err}"
        );
        assert!(std::fs::read(d.join("cut/report.json")).expect("kept") == before, "a refused resume wrote");
        std::fs::write(&image, &bytes).expect("restores the image");
    }
    ok(&fluidnerf(d, &resume.iter().map(String::as_str).collect::<Vec<_>>()));
    let (full, cut) = (d.join("full"), d.join("cut"));
    assert_eq!(report(&cut)["status"], "finished");
    let weights = files(&full, "windows", ".safetensors");
    assert_eq!(weights.len(), 2);
    assert!(weights == files(&cut, "windows", ".safetensors"), "the resumed run's weights differ");
    let volumes = files(&full, "frames", ".npy");
    assert_eq!(volumes.len(), 5);
    assert!(volumes == files(&cut, "frames", ".npy"), "the resumed run's volumes differ");
    let histories = |dir: &std::path::Path| report(dir)["history"]["loss"].clone();
    assert_eq!(histories(&full), histories(&cut));

    // A resume that cannot load a window's saved state leaves the finished run as it was.
    let first = cut.join("windows/w000.checkpoint.safetensors");
    std::fs::write(&first, &std::fs::read(&first).expect("readable")[..1000]).expect("truncated");
    let before = std::fs::read(cut.join("report.json")).expect("readable");
    common::refused(
        &fluidnerf(d, &resume.iter().map(String::as_str).collect::<Vec<_>>()),
        "w000.checkpoint.safetensors",
    );
    assert!(std::fs::read(cut.join("report.json")).expect("kept") == before, "a refused resume changed report.json");
}

/// The box of the generated scene.
fn vol_box(d: &std::path::Path) -> fluidnerf_core::Aabb {
    fluidnerf_io::scene::load_scene(&d.join("scene")).expect("scene").aabb
}

/// A time step given to the space–time grid is reported as unused: the grid reads time on each
/// window's frame axis. And `tr-fast` is the default method for a scene of several instants.
#[test]
fn a_time_step_given_to_the_grid_field_is_reported_unused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth =
        "synth -q --preset jet-tr60 --cameras 4 --pixels 16 --resolution 12 --model pinhole --times 14,15,17 -o scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    let run = |name: &str, extra: &[&str]| {
        let mut args = vec!["reconstruct", "scene", "-o", name, "--method", "tr-fast", "--max-iterations", "2"];
        args.extend(["--resolution", "8", "--checkpoint-every", "0", "--rays-per-image", "16"]);
        args.extend(extra);
        let out = fluidnerf(d, &args);
        ok(&out);
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let warning = "the time step is not used by a hash-grid field";
    assert!(run("given", &["--time-step", "0.5"]).contains(warning));
    assert!(!run("inferred", &[]).contains(warning));
    let temporal = json(&d.join("given/temporal.json"));
    assert_eq!(temporal["windows"][0]["time_axis"], "frames");
    // Without --method, a scene of several instants gets tr-fast, not a static method.
    let args = "reconstruct scene -o default --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    assert_eq!(report(&d.join("default"))["method"], "tr-fast");
}

/// A held-out time at which the scene has no frame holds no image out: the run says so, and
/// still writes a volume there; a frame's time gets no such warning.
#[test]
fn a_held_out_time_matching_no_frame_is_warned_about() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth =
        "synth -q --preset jet-tr60 --cameras 4 --pixels 16 --resolution 12 --model pinhole --times 14,15,16 -o scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    let run = |name: &str, held: &str| {
        let args = format!(
            "reconstruct scene -o {name} --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 \
             --rays-per-image 16 --holdout-times {held}"
        );
        let out = fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>());
        ok(&out);
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let warning = "held-out time 15.5 matches no frame of the scene";
    assert!(run("between", "15.5").contains(warning));
    let times: Vec<f64> = report(&d.join("between"))["volumes"]
        .as_array()
        .expect("volumes")
        .iter()
        .map(|v| v["time"].as_f64().expect("time"))
        .collect();
    assert_eq!(times, [14.0, 15.0, 15.5, 16.0]);
    assert!(!run("frame", "15").contains("matches no frame"));
}

/// `--start-method tv` on a time-resolved run: SART-TV runs on each instant of the window that
/// starts afresh, alone, and the window's field starts from those volumes, so after a few
/// iterations every instant scores about as well as its own SART-TV volume and better than a
/// field started uniform. Static-per-frame windows each start from their own instant.
#[test]
fn time_resolved_windows_start_from_their_instants_voxel_runs() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth =
        "synth -q --preset jet-tr60 --cameras 6 --pixels 24 --resolution 16 --model pinhole --times 14,15,17 -o scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    let run = |out: &str, extra: &str| {
        let line = format!(
            "reconstruct scene -o {out} --method tr-fast --max-iterations 10 --resolution 16 --checkpoint-every 0 -q {extra}"
        );
        ok(&fluidnerf(d, &line.split_whitespace().collect::<Vec<_>>()));
        let report = json(&d.join(out).join("report.json"));
        let per_frame = report["volumes"].as_array().expect("per-frame metrics").clone();
        per_frame.iter().map(|f| f["metrics"]["global"]["nrmse"].as_f64().expect("scored")).collect::<Vec<f64>>()
    };
    let started = run("started", "--start-method tv");
    let fresh = run("fresh", "");
    let config = json(&d.join("started/config.json"));
    assert_eq!(config["method"]["start"]["method"], "tv", "{config}");
    for (i, (s, f)) in started.iter().zip(&fresh).enumerate() {
        let voxel = json(&d.join(format!("started/start/t{i:02}/report.json")));
        let v = voxel["final_nrmse"].as_f64().expect("scored");
        assert!(*s < 1.2 * v && *s < 0.8 * f, "instant {i}: started {s:.3}, its SART-TV {v:.3}, uniform start {f:.3}");
    }
    // Per-frame windows (a field of space alone each) start from their own instant.
    // (Short fits to the starts: only the starts are checked here.)
    let line = "reconstruct scene -o pf --method static-per-frame --preset fast --max-iterations 10 --resolution 16 \
                --checkpoint-every 0 -q --start-method tv --start-fit-steps 20";
    ok(&fluidnerf(d, &line.split_whitespace().collect::<Vec<_>>()));
    assert!(d.join("pf/start/t02/report.json").is_file());
    // A voxel method is not a start for itself, and a start method must be a voxel method.
    let bad = fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "asart", "--start-method", "tv"]);
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains("--start-method"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
    refused(
        &fluidnerf(d, &["reconstruct", "scene", "-o", "x", "--method", "tr-fast", "--start-method", "fast"]),
        "not a voxel method",
    );
}

/// Ctrl-C during a time-resolved run's start (the instants' voxel runs, or the window's fit to
/// them) stops it at once, says that the window's field never trained, and a resume runs the
/// start again (reading back the instants' starts that finished) to end where a run without a
/// break ends. Before, the instants after the stopped one still ran a voxel iteration each, the
/// fit ran all its steps (seconds) after the stop, nothing warned, and a resume trained the
/// field fitted to the unfinished starts: another run than its `config.json` describes.
#[test]
fn ctrl_c_during_a_time_resolved_start_stops_it_and_a_resume_runs_it_again() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth =
        "synth -q --preset jet-tr60 --cameras 6 --pixels 32 --resolution 16 --model pinhole --times 14,15,17 -o scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    // The settings, from a run stopped at once, with a short fit to the starts.
    let line = "reconstruct scene -o c --method tr-fast --start-method asart --resolution 64 --max-iterations 4 -q";
    let out = interrupted_once_made(d, &line.split_whitespace().collect::<Vec<_>>(), "c/config.json");
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    edit_json(&d.join("c/config.json"), |c| c["method"]["start"]["fit"]["iterations"] = serde_json::json!(20));
    let args = ["reconstruct", "--config", "c/config.json", "-o", "r"];
    let out = interrupted_once_made(d, &args, "r/start/t01");
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    // No instant's start ran after the one stopped.
    let starts: Vec<String> = (0..3)
        .map(|i| d.join(format!("r/start/t{i:02}")))
        .filter(|p| p.exists())
        .map(|p| report(&p)["status"].to_string())
        .collect();
    if let Some(i) = starts.iter().position(|s| s.contains("interrupted")) {
        assert_eq!(i + 1, starts.len(), "a start ran after the stop: {starts:?}");
    }
    let r = report(&d.join("r"));
    assert_eq!(r["status"], "interrupted", "{r}");
    let warnings = r["warnings"].to_string();
    assert!(
        warnings.contains("stopped during the start of window 0 (t = 14–17), before its field trained"),
        "{warnings}"
    );

    // Its window is checked against the images all the same: the starts it reads back were made
    // from them.
    let image = d.join("scene/images/cam000_t00.png");
    let original = std::fs::read(&image).expect("an image");
    std::fs::copy(d.join("scene/images/cam001_t00.png"), &image).expect("copied");
    refused(&fluidnerf(d, &["reconstruct", "-o", "r", "--resume"]), "was trained on other images or cameras");
    std::fs::write(&image, original).expect("restored");
    // The instant whose start finished is read back, not run again (its report would change).
    let first = std::fs::read(d.join("r/start/t00/report.json")).expect("the first instant's start");
    let resumed = fluidnerf(d, &["reconstruct", "-o", "r", "--resume"]);
    ok(&resumed);
    assert!(String::from_utf8_lossy(&resumed.stderr).contains("the window starts again from its start"));
    assert!(std::fs::read(d.join("r/start/t00/report.json")).unwrap() == first, "the finished start ran again");
    ok(&fluidnerf(d, &["reconstruct", "--config", "c/config.json", "-o", "whole", "-q"]));
    same_files(&d.join("r"), &d.join("whole"), &["windows/w000.safetensors", "frames/volume_002.npy"]);
    assert!(!report(&d.join("r"))["warnings"].to_string().contains("before its field trained"));
}

/// A time-resolved run killed hard (SIGKILL, a power loss) during a window's starts leaves no
/// checkpoint of that window to check the images against: its resume reads an instant's
/// finished start back only when it was made from the images and cameras the scene holds now.
/// Before, a check of the start's settings alone let a resume on changed images fit the window
/// to a start made from the old ones.
#[test]
fn a_resume_after_a_hard_kill_runs_a_start_again_whose_images_changed() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth =
        "synth -q --preset jet-tr60 --cameras 4 --pixels 24 --resolution 12 --model pinhole --times 14,15,16,17 -o scene";
    ok(&fluidnerf(d, &synth.split_whitespace().collect::<Vec<_>>()));
    // Two windows of two instants, each started from its instants' ASART runs, with a short fit.
    let line = "reconstruct scene -o c --method tr-fast --window 2 --overlap 0 --start-method asart --resolution 32 \
                --max-iterations 4 -q";
    let out = interrupted_once_made(d, &line.split_whitespace().collect::<Vec<_>>(), "c/config.json");
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    edit_json(&d.join("c/config.json"), |c| c["method"]["start"]["fit"]["iterations"] = serde_json::json!(20));
    // Killed once the second window's first instant's start has finished.
    let args = ["reconstruct", "--config", "c/config.json", "-o", "r", "-q"];
    let out = killed_once_made(d, &args, "r/start/t02/report.json");
    assert_eq!(std::os::unix::process::ExitStatusExt::signal(&out.status), Some(9), "not killed");
    assert!(!d.join("r/windows/w001.safetensors").exists(), "the second window trained before the kill");
    let first = std::fs::read(d.join("r/start/t02/report.json")).expect("the start's report");
    // One image of that instant replaced by another camera's: its start runs again.
    std::fs::copy(d.join("scene/images/cam001_t02.png"), d.join("scene/images/cam000_t02.png")).expect("copied");
    let resumed = fluidnerf(d, &["reconstruct", "-o", "r", "--resume"]);
    ok(&resumed);
    let said = String::from_utf8_lossy(&resumed.stderr);
    assert!(said.contains("made from other images or cameras than the scene's now; run again"), "{said}");
    assert!(std::fs::read(d.join("r/start/t02/report.json")).unwrap() != first, "the old start was read back");
}

/// A run stopped inside its first window writes the frames that window trained and no others:
/// the report lists the instants it did not reach (a held-out time among them), `volumes.pvd`
/// only the frames written, and `export`, `render` and `eval` at an instant it did not reach
/// refuse, naming the time and `--resume`. `--resume` then writes the whole series, as an
/// uninterrupted run does.
#[test]
fn a_run_stopped_in_its_first_window_writes_only_the_frames_it_trained() {
    use std::ops::ControlFlow;
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 6, 24, 12, &["--times", "14,15,16,17,18,19"]);
    // Windows of 3 frames overlapping by 1: frames 0..3, 2..5, 3..6.
    let args = "reconstruct scene --method tr-fast --window 3 --overlap 1 --holdout-times 18.5 --max-iterations 12 \
                --rays-per-image 64 --coarse-samples 16 --resolution 12 --checkpoint-every 0 -q -o full";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));

    // The same run, stopped at the fifth iteration of its first window.
    let scene = fluidnerf_io::scene::load_scene(&d.join("scene")).expect("scene");
    let mut config = fluidnerf_pipeline::RunConfig::read(&d.join("full/config.json")).expect("config");
    config.scene = scene.root.clone();
    let dir =
        fluidnerf_pipeline::RunDir::create(d.join("cut"), fluidnerf_pipeline::Overwrite::Refuse, Some(&scene.root))
            .expect("run folder");
    let cut = fluidnerf_pipeline::reconstruct(&scene, &config, &dir, |e| match e {
        fluidnerf_pipeline::RunEvent::Iteration { iteration: 5.., .. } => ControlFlow::Break(()),
        _ => ControlFlow::Continue(()),
    })
    .expect("runs");
    drop(dir);
    assert_eq!(cut.status, fluidnerf_pipeline::RunStatus::Interrupted);
    assert_eq!(cut.windows.len(), 1);
    let written: Vec<(Option<f64>, bool)> = cut.volumes.iter().map(|v| (v.time, v.trained)).collect();
    assert_eq!(written, [(Some(14.0), true), (Some(15.0), true), (Some(16.0), true)]);
    assert_eq!(cut.not_reached, [17.0, 18.0, 18.5, 19.0]);
    assert!(cut.warnings.iter().any(|w| w.contains("t = 17, 18, 18.5, 19") && w.contains("--resume")), "{cut:?}");
    let on_disk = report(&d.join("cut"));
    assert_eq!(on_disk["not_reached"], serde_json::json!([17.0, 18.0, 18.5, 19.0]));
    assert_eq!(files(&d.join("cut"), "frames", ".npy").len(), 3, "volumes written past the trained frames");
    let pvd = std::fs::read_to_string(d.join("cut/volumes.pvd")).expect("pvd");
    assert_eq!(pvd.matches("<DataSet").count(), 3, "{pvd}");
    assert!(pvd.contains("timestep=\"16\"") && !pvd.contains("timestep=\"17\""), "{pvd}");

    // Its field is read at the instants it trained, and refused at those it did not reach.
    ok(&fluidnerf(d, &["export", "cut", "--out", "exp", "--npy", "--time", "15", "--resolution", "12", "-q"]));
    let never = "time 18 was never trained: the run was stopped before it reached t = 17, 18, 18.5, 19 (its \
                 windows trained 14 … 16); continue it with `reconstruct --resume`";
    common::refused(&fluidnerf(d, &["export", "cut", "--out", "exp18", "--npy", "--time", "18", "-q"]), never);
    common::refused(
        &fluidnerf(d, &["render", "cut", "--scene", "scene", "--out", "ren18", "--camera", "0", "--time", "18"]),
        never,
    );
    for args in [&["eval", "cut", "--no-regions"][..], &["eval", "cut", "--no-regions", "--use-volume"]] {
        common::refused(&fluidnerf(d, args), "time 17 was never trained");
    }
    // Its NRMSE is a mean over the instants it reached: compare refuses it beside a whole run,
    // naming its report and the instants it did not reach.
    let cmp = fluidnerf(d, &["compare", "full", "cut", "-o", "cmp", "-q"]);
    common::refused(&cmp, "cut/report.json: the tr-fast run was stopped before it reached t = 17, 18, 18.5, 19");
    // One sentence, without the source's indentation in it.
    common::refused(
        &cmp,
        "so its NRMSE is over the instants it reached only, not over the recording as a whole run's is; continue it \
         with `reconstruct --resume` and compare it then, or leave it out",
    );
    assert!(!d.join("cmp").exists(), "nothing written for a refused comparison");

    // Resumed, it writes what the uninterrupted run writes.
    ok(&fluidnerf(d, &["reconstruct", "-o", "cut", "--resume", "-q"]));
    let resumed = report(&d.join("cut"));
    assert_eq!(resumed["status"], "finished");
    assert_eq!(resumed["not_reached"], serde_json::json!([]));
    assert_eq!(resumed["volumes"].as_array().map(Vec::len), Some(7));
    let volumes = files(&d.join("full"), "frames", ".npy");
    assert_eq!(volumes.len(), 7);
    assert!(volumes == files(&d.join("cut"), "frames", ".npy"), "the resumed run's volumes differ");
    ok(&fluidnerf(d, &["export", "cut", "--out", "exp18", "--npy", "--time", "18", "--resolution", "12", "-q"]));
    ok(&fluidnerf(d, &["compare", "full", "cut", "-o", "cmp", "-q"]));
}

/// A time whose every frame the scene holds out is reconstructed and scored as a held-out time,
/// as one given to `--holdout-times` is, and the run says so: between training times it comes
/// from the field there (eval scores it and reprojects its frames), at the end it is held at
/// the last training time, with the same warning as a held-out time there.
#[test]
fn a_time_whose_frames_are_all_held_out_is_reconstructed_as_a_held_out_time() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 12, &["--times", "14,15,16"]);
    let transforms = d.join("scene/transforms.json");
    let original: serde_json::Value = json(&transforms);
    let hold_out = |time: f64| {
        let mut scene = original.clone();
        for frame in scene["frames"].as_array_mut().expect("frames") {
            if frame["time"] == time {
                frame["holdout"] = serde_json::json!(true);
            }
        }
        std::fs::write(&transforms, scene.to_string()).expect("writes");
    };
    let run = |out: &str| {
        let args = "reconstruct scene --method tr-fast --max-iterations 8 --rays-per-image 32 --coarse-samples 8 \
                    --resolution 12 --checkpoint-every 0 -q --force -o";
        ok(&fluidnerf(d, &args.split_whitespace().chain([out]).collect::<Vec<_>>()));
        report(&d.join(out))
    };
    let volumes = |r: &serde_json::Value| -> Vec<(f64, bool)> {
        let v = r["volumes"].as_array().expect("volumes");
        v.iter().map(|v| (v["time"].as_f64().expect("time"), v["trained"] == true)).collect()
    };
    let warned = |r: &serde_json::Value, needle: &str| {
        r["warnings"].as_array().expect("warnings").iter().any(|w| w.as_str().is_some_and(|w| w.contains(needle)))
    };
    let every = |t: &str| format!("every frame at t = {t} is held out in the scene");

    hold_out(15.0);
    let middle = run("middle");
    assert_eq!(volumes(&middle), [(14.0, true), (15.0, false), (16.0, true)]);
    assert!(middle["volumes"][1]["metrics"]["global"]["nrmse"].is_number(), "{middle}");
    assert!(warned(&middle, &every("15")) && !warned(&middle, "outside the training times"), "{middle}");
    ok(&fluidnerf(d, &["eval", "middle", "--no-regions", "--json", "middle.json"]));
    let scored = json(&d.join("middle.json"));
    assert_eq!(scored["steps"].as_array().map(Vec::len), Some(3));
    assert_eq!(scored["reprojection"].as_array().map(Vec::len), Some(4), "the frames at t = 15 are reprojected");

    hold_out(16.0);
    let end = run("end");
    assert_eq!(volumes(&end), [(14.0, true), (15.0, true), (16.0, false)]);
    assert!(warned(&end, &every("16")), "{end}");
    assert!(warned(&end, "held-out time 16 lies outside the training times"), "{end}");
}

#[test]
fn a_frame_without_time_in_a_time_resolved_scene_is_refused_by_name() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 12, &["--times", "14,15"]);
    let image = edit_json(&d.join("scene/transforms.json"), |v| {
        v["frames"][2].as_object_mut().expect("frame").remove("time");
        v["frames"][2]["file_path"].as_str().expect("file_path").to_string()
    });

    // Read as time 0, it was one more instant seen by a single camera.
    let needle = format!("frame 2 ({image}) has no `time`, but the other 7 frame(s) have one");
    refused(&fluidnerf(d, &["info", "scene"]), &needle);
    let run = ["reconstruct", "scene", "-o", "run", "--method", "tr-fast", "--stop", "budget", "--resolution", "8"];
    refused(&fluidnerf(d, &[&run[..], &["--max-iterations", "2", "-q"]].concat()), &needle);
    assert!(!d.join("run").exists(), "nothing written");
}

/// Ground truth at only some of the frame times: reconstruct warns, naming the times without
/// truth, and says its NRMSE is a mean over the others; eval and info say which times go
/// unscored, and a list of volumes that does not match the truth is refused naming them.
#[test]
fn truth_at_only_some_times_is_reported_naming_the_times_without() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 12, &["--times", "14,15,16"]);
    edit_json(&d.join("scene/transforms.json"), |v| {
        v["truth"].as_array_mut().expect("truth").retain(|t| t["time"] != 15.0)
    });
    let gap = "the ground truth covers 2 of the 3 frame times: none at t = 15";

    let info = fluidnerf(d, &["info", "scene"]);
    assert!(String::from_utf8_lossy(&info.stdout).contains(gap), "{}", String::from_utf8_lossy(&info.stdout));
    let args = "reconstruct scene --method tr-fast --max-iterations 4 --rays-per-image 32 --coarse-samples 8 \
                --resolution 12 --checkpoint-every 0 -o run";
    let out = fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>());
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("(mean over the 2 of 3 times with ground truth)"));
    let r = report(&d.join("run"));
    assert!(r["warnings"].as_array().expect("warnings").iter().any(|w| w.as_str().is_some_and(|w| w.contains(gap))));
    let scored: Vec<bool> =
        r["volumes"].as_array().expect("volumes").iter().map(|v| v["metrics"].is_object()).collect();
    assert_eq!(scored, [true, false, true]);

    let out = fluidnerf(d, &["eval", "run", "--no-regions"]);
    ok(&out);
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("not scored: no ground truth at t = 15 (the scene's truth covers 2 of its 3 frame times)"));
    assert_eq!(json(&d.join("run/metrics.json"))["times_without_truth"], serde_json::json!([15.0]));
    let volumes = ["run/frames/volume_000.npy", "run/frames/volume_001.npy", "run/frames/volume_002.npy"];
    let out = fluidnerf(d, &[&["eval", "--scene", "scene", "--json", "m.json"][..], &volumes[..]].concat());
    refused(&out, "3 reconstruction volumes given but the scene has 2 ground-truth time steps (none at t = 15");

    // A static run mixes the times and is scored against the first truth listed, and says so.
    ok(&fluidnerf(d, &["reconstruct", "scene", "--method", "asart", "--max-iterations", "2", "-q", "-o", "voxel"]));
    let r = report(&d.join("voxel"));
    let says = "its metrics are against the first of the 2 ground truths listed (at t = 14) only";
    assert!(r["warnings"].as_array().expect("warnings").iter().any(|w| w.as_str().is_some_and(|w| w.contains(says))));
}

/// One ground truth without a time, in a scene of several times, stands for every time: a
/// time-resolved run scores each instant against it (a steady flow's truth), and info and the
/// run say so, since one instant's truth given without its time would score the others against
/// the wrong volume. Eval scores such a run the same way.
#[test]
fn a_timeless_truth_of_a_time_resolved_scene_is_used_for_every_instant_and_said_so() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 3, 16, 8, &["--times", "14,15"]);
    edit_json(&d.join("scene/transforms.json"), |v| {
        v["truth"] = serde_json::json!([{"file_path": "truth/truth_t00.npy"}]);
    });
    let says = "the ground truth (truth/truth_t00.npy) has no time, so a time-resolved run scores each of the 2 \
                frame times (14 … 15) against it, as for a steady flow";
    let info = fluidnerf(d, &["info", "scene"]);
    ok(&info);
    assert!(String::from_utf8_lossy(&info.stdout).contains(says), "{}", String::from_utf8_lossy(&info.stdout));
    let args = "reconstruct scene --method tr-fast --max-iterations 2 --rays-per-image 32 --coarse-samples 8 \
                --resolution 8 --checkpoint-every 0 -q -o run";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let r = report(&d.join("run"));
    assert!(r["warnings"].as_array().expect("warnings").iter().any(|w| w.as_str().is_some_and(|w| w.contains(says))));
    let scored: Vec<bool> =
        r["volumes"].as_array().expect("volumes").iter().map(|v| v["metrics"].is_object()).collect();
    assert_eq!(scored, [true, true]);
    // Eval scores it as the run did (it refused the run before), and as many volumes as frame
    // times (refused as "2 volumes given but the scene has 1 ground-truth time steps").
    let out = fluidnerf(d, &["eval", "run", "--no-regions", "--json", "m.json"]);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stderr).contains(says));
    let (scored, reported) = eval_and_report_nrmse(d, "run");
    assert_eq!(scored.len(), 2);
    for (s, r) in scored.iter().zip(&reported) {
        assert!((s - r).abs() <= 1e-6 * r, "eval {scored:?}, report {reported:?}");
    }
    let files = ["run/frames/volume_000.npy", "run/frames/volume_001.npy"];
    ok(&fluidnerf(d, &[&["eval", "-s", "scene", "--no-regions", "--json", "f.json", "-q"][..], &files].concat()));
    assert_eq!(json(&d.join("f.json"))["steps"].as_array().map(Vec::len), Some(2));
}

/// The grid's time axis spans each window's frames, one cell per frame interval: a `time_span`
/// or `time_resolution` edited into a `tr-fast` configuration was replaced without a word. One
/// that differs from both its default and the value used is refused naming its key; the
/// value used is accepted.
#[test]
fn an_edited_time_axis_of_the_grid_that_windows_replace_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 3, 16, 12, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o first --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let run = |key: &str, value: serde_json::Value| {
        let config = d.join("run.json");
        std::fs::copy(d.join("first/config.json"), &config).expect("copies the config");
        edit_json(&config, |v| v["method"]["field"]["hash-grid"][key] = value);
        let _ = std::fs::remove_dir_all(d.join("again"));
        fluidnerf(d, &["reconstruct", "--config", "run.json", "-o", "again", "-q"])
    };
    for key in ["time_span", "time_resolution"] {
        let out = run(key, serde_json::json!(5));
        refused(&out, &format!("method.field.hash-grid.{key}: 5 would be ignored"));
        refused(&out, "sets it to 2 for windows of 3 frames");
        assert!(!d.join("again").exists(), "nothing written");
        ok(&run(key, serde_json::json!(2)));
    }
}

/// A scene whose frames hold no time trained a time-resolved field at t = 0 with only a warning
/// in one piece, while its windows alone (--window-index) were refused: both refuse it alike,
/// for every time-resolved method, and write nothing.
#[test]
fn a_time_resolved_run_of_a_scene_without_frame_times_is_refused_in_one_piece_as_in_windows() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 3, 16, 8, &[]);
    let scene = std::fs::canonicalize(d.join("scene")).expect("scene");
    for method in ["tr-fast", "tr-fluidnerf", "static-per-frame"] {
        let needle = format!(
            "method: {method} plans its windows over the frames' times, and the scene {} has no frame times (no \
             frame has a `time`); give every frame its time, or reconstruct the scene with a static method",
            scene.display()
        );
        let run = ["reconstruct", "scene", "-o", "run", "--method", method, "--max-iterations", "2", "-q"];
        refused(&fluidnerf(d, &run), &needle);
        assert!(!d.join("run").exists(), "{method}: nothing written");
        refused(&fluidnerf(d, &[&run[..], &["--window-index", "0"]].concat()), &needle);
        assert!(!d.join("run").exists(), "{method}: nothing written");
    }
}

/// An instant that fewer cameras imaged than the recording has is reconstructed from the views
/// it has, and said so by `info` and by the run: a camera's frame left out at one instant, and
/// a frame whose time was jittered off its instant into one of its own (seen by one camera).
/// The warning names each instant, how many cameras it has and which are missing.
#[test]
fn instants_imaged_by_fewer_cameras_than_the_recording_has_are_named() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let transforms = d.join("scene/transforms.json");
    let mut scene = json(&transforms);
    let frames = scene["frames"].as_array_mut().expect("frames");
    frames.retain(|f| !(f["camera"] == "cam003" && f["time"] == 15.0));
    let jittered = frames.iter_mut().find(|f| f["camera"] == "cam000" && f["time"] == 16.0).expect("frame");
    jittered["time"] = serde_json::json!(16.000001);
    std::fs::write(&transforms, scene.to_string()).expect("writes");
    let says = "3 instants of the recording have fewer views than its 4 cameras: t = 15 has 3 (no cam003); t = 16 \
                has 3 (no cam000); t = 16.000001 has 1 (only cam000)";

    let info = fluidnerf(d, &["info", "scene"]);
    let printed = String::from_utf8_lossy(&info.stdout);
    assert!(printed.contains(says), "{printed}");

    let args = "reconstruct scene -o run --method tr-fast --max-iterations 2 --rays-per-image 16 --coarse-samples 8 \
                --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let warnings = report(&d.join("run"))["warnings"].clone();
    let warned = warnings.as_array().expect("warnings").iter().any(|w| w.as_str().is_some_and(|w| w.contains(says)));
    assert!(warned, "{warnings}");

    // A full recording says nothing.
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16", "--force"]);
    let info = fluidnerf(d, &["info", "scene"]);
    assert!(!String::from_utf8_lossy(&info.stdout).contains("fewer views"));
}

/// A network's windows read time as `t' = (t − t₀)/Δt`: a run resumed with another
/// `--time-step` would continue them on other time inputs. It is refused naming the time step
/// and both values (it was refused as if the images had changed).
#[test]
fn a_run_resumed_with_another_time_step_is_refused_naming_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fluidnerf --preset tr-small --window 2 --overlap 1 \
                --max-iterations 2 --rays-per-image 16 --coarse-samples 8 --fine-samples 0 --resolution 8 \
                --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let out = fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--time-step", "2", "-q"]);
    refused(
        &out,
        "run/windows/progress.json: cannot resume: the run being resumed has a different time step Δt (1, now 2",
    );
    assert!(report(&d.join("run"))["status"] == "finished", "the refused resume changed the run");
    // Other training settings were only warned of: the finished windows kept theirs, and the
    // config.json written recorded the new ones, which rerun to another result.
    let out = fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--rays-per-image", "32", "-q"]);
    refused(
        &out,
        "cannot resume: the run was trained with other settings (under `method.train`: `rays_per_image`: 16 → 32)",
    );
    ok(&fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--time-step", "1", "-q"]));
}

/// The safetensors file `path` rewritten without its metadata, as files were written before
/// windows were tagged.
fn strip_metadata(path: &std::path::Path) {
    let bytes = std::fs::read(path).expect("reads the weights");
    let len = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + len]).expect("header");
    assert!(header.as_object_mut().expect("object").remove("__metadata__").is_some(), "the file was tagged");
    let mut text = header.to_string().into_bytes();
    while !text.len().is_multiple_of(8) {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend(&bytes[8 + len..]);
    std::fs::write(path, out).expect("writes the weights");
}

/// One window's weights copied over another's (`windows/w000.safetensors` over `w001`) were
/// read by eval, export and render as that window's, and one frame's volume copied over
/// another's was scored as that frame's, without a word. Each window's weights now say which
/// window they are, and the report records each volume's digest: the copy is refused naming the
/// file and what it should hold. Files without them (runs written before) are read as before.
#[test]
fn a_window_or_frame_file_copied_over_another_is_refused_naming_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 3, 16, 12, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fast --window 2 --overlap 1 --max-iterations 2 --resolution 8 \
                --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let eval = ["eval", "run", "--json", "m.json", "--force"];
    let export = ["export", "run", "-o", "ex", "--npy", "--time", "15"];
    ok(&fluidnerf(d, &eval));
    let (w0, w1) = (d.join("run/windows/w000.safetensors"), d.join("run/windows/w001.safetensors"));
    let own = std::fs::read(&w1).expect("reads window 1");
    std::fs::copy(&w0, &w1).expect("copies window 0 over window 1");
    for args in [&eval[..], &export[..]] {
        let out = fluidnerf(d, args);
        refused(&out, "windows/w001.safetensors: holds the weights of window 0 (frames 0..2, t = 14, 15,");
        refused(&out, "but temporal.json lists this file as those of window 1 (frames 1..3, t = 15, 16,");
    }
    assert!(!d.join("ex").exists(), "exported the copy");
    // Restored, and then without its tag, as a run written before: read as before.
    std::fs::write(&w1, &own).expect("restores window 1");
    ok(&fluidnerf(d, &eval));
    strip_metadata(&w1);
    ok(&fluidnerf(d, &eval));

    // A frame's volume copied over another's, scored from the volumes.
    let (v0, v1) = (d.join("run/frames/volume_000.npy"), d.join("run/frames/volume_001.npy"));
    let by_volume = ["eval", "run", "--use-volume", "--json", "m.json", "--force"];
    ok(&fluidnerf(d, &by_volume));
    std::fs::copy(&v0, &v1).expect("copies frame 0 over frame 1");
    let out = fluidnerf(d, &by_volume);
    refused(&out, "frames/volume_001.npy: holds other values than the run wrote there (its report.json records the volume at t = 15");
    refused(&out, "it holds the run's volume frames/volume_000.npy at t = 14 (copied over?)");
    // A report without digests (written before) reads the files as before.
    edit_json(&d.join("run/report.json"), |v| {
        for volume in v["volumes"].as_array_mut().expect("volumes") {
            volume.as_object_mut().expect("object").remove("digest");
        }
    });
    ok(&fluidnerf(d, &by_volume));
}

/// A window that was still training when its run stopped continued past a lower
/// `--max-iterations` given with `--resume`: it kept its longer training while `config.json`
/// recorded the lower cap, so a rerun of that configuration gave another result. The resume is
/// now refused naming the checkpoint and its iteration, as a static run's is.
#[test]
fn a_window_resumed_below_its_checkpoints_iteration_is_refused_naming_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fluidnerf --preset tr-small --window 2 --overlap 1 \
                --max-iterations 4 --rays-per-image 16 --coarse-samples 8 --fine-samples 0 --resolution 8 \
                --checkpoint-every 1 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    // The process died after the second window's last checkpoint, before it was listed as finished.
    edit_json(&d.join("run/windows/progress.json"), |p| {
        p["finished"].as_array_mut().expect("a list").truncate(1);
    });
    let before = std::fs::read(d.join("run/config.json")).expect("config");
    let out = fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--max-iterations", "2", "-q"]);
    refused(&out, "stopping.max_iterations: ");
    refused(&out, "w001.checkpoint.safetensors (window 1, still training) is at iteration 4, beyond the cap of 2");
    refused(&out, "give --max-iterations of at least 4");
    assert!(std::fs::read(d.join("run/config.json")).expect("kept") == before, "the refused resume wrote");
    ok(&fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "-q"]));
    let windows = report(&d.join("run"))["windows"].clone();
    assert_eq!(windows[1]["train"]["iterations"], 4);
}

/// A finished run resumed with another `--max-iterations` read its windows back untrained and
/// wrote the new cap into `config.json`: the report said 2 iterations, the configuration 4, and
/// a rerun from it gave another result. Refused now, naming the window and the cap it used.
#[test]
fn a_finished_window_resumed_with_another_cap_is_refused_naming_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fast --window 2 --overlap 1 --max-iterations 2 --resolution 8 \
                --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let before = std::fs::read(d.join("run/config.json")).expect("config");
    for cap in ["4", "1"] {
        let out = fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--max-iterations", cap, "-q"]);
        refused(&out, "w000.checkpoint.safetensors (window 0, finished) stopped at its cap of 2 iterations");
        refused(
            &out,
            &format!("a cap of {cap} would be recorded for a run that did not use it; give --max-iterations 2"),
        );
        assert!(std::fs::read(d.join("run/config.json")).expect("kept") == before, "the refused resume wrote");
    }
    // The same cap resumes (there is nothing left to train).
    ok(&fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--max-iterations", "2", "-q"]));
    ok(&fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "-q"]));
}

/// A resumed run left the earlier run's series and scores in its folder: with a held-out time
/// dropped, `frames/volume_004.*` of the earlier run stayed beside the four volumes the resumed
/// run wrote (a glob of `frames/` handed `eval` five volumes, the last another run's), and
/// `metrics.json` went on scoring the earlier field. A resume now clears both before it writes.
#[test]
fn a_resumed_run_leaves_no_volume_or_score_of_the_run_it_continues() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fluidnerf --preset tr-small --max-iterations 2 \
                --rays-per-image 16 --coarse-samples 8 --fine-samples 0 --resolution 8 --checkpoint-every 0 -q \
                --holdout-times 14.5,15.5";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    assert!(d.join("run/frames/volume_004.npy").is_file());
    ok(&fluidnerf(d, &["eval", "run", "--no-reprojection", "-q"]));
    assert!(d.join("run/metrics.json").is_file());
    let out = fluidnerf(d, &["reconstruct", "-o", "run", "--resume", "--holdout-times", "14.5", "-q"]);
    ok(&out);
    let mut listed: Vec<String> = std::fs::read_dir(d.join("run/frames"))
        .expect("frames")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    listed.sort();
    let written: Vec<String> =
        (0..4).flat_map(|i| [format!("volume_{i:03}.npy"), format!("volume_{i:03}.vti")]).collect();
    assert_eq!(listed, written, "frames/ holds volumes the resumed run did not write");
    let times: Vec<f64> = report(&d.join("run"))["volumes"]
        .as_array()
        .expect("volumes")
        .iter()
        .map(|v| v["time"].as_f64().unwrap())
        .collect();
    assert_eq!(times, [14.0, 14.5, 15.0, 16.0]);
    assert!(!d.join("run/metrics.json").exists() && !d.join("run/metrics.csv").exists(), "the earlier scores stayed");
}

/// A run's frames given to `eval` out of order (`frames/volume_001.npy` before
/// `volume_000.npy`) were each scored against the other instant's truth, without a word. Each
/// frame's time is in the run's report: a frame given for another time step is now refused,
/// naming the file, both times and the order wanted.
#[test]
fn a_runs_frames_given_to_eval_out_of_order_are_refused_naming_the_times() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fluidnerf --preset tr-small --max-iterations 2 \
                --rays-per-image 16 --coarse-samples 8 --fine-samples 0 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let frames =
        |order: [usize; 3]| -> Vec<String> { order.iter().map(|i| format!("run/frames/volume_{i:03}.npy")).collect() };
    let eval = |files: Vec<String>| {
        let mut a = vec!["eval".to_string(), "--scene".into(), "scene".into(), "--no-reprojection".into()];
        a.extend(["--json".into(), "m.json".into(), "--force".into(), "-q".into()]);
        a.extend(files);
        fluidnerf(d, &a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    ok(&eval(frames([0, 1, 2])));
    let out = eval(frames([1, 0, 2]));
    refused(&out, "RECON run/frames/volume_001.npy: it was written at t = 15 (run/report.json)");
    refused(&out, "given as volume 1 of 3, for the time step at t = 14; the scene's time step 2 has that time");
    refused(&out, "in the order of the steps' times (14, 15, 16)");
    // The .vti files of the series are read the same way.
    let vti = vec![
        "run/frames/volume_000.vti".to_string(),
        "run/frames/volume_002.vti".into(),
        "run/frames/volume_001.vti".into(),
    ];
    refused(&eval(vti), "RECON run/frames/volume_002.vti: it was written at t = 16");
}

/// `eval RUN --use-volume` scored a time-resolved run's volumes by their place in the series,
/// not by their time: with the scene's truth listed latest first, the volume of t = 14 was
/// scored against the truth of t = 16, and a run with a volume at a held-out time the truth
/// does not have was refused as "4 reconstruction volumes given". Each step now gets the
/// run's volume at its own time, and the scores are those the run reported.
#[test]
fn a_runs_volumes_are_scored_at_their_own_times() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fluidnerf --preset tr-small --max-iterations 2 \
                --rays-per-image 16 --coarse-samples 8 --fine-samples 0 --resolution 8 --checkpoint-every 0 -q \
                --holdout-times 14.5";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let reported: Vec<(f64, f64)> = report(&d.join("run"))["volumes"]
        .as_array()
        .expect("volumes")
        .iter()
        .filter(|v| !v["metrics"].is_null())
        .map(|v| (v["time"].as_f64().unwrap(), v["metrics"]["global"]["nrmse"].as_f64().unwrap()))
        .collect();
    assert_eq!(reported.len(), 3, "{reported:?}");
    edit_json(&d.join("scene/transforms.json"), |s| s["truth"].as_array_mut().expect("truth").reverse());
    let out = fluidnerf(d, &["eval", "run", "--use-volume", "--no-reprojection", "--json", "m.json", "-q"]);
    ok(&out);
    let scored = json(&d.join("m.json"))["steps"].clone();
    for (step, time) in scored.as_array().expect("steps").iter().zip([16.0, 15.0, 14.0]) {
        assert_eq!(step["time"].as_f64(), Some(time));
        let (_, nrmse) = reported.iter().find(|(t, _)| *t == time).expect("reported");
        let got = step["global"]["nrmse"].as_f64().expect("nrmse");
        assert!((got - nrmse).abs() < 1e-6, "t = {time}: scored {got}, the run reported {nrmse}");
    }
}

/// A time-resolved field driven to zero by its learning rate is reported, as a static one is.
#[test]
fn a_series_driven_to_zero_by_its_learning_rate_is_reported() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 3, 16, 12, &["--times", "14,15"]);
    let args = "reconstruct scene -o run --method tr-fast --max-iterations 30 --resolution 12 --checkpoint-every 0 \
                --learning-rate 1 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let r = report(&d.join("run"));
    let warned = r["warnings"].as_array().expect("warnings").iter().any(|w| {
        w.as_str().is_some_and(|w| w.contains("the reconstruction is empty") && w.contains("--learning-rate"))
    });
    assert!(warned, "{r}");
}

/// A static run on a scene of several times listed its held-out camera once per time under one
/// name, with nothing to tell the lines apart; each now says its time, as do the gains.
#[test]
fn held_out_scores_of_a_scene_of_several_times_say_their_time() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15", "--holdout", "3"]);
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "asart", "--resolution", "8"]);
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let held: Vec<&str> = stdout.lines().filter(|l| l.starts_with("held-out ")).collect();
    assert_eq!(held.len(), 2, "{stdout}");
    assert!(held[0].starts_with("held-out cam003 at t = 14: ") && held[1].starts_with("held-out cam003 at t = 15: "));
    let frames = report(&d.join("run"))["preprocessing"]["frames"].clone();
    assert_eq!(frames[0]["time"], 14.0);
}

/// A time-resolved field rendered through the cameras of a scene whose frames hold no time is
/// drawn at one instant, which render.json recorded as null; views at several instants record
/// none, each being its frame's.
#[test]
fn render_json_records_the_one_instant_its_views_show() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15"]);
    let args = "reconstruct scene -o run --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    // The first instant's frames without their times: a static scene of the same cameras.
    let fixed = d.join("fixed");
    std::fs::create_dir_all(&fixed).expect("mkdir");
    let mut t = json(&d.join("scene/transforms.json"));
    let frames: Vec<serde_json::Value> = t["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .filter(|f| f["time"] == 14.0)
        .map(|f| {
            let mut f = f.clone();
            f.as_object_mut().expect("object").remove("time");
            f["file_path"] = format!("../scene/{}", f["file_path"].as_str().expect("path")).into();
            f
        })
        .collect();
    t["frames"] = frames.into();
    t.as_object_mut().expect("object").remove("truth");
    std::fs::write(fixed.join("transforms.json"), t.to_string()).expect("writes");
    ok(&fluidnerf(d, &["render", "run", "--scene", "fixed", "-o", "still", "-q"]));
    assert_eq!(json(&d.join("still/render.json"))["time"], 14.0);
    ok(&fluidnerf(d, &["render", "run", "--scene", "scene", "-o", "both", "-q"]));
    assert_eq!(json(&d.join("both/render.json"))["time"], serde_json::Value::Null);
    // The frames rendered, every one when none was named (the list read empty, as if none were).
    assert_eq!(json(&d.join("both/render.json"))["cameras"], serde_json::json!([0, 1, 2, 3, 4, 5, 6, 7]));
}

/// The volume NRMSE at each time, of `eval`'s `m.json` in `dir` and of the run's report.
fn eval_and_report_nrmse(dir: &std::path::Path, run: &str) -> (Vec<f64>, Vec<f64>) {
    let nrmse = |v: &serde_json::Value| v["global"]["nrmse"].as_f64().expect("nrmse");
    let scored = json(&dir.join("m.json"))["steps"].as_array().expect("steps").iter().map(nrmse).collect();
    let volumes = report(&dir.join(run))["volumes"].clone();
    let reported = volumes.as_array().expect("volumes").iter().map(|v| nrmse(&v["metrics"])).collect();
    (scored, reported)
}

/// A time held out at an end of the recording: `reconstruct` wrote and scored its volume with
/// the field held at the nearest trained instant, and then `eval`, `render` and `export` refused
/// the whole run ("time 16 lies outside the run's instants 14 … 15"). They now sample it as the
/// run did, say so, and eval's scores are the report's.
#[test]
fn a_time_held_out_at_an_end_is_read_as_the_run_scored_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fast --holdout-times 16 --max-iterations 4 --resolution 8 \
                --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let out = fluidnerf(d, &["eval", "run", "--no-regions", "--json", "m.json"]);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stderr).contains("t = 16 held out at an end of the recording"));
    let (scored, reported) = eval_and_report_nrmse(d, "run");
    assert_eq!(scored.len(), 3);
    for (s, r) in scored.iter().zip(&reported) {
        assert!((s - r).abs() <= 1e-6 * r, "eval {scored:?}, report {reported:?}");
    }
    ok(&fluidnerf(d, &["render", "run", "-o", "views", "-q"]));
    ok(&fluidnerf(d, &["export", "run", "-o", "ex", "--npy", "--time", "16", "--resolution", "8", "-q"]));
    let exported = std::fs::read(d.join("ex/volume.npy")).expect("exported");
    assert!(exported == std::fs::read(d.join("run/frames/volume_002.npy")).expect("the run's"), "another volume");
    // A time outside that was not held out is still refused.
    refused(&fluidnerf(d, &["export", "run", "-o", "ex2", "--npy", "--time", "17"]), "lies outside");
}

/// Volumes exported at each instant (`export --time`) and given to `eval` in another order were
/// scored against other instants' truth without a word, though each `export.json` records its
/// time. They are refused as a run's own frames given out of order are.
#[test]
fn exported_instants_given_to_eval_out_of_order_are_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    for t in ["14", "15", "16"] {
        ok(&fluidnerf(d, &["export", "run", "-o", &format!("ex{t}"), "--npy", "--time", t, "-q"]));
    }
    let eval = |order: [&str; 3]| {
        let mut a = vec!["eval", "-s", "scene", "--no-reprojection", "--json", "m.json", "--force", "-q"];
        let files: Vec<String> = order.iter().map(|t| format!("ex{t}/volume.npy")).collect();
        a.extend(files.iter().map(String::as_str));
        fluidnerf(d, &a)
    };
    ok(&eval(["14", "15", "16"]));
    let out = eval(["16", "15", "14"]);
    refused(&out, "RECON ex16/volume.npy: it was written at t = 16 (ex16/export.json)");
    refused(&out, "given as volume 1 of 3, for the time step at t = 14; the scene's time step 3 has that time");
}

/// A render of a time-resolved field's scene views at several instants recorded `"time": null`
/// and not the instant of each view; one volume rendered through cameras of several instants
/// showed the same field in every view without a word.
#[test]
fn render_records_each_views_instant_and_warns_of_one_volume_for_several() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 2, 16, 8, &["--times", "14,15"]);
    let args = "reconstruct scene -o run --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    ok(&fluidnerf(d, &["render", "run", "-o", "views", "-q"]));
    let settings = json(&d.join("views/render.json"));
    let frames = json(&d.join("scene/transforms.json"))["frames"].clone();
    let times: Vec<f64> = frames.as_array().expect("frames").iter().map(|f| f["time"].as_f64().expect("t")).collect();
    assert_eq!(settings["time"], serde_json::Value::Null);
    assert_eq!(settings["times"], serde_json::json!(times));
    // A frame of the run holds one instant, and says which views are of another.
    let out = fluidnerf(d, &["render", "run/frames/volume_000.npy", "-s", "scene", "-o", "one"]);
    ok(&out);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("holds the field at t = 14 (run/report.json), but views asked are of frames at t = 15"),
        "{err}"
    );
    assert!(json(&d.join("one/render.json")).get("times").is_none());
    // A volume of no recorded instant.
    std::fs::copy(d.join("run/frames/volume_000.npy"), d.join("loose.npy")).expect("copy");
    let out = fluidnerf(d, &["render", "loose.npy", "-s", "scene", "-o", "two"]);
    ok(&out);
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("is fixed in time, but the views asked are of frames at several")
    );
}

/// `--window-index` given to a folder holding a run of other settings was checked against this
/// command's plan first: "the run has 1 window(s)" for a folder whose run has two. The folder's
/// other settings are now named first, as they are for an index in range.
#[test]
fn a_window_index_for_a_folder_of_other_settings_names_the_settings() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fast --window 2 --overlap 1 --max-iterations 2 --resolution 8 \
                --checkpoint-every 0 --window-index 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "tr-fast", "--window-index", "1"]);
    refused(&out, "run/config.json: holds a run with other settings (");
    refused(&out, "`method.windows.frames`: 2 → 16");
}

/// A run's frame exported again (`export RUN/frames/volume_002.vti`) lost its instant, and a
/// copied `.vti` never had one: `eval` then scored it against another instant's truth without a
/// word, and one such volume against every instant's. A frame's `.vti` and raw sidecar now
/// record their instant, `export` and `render` carry it on, and `eval` scores a volume of one
/// instant at that instant alone.
#[test]
fn a_volumes_instant_goes_with_it_through_export_render_and_eval() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    assert_eq!(fluidnerf_io::volume::vti_time(&d.join("run/frames/volume_002.vti")), Some(16.0));
    ok(&fluidnerf(d, &["export", "run/frames/volume_002.vti", "-o", "x2", "--vti", "--raw", "-q"]));
    assert_eq!(json(&d.join("x2/export.json"))["time"], 16.0);
    assert_eq!(fluidnerf_io::volume::vti_time(&d.join("x2/volume.vti")), Some(16.0));
    assert_eq!(fluidnerf_io::volume::raw_time(&d.join("x2/volume.raw")), Some(16.0));
    // Copied away from export.json, the file still says its instant.
    std::fs::create_dir(d.join("loose")).expect("mkdir");
    std::fs::copy(d.join("x2/volume.vti"), d.join("loose/t16.vti")).expect("copy");
    let eval = |files: &[&str]| {
        let mut a = vec!["eval", "-s", "scene", "--no-reprojection", "--no-regions", "--json", "m.json", "--force"];
        a.extend(files);
        fluidnerf(d, &a)
    };
    refused(
        &eval(&["run/frames/volume_000.npy", "loose/t16.vti", "run/frames/volume_002.npy"]),
        "RECON loose/t16.vti: it was written at t = 16 (its TimeValue field data), but it is given as volume 2 of 3",
    );
    // Alone, it is scored at its own instant, as the run scored it there.
    ok(&eval(&["loose/t16.vti"]));
    let steps = json(&d.join("m.json"))["steps"].clone();
    let steps = steps.as_array().expect("steps");
    assert_eq!(steps.len(), 1, "scored at one instant, not at each of three");
    assert_eq!(steps[0]["time"], 16.0);
    let reported = report(&d.join("run"))["volumes"][2]["metrics"]["global"]["nrmse"].as_f64().expect("nrmse");
    let scored = steps[0]["global"]["nrmse"].as_f64().expect("nrmse");
    assert!((scored - reported).abs() <= 1e-6 * reported, "{scored} against the report's {reported}");
    // A render records it, and warns of cameras of other instants.
    let out = fluidnerf(d, &["render", "loose/t16.vti", "--scene", "scene", "-o", "views"]);
    ok(&out);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(
            "holds the field at t = 16 (its TimeValue field data), but views asked are of frames at t = 14, 15"
        ),
        "{err}"
    );
    assert_eq!(json(&d.join("views/render.json"))["time"], 16.0);
}

/// `export RUN --compare TRUTH` drew the truth of one instant beside the field of another (the
/// run's first, `--time`'s default), and `eval VOLUME --truth TRUTH` scored a frame against
/// another instant's truth, both without a word. The scene lists each truth's instant: another
/// than the reconstruction's is refused.
#[test]
fn a_truth_of_another_instant_is_refused_beside_a_reconstruction() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16"]);
    let args = "reconstruct scene -o run --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    let export = |extra: &[&str]| {
        let mut a = vec!["export", "run", "-o", "cmp", "--slices", "x=0.5", "--resolution", "8", "--force", "-q"];
        a.extend(extra);
        fluidnerf(d, &a)
    };
    refused(
        &export(&["--compare", "scene/truth/truth_t02.npy"]),
        "--compare scene/truth/truth_t02.npy: the truth is at t = 16 (the scene lists it at that time), but the \
         reconstruction is at t = 14 (the run's first instant, --time's default)",
    );
    ok(&export(&["--compare", "scene/truth/truth_t02.npy", "--time", "16"]));
    let eval = |truth: &str| {
        let a = ["eval", "-s", "scene", "run/frames/volume_000.npy", "--truth", truth, "--no-reprojection", "--force"];
        fluidnerf(d, &[&a[..], &["--json", "m.json", "-q"]].concat())
    };
    refused(&eval("scene/truth/truth_t02.npy"), "the reconstruction is at t = 14 (run/report.json records it");
    ok(&eval("scene/truth/truth_t00.npy"));
}

/// `--eval-every` was recorded by time-resolved runs and never acted (they score their frames
/// once, at the end), and `compare` then gave their whole run's time as the time to an accuracy
/// with no note that it had one point to go by.
#[test]
fn eval_every_is_refused_for_time_resolved_runs_and_compare_notes_a_single_point() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15"]);
    let args = "reconstruct scene --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    let args: Vec<&str> = args.split_whitespace().collect();
    refused(
        &fluidnerf(d, &[&args[..], &["-o", "run", "--eval-every", "1"]].concat()),
        "time-resolved runs score their frames once, at the end",
    );
    let out = fluidnerf(d, &[&args[..], &["-o", "run", "--eval-every", "0"]].concat());
    ok(&out);
    // What the run wrote is named, its frames too (it named config.json and the reports alone).
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains(
            "wrote run (config.json, report.json, report.html, temporal.json, volumes.pvd, frames/ (2 volumes"
        ),
        "{text}"
    );
    ok(&fluidnerf(d, &[&args[..], &["-o", "run2", "--seed", "1"]].concat()));
    let out = fluidnerf(d, &["compare", "run", "run2", "-o", "cmp", "-q"]);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("scored its NRMSE once, at its end"), "{text}");
    let warnings = json(&d.join("cmp/compare.json"))["warnings"].to_string();
    assert!(warnings.contains("scored its NRMSE once"), "{warnings}");
}

/// With several volumes, a held-out frame at an instant none of them holds was drawn from the
/// volume of the nearest step and scored against another instant's field without a word. A
/// run's volumes hold every instant it wrote, so `--use-volume` draws each frame from its own;
/// volume files of other instants are refused for it.
#[test]
fn held_out_frames_are_drawn_from_the_volume_of_their_own_instant() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "jet-tr", 4, 16, 8, &["--times", "14,15,16", "--holdout", "3"]);
    let args = "reconstruct scene -o run --method tr-fast --max-iterations 2 --resolution 8 --checkpoint-every 0 -q";
    ok(&fluidnerf(d, &args.split_whitespace().collect::<Vec<_>>()));
    // The scene's truth at t = 14 and 16 only: its held-out frame at 15 has no truth step.
    edit_json(&d.join("scene/transforms.json"), |t| {
        let truth = t["truth"].as_array_mut().expect("truth");
        truth.retain(|e| e["time"] != 15.0);
    });
    let eval = |recon: &[&str]| {
        let mut a = vec!["eval", "-s", "scene", "--no-regions", "--json", "m.json", "--force"];
        a.extend(recon);
        fluidnerf(d, &a)
    };
    refused(
        &eval(&["run/frames/volume_000.npy", "run/frames/volume_002.npy"]),
        "is at t = 15, and no volume given is of that instant (they are of t = 14, 16)",
    );
    ok(&eval(&["run/frames/volume_000.npy", "run/frames/volume_002.npy", "--no-reprojection"]));
    ok(&eval(&["run", "--use-volume"]));
    let through_run = json(&d.join("m.json"))["reprojection"].clone();
    // The volume of t = 15 alone, scored against that instant's truth file.
    ok(&eval(&["run/frames/volume_001.npy", "--truth", "scene/truth/truth_t01.npy"]));
    let through_frame = json(&d.join("m.json"))["reprojection"].clone();
    let row_at_15 = |r: &serde_json::Value| {
        r.as_array().expect("rows").iter().find(|row| row["time"] == 15.0).expect("a frame at 15")["nrmse"].clone()
    };
    assert_eq!(row_at_15(&through_run), row_at_15(&through_frame), "drawn from the volume of t = 15");
    // One volume of one instant is reprojected onto that instant's held-out frames alone.
    let rows = through_frame.as_array().expect("rows");
    assert!(!rows.is_empty() && rows.iter().all(|row| row["time"] == 15.0), "{through_frame}");
    let out = eval(&["run/frames/volume_001.npy", "--truth", "scene/truth/truth_t01.npy"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("holds the field at t = 15: the held-out frames of other instants are not reprojected"),
        "{err}"
    );
    // Against a truth listed without a time, it is scored as against a steady flow's, and said so.
    edit_json(&d.join("scene/transforms.json"), |t| {
        t["truth"] = serde_json::json!([{"file_path": "truth/truth_t01.npy"}])
    });
    let out = eval(&["run/frames/volume_001.npy", "--no-reprojection"]);
    ok(&out);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("and the scene's ground truth has no time: it is scored against it as against a steady flow's"),
        "{err}"
    );
}
