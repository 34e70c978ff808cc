//! Helpers shared by the end-to-end tests that run the real `fluidnerf` binary.

use std::path::Path;
use std::process::{Command, Output};

/// Runs `fluidnerf ARGS` with `dir` as the working directory.
pub fn fluidnerf(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fluidnerf")).current_dir(dir).args(args).output().expect("runs fluidnerf")
}

/// Asserts that a run succeeded, showing its output when it did not.
pub fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Asserts that a run failed and that its error output names `needle`.
pub fn refused(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded, but should have refused ({needle}): {stderr}");
    assert!(stderr.contains(needle), "{stderr}");
}

/// Parses a JSON file.
pub fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("readable")).expect("json")
}

/// Reads the JSON file `path`, lets `change` edit it, writes it back and returns what `change`
/// returned: how the tests make a scene file bad in one place.
pub fn edit_json<R>(path: &Path, change: impl FnOnce(&mut serde_json::Value) -> R) -> R {
    let mut v = json(path);
    let r = change(&mut v);
    std::fs::write(path, v.to_string()).expect("writes the edited file");
    r
}

/// The `report.json` of a run directory.
pub fn report(dir: &Path) -> serde_json::Value {
    json(&dir.join("report.json"))
}

/// Writes `dir/scene`: `synth --preset demo` with a `phantom` (ball, blobs, …) seen by
/// `cameras` cameras of `pixels`² px, its truth at `resolution`³, and `extra` options.
pub fn demo_scene(dir: &Path, phantom: &str, cameras: u32, pixels: u32, resolution: u32, extra: &[&str]) {
    let (c, p, r) = (cameras.to_string(), pixels.to_string(), resolution.to_string());
    let mut args = vec!["synth", "--preset", "demo", "--phantom", phantom, "--cameras", &c, "--pixels", &p];
    args.extend(["--resolution", &r, "-o", "scene", "-q"]);
    args.extend_from_slice(extra);
    ok(&fluidnerf(dir, &args));
}

/// Runs `fluidnerf ARGS` in `dir`, waits until it has made `made` (a path under `dir`) and half
/// a second more, interrupts it as Ctrl-C does (SIGINT), and returns its output.
pub fn interrupted_once_made(dir: &Path, args: &[&str], made: &str) -> Output {
    signalled_once_made(dir, args, made, "-INT", 500)
}

/// Runs `fluidnerf ARGS` in `dir`, waits until it has made `made` and half a second more, sends
/// it SIGTERM as a batch scheduler's time limit does, and returns its output.
pub fn terminated_once_made(dir: &Path, args: &[&str], made: &str) -> Output {
    signalled_once_made(dir, args, made, "-TERM", 500)
}

/// Runs `fluidnerf ARGS` in `dir`, waits until it has made `made` (a path under `dir`) and kills
/// it at once as a power loss would (SIGKILL: no handler runs), and returns its output.
pub fn killed_once_made(dir: &Path, args: &[&str], made: &str) -> Output {
    signalled_once_made(dir, args, made, "-KILL", 0)
}

/// Runs `fluidnerf ARGS` in `dir`, waits until it has made `made` and `after_ms` more, sends it
/// `signal` (an option of `kill`), and returns its output.
fn signalled_once_made(dir: &Path, args: &[&str], made: &str, signal: &str, after_ms: u64) -> Output {
    let child = Command::new(env!("CARGO_BIN_EXE_fluidnerf"))
        .current_dir(dir)
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("starts");
    let start = std::time::Instant::now();
    while !dir.join(made).exists() {
        assert!(start.elapsed().as_secs() < 60, "{args:?} did not make {made}");
        std::thread::sleep(std::time::Duration::from_millis(if after_ms == 0 { 5 } else { 20 }));
    }
    std::thread::sleep(std::time::Duration::from_millis(after_ms));
    let killed = Command::new("kill").args([signal, &child.id().to_string()]).status().expect("kill");
    assert!(killed.success());
    child.wait_with_output().expect("waits")
}

/// Asserts that each of `files` is byte for byte the same in the run folders `run` and `whole`
/// (a run resumed after a break, and the same run without one).
pub fn same_files(run: &Path, whole: &Path, files: &[&str]) {
    for file in files {
        let (a, b) = (std::fs::read(run.join(file)).expect("read"), std::fs::read(whole.join(file)).expect("read"));
        assert!(a == b, "{file} differs from the run without a break");
    }
}
