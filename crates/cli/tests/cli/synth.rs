//! End-to-end tests of `fluidnerf synth`: a small data set is written, reads back as a scene
//! whose images match its recorded intensity scale, reruns from its `synth.json` to the same
//! bytes, and bad settings fail before any work with a clear message.

use std::path::Path;
use std::process::{Command, Output};

fn synth(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf")).arg("synth").args(args).output().expect("runs fluidnerf")
}

/// `synth -q -o out --config config`: a scene made again from a saved synth.json.
fn synth_from(out: &Path, config: &Path) -> Output {
    synth(&["-q", "-o", out.to_str().expect("utf-8"), "--config", config.to_str().expect("utf-8")])
}

fn text(o: &Output) -> (String, String) {
    (String::from_utf8_lossy(&o.stdout).into_owned(), String::from_utf8_lossy(&o.stderr).into_owned())
}

/// A tiny data set: 5 cameras of 24² px around a 24³ jet, camera 4 held out.
const SMALL: &[&str] =
    &["--preset", "demo", "--cameras", "5", "--pixels", "24", "--resolution", "24", "--holdout", "4", "--seed", "3"];

fn run_small(dir: &Path, extra: &[&str]) -> Output {
    let mut args: Vec<&str> = vec!["-q", "-o", dir.to_str().expect("utf-8 path")];
    args.extend_from_slice(SMALL);
    args.extend_from_slice(extra);
    synth(&args)
}

/// [`run_small`] imaging the truth volume `truth` (on its own grid, so without `--resolution`).
fn run_small_volume(dir: &Path, truth: &Path, extra: &[&str]) -> Output {
    let mut args: Vec<&str> = vec!["-q", "-o", dir.to_str().expect("utf-8 path")];
    let at = SMALL.iter().position(|&a| a == "--resolution").expect("SMALL gives a resolution");
    args.extend(SMALL[..at].iter().chain(&SMALL[at + 2..]));
    args.extend(["--truth-volume", truth.to_str().expect("utf-8 path")]);
    args.extend_from_slice(extra);
    synth(&args)
}

#[test]
fn writes_a_scene_that_reads_back() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("set");
    let o = run_small(&dir, &["--noise", "0.02"]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "stdout: {out}\nstderr: {err}");
    assert!(out.contains("cameras   5 (1 held out)"), "{out}");
    for f in
        ["transforms.json", "preview.png", "synth.json", "truth/truth.npy", "images/cam000.png", "images/cam004.png"]
    {
        assert!(dir.join(f).is_file(), "missing {f}");
    }
    let scene = fluidnerf_io::scene::load_scene(&dir).expect("scene reads back");
    assert_eq!(scene.frames.len(), 5);
    assert!(scene.frames[4].holdout && !scene.frames[0].holdout);
    assert_eq!(scene.units, "mm");
    let recorded = fluidnerf_io::scene::recorded(&scene).expect("recording").flow_axis;
    assert_eq!(recorded.map(|a| a.to_array()), Some([1.0, 0.0, 0.0]), "the jet's flow axis is recorded");
    let images = fluidnerf_io::scene::load_images(&scene).expect("images read back");
    let peak = images.iter().map(|i| i.min_max().1).fold(0.0f32, f32::max);
    // Brightest noiseless pixel at 80 % of 16-bit full scale, plus a little noise.
    assert!(peak > 0.7 * 65535.0 && peak < 0.95 * 65535.0, "peak {peak}");
    let truth = fluidnerf_io::scene::load_truth(&scene).expect("truth reads back");
    assert_eq!(truth[0].1.dims, [24, 24, 24]);
    let (lo, hi) = truth[0].1.min_max();
    assert!(lo >= 0.0 && hi <= 1.0 && hi > 0.9, "jet values in [0, 1], got [{lo}, {hi}]");

    // The same settings, rerun from synth.json, give the same bytes.
    let again = tmp.path().join("again");
    let o = synth_from(&again, &dir.join("synth.json"));
    assert!(o.status.success(), "{:?}", text(&o));
    for f in ["images/cam002.png", "truth/truth.npy", "transforms.json"] {
        assert_eq!(
            std::fs::read(dir.join(f)).expect("read"),
            std::fs::read(again.join(f)).expect("read"),
            "{f} differs"
        );
    }
    // A value of the wrong type in a saved configuration is named by its key in the file.
    let record = std::fs::read_to_string(dir.join("synth.json")).expect("read");
    let mut v: serde_json::Value = serde_json::from_str(&record).expect("json");
    v["settings"]["rig"]["subset"]["every"] = "2".into();
    let (bad, unused) = (tmp.path().join("bad.json"), tmp.path().join("unused"));
    let bad_config = ["-q", "-o", unused.to_str().expect("utf-8"), "--config", bad.to_str().expect("utf-8")];
    std::fs::write(&bad, v.to_string()).expect("writes");
    let o = synth(&bad_config);
    let err = text(&o).1;
    assert!(!o.status.success() && err.contains("bad.json: not a valid synth configuration"), "{err}");
    assert!(err.contains("at `settings.rig.subset.every`: invalid type: string \"2\", expected usize"), "{err}");
    std::fs::write(&bad, v["settings"].to_string()).expect("writes");
    let o = synth(&bad_config);
    assert!(text(&o).1.contains("at `rig.subset.every`"), "the settings alone: {}", text(&o).1);
    // Another fluidnerf file is named for what it is, not by its first unknown key.
    std::fs::write(&bad, r#"{"format": 1, "scene": "s", "method": {"name": "asart"}, "seed": 0}"#).expect("writes");
    let o = synth(&bad_config);
    assert!(
        text(&o).1.contains("bad.json: is a run's configuration (config.json), not the settings"),
        "{:?}",
        text(&o)
    );
    // And a synth.json given to reconstruct, which names its key too.
    let o = Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .args(["reconstruct", "--config", dir.join("synth.json").to_str().expect("utf-8"), "-o"])
        .arg(&unused)
        .output()
        .expect("runs");
    let err = text(&o).1;
    assert!(
        err.contains("synth.json: is the settings of a synthetic scene (synth.json), not a run's configuration"),
        "{err}"
    );
    assert!(!unused.exists());

    // Another seed changes the noise.
    let other = tmp.path().join("other");
    let o = run_small(&other, &["--noise", "0.02", "--seed", "4"]);
    assert!(o.status.success(), "{:?}", text(&o));
    assert_ne!(
        std::fs::read(dir.join("images/cam002.png")).expect("read"),
        std::fs::read(other.join("images/cam002.png")).expect("read")
    );

    // An existing scene is not overwritten without --force.
    let o = run_small(&dir, &[]);
    assert!(!o.status.success());
    assert!(text(&o).1.contains("--force"), "{:?}", text(&o));
    assert!(run_small(&dir, &["--force"]).status.success());
    // Nor are a user's files in a folder without a scene.
    let mine = tmp.path().join("mine");
    std::fs::create_dir_all(mine.join("images")).expect("mkdir");
    std::fs::write(mine.join("images/cam000.png"), "mine").expect("writes");
    let o = run_small(&mine, &[]);
    assert!(!o.status.success() && text(&o).1.contains("not empty"), "{:?}", text(&o));
    assert_eq!(std::fs::read_to_string(mine.join("images/cam000.png")).expect("kept"), "mine");
}

/// A scene replaced with --force whose writing failed part way (a full disk; here a folder in
/// one image's place) kept its `transforms.json` beside a mix of its own images and new ones,
/// and every command read it as a valid scene. The failed rewrite leaves no scene file.
#[test]
fn a_replacement_that_fails_part_way_leaves_no_scene_that_reads() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("s");
    let o = run_small(&dir, &[]);
    assert!(o.status.success(), "{:?}", text(&o));
    let image = dir.join("images/cam003.png");
    std::fs::remove_file(&image).expect("removes an image");
    std::fs::create_dir_all(image.join("x")).expect("a folder in its place");
    let o = run_small(&dir, &["--force", "--seed", "4", "--noise", "0.05"]);
    let (out, err) = text(&o);
    assert!(!o.status.success(), "should fail: {out}");
    assert!(err.contains("cam003.png"), "{err}");
    assert!(!dir.join("transforms.json").exists(), "the earlier scene file describes other images");
}

/// A scene whose own record cannot be written (here a folder where its preview goes) leaves no
/// scene file: the folder loaded as a scene although synth had failed, and without synth.json
/// it could not be rerun or replaced cleanly.
#[test]
fn a_scene_whose_record_cannot_be_written_does_not_load() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("s");
    std::fs::create_dir_all(dir.join("preview.png/x")).expect("a folder where the preview goes");
    let o = run_small(&dir, &["--force"]);
    let (out, err) = text(&o);
    assert!(!o.status.success(), "should fail: {out}");
    assert!(err.contains("preview.png") && err.contains("unfinished"), "{err}");
    assert!(!dir.join("transforms.json").exists(), "a failed synth left a scene that loads");
}

/// Images too large for memory were refused with advice to lower the resolution, the cameras
/// or the time steps: not the image size, which was what took the memory. The refusal says how
/// much the truth and the images each need.
#[test]
fn a_memory_refusal_names_what_takes_the_memory() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("big");
    let o = run_small(&dir, &["--pixels", "1000000", "--resolution", "8"]);
    let (out, err) = text(&o);
    assert!(!o.status.success(), "should fail: {out}");
    assert!(err.contains("MiB for the images (their pixels"), "{err}");
    assert!(err.contains(" 0 MiB for the truth"), "{err}");
    assert!(!dir.exists() || !dir.join("transforms.json").exists(), "nothing is written");
}

#[test]
fn bad_settings_fail_before_any_work() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("bad");
    for (extra, needle) in [
        (&["--cameras", "0"][..], "at least one camera"),
        (&["--noise", "-0.1"][..], "gaussian_noise"),
        (&["--resolution", "4000", "--pixels", "4000"][..], "memory"),
        (&["--bit-depth", "14"][..], "bit_depth"),
        (&["--holdout", "9"][..], "does not exist"),
        (&["--f-number", "0"][..], "f_number"),
        // The box images between the pixels: the scene was written, then refused by every reader.
        (&["--distance", "100000"][..], "camera 0 (cam000) images the reconstruction box smaller than its pixels"),
        (&["--pixel-pitch", "1e300"][..], "no pixel's ray crosses the box"),
    ] {
        let o = run_small(&dir, extra);
        let (out, err) = text(&o);
        assert!(!o.status.success(), "{extra:?} should fail: {out}");
        assert!(err.contains(needle), "{extra:?}: expected `{needle}` in: {err}");
        assert!(!dir.join("transforms.json").exists(), "{extra:?} wrote output");
    }
    let o = synth(&["--list-presets"]);
    let (out, _) = text(&o);
    assert!(o.status.success());
    for name in ["demo", "planar15", "planar120", "arc180", "sphere15", "jet-tr60"] {
        assert!(out.contains(name), "{name} missing from {out}");
    }
}

/// `--list-presets` with options of a synthesis printed the list and ignored them: a user who
/// asked for a scene had none, and no error. Refused, naming the option, and nothing written.
#[test]
fn list_presets_refuses_the_options_of_a_synthesis() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("set");
    let d = dir.to_str().expect("utf-8 path");
    for (extra, named) in [
        (&["--preset", "demo"][..], "--preset"),
        (&["-o", d], "--out"),
        (&["--cameras", "4"], "--cameras"),
        (&["--seed", "3"], "--seed"),
        (&["--force"], "--force"),
    ] {
        let args: Vec<&str> = ["--list-presets"].iter().chain(extra).copied().collect();
        let o = synth(&args);
        let (out, err) = text(&o);
        assert!(!o.status.success(), "{args:?} should fail: {out}");
        assert!(err.contains("'--list-presets' cannot be used with") && err.contains(named), "{args:?}: {err}");
        assert!(out.is_empty(), "{args:?} printed the list: {out}");
    }
    let o = synth(&["--list-presets", "--preset", "demo", "-o", d, "--cameras", "4"]);
    assert!(!o.status.success());
    assert!(!dir.exists(), "a refused command wrote {}", dir.display());
    // The options that are not the synthesis's are still taken.
    let o = synth(&["--list-presets", "-q"]);
    assert!(o.status.success(), "{:?}", text(&o));
    assert!(text(&o).0.contains("planar15"));
}

#[test]
fn time_resolved_and_thin_lens() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("tr");
    let o =
        run_small(&dir, &["--phantom", "jet-tr", "--times", "14,16", "--model", "thin-lens", "--rays-per-voxel", "8"]);
    assert!(o.status.success(), "{:?}", text(&o));
    let scene = fluidnerf_io::scene::load_scene(&dir).expect("scene");
    assert_eq!(scene.times(), vec![14.0, 16.0]);
    assert_eq!(scene.frames.len(), 10);
    assert!(dir.join("images/cam000_t01.png").is_file());
    let truth = fluidnerf_io::scene::load_truth(&scene).expect("truth");
    assert_eq!(truth.len(), 2);
    assert_ne!(truth[0].1.data, truth[1].1.data, "the ring moves between t* = 14 and 16");
}

#[test]
fn user_volume_becomes_the_truth() {
    use fluidnerf_core::glam::DVec3;
    use fluidnerf_core::{Aabb, Volume};
    let tmp = tempfile::tempdir().expect("tempdir");
    let aabb = Aabb::cube(DVec3::ZERO, 40.0);
    let vol = Volume::from_fn([16, 12, 20], aabb, |p| (1.0 - p.length() / 20.0).max(0.0) as f32);
    let npy = tmp.path().join("mine.npy");
    fluidnerf_io::volume::write_npy(&npy, &vol).expect("writes volume");
    let dir = tmp.path().join("set");
    let o = run_small_volume(&dir, &npy, &[]);
    assert!(o.status.success(), "{:?}", text(&o));
    let scene = fluidnerf_io::scene::load_scene(&dir).expect("scene");
    let truth = fluidnerf_io::scene::load_truth(&scene).expect("truth");
    assert_eq!(truth[0].1.data, vol.data);
    let recorded = fluidnerf_io::scene::recorded(&scene).expect("recording").flow_axis;
    assert_eq!(recorded, None, "a user's volume has no known flow axis");
    let o = run_small_volume(&tmp.path().join("missing"), Path::new("/nonexistent/v.npy"), &[]);
    assert!(!o.status.success());
    assert!(text(&o).1.contains("/nonexistent/v.npy"), "{:?}", text(&o));

    // What the volume replaces is refused, not ignored: the phantom, its grid, and the box of a
    // .vti, which holds its own.
    let vti = tmp.path().join("mine.vti");
    fluidnerf_io::volume::write_vti(&vti, &vol).expect("writes volume");
    let text_file = tmp.path().join("notes.txt");
    std::fs::write(&text_file, "hello").expect("writes");
    for (truth, extra, needle) in [
        (&npy, &["--phantom", "ball"][..], "'--truth-volume <TRUTH_VOLUME>' cannot be used with '--phantom"),
        (&npy, &["--resolution", "8"][..], "--resolution 8: the truth volume"),
        (&vti, &["--aabb", "-5,-5,-5,5,5,5"][..], "mine.vti is a .vti, which holds its own box"),
        // A file that is no volume is said to be so first (it was told about --resolution).
        (&text_file, &["--resolution", "8"][..], "notes.txt: the ground truth must be a .npy, .vti or .tif volume"),
    ] {
        let dir = tmp.path().join("refused");
        let o = run_small_volume(&dir, truth, extra);
        let (_, err) = text(&o);
        assert!(!o.status.success() && err.contains(needle), "{extra:?}: expected `{needle}` in: {err}");
        assert!(!dir.exists(), "{extra:?} wrote output");
    }
    // A .npy fills the box given.
    let o = run_small_volume(&tmp.path().join("boxed"), &npy, &["--aabb", "-5,-5,-5,5,5,5"]);
    assert!(o.status.success(), "{:?}", text(&o));

    // A TIFF stack calibrated for ImageJ brings its box, as a .vti does, and refuses another.
    let shifted = Aabb { min: DVec3::new(-10.0, -20.0, -5.0), max: DVec3::new(22.0, 4.0, 35.0) };
    let stack_vol = Volume::from_vec([16, 12, 20], shifted, vol.data.clone());
    let tif = tmp.path().join("mine.tif");
    fluidnerf_io::volume::write_tiff_stack(&tif, &stack_vol, "mm").expect("writes the stack");
    let from_tif = tmp.path().join("from_tif");
    let o = run_small_volume(&from_tif, &tif, &[]);
    assert!(o.status.success(), "{:?}", text(&o));
    let scene = fluidnerf_io::scene::load_scene(&from_tif).expect("scene");
    assert!((scene.aabb.min - shifted.min).abs().max_element() < 1e-9, "{:?}", scene.aabb);
    assert!((scene.aabb.max - shifted.max).abs().max_element() < 1e-9, "{:?}", scene.aabb);
    assert_eq!(fluidnerf_io::scene::load_truth(&scene).expect("truth")[0].1.data, vol.data);
    let refused = tmp.path().join("refused_tif");
    let o = run_small_volume(&refused, &tif, &["--aabb", "-5,-5,-5,5,5,5"]);
    let (_, err) = text(&o);
    assert!(!o.status.success() && err.contains("mine.tif is a TIFF stack calibrated with its own box"), "{err}");
    assert!(!refused.exists(), "a refused stack wrote output");

    // Rerun from its synth.json with another phantom, the volume is no longer read, and the
    // new synth.json does not name it either.
    let ball = tmp.path().join("ball");
    let config = dir.join("synth.json");
    let o = synth(&[
        "-q",
        "-o",
        ball.to_str().expect("utf-8"),
        "--config",
        config.to_str().expect("utf-8"),
        "--phantom",
        "ball",
    ]);
    assert!(o.status.success(), "{:?}", text(&o));
    let written = std::fs::read_to_string(ball.join("synth.json")).expect("synth.json");
    assert!(!written.contains("mine.npy"), "the replaced volume is still recorded: {written}");
}

/// A scene that `info` would reject is refused before anything is written: a ground truth with
/// NaN or infinite voxels (float64 values beyond float32's range read as infinite), no positive
/// voxel, and a time given twice.
#[test]
fn truths_that_are_not_finite_and_repeated_times_are_refused_up_front() {
    use fluidnerf_core::glam::DVec3;
    use fluidnerf_core::{Aabb, Volume};
    let tmp = tempfile::tempdir().expect("tempdir");
    let aabb = Aabb::cube(DVec3::ZERO, 40.0);
    let mut vol = Volume::from_fn([8, 8, 8], aabb, |p| (1.0 - p.length() / 20.0).max(0.0) as f32);
    vol.data[3] = f32::NAN;
    let nan = tmp.path().join("nan.npy");
    fluidnerf_io::volume::write_npy(&nan, &vol).expect("writes volume");
    // A float64 volume whose values overflow float32.
    let big = tmp.path().join("big.npy");
    let mut header = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2, 2), }".to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((header.len() as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    for v in [1.0f64, 2.0, 1e300, 0.0, 0.0, 0.0, 0.0, 0.0] {
        bytes.extend(v.to_le_bytes());
    }
    std::fs::write(&big, bytes).expect("writes volume");
    // A volume with no positive voxel made black images said to be seen by no camera.
    let dark = tmp.path().join("dark.npy");
    fluidnerf_io::volume::write_npy(&dark, &Volume::from_fn([8, 8, 8], aabb, |_| -1.0)).expect("writes volume");
    // Finite float32 values whose line integrals overflow: a camera's non-finite pixel was
    // refused, naming neither the file nor the cause.
    let huge = tmp.path().join("huge.npy");
    fluidnerf_io::volume::write_npy(&huge, &Volume::from_fn([8, 8, 8], aabb, |_| 1e38)).expect("writes volume");
    for (truth, extra, needle) in [
        (Some(&nan), vec![], "nan.npy: voxel (i 3, j 0, k 0) is NaN"),
        (Some(&huge), vec![], "huge.npy: values up to 1.000e38 over paths up to the box's diagonal"),
        (Some(&dark), vec![], "dark.npy: no voxel is positive (the largest value is -1)"),
        (Some(&big), vec![], "beyond float32's range"),
        (None, vec!["--phantom", "jet-tr", "--times", "14,14"], "14 is given twice"),
    ] {
        let dir = tmp.path().join("set");
        let o = match truth {
            Some(truth) => run_small_volume(&dir, truth, &extra),
            None => run_small(&dir, &extra),
        };
        let (_, err) = text(&o);
        assert!(!o.status.success(), "{extra:?} should fail");
        assert!(err.contains(needle), "{extra:?}: expected `{needle}` in: {err}");
        assert!(!dir.exists(), "{extra:?} wrote output");
    }
}

#[test]
fn aabb_takes_negative_corners_and_exactly_six_numbers() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("box");
    let o = run_small(&dir, &["--aabb", "-12,-10,-8,12,10,8"]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "stdout: {out}\nstderr: {err}");
    let scene = fluidnerf_io::scene::load_scene(&dir).expect("scene reads back");
    assert_eq!(scene.aabb.min.to_array(), [-12.0, -10.0, -8.0]);
    assert_eq!(scene.aabb.max.to_array(), [12.0, 10.0, 8.0]);

    let o = run_small(&tmp.path().join("five"), &["--aabb", "-12,-10,-8,12,10"]);
    assert!(!o.status.success());
    assert!(text(&o).1.contains("--aabb takes 6 numbers"), "{}", text(&o).1);

    // A box too large for 32-bit rendering is refused up front, naming --aabb, not by a
    // non-finite pixel after the rendering; one wide but within range still renders.
    for aabb in ["--aabb=-1e300,-1,-1,1,1,1", "--aabb=-1,-1,-1,1,1e17,1"] {
        let dir = tmp.path().join("huge");
        let o = run_small(&dir, &[aabb]);
        let err = text(&o).1;
        assert!(!o.status.success() && err.contains("--aabb") && err.contains("within ±1e16"), "{aabb}: {err}");
        assert!(!err.contains("non-finite"), "{aabb}: {err}");
        assert!(!dir.exists(), "{aabb}: wrote output");
    }
    // Sides out of the range 32-bit voxel sizes and field values hold are refused naming the
    // option and the range: such boxes made scenes that reconstructed to volumes of zeros.
    for aabb in ["--aabb=0,0,0,1e-36,1e-36,1e-36", "--aabb=-1e12,-1,-1,1e12,1,1"] {
        let dir = tmp.path().join("out-of-range");
        let o = run_small(&dir, &[aabb]);
        let err = text(&o).1;
        assert!(!o.status.success() && err.contains("--aabb") && err.contains("between 1e-6 and 1e9"), "{aabb}: {err}");
        assert!(!dir.exists(), "{aabb}: wrote output");
    }
    // With the cameras outside it: a camera inside the box would make a scene no command reads.
    let wide = "--aabb=-5e8,-5e8,-5e8,5e8,5e8,5e8";
    let o = run_small(&tmp.path().join("wide"), &[wide, "--distance", "2e9"]);
    assert!(o.status.success(), "{}", text(&o).1);
    let dir = tmp.path().join("inside");
    let o = run_small(&dir, &[wide]);
    let err = text(&o).1;
    assert!(!o.status.success() && err.contains("camera 0 (cam000) at [0.0, 360.0, 0.0] mm is inside"), "{err}");
    assert!(!dir.exists(), "wrote a scene no command reads");
}

/// Fraction of pixels above 5 % of the image's peak, and the lit region's height / width (rows
/// and columns holding a lit pixel).
fn lit_shape(img: &fluidnerf_core::Image) -> (f64, f64) {
    let peak = img.min_max().1;
    let lit = |c: usize, r: usize| img.data[r * img.width + c] > 0.05 * peak;
    let count = (0..img.height).flat_map(|r| (0..img.width).map(move |c| (c, r))).filter(|&(c, r)| lit(c, r)).count();
    let rows = (0..img.height).filter(|&r| (0..img.width).any(|c| lit(c, r))).count();
    let cols = (0..img.width).filter(|&c| (0..img.height).any(|r| lit(c, r))).count();
    (count as f64 / (img.width * img.height) as f64, rows as f64 / cols.max(1) as f64)
}

#[test]
fn cfd_plume_preset_is_time_resolved_and_rises_in_the_images() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("plume-tr");
    let o = synth(&["-q", "-o", dir.to_str().expect("utf-8"), "--preset", "plume-tr"]);
    let (out, err) = text(&o);
    assert!(o.status.success(), "stdout: {out}\nstderr: {err}");
    assert!(out.contains("3 solver steps [50.0, 52.0, 60.0]"), "{out}");
    let scene = fluidnerf_io::scene::load_scene(&dir).expect("scene");
    assert_eq!(scene.units, "mm");
    assert_eq!(scene.aabb.min.to_array(), [-12.0, -18.0, -12.0], "the box is the simulation domain");
    assert_eq!(scene.aabb.max.to_array(), [12.0, 18.0, 12.0]);
    assert_eq!(scene.times(), vec![50.0, 52.0, 60.0]);
    assert_eq!(scene.frames.len(), 36);
    let truth = fluidnerf_io::scene::load_truth(&scene).expect("truth");
    assert_eq!(truth.len(), 3);
    assert_eq!(truth[0].1.dims, [48, 72, 48], "truth on the solver's grid");
    assert_ne!(truth[0].1.data, truth[1].1.data, "2 solver steps apart");
    assert_ne!(truth[1].1.data, truth[2].1.data, "8 solver steps apart");
    let images = fluidnerf_io::scene::load_images(&scene).expect("images");
    for (frame, img) in scene.frames.iter().zip(&images) {
        let (lit, tall) = lit_shape(img);
        let name = frame.file_path.display();
        assert!(lit > 0.03 && lit < 0.6, "{name}: {:.1} % of the pixels lit", 100.0 * lit);
        assert!(tall > 1.2, "{name}: the plume rises along the image's vertical, height/width {tall:.2}");
    }
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("synth.json")).expect("synth.json")).expect("json");
    let note = record["phantom_note"].as_str().expect("a CFD data set records a note");
    assert!(note.contains("+y") && note.contains("solver steps"), "{note}");
    let recorded = fluidnerf_io::scene::recorded(&scene).expect("recording").flow_axis;
    assert_eq!(recorded.map(|a| a.to_array()), Some([0.0, 1.0, 0.0]), "the plume's flow axis is recorded");
}

#[test]
fn cfd_phantoms_from_any_preset_and_their_steps() {
    let tmp = tempfile::tempdir().expect("tempdir");
    // Switching the phantom to a CFD one moves the box to the domain and the ring about y.
    let dir = tmp.path().join("jet");
    let o = run_small(&dir, &["--phantom", "cfd-jet", "--cfd-step", "40"]);
    assert!(o.status.success(), "{:?}", text(&o));
    let scene = fluidnerf_io::scene::load_scene(&dir).expect("scene");
    assert_eq!(scene.aabb.max.to_array(), [12.0, 18.0, 12.0]);
    assert!(scene.frames.iter().all(|f| f.camera.centre().y.abs() < 1e-9), "ring about the y axis");
    let images = fluidnerf_io::scene::load_images(&scene).expect("images");
    assert!(images.iter().all(|i| lit_shape(i).0 > 0.02), "every camera sees the jet");
    let truth = fluidnerf_io::scene::load_truth(&scene).expect("truth");
    assert_eq!(truth[0].1.dims, [16, 24, 16], "--resolution 24 resamples the solver's grid");
    for (extra, needle) in [
        (&["--phantom", "plume", "--times", "51"][..], "solver steps"),
        (&["--phantom", "plume", "--cfd-step", "7"][..], "cfd_step"),
        // A step no phantom reads was ignored without a word.
        (&["--cfd-step", "50"][..], "applies to the CFD phantoms (plume, cfd-jet) only"),
        (&["--phantom", "plume", "--times", "40,50", "--cfd-step", "60"][..], "give one or the other"),
    ] {
        let o = run_small(&tmp.path().join("bad"), extra);
        assert!(!o.status.success(), "{extra:?} should fail");
        assert!(text(&o).1.contains(needle), "{extra:?}: expected `{needle}` in {}", text(&o).1);
    }
    let o = synth(&["--list-presets"]);
    let (out, _) = text(&o);
    for name in ["plume15", "plume4", "plume8", "cfdjet15", "plume-tr"] {
        assert!(out.lines().any(|l| l.split_whitespace().next() == Some(name)), "{name} missing from {out}");
    }
    // Every description starts in one column, past the longest name (`real-like-small` ran
    // into its description, one space apart, where the others stood in a column).
    let starts: Vec<usize> = out
        .lines()
        .map(|l| {
            let name_end = 2 + l[2..].find(' ').expect("a name, then a description");
            name_end + l[name_end..].find(|c: char| c != ' ').expect("a description")
        })
        .collect();
    assert!(starts.iter().all(|&s| s == starts[0]), "{starts:?}\n{out}");
    assert!(out.lines().all(|l| l[..starts[0]].ends_with("  ")), "two spaces at least before each description:\n{out}");
}

/// Ctrl-C (SIGINT) stops a synthesis as it stops a reconstruction: exit status 130, and
/// nothing half-written left behind.
#[cfg(unix)]
#[test]
fn an_interrupted_synthesis_exits_130_and_leaves_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("big");
    let child = Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .args(["synth", "--preset", "planar60", "-q", "-o", out.to_str().expect("utf-8 path")])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("starts");
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let killed = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill runs");
    assert!(killed.success());
    let o = child.wait_with_output().expect("waits");
    let (_, err) = text(&o);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(!out.exists(), "an interrupted synthesis left {}", out.display());
}

/// Counts and lengths of a configuration's phantom far beyond their defaults are refused,
/// naming the key: a billion blobs or turbulence modes failed to allocate and aborted the
/// program, and a hundred octaves of turbulence, or lengths such as 1e300 (past f32's range)
/// or 1e-45 (below it), gave images of NaN, blamed on `phantom` as a whole.
#[test]
fn phantom_counts_beyond_reason_are_refused_by_key() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (config, out) = (tmp.path().join("synth.json"), tmp.path().join("out"));
    for (kind, key, value, needle) in [
        ("blobs", "blob_count", serde_json::json!(1_000_000_000u64), "`phantom.blob_count`: must be in 1..=1000"),
        (
            "jet",
            "turbulence_modes",
            serde_json::json!(10_000_000_000u64),
            "`phantom.jet.turbulence_modes`: must be at most",
        ),
        (
            "jet",
            "inertial_octaves",
            serde_json::json!(100.0),
            "`phantom.jet.inertial_octaves`: must be zero or positive and at most 20",
        ),
        (
            "jet",
            "spreading_rate",
            serde_json::json!(1e300),
            "`phantom.jet.spreading_rate`: must be between 0.001 and 1000, got 1e300",
        ),
        (
            "jet",
            "transition_end_d",
            serde_json::json!(1e300),
            "`phantom.jet.transition_end_d`: must exceed core_length_d (5.5) and be at most 1000",
        ),
        (
            "jet",
            "wrinkle",
            serde_json::json!(1e300),
            "`phantom.jet.wrinkle`: must be zero or positive and at most 1000",
        ),
        (
            "jet",
            "nozzle_diameter_mm",
            serde_json::json!(1e300),
            "`phantom.jet.nozzle_diameter_mm`: must be between 0.001 mm and 1000000 mm",
        ),
        (
            "jet-tr",
            "nozzle_diameter_mm",
            serde_json::json!(1e30),
            "`phantom.jet_tr.nozzle_diameter_mm`: must be between 0.001 mm and 1000000 mm",
        ),
        (
            "jet-tr",
            "front_speed",
            serde_json::json!(1e300),
            "`phantom.jet_tr.front_speed`: must be between 0.001 and 1000",
        ),
        (
            "jet",
            "nozzle_diameter_mm",
            serde_json::json!(1e-45),
            "`phantom.jet.nozzle_diameter_mm`: must be between 0.001 mm and 1000000 mm, got 1e-45",
        ),
        (
            "jet",
            "spreading_rate",
            serde_json::json!(1e-40),
            "`phantom.jet.spreading_rate`: must be between 0.001 and 1000, got 1e-40",
        ),
        (
            "jet-tr",
            "nozzle_diameter_mm",
            serde_json::json!(1e-45),
            "`phantom.jet_tr.nozzle_diameter_mm`: must be between 0.001 mm and 1000000 mm, got 1e-45",
        ),
        (
            "jet-tr",
            "trailing_wavelength_d",
            serde_json::json!(1e-40),
            "`phantom.jet_tr.trailing_wavelength_d`: must be between 0.001 and 1000, got 1e-40",
        ),
    ] {
        let mut phantom = serde_json::json!({ "kind": kind });
        match kind {
            "jet" => phantom["jet"] = serde_json::json!({ key: value }),
            "jet-tr" => phantom["jet_tr"] = serde_json::json!({ key: value }),
            _ => phantom[key] = value,
        }
        let times: &[f64] = if kind == "jet-tr" { &[15.0] } else { &[] };
        let settings = serde_json::json!({
            "phantom": phantom, "resolution": 8, "lens": { "resolution": [16, 16] }, "times": times,
            "rig": { "layout": { "layout": "ring", "count": 3, "arc_deg": 360.0, "start_deg": 0.0 } },
        });
        std::fs::write(&config, settings.to_string()).expect("writes");
        let o = synth(&["-q", "-o", out.to_str().expect("utf-8"), "--config", config.to_str().expect("utf-8")]);
        let err = text(&o).1;
        assert!(!o.status.success() && err.contains(needle), "{key}: {err}");
        assert!(!out.exists(), "{key}: wrote output");
    }
}

/// Thin-lens rays per voxel beyond the bound are refused naming the option: 1e300 counted rays
/// past `u64::MAX` and never finished.
#[test]
fn rays_per_voxel_beyond_the_bound_are_refused_naming_the_option() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("out");
    for n in ["1e300", "2000000", "0", "NaN"] {
        let o = run_small(&dir, &["--model", "thin-lens", "--rays-per-voxel", n]);
        let err = text(&o).1;
        assert!(!o.status.success(), "{n}: {err}");
        assert!(err.contains("--rays-per-voxel on the command line") && err.contains("at most 1048576"), "{n}: {err}");
        assert!(!dir.exists(), "{n}: wrote output");
    }
}

/// Every option that sets a key of the configuration names itself when its value is refused,
/// not only the key: `--noise 5` was reported as `sensor.gaussian_noise` alone. A value refused
/// only once the rig is built (a camera inside the box) is named alike.
#[test]
fn a_bad_value_of_any_option_is_refused_naming_the_option() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("out");
    for (extra, option, key) in [
        (&["--resolution", "1"][..], "--resolution", "resolution"),
        (&["--phantom", "jet-tr", "--times", "15,15"], "--times", "times"),
        (&["--cfd-step", "7"], "--cfd-step", "phantom.cfd_step"),
        (&["--cameras", "0"], "--cameras", "rig.layout.count"),
        (&["--arc", "400"], "--arc", "rig.layout.arc_deg"),
        (&["--every", "0"], "--every", "rig.subset.every"),
        (&["--first", "0"], "--first", "rig.subset"),
        (&["--holdout", "9"], "--holdout", "rig.holdout"),
        (&["--jitter-position", "NaN"], "--jitter-position", "rig.jitter.position_mm"),
        (&["--jitter-rotation", "inf"], "--jitter-rotation", "rig.jitter.rotation_deg"),
        (&["--jitter-rotation", "1e30"], "--jitter-rotation", "rig.jitter.rotation_deg"),
        (&["--distance", "0"], "--distance", "rig.distance_mm"),
        (&["--distance", "1"], "--distance", "rig.distance_mm"),
        (&["--pixels", "0"], "--pixels", "lens.resolution"),
        (&["--magnification", "0.2"], "--magnification", "lens.magnification"),
        (&["--focal-length", "0"], "--focal-length", "lens.focal_length_mm"),
        (&["--f-number", "0"], "--f-number", "lens.f_number"),
        // An aperture of 6e301 mm spread every voxel's light off the sensor: black images.
        (&["--f-number", "1e-300"], "--f-number", "lens.f_number"),
        (&["--pixel-pitch", "0"], "--pixel-pitch", "lens.pixel_pitch_mm"),
        (&["--supersample", "0"], "--supersample", "image.supersample"),
        (&["--noise", "5"], "--noise", "sensor.gaussian_noise"),
        (&["--full-well", "0"], "--full-well", "sensor.full_well"),
        // A pixel that holds no whole photo-electron: images of rare saturated specks.
        (&["--full-well", "1e-300"], "--full-well", "sensor.full_well"),
        (&["--dark-offset", "1e9"], "--dark-offset", "sensor.dark_offset"),
        // The offset lifted the brightest pixels past full scale: they were written clipped.
        (&["--dark-offset", "60000"], "--dark-offset", "sensor.dark_offset"),
        (&["--bit-depth", "9"], "--bit-depth", "sensor.bit_depth"),
        (&["--full-scale-fraction", "2"], "--full-scale-fraction", "sensor.full_scale_fraction"),
        // The brightest pixel below one count: every image was written black.
        (&["--full-scale-fraction", "1e-6"], "--full-scale-fraction", "sensor.full_scale_fraction"),
        (&["--real-like", "--full-scale-fraction", "0.001"], "--full-scale-fraction", "sensor.full_scale_fraction"),
        (&["--real-like", "--noise", "0.05"], "--noise", "sensor.gaussian_noise"),
        (&["--gain-spread", "2"], "--gain-spread", "real.gain_spread"),
        (&["--background-level", "0.9"], "--background-level", "real.background"),
        (&["--dark-noise", "0.9"], "--dark-noise", "real.dark_noise"),
        (&["--background-frames", "0"], "--background-frames", "real.background_frames"),
        (&["--jpeg-quality", "0"], "--jpeg-quality", "real.jpeg_quality"),
        (&["--vignetting", "0.95"], "--vignetting", "real.vignetting"),
        (&["--vignetting", "0.5", "--flat-frames", "0"], "--flat-frames", "real.flat_frames"),
    ] {
        let o = run_small(&dir, extra);
        let err = text(&o).1;
        assert!(!o.status.success(), "{extra:?}: {err}");
        assert!(err.contains(&format!("{option} on the command line: invalid setting `{key}`")), "{extra:?}: {err}");
        assert!(!dir.exists(), "{extra:?}: wrote output");
    }
    // The key alone when it came from a file.
    let config = tmp.path().join("synth.json");
    std::fs::write(&config, serde_json::json!({ "sensor": { "gaussian_noise": 5.0 } }).to_string()).expect("writes");
    let o = synth(&["-q", "-o", dir.to_str().expect("utf-8"), "--config", config.to_str().expect("utf-8")]);
    let err = text(&o).1;
    assert!(!o.status.success() && err.contains("invalid setting `sensor.gaussian_noise`"), "{err}");
    assert!(!err.contains("on the command line"), "{err}");
    // A ring started 1e30 degrees round put every camera at the same angle.
    let ring = serde_json::json!({ "layout": "ring", "count": 3, "arc_deg": 360.0, "start_deg": 1e30 });
    std::fs::write(&config, serde_json::json!({ "rig": { "layout": ring } }).to_string()).expect("writes");
    let o = synth(&["-q", "-o", dir.to_str().expect("utf-8"), "--config", config.to_str().expect("utf-8")]);
    let err = text(&o).1;
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("invalid setting `rig.layout.start_deg`: must lie in [-3600, 3600] degrees"), "{err}");
    assert!(!dir.exists(), "wrote output");
}

/// A brightest pixel below one count rounds every image to black: the scene was written as if
/// fine, with an intensity scale that every reader then refused.
#[test]
fn a_full_scale_fraction_below_one_count_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("out");
    let o = run_small(&dir, &["--full-scale-fraction", "1e-300"]);
    let err = text(&o).1;
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("invalid setting `sensor.full_scale_fraction`: 1e-300 puts the brightest pixel at")
            && err.contains("every image would round to black; give at least 1.526e-5"),
        "{err}"
    );
    assert!(!dir.exists(), "wrote output");
    // One count of the 8-bit sensor is enough.
    let o = run_small(&dir, &["--bit-depth", "8", "--full-scale-fraction", "0.004"]);
    assert!(o.status.success(), "{:?}", text(&o));
}

/// `--force` over an earlier synthetic scene replaces it whole: its images, background frames
/// and truth volumes that the new scene has not were left beside the new scene's, so the
/// folder held the files of two scenes. Files that are no scene's stay.
#[test]
fn force_leaves_no_file_of_the_earlier_scene() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("scene");
    let out = dir.to_str().expect("utf-8 path");
    let tiny = ["-q", "--preset", "demo", "--pixels", "16", "--resolution", "8", "-o", out];
    let o = synth(&[&tiny[..], &["--cameras", "6", "--real-like"]].concat());
    assert!(o.status.success(), "{:?}", text(&o));
    std::fs::write(dir.join("notes.txt"), "mine").expect("writes");
    let o = synth(&[&tiny[..], &["--cameras", "3", "--phantom", "jet-tr", "--force"]].concat());
    assert!(o.status.success(), "{:?}", text(&o));
    let names = |sub: &str| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir.join(sub))
            .map(|d| d.map(|e| e.expect("entry").file_name().to_string_lossy().into_owned()).collect())
            .unwrap_or_default();
        v.sort();
        v
    };
    let images: Vec<String> = (0..3).flat_map(|c| (0..3).map(move |t| format!("cam{c:03}_t{t:02}.png"))).collect();
    assert_eq!(names("images"), images);
    assert_eq!(names("truth"), ["truth_t00.npy", "truth_t01.npy", "truth_t02.npy"]);
    assert!(!dir.join("background").exists(), "the earlier recording's background frames stayed");
    assert!(dir.join("notes.txt").is_file(), "a file of no scene was removed");
}

/// A scene's own truth given back as the truth volume of the scene that replaces it is refused
/// before any work, even with --force: it was removed as a file of the earlier scene (or
/// written over), and the scene's truth kept its own.
#[test]
fn a_truth_volume_among_the_files_a_synthesis_replaces_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("scene");
    let out = dir.to_str().expect("utf-8 path");
    let tiny = ["-q", "--preset", "demo", "--cameras", "3", "--pixels", "16", "--resolution", "8", "-o", out];
    let o = synth(&tiny);
    assert!(o.status.success(), "{:?}", text(&o));
    let truth = dir.join("truth/truth.npy");
    let before = std::fs::read(&truth).expect("reads");
    let o = run_small_volume(&dir, &truth, &["--force"]);
    let (_, err) = text(&o);
    assert!(!o.status.success() && err.contains("--truth-volume: lies among the files of the scene"), "{err}");
    assert_eq!(std::fs::read(&truth).expect("kept"), before);
    // Kept outside the folders a scene writes, it may be used.
    let kept = dir.join("mine.npy");
    std::fs::rename(&truth, &kept).expect("moves");
    let o = run_small_volume(&dir, &kept, &["--force"]);
    assert!(o.status.success(), "{:?}", text(&o));
    assert!(kept.is_file());
}

/// An f-number no lens in air has (below 0.5, a numerical aperture above 1) made an aperture of
/// 6e301 mm at 1e-300 and a scene of black images; it is refused naming the key.
#[test]
fn an_f_number_below_any_lens_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("out");
    let o = run_small(&dir, &["--f-number", "0.3"]);
    let err = text(&o).1;
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("invalid setting `lens.f_number`: must be at least 0.5 (a lens in air has a numerical aperture of at most 1), got 0.3"),
        "{err}"
    );
    assert!(!dir.exists(), "wrote output");
}

/// A quadrature step of a vanishing fraction of a voxel took steps without end: synth with
/// `image.step_fraction` 1e-300 ran until it was killed.
#[test]
fn a_step_fraction_too_small_to_finish_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("out");
    let config = tmp.path().join("synth.json");
    std::fs::write(
        &config,
        serde_json::json!({ "image": { "model": "pinhole", "step_fraction": 1e-300 } }).to_string(),
    )
    .expect("writes");
    let o = synth(&["-q", "-o", dir.to_str().expect("utf-8"), "--config", config.to_str().expect("utf-8")]);
    let err = text(&o).1;
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("invalid setting `image.step_fraction`: must be in [0.01, 2], got 1e-300"), "{err}");
    assert!(!dir.exists(), "wrote output");
}

/// A starting jet before it starts (t* = 0) holds no light: every image was black, and the
/// scene was written with a warning for every reader to refuse. It is refused naming the times
/// and why; a series in which only some times are dark is still a series.
#[test]
fn a_phantom_empty_at_every_time_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("out");
    let o = run_small(&dir, &["--phantom", "jet-tr", "--times", "0"]);
    let err = text(&o).1;
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("invalid setting `times`: every image of the 5 cameras is black")
            && err.contains("the jet-tr phantom is empty (no voxel above 0) at t* = 0"),
        "{err}"
    );
    assert!(!dir.exists(), "wrote output");
    let o = run_small(&dir, &["--phantom", "jet-tr", "--times", "0,14"]);
    assert!(o.status.success(), "{:?}", text(&o));
}

/// synth.json records its seed at the top beside `settings.seed`, which is the one read: a seed
/// edited at the top alone made the scene of the old seed without a word; it is refused naming
/// both keys, and one edited alike in both is taken.
#[test]
fn a_seed_edited_at_the_top_of_synth_json_alone_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let first = dir.path().join("first");
    let o = run_small(&first, &[]);
    assert!(o.status.success(), "{}", text(&o).1);
    let config = dir.path().join("edited.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(first.join("synth.json")).expect("reads")).expect("json");
    v["seed"] = 7.into();
    std::fs::write(&config, v.to_string()).expect("writes");
    let second = dir.path().join("second");
    let args = ["-q", "--config", config.to_str().expect("utf-8"), "-o", second.to_str().expect("utf-8")];
    let o = synth(&args);
    let (_, err) = text(&o);
    assert!(!o.status.success() && err.contains("`seed` 7 and `settings.seed` 3 disagree"), "{err}");
    assert!(err.contains("edited.json"), "{err}");
    assert!(!second.exists());
    // --seed decides, whatever the file says.
    let o = synth(&[&args[..], &["--seed", "7"]].concat());
    assert!(o.status.success(), "{}", text(&o).1);
    std::fs::remove_dir_all(&second).expect("removes");
    v["settings"]["seed"] = 7.into();
    std::fs::write(&config, v.to_string()).expect("writes");
    let o = synth(&args);
    assert!(o.status.success(), "{}", text(&o).1);
}

/// A synth.json's setting of another phantom than the one it makes, away from its default,
/// was taken and ignored; it is refused naming the file, the key and the phantom. A synth.json
/// the command wrote is taken, also one written after --phantom changed a configuration's
/// phantom (which drops the old phantom's settings).
#[test]
fn another_phantoms_settings_in_a_config_are_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (set, out) = (tmp.path().join("set"), tmp.path().join("out"));
    let o = run_small(&set, &["--phantom", "blobs", "--resolution", "8", "--pixels", "12"]);
    assert!(o.status.success(), "{}", text(&o).1);
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(set.join("synth.json")).expect("reads")).expect("json");
    let config = tmp.path().join("synth.json");
    let config_arg = config.to_str().expect("utf-8");
    for (kind, key, value, says) in [
        (
            "jet",
            "jet_tr.front_speed",
            serde_json::json!(2.0),
            "`phantom.jet_tr.front_speed`: 2.0 is set for another phantom than the jet phantom",
        ),
        (
            "ball",
            "volume_path",
            serde_json::json!("cfd.tif"),
            "`phantom.volume_path`: \"cfd.tif\" is set for another phantom than the ball phantom",
        ),
        (
            "ball",
            "blob_count",
            serde_json::json!(8),
            "`phantom.blob_count`: 8 is set for another phantom than the ball phantom",
        ),
    ] {
        let mut c = written.clone();
        c["settings"]["phantom"]["kind"] = kind.into();
        match key.split_once('.') {
            Some((group, inner)) => c["settings"]["phantom"][group][inner] = value,
            None => c["settings"]["phantom"][key] = value,
        }
        std::fs::write(&config, c.to_string()).expect("writes");
        let o = synth(&["-q", "-o", out.to_str().expect("utf-8"), "--config", config_arg]);
        let err = text(&o).1;
        assert!(!o.status.success(), "{key}: accepted");
        assert!(err.contains(&format!("the settings of {config_arg}")) && err.contains(says), "{key}: {err}");
        assert!(!out.exists(), "{key}: wrote output");
    }
    // Where the phantom uses it, it is taken; --phantom then changes the phantom, and the
    // synth.json written is taken as it is.
    let mut c = written.clone();
    c["settings"]["phantom"]["blob_count"] = 3.into();
    std::fs::write(&config, c.to_string()).expect("writes");
    let o = synth(&["-q", "-o", out.to_str().expect("utf-8"), "--config", config_arg, "--phantom", "ball"]);
    assert!(o.status.success(), "{}", text(&o).1);
    let again = tmp.path().join("again");
    let o = synth_from(&again, &out.join("synth.json"));
    assert!(o.status.success(), "{}", text(&o).1);
}

/// Times given out of order were made in that order, so the scene's frames ran backwards in
/// time; they are sorted, the frames, truths and recorded times follow time, and the summary
/// says so.
#[test]
fn times_given_out_of_order_are_sorted() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("set");
    let mut args = vec!["-o", dir.to_str().expect("utf-8")];
    args.extend(["--preset", "demo", "--phantom", "jet-tr", "--times", "16,14", "--cameras", "3"]);
    args.extend(["--pixels", "12", "--resolution", "8"]);
    let o = synth(&args);
    let (out, err) = text(&o);
    assert!(o.status.success(), "{err}");
    assert!(out.contains("2 times t* = [14.0, 16.0] (sorted into time order)"), "{out}");
    let read = |f: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join(f)).expect("reads")).expect("json")
    };
    let frames = read("transforms.json")["frames"].as_array().expect("frames").clone();
    let times: Vec<f64> = frames.iter().map(|f| f["time"].as_f64().expect("a time")).collect();
    assert_eq!(times, [14.0, 14.0, 14.0, 16.0, 16.0, 16.0]);
    assert!(frames[0]["file_path"].as_str().expect("a path").ends_with("_t00.png"), "{frames:?}");
    assert_eq!(read("synth.json")["settings"]["times"], serde_json::json!([14.0, 16.0]));
}

/// --pixels 1 wrote a scene of 1×1 images, which no held-out view can be scored on; images
/// are at least the SSIM window wide, and fewer pixels are refused naming the option.
#[test]
fn pixels_below_the_ssim_window_are_refused_naming_the_option() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("set");
    for pixels in ["1", "6"] {
        let o = run_small(&dir, &["--pixels", pixels]);
        let err = text(&o).1;
        assert!(!o.status.success(), "--pixels {pixels}: accepted");
        assert!(
            err.contains("--pixels on the command line: invalid setting `lens.resolution`: width and height must be at least 7 pixels"),
            "--pixels {pixels}: {err}"
        );
        assert!(!dir.exists(), "--pixels {pixels}: wrote output");
    }
    let o = run_small(&dir, &["--pixels", "7", "--resolution", "8"]);
    assert!(o.status.success(), "{}", text(&o).1);
}

/// A folder named `transforms.json` where the scene file goes is refused before any work, even
/// with --force: the scene could not be written over it, and failed only at the end, as "Is a
/// directory", after the images were made.
#[test]
fn a_folder_where_the_scene_file_goes_is_refused_up_front() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("scene");
    std::fs::create_dir_all(dir.join("transforms.json")).expect("mkdir");
    for extra in [&[][..], &["--force"]] {
        let o = run_small(&dir, extra);
        let (_, err) = text(&o);
        assert!(!o.status.success(), "{extra:?}");
        assert!(err.contains("transforms.json: is a folder, where the scene file goes"), "{extra:?}: {err}");
        assert!(!dir.join("images").exists(), "{extra:?}: images were written");
    }
}

/// A sensor of fewer bits than 16 keeps its counts unscaled in 16-bit PNGs: the summary said
/// "8-bit PNG" of files that are 16-bit.
#[test]
fn the_summary_names_the_png_depth_the_images_are_written_in() {
    let tmp = tempfile::tempdir().expect("tempdir");
    for (bits, says) in
        [("8", "16-bit PNG of 8-bit counts,"), ("12", "16-bit PNG of 12-bit counts,"), ("16", "16-bit PNG,")]
    {
        let dir = tmp.path().join(bits);
        let o = run_small(&dir, &["--bit-depth", bits]);
        let (out, err) = text(&o);
        assert!(o.status.success(), "stdout: {out}\nstderr: {err}");
        assert!(out.contains(&format!("images    5 × {says}")), "{bits}: {out}");
        // The PNG header's bit depth (IHDR: 8-byte signature, 8-byte chunk head, 8 bytes of size).
        let png = std::fs::read(dir.join("images/cam000.png")).expect("an image");
        assert_eq!(png[24], 16, "{bits}-bit counts are written in a 16-bit PNG");
    }
}

/// A truth volume mostly below zero was imaged as black (the signed integrals clipped at zero)
/// and refused as cameras that did not see the phantom; its negative voxels are now named.
#[test]
fn a_truth_volume_with_negative_voxels_is_warned_of() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let aabb = fluidnerf_core::Aabb::cube(Default::default(), 2.0);
    let truth = tmp.path().join("signed.npy");
    let v = fluidnerf_core::Volume::from_fn([12, 12, 12], aabb, |p| if p.length() < 0.4 { 1.0 } else { -0.5 });
    fluidnerf_io::volume::write_npy(&truth, &v).expect("writes truth");
    let dir = tmp.path().join("set");
    let (d, t) = (dir.to_str().expect("utf-8 path"), truth.to_str().expect("utf-8 path"));
    let o = synth(&["-o", d, "--preset", "demo", "--cameras", "5", "--pixels", "24", "--truth-volume", t]);
    let (_, err) = text(&o);
    assert!(
        err.contains("signed.npy: 1672 of the 1728 voxels are negative (down to -0.5, the largest value is 1)"),
        "{err}"
    );
}
