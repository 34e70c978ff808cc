//! Output folders: a run is never written into its scene (its folder, a folder inside it, or
//! one holding its inputs), `--force` replaces only fluidnerf's own runs, and `import`,
//! `export`, `render`, `compare` and `synth` refuse folders that hold results of another kind
//! (and exports and renders the scene's folder and its inputs' folders).

use crate::common;
use common::*;

use std::path::Path;

/// The files under `dir`, relative, sorted.
fn files(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("reads the folder") {
            let p = e.expect("entry").path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(dir).expect("inside").display().to_string());
            }
        }
    }
    out.sort();
    out
}

/// A scene whose truth is `truth/volume.npy` (the name a run's volume has).
fn scene_with_truth_named_volume(d: &Path) {
    ok(&fluidnerf(d, &["synth", "--pixels", "16", "--resolution", "12", "--cameras", "4", "-o", "s", "-q"]));
    let s = d.join("s");
    std::fs::rename(s.join("truth/truth.npy"), s.join("truth/volume.npy")).expect("renames the truth");
    let text = std::fs::read_to_string(s.join("transforms.json")).expect("reads");
    assert!(text.contains("truth/truth.npy"));
    std::fs::write(s.join("transforms.json"), text.replace("truth/truth.npy", "truth/volume.npy")).expect("writes");
}

#[test]
fn reconstruct_never_writes_into_the_scene_or_replaces_what_is_not_a_run() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    scene_with_truth_named_volume(d);
    let before = files(&d.join("s"));
    let run = |out: &str, extra: &[&str]| {
        let mut args = vec!["reconstruct", "s", "-o", out, "-m", "asart", "--resolution", "8"];
        args.extend(["--max-iterations", "2", "-q"]);
        args.extend_from_slice(extra);
        fluidnerf(d, &args)
    };
    for out in ["s/truth", "s/images", "s/new"] {
        for extra in [&[][..], &["--force"]] {
            refused(&run(out, extra), "lies inside the scene folder");
        }
    }
    refused(&run(".", &["--force"]), "contains the scene folder");
    assert_eq!(files(&d.join("s")), before, "the scene is untouched");

    // Images kept outside the scene folder, named by absolute path.
    let text = std::fs::read_to_string(d.join("s/transforms.json")).expect("reads");
    std::fs::rename(d.join("s/images"), d.join("images")).expect("moves the images");
    let abs = d.join("images").canonicalize().expect("exists");
    std::fs::write(d.join("s/transforms.json"), text.replace("\"images/", &format!("\"{}/", abs.display())))
        .expect("writes");
    refused(&run("images", &["--force"]), "an image the scene reads");
    ok(&run("run", &[]));

    // A folder with a run's file names but no run is never replaced, even with --force.
    std::fs::create_dir_all(d.join("mine")).expect("mkdir");
    std::fs::write(d.join("mine/volume.npy"), "mine").expect("writes");
    refused(&run("mine", &["--force"]), "not a fluidnerf run folder");
    assert_eq!(std::fs::read_to_string(d.join("mine/volume.npy")).expect("kept"), "mine");
    // A run is.
    ok(&run("run", &["--force"]));
}

#[test]
fn import_export_render_and_synth_refuse_folders_of_another_kind() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    ok(&fluidnerf(d, &["synth", "--pixels", "16", "--resolution", "12", "--cameras", "4", "-o", "s", "-q"]));
    let recon = ["-m", "asart", "--resolution", "8", "--max-iterations", "2", "-q"];
    ok(&fluidnerf(d, &[&["reconstruct", "s", "-o", "r1"][..], &recon].concat()));
    ok(&fluidnerf(d, &[&["reconstruct", "s", "-o", "r2"][..], &recon].concat()));
    ok(&fluidnerf(d, &["export", "r1", "-o", "exp", "--npy", "-q"]));
    ok(&fluidnerf(d, &["render", "r1", "-s", "s", "-o", "views", "--camera", "0", "-q"]));
    let (scene, run1, run2) = (files(&d.join("s")), files(&d.join("r1")), files(&d.join("r2")));

    for force in [&[][..], &["--force"]] {
        let import = |out: &str| fluidnerf(d, &[&["import", "--transforms", "s", "-o", out][..], force].concat());
        refused(&import("r1"), "is a reconstruction run folder");
        refused(&import("exp"), "is an export folder");
        refused(&import("views"), "is a folder of rendered views");
        let export = |out: &str| fluidnerf(d, &[&["export", "r1", "-o", out, "--npy", "-q"][..], force].concat());
        refused(&export("s"), "is a scene folder");
        refused(&export("r1"), "is a reconstruction run folder");
        refused(&export("views"), "is a folder of rendered views");
        let render = |out: &str| {
            fluidnerf(d, &[&["render", "r1", "-s", "s", "-o", out, "--camera", "0", "-q"][..], force].concat())
        };
        refused(&render("r2"), "is a reconstruction run folder");
        refused(&render("s"), "is a scene folder");
        refused(&render("exp"), "is an export folder");
        let synth = |out: &str| fluidnerf(d, &[&["synth", "--pixels", "16", "-o", out, "-q"][..], force].concat());
        refused(&synth("r1"), "is a reconstruction run folder");
        refused(&synth("exp"), "is an export folder");
        let reconstruct = |out: &str| fluidnerf(d, &[&["reconstruct", "s", "-o", out][..], &recon, force].concat());
        refused(&reconstruct("exp"), "is an export folder");
        refused(&reconstruct("views"), "is a folder of rendered views");
        // Nor do exports and renders go among the scene's inputs, the scene given or recorded.
        refused(&render("s/images"), "holds");
        refused(&export("s/truth"), "holds");
        let compare = |out: &str| fluidnerf(d, &[&["compare", "r1", "-o", out][..], force].concat());
        refused(&compare("s"), "is a scene folder");
        refused(&compare("r2"), "is a reconstruction run folder");
        // A file where the folder, or one of its parents, would go is named as such.
        std::fs::write(d.join("afile"), "mine").expect("writes");
        for out in [export("afile"), render("afile"), synth("afile"), compare("afile")] {
            refused(&out, "afile: exists and is not a folder");
        }
        refused(&export("afile/sub"), "afile/sub: cannot create the output folder, ");
        assert_eq!(std::fs::read_to_string(d.join("afile")).expect("reads"), "mine");
    }
    assert_eq!(files(&d.join("s")), scene);
    assert_eq!(files(&d.join("r1")), run1);
    assert_eq!(files(&d.join("r2")), run2);
    // The same commands into folders of their own kind go on as before.
    ok(&fluidnerf(d, &["export", "r1", "-o", "exp", "--npy", "--force", "-q"]));
    ok(&fluidnerf(d, &["render", "r1", "-s", "s", "-o", "views", "--camera", "0", "--force", "-q"]));
    // A folder of their own inside the scene's is allowed for renders and exports.
    ok(&fluidnerf(d, &["render", "r1", "-o", "s/renders", "--camera", "0", "-q"]));
    ok(&fluidnerf(d, &["export", "r1", "-o", "s/exports", "--npy", "-q"]));
}

/// An output folder that takes no new file (here under /sys, read-only even for root) is
/// refused before any work by every command that writes one: it failed only once the results
/// were ready.
#[test]
fn an_unwritable_output_folder_is_refused_before_any_work() {
    let sys = Path::new("/sys/kernel");
    if !sys.is_dir() {
        return;
    }
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    ok(&fluidnerf(d, &["synth", "--pixels", "16", "--resolution", "8", "--cameras", "4", "-o", "s", "-q"]));
    ok(&fluidnerf(
        d,
        &["reconstruct", "s", "-o", "r", "-m", "sart", "--resolution", "8", "--max-iterations", "2", "-q"],
    ));
    for out in ["/sys/kernel", "/sys/kernel/fluidnerf-out/sub"] {
        let needle = format!("{out}: cannot write into the output folder");
        let synth = ["synth", "--pixels", "16", "--resolution", "8", "--cameras", "4", "-o", out, "--force"];
        refused(&fluidnerf(d, &synth), &needle);
        refused(&fluidnerf(d, &["export", "r", "-o", out, "--npy"]), &needle);
        refused(&fluidnerf(d, &["render", "r", "-o", out]), &needle);
        refused(&fluidnerf(d, &["compare", "r", "-o", out]), &needle);
    }
}

/// `--force` replaces a finished run only once the new run has passed its own checks: a run
/// refused by them (held-out stopping without a held-out view, a time-resolved method on a
/// static scene, too little memory) leaves the earlier run as it was, and one that passes
/// them replaces it.
#[test]
fn a_forced_run_refused_by_its_checks_leaves_the_earlier_run() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 8, &[]);
    let reconstruct = |extra: &[&str]| {
        let method = if extra.contains(&"tr-fast") { &[][..] } else { &["--method", "asart"][..] };
        let args = ["reconstruct", "scene", "-o", "run", "--resolution", "8", "-q"];
        fluidnerf(d, &[&args[..], method, extra].concat())
    };
    ok(&reconstruct(&["--max-iterations", "3"]));
    let before = files(&d.join("run"));
    let volume = std::fs::read(d.join("run/volume.npy")).expect("volume");
    for (extra, says) in [
        (&["--stop", "held-out", "--force"][..], "held-out"),
        (&["--method", "tr-fast", "--force"][..], "tr-fast"),
        (&["--memory-limit", "0.000001", "--force"][..], "memory"),
    ] {
        refused(&reconstruct(extra), says);
        assert_eq!(files(&d.join("run")), before, "{extra:?}");
        assert_eq!(std::fs::read(d.join("run/volume.npy")).expect("volume"), volume, "{extra:?}");
    }
    ok(&fluidnerf(d, &["eval", "run", "-q"]));
    // A --force run killed after it set the earlier run aside and before it wrote anything
    // leaves it in `.replaced/`; the next command to read the folder puts it back.
    let aside = d.join("run/.replaced");
    let set_aside = || {
        std::fs::create_dir(&aside).expect("aside");
        for name in files(&d.join("run")) {
            std::fs::rename(d.join("run").join(&name), aside.join(&name)).expect("set aside");
        }
    };
    set_aside();
    ok(&fluidnerf(d, &["export", "run", "-o", "out", "--npy", "-q"]));
    assert!(!aside.exists());
    assert_eq!(std::fs::read(d.join("run/volume.npy")).expect("volume"), volume);
    // Every reader, also those that read config.json or report.json first: they said the
    // folder named no scene, held no run to continue or no report.
    for (k, args) in [
        &["eval", "run", "--force", "-q"][..],
        &["render", "run", "-o", "views", "-q"],
        &["compare", "run", "-o", "cmp", "-q"],
        &["reconstruct", "-o", "run", "--resume", "-q"],
    ]
    .iter()
    .enumerate()
    {
        set_aside();
        let out = fluidnerf(d, args);
        // A voxel run is not continued: refused as such, once its files are back.
        if k == 3 {
            refused(&out, "--resume does not apply to --method asart");
            assert!(!String::from_utf8_lossy(&out.stderr).contains("no config.json"), "{args:?}");
        } else {
            ok(&out);
        }
        assert!(!aside.exists(), "{args:?}");
        assert_eq!(std::fs::read(d.join("run/volume.npy")).expect("volume"), volume, "{args:?}");
    }
    ok(&reconstruct(&["--max-iterations", "1", "--force"]));
    let report = std::fs::read_to_string(d.join("run/report.json")).expect("report");
    assert!(report.contains("\"iterations\": 1"), "replaced: {report}");
    assert!(!d.join("run/.replaced").exists());
}
