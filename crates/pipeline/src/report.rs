//! [`RunReport`]: what a run did and how well, the same type for every method, written to
//! `report.json` ([`REPORT_FORMAT`]) and read back by `compare`, `eval` and the HTML report.

use std::path::Path;

use fluidnerf_classical::{MemoryEstimate, ProjectorKind};
use fluidnerf_core::Aabb;
use fluidnerf_metrics::{NrmsePoint, StepMetrics};
use fluidnerf_neural::train::TrainReport;
use serde::{Deserialize, Serialize};

use crate::{Method, PipelineError, StoppingPolicy};

/// The version of the `report.json` layout this build writes and reads.
pub const REPORT_FORMAT: u32 = 1;

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RunStatus {
    /// A stopping rule ended it.
    Finished,
    /// The caller stopped it (Ctrl-C); the results of the last iteration were written.
    Interrupted,
}

/// Which rule ended the run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StopReason {
    /// The method's own convergence rule.
    Converged,
    /// The iteration cap.
    IterationCap,
    /// The time budget.
    TimeBudget,
    /// The held-out loss stopped improving (patience ran out).
    HeldOutPatience,
    /// The caller stopped the run.
    Interrupted,
}

impl StopReason {
    /// The name `report.json` gives it.
    pub fn name(self) -> &'static str {
        match self {
            StopReason::Converged => "converged",
            StopReason::IterationCap => "iteration-cap",
            StopReason::TimeBudget => "time-budget",
            StopReason::HeldOutPatience => "held-out-patience",
            StopReason::Interrupted => "interrupted",
        }
    }

    /// The reason a [`Self::name`] names, if any.
    pub fn from_name(name: &str) -> Option<StopReason> {
        [
            StopReason::Converged,
            StopReason::IterationCap,
            StopReason::TimeBudget,
            StopReason::HeldOutPatience,
            StopReason::Interrupted,
        ]
        .into_iter()
        .find(|r| r.name() == name)
    }

    /// What ended the run, in words for a report's table: "held-out rule", "time budget".
    pub fn words(self) -> &'static str {
        match self {
            StopReason::Converged => "its own convergence rule",
            StopReason::IterationCap => "iteration cap",
            StopReason::TimeBudget => "time budget",
            StopReason::HeldOutPatience => "held-out rule",
            StopReason::Interrupted => "interrupted",
        }
    }

    /// A terminal table's mark of a run that a cap (`*`) or the time budget (`t`) ended before
    /// its stopping rule did; empty otherwise.
    pub fn mark(self) -> &'static str {
        match self {
            StopReason::IterationCap => "*",
            StopReason::TimeBudget => "t",
            _ => "",
        }
    }

    /// How a run that stopped for this reason ended.
    pub fn status(self) -> RunStatus {
        if self == StopReason::Interrupted {
            RunStatus::Interrupted
        } else {
            RunStatus::Finished
        }
    }
}

impl From<fluidnerf_neural::train::StopReason> for StopReason {
    fn from(r: fluidnerf_neural::train::StopReason) -> Self {
        use fluidnerf_neural::train::StopReason as N;
        match r {
            N::Converged => StopReason::Converged,
            N::MaxIterations => StopReason::IterationCap,
            N::TimeBudget => StopReason::TimeBudget,
            N::Interrupted => StopReason::Interrupted,
        }
    }
}

impl From<fluidnerf_classical::StopReason> for StopReason {
    fn from(r: fluidnerf_classical::StopReason) -> Self {
        use fluidnerf_classical::StopReason as C;
        match r {
            C::Converged => StopReason::Converged,
            C::MaxIterations => StopReason::IterationCap,
            C::Interrupted => StopReason::Interrupted,
        }
    }
}

/// What the loss history measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LossKind {
    /// The neural training loss: MSE in normalised pixel units (Eq. 5.5).
    TrainingMse,
    /// The voxel methods' relative residual `‖p − A g‖ / ‖p‖`.
    RelativeResidual,
}

/// One held-out evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HoldoutPoint {
    pub iteration: usize,
    /// Mean squared pixel error on the held-out views (neural methods: on a fixed subset of
    /// their pixels, normalised by the image scale as the training loss is; voxel methods:
    /// every held-out pixel, relative to the held-out images' mean square).
    pub loss: f64,
    /// Seconds of the method's own work at this evaluation, as [`NrmsePoint::train_time_s`]
    /// counts them. None: not recorded (reports written before it was).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_time_s: Option<f64>,
}

/// The histories every method records.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct History {
    pub loss_kind: Option<LossKind>,
    /// The loss (or residual) after every iteration (of every window, in order).
    pub loss: Vec<f64>,
    pub holdout: Vec<HoldoutPoint>,
    /// Volume NRMSE over the truth sample against iterations and training time.
    pub nrmse: Vec<NrmsePoint>,
    /// Iterations between NRMSE points (0: only the last).
    pub eval_every: usize,
}

/// One written volume: the result of a static run, or one frame of a time-resolved one.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VolumeRecord {
    /// Relative to the run folder.
    pub file: String,
    /// Time in the scene's unit (None for a static run).
    pub time: Option<f64>,
    /// Whether images of this time were trained on.
    pub trained: bool,
    /// `[nx, ny, nz]`.
    pub dims: [usize; 3],
    /// Against the scene's ground truth at this time, when it has one: the field sampled at
    /// the truth's voxel centres (voxel methods: their volume resampled there).
    pub metrics: Option<StepMetrics>,
    /// The digest of the values written ([`crate::volume_digest`]), recorded for the frames of
    /// a time-resolved run, which share one grid: reading the run refuses a file that holds
    /// other values, such as another frame's volume copied over it. None: not recorded (static
    /// runs, and runs written before it was).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub digest: Option<String>,
}

/// Details of a voxel method's run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassicalDetails {
    /// The projector used (`auto` resolved).
    pub projector: ProjectorKind,
    /// Sub-voxels per axis of the splat.
    pub splat_subdivisions: Option<usize>,
    pub voxel_size: [f64; 3],
    pub views: usize,
    pub pixels: usize,
    /// Voxels the visual hull kept, when used.
    pub hull_voxels: Option<usize>,
    pub memory_estimate: MemoryEstimate,
    /// A fingerprint of the views the run reconstructed from (`Measured::fingerprint`): a
    /// resume reads a voxel start back only when its views are the scene's now. None: not
    /// recorded (runs written before it was).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub views_fingerprint: Option<String>,
}

/// Details of a static neural run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct NeuralDetails {
    pub preset: Option<String>,
    pub num_params: usize,
    pub weights_bytes: usize,
    pub image_scale: f64,
    pub occupied_fraction: f64,
    pub rays_kept: usize,
    pub rays_on_box: usize,
    pub train: TrainReport,
}

/// One window of a time-resolved run.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WindowDetails {
    pub frames: [usize; 2],
    pub time_origin: f64,
    pub occupied_fraction: f64,
    pub train: TrainReport,
}

/// The report of a run (module docs).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunReport {
    /// Layout version ([`REPORT_FORMAT`]).
    pub format: u32,
    pub fluidnerf_version: String,
    pub method: Method,
    /// The reconstruction box of the scene (the box every volume of the run fills).
    pub aabb: Aabb,
    /// The scene's world length unit.
    pub units: String,
    pub status: RunStatus,
    pub stop_reason: StopReason,
    /// The policy the run was stopped by, and its description.
    pub stopping: StoppingPolicy,
    pub stopping_rule: String,
    /// Iterations done (summed over windows).
    pub iterations: usize,
    /// The iteration whose field or volume was written (held-out early stopping keeps an
    /// earlier one; otherwise the last).
    pub kept_iteration: usize,
    /// Seconds of loading, ray casting, projector set-up.
    pub setup_s: f64,
    /// Seconds of the method's own work, evaluations excluded.
    pub train_time_s: f64,
    /// Seconds spent on NRMSE and held-out evaluations.
    pub eval_s: f64,
    /// CPU seconds of the process (user + system), to read timings on a busy machine.
    pub cpu_s: Option<f64>,
    /// Peak resident memory of the process (Linux).
    pub peak_rss_bytes: Option<u64>,
    /// The memory estimate checked before the run.
    pub memory_estimate_bytes: u64,
    /// Bytes of the compact result: the weights of a neural field, the volume otherwise.
    pub result_bytes: u64,
    pub history: History,
    pub volumes: Vec<VolumeRecord>,
    /// The instants (training and held-out times, increasing) of a time-resolved run that was
    /// stopped before its windows reached them: no volume is written there, and its field does
    /// not stand for them (after the last trained frame it only repeats that frame). Empty
    /// when the run reached every instant; `--resume` trains the rest.
    #[serde(default)]
    pub not_reached: Vec<f64>,
    /// Mean volume NRMSE over the trained times with truth (the static result's NRMSE).
    pub final_nrmse: Option<f64>,
    pub final_ssim_global: Option<f64>,
    pub classical: Option<ClassicalDetails>,
    pub neural: Option<NeuralDetails>,
    pub windows: Vec<WindowDetails>,
    /// What was done to the images before and during the reconstruction.
    #[serde(default)]
    pub preprocessing: Option<Preprocessing>,
    /// The warnings the run gave, in order (also shown by the command and sent to a Python
    /// callback as they happen).
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// The preprocessing of a run's images: what the scene records (background, masks), what the
/// run did (gains), and what came of it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Preprocessing {
    /// The scene's preprocessing keys in words (`fluidnerf_io::scene::Recording::describe`).
    pub scene: String,
    /// Pixels negative after background subtraction, set to 0.
    pub clipped_pixels: usize,
    /// Pixels at the full scale of their integer images (saturated), used as they are.
    #[serde(default)]
    pub saturated_pixels: usize,
    /// Pixels left out by the frames' masks.
    pub masked_pixels: usize,
    /// The smallest and largest value of the frames' flat fields, normalised to mean 1 over
    /// their used pixels, that the images were divided by (absent without flat fields;
    /// `fluidnerf_io::scene::load_preprocessed` states the correction).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flat_field_range: Option<[f64; 2]>,
    /// The gains as the run took them: where the configuration said `auto`
    /// ([`crate::GainMode::Auto`]), `mode` is `fit` or `none` for a static run, `balance` or
    /// `none` for a time-resolved one (which fits no gains).
    pub gains: crate::GainConfig,
    /// Why `auto` fitted (or balanced) gains: the image whose total lies farthest off its
    /// time's median.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gains_auto: Option<String>,
    /// Per frame of the scene, in order.
    pub frames: Vec<FrameGain>,
}

impl Preprocessing {
    /// `", divided by flat fields of 0.620 .. 1.210"`, or nothing without flat fields.
    pub fn flat_field_text(&self) -> String {
        self.flat_field_range
            .map(|[lo, hi]| format!(", divided by flat fields of {lo:.3} .. {hi:.3}"))
            .unwrap_or_default()
    }

    /// Lines for a terminal: what was done, each camera's gain, the held-out scores.
    pub fn summary_lines(&self) -> Vec<String> {
        let mut out = vec![format!(
            "preprocessing: {}; {} pixel(s) clipped at 0, {} saturated, {} masked{}; gains: {}{}{}",
            self.scene,
            self.clipped_pixels,
            self.saturated_pixels,
            self.masked_pixels,
            self.flat_field_text(),
            self.gains.mode,
            if self.gains.offset { " with offsets" } else { "" },
            self.gains_auto.as_ref().map(|why| format!(" (auto: {why})")).unwrap_or_default()
        )];
        if self.gains.mode != crate::GainMode::None {
            let gains: Vec<String> = self
                .frames
                .iter()
                .filter(|f| !f.holdout)
                .map(|f| {
                    let at = f.time.map(|t| format!(" at t = {}", fluidnerf_core::num(t))).unwrap_or_default();
                    if f.offset != 0.0 {
                        format!("{}{at} {:.3} ({:+.3})", f.camera, f.gain, f.offset)
                    } else {
                        format!("{}{at} {:.3}", f.camera, f.gain)
                    }
                })
                .collect();
            out.push(format!("camera gains: {}", gains.join(", ")));
        }
        for f in &self.frames {
            if let Some(s) = &f.holdout_scores {
                // A camera held out at several times was listed once per time under one name.
                let at = f.time.map(|t| format!(" at t = {}", fluidnerf_core::num(t))).unwrap_or_default();
                out.push(format!(
                    "held-out {}{at}: reprojection NRMSE {:.4} as measured, {:.4} after its best-fit gain {:.3}",
                    f.camera, s.nrmse_raw, s.nrmse_fitted, s.fitted_gain
                ));
            }
        }
        out
    }
}

/// The gain of one image: `pixel = gain × model + offset`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameGain {
    pub frame: usize,
    /// The camera's name, or the image file when the frame names no camera.
    pub camera: String,
    /// The frame's time, in a scene of several (where a camera's name recurs once per time).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time: Option<f64>,
    pub holdout: bool,
    /// Training images: the gain the run used (1 without gains; the balancing factor with
    /// `balance`; the fitted gain with `fit`). Held-out images: the balancing factor; their
    /// best-fit gain against the reconstruction is in `holdout_scores`.
    pub gain: f64,
    pub offset: f64,
    /// Held-out images: NRMSE of the reprojection as measured, and after the best-fit gain.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub holdout_scores: Option<HoldoutScore>,
}

/// A held-out image against the reconstruction's rendering of it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HoldoutScore {
    /// `‖p − r‖ / ‖p‖` over the used pixels.
    pub nrmse_raw: f64,
    /// The same after scaling the rendering by the best-fit gain `Σ p r / Σ r²`.
    pub nrmse_fitted: f64,
    pub fitted_gain: f64,
}

impl RunReport {
    /// The iteration kept, where it is not the last (held-out early stopping kept an earlier
    /// one): what the plots mark.
    pub fn kept_before_end(&self) -> Option<usize> {
        (self.kept_iteration != self.iterations).then_some(self.kept_iteration)
    }

    /// Reads `report.json`; errors name the file, the key path, or a format this version
    /// does not read.
    pub fn read(path: &Path) -> Result<Self, PipelineError> {
        #[derive(Deserialize)]
        struct Version {
            format: Option<u32>,
        }
        let v: Version = crate::rundir::read_json(path)?;
        match v.format {
            Some(REPORT_FORMAT) => crate::rundir::read_json(path),
            Some(f) => Err(PipelineError::file(
                path,
                format!("report format {f} is not the format {REPORT_FORMAT} this version reads"),
            )),
            None => Err(PipelineError::file(path, "not a run report (no `format`): written by an older version?")),
        }
    }

    /// The terminal summary line of the run, the figures of `report.json` at the precision
    /// the HTML report shows.
    pub fn summary_line(&self) -> String {
        let reason = match self.stop_reason {
            StopReason::Converged => "converged",
            StopReason::IterationCap => "iteration cap",
            StopReason::TimeBudget => "time budget",
            StopReason::HeldOutPatience => "held-out loss stopped improving",
            StopReason::Interrupted => "interrupted",
        };
        let noun = if self.iterations == 1 { "iteration" } else { "iterations" };
        let mut s = format!("{}: {} {noun} ({reason}), {:.1} s", self.method, self.iterations, self.train_time_s);
        if self.kept_iteration != self.iterations {
            s += &format!(", kept iteration {}", self.kept_iteration);
        }
        if let Some(n) = self.final_nrmse {
            s += &format!(", volume NRMSE {}", fluidnerf_viz::report::format_value(n));
            // A time-resolved run whose truth covers only some of its times.
            let trained = self.volumes.iter().filter(|v| v.trained).count();
            let scored = self.volumes.iter().filter(|v| v.trained && v.metrics.is_some()).count();
            if scored < trained {
                s += &format!(" (mean over the {scored} of {trained} times with ground truth)");
            }
        }
        if let Some(g) = self.final_ssim_global {
            s += &format!(", global SSIM {}", fluidnerf_viz::report::format_value(g));
        }
        let trains = self.neural.iter().map(|n| &n.train).chain(self.windows.iter().map(|w| &w.train));
        if trains.into_iter().any(|t| t.bf16_products) {
            s += ", decoder trained with bfloat16 products";
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stop reason's name is the one `report.json` writes.
    #[test]
    fn a_stop_reasons_name_is_its_report_spelling() {
        use StopReason::*;
        for r in [Converged, IterationCap, TimeBudget, HeldOutPatience, Interrupted] {
            assert_eq!(serde_json::to_value(r).unwrap(), r.name());
            assert_eq!(StopReason::from_name(r.name()), Some(r));
        }
        assert_eq!(StopReason::from_name("held-out"), None);
    }
}
