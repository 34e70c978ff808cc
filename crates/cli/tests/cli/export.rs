//! End-to-end tests of `fluidnerf export` on tiny volumes generated in a temporary directory.

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Volume};

fn fluidnerf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf")).args(args).output().expect("runs the binary")
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn linear(p: DVec3) -> f32 {
    (1.0 + 0.5 * p.x - 0.25 * p.y + 2.0 * p.z) as f32
}

/// A linear field on [0, 4]³ (16³ voxels) as `.vti`; trilinear resampling reproduces it exactly
/// inside the hull of the voxel centres.
fn source(dir: &Path) -> std::path::PathBuf {
    let vol = Volume::from_fn([16, 16, 16], Aabb::new(DVec3::ZERO, DVec3::splat(4.0)), linear);
    let path = dir.join("recon.vti");
    fluidnerf_io::volume::write_vti(&path, &vol).expect("writes the source");
    path
}

#[test]
fn vti_export_has_the_right_origin_spacing_and_values() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    let o = fluidnerf(&[
        "export",
        src.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
        "--vti",
        "--npy",
        "--raw",
        "--tiff",
        "--box",
        "0.5,1,1,3.5,3,2",
        "--resolution",
        "12",
    ]);
    ok(&o);
    // Box 3 × 2 × 1 at 12 cells along x: cubic cells of 0.25.
    let v = fluidnerf_io::volume::read_vti(&out.join("volume.vti")).expect("reads back");
    assert_eq!(v.dims, [12, 8, 4]);
    assert!((v.aabb.min - DVec3::new(0.5, 1.0, 1.0)).abs().max_element() < 1e-6, "{:?}", v.aabb);
    assert!((v.aabb.max - DVec3::new(3.5, 3.0, 2.0)).abs().max_element() < 1e-6, "{:?}", v.aabb);
    assert!((v.spacing() - DVec3::splat(0.25)).abs().max_element() < 1e-9);
    // VTK point data sit at grid points: the first one is the first voxel centre.
    let text = std::fs::read(out.join("volume.vti")).expect("reads");
    let header = String::from_utf8_lossy(&text[..text.len().min(2000)]).to_string();
    let origin = header.split("Origin=\"").nth(1).and_then(|s| s.split('"').next()).expect("an Origin attribute");
    let origin: Vec<f64> = origin.split_whitespace().map(|x| x.parse().expect("a number")).collect();
    assert!(
        (origin[0] - 0.625).abs() < 1e-9 && (origin[1] - 1.125).abs() < 1e-9 && (origin[2] - 1.125).abs() < 1e-9,
        "{origin:?}"
    );
    let spacing = header.split("Spacing=\"").nth(1).and_then(|s| s.split('"').next()).expect("a Spacing attribute");
    assert!(spacing.split_whitespace().all(|x| (x.parse::<f64>().expect("a number") - 0.25).abs() < 1e-9), "{spacing}");
    for k in 0..4 {
        for j in 0..8 {
            for i in 0..12 {
                let want = linear(v.voxel_centre(i, j, k));
                assert!((v.get(i, j, k) - want).abs() < 1e-4, "voxel ({i},{j},{k}): {} vs {want}", v.get(i, j, k));
            }
        }
    }
    // The .npy holds the same values.
    let n = fluidnerf_io::volume::read_npy(&out.join("volume.npy"), v.aabb).expect("reads");
    assert_eq!(n.data, v.data);
    let raw = fluidnerf_io::volume::read_raw(&out.join("volume.raw")).expect("reads with its sidecar");
    assert_eq!((raw.dims, raw.aabb), (v.dims, v.aabb));
    assert_eq!(raw.data, v.data);
    // The TIFF stack holds the same values and, from its calibration alone, the same box.
    let tif = fluidnerf_io::volume::read_tiff_stack(&out.join("volume.tif"), None, None).expect("reads the stack");
    assert_eq!((tif.dims, &tif.data), (v.dims, &v.data));
    assert!(
        (tif.aabb.min - v.aabb.min).abs().max_element() < 1e-9
            && (tif.aabb.max - v.aabb.max).abs().max_element() < 1e-9
    );
    // ... and is read back as a reconstruction of its own, without a scene.
    let again_out = dir.path().join("from_tif");
    ok(&fluidnerf(&[
        "export",
        out.join("volume.tif").to_str().expect("utf-8"),
        "-o",
        again_out.to_str().expect("utf-8"),
        "--npy",
    ]));
    let n = fluidnerf_io::volume::read_npy(&again_out.join("volume.npy"), v.aabb).expect("reads");
    assert_eq!((n.dims, &n.data), (v.dims, &v.data));
    let settings: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("export.json")).expect("settings")).expect("JSON");
    assert_eq!(settings["dims"], serde_json::json!([12, 8, 4]));
    // Refuses to overwrite without --force.
    let again = fluidnerf(&["export", src.to_str().expect("utf-8"), "--out", out.to_str().expect("utf-8"), "--vti"]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
}

/// `--average` takes cell averages of trained fields; a volume is resampled as it is, so
/// on one the option did nothing without a word, as `--time` does with one (which export.json
/// then does not record).
#[test]
fn average_on_a_volume_is_warned_of() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    let o = fluidnerf(&[
        "export",
        src.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
        "--npy",
        "--average",
        "4",
        "--time",
        "3",
    ]);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--average 4 has no effect") && err.contains("recon.vti is a volume"), "{err}");
    assert!(err.contains("--time 3 has no effect"), "{err}");
    // export.json records the time sampled, which is none: not the 3 that changed nothing.
    let settings: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("export.json")).expect("settings")).expect("JSON");
    assert_eq!(settings["time"], serde_json::Value::Null);
}

#[test]
fn slices_comparison_and_isosurface() {
    let dir = tempfile::tempdir().expect("tempdir");
    let aabb = Aabb::new(DVec3::ZERO, DVec3::new(4.0, 2.0, 2.0));
    let c = aabb.centre();
    let ball = |p: DVec3| (1.0 - ((p - c).length() / 0.8).powi(2) * 0.5) as f32;
    let truth = Volume::from_fn([32, 16, 16], aabb, ball);
    let recon = Volume::from_fn([32, 16, 16], aabb, |p| ball(p) + 0.01 * p.x as f32);
    let (t, r) = (dir.path().join("truth.vti"), dir.path().join("recon.vti"));
    fluidnerf_io::volume::write_vti(&t, &truth).expect("writes");
    fluidnerf_io::volume::write_vti(&r, &recon).expect("writes");
    let out = dir.path().join("out");
    let o = fluidnerf(&[
        "export",
        r.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
        "--slices",
        "z=0.5,x=0.25",
        "--compare",
        t.to_str().expect("utf-8"),
        "--isosurface",
        "0.5",
        "--mesh",
        "ply,obj",
    ]);
    ok(&o);
    for f in ["slice_z_0.500.png", "slice_x_0.250.png", "compare_z_0.500.png", "compare_x_0.250.png"] {
        // Colour pictures read back as luminance: only their size matters here.
        let img = fluidnerf_io::image::read_image(&out.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert!(img.width > 200 && img.height > 150, "{f}: {}x{}", img.width, img.height);
    }
    assert!(!out.join("volume.npy").exists(), "volumes only when asked for");
    // A .npy truth holds no box: without --scene it fills the reconstruction's.
    let tn = dir.path().join("truth.npy");
    fluidnerf_io::volume::write_npy(&tn, &truth).expect("writes");
    let out_npy = dir.path().join("out_npy");
    ok(&fluidnerf(&[
        "export",
        r.to_str().expect("utf-8"),
        "--out",
        out_npy.to_str().expect("utf-8"),
        "--slices",
        "z=0.5",
        "--compare",
        tn.to_str().expect("utf-8"),
    ]));
    assert!(out_npy.join("compare_z_0.500.png").is_file());
    // Without slices a truth is drawn nowhere: it was taken and ignored without a word.
    let unused = dir.path().join("unused");
    let refused = fluidnerf(&[
        "export",
        r.to_str().expect("utf-8"),
        "--out",
        unused.to_str().expect("utf-8"),
        "--npy",
        "--compare",
        tn.to_str().expect("utf-8"),
    ]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("add --slices"), "--compare without slices: {err}");
    assert!(!unused.exists(), "a refused export wrote");
    let ply = std::fs::read(out.join("isosurface.ply")).expect("a mesh");
    assert!(ply.starts_with(b"ply\n"));
    let obj = std::fs::read_to_string(out.join("isosurface.obj")).expect("a mesh");
    assert!(obj.lines().filter(|l| l.starts_with("f ")).count() > 100);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("isosurface at 0.5"), "{stdout}");
    // The isosurface at `level` alone, into `name`: what it printed.
    let surface = |name: &str, level: &str| {
        let o = fluidnerf(&[
            "export",
            r.to_str().expect("utf-8"),
            "--out",
            dir.path().join(name).to_str().expect("utf-8"),
            "--isosurface",
            level,
        ]);
        ok(&o);
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    // A level no value reaches gives an empty surface, said as such, never an area of -0.
    let stdout = surface("empty", "5");
    assert!(stdout.contains("isosurface at 5: empty, area 0:") && !stdout.contains("area -"), "{stdout}");
    // A negative level is a value (algebraic methods leave negative voxels), not an option.
    let stdout = surface("below", "-1");
    assert!(stdout.contains("isosurface at -1:") && !stdout.contains("empty"), "{stdout}");
    // Bad slice specifications are rejected before any work.
    let bad =
        fluidnerf(&["export", r.to_str().expect("utf-8"), "--out", out.to_str().expect("utf-8"), "--slices", "w=0.5"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("axis"));
}

#[test]
fn a_box_apart_from_the_reconstruction_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    let export = |b: &str| {
        fluidnerf(&[
            "export",
            src.to_str().expect("utf-8"),
            "--out",
            out.to_str().expect("utf-8"),
            "--npy",
            "--box",
            b,
            "--resolution",
            "8",
        ])
    };
    // Beyond the box, and touching it only at a face: nothing of the reconstruction inside.
    for b in ["1000,1000,1000,1010,1010,1010", "4,0,0,5,4,4", "-2,-2,-2,0,4,4"] {
        let o = export(b);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("does not overlap"), "--box {b}: {err}");
        assert!(!out.exists(), "--box {b} wrote {}", out.display());
    }
    ok(&export("3,3,3,5,5,5"));
}

/// A --compare truth in a box apart from the exported one is refused naming both boxes: its
/// slices were drawn empty beside the reconstruction's, and the export succeeded.
#[test]
fn a_compare_truth_apart_from_the_export_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let far = Volume::from_fn([8, 8, 8], Aabb::new(DVec3::splat(100.0), DVec3::splat(104.0)), linear);
    let truth = dir.path().join("far.vti");
    fluidnerf_io::volume::write_vti(&truth, &far).expect("writes the truth");
    let out = dir.path().join("out");
    let o = fluidnerf(&[
        "export",
        src.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
        "--slices",
        "z=0.5",
        "--compare",
        truth.to_str().expect("utf-8"),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("far.vti: the truth fills the box [100, 100, 100] .. [104, 104, 104], which does not overlap the exported box [0, 0, 0] .. [4, 4, 4]"), "{err}");
    assert!(!out.exists(), "wrote {}", out.display());
}

/// With --force, a folder where an output goes is refused before anything is written: found only
/// when its turn came, it left the outputs before it overwritten and export.json stale.
#[test]
fn a_folder_in_an_outputs_place_is_refused_before_writing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    std::fs::create_dir_all(out.join("volume.vti")).expect("mkdir");
    std::fs::write(out.join("volume.npy"), "mine").expect("writes");
    let (src, out_text) = (src.to_str().expect("utf-8"), out.to_str().expect("utf-8"));
    let o = fluidnerf(&["export", src, "-o", out_text, "--npy", "--vti", "--force"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("volume.vti exists and is not a file"), "{e}");
    assert_eq!(std::fs::read_to_string(out.join("volume.npy")).expect("kept"), "mine");
}

/// A forced export into the folder of an earlier one removes the earlier outputs it does not
/// write again (the `export.json` left would describe none of them); other files stay.
#[test]
fn a_forced_export_removes_the_earlier_outputs_it_does_not_write() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let (src, out) = (src.to_str().expect("utf-8"), dir.path().join("out"));
    let out_text = out.to_str().expect("utf-8");
    ok(&fluidnerf(&["export", src, "-o", out_text, "--npy", "--vti", "--raw", "--tiff", "--slices", "z=0.5,x=0.25"]));
    for f in ["volume.vti", "volume.raw", "volume.raw.json", "volume.tif", "slice_x_0.250.png", "slice_z_0.500.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    std::fs::write(out.join("notes.txt"), "keep me").expect("writes");
    let o = fluidnerf(&["export", src, "-o", out_text, "--npy", "--slices", "z=0.5", "--resolution", "8", "--force"]);
    ok(&o);
    let mut left: Vec<String> = std::fs::read_dir(&out)
        .expect("lists")
        .map(|e| e.expect("entry").file_name().into_string().expect("utf-8"))
        .collect();
    left.sort();
    assert_eq!(left, ["export.json", "notes.txt", "slice_z_0.500.png", "volume.npy"]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("an output of the earlier export"));
}

/// The files an export reads are never its outputs, even with --force: a volume exported into
/// its own folder was written over, and a second export there removed it as an earlier output.
#[test]
fn an_export_never_writes_over_or_removes_what_it_reads() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    let out_text = out.to_str().expect("utf-8");
    ok(&fluidnerf(&["export", src.to_str().expect("utf-8"), "-o", out_text, "--vti", "--raw"]));
    let own = |name: &str| std::fs::read(out.join(name)).expect("reads");
    let (vti, raw, sidecar) = (own("volume.vti"), own("volume.raw"), own("volume.raw.json"));
    let input = |name: &str| out.join(name).to_str().expect("utf-8").to_string();
    for args in [
        vec!["export", &input("volume.vti"), "-o", out_text, "--vti", "--force"],
        vec!["export", &input("volume.vti"), "-o", out_text, "--npy", "--force"],
        vec!["export", &input("volume.raw"), "-o", out_text, "--raw", "--force"],
        vec!["export", &input("volume.raw"), "-o", out_text, "--npy", "--force"],
    ] {
        let o = fluidnerf(&args);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains("is the reconstruction read; an input is never overwritten"), "{e}");
    }
    let truth = dir.path().join("truth");
    let truth_text = truth.to_str().expect("utf-8");
    ok(&fluidnerf(&["export", src.to_str().expect("utf-8"), "-o", truth_text, "--vti"]));
    let truth_vti = std::fs::read(truth.join("volume.vti")).expect("reads");
    let compare = truth.join("volume.vti").to_str().expect("utf-8").to_string();
    let args = ["export", &input("volume.vti"), "-o", truth_text, "--vti", "--slices", "z=0.5", "--compare", &compare];
    let o = fluidnerf(&[&args[..], &["--force"]].concat());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("is the ground truth given with --compare"), "{e}");
    assert_eq!(std::fs::read(truth.join("volume.vti")).expect("kept"), truth_vti);
    assert_eq!((own("volume.vti"), own("volume.raw"), own("volume.raw.json")), (vti, raw, sidecar));
}

/// A run's box is in its scene's unit, which its report records: an export of the run folder
/// labels and calibrates its files in that unit without the scene, and refuses another --units,
/// which would calibrate a TIFF stack of a scene in metres as millimetres.
#[test]
fn an_export_keeps_the_units_of_the_run_and_refuses_others() {
    let dir = tempfile::tempdir().expect("tempdir");
    common::demo_scene(dir.path(), "ball", 4, 16, 12, &[]);
    common::edit_json(&dir.path().join("scene/transforms.json"), |t| t["units"] = "m".into());
    let run = ["reconstruct", "scene", "-o", "run", "-m", "asart", "--resolution", "12", "-q"];
    common::ok(&common::fluidnerf(dir.path(), &run));

    common::ok(&common::fluidnerf(dir.path(), &["export", "run", "-o", "out", "--tiff", "-q"]));
    assert_eq!(common::json(&dir.path().join("out/export.json"))["units"], "m");
    let tiff = fluidnerf_io::volume::read_tiff_stack(&dir.path().join("out/volume.tif"), None, Some("m"));
    let box_max = tiff.expect("reads the stack").aabb.max;
    assert!((box_max - DVec3::splat(20.0)).abs().max_element() < 1e-3, "{box_max:?}");

    let o = common::fluidnerf(dir.path(), &["export", "run", "-o", "other", "--tiff", "--units", "mm"]);
    common::refused(&o, "--units mm: the run run is in m");
    assert!(!dir.path().join("other/volume.tif").exists());
    let o = common::fluidnerf(dir.path(), &["export", "run", "-s", "scene", "-o", "other", "--units", "cm"]);
    common::refused(&o, "--units cm: the scene");
}

/// A calibrated TIFF stack records its own length unit. Exported without a scene, it was
/// labelled mm (or --units) with its numbers unchanged, a stack in µm coming out a thousand
/// times too large; and a calibrated truth given to --compare was read in its own unit beside a
/// run in another. Now the stack's unit labels the export, --units converts it, and the truth
/// is converted to the run's unit.
#[test]
fn a_calibrated_stack_is_exported_in_its_own_unit_or_converted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let aabb = Aabb::new(DVec3::new(0.0, 0.0, 0.0), DVec3::new(8000.0, 6000.0, 4000.0));
    let v = Volume::from_fn([8, 6, 4], aabb, |p| (p.x / 1000.0) as f32);
    fluidnerf_io::volume::write_tiff_stack(&d.join("um.tif"), &v, "µm").expect("writes the stack");
    common::ok(&common::fluidnerf(d, &["export", "um.tif", "-o", "own", "--npy", "-q"]));
    let e = common::json(&d.join("own/export.json"));
    assert_eq!(e["units"], "µm");
    assert_eq!(e["aabb"]["max"], serde_json::json!([8000.0, 6000.0, 4000.0]));
    common::ok(&common::fluidnerf(d, &["export", "um.tif", "-o", "mm", "--npy", "--units", "mm", "-q"]));
    let e = common::json(&d.join("mm/export.json"));
    assert_eq!(e["units"], "mm");
    assert_eq!(e["aabb"]["max"], serde_json::json!([8.0, 6.0, 4.0]));
    let o = common::fluidnerf(d, &["export", "um.tif", "-o", "odd", "--npy", "--units", "furlong"]);
    common::refused(&o, "--units furlong: um.tif is calibrated in µm, and only nm, µm, mm, cm and m are converted");

    // A run in mm beside a truth calibrated in cm: the truth's box is converted, so its panel is
    // drawn where the run's field is.
    common::demo_scene(d, "ball", 4, 16, 12, &[]);
    common::ok(&common::fluidnerf(
        d,
        &["reconstruct", "scene", "-o", "run", "-m", "asart", "--resolution", "12", "-q"],
    ));
    let scene = fluidnerf_io::scene::load_scene(&d.join("scene")).expect("scene");
    let truth = fluidnerf_io::volume::read_npy(&d.join("scene/truth/truth.npy"), scene.aabb).expect("truth");
    let in_cm =
        Volume::from_vec(truth.dims, Aabb::new(truth.aabb.min / 10.0, truth.aabb.max / 10.0), truth.data.clone());
    fluidnerf_io::volume::write_tiff_stack(&d.join("cm.tif"), &in_cm, "cm").expect("writes the stack");
    let slices = ["--slices", "z=0.5"];
    common::ok(&common::fluidnerf(
        d,
        &[&["export", "run", "-o", "a", "--compare", "scene/truth/truth.npy", "-q"][..], &slices].concat(),
    ));
    common::ok(&common::fluidnerf(
        d,
        &[&["export", "run", "-o", "b", "--compare", "cm.tif", "-q"][..], &slices].concat(),
    ));
    let picture = |out: &str| std::fs::read(d.join(out).join("compare_z_0.500.png")).expect("the comparison");
    assert_eq!(picture("a"), picture("b"), "the truth in cm drawn as the truth in mm");
}

/// The colour map and the colour-bar label style the slice pictures: given to an export that
/// draws none, they were taken and ignored without a word.
#[test]
fn slice_styles_without_slices_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let src = src.to_str().expect("utf-8");
    let out = dir.path().join("out");
    for (option, value) in [("--colormap", "magma"), ("--value-label", "E [W/m³]")] {
        let o = fluidnerf(&["export", src, "--out", out.to_str().expect("utf-8"), "--npy", option, value]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{option}: {err}");
        assert!(err.contains(&format!("{option} styles the slice pictures, and none are asked for")), "{err}");
        assert!(!out.exists(), "{option}: a refused export wrote");
    }
    // The default export draws slices: there they apply, and export.json records them.
    ok(&fluidnerf(&["export", src, "--out", out.to_str().expect("utf-8"), "--colormap", "magma"]));
    let settings = common::json(&out.join("export.json"));
    assert_eq!(settings["colormap"], "magma");
    assert_eq!(settings["value_label"], "emission E [a.u.]");
}

/// The diverging map is refused for the field's slices, and an unknown map's message lists the
/// maps that are accepted: it listed "diverging" among them.
#[test]
fn the_colour_maps_offered_are_those_accepted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    let (src, out) = (src.to_str().expect("utf-8"), out.to_str().expect("utf-8"));
    let err = |map: &str| {
        let o = fluidnerf(&["export", src, "--out", out, "--colormap", map]);
        assert!(!o.status.success(), "{map}");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let unknown = err("jet");
    assert!(unknown.contains("expected one of viridis, magma, inferno, cividis, gray\n"), "{unknown}");
    let diverging = err("diverging");
    assert!(diverging.contains("kept for differences") && diverging.contains("viridis"), "{diverging}");
    assert!(!dir.path().join("out").exists());
}

/// The reconstruction's own box given as `--box` (typed from the scene) resampled a volume to
/// 128 voxels along its longest side, though `--resolution`'s default keeps "a volume's own grid
/// when the box is unchanged"; and `export.json` did not record the spacing its help promises.
#[test]
fn the_own_box_given_keeps_the_grid_and_export_json_records_the_spacing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    let (src, out_s) = (src.to_str().expect("utf-8"), out.to_str().expect("utf-8"));
    // Typed to a thousandth of a voxel (0.25 here), as `info` prints boxes to three decimals.
    ok(&fluidnerf(&["export", src, "--out", out_s, "--npy", "--box", "-0.0002,0,0,4.0002,4,4"]));
    let settings = common::json(&out.join("export.json"));
    assert_eq!(settings["dims"], serde_json::json!([16, 16, 16]));
    assert_eq!(settings["spacing"], serde_json::json!([0.25, 0.25, 0.25]));
    assert_eq!(settings["average"], serde_json::Value::Null, "a volume is resampled, not averaged");
    assert_eq!(settings["time"], serde_json::Value::Null, "a volume of no recorded instant");
    // Another box still samples 128 voxels along its longest side, of the spacing recorded.
    ok(&fluidnerf(&["export", src, "--out", out_s, "--npy", "--box", "0,0,0,4,2,1", "--force"]));
    let settings = common::json(&out.join("export.json"));
    assert_eq!(settings["dims"], serde_json::json!([128, 64, 32]));
    assert_eq!(settings["spacing"], serde_json::json!([0.03125, 0.03125, 0.03125]));
}

/// A `--box` reaching beyond the reconstruction's, and a `--compare` truth covering only part of
/// the exported box, were exported without a word: the volume is zero there, and the truth's
/// panels too, the difference showing the whole reconstruction as error.
#[test]
fn boxes_reaching_beyond_the_reconstruction_or_the_truth_are_warned_of() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = source(dir.path());
    let out = dir.path().join("out");
    let (src, out_s) = (src.to_str().expect("utf-8"), out.to_str().expect("utf-8"));
    let o = fluidnerf(&["export", src, "--out", out_s, "--npy", "--box", "-4,0,0,4,4,4", "--resolution", "8"]);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(
            "--box reaches beyond the reconstruction's box [0, 0, 0] .. [4, 4, 4]: the export is zero there, 50 %"
        ),
        "{err}"
    );
    let o =
        fluidnerf(&["export", src, "--out", out_s, "--npy", "--box", "1,1,1,3,3,3", "--resolution", "8", "--force"]);
    ok(&o);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("reaches beyond"), "a box inside the reconstruction's");

    let small = Volume::from_fn([8, 8, 8], Aabb::new(DVec3::ZERO, DVec3::new(2.0, 4.0, 4.0)), linear);
    let truth = dir.path().join("half.vti");
    fluidnerf_io::volume::write_vti(&truth, &small).expect("writes the truth");
    let compare = |truth: &Path| {
        let truth = truth.to_str().expect("utf-8");
        fluidnerf(&["export", src, "--out", out_s, "--slices", "z=0.5", "--compare", truth, "--force"])
    };
    let o = compare(&truth);
    ok(&o);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("half.vti: the truth fills the box [0, 0, 0] .. [2, 4, 4], 50 % of the exported box"),
        "{err}"
    );
    let o = compare(&source(&dir.path().join("whole")));
    ok(&o);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("the truth fills"), "the same box");
}

/// The enclosed volume printed for an isosurface that leaves the box was the divergence
/// theorem's sum over an open mesh: it changed, even in sign, when the box was moved. It is now
/// the volume of the region brighter than the level inside the outermost voxel centres.
#[test]
fn an_open_isosurface_encloses_the_same_volume_wherever_the_box_lies() {
    let dir = tempfile::tempdir().expect("tempdir");
    let enclosed = |shift: f64| {
        // A ball of radius 1.2 centred on the box's face x = 0: cut by the box.
        let aabb = Aabb::new(DVec3::new(shift, 0.0, 0.0), DVec3::new(shift + 4.0, 4.0, 4.0));
        let c = DVec3::new(shift, 2.0, 2.0);
        let ball = Volume::from_fn([32, 32, 32], aabb, |p| (1.0 - 0.5 * ((p - c).length() / 1.2).powi(2)) as f32);
        let path = dir.path().join(format!("ball{shift}.vti"));
        fluidnerf_io::volume::write_vti(&path, &ball).expect("writes");
        let out = dir.path().join(format!("out{shift}"));
        let o = fluidnerf(&[
            "export",
            path.to_str().expect("utf-8"),
            "--out",
            out.to_str().expect("utf-8"),
            "--isosurface",
            "0.5",
        ]);
        ok(&o);
        let text = String::from_utf8_lossy(&o.stdout).into_owned();
        let at = text.find("enclosed volume ").expect("printed") + "enclosed volume ".len();
        let v: f64 = text[at..].split_whitespace().next().expect("a number").parse().expect("a number");
        assert!(text.contains("the surface is open where it leaves the box"), "{text}");
        v
    };
    let (here, there) = (enclosed(0.0), enclosed(-250.0));
    assert!((here - there).abs() <= 1e-3 * here, "{here} against {there}");
    // Inside the outermost centres (x ≥ 1/16): nearly half the ball, less a slab of 1/16.
    let r: f64 = 1.2;
    let h = 4.0 / 32.0 / 2.0;
    let cap = std::f64::consts::PI * (2.0 / 3.0 * r.powi(3) - r * r * h + h.powi(3) / 3.0);
    assert!((here - cap).abs() < 0.03 * cap, "{here} against {cap}");
}
