//! Bad input, as a hostile user would bring it: malformed scenes and options, built from one
//! valid scene. Every case must exit non-zero, name the file, key or option at fault, never
//! panic, and leave nothing behind in the output folder.

use std::path::Path;

use crate::common;
use common::*;

/// How a case breaks the scene (in its own copy) before the command runs.
enum Break {
    None,
    /// Replaces `transforms.json` with this text.
    Transforms(&'static str),
    /// Edits the parsed `transforms.json`.
    Json(fn(&mut serde_json::Value)),
    /// Writes these bytes over a file of the scene.
    File(&'static str, &'static [u8]),
    /// Removes a file of the scene.
    Remove(&'static str),
    /// Replaces a file of the scene with a link to this path (a device, say).
    Link(&'static str, &'static str),
    /// Writes a ground-truth volume built by the function.
    Truth(fn(&Path)),
}

struct Case {
    name: &'static str,
    brk: Break,
    /// The command, with `SCENE` and `OUT` placeholders.
    args: &'static [&'static str],
    /// Text the error must contain (a file, key or option name).
    says: &'static str,
}

const RUN: &[&str] =
    &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--resolution", "8", "--max-iterations", "1"];
const FAST: &[&str] =
    &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--resolution", "8", "--max-iterations", "2"];

/// Gives the scene's frames two instants, 0 and 1, in turn.
fn two_instants(v: &mut serde_json::Value) {
    for (i, f) in v["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
        f["time"] = (i % 2).into();
    }
}

/// A one-iteration `tr-fluidnerf` run with `--time-step` set to this.
macro_rules! tr_step {
    ($step:literal) => {
        &[
            "reconstruct",
            "SCENE",
            "-o",
            "OUT",
            "--method",
            "tr-fluidnerf",
            "--resolution",
            "8",
            "--max-iterations",
            "1",
            "--time-step",
            $step,
        ]
    };
}

fn cases() -> Vec<Case> {
    use Break::*;
    let c = |name, brk, args, says| Case { name, brk, args, says };
    vec![
        c("no transforms.json", Remove("transforms.json"), RUN, "transforms.json"),
        c("transforms.json not JSON", Transforms("{"), RUN, "transforms.json"),
        c("transforms.json an array", Transforms("[]"), RUN, "transforms.json"),
        c("transforms.json empty", Transforms(""), RUN, "transforms.json"),
        c("no frames", Json(|v| v["frames"] = serde_json::json!([])), RUN, "transforms.json"),
        c(
            "frame without a file",
            Json(|v| v["frames"][0].as_object_mut().unwrap().remove("file_path").map(drop).unwrap_or(())),
            RUN,
            "file_path",
        ),
        c("image missing", Remove("images/cam000.png"), RUN, "cam000.png"),
        c("image garbage", File("images/cam000.png", b"not a png"), RUN, "cam000.png"),
        // Read whole, /dev/zero never ended and grew without limit.
        c("image linked to a device", Link("images/cam000.png", "/dev/zero"), RUN, "cam000.png: image file is a device"),
        c("truth missing", Remove("truth/truth.npy"), RUN, "truth.npy"),
        c("truth garbage", File("truth/truth.npy", b"\x93NUMPY garbage"), RUN, "truth.npy"),
        c(
            "two truths of one instant",
            Json(|v| {
                let first = v["truth"][0].clone();
                v["truth"].as_array_mut().unwrap().push(first);
            }),
            RUN,
            "truth entries 0 (truth/truth.npy) and 1 (truth/truth.npy) are both",
        ),
        c(
            "truth with NaN",
            Truth(|p| {
                let mut v =
                    fluidnerf_io::volume::read_npy(p, fluidnerf_core::Aabb::cube(Default::default(), 1.0)).unwrap();
                v.data[5] = f32::NAN;
                fluidnerf_io::volume::write_npy(p, &v).unwrap();
            }),
            RUN,
            "truth.npy",
        ),
        c(
            "every frame held out, fast",
            Json(|v| {
                for f in v["frames"].as_array_mut().unwrap() {
                    f["holdout"] = serde_json::json!(true);
                }
            }),
            FAST,
            "every frame is held out",
        ),
        c("synth noise of 500 %", None, &["synth", "-o", "OUT", "--pixels", "16", "--noise", "5"], "gaussian_noise"),
        c("synth one voxel", None, &["synth", "-o", "OUT", "--pixels", "16", "--resolution", "1"], "resolution"),
        c(
            "synth real-like with the plain sensor's noise",
            None,
            &["synth", "-o", "OUT", "--pixels", "16", "--real-like", "--noise", "0.05"],
            "`sensor.gaussian_noise`: --noise does not apply to a real-like recording",
        ),
        c(
            "study camera count twice",
            None,
            &["study", "-o", "OUT", "--methods", "asart", "--cameras", "4,4", "--noise", "0"],
            "--cameras: 4 is given twice",
        ),
        c(
            "study of an unknown scene preset",
            None,
            &["study", "-o", "OUT", "--methods", "asart", "--cameras", "4", "--noise", "0", "--scene-preset", "nope"],
            "--scene-preset: unknown preset `nope`",
        ),
        c(
            "study method twice",
            None,
            &["study", "-o", "OUT", "--methods", "asart,asart", "--cameras", "4", "--noise", "0"],
            "--methods: asart is given twice",
        ),
        c(
            "study layout twice",
            None,
            &["study", "-o", "OUT", "--methods", "asart", "--cameras", "4", "--layouts", "ring360,ring360"],
            "--layouts: ring360 is given twice",
        ),
        c(
            "study noise levels named alike",
            None,
            &["study", "-o", "OUT", "--methods", "asart", "--cameras", "4", "--noise", "0.0001,0.0002"],
            "--noise: 0.0001 and 0.0002 would share one scene folder",
        ),
        c(
            "study noise on a real-like preset",
            None,
            &["study", "-o", "OUT", "--methods", "asart", "--cameras", "4", "--noise", "0,0.05", "--scene-preset", "real-like-small"],
            "--noise: 0.05 does not apply to real-like-small",
        ),
        c(
            "synth camera held out twice",
            None,
            &["synth", "-o", "OUT", "--pixels", "16", "--holdout", "cam008,1"],
            "--holdout: cam008 and 1 name the same camera",
        ),
        // A transforms.json points at its own images: both options were ignored without a word.
        c(
            "import --images with --transforms",
            None,
            &["import", "--transforms", "SCENE/transforms.json", "-o", "OUT", "--images", "SCENE/images"],
            "'--transforms <TRANSFORMS>' cannot be used with '--images <IMAGES>'",
        ),
        c(
            "import --skip-uncalibrated with --transforms",
            None,
            &["import", "--transforms", "SCENE/transforms.json", "-o", "OUT", "--skip-uncalibrated"],
            "'--transforms <TRANSFORMS>' cannot be used with '--skip-uncalibrated'",
        ),
        // Named the transforms.json being written rather than the option.
        c(
            "import with an intensity scale of zero",
            None,
            &["import", "--transforms", "SCENE/transforms.json", "-o", "OUT", "--intensity-scale", "0"],
            "--intensity-scale must be a positive number",
        ),
        // The scene imported, and every reconstruction of it was refused (cam001 is held out
        // in the file already).
        c(
            "import with every camera held out",
            None,
            &["import", "--transforms", "SCENE/transforms.json", "-o", "OUT", "--holdout", "cam000,cam002,cam003,cam004"],
            "--holdout: every frame would be held out",
        ),
        c(
            "import camera held out twice",
            None,
            &["import", "--transforms", "SCENE/transforms.json", "-o", "OUT", "--holdout", "cam000,cam000"],
            "--holdout: cam000 is given twice",
        ),
        c(
            "held-out time twice",
            Json(two_instants),
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tr-fast", "--holdout-times", "1,1"],
            "--holdout-times on the command line: method.holdout_times: 1 is given twice",
        ),
        c("compare threshold twice", None, &["compare", "SCENE", "-o", "OUT", "--thresholds", "0.5,0.5"], "--thresholds"),
        c(
            "compare a volume file",
            None,
            &["compare", "SCENE/truth/truth.npy", "-o", "OUT"],
            "truth.npy: not a run directory or a report (a JSON object",
        ),
        c(
            "render camera twice",
            None,
            &["render", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--camera", "0,0"],
            "--camera: 0 is given twice",
        ),
        c(
            "export mesh format twice",
            None,
            &["export", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--isosurface", "0.1", "--mesh", "ply,ply"],
            "--mesh: ply is given twice",
        ),
        // Without an isosurface no mesh is written: the format was ignored without a word.
        c(
            "export mesh format without an isosurface",
            None,
            &["export", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--mesh", "obj"],
            "--isosurface",
        ),
        // Each was ignored without a word: the gaussian window has its own side, and without
        // reprojection no ray is cast.
        c(
            "eval uniform window side with the gaussian window",
            None,
            &["eval", "SCENE/truth/truth.npy", "--scene", "SCENE", "--json", "OUT/m.json", "--ssim-window", "gaussian", "--ssim-size", "9"],
            "--ssim-size 9 sets the side of the uniform window",
        ),
        c(
            "eval supersampling without reprojection",
            None,
            &["eval", "SCENE/truth/truth.npy", "--scene", "SCENE", "--json", "OUT/m.json", "--no-reprojection", "--supersample", "4"],
            "--no-reprojection",
        ),
        c(
            "eval region name twice",
            None,
            &["eval", "SCENE/truth/truth.npy", "--scene", "SCENE", "--json", "OUT/m.json", "--regions", "a:0:0.5,a:0.5:1"],
            "--regions: the name a is given twice",
        ),
        c("aabb inverted", Json(|v| v["aabb"] = serde_json::json!([[1, 1, 1], [-1, -1, -1]])), RUN, "aabb"),
        c("aabb missing", Json(|v| drop(v.as_object_mut().unwrap().remove("aabb"))), RUN, "aabb"),
        c("aabb wrong type", Json(|v| v["aabb"] = serde_json::json!("box")), RUN, "aabb"),
        c(
            "aabb small and far out",
            Json(|v| v["aabb"] = serde_json::json!([[1e6, 0, 0], [1.00001e6, 10, 10]])),
            RUN,
            "transforms.json: `aabb`: invalid aabb: the box reaches 1000010 from the origin, more than 10000 times its smallest side (10)",
        ),
        c(
            "aabb tiny",
            Json(|v| v["aabb"] = serde_json::json!([[0, 0, 0], [1e-36, 1e-36, 1e-36]])),
            RUN,
            "transforms.json: `aabb`: invalid aabb: sides must be between 1e-6 and 1e9 world units",
        ),
        c(
            "aabb huge",
            Json(|v| v["aabb"] = serde_json::json!([[-1e12, -1e12, -1e12], [1e12, 1e12, 1e12]])),
            RUN,
            "transforms.json: `aabb`: invalid aabb: sides must be between 1e-6 and 1e9 world units",
        ),
        c("negative intensity_scale", Json(|v| v["intensity_scale"] = serde_json::json!(-1.0)), RUN, "intensity_scale"),
        c("tiny intensity_scale", Json(|v| v["intensity_scale"] = serde_json::json!(1e-40)), RUN, "overflow or vanish"),
        c("huge intensity_scale", Json(|v| v["intensity_scale"] = serde_json::json!(1e300)), RUN, "overflow or vanish"),
        c("negative focal length", Json(|v| v["fl_x"] = serde_json::json!(-5.0)), RUN, "focal"),
        // Infinite in 32-bit floats: every camera was a point, and the run wrote a volume of
        // noise with no error.
        c(
            "focal length beyond 32-bit floats",
            Json(|v| {
                v["fl_x"] = serde_json::json!(1e39);
                v["fl_y"] = serde_json::json!(1e39);
            }),
            RUN,
            "transforms.json: frame 0 (images/cam000.png): invalid intrinsics: focal lengths, principal point and skew \
             must lie within ±1000000000 px",
        ),
        // Such a size left the camera blind, and the error said the camera did not see the box.
        c(
            "image size mistyped as huge",
            Json(|v| {
                v["w"] = serde_json::json!(1_000_000_000u64);
                v["h"] = serde_json::json!(1_000_000_000u64);
            }),
            RUN,
            "cam000.png: image is 20x20 pixels but frame 0's intrinsics say 1000000000x1000000000",
        ),
        c(
            "transform matrix too short",
            Json(|v| v["frames"][0]["transform_matrix"] = serde_json::json!([[1, 0, 0, 0]])),
            RUN,
            "transform_matrix",
        ),
        c("resolution 0", None, &["reconstruct", "SCENE", "-o", "OUT", "--resolution", "0"], "resolution"),
        c(
            "resolution 1",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--resolution", "1"],
            "resolution",
        ),
        c(
            "resolution 5000",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--resolution", "5000"],
            "resolution",
        ),
        c(
            "max-iterations 0 neural",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--max-iterations", "0"],
            "--max-iterations on the command line: stopping.max_iterations",
        ),
        c(
            "max-iterations 0 voxel",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--max-iterations", "0"],
            "max_iterations",
        ),
        // Intervals, patience and caps beyond any run are refused naming the option: 2^64 - 1
        // was taken, an interval never acted and a cap overflowed a progress total.
        c(
            "eval-every beyond any run",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--eval-every", "10000001"],
            "--eval-every on the command line: eval_every: must be at most 10000000 iterations",
        ),
        c(
            "checkpoint-every beyond any run",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--checkpoint-every", "18446744073709551615"],
            "--checkpoint-every on the command line: checkpoint_every: must be at most 10000000 iterations",
        ),
        c(
            "max-iterations beyond any run",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--max-iterations", "18446744073709551615"],
            "--max-iterations on the command line: stopping.max_iterations: must be 1 to 1000000000 iterations",
        ),
        c(
            "holdout-every beyond any run",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--stop", "held-out", "--holdout-every", "10000001"],
            "--holdout-every on the command line: stopping.holdout_every: must be at most 10000000 iterations",
        ),
        c(
            "patience beyond any run",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--stop", "held-out", "--patience", "18446744073709551615"],
            "--patience on the command line: stopping.patience: must be at most 10000000 evaluations",
        ),
        c(
            "gain-every beyond any run",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--gains", "fit", "--gain-every", "10000001"],
            "--gain-every on the command line: gains.every: must be 1 to 10000000 iterations",
        ),
        c(
            "demo max-iterations beyond any run",
            None,
            &["demo", "-o", "OUT", "--max-iterations", "18446744073709551615"],
            "--max-iterations <MAX_ITERATIONS>': an iteration cap is a whole number from 1 to 1000000000",
        ),
        c(
            "study max-iterations 0",
            None,
            &["study", "-o", "OUT", "--max-iterations", "0"],
            "--max-iterations <MAX_ITERATIONS>': an iteration cap is a whole number from 1 to 1000000000",
        ),
        c(
            "negative time budget",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--time-budget=-1"],
            "--time-budget on the command line: stopping.time_budget_s",
        ),
        c("NaN time budget", None, &["reconstruct", "SCENE", "-o", "OUT", "--time-budget", "NaN"], "time_budget"),
        // Each was ignored without a word.
        c(
            "gain refits without fitted gains",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--gains", "none", "--gain-every", "3"],
            "--gain-every applies only to fitted gains, but the gains are `none`; give --gains fit (or auto)",
        ),
        c(
            "gain rounds with balanced gains",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--gains", "balance", "--gain-rounds", "2"],
            "--gain-rounds applies only to fitted gains, but the gains are `balance`",
        ),
        c(
            "gain rounds for a neural method",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--gains", "fit", "--gain-rounds", "2"],
            "--gain-rounds does not apply to --method fast",
        ),
        c(
            "two neural options for a voxel method",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--rays-per-image", "9", "--fine-samples", "0"],
            "--rays-per-image, --fine-samples do not apply to --method asart",
        ),
        // Both turned the plateau rule off, as 0 does, and the run went on to the cap.
        c(
            "NaN plateau tolerance",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--plateau-tolerance", "nan"],
            "--plateau-tolerance <FRACTION>': nan: the tolerance is a positive fraction",
        ),
        c(
            "negative plateau tolerance",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--plateau-tolerance=-0.5"],
            "or 0 to run to the iteration cap",
        ),
        // The rule stopped the run right after its first window.
        c(
            "huge plateau tolerance",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--plateau-tolerance", "1e300"],
            "--plateau-tolerance <FRACTION>': 1e300: the tolerance is a positive fraction of the residual, at most 1",
        ),
        c(
            "relaxation 3 asart",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--relaxation", "3"],
            "relaxation",
        ),
        c(
            "relaxation 1.5 mart",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "mart", "--relaxation", "1.5"],
            "relaxation",
        ),
        c(
            "negative Tikhonov weight",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tikhonov", "--tikhonov-weight=-1"],
            "weight",
        ),
        c(
            "negative TV weight",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tv", "--tv-weight=-1"],
            "tv_weight",
        ),
        c(
            "unknown preset",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--preset", "turbo"],
            "preset",
        ),
        c(
            "no rays per image",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--rays-per-image", "0"],
            "rays_per_image",
        ),
        c(
            "one sample per ray",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--coarse-samples", "1"],
            "coarse_samples",
        ),
        c(
            "negative learning rate",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--learning-rate=-1"],
            "learning",
        ),
        c(
            "absurd learning rate",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--learning-rate", "1e300"],
            "'--learning-rate <LEARNING_RATE>': a learning rate must be positive and at most 1 (an Adam step moves \
             each parameter by about the rate), got 1e300",
        ),
        c(
            "learning rate below what f32 holds",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--learning-rate", "1e-50"],
            "1e-50 is below the smallest the training's f32 holds",
        ),
        c(
            "large learning rate, time-resolved",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tr-fast", "--learning-rate", "5"],
            "'--learning-rate <LEARNING_RATE>': a learning rate must be positive and at most 1",
        ),
        c(
            "held-out every 0",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--stop", "held-out", "--holdout-every", "0"],
            "holdout_every",
        ),
        // The held-out rule's settings were ignored by runs that stop otherwise.
        c(
            "patience with the method's own rule",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--stop", "own", "--patience", "3"],
            "--patience sets held-out early stopping, which this run does not use: the run stops by the method's own",
        ),
        c(
            "held-out interval on a scene without held-out views",
            Json(|v| {
                for f in v["frames"].as_array_mut().expect("frames") {
                    f["holdout"] = false.into();
                }
            }),
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--holdout-every", "2", "--patience", "3"],
            "--holdout-every, --patience set held-out early stopping, which this run does not use: the scene",
        ),
        // The voxel methods' own rule's tolerance was recorded and ignored by runs that stop
        // otherwise: SCENE holds a view out, so `auto` stops by it.
        c(
            "plateau tolerance with held-out views",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "sart", "--resolution", "8", "--plateau-tolerance", "0.1"],
            "--plateau-tolerance sets the method's own stopping rule, which this run does not use: the scene",
        ),
        c(
            "plateau tolerance with the budget rule",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "sart", "--stop", "budget", "--max-iterations", "2", "--plateau-tolerance", "0.1"],
            "--plateau-tolerance sets the method's own stopping rule, which this run does not use: the run stops by \
             its budget alone",
        ),
        c(
            "NRMSE interval on a scene without ground truth",
            Json(|v| {
                v.as_object_mut().expect("object").remove("truth");
            }),
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--eval-every", "2"],
            "--eval-every evaluates the volume NRMSE against the scene's ground truth, and the scene",
        ),
        c("memory limit 0", None, &["reconstruct", "SCENE", "-o", "OUT", "--memory-limit", "0"], "memory_limit"),
        c(
            "memory limit too small",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--memory-limit", "0.000001"],
            "needs about",
        ),
        c(
            "splat subdivisions 17",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "sart", "--splat-subdivisions", "17"],
            "splat_subdivisions",
        ),
        c(
            "ray step 0",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "sart", "--projector", "ray", "--ray-step", "0"],
            "ray_step",
        ),
        c(
            "hull threshold 1.5",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "sart", "--hull-threshold", "1.5"],
            "hull_threshold",
        ),
        c(
            "hull noise sigmas -1",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "sart", "--hull-noise-sigmas=-1"],
            "hull_noise_sigmas",
        ),
        c(
            "TV option on ASART",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--tv-weight", "0.1"],
            "--tv-weight",
        ),
        c(
            "window on a static method",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--window", "2"],
            "--window",
        ),
        c(
            "voxel option on a neural method",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--projector", "ray"],
            "--projector",
        ),
        c(
            "overlap not below the window",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tr-fast", "--window", "2", "--overlap", "2"],
            "overlap",
        ),
        c(
            "gain fit on a time-resolved method",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tr-fast", "--gains", "fit"],
            "gain fitting is available for static methods",
        ),
        c(
            "negative time step",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tr-fast", "--time-step=-1"],
            "time_step",
        ),
        c(
            "held-out rule without held-out views",
            Json(|v| {
                for f in v["frames"].as_array_mut().unwrap() {
                    f.as_object_mut().unwrap().remove("holdout");
                }
            }),
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "asart", "--stop", "held-out"],
            "held-out views",
        ),
        c(
            "resume with nothing to resume",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--resume"],
            "--resume",
        ),
        c(
            "output is the scene folder",
            None,
            &["reconstruct", "SCENE", "-o", "SCENE", "--method", "asart", "--force"],
            "scene's own folder",
        ),
        c("config missing", None, &["reconstruct", "--config", "SCENE/none.json", "-o", "OUT"], "none.json"),
        c(
            "config not JSON",
            File("run.json", b"{"),
            &["reconstruct", "--config", "SCENE/run.json", "-o", "OUT"],
            "run.json",
        ),
        c(
            "config unknown key",
            File("run.json", br#"{"format":1,"scene":"x","method":{"name":"asart"},"seeed":1}"#),
            &["reconstruct", "--config", "SCENE/run.json", "-o", "OUT"],
            "seeed",
        ),
        c(
            "config unknown method",
            File("run.json", br#"{"format":1,"scene":"x","method":{"name":"fbp"}}"#),
            &["reconstruct", "--config", "SCENE/run.json", "-o", "OUT"],
            "fbp",
        ),
        c(
            "config of a later format",
            File("run.json", br#"{"format":7,"scene":"x","method":{"name":"asart"}}"#),
            &["reconstruct", "--config", "SCENE/run.json", "-o", "OUT"],
            "format 7",
        ),
        c(
            "config naming no scene that exists",
            File("run.json", br#"{"format":1,"scene":"nowhere","method":{"name":"asart"}}"#),
            &["reconstruct", "--config", "SCENE/run.json", "-o", "OUT"],
            "its `scene`, nowhere, does not exist",
        ),
        c(
            "frame times whose spread overflows",
            Json(|v| {
                for (i, f) in v["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
                    f["time"] = if i % 2 == 0 { -1.7e308 } else { 1.7e308 }.into();
                }
            }),
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "tr-fast", "--resolution", "8", "--max-iterations", "1"],
            "the frame times run from frame 0 (images/cam000.png) at -1.7e308 to frame 1 (images/cam001.png) at 1.7e308, a spread too large",
        ),
        c(
            // Δt, the smallest gap, is 1e-8: the span is 1e316 steps, beyond a 32-bit time input.
            "frame times whose span is more steps than 32-bit floating point holds",
            Json(|v| {
                for (i, f) in v["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
                    f["time"] = [0.0, 1e-8, 1e308][i % 3].into();
                }
            }),
            &["info", "SCENE"],
            "frame 2 (images/cam002.png) at 1e308 lies about 1e316 time steps of Δt = 1e-8",
        ),
        c(
            "a time step too small for the times",
            Json(two_instants),
            tr_step!("1e-40"),
            "method.time_step: the times run from 0 to 1, 1e40 time steps",
        ),
        c(
            // Every frame read as one instant: the field was trained as a static one.
            "a time step too large for the times",
            Json(two_instants),
            tr_step!("1e308"),
            "method.time_step: the times 0 and 1 are 1e-308 time steps of Δt = 1e308 apart, which the network's \
             time input t' = (t − t₀)/Δt reads as one instant",
        ),
        c(
            // Within f32's range, but t' = 1e30 made the first loss infinite, reported as a
            // divergence asking for a lower learning rate.
            "a time step small enough to overflow the network",
            Json(two_instants),
            tr_step!("1e-30"),
            "time steps of Δt = 1e-30: more than the 16777216 steps",
        ),
        c(
            // Times distinct in 32 bits, but too close for the network to tell apart.
            "a time step that makes the frames one instant",
            Json(two_instants),
            tr_step!("1e30"),
            "time steps of Δt = 1e30 apart, which the network's time input t' = (t − t₀)/Δt reads as one instant (they must \
             be at least 0.001 steps apart)",
        ),
        c(
            "config relaxation far out of range",
            File("run.json", br#"{"format":1,"scene":"x","method":{"name":"asart","params":{"relaxation":1e300}}}"#),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            // Written compactly, not as 301 digits.
            "relaxation: for Asart must be in (0, 2), got 1e300\n",
        ),
        c(
            "relaxation flag far out of range",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "sart", "--relaxation=-1e-300"],
            "got -1e-300\n",
        ),
        c(
            "relaxation at which the additive methods need not converge",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "art", "--relaxation", "2"],
            "relaxation: for Art must be in (0, 2), got 2\n",
        ),
        c(
            "config naming a file as its scene",
            File("run.json", br#"{"format":1,"scene":"scene/images/cam000.png","method":{"name":"asart"}}"#),
            &["reconstruct", "--config", "SCENE/run.json", "-o", "OUT"],
            "run.json: its `scene`: ",
        ),
        c(
            "scene given as a file",
            None,
            &["reconstruct", "SCENE/images/cam000.png", "-o", "OUT", "--method", "asart"],
            "cam000.png: is a file, not a scene folder",
        ),
        c(
            "config of another method",
            File("run.json", br#"{"format":1,"scene":"x","method":{"name":"asart"}}"#),
            &["reconstruct", "--config", "SCENE/run.json", "-o", "OUT", "--method", "fast"],
            "--method",
        ),
        c(
            "config: occupancy margin negative",
            File(
                "run.json",
                br#"{"format":1,"scene":"x","method":{"name":"fast","field":{"hash-grid":{}},"train":{"occupancy":{"margin_px":-5}}}}"#,
            ),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "occupancy.margin_px",
        ),
        c(
            "config: occupancy grid too fine",
            File(
                "run.json",
                br#"{"format":1,"scene":"x","method":{"name":"fast","field":{"hash-grid":{}},"train":{"occupancy":{"resolution":100000}}}}"#,
            ),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "occupancy.resolution",
        ),
        c(
            "config: occupancy dilated without end",
            File(
                "run.json",
                br#"{"format":1,"scene":"x","method":{"name":"fast","field":{"hash-grid":{}},"train":{"occupancy":{"dilate":1000000000}}}}"#,
            ),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "occupancy.dilate",
        ),
        c(
            "config: occupancy floor above 1",
            File("run.json", br#"{"format":1,"scene":"x","method":{"name":"fast","field":{"hash-grid":{}},"train":{"occupancy":{"floor":5}}}}"#),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "occupancy.floor",
        ),
        c(
            "config: occupancy noise sigmas negative",
            File(
                "run.json",
                br#"{"format":1,"scene":"x","method":{"name":"fast","field":{"hash-grid":{}},"train":{"occupancy":{"noise_sigmas":-1}}}}"#,
            ),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "occupancy.noise_sigmas",
        ),
        c(
            "config: dense field too fine",
            File(
                "run.json",
                br#"{"format":1,"scene":"x","method":{"name":"voxel","field":{"dense":{"resolution":100000}},"train":{}}}"#,
            ),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "run.json: method.field.dense.resolution: must be 1 to 1024 cells, got 100000",
        ),
        c(
            "config: samples per ray without end",
            File("run.json", br#"{"format":1,"scene":"x","method":{"name":"fast","field":{"hash-grid":{}},"train":{"coarse_samples":100000}}}"#),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "coarse_samples",
        ),
        c(
            "config: no training iteration",
            File("run.json", br#"{"format":1,"scene":"x","method":{"name":"fast","field":{"hash-grid":{}},"train":{"max_iterations":0}}}"#),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "max_iterations",
        ),
        c(
            "config: ray step too fine",
            File(
                "run.json",
                br#"{"format":1,"scene":"x","method":{"name":"asart","projector":{"kind":"ray","ray_step":1e-6}}}"#,
            ),
            &["reconstruct", "SCENE", "--config", "SCENE/run.json", "-o", "OUT"],
            "ray_step",
        ),
        c("eval of a folder without a run", None, &["eval", "SCENE/images", "--scene", "SCENE"], "images"),
        c("fast run of an unreadable image", File("images/cam001.png", b""), FAST, "cam001.png"),
        c(
            "two frames of one camera at one instant",
            Json(|v| v["frames"][1]["camera"] = v["frames"][0]["camera"].clone()),
            RUN,
            "both camera",
        ),
        c(
            "a blank camera name",
            Json(|v| v["frames"][1]["camera"] = serde_json::json!(" ")),
            RUN,
            "frame 1 (images/cam001.png), key `frames[1].camera`: is \" \", which names no camera",
        ),
        c(
            "one camera at times 0 and -0",
            Json(|v| {
                for (i, f) in v["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
                    f["time"] = ((i % 2) as f64).into();
                }
                v["frames"][2]["camera"] = v["frames"][0]["camera"].clone();
                v["frames"][2]["time"] = (-0.0).into();
            }),
            RUN,
            "frames 0 and 2 are both camera",
        ),
        c(
            "one instant written two ways",
            Json(|v| {
                for (i, f) in v["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
                    f["time"] = ((i % 2) as f64).into();
                }
                v["frames"][2]["time"] = 1e-10.into();
            }),
            RUN,
            "frame 0 (images/cam000.png) at 0 and frame 2 (images/cam002.png) at 1e-10 are one instant",
        ),
        c(
            "two truths at 0 and -0",
            Json(|v| {
                for (i, f) in v["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
                    f["time"] = ((i % 2) as f64).into();
                }
                let file = v["truth"][0]["file_path"].clone();
                v["truth"] = serde_json::json!([{ "time": 0.0, "file_path": file }, { "time": -0.0, "file_path": file }]);
            }),
            RUN,
            "truth entries 0 (truth/truth.npy) and 1 (truth/truth.npy) are both at time",
        ),
        c(
            "a truth without time among timed ones",
            Json(|v| {
                for (i, f) in v["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
                    f["time"] = ((i % 2) as f64).into();
                }
                let file = v["truth"][0]["file_path"].clone();
                v["truth"] = serde_json::json!([{ "time": 0.0, "file_path": file }, { "file_path": file }]);
            }),
            RUN,
            "truth entry 1 (truth/truth.npy) has no `time`, but entry 0 (truth/truth.npy) has one",
        ),
        c(
            "background above every pixel",
            Json(|v| v["background"] = serde_json::json!(1e9)),
            RUN,
            fluidnerf_core::image::ALL_BLACK,
        ),
        c(
            "background above every pixel, a field",
            Json(|v| v["background"] = serde_json::json!(1e9)),
            FAST,
            fluidnerf_core::image::ALL_BLACK,
        ),
        c(
            "background above every pixel, info",
            Json(|v| v["background"] = serde_json::json!(1e9)),
            &["info", "SCENE"],
            fluidnerf_core::image::ALL_BLACK,
        ),
        c("negative background", Json(|v| v["background"] = serde_json::json!(-100.0)), RUN, "at least 0"),
        c(
            "metrics as JSON and CSV into one file",
            None,
            &["eval", "SCENE/truth/truth.npy", "--scene", "SCENE", "--json", "OUT/m", "--csv", "OUT/m"],
            "same file",
        ),
        c(
            "metrics into a folder that does not exist",
            None,
            &["eval", "SCENE/truth/truth.npy", "--scene", "SCENE", "--json", "OUT/m.json"],
            "does not exist",
        ),
        c(
            "two slices into one picture",
            None,
            &["export", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--slices", "x=0.5,x=0.5004"],
            "would both write",
        ),
        c(
            "more rays per image than any memory holds",
            None,
            &["reconstruct", "SCENE", "-o", "OUT", "--method", "fast", "--rays-per-image", "1000000000"],
            "--rays-per-image on the command line: method.train.rays_per_image: must be 1 to 4194304",
        ),
        c(
            "export finer than the largest grid",
            None,
            &["export", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--npy", "--resolution", "5000"],
            "--resolution",
        ),
        c(
            "export beyond memory",
            None,
            &["export", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--npy", "--resolution", "4096"],
            "available",
        ),
        c(
            "export at a time that is not a number",
            None,
            &["export", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--npy", "--time=NaN"],
            "--time",
        ),
        c(
            "render of too many orbit views",
            None,
            &["render", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--orbit", "100000000"],
            "--orbit",
        ),
        // Options of orbit views and their turntable were ignored without a word otherwise.
        c(
            "render width without an orbit",
            None,
            &["render", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--width", "64"],
            "--orbit",
        ),
        c(
            "render turntable colour map without an orbit",
            None,
            &["render", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--colormap", "gray"],
            "--orbit",
        ),
        c(
            "render turntable frame time without an orbit",
            None,
            &["render", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--frame-ms", "200"],
            "--orbit",
        ),
        // Refused by the renderer at the first view, after the output folder was made.
        c(
            "render with a step too fine to finish",
            None,
            &["render", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--projector", "rays", "--step", "1e-9"],
            "--step 1e-9 would take more than 1048576 samples",
        ),
        c(
            "render of too wide an orbit view",
            None,
            &["render", "SCENE/truth/truth.npy", "--scene", "SCENE", "-o", "OUT", "--orbit", "1", "--width", "100000"],
            "--width",
        ),
    ]
}

#[test]
fn malformed_scenes_and_options_are_refused_cleanly() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 5, 20, 12, &["--holdout", "1"]);
    let cases = cases();
    assert!(cases.len() >= 40, "{} cases", cases.len());
    let mut failures = Vec::new();
    for (k, case) in cases.iter().enumerate() {
        let scene = d.join(format!("s{k:02}"));
        copy_dir(&d.join("scene"), &scene);
        let transforms = scene.join("transforms.json");
        match &case.brk {
            Break::None => {}
            Break::Transforms(text) => std::fs::write(&transforms, text).expect("writes"),
            Break::Json(edit) => {
                let mut v: serde_json::Value =
                    serde_json::from_str(&std::fs::read_to_string(&transforms).expect("reads")).expect("json");
                edit(&mut v);
                std::fs::write(&transforms, v.to_string()).expect("writes");
            }
            Break::File(name, bytes) => std::fs::write(scene.join(name), bytes).expect("writes"),
            Break::Remove(name) => std::fs::remove_file(scene.join(name)).expect("removes"),
            Break::Link(name, target) => {
                std::fs::remove_file(scene.join(name)).expect("removes");
                std::os::unix::fs::symlink(target, scene.join(name)).expect("links");
            }
            Break::Truth(edit) => edit(&scene.join("truth/truth.npy")),
        }
        let out = d.join(format!("o{k:02}"));
        let args: Vec<String> = case
            .args
            .iter()
            .map(|a| a.replace("SCENE", &scene.to_string_lossy()).replace("OUT", &out.to_string_lossy()))
            .collect();
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let before: Vec<_> = list(&scene);
        let o = fluidnerf(d, &refs);
        let err = String::from_utf8_lossy(&o.stderr);
        let mut why = Vec::new();
        if o.status.success() {
            why.push("exited 0".to_string());
        }
        if o.status.code() == Some(101) || err.contains("panicked") {
            why.push("panicked".into());
        }
        if !err.contains(case.says) {
            why.push(format!("does not say {:?}", case.says));
        }
        if out.exists() {
            why.push("left an output folder".into());
        }
        if list(&scene) != before {
            why.push("changed the scene folder".into());
        }
        if !why.is_empty() {
            failures.push(format!("{}: {} — stderr: {}", case.name, why.join(", "), err.trim()));
        }
    }
    assert!(failures.is_empty(), "{} of {} cases:\n{}", failures.len(), cases.len(), failures.join("\n"));
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("lists") {
        let e = e.expect("entry");
        let target = to.join(e.file_name());
        if e.path().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).expect("copies");
        }
    }
}

/// Names and sizes of the files under `dir`.
fn list(dir: &Path) -> Vec<(String, u64)> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).expect("lists").flatten() {
        if e.path().is_dir() {
            v.extend(list(&e.path()));
        } else {
            v.push((e.path().to_string_lossy().into_owned(), e.metadata().map(|m| m.len()).unwrap_or(0)));
        }
    }
    v.sort();
    v
}

/// A scene folder whose name is not UTF-8 cannot be recorded in `config.json`: refused before
/// any work, naming the path and not the config file.
#[cfg(unix)]
#[test]
fn a_scene_path_that_is_not_utf8_is_refused_up_front() {
    use std::os::unix::ffi::OsStrExt;
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 3, 12, 8, &[]);
    let odd = d.join(std::ffi::OsStr::from_bytes(b"scene\xff"));
    std::fs::rename(d.join("scene"), &odd).expect("renames");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .current_dir(d)
        .arg("reconstruct")
        .arg(&odd)
        .args(["-o", "run", "--method", "asart"])
        .output()
        .expect("runs");
    refused(&out, "not valid UTF-8");
    assert!(!d.join("run").exists(), "left an output folder");
}

/// An input whose path is not UTF-8 cannot be recorded in the JSON file a command writes next
/// to its results: refused before any work, naming the path and the option, and leaving
/// nothing behind (serialising it used to fail after the results were written, naming
/// nothing).
#[cfg(unix)]
#[test]
fn inputs_whose_paths_are_not_utf8_are_refused_before_any_output() {
    use std::os::unix::ffi::OsStrExt;
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    ok(&fluidnerf(
        d,
        &["reconstruct", "scene", "-o", "run", "--method", "asart", "--resolution", "8", "--max-iterations", "1"],
    ));
    let odd = std::ffi::OsStr::from_bytes(b"run\xff");
    std::fs::rename(d.join("run"), d.join(odd)).expect("renames");
    let odd_scene = std::ffi::OsStr::from_bytes(b"scene\xfe");
    copy_dir(&d.join("scene"), &d.join(odd_scene));
    let odd_study = std::ffi::OsStr::from_bytes(b"study\xfd");
    let study: &[&std::ffi::OsStr] = &[
        "study".as_ref(),
        "-o".as_ref(),
        odd_study,
        "--preset".as_ref(),
        "smoke".as_ref(),
        "--methods".as_ref(),
        "asart".as_ref(),
    ];
    let cases: [(&[&std::ffi::OsStr], &str); 6] = [
        (study, "--out study"),
        (&["eval".as_ref(), odd, "--json".as_ref(), "m.json".as_ref()], "RECON run"),
        (&["export".as_ref(), odd, "-o".as_ref(), "exported".as_ref(), "--npy".as_ref()], "RECON run"),
        (&["render".as_ref(), odd, "-o".as_ref(), "views".as_ref()], "RECON run"),
        (&["compare".as_ref(), odd, "-o".as_ref(), "compared".as_ref()], "RUN run"),
        (
            &["import".as_ref(), "--transforms".as_ref(), odd_scene, "-o".as_ref(), "imported".as_ref()],
            "--transforms scene",
        ),
    ];
    for (args, says) in cases {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
            .current_dir(d)
            .args(args)
            .output()
            .expect("runs");
        refused(&o, says);
        refused(&o, "the path is not valid UTF-8");
        assert!(!String::from_utf8_lossy(&o.stderr).contains("panicked"), "{args:?}");
    }
    for made in ["m.json", "exported", "views", "compared", "imported"] {
        assert!(!d.join(made).exists(), "left {made}");
    }
    let names: Vec<_> = std::fs::read_dir(d).expect("lists").map(|e| e.expect("entry").file_name()).collect();
    assert!(!names.iter().any(|n| n.to_string_lossy().starts_with("study")), "left a study folder: {names:?}");
}

#[test]
fn a_saved_configuration_with_a_bad_value_is_refused_naming_the_file_and_the_key() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    ok(&fluidnerf(
        d,
        &["reconstruct", "scene", "-o", "run", "--method", "fast", "--resolution", "8", "--max-iterations", "1", "-q"],
    ));
    let saved: serde_json::Value = json(&d.join("run/config.json"));
    type Edit = fn(&mut serde_json::Value);
    let edits: [(&str, Edit); 15] = [
        ("method.field.hash-grid.levels", |v| v["method"]["field"]["hash-grid"]["levels"] = 0.into()),
        ("method.field.hash-grid.mlp_depth: 0 not in 1..=16", |v| {
            v["method"]["field"]["hash-grid"]["mlp_depth"] = 0.into()
        }),
        ("method.field.hash-grid.init_scale: -1 is not", |v| {
            v["method"]["field"]["hash-grid"]["init_scale"] = (-1.0).into()
        }),
        ("method.train.coarse_samples", |v| v["method"]["train"]["coarse_samples"] = 1.into()),
        ("method.train.adam.beta1", |v| v["method"]["train"]["adam"]["beta1"] = 1.0.into()),
        ("method.train.schedule", |v| v["method"]["train"]["schedule"]["initial"] = 0.0.into()),
        ("method.train.schedule.initial: the learning rate must be positive and at most 1", |v| {
            v["method"]["train"]["schedule"]["initial"] = 1e30.into()
        }),
        ("method.train.schedule.at_decay_iters", |v| v["method"]["train"]["schedule"]["at_decay_iters"] = 20.0.into()),
        // Beyond f32: shown as written, not as the infinity or zero it would round to.
        ("at `method.train.schedule.initial`: 1e300 is beyond what this setting's 32-bit float holds", |v| {
            v["method"]["train"]["schedule"]["initial"] = 1e300.into()
        }),
        ("at `method.train.adam.eps`: 1e-60 is below the smallest non-zero value", |v| {
            v["method"]["train"]["adam"]["eps"] = 1e-60.into()
        }),
        // A step divided by ε instead of the gradients' size: training made no progress.
        ("method.train.adam.eps: must be at most 1", |v| v["method"]["train"]["adam"]["eps"] = 1e30.into()),
        // Beyond any memory: refused by its key, not a panic or an aborted allocation.
        ("method.train.rays_per_image: must be 1 to 4194304 pixels per image, got 18446744073709551615", |v| {
            v["method"]["train"]["rays_per_image"] = u64::MAX.into()
        }),
        // Not blamed on the resolution or the image count by the memory check.
        ("method.train.chunk_samples: must be 1 to 16777216 field rows per chunk, got 1099511627776", |v| {
            v["method"]["train"]["chunk_samples"] = (1u64 << 40).into()
        }),
        // Not read as one ray per chunk, a setting nobody means.
        ("method.train.chunk_samples: must be 1 to 16777216 field rows per chunk, got 0", |v| {
            v["method"]["train"]["chunk_samples"] = 0.into()
        }),
        // Not a prior silently left out (its draws counted beyond 64 bits) nor one that never ends.
        ("method.train.prior.points: must be 1 to 65536 points per iteration, got 4611686018427387904", |v| {
            v["method"]["train"]["prior"]["tv"] = 1.0.into();
            v["method"]["train"]["prior"]["points"] = (1u64 << 62).into();
        }),
    ];
    for (key, edit) in edits {
        let mut v = saved.clone();
        edit(&mut v);
        std::fs::write(d.join("cfg.json"), v.to_string()).expect("writes");
        let o = fluidnerf(d, &["reconstruct", "--config", "cfg.json", "-o", "again"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("cfg.json") && err.contains(key), "{key}: {err}");
        assert!(!d.join("again").exists(), "{key}: left an output folder");
    }
}

/// A method's setting out of range is named by its key, and by the option that gave it when it
/// came from the command line, not blamed on the `--config` file it overrode.
#[test]
fn a_method_setting_is_named_by_its_key_and_by_the_option_that_gave_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    let synth = ["synth", "--preset", "demo", "--phantom", "jet-tr", "--times", "1,2,3", "--cameras", "3"];
    ok(&fluidnerf(d, &[&synth[..], &["--pixels", "12", "--resolution", "8", "-o", "timed", "-q"]].concat()));
    let quick = ["--resolution", "8", "--max-iterations", "1", "-q", "--checkpoint-every", "0"];
    for (scene, method) in [("scene", "tv"), ("scene", "fast"), ("timed", "tr-fast")] {
        let run = ["reconstruct", scene, "-o", method, "--method", method];
        let quick = if method == "tv" { &quick[..5] } else { &quick[..] };
        ok(&fluidnerf(d, &[&run[..], quick].concat()));
    }
    for (method, option, value, key) in [
        ("tv", "--ray-step", "0", "method.projector.ray_step"),
        ("tv", "--splat-subdivisions", "17", "method.projector.splat_subdivisions"),
        ("tv", "--hull-threshold", "1.5", "method.projector.hull_threshold"),
        ("tv", "--hull-noise-sigmas", "1000", "method.projector.hull_noise_sigmas"),
        ("tv", "--hull-dilation", "99", "method.projector.hull_dilation"),
        ("tv", "--relaxation", "3", "method.params.relaxation"),
        ("tv", "--tv-weight", "nan", "method.params.tv_weight"),
        ("tv", "--tv-weight", "2", "method.params.tv_weight"),
        ("tv", "--tv-steps", "100000", "method.params.tv_steps"),
        ("fast", "--rays-per-image", "0", "method.train.rays_per_image"),
        ("fast", "--coarse-samples", "1", "method.train.coarse_samples"),
        ("fast", "--fine-samples", "100000", "method.train.coarse_samples"),
        ("fast", "--tv-prior", "nan", "method.train.prior.tv"),
        ("fast", "--tv-prior", "1e30", "method.train.prior.tv"),
        ("tr-fast", "--smooth-prior", "3e38", "method.train.prior.smooth"),
        ("fast", "--smooth-prior=-1", "", "method.train.prior.smooth"),
        ("fast", "--sparsity-prior", "inf", "method.train.prior.sparsity"),
        ("tr-fast", "--window", "1", "method.windows.overlap"),
        ("tr-fast", "--time-origin", "recording", "method.windows.time_origin"),
    ] {
        let config = format!("{method}/config.json");
        let mut args = vec!["reconstruct", "--config", &config, "-o", "again", option];
        args.extend([value].iter().filter(|v| !v.is_empty()));
        let o = fluidnerf(d, &args);
        let err = String::from_utf8_lossy(&o.stderr);
        let flag = option.split('=').next().unwrap_or(option);
        assert!(!o.status.success(), "{option} {value}: accepted");
        assert!(err.contains(&format!("{flag} on the command line: {key}")), "{option} {value}: {err}");
        assert!(!err.contains("config.json"), "{option} {value}: blames the file: {err}");
        assert!(!d.join("again").exists(), "{option}: left an output folder");
    }
    // The same value in the file is the file's, named with its key.
    edit_json(&d.join("tv/config.json"), |v| v["method"]["projector"]["ray_step"] = 0.into());
    let o = fluidnerf(d, &["reconstruct", "--config", "tv/config.json", "-o", "again"]);
    refused(&o, "the settings of tv/config.json: method.projector.ray_step: must be in [0.01, 4]");
}

/// A run folder whose volume is another run's (another grid than its report records) is not
/// scored, exported or rendered as its own.
#[test]
fn a_run_holding_another_runs_volume_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    for (run, resolution) in [("run", "8"), ("other", "10")] {
        ok(&fluidnerf(
            d,
            &[
                "reconstruct",
                "scene",
                "-o",
                run,
                "--method",
                "asart",
                "--resolution",
                resolution,
                "--max-iterations",
                "1",
            ],
        ));
    }
    std::fs::copy(d.join("other/volume.npy"), d.join("run/volume.npy")).expect("copies");
    let says = "run/volume.npy: holds a 10x10x10 volume, but the run's report.json records 8x8x8";
    for args in [
        &["eval", "run", "--json", "m.json"][..],
        &["export", "run", "-o", "exported", "--npy"],
        &["render", "run", "-o", "views"],
    ] {
        let o = fluidnerf(d, args);
        refused(&o, says);
        assert!(!String::from_utf8_lossy(&o.stderr).contains("panicked"), "{args:?}");
    }
    for made in ["m.json", "exported", "views"] {
        assert!(!d.join(made).exists(), "left {made}");
    }
    // A report whose volume lies outside its folder (here the other run's, of the same grid).
    ok(&fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "run",
            "--method",
            "asart",
            "--resolution",
            "10",
            "--max-iterations",
            "1",
            "--force",
        ],
    ));
    edit_json(&d.join("run/report.json"), |v| v["volumes"][0]["file"] = "../other/volume.npy".into());
    let o = fluidnerf(d, &["eval", "run", "--json", "m.json"]);
    refused(&o, "run/report.json: lists the volume ../other/volume.npy, which is not a file inside the run folder");
    assert!(!d.join("m.json").exists(), "wrote metrics");
}

/// A run whose report.json lists no volume (edited) is refused naming the key: eval indexed
/// the first of none and panicked.
#[test]
fn a_run_whose_report_lists_no_volume_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    let args = ["reconstruct", "scene", "-o", "run", "--method", "asart", "--resolution", "8"];
    ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "1", "-q"]].concat()));
    edit_json(&d.join("run/report.json"), |v| v["volumes"] = serde_json::json!([]));
    let says = "run/report.json: `volumes` lists no volume";
    for args in [
        &["eval", "run", "--json", "m.json", "--no-reprojection"][..],
        &["render", "run", "-o", "views"],
        &["export", "run", "-o", "exported", "--npy"],
    ] {
        let o = fluidnerf(d, args);
        refused(&o, says);
        assert!(!String::from_utf8_lossy(&o.stderr).contains("panicked"), "{args:?}");
    }
    for made in ["m.json", "views", "exported"] {
        assert!(!d.join(made).exists(), "left {made}");
    }
}

/// A run folder whose report.json is another run's (of another method) is not read as one run:
/// the report's scores and curves would be taken for the results of the folder's own method.
#[test]
fn a_run_holding_another_runs_report_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    for (run, method) in [("run", "asart"), ("other", "sart")] {
        let args = ["reconstruct", "scene", "-o", run, "--method", method, "--resolution", "8"];
        ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "1", "-q"]].concat()));
    }
    std::fs::copy(d.join("other/report.json"), d.join("run/report.json")).expect("copies");
    let says = "run/report.json: reports a run of method sart, but the folder's config.json configures method asart";
    // compare drew the other run's curve under this folder's name.
    let commands = [
        &["eval", "run", "--json", "m.json"][..],
        &["render", "run", "-o", "views"],
        &["compare", "other", "run", "-o", "curves"],
    ];
    for args in commands {
        refused(&fluidnerf(d, args), says);
    }
    for made in ["m.json", "views", "curves"] {
        assert!(!d.join(made).exists(), "left {made}");
    }
}

/// A run folder whose model.json is not its own — a field of another box than its report
/// records, or of other settings than its config.json (here the decoder's activation, which
/// the weights' shapes do not tell) — is not scored or rendered as its result.
#[test]
fn a_run_holding_another_runs_model_description_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    let args = ["reconstruct", "scene", "-o", "run", "--method", "fast", "--resolution", "8"];
    ok(&fluidnerf(d, &[&args[..], &["--rays-per-image", "32", "--max-iterations", "2", "-q"]].concat()));
    let model = d.join("run/model.json");
    let original = std::fs::read(&model).expect("model.json");
    let max = edit_json(&model, |v| {
        let max = v["meta"]["aabb"]["max"][0].as_f64().expect("a box");
        v["meta"]["aabb"]["max"][0] = (2.0 * max).into();
        max
    });
    let says = format!("run/model.json: describes a field in the box [{}", -max);
    let says_box = format!(
        "but the run's report.json records the box [{}, {}, {}] .. [{}, {}, {}]",
        -max, -max, -max, max, max, max
    );
    for args in [&["eval", "run", "--json", "m.json"][..], &["render", "run", "-o", "views"]] {
        let o = fluidnerf(d, args);
        refused(&o, &says);
        refused(&o, &says_box);
    }
    std::fs::write(&model, &original).expect("restores model.json");
    edit_json(&model, |v| v["field"]["hash-grid"]["activation"] = "swish".into());
    let says = r#"run/model.json: describes another field than the run's config.json configures (`hash-grid.activation`: "relu" → "swish")"#;
    for args in [&["eval", "run", "--json", "m.json"][..], &["render", "run", "-o", "views"]] {
        refused(&fluidnerf(d, args), says);
    }
    for made in ["m.json", "views"] {
        assert!(!d.join(made).exists(), "left {made}");
    }
    std::fs::write(&model, &original).expect("restores model.json");
    ok(&fluidnerf(d, &["eval", "run", "--json", "m.json", "-q"]));
}

/// A time-resolved run's temporal.json is stitched as a run plans its windows: one listing other
/// windows than the run's report (one left out, or reordered), windows out of order in a folder
/// without a report, or weights outside the run folder, would blend other fields than the
/// run's; one of another field than config.json configures would read them as another network.
/// Each is refused naming temporal.json.
#[test]
fn a_time_resolved_run_with_other_windows_than_its_own_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let synth = ["synth", "-q", "--preset", "jet-tr60", "--cameras", "4", "--pixels", "16", "--resolution", "8"];
    ok(&fluidnerf(d, &[&synth[..], &["--model", "pinhole", "--times", "14,15,16,17", "-o", "scene"]].concat()));
    let args = ["reconstruct", "scene", "-o", "run", "--method", "tr-fast", "--window", "2", "--overlap", "1"];
    let small = ["--max-iterations", "2", "--rays-per-image", "16", "--coarse-samples", "8", "--resolution", "8"];
    ok(&fluidnerf(d, &[&args[..], &small, &["-q"]].concat()));
    let temporal = d.join("run/temporal.json");
    let original = std::fs::read(&temporal).expect("temporal.json");
    let eval = |run: &str, extra: &[&str]| fluidnerf(d, &[&["eval", run, "--json", "m.json"][..], extra].concat());

    edit_json(&temporal, |v| v["windows"].as_array_mut().expect("windows").remove(1));
    refused(
        &eval("run", &[]),
        "run/temporal.json: lists the windows [[0, 2], [2, 4]], but the run's report.json records the windows [[0, 2], \
         [1, 3], [2, 4]]",
    );
    std::fs::write(&temporal, &original).expect("restores temporal.json");
    edit_json(&temporal, |v| v["field"]["hash-grid"]["activation"] = "swish".into());
    refused(
        &eval("run", &[]),
        r#"run/temporal.json: describes another field than the run's config.json configures (`hash-grid.activation`: "relu" → "swish")"#,
    );
    std::fs::write(&temporal, &original).expect("restores temporal.json");
    let elsewhere = d.join("run/windows/w001.safetensors").to_str().expect("UTF-8").to_string();
    edit_json(&temporal, |v| v["windows"][1]["weights"] = elsewhere.clone().into());
    refused(&eval("run", &[]), &format!("window frames [1, 3]: its weights {elsewhere} are not a file inside the run"));
    // A window's time origin edited would shift its instants.
    std::fs::write(&temporal, &original).expect("restores temporal.json");
    edit_json(&temporal, |v| v["windows"][1]["time_origin"] = 14.0.into());
    refused(
        &eval("run", &[]),
        "run/temporal.json: window frames [1, 3] has the time origin 14, but the run's report.json records 15",
    );
    // An instant listed twice would sit at two frame positions of the stitching.
    std::fs::write(&temporal, &original).expect("restores temporal.json");
    edit_json(&temporal, |v| v["frame_times"][2] = 15.0.into());
    let twice = "run/temporal.json: frame_times: frame 2 at t = 15 does not come after frame 1 at t = 15";
    refused(&eval("run", &[]), twice);
    refused(&fluidnerf(d, &["export", "run", "-o", "exp", "--npy", "--time", "15.5", "-q"]), twice);
    assert!(!d.join("exp").exists(), "exported a run whose frame times repeat");

    // Assembled by hand: no report to compare with, but the windows must still follow each other.
    std::fs::write(&temporal, &original).expect("restores temporal.json");
    edit_json(&temporal, |v| v["windows"].as_array_mut().expect("windows").reverse());
    for file in ["report.json", "config.json"] {
        std::fs::remove_file(d.join("run").join(file)).expect("removes");
    }
    refused(
        &eval("run", &["--scene", "scene"]),
        "run/temporal.json: window frames [2, 4] do not follow the window before them",
    );
    std::fs::write(&temporal, &original).expect("restores temporal.json");
    edit_json(&temporal, |v| v["frame_times"][3] = 16.0.into());
    refused(
        &eval("run", &["--scene", "scene"]),
        "run/temporal.json: frame_times: frame 3 at t = 16 does not come after frame 2 at t = 16",
    );
    assert!(!d.join("m.json").exists(), "wrote metrics");
    std::fs::write(&temporal, &original).expect("restores temporal.json");
    ok(&eval("run", &["--scene", "scene", "-q"]));
}

/// A voxel run's folder holding a neural field's model.json (copied in from another run) was
/// read as a field, and refused saying that its own volume.npy, which is there, is missing.
/// The stray file is named instead.
#[test]
fn a_run_holding_a_description_of_another_kind_names_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    for (run, method) in [("run", "asart"), ("field", "fast")] {
        let args = ["reconstruct", "scene", "-o", run, "--method", method, "--resolution", "8"];
        ok(&fluidnerf(d, &[&args[..], &["--max-iterations", "2", "-q"]].concat()));
    }
    for file in ["model.json", "weights.safetensors"] {
        std::fs::copy(d.join("field").join(file), d.join("run").join(file)).expect("copies");
    }
    let says = "run: a asart run that holds model.json, which such a run does not write";
    for args in [&["eval", "run", "--json", "m.json"][..], &["render", "run", "-o", "views"]] {
        refused(&fluidnerf(d, args), says);
    }
    std::fs::remove_file(d.join("run/model.json")).expect("removes");
    ok(&fluidnerf(d, &["eval", "run", "--json", "m.json", "-q"]));
}

/// A run given twice to `compare` (as its folder and its report, or through a link) would be
/// drawn and tabled as two runs that agree.
#[test]
fn a_run_given_twice_to_compare_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    ok(&fluidnerf(
        d,
        &["reconstruct", "scene", "-o", "run", "--method", "asart", "--resolution", "8", "--max-iterations", "1"],
    ));
    std::os::unix::fs::symlink("run", d.join("link")).expect("links");
    for (args, says) in [
        (
            &["compare", "run", "run/report.json", "-o", "compared"],
            "run/report.json is given twice (as run and run/report.json)",
        ),
        (&["compare", "run", "link", "-o", "compared"], "link/report.json is given twice (as run and link)"),
    ] {
        let o = fluidnerf(d, args);
        refused(&o, says);
        assert!(!String::from_utf8_lossy(&o.stderr).contains("panicked"), "{args:?}");
        assert!(!d.join("compared").exists(), "{args:?}: left an output folder");
    }
}

/// A volume given with `eval --truth` has no time: a time-resolved run was scored at time 0,
/// its first instant, whatever instant the volume held.
#[test]
fn a_timeless_truth_for_a_time_resolved_run_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    ok(&fluidnerf(
        d,
        &[
            "synth",
            "--preset",
            "jet-tr60",
            "--pixels",
            "16",
            "--resolution",
            "8",
            "--cameras",
            "3",
            "--times",
            "14,15",
            "-o",
            "scene",
            "-q",
        ],
    ));
    let run =
        ["reconstruct", "scene", "-o", "run", "--method", "tr-fast", "--resolution", "8", "--max-iterations", "2"];
    ok(&fluidnerf(d, &run));
    let o = fluidnerf(d, &["eval", "run", "--truth", "scene/truth/truth_t01.npy", "--json", "m.json"]);
    refused(&o, "--truth scene/truth/truth_t01.npy: a volume without a time, but the run in run is time-resolved");
    assert!(!String::from_utf8_lossy(&o.stderr).contains("panicked"));
    assert!(!d.join("m.json").exists(), "wrote metrics");
}

/// A seed out of range is refused by every command that takes one, saying what a seed is: `-1`
/// was "unexpected argument '-1' found" (taken for an option) or "invalid digit found in
/// string", and nothing was run or written.
#[test]
fn a_seed_out_of_range_says_what_a_seed_is() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let commands: [&[&str]; 4] = [
        &["synth", "-o", "out"],
        &["reconstruct", "scene", "-o", "out"],
        &["demo", "-o", "out"],
        &["study", "-o", "out"],
    ];
    for command in commands {
        for seed in [&["--seed", "-1"][..], &["--seed=-1"], &["--seed", "1.5"], &["--seed", "18446744073709551616"]] {
            let args: Vec<&str> = command.iter().chain(seed).copied().collect();
            let out = fluidnerf(d, &args);
            refused(&out, "a seed is a whole number from 0 to 2^64 - 1 (18446744073709551615)");
            refused(&out, "--seed");
            assert!(!d.join("out").exists(), "{args:?} wrote output");
        }
    }
    // The largest seed is taken (a tiny scene: `--list-presets` takes no seed).
    demo_scene(d, "blobs", 4, 16, 12, &["--seed", "18446744073709551615"]);
    let record = std::fs::read_to_string(d.join("scene/synth.json")).expect("synth.json");
    assert!(record.contains("18446744073709551615"), "{record}");
}

/// A neural run's `method.preset` labels it in its report and in `compare`: a name no preset
/// has, or a preset of another family of methods, is refused naming the key and the presets
/// the method starts from.
#[test]
fn a_config_naming_an_unknown_preset_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    let quick = ["--resolution", "8", "--max-iterations", "1", "-q", "--checkpoint-every", "0"];
    ok(&fluidnerf(d, &[&["reconstruct", "scene", "-o", "fast", "--method", "fast"][..], &quick].concat()));
    for preset in ["nope", "tr-fast"] {
        edit_json(&d.join("fast/config.json"), |v| v["method"]["preset"] = preset.into());
        let o = fluidnerf(d, &["reconstruct", "--config", "fast/config.json", "-o", "again", "-q"]);
        refused(
            &o,
            &format!(
                "the settings of fast/config.json: method.preset: unknown preset \"{preset}\" for fast (known: \
                 faithful, ch7, experimental, fast, dense, voxel)"
            ),
        );
        assert!(!d.join("again").exists(), "{preset}: left an output folder");
    }
}

/// A frame whose `file_path` is empty loaded, and only reading the images failed ("image file
/// is a folder"), naming neither the frame nor the key; it is refused when the scene loads.
#[test]
fn a_frame_with_an_empty_file_path_is_refused_naming_the_frame_and_the_key() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    edit_json(&d.join("scene/transforms.json"), |v| v["frames"][1]["file_path"] = "".into());
    for args in [&["info", "scene"][..], &["reconstruct", "scene", "-o", "run", "--method", "sart", "-q"]] {
        refused(
            &fluidnerf(d, args),
            "scene/transforms.json: frame 1, key `frames[1].file_path`: is \"\", which names no image file",
        );
    }
    assert!(!d.join("run").exists(), "a run started");
}

/// A truth entry whose `file_path` is empty, or names a folder, loaded, and was refused only
/// when the truth was read, as "volume file is a folder" naming neither the entry nor the key;
/// it is refused when the scene loads, as a frame's is.
#[test]
fn a_truth_entry_naming_no_volume_is_refused_naming_the_entry_and_the_key() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 4, 16, 12, &[]);
    for (path, says) in [("", "is \"\", which names no volume file"), ("truth", "truth is a folder, not a volume file")]
    {
        edit_json(&d.join("scene/transforms.json"), |v| v["truth"][0]["file_path"] = path.into());
        for args in [&["info", "scene"][..], &["reconstruct", "scene", "-o", "run", "--method", "sart", "-q"]] {
            refused(
                &fluidnerf(d, args),
                &format!("scene/transforms.json: truth entry 0, key `truth[0].file_path`: {says}"),
            );
        }
        assert!(!d.join("run").exists(), "a run started");
    }
}

/// A time step so small that the later of three or more times all read as an infinite 32-bit
/// time input is refused for the span it makes, asking for a larger step: those times compared
/// equal, and the run was refused as reading two of them as one instant, asking for a smaller
/// step, the opposite of the cure.
#[test]
fn a_time_step_too_small_for_three_instants_asks_for_a_larger_one() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "blobs", 3, 16, 8, &[]);
    edit_json(&d.join("scene/transforms.json"), |v| {
        for (i, f) in v["frames"].as_array_mut().expect("frames").iter_mut().enumerate() {
            f["time"] = i.into();
        }
    });
    let o = fluidnerf(
        d,
        &[
            "reconstruct",
            "scene",
            "-o",
            "run",
            "--method",
            "tr-fluidnerf",
            "--resolution",
            "8",
            "--max-iterations",
            "1",
            "--time-step",
            "1e-300",
        ],
    );
    refused(&o, "method.time_step: the times run from 0 to 2, ");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("time steps of Δt = 1e-300: more than the 16777216 steps"), "{err}");
    assert!(err.contains("give a larger time step"), "{err}");
    let error: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert!(error.len() == 1 && !error[0].contains("one instant"), "{err}");
    assert!(!d.join("run").exists(), "left an output folder");
}

/// A NaN or an infinity, which Python's `json.dump` writes bare, is named as such with its key
/// in every JSON file read: the scene's transforms.json, a run's config.json and synth's
/// settings were refused as "expected value at line L column C" only.
#[test]
fn nan_or_infinity_in_a_json_file_is_named_with_its_key() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    demo_scene(d, "ball", 3, 16, 8, &[]);
    ok(&fluidnerf(d, &["reconstruct", "scene", "-o", "run", "--method", "asart", "--max-iterations", "1", "-q"]));
    // Each file with one value written as Python writes a float that is not finite.
    let bad = |from: &str, to: &str, edit: fn(&mut serde_json::Value), token: &str| {
        let mut v = json(&d.join(from));
        edit(&mut v);
        std::fs::write(d.join(to), v.to_string().replace("\"BAD\"", token)).expect("writes");
    };
    std::fs::create_dir_all(d.join("bad")).expect("mkdir");
    bad(
        "scene/transforms.json",
        "bad/transforms.json",
        |v| v["frames"][1]["transform_matrix"][0][2] = "BAD".into(),
        "NaN",
    );
    let o = fluidnerf(d, &["info", "bad"]);
    refused(&o, "transforms.json: malformed JSON: line 1 column");
    refused(&o, "at `frames[1].transform_matrix[0][2]`: NaN is not a JSON number");
    bad("run/config.json", "cfg.json", |v| v["method"]["params"]["relaxation"] = "BAD".into(), "Infinity");
    let o = fluidnerf(d, &["reconstruct", "--config", "cfg.json", "-o", "again"]);
    refused(&o, "cfg.json");
    refused(&o, "at `method.params.relaxation`: Infinity is not a JSON number");
    bad("scene/synth.json", "synth.json", |v| v["settings"]["aabb"]["min"][0] = "BAD".into(), "-Infinity");
    let o = fluidnerf(d, &["synth", "--config", "synth.json", "-o", "again"]);
    refused(&o, "synth.json: not valid JSON: line 1 column");
    refused(&o, "at `settings.aabb.min[0]`: -Infinity is not a JSON number");
    assert!(!d.join("again").exists(), "left an output folder");
}
