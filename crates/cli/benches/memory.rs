//! The memory estimate that `reconstruct` checks before a run, against the peak resident
//! memory the run then reached, for every family of methods at two sizes.
//!
//! Each run is a separate `fluidnerf reconstruct` process on a synthetic jet (15 cameras), so
//! its peak RSS (`VmHWM`, recorded in `report.json` as `peak_rss_bytes`) is its own. Prints one
//! row per run: the estimate, the peak, and their ratio (above 1: the estimate was generous).
//!
//! `cargo bench -p fluidnerf --bench memory`

use std::path::Path;
use std::process::Command;

fn fluidnerf(dir: &Path, args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_fluidnerf")).current_dir(dir).args(args).output().expect("runs");
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

#[allow(clippy::print_stdout)]
fn main() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let runs: [(&str, &[&str]); 5] = [
        ("asart", &["--method", "asart", "--max-iterations", "3"]),
        ("mlem", &["--method", "mlem", "--max-iterations", "3"]),
        ("tv", &["--method", "tv", "--max-iterations", "3"]),
        ("fast", &["--method", "fast", "--max-iterations", "20"]),
        ("voxel", &["--method", "voxel", "--max-iterations", "20"]),
    ];
    println!(
        "{:<8} {:>6} {:>6} {:>14} {:>14} {:>9}",
        "method", "pixels", "voxels", "estimate [MiB]", "peak RSS [MiB]", "est/peak"
    );
    for (pixels, resolution) in [("64", "64"), ("128", "128")] {
        let scene = format!("scene{pixels}");
        fluidnerf(
            d,
            &["synth", "--preset", "demo", "--pixels", pixels, "--resolution", resolution, "-o", &scene, "-q"],
        );
        for (name, extra) in runs {
            let out = format!("{name}-{pixels}");
            let mut args = vec!["reconstruct", &scene, "-o", &out, "--resolution", resolution, "-q"];
            args.extend_from_slice(extra);
            fluidnerf(d, &args);
            let report: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(d.join(&out).join("report.json")).expect("report"))
                    .expect("json");
            let mib = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN) / (1u64 << 20) as f64;
            let (est, peak) = (mib(&report["memory_estimate_bytes"]), mib(&report["peak_rss_bytes"]));
            println!("{name:<8} {pixels:>6} {resolution:>6} {est:>14.1} {peak:>14.1} {:>9.2}", est / peak);
        }
    }
}
