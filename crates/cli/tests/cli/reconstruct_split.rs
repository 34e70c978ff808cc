//! `fluidnerf reconstruct --window-index K | --frames A..B | --finish`: a time-resolved run
//! split over separate processes (as a job array would) ends with exactly the run in one
//! piece; windows are idempotent, warm starts wait for their window, and misuse is refused
//! with the file or setting named.

use crate::common;
use common::*;

fn split_scene(d: &std::path::Path) {
    ok(&fluidnerf(
        d,
        &[
            "synth",
            "-q",
            "--preset",
            "jet-tr60",
            "--cameras",
            "5",
            "--pixels",
            "16",
            "--resolution",
            "12",
            "--model",
            "pinhole",
            "--times",
            "14,14.5,15,15.5,16",
            "-o",
            "scene",
        ],
    ));
}

/// Settings of every run below: tr-fast in windows of 2 frames overlapping by 1 (4 windows over
/// 5 frames); [`reconstruct_warm`] warm-starts them, which tr-fast does not by default.
const RUN: [&str; 15] = [
    "--method",
    "tr-fast",
    "--resolution",
    "10",
    "--max-iterations",
    "8",
    "--window",
    "2",
    "--overlap",
    "1",
    "--rays-per-image",
    "48",
    "--coarse-samples",
    "12",
    "-q",
];

fn reconstruct(d: &std::path::Path, out: &str, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["reconstruct", "scene", "-o", out];
    args.extend(RUN);
    args.extend(extra);
    fluidnerf(d, &args)
}

/// [`reconstruct`] with every window started from the previous one's field.
fn reconstruct_warm(d: &std::path::Path, out: &str, extra: &[&str]) -> std::process::Output {
    reconstruct(d, out, &[&["--no-warm-start", "false"][..], extra].concat())
}

fn stderr(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn windows_run_separately_and_finished_equal_the_run_in_one_piece() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    split_scene(d);
    ok(&reconstruct_warm(d, "serial", &[]));

    // Window 1 warm-starts from window 0, which has not run: refused, naming the checkpoint.
    let out = reconstruct_warm(d, "split", &["--window-index", "1"]);
    assert!(!out.status.success());
    let e = stderr(&out);
    assert!(
        e.contains("w000.checkpoint.safetensors") && e.contains("window 1 starts from the field of window 0"),
        "{e}"
    );

    // Finishing before every window is done names the missing ones.
    ok(&reconstruct_warm(d, "split", &["--window-index", "0"]));
    let out = fluidnerf(d, &["reconstruct", "--finish", "-o", "split", "-q"]);
    assert!(!out.status.success());
    let e = stderr(&out);
    assert!(e.contains("window(s) 1, 2, 3 of 4 have not finished") && e.contains("w001.done.json"), "{e}");

    // Window 1 does not warm-start from a window trained on other images: one pixel of an
    // image of window 0 changed, it is refused, naming window 0's checkpoint.
    let image = d.join("scene/images/cam000_t00.png");
    let bytes = std::fs::read(&image).expect("reads the image");
    let mut pixels = image::load_from_memory(&bytes).expect("decodes").to_luma16();
    let (w, h) = pixels.dimensions();
    pixels.get_pixel_mut(w / 2, h / 2).0[0] ^= 0x0100;
    pixels.save(&image).expect("writes the image");
    let out = reconstruct_warm(d, "split", &["--window-index", "1"]);
    let e = stderr(&out);
    assert!(
        !out.status.success() && e.contains("w000.checkpoint.safetensors") && e.contains("other images or cameras"),
        "{e}"
    );
    assert!(!d.join("split/windows/w001.checkpoint.safetensors").exists(), "the refused window trained");
    std::fs::write(&image, &bytes).expect("restores the image");

    // Frames 1..5 hold windows 1, 2 and 3; window 0 is done, so they run in order.
    let out = reconstruct_warm(d, "split", &["--frames", "1..5"]);
    ok(&out);
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(text.matches(": trained,").count(), 3, "{text}");
    // Run again, a window is read back, not trained.
    let out = reconstruct_warm(d, "split", &["--window-index", "2"]);
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("finished earlier"));
    for k in 0..4 {
        assert!(d.join(format!("split/windows/w{k:03}.done.json")).is_file());
    }

    // --finish takes the settings from the run folder and writes what the serial run wrote.
    ok(&fluidnerf(d, &["reconstruct", "--finish", "-o", "split", "-q"]));
    for i in 0..5 {
        let name = format!("frames/volume_{i:03}.npy");
        let (a, b) = (std::fs::read(d.join("serial").join(&name)), std::fs::read(d.join("split").join(&name)));
        assert_eq!(a.expect("serial volume"), b.expect("split volume"), "{name} differs");
    }
    let (a, b) = (report(&d.join("serial")), report(&d.join("split")));
    assert_eq!(a["history"]["loss"], b["history"]["loss"]);
    assert_eq!(a["windows"].as_array().map(Vec::len), Some(4));
    assert_eq!(a["final_nrmse"], b["final_nrmse"]);
    assert_eq!(
        std::fs::read_to_string(d.join("serial/volumes.pvd")).expect("pvd"),
        std::fs::read_to_string(d.join("split/volumes.pvd")).expect("pvd")
    );
    // A finished run takes no more windows.
    let out = reconstruct_warm(d, "split", &["--window-index", "0"]);
    assert!(!out.status.success() && stderr(&out).contains("already holds a finished run"), "{}", stderr(&out));
    // Nor does a run in one piece stopped by Ctrl-C, which wrote its report: it is continued with
    // --resume, which the refusal says (it called the run finished, and said to remove it).
    edit_json(&d.join("serial/report.json"), |v| v["status"] = "interrupted".into());
    let out = reconstruct_warm(d, "serial", &["--window-index", "0"]);
    let e = stderr(&out);
    assert!(!out.status.success() && e.contains("serial: holds a run that was interrupted"), "{e}");
    assert!(e.contains("reconstruct --resume") && !e.contains("finished run"), "{e}");
}

#[test]
fn independent_windows_run_in_any_order_and_misuse_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    split_scene(d);
    // Without warm starts every window stands alone: the last one first is fine. tr-fast's
    // windows are not warm-started by default, so the serial run without the switch is the
    // split run with it.
    ok(&reconstruct(d, "serial", &[]));
    for k in ["3", "1", "0", "2"] {
        ok(&reconstruct(d, "split", &["--no-warm-start", "--window-index", k]));
    }
    ok(&fluidnerf(d, &["reconstruct", "--finish", "-o", "split", "-q"]));
    for i in 0..5 {
        let name = format!("frames/volume_{i:03}.npy");
        assert_eq!(std::fs::read(d.join("serial").join(&name)).ok(), std::fs::read(d.join("split").join(&name)).ok());
    }

    // Other settings in the same folder would mix two runs.
    let out = fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "other",
            "--method",
            "tr-fast",
            "--window",
            "2",
            "--overlap",
            "1",
            "--max-iterations",
            "2",
            "--resolution",
            "10",
            "--window-index",
            "0",
            "-q",
        ],
    );
    ok(&out);
    let out = fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "other",
            "--method",
            "tr-fast",
            "--window",
            "2",
            "--overlap",
            "1",
            "--max-iterations",
            "3",
            "--resolution",
            "10",
            "--window-index",
            "1",
            "-q",
        ],
    );
    let err = stderr(&out);
    assert!(!out.status.success() && err.contains("other settings (`stopping.max_iterations`: 2 → 3)"), "{err}");
    // An index beyond the plan, a frame range holding no window, a static method.
    let out = reconstruct(d, "x", &["--window-index", "4"]);
    let err = stderr(&out);
    assert!(
        !out.status.success() && err.contains("--window-index 4: the run has 4 window(s), numbered 0 to 3"),
        "{err}"
    );
    let out = reconstruct(d, "x", &["--frames", "0..1"]);
    assert!(!out.status.success() && stderr(&out).contains("no window lies inside frames 0..1"), "{}", stderr(&out));
    let out = reconstruct(d, "x", &["--frames", "3..2"]);
    assert!(!out.status.success() && stderr(&out).contains("the range is empty"), "{}", stderr(&out));
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "y", "--method", "asart", "--window-index", "0"]);
    assert!(!out.status.success() && stderr(&out).contains("--window-index does not apply to --method asart"));
    // An overlap without windows to overlap was recorded and ignored without a word.
    let out =
        fluidnerf(d, &["reconstruct", "scene", "-o", "z", "--method", "tr-fast", "--window", "0", "--overlap", "1"]);
    assert!(!out.status.success() && stderr(&out).contains("no windows to overlap"), "{}", stderr(&out));
    assert!(!d.join("z").exists(), "a refused run wrote");
    // Nor with windows that hold every frame of the scene (5) in one, in one piece or split.
    for split in [&[][..], &["--window-index", "0"]] {
        let args = ["reconstruct", "scene", "-o", "z", "--method", "tr-fast", "--window", "5", "--overlap", "2"];
        let out = fluidnerf(d, &[&args[..], split].concat());
        let e = stderr(&out);
        assert!(
            !out.status.success()
                && e.contains("--overlap 2: windows of 5 frames hold all 5 training frames of the scene in one window")
                && e.contains("give --window below 5"),
            "{e}"
        );
        assert!(!d.join("z").exists(), "a refused run wrote");
    }
    // A --window shorter than the preset's overlap (tr-fast: 4 frames) says where the overlap
    // came from and what to give.
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "z", "--method", "tr-fast", "--window", "3"]);
    let e = stderr(&out);
    assert!(
        !out.status.success()
            && e.contains(
                "--window on the command line: method.windows.overlap: windows of 3 frames would overlap by 4 frames \
                 (the preset's overlap, as --overlap is not given)"
            )
            && e.contains("give --overlap below 3 with --window 3"),
        "{e}"
    );
    assert!(!d.join("z").exists(), "a refused run wrote");
    // Nor does a time step apply to static fields, one per frame.
    let out = fluidnerf(d, &["reconstruct", "scene", "-o", "z", "--method", "static-per-frame", "--time-step", "0.5"]);
    let e = stderr(&out);
    assert!(!out.status.success() && e.contains("--time-step does not apply to --method static-per-frame"), "{e}");
    assert!(!d.join("z").exists(), "a refused run wrote");
}

/// A window's done file names the checkpoint of its final state: one naming another window's
/// (or another run's) would have that state stitched in as this window. It was refused only
/// when the views differed, and then blamed on the scene's images; another run's of the same
/// views was taken. It is refused naming the done file and both checkpoints.
#[test]
fn a_done_file_naming_another_checkpoint_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    split_scene(d);
    for k in ["0", "1", "2", "3"] {
        ok(&reconstruct_warm(d, "w", &["--window-index", k]));
    }
    let done = d.join("w/windows/w001.done.json");
    let original = std::fs::read(&done).expect("done file");
    let copy = d.join("copy");
    std::fs::create_dir_all(copy.join("windows")).expect("mkdir");
    std::fs::copy(d.join("w/windows/w001.checkpoint.safetensors"), copy.join("windows/w001.checkpoint.safetensors"))
        .expect("copies");
    let elsewhere = copy.join("windows/w001.checkpoint.safetensors").to_str().expect("UTF-8").to_string();
    for other in ["windows/w000.checkpoint.safetensors", &elsewhere] {
        edit_json(&done, |v| v["checkpoint"] = other.into());
        let out = fluidnerf(d, &["reconstruct", "--finish", "-o", "w", "-q"]);
        refused(
            &out,
            &format!(
                "w/windows/w001.done.json: window 1 is recorded as finished with the checkpoint {other}, but a \
                 window's final state is its own windows/w001.checkpoint.safetensors"
            ),
        );
        assert!(!d.join("w/report.json").exists(), "finished with {other}");
        std::fs::write(&done, &original).expect("restores the done file");
    }
    // A negative time or loss would be summed into the run's report as measured.
    for key in ["train_time_s", "final_loss"] {
        edit_json(&done, |v| v["report"][key] = (-5.0).into());
        let out = fluidnerf(d, &["reconstruct", "--finish", "-o", "w", "-q"]);
        refused(
            &out,
            &format!(
                "w/windows/w001.done.json: window 1 is recorded as finished with report.{key} -5, which no run writes"
            ),
        );
        assert!(!d.join("w/report.json").exists(), "finished with a negative {key}");
        std::fs::write(&done, &original).expect("restores the done file");
    }
    ok(&fluidnerf(d, &["reconstruct", "--finish", "-o", "w", "-q"]));
}

#[test]
fn an_unfinished_split_run_is_named_as_such_by_export_render_and_eval() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    split_scene(d);
    ok(&reconstruct(d, "split", &["--no-warm-start", "--window-index", "0"]));
    for args in
        [&["export", "split", "-o", "out", "-q"][..], &["render", "split", "-o", "out", "-q"], &["eval", "split", "-q"]]
    {
        let out = fluidnerf(d, args);
        refused(&out, "split: holds a time-resolved run that is not finished");
        assert!(stderr(&out).contains("--finish -o split"), "{args:?}: {}", stderr(&out));
    }
}
