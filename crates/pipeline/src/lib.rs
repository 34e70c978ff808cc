//! A fluidnerf reconstruction run as a library call: one [`RunConfig`] (the one source of
//! defaults, written to `config.json` and read back for faithful reruns), one [`RunDir`]
//! (paths, atomic writes, lock, the rules for replacing or resuming), a stream of
//! [`RunEvent`]s to a callback that can stop the run, and one typed [`RunReport`] for every
//! method — voxel, static neural and time-resolved alike.
//!
//! Every front end (the `fluidnerf` command line, its demo, scripts, a cluster scheduler)
//! builds a `RunConfig` and calls [`reconstruct`]; none of them writes run files itself.
//!
//! ```
//! use std::ops::ControlFlow;
//! use fluidnerf_pipeline::{reconstruct, Method, Overwrite, RunConfig, RunDir, RunEvent, StopRule};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! # let tmp = tempfile::tempdir()?;
//! # let scene_dir = tmp.path().join("scene");
//! # fluidnerf_pipeline::testing::small_scene(&scene_dir)?;
//! let scene = fluidnerf_io::scene::load_scene(&scene_dir)?;
//! let mut config = RunConfig::new(&scene_dir, Method::Asart);
//! config.resolution = 24;
//! config.stopping.rule = StopRule::Budget;
//! config.stopping.max_iterations = Some(5);
//! let dir = RunDir::create(tmp.path().join("run"), Overwrite::Refuse, Some(&scene.root))?;
//! let report = reconstruct(&scene, &config, &dir, |event| {
//!     if let RunEvent::Iteration { iteration, loss, .. } = event {
//!         println!("iteration {iteration}: residual {loss:.4}");
//!     }
//!     ControlFlow::Continue(())
//! })?;
//! assert_eq!(report.iterations, 5);
//! println!("volume NRMSE {:.3}", report.final_nrmse.unwrap());
//! # Ok(())
//! # }
//! ```

mod classical;
pub mod config;
mod error;
pub mod event;
pub mod html;
pub mod load;
mod measured;
mod neural;
pub mod report;
pub mod rundir;
pub mod score;
pub mod synthetic;
mod temporal;
#[doc(hidden)]
pub mod testing;

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_core::{Scene, Volume};

pub use config::{
    ClassicalSpec, Family, GainConfig, GainMode, Method, MethodConfig, NeuralSpec, RunConfig, StartMethod, StartSpec,
    StopRule, StoppingPolicy, TemporalSpec, CONFIG_FORMAT,
};
pub use error::PipelineError;
pub use event::{duration, RunEvent, WindowPos};
pub use measured::{
    flat_training_images, gain_hint, light_off_box, one_value_throughout, Floor, OffBox, GAIN_HINT_RATIO,
};
pub use report::{
    ClassicalDetails, FrameGain, History, HoldoutPoint, HoldoutScore, LossKind, NeuralDetails, Preprocessing,
    RunReport, RunStatus, StopReason, VolumeRecord, WindowDetails, REPORT_FORMAT,
};
pub use rundir::{DirState, Overwrite, RunDir, RunKind};
pub use temporal::{
    check_given_windows, check_window_folder, finish_windows, reconstruct_windows, window_plan, GivenWindows,
    WindowOutcome, WindowPlan,
};

/// Runs the reconstruction `config` of `scene` into `dir`: decides the stopping rule
/// ([`RunConfig::resolved`]), validates everything first, writes `config.json`, works (reporting through `on_event`, which may stop the run), then writes
/// the results, `report.html`, and `report.json` last. A fresh run that fails before it saved
/// anything to resume from removes what it wrote ([`RunDir::discard_unresumable`]). A run stopped by `on_event` still writes
/// its results and returns a report with [`RunStatus::Interrupted`].
pub fn reconstruct(
    scene: &Scene,
    config: &RunConfig,
    dir: &RunDir,
    mut on_event: impl FnMut(&RunEvent) -> ControlFlow<()>,
) -> Result<RunReport, PipelineError> {
    let config = &config.resolved(scene);
    check_scene_named(config, scene)?;
    // A folder made without the scene's root (`RunDir::create(.., None)`) was never checked
    // against the scene: results could land among its images and truth.
    rundir::check_new_run_folder(dir.root(), Some(&scene.root))?;
    config.validate()?;
    if dir.resuming() {
        check_resumable(config, dir)?;
    }
    // A start run that cannot be started from is refused before any work, not after the
    // training views are prepared.
    if let MethodConfig::Neural(_, NeuralSpec { start: Some(StartSpec { run: Some(run), .. }), .. }) = &config.method {
        neural::start_run(run, scene)?;
    }
    let mut session = Session {
        on_event: &mut on_event,
        stopped: false,
        started: Instant::now(),
        cpu0: cpu_seconds(),
        budget_s: config.stopping.time_budget_s,
        estimate: Estimator::default(),
        warnings: Vec::new(),
    };
    let truth = load_truth(scene)?;
    if let Some(message) = unmatched_truth(scene) {
        session.warn(&message);
    }
    let result = match config.method().family() {
        Family::Classical => classical::run(scene, config, dir, &truth, &mut session),
        Family::Neural => neural::run(scene, config, dir, &truth, &mut session),
        Family::Temporal => temporal::run(scene, config, dir, &truth, &mut session, false),
    };
    if result.is_err() {
        dir.discard_unresumable();
    }
    result
}

/// Refuses a configuration whose `scene` is not the scene given to run: `config.json` would
/// record the one and the results be of the other, and a rerun from that file would
/// reconstruct another scene. `scene` may name the scene's folder or its file.
pub(crate) fn check_scene_named(config: &RunConfig, scene: &Scene) -> Result<(), PipelineError> {
    let named = &config.scene;
    let folder = if named.is_file() { named.parent().unwrap_or(named) } else { named.as_path() };
    if rundir::same_path(folder, &scene.root) {
        return Ok(());
    }
    Err(PipelineError::invalid(
        "scene",
        format!(
            "{} is not the scene being reconstructed (the one in {}), so config.json would record another scene \
             than the run's; set `scene` to the scene's folder or file",
            named.display(),
            scene.root.display()
        ),
    ))
}

/// Refuses to resume the run in `dir` with `config` when it cannot continue it: a voxel method
/// keeps no checkpoint to continue from, and a method other than that of the folder's run would
/// write its results over that run's, leaving the two runs' files mixed in one folder (the
/// command line refuses both from its options; a library or Python caller gives a whole
/// configuration).
fn check_resumable(config: &RunConfig, dir: &RunDir) -> Result<(), PipelineError> {
    let method = config.method();
    if method.family() == Family::Classical {
        return Err(PipelineError::invalid(
            "method.name",
            format!(
                "{method} is a voxel method, which keeps no checkpoint to resume from; run it anew (--force; \
                 `overwrite=\"force\"` from Python)"
            ),
        ));
    }
    let path = dir.config();
    if path.is_file() {
        let saved = RunConfig::read(&path)?.method();
        if saved != method {
            return Err(PipelineError::file(
                &path,
                format!(
                    "holds a run of method {saved}, which a resume continues with its own method, not {method}; \
                     resume it with its own settings, or start a new run (--force; `overwrite=\"force\"` from \
                     Python)"
                ),
            ));
        }
    }
    Ok(())
}

/// A warning for frame times without ground truth ([`Scene::times_without_truth`]): their
/// volumes are not scored, and a time-resolved run's scores cover the other times only.
pub fn truth_gaps(scene: &Scene) -> Option<String> {
    let missing = scene.times_without_truth();
    (!missing.is_empty()).then(|| {
        let times = scene.times();
        format!(
            "the ground truth covers {} of the {} frame times: none at t = {}, so a time-resolved run cannot score \
             its volume{} there and its scores (final_nrmse among them) are over the other times only",
            times.len() - missing.len(),
            times.len(),
            missing.iter().map(|&t| fluidnerf_core::num(t).to_string()).collect::<Vec<_>>().join(", "),
            if missing.len() == 1 { "" } else { "s" }
        )
    })
}

/// A warning for the instants of a recording that fewer cameras imaged than it has
/// ([`Scene::instants_short_of_cameras`]): a time-resolved run reconstructs each instant from
/// the views it has, so those instants rest on fewer views than the others (one view, for a
/// frame whose time was jittered off its instant), which nothing else in the run would show.
pub fn instants_short_of_cameras(scene: &Scene) -> Option<String> {
    let short = scene.instants_short_of_cameras();
    let first = short.first()?;
    let described: Vec<String> = short
        .iter()
        .take(5)
        .map(|s| {
            let t = fluidnerf_core::num(s.time);
            match s.missing.as_slice() {
                [] => format!("t = {t} has {} frames", s.cameras),
                missing if s.cameras <= missing.len() => {
                    let present: Vec<String> = scene
                        .frames
                        .iter()
                        .filter(|f| f.time.is_some_and(|ft| fluidnerf_core::scene::same_time(ft, s.time)))
                        .filter_map(|f| f.camera_name.clone())
                        .collect();
                    format!("t = {t} has {} (only {})", s.cameras, present.join(", "))
                }
                missing => format!("t = {t} has {} (no {})", s.cameras, missing.join(", ")),
            }
        })
        .collect();
    let more = if short.len() > 5 { format!(" and {} more instants", short.len() - 5) } else { String::new() };
    let whole = if first.missing.is_empty() {
        format!("the {} frames of its fullest instant", first.of)
    } else {
        format!("its {} cameras", first.of)
    };
    Some(format!(
        "{} instant{} of the recording have fewer views than {whole}: {}{more}; a time-resolved run reconstructs each \
         instant from the views it has, so these rest on fewer views than the others. If a frame's time is \
         mistyped or jittered off its instant, give it that instant's time",
        short.len(),
        if short.len() == 1 { "" } else { "s" },
        described.join("; ")
    ))
}

/// A warning for one ground truth without a time in a scene of several frame times: it stands
/// for every time ([`Scene::times_without_truth`]), so a time-resolved run scores each of its
/// instants against it. Right for a steady flow; for one instant's truth given without its
/// time, every other instant's score would be against the wrong volume, so it is said.
pub fn timeless_truth(scene: &Scene) -> Option<String> {
    let times = scene.times();
    match scene.truth.as_slice() {
        [only] if only.time.is_none() && times.len() > 1 => Some(format!(
            "the ground truth ({}) has no time, so a time-resolved run scores each of the {} frame times ({} … {}) \
             against it, as for a steady flow; if it is one instant's truth, give it that instant's `time`",
            only.file_path.display(),
            times.len(),
            fluidnerf_core::num(times[0]),
            fluidnerf_core::num(times[times.len() - 1])
        )),
        _ => None,
    }
}

/// Why a static run's metrics are against one ground truth of several: the first one listed.
pub(crate) fn first_truth_only(scene: &Scene) -> String {
    match scene.truth.first() {
        Some(first) if scene.truth.len() > 1 => format!(
            "; its metrics are against the first of the {} ground truths listed ({}) only",
            scene.truth.len(),
            first.time.map_or("without a time".to_string(), |t| format!("at t = {}", fluidnerf_core::num(t)))
        ),
        _ => String::new(),
    }
}

/// A warning for ground truth at times no frame has ([`Scene::unmatched_truth_times`]).
pub fn unmatched_truth(scene: &Scene) -> Option<String> {
    let unmatched = scene.unmatched_truth_times();
    (!unmatched.is_empty()).then(|| {
        let list = |t: &[f64]| t.iter().map(f64::to_string).collect::<Vec<_>>().join(", ");
        format!(
            "ground truth at time {} matches no frame's time (frames at {}): a time-resolved run never scores it",
            list(&unmatched),
            list(&scene.times())
        )
    })
}

/// The scene's ground truth; one that is listed but unreadable is refused, naming the file.
/// How a run scores its volumes against the truth: the default metric options, with the
/// regions along the scene's `flow_axis`, else along the axis estimated from the first truth,
/// else along +x ([`fluidnerf_metrics::regions_flow_axis`]), as `fluidnerf eval` takes them, so
/// that a region of the report and of `eval` is the same part of the box.
fn metric_options(
    scene: &Scene,
    truth: &[(Option<f64>, Volume)],
) -> Result<fluidnerf_metrics::VolumeMetricOptions, PipelineError> {
    let recorded = fluidnerf_io::scene::recorded(scene)?.flow_axis;
    let axis = fluidnerf_metrics::regions_flow_axis(None, recorded, truth.first().map(|(_, t)| t));
    Ok(fluidnerf_metrics::VolumeMetricOptions {
        regions: fluidnerf_metrics::default_regions(axis.map(|(a, _)| a)),
        ..Default::default()
    })
}

fn load_truth(scene: &Scene) -> Result<Vec<(Option<f64>, Volume)>, PipelineError> {
    let truth = fluidnerf_io::scene::load_truth(scene)?;
    for ((time, volume), r) in truth.iter().zip(&scene.truth) {
        if let Some(i) = volume.data.iter().position(|v| !v.is_finite()) {
            return Err(PipelineError::file(
                &scene.resolve(&r.file_path),
                format!(
                    "ground truth{} has a non-finite value at voxel {i}",
                    time.map(|t| format!(" at t = {t}")).unwrap_or_default()
                ),
            ));
        }
        // Refused as `info` and `eval` refuse it: the run scored NaN against it, and a
        // time-resolved run's headline averaged its NRMSE over the other times and its SSIM
        // over all of them.
        if volume.data.iter().all(|&v| v == 0.0) {
            return Err(PipelineError::file(
                &scene.resolve(&r.file_path),
                format!(
                    "every voxel of the ground truth{} is zero, so the NRMSE against it (relative to the truth's \
                     norm) is undefined; give a truth that holds the field, or leave this one out of the scene",
                    time.map(|t| format!(" at t = {t}")).unwrap_or_default()
                ),
            ));
        }
    }
    Ok(truth)
}

/// The caller's callback and what the run measures of itself.
pub(crate) struct Session<'a> {
    on_event: &'a mut dyn FnMut(&RunEvent) -> ControlFlow<()>,
    /// The callback asked to stop.
    stopped: bool,
    started: Instant,
    cpu0: Option<f64>,
    /// The run's time budget (`stopping.time_budget_s`), which bounds the estimate.
    budget_s: Option<f64>,
    /// Every warning given, for `report.json` and `report.html`.
    warnings: Vec<String>,
    estimate: Estimator,
}

/// Measures the first iterations of a run to tell how long the rest will take
/// ([`RunEvent::Estimate`]).
#[derive(Debug, Default)]
struct Estimator {
    /// When iterations started, and the first iteration counted.
    started: Option<(Instant, usize)>,
    /// Iteration cap per window and windows.
    cap: usize,
    windows: usize,
    /// Iterations done since `started` (every window).
    done: usize,
    sent: bool,
    /// Seconds since [`RunEvent::Started`] spent fitting the field to a start before the first
    /// iteration (a time-resolved window's): not iterations' time, but the budget's.
    fit_s: f64,
}

impl Estimator {
    /// Tracks `event`; returns the estimate once enough is measured.
    fn observe(&mut self, event: &RunEvent, budget_s: Option<f64>, now: Instant) -> Option<(f64, usize, f64, bool)> {
        match event {
            RunEvent::Started { max_iterations, windows, start_iteration, .. } => {
                *self = Estimator {
                    started: Some((now, *start_iteration)),
                    cap: *max_iterations,
                    windows: (*windows).max(1),
                    ..Estimator::default()
                };
                None
            }
            // A fit before the first iteration: its time is not an iteration's.
            RunEvent::StartFit { .. } if !self.sent && self.done == 0 => {
                if let Some((t0, first)) = self.started {
                    self.fit_s += now.duration_since(t0).as_secs_f64();
                    self.started = Some((now, first));
                }
                None
            }
            RunEvent::Iteration { .. } if !self.sent => {
                let (t0, first) = self.started?;
                self.done += 1;
                let elapsed = now.duration_since(t0).as_secs_f64();
                if !((self.done >= 3 && elapsed >= 1.0) || elapsed >= 10.0) {
                    return None;
                }
                self.sent = true;
                let per_iteration = elapsed / self.done as f64;
                let left = (self.cap * self.windows).saturating_sub(first + self.done);
                let mut seconds = per_iteration * left as f64;
                let mut limited = false;
                if let Some(b) = budget_s {
                    // The budget counts training time from the start of the run (every window).
                    let rest = (b - self.fit_s - elapsed).max(0.0);
                    if rest < seconds {
                        seconds = rest;
                        limited = true;
                    }
                }
                Some((per_iteration, left, seconds, limited))
            }
            _ => None,
        }
    }
}

impl Session<'_> {
    /// Delivers `event`; remembers a request to stop. After the first iterations, also
    /// delivers the run's [`RunEvent::Estimate`].
    pub(crate) fn emit(&mut self, event: RunEvent) -> ControlFlow<()> {
        let mut flow = (self.on_event)(&event);
        if let Some((seconds_per_iteration, iterations_left, seconds_left, budget_limited)) =
            self.estimate.observe(&event, self.budget_s, Instant::now())
        {
            let estimate = RunEvent::Estimate { seconds_per_iteration, iterations_left, seconds_left, budget_limited };
            if (self.on_event)(&estimate).is_break() {
                flow = ControlFlow::Break(());
            }
        }
        if flow.is_break() {
            self.stopped = true;
        }
        flow
    }

    /// Delivers a warning and keeps it for the run's report, so that it is not lost where
    /// nobody watches the events (`-q`, a Python call without a callback, a study).
    pub(crate) fn warn(&mut self, message: &str) {
        self.warnings.push(message.to_string());
        let _ = self.emit(RunEvent::Warning(message));
    }

    pub(crate) fn cpu_s(&self) -> Option<f64> {
        self.cpu0.zip(cpu_seconds()).map(|(a, b)| b - a)
    }

    pub(crate) fn elapsed_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}

const GIB: f64 = (1u64 << 30) as f64;

/// The memory a run may use: `--memory-limit` (`memory_limit_gib`), else the memory available now.
pub(crate) fn memory_limit(config: &RunConfig) -> u64 {
    match config.memory_limit_gib {
        Some(g) => (g * GIB) as u64,
        None => available_memory().unwrap_or(u64::MAX),
    }
}

/// Refuses a run whose estimated memory exceeds the limit (default: the memory available now).
pub(crate) fn check_memory(
    config: &RunConfig,
    needed: u64,
    what: impl FnOnce() -> String,
) -> Result<(), PipelineError> {
    let limit = memory_limit(config);
    log::info!("estimated memory {:.3} GiB of {:.3} GiB allowed", needed as f64 / GIB, limit as f64 / GIB);
    if needed > limit {
        return Err(PipelineError::Memory(format!(
            "{} needs {} but only {} {}; lower the resolution or the image count, or raise \
             the limit (--memory-limit; memory_limit_gib in a configuration and from Python)",
            what(),
            // A saturated estimate: the request is beyond what 64 bits count.
            if needed == u64::MAX { "more than 16 EiB".to_string() } else { format!("about {}", bytes(needed)) },
            bytes(limit),
            if config.memory_limit_gib.is_some() {
                "are allowed (--memory-limit, memory_limit_gib)"
            } else {
                "are available"
            }
        )));
    }
    Ok(())
}

/// A byte count for people: "3.41 MiB".
pub fn bytes(n: u64) -> String {
    match n {
        n if n >= 1 << 30 => format!("{:.2} GiB", n as f64 / (1u64 << 30) as f64),
        n if n >= 1 << 20 => format!("{:.2} MiB", n as f64 / (1u64 << 20) as f64),
        n if n >= 1 << 10 => format!("{:.1} KiB", n as f64 / 1024.0),
        n => format!("{n} B"),
    }
}

/// CPU seconds (user + system) this process has used so far (Linux; None elsewhere).
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may contain spaces) closed by ')': utime and stime
    // are the 12th and 13th, in clock ticks of 1/100 s (USER_HZ).
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    Some((fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?) / 100.0)
}

/// A `/proc/meminfo` or `/proc/self/status` entry (`key` with its colon), in bytes.
pub fn proc_bytes(file: &str, key: &str) -> Option<u64> {
    let text = std::fs::read_to_string(file).ok()?;
    let line = text.lines().find(|l| l.starts_with(key))?;
    let kib: u64 = line[key.len()..].trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kib * 1024)
}

/// Memory the system can still hand out now (Linux; None elsewhere): the limit of runs and
/// of the commands that check their buffers before allocating them.
pub fn available_memory() -> Option<u64> {
    proc_bytes("/proc/meminfo", "MemAvailable:")
}

/// Peak resident memory of this process (Linux).
pub(crate) fn peak_rss() -> Option<u64> {
    proc_bytes("/proc/self/status", "VmHWM:")
}

/// A digest of a volume's values: FNV-1a (64 bits) over their f32 bit patterns and its grid, as
/// 16 hex digits. It tells the volumes of one run apart (a frame's from another frame's); it is
/// no protection against a file forged on purpose.
pub fn volume_digest(volume: &Volume) -> String {
    let mut h = Fnv::default();
    volume.dims.iter().for_each(|&n| h.word(n as u32));
    volume.data.iter().for_each(|v| h.word(v.to_bits()));
    h.hex()
}

/// The digest of a file's bytes (16 hex digits, FNV-1a over its length and its bytes in
/// little-endian 32-bit words): how a study records the scene files its runs were made from.
pub fn bytes_digest(bytes: &[u8]) -> String {
    let mut h = Fnv::default();
    h.float(bytes.len() as f64);
    let mut words = bytes.chunks_exact(4);
    for w in &mut words {
        h.word(u32::from_le_bytes([w[0], w[1], w[2], w[3]]));
    }
    let rest = words.remainder();
    if !rest.is_empty() {
        let mut last = [0u8; 4];
        last[..rest.len()].copy_from_slice(rest);
        h.word(u32::from_le_bytes(last));
    }
    h.hex()
}

/// FNV-1a (64 bits) over 32-bit words, for the digests and fingerprints runs record
/// ([`volume_digest`], `Measured::fingerprint`).
pub(crate) struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub(crate) fn word(&mut self, w: u32) {
        self.0 = (self.0 ^ u64::from(w)).wrapping_mul(0x0000_0100_0000_01b3);
    }

    /// A 64-bit value as two words, low then high.
    pub(crate) fn float(&mut self, v: f64) {
        let bits = v.to_bits();
        self.word(bits as u32);
        self.word((bits >> 32) as u32);
    }

    /// The hash as 16 hex digits.
    pub(crate) fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// Below this fraction of the brightest training pixel, the most a volume could render is
/// taken for nothing ([`empty_field_warning`]).
const EMPTY_FIELD_FRACTION: f64 = 1e-3;

/// The warning of a neural run whose volumes hold next to nothing although its training images
/// are bright: its largest value `volume_max`, integrated along the box's diagonal (the longest
/// chord any ray has through it), renders less than a thousandth of the brightest training
/// pixel, so that no pixel the field renders comes near the images. A learning rate too large
/// for the field drives its output to zero, or next to it, everywhere, where it stays (the
/// `fast` preset at rates of 0.3 to 1 did, within 60 iterations), and the run would otherwise
/// end as if it had converged, with an empty volume.
pub(crate) fn empty_field_warning(
    problem: &fluidnerf_neural::train::Problem,
    volume_max: f32,
    train: &fluidnerf_neural::train::TrainConfig,
) -> Option<String> {
    let peak = problem.views.iter().map(|v| f64::from(v.image.min_max().1)).fold(0.0, f64::max);
    let rendered = f64::from(volume_max.max(0.0)) * problem.aabb.size().length() * problem.intensity_scale;
    if !(peak > 0.0 && peak.is_finite()) || rendered >= EMPTY_FIELD_FRACTION * peak {
        return None;
    }
    Some(format!(
        "the reconstruction is empty: its largest value, {:.3e}, renders less than a thousandth of the brightest \
         training pixel ({}) along the box's longest chord; training drove the field to zero, as a learning rate \
         too large for it does (method.train.schedule.initial is {}): lower it (--learning-rate)",
        volume_max,
        fluidnerf_core::num(peak),
        fluidnerf_core::num(train.schedule.initial),
    ))
}

/// Writes `stem.npy` and `stem.vti`; the `.vti` of a time-resolved field's frame records its
/// instant `time` (ParaView's `TimeValue`).
pub(crate) fn write_volume(dir: &RunDir, stem: &str, volume: &Volume, time: Option<f64>) -> Result<(), PipelineError> {
    fluidnerf_io::volume::write_npy(&dir.path(&format!("{stem}.npy")), volume)?;
    fluidnerf_io::volume::write_vti_at(&dir.path(&format!("{stem}.vti")), volume, time)?;
    Ok(())
}

/// The held-out early-stopping bookkeeping shared by every method: the best evaluation so far
/// and the evaluations since.
#[derive(Debug)]
pub(crate) struct BestHoldout<T> {
    pub best: Option<(usize, f64, T)>,
    since: usize,
    patience: usize,
}

impl<T> BestHoldout<T> {
    pub(crate) fn new(patience: usize) -> Self {
        BestHoldout { best: None, since: 0, patience }
    }

    /// Records an evaluation; `keep` makes the state to keep when it is the best. Returns true
    /// when patience has run out.
    pub(crate) fn record(&mut self, iteration: usize, loss: f64, keep: impl FnOnce() -> T) -> bool {
        if self.best.as_ref().is_none_or(|b| loss < b.1) {
            self.best = Some((iteration, loss, keep()));
            self.since = 0;
        } else {
            self.since += 1;
        }
        self.patience > 0 && self.since >= self.patience
    }
}

/// Finishes a run: `report.html` (a failure to draw it is a warning, to write it an error), then `report.json`, the
/// completion marker. `measured` holds the images the run read, for the report's camera figure
/// ([`html::run_html`]).
pub(crate) fn finish(
    scene: &Scene,
    dir: &RunDir,
    mut report: RunReport,
    truth: &[(Option<f64>, Volume)],
    measured: Option<&measured::Measured>,
    session: &mut Session,
) -> Result<RunReport, PipelineError> {
    report.warnings = session.warnings.clone();
    let preprocessed = measured.map(|m| m.preprocessed(html::CAMERA_FIGURE_FRAMES));
    match html::run_html(dir, scene, &report, truth, preprocessed.as_deref()) {
        // A report that cannot be drawn is a warning; one that cannot be written (a full disk,
        // a folder that turned read-only) fails the run like any other output it cannot write.
        Ok(Some(html)) => fluidnerf_viz::report::write_report_html(&dir.report_html(), &html)?,
        Ok(None) => {}
        Err(e) => {
            session.warn(&format!("could not write {}: {e}", dir.report_html().display()));
            report.warnings = session.warnings.clone();
        }
    }
    dir.write_json("report.json", &report)?;
    Ok(report)
}

/// The mean of the finite values, if any.
pub(crate) fn mean(values: impl IntoIterator<Item = f64>) -> Option<f64> {
    let v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// Reports hold volume digests, so their values must not change: FNV-1a over the words
    /// 2, 1, 1, bits(0.0), bits(1.0), as a few lines of Python compute it (offset basis
    /// 0xcbf29ce484222325, prime 0x100000001b3, `h = ((h ^ w) * prime) mod 2⁶⁴` per word).
    #[test]
    fn a_volumes_digest_is_fnv1a_over_its_dims_and_values() {
        let aabb = fluidnerf_core::Aabb::cube(fluidnerf_core::glam::DVec3::ZERO, 1.0);
        let volume = Volume { dims: [2, 1, 1], aabb, data: vec![0.0, 1.0] };
        assert_eq!(volume_digest(&volume), "e6c8e580b6fd002f");
    }

    /// [`testing::small_scene`] written into `scene/` of a new temporary folder, and loaded.
    fn small_scene_loaded() -> (tempfile::TempDir, std::path::PathBuf, Scene) {
        let tmp = tempfile::tempdir().expect("tempdir");
        let scene_dir = tmp.path().join("scene");
        testing::small_scene(&scene_dir).expect("scene");
        let scene = fluidnerf_io::scene::load_scene(&scene_dir).expect("loads");
        (tmp, scene_dir, scene)
    }

    /// A method paired with another family's settings, as a library caller can build it, is
    /// refused by its key before any work: a voxel method given a field's settings panicked in
    /// the run, and `config.json` recorded another method.
    #[test]
    fn a_method_given_another_familys_settings_is_refused_not_run() {
        let (tmp, scene_dir, scene) = small_scene_loaded();
        let settings = |m: Method| RunConfig::new(&scene_dir, m).method;
        let MethodConfig::Neural(_, field) = settings(Method::Fast) else { unreachable!("fast is neural") };
        let MethodConfig::Temporal(_, windows) = settings(Method::TrFast) else { unreachable!("tr-fast is temporal") };
        for (k, method) in [
            MethodConfig::Neural(Method::Asart, field.clone()),
            MethodConfig::Neural(Method::TrFast, field),
            MethodConfig::Temporal(Method::Fast, windows.clone()),
            MethodConfig::Temporal(Method::Sart, windows),
        ]
        .into_iter()
        .enumerate()
        {
            let mut config = RunConfig::new(&scene_dir, Method::Asart);
            config.method = method;
            config.resolution = 8;
            config.stopping.max_iterations = Some(1);
            let m = config.method();
            match config.validate() {
                Err(PipelineError::Invalid { key, why }) => {
                    assert_eq!(key, "method", "{m}: {why}");
                    assert!(why.starts_with(&format!("{m} is {}", m.family().describe())), "{m}: {why}");
                }
                other => panic!("{m}: {other:?}"),
            }
            let out = tmp.path().join(format!("run{k}"));
            let dir = RunDir::create(&out, Overwrite::Refuse, Some(&scene.root)).expect("run folder");
            let e = reconstruct(&scene, &config, &dir, |_| ControlFlow::Continue(())).expect_err("refused");
            assert!(matches!(&e, PipelineError::Invalid { key, .. } if key == "method"), "{m}: {e}");
            assert!(!out.join("config.json").exists(), "{m}: nothing is recorded");
        }
    }

    /// A configuration naming another scene than the one run was run, and `config.json` named
    /// that other scene; a relative `scene` was recorded as given, for a rerun to find from the
    /// working directory it happened to start in. The first is refused by its key before any
    /// work, the second recorded absolute.
    #[test]
    fn a_config_naming_another_scene_is_refused_and_the_scene_recorded_absolute() {
        let (tmp, scene_dir, scene) = small_scene_loaded();
        let other = tmp.path().join("other");
        std::fs::create_dir_all(&other).expect("mkdir");
        let mut config = RunConfig::new(&other, Method::Asart);
        config.resolution = 8;
        config.stopping.rule = StopRule::Budget;
        config.stopping.max_iterations = Some(1);
        let out = tmp.path().join("run");
        let dir = RunDir::create(&out, Overwrite::Refuse, Some(&scene.root)).expect("run folder");
        let e = reconstruct(&scene, &config, &dir, |_| ControlFlow::Continue(())).expect_err("another scene");
        assert!(matches!(&e, PipelineError::Invalid { key, .. } if key == "scene"), "{e}");
        assert!(e.to_string().contains("other") && e.to_string().contains("is not the scene"), "{e}");
        assert!(!out.join("config.json").exists(), "nothing is recorded");
        let windows = reconstruct_windows(&scene, &config, &tmp.path().join("w"), 0..1, |_| ControlFlow::Continue(()));
        assert!(matches!(&windows, Err(PipelineError::Invalid { key, .. }) if key == "scene"), "{windows:?}");
        // The scene's file names it as well as its folder does, spelled with `..` too.
        config.scene = other.join("../scene/transforms.json");
        reconstruct(&scene, &config, &dir, |_| ControlFlow::Continue(())).expect("the scene's file");
        let saved = RunConfig::read(&dir.config()).expect("config.json");
        assert!(saved.scene.is_absolute(), "{}", saved.scene.display());
        assert!(rundir::same_path(&saved.scene, &scene_dir.join("transforms.json")));
    }

    /// A run folder made without the scene's root was not checked against the scene, and the
    /// run wrote its results inside the scene's folder, among the files the scene reads.
    #[test]
    fn a_run_folder_inside_the_scene_is_refused_even_when_made_without_the_scene() {
        let (_tmp, scene_dir, scene) = small_scene_loaded();
        let mut config = RunConfig::new(&scene_dir, Method::Asart);
        config.resolution = 8;
        let out = scene_dir.join("run");
        let dir = RunDir::create(&out, Overwrite::Refuse, None).expect("made without the scene");
        let e = reconstruct(&scene, &config, &dir, |_| ControlFlow::Continue(())).expect_err("inside the scene");
        assert!(matches!(&e, PipelineError::RunDir { .. }) && e.to_string().contains("inside the scene folder"), "{e}");
        assert!(!out.join("config.json").exists() && !out.join("volume.npy").exists(), "nothing is written");
    }

    #[test]
    fn the_estimate_comes_once_from_the_measured_rate_and_respects_the_budget() {
        let t0 = Instant::now();
        let at = |s: f64| t0 + Duration::from_secs_f64(s);
        let started = RunEvent::Started { method: Method::Fast, max_iterations: 100, windows: 2, start_iteration: 0 };
        let iteration =
            RunEvent::Iteration { window: None, iteration: 1, loss: 1.0, smoothed: None, train_time_s: 0.0 };
        let run = |budget: Option<f64>| {
            let mut e = Estimator::default();
            assert_eq!(e.observe(&started, budget, t0), None);
            (1..=6).map(|i| e.observe(&iteration, budget, at(0.5 * i as f64))).collect::<Vec<_>>()
        };
        // Three iterations in 1.5 s: 0.5 s each, 200 - 3 left (two windows of 100).
        let free = run(None);
        assert_eq!(&free[..2], &[None, None]);
        assert_eq!(free[2], Some((0.5, 197, 98.5, false)));
        assert!(free[3..].iter().all(Option::is_none), "the estimate is sent once: {free:?}");
        // A 30 s budget, 1.5 s of it spent, bounds the rest.
        assert_eq!(run(Some(30.0))[2], Some((0.5, 197, 28.5, true)));
        // A slow first iteration (20 s) is enough on its own.
        let mut e = Estimator::default();
        e.observe(&started, None, t0);
        assert_eq!(e.observe(&iteration, None, at(20.0)), Some((20.0, 199, 3980.0, false)));
        // A window's fit to its start (8 s) before the first iteration is not an iteration's
        // time, but is the budget's.
        let mut e = Estimator::default();
        e.observe(&started, Some(30.0), t0);
        for s in [1.0, 8.0] {
            assert_eq!(e.observe(&RunEvent::StartFit { step: 0, steps: 10 }, Some(30.0), at(s)), None);
        }
        let after: Vec<_> = (1..=3).map(|i| e.observe(&iteration, Some(30.0), at(8.0 + 0.5 * i as f64))).collect();
        assert_eq!(after[2], Some((0.5, 197, 20.5, true)));
        let text = RunEvent::Estimate {
            seconds_per_iteration: 20.0,
            iterations_left: 199,
            seconds_left: 3980.0,
            budget_limited: false,
        }
        .describe_estimate()
        .expect("an estimate");
        assert_eq!(text, "about 20 s per iteration, at most 199 more iterations: at most 1 h 06 min");
        // Bounded by the budget: the iterations it leaves room for, not the cap's; and a budget
        // spent before the next iteration ends said "at most 24999 more iterations: at most 0.000 s".
        let budget = |spi: f64, left: usize, secs: f64| {
            RunEvent::Estimate {
                seconds_per_iteration: spi,
                iterations_left: left,
                seconds_left: secs,
                budget_limited: true,
            }
            .describe_estimate()
            .expect("an estimate")
        };
        assert_eq!(
            budget(0.5, 24999, 28.5),
            "about 0.500 s per iteration, about 57 more iterations: at most 28 s (the time budget)"
        );
        assert!(budget(14.0, 24999, 0.0).starts_with("about 14 s per iteration, more than is left of the time budget"));
    }
}
