//! [`RunConfig`]: everything a run is configured by, the one source of its defaults, written
//! to `config.json` and read back for a faithful rerun.
//!
//! On disk (`config.json`, [`CONFIG_FORMAT`] 1):
//!
//! ```json
//! {
//!   "format": 1,
//!   "fluidnerf_version": "0.1.0",
//!   "scene": "/data/jet15",
//!   "method": { "name": "asart", "projector": { "kind": "auto", … }, "params": { "relaxation": 0.5, … } },
//!   "seed": 0,
//!   "resolution": 128,
//!   "stopping": { "rule": "own", "max_iterations": null, "time_budget_s": null, … },
//!   "checkpoint_every": 500,
//!   "eval_every": null,
//!   "memory_limit_gib": null,
//!   "gains": { "mode": "auto", "offset": false, "every": null, "rounds": 4 }
//! }
//! ```
//!
//! `method` is tagged by `name`; its other keys are that method's parameters: for the voxel
//! methods `projector` ([`ProjectorConfig`]) and `params` (the solver's parameters); for the
//! static neural methods `preset`, `field`, `train` and, when the field starts from another
//! reconstruction (always for `hybrid`), `start` ([`StartSpec`]); for the time-resolved ones
//! also `windows`, `holdout_times` and `time_step`. Unknown keys are refused with their path.
//!
//! The [`StoppingPolicy`] is applied on top of every method's own parameters, so one policy
//! stops classical and neural methods alike ([`RunConfig::effective_method`]).

use std::path::{Path, PathBuf};
use std::str::FromStr;

use fluidnerf_classical::{
    Algorithm, ArtParams, AsartParams, ClassicalMethod, MartParams, MlemParams, ProjectorConfig, SartParams,
    SmartParams, TikhonovParams, TvParams,
};
use fluidnerf_core::num;
use fluidnerf_neural::hashgrid::HashGridConfig;
use fluidnerf_neural::start::StartFit;
use fluidnerf_neural::temporal::{temporal_preset, TemporalConfig, WindowConfig, TEMPORAL_PRESETS};
use fluidnerf_neural::train::{Batching, TrainConfig};
use fluidnerf_neural::trained::{FieldConfig, NeuralConfig, PRESETS};
use serde::{Deserialize, Serialize};

use crate::PipelineError;

/// The version of the `config.json` layout this build writes and reads.
pub const CONFIG_FORMAT: u32 = 1;

/// Reconstruction methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    Asart,
    Art,
    Sart,
    Mart,
    Smart,
    Mlem,
    Tv,
    Tikhonov,
    Fluidnerf,
    Fast,
    Voxel,
    Hybrid,
    TrFluidnerf,
    TrFast,
    StaticPerFrame,
}

/// The three kinds of run, which write different run folders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// A voxel grid solved algebraically: `volume.npy`.
    Classical,
    /// A static neural field: weights, `model.json` and `volume.npy`.
    Neural,
    /// A field of space and time: windows, `temporal.json` and a volume per frame.
    Temporal,
}

impl Family {
    /// The family in words: "a voxel method".
    pub fn describe(self) -> &'static str {
        match self {
            Family::Classical => "a voxel method",
            Family::Neural => "a static neural method",
            Family::Temporal => "a time-resolved method",
        }
    }
}

impl Method {
    pub const ALL: [Method; 15] = [
        Method::Asart,
        Method::Art,
        Method::Sart,
        Method::Mart,
        Method::Smart,
        Method::Mlem,
        Method::Tv,
        Method::Tikhonov,
        Method::Fluidnerf,
        Method::Fast,
        Method::Voxel,
        Method::Hybrid,
        Method::TrFluidnerf,
        Method::TrFast,
        Method::StaticPerFrame,
    ];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Method::Asart => "asart",
            Method::Art => "art",
            Method::Sart => "sart",
            Method::Mart => "mart",
            Method::Smart => "smart",
            Method::Mlem => "mlem",
            Method::Tv => "tv",
            Method::Tikhonov => "tikhonov",
            Method::Fluidnerf => "fluidnerf",
            Method::Fast => "fast",
            Method::Voxel => "voxel",
            Method::Hybrid => "hybrid",
            Method::TrFluidnerf => "tr-fluidnerf",
            Method::TrFast => "tr-fast",
            Method::StaticPerFrame => "static-per-frame",
        }
    }

    /// A label for tables and legends.
    pub fn label(self) -> &'static str {
        match self {
            Method::Asart => "ASART",
            Method::Art => "ART",
            Method::Sart => "SART",
            Method::Mart => "MART",
            Method::Smart => "SMART",
            Method::Mlem => "MLEM",
            Method::Tv => "SART-TV",
            Method::Tikhonov => "SART-Tikhonov",
            Method::Fluidnerf => "FluidNeRF",
            Method::Fast => "FluidNeRF (fast field)",
            Method::Voxel => "voxel grid + TV",
            Method::Hybrid => "voxel start → grid field",
            Method::TrFluidnerf => "TR-FluidNeRF",
            Method::TrFast => "TR-FluidNeRF (fast field)",
            Method::StaticPerFrame => "FluidNeRF per frame",
        }
    }

    /// One line for `--help`.
    pub fn summary(self) -> &'static str {
        match self {
            Method::Asart => "adaptive simultaneous ART, the dissertation's baseline (Eq. 2.29–2.30)",
            Method::Art => "algebraic reconstruction technique, row by row (Kaczmarz, Eq. 2.21)",
            Method::Sart => "simultaneous ART, view by view (Eq. 2.27)",
            Method::Mart => "multiplicative ART (Eq. 2.25)",
            Method::Smart => "simultaneous multiplicative ART (Eq. 2.28)",
            Method::Mlem => "maximum-likelihood expectation maximisation (Eq. 2.33)",
            Method::Tv => "SART with total-variation regularisation (edge preserving)",
            Method::Tikhonov => "SART with second-order Tikhonov regularisation (Eq. 2.35)",
            Method::Fluidnerf => "FluidNeRF as published: positional encoding + MLP (chapter 5.1)",
            Method::Fast => "FluidNeRF with a multiresolution grid and a tiny MLP: much faster",
            Method::Voxel => "voxel baseline: a grid at the output resolution trained like the fields, with TV",
            Method::Hybrid => {
                "ASART (clean images) or SART-TV (noisy ones) first, then the fast field started from its volume, \
                 in one time budget"
            }
            Method::TrFluidnerf => "time-resolved FluidNeRF (chapter 5.2): one MLP E(x, t) for all frames",
            Method::TrFast => "time-resolved, with a space–time hash grid, in sliding windows",
            Method::StaticPerFrame => "static FluidNeRF trained on each frame separately (TR baseline)",
        }
    }

    /// Whether the run's seed changes its result: the fields draw their rays, samples and
    /// initial weights from it, ART and MART their row order; the other voxel methods have no
    /// randomness.
    pub fn uses_seed(self) -> bool {
        self.family() != Family::Classical || matches!(self, Method::Art | Method::Mart)
    }

    /// Whether the method's static result is a field (the networks, the grid field, the
    /// hybrid) rather than a voxel grid (the classical methods and the voxel baseline, which
    /// the neural engine trains): the two sides of the project's comparisons
    /// (docs/claims.md).
    pub fn is_field(self) -> bool {
        matches!(self, Method::Fluidnerf | Method::Fast | Method::Hybrid)
    }

    pub fn family(self) -> Family {
        match self {
            Method::Fluidnerf | Method::Fast | Method::Voxel | Method::Hybrid => Family::Neural,
            Method::TrFluidnerf | Method::TrFast | Method::StaticPerFrame => Family::Temporal,
            _ => Family::Classical,
        }
    }

    fn algorithm(self) -> Option<Algorithm> {
        Some(match self {
            Method::Asart => Algorithm::Asart,
            Method::Art => Algorithm::Art,
            Method::Sart => Algorithm::Sart,
            Method::Mart => Algorithm::Mart,
            Method::Smart => Algorithm::Smart,
            Method::Mlem => Algorithm::Mlem,
            Method::Tv => Algorithm::Tv,
            Method::Tikhonov => Algorithm::Tikhonov,
            _ => return None,
        })
    }

    /// The preset a neural or time-resolved method starts from.
    pub fn default_preset(self) -> Option<&'static str> {
        match self {
            Method::Fluidnerf => Some("faithful"),
            Method::Fast => Some("fast"),
            Method::Voxel => Some("voxel"),
            Method::Hybrid => Some("fast"),
            Method::TrFluidnerf => Some("tr-faithful"),
            Method::TrFast => Some("tr-fast"),
            Method::StaticPerFrame => Some("static-swish"),
            _ => None,
        }
    }

    /// The method's default parameters.
    pub fn default_config(self) -> MethodConfig {
        match (self.algorithm(), self.default_preset()) {
            (Some(a), _) => MethodConfig::Classical(ClassicalSpec {
                projector: ProjectorConfig::default(),
                method: ClassicalMethod::default_for(a),
            }),
            (None, Some(preset)) => {
                MethodConfig::with_preset(self, preset).unwrap_or_else(|_| unreachable!("built-in preset {preset}"))
            }
            (None, None) => unreachable!("every non-classical method has a preset"),
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = PipelineError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Method::ALL.into_iter().find(|m| m.name() == s).ok_or_else(|| {
            let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
            PipelineError::invalid("method", format!("unknown method {s:?} (known: {})", names.join(", ")))
        })
    }
}

/// A voxel method: the shared projector settings and the solver's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct ClassicalSpec {
    pub projector: ProjectorConfig,
    pub method: ClassicalMethod,
}

/// A static neural method: the field and its training (from `preset`, then overridden).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NeuralSpec {
    /// The named configuration the field and training started from (information only).
    #[serde(default)]
    pub preset: Option<String>,
    pub field: FieldConfig,
    pub train: TrainConfig,
    /// Start the field from another run's reconstruction instead of a uniform field
    /// ([`StartSpec`]). Default none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<StartSpec>,
}

/// A field's start from another reconstruction: before ray training the field is fitted to
/// it (a volume read trilinearly, or a field) by least squares on random points
/// ([`fluidnerf_neural::start`]), and ray training then runs at reduced learning rates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartSpec {
    /// A run folder written by `reconstruct` (any static method); its time is not part of
    /// this run's. None: [`StartSpec::method`] runs first into `start/` of this run's folder,
    /// and its time counts against this run's budget. Default none.
    #[serde(default)]
    pub run: Option<PathBuf>,
    /// The voxel method run first when no run is named: its defaults, this run's output grid,
    /// its own iteration cap, this run's held-out rule if it has one (otherwise its own rule)
    /// and at most half this run's time budget. Default `auto`: ASART when the training
    /// images are clean, SART-TV when they are noisy ([`StartMethod::Auto`]), chosen on the
    /// jet (docs/claims.md).
    #[serde(default)]
    pub method: StartMethod,
    #[serde(default)]
    pub fit: StartFit,
    /// Factor on the ray training's learning-rate schedule: a start is close to a solution,
    /// and the full rate of a fresh field scrambles it. Default 0.25, chosen on the jet
    /// (docs/claims.md).
    #[serde(default = "default_start_lr_scale")]
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub learning_rate_scale: f32,
}

impl Default for StartSpec {
    fn default() -> Self {
        StartSpec {
            run: None,
            method: StartMethod::Auto,
            fit: StartFit::default(),
            learning_rate_scale: default_start_lr_scale(),
        }
    }
}

impl StartSpec {
    /// Rejects settings no start can use.
    pub fn validate(&self) -> Result<(), PipelineError> {
        // The fit's settings are named by their key under `method.start.fit`.
        self.fit.validate().map_err(|e| match e {
            fluidnerf_neural::NeuralError::Invalid { what, why } => PipelineError::invalid(
                format!("method.start.fit.{}", what.strip_prefix("start.").unwrap_or(&what)),
                why,
            ),
            other => PipelineError::invalid("method.start.fit", other.to_string()),
        })?;
        if let (Some(run), StartMethod::Method(m)) = (&self.run, self.method) {
            return Err(PipelineError::invalid(
                "method.start.method",
                format!(
                    "is {m}, a voxel method to run first, but `method.start.run` names the run {} to start from, \
                     which would be the start and {m} never run: give one (set `method` to \"auto\", or `run` to \
                     null)",
                    run.display()
                ),
            ));
        }
        if let StartMethod::Method(m) = self.method {
            if m.family() != Family::Classical {
                return Err(PipelineError::invalid(
                    "method.start.method",
                    format!("{m} is not a voxel method; a start runs one of those"),
                ));
            }
        }
        if !(self.learning_rate_scale > 0.0 && self.learning_rate_scale <= 1.0) {
            return Err(PipelineError::invalid(
                "method.start.learning_rate_scale",
                format!("must be in (0, 1], got {}", num(self.learning_rate_scale)),
            ));
        }
        Ok(())
    }
}

/// The voxel method of a start ([`StartSpec::method`]): `"auto"` or a voxel method's name in
/// the configuration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StartMethod {
    /// ASART when the training images are clean, SART-TV when they are noisy: the median over
    /// the training images of their estimated noise ([`fluidnerf_core::Image::relative_noise`],
    /// a fraction of each image's range) decides, against
    /// [`fluidnerf_core::image::NOISY_ABOVE`]. An
    /// unregularised start carries the images' noise into the field, which the field then
    /// keeps; on clean images it is the more detailed start (docs/claims.md).
    #[default]
    Auto,
    /// This voxel method, whatever the images.
    Method(Method),
}

impl StartMethod {
    /// The voxel method for training images whose median estimated noise is `noise` (`None`:
    /// no estimate, which counts as noisy), and why.
    pub fn resolve(self, noise: Option<f64>) -> (Method, String) {
        match (self, noise) {
            (StartMethod::Method(m), _) => (m, format!("{m}, as configured")),
            (StartMethod::Auto, Some(n)) if fluidnerf_core::image::reads_clean(noise) => (
                Method::Asart,
                format!("asart: the images' noise is estimated at {:.2} % of their range, clean", 100.0 * n),
            ),
            (StartMethod::Auto, Some(n)) => {
                (Method::Tv, format!("tv: the images' noise is estimated at {:.2} % of their range, noisy", 100.0 * n))
            }
            (StartMethod::Auto, None) => (Method::Tv, "tv: the images' noise could not be estimated".into()),
        }
    }
}

impl std::fmt::Display for StartMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StartMethod::Auto => f.write_str("auto"),
            StartMethod::Method(m) => f.write_str(m.name()),
        }
    }
}

impl Serialize for StartMethod {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

/// `"auto"` or any method's name; [`StartSpec::validate`] then refuses a method that is not a
/// voxel method.
impl FromStr for StartMethod {
    type Err = PipelineError;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        if name == "auto" {
            return Ok(StartMethod::Auto);
        }
        name.parse::<Method>()
            .map(StartMethod::Method)
            .map_err(|e| PipelineError::invalid("method", format!("{e}; or \"auto\"")))
    }
}

impl<'de> Deserialize<'de> for StartMethod {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?.parse().map_err(serde::de::Error::custom)
    }
}

fn default_start_lr_scale() -> f32 {
    0.25
}

/// A time-resolved method: field, training, windows, and which times are held out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemporalSpec {
    #[serde(default)]
    pub preset: Option<String>,
    pub field: FieldConfig,
    pub train: TrainConfig,
    pub windows: WindowConfig,
    /// Frame times whose images are not trained on; volumes and metrics are still produced
    /// there (as at a time whose every frame the scene holds out). Default none.
    #[serde(default)]
    pub holdout_times: Vec<f64>,
    /// Frame spacing Δt of `t' = (t − t₀)/Δt`; None: the smallest gap between training times.
    #[serde(default)]
    pub time_step: Option<f64>,
    /// Start every window that does not continue the previous one from reconstructions of its
    /// instants: [`StartSpec::method`] runs on each training instant alone into
    /// `start/tNN/`, and the window's field is fitted to those volumes at its frames. Its
    /// time counts against the time budget of every window. A start names no run here.
    /// Default none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<StartSpec>,
}

impl TemporalSpec {
    /// The neural crate's configuration.
    pub fn temporal_config(&self) -> TemporalConfig {
        TemporalConfig { field: self.field.clone(), train: self.train.clone(), windows: self.windows.clone() }
    }
}

/// A method with its parameters. Serialised tagged by `name` (module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(into = "WireMethod")]
pub enum MethodConfig {
    Classical(ClassicalSpec),
    /// `fluidnerf` or `fast`.
    Neural(Method, NeuralSpec),
    /// `tr-fluidnerf`, `tr-fast` or `static-per-frame`.
    Temporal(Method, TemporalSpec),
}

impl MethodConfig {
    pub fn method(&self) -> Method {
        match self {
            MethodConfig::Classical(c) => match c.method.algorithm() {
                Algorithm::Asart => Method::Asart,
                Algorithm::Art => Method::Art,
                Algorithm::Sart => Method::Sart,
                Algorithm::Mart => Method::Mart,
                Algorithm::Smart => Method::Smart,
                Algorithm::Mlem => Method::Mlem,
                Algorithm::Tv => Method::Tv,
                Algorithm::Tikhonov => Method::Tikhonov,
            },
            MethodConfig::Neural(m, _) | MethodConfig::Temporal(m, _) => *m,
        }
    }

    /// These settings with the field, the training and the windows of the named preset
    /// ([`MethodConfig::with_preset`] of the same method), keeping what no preset sets: the
    /// start ([`StartSpec`]: another run, or a voxel method run first) and, for the
    /// time-resolved methods, the held-out times and the frame spacing. `--preset` given with
    /// `--config` goes through here, so that a rerun with another preset starts as the
    /// configured run did.
    pub fn with_preset_kept(&self, preset: &str) -> Result<Self, PipelineError> {
        let mut fresh = MethodConfig::with_preset(self.method(), preset)?;
        match (self, &mut fresh) {
            (MethodConfig::Neural(_, old), MethodConfig::Neural(_, new)) => {
                new.start = old.start.clone().or_else(|| new.start.take());
            }
            (MethodConfig::Temporal(_, old), MethodConfig::Temporal(_, new)) => {
                new.start = old.start.clone().or_else(|| new.start.take());
                new.holdout_times = old.holdout_times.clone();
                new.time_step = old.time_step;
            }
            _ => {}
        }
        Ok(fresh)
    }

    /// The neural or time-resolved `method` configured from the named preset: any name of
    /// [`PRESETS`] for the static neural methods; any of [`TEMPORAL_PRESETS`] or [`PRESETS`]
    /// for the time-resolved ones.
    pub fn with_preset(method: Method, preset: &str) -> Result<Self, PipelineError> {
        let unknown = |known: String| {
            PipelineError::invalid("preset", format!("unknown preset {preset:?} for {method} (known: {known})"))
        };
        match method.family() {
            Family::Classical => {
                Err(PipelineError::invalid("preset", format!("{method} is a voxel method and has no presets")))
            }
            Family::Neural => {
                let mut c = NeuralConfig::preset(preset).ok_or_else(|| unknown(PRESETS.join(", ")))?;
                // The hybrid starts from a voxel method run first in the same run folder, and
                // on clean images trains on rays over each pixel's area (both chosen by the
                // images' noise).
                let start = (method == Method::Hybrid).then(StartSpec::default);
                if method == Method::Hybrid {
                    c.train.pixel_supersample = fluidnerf_neural::train::Supersample::Auto;
                }
                Ok(MethodConfig::Neural(
                    method,
                    NeuralSpec { preset: Some(preset.into()), field: c.field, train: c.train, start },
                ))
            }
            Family::Temporal => {
                let c = match (temporal_preset(preset), NeuralConfig::preset(preset)) {
                    (Some(c), _) => c,
                    (None, Some(c)) => {
                        TemporalConfig { field: c.field, train: c.train, windows: WindowConfig::default() }
                    }
                    (None, None) => {
                        return Err(unknown(format!("{}; static: {}", TEMPORAL_PRESETS.join(", "), PRESETS.join(", "))))
                    }
                };
                let mut spec = TemporalSpec {
                    preset: Some(preset.into()),
                    field: c.field,
                    train: c.train,
                    windows: c.windows,
                    holdout_times: Vec::new(),
                    time_step: None,
                    start: None,
                };
                if method == Method::StaticPerFrame {
                    spec.windows = WindowConfig::per_frame();
                    spec.train.batching = Batching::AllViews;
                    // Its fields are of space alone: a time-resolved preset's time encoding goes.
                    if let FieldConfig::Mlp(mlp) = &mut spec.field {
                        mlp.time_freqs = 0;
                    }
                } else {
                    spec.train.batching = Batching::OneTimeStep;
                }
                Ok(MethodConfig::Temporal(method, spec))
            }
        }
    }

    /// The training configuration of a neural or time-resolved method.
    pub fn train_mut(&mut self) -> Option<&mut TrainConfig> {
        match self {
            MethodConfig::Classical(_) => None,
            MethodConfig::Neural(_, n) => Some(&mut n.train),
            MethodConfig::Temporal(_, t) => Some(&mut t.train),
        }
    }

    pub fn train(&self) -> Option<&TrainConfig> {
        match self {
            MethodConfig::Classical(_) => None,
            MethodConfig::Neural(_, n) => Some(&n.train),
            MethodConfig::Temporal(_, t) => Some(&t.train),
        }
    }

    /// Rejects parameters no run can use, and a method paired with the settings of another
    /// family (`MethodConfig::Neural(Method::Asart, …)`): the run would read them as its own
    /// kind, and `config.json` would record another method.
    pub fn validate(&self) -> Result<(), PipelineError> {
        let (settings, variant) = match self {
            MethodConfig::Classical(_) => (Family::Classical, "Classical"),
            MethodConfig::Neural(..) => (Family::Neural, "Neural"),
            MethodConfig::Temporal(..) => (Family::Temporal, "Temporal"),
        };
        let m = self.method();
        if m.family() != settings {
            return Err(PipelineError::invalid(
                "method",
                format!(
                    "{m} is {}, but it is given the settings of {} (MethodConfig::{variant}); start from \
                     Method::default_config() of {m}",
                    m.family().describe(),
                    settings.describe()
                ),
            ));
        }
        match self {
            MethodConfig::Classical(c) => {
                c.projector.validate().map_err(|e| classical_under("method.projector", e))?;
                c.method.validate().map_err(|e| classical_under("method.params", e))
            }
            MethodConfig::Neural(m, n) => {
                refuse_unknown_preset(*m, n.preset.as_deref())?;
                validate_field(&n.field)?;
                refuse_time_frequencies(*m, &n.field)?;
                refuse_frame_batching(*m, &n.train)?;
                n.train.validate().map_err(|e| under("method.train", e))?;
                if let Some(start) = &n.start {
                    start.validate()?;
                } else if *m == Method::Hybrid {
                    return Err(PipelineError::invalid(
                        "method.start",
                        "the hybrid method starts from a run: give start",
                    ));
                }
                Ok(())
            }
            MethodConfig::Temporal(m, t) => {
                refuse_unknown_preset(*m, t.preset.as_deref())?;
                validate_field(&t.field)?;
                if *m == Method::StaticPerFrame {
                    refuse_time_frequencies(*m, &t.field)?;
                }
                if matches!(t.field, FieldConfig::Dense(_)) && *m != Method::StaticPerFrame {
                    return Err(PipelineError::invalid(
                        "method.field.dense",
                        format!("{m} trains a field of space and time; a dense grid holds one of space only"),
                    ));
                }
                t.train.validate().map_err(|e| under("method.train", e))?;
                t.temporal_config().validate().map_err(|e| under("method", e))?;
                if let Some(start) = &t.start {
                    start.validate()?;
                    if start.run.is_some() {
                        return Err(PipelineError::invalid(
                            "method.start.run",
                            "a time-resolved run starts from voxel runs of its own instants; it names no run",
                        ));
                    }
                }
                if let Some(dt) = t.time_step {
                    if !(dt > 0.0 && dt.is_finite()) {
                        return Err(PipelineError::invalid(
                            "method.time_step",
                            format!("must be positive, got {}", num(dt)),
                        ));
                    }
                }
                if let Some(h) = t.holdout_times.iter().find(|h| !h.is_finite()) {
                    return Err(PipelineError::invalid("method.holdout_times", format!("{} is not a time", num(*h))));
                }
                // A time given twice would be reconstructed, written and scored twice.
                let times = &t.holdout_times;
                let repeat = times.iter().enumerate().find_map(|(i, &h)| {
                    times[..i].iter().find(|&&g| fluidnerf_core::scene::same_time(g, h)).map(|&g| (g, h))
                });
                if let Some((g, h)) = repeat {
                    let what = if g == h {
                        format!("{} is given twice", num(h))
                    } else {
                        format!("{} and {} are the same time", num(g), num(h))
                    };
                    return Err(PipelineError::invalid("method.holdout_times", format!("{what}; give each time once")));
                }
                if *m == Method::StaticPerFrame && t.windows != WindowConfig::per_frame() {
                    return Err(PipelineError::invalid(
                        "method.windows",
                        "static-per-frame trains one frame per window without warm starts",
                    ));
                }
                Ok(())
            }
        }
    }
}

/// An error of a neural method's training, with a setting of `method.train` that it refuses once
/// the images are read (the `image_scale` that would put them out of range) named by its key,
/// as its checks before the run name it.
pub(crate) fn training_error(e: fluidnerf_neural::NeuralError) -> PipelineError {
    match e {
        fluidnerf_neural::NeuralError::Invalid { what, why } if what == "image_scale" => {
            PipelineError::invalid(format!("method.train.{what}"), why)
        }
        other => other.into(),
    }
}

/// A neural setting's error under its place in the configuration: `prefix.what` when the error
/// names a key (no spaces), else `prefix` with the error's own words.
fn under(prefix: &str, e: fluidnerf_neural::NeuralError) -> PipelineError {
    match e {
        fluidnerf_neural::NeuralError::Invalid { what, why } if !what.contains(' ') => {
            PipelineError::invalid(format!("{prefix}.{what}"), why)
        }
        other => PipelineError::invalid(prefix, other.to_string()),
    }
}

/// A voxel method's setting error under its key in the configuration (`method.projector.ray_step`,
/// `method.params.relaxation`), so that the key, and the option that set it, can be named.
fn classical_under(prefix: &str, e: fluidnerf_classical::ClassicalError) -> PipelineError {
    match e {
        fluidnerf_classical::ClassicalError::Invalid { what, why } => {
            PipelineError::invalid(format!("{prefix}.{what}"), why)
        }
        other => PipelineError::invalid(prefix, other.to_string()),
    }
}

/// Refuses time frequencies, and a hash grid's time axis set off its defaults, for a field of
/// space alone (`method`'s field has no time input), where they would be ignored.
/// The recorded `method.preset` must be a preset `method` starts from ([`MethodConfig::with_preset`]):
/// it labels the run in its report and in `compare`, so a name no preset has, or another
/// family's, would label the run with a configuration it never had.
fn refuse_unknown_preset(method: Method, preset: Option<&str>) -> Result<(), PipelineError> {
    let Some(preset) = preset else { return Ok(()) };
    let known: Vec<&str> = match method.family() {
        Family::Classical => Vec::new(),
        Family::Neural => PRESETS.to_vec(),
        Family::Temporal => TEMPORAL_PRESETS.iter().chain(PRESETS.iter()).copied().collect(),
    };
    if known.contains(&preset) {
        return Ok(());
    }
    Err(PipelineError::invalid(
        "method.preset",
        format!("unknown preset {preset:?} for {method} (known: {})", known.join(", ")),
    ))
}

fn refuse_time_frequencies(method: Method, field: &FieldConfig) -> Result<(), PipelineError> {
    match field {
        FieldConfig::HashGrid(c) => {
            let d = HashGridConfig::default();
            let set = [
                ("time_span", c.time_span != d.time_span, num(c.time_span).to_string(), num(d.time_span).to_string()),
                (
                    "time_resolution",
                    c.time_resolution != d.time_resolution,
                    c.time_resolution.to_string(),
                    d.time_resolution.to_string(),
                ),
                (
                    "time_base_resolution",
                    c.time_base_resolution != d.time_base_resolution,
                    c.time_base_resolution.to_string(),
                    d.time_base_resolution.to_string(),
                ),
            ];
            match set.into_iter().find(|s| s.1) {
                Some((key, _, given, default)) => Err(PipelineError::invalid(
                    format!("method.field.hash-grid.{key}"),
                    format!(
                        "{given} would be ignored: {method} trains a field of space alone, which has no time axis; \
                         leave it at its default {default}, or use a time-resolved method (tr-fast)"
                    ),
                )),
                None => Ok(()),
            }
        }
        FieldConfig::Mlp(c) if c.time_freqs > 0 => Err(PipelineError::invalid(
            "method.field.mlp.time_freqs",
            format!(
                "{} time frequencies, but {method} trains a field of space alone, which has no time to encode; \
                 set 0, or use a time-resolved method (tr-fluidnerf)",
                c.time_freqs
            ),
        )),
        _ => Ok(()),
    }
}

/// Refuses the training settings of a time-resolved run's frames for a static method, where
/// they would be ignored: its field is of one instant, so `batching: one-time-step` batches
/// every view as `all-views` does, and `schedule_per_frame` and `stop_per_frame`, which count
/// cycles through the frames of one-time-step batching, count iterations.
fn refuse_frame_batching(method: Method, train: &TrainConfig) -> Result<(), PipelineError> {
    let set = [
        ("batching", train.batching == Batching::OneTimeStep, "one-time-step"),
        ("schedule_per_frame", train.schedule_per_frame, "true"),
        ("stop_per_frame", train.stop_per_frame, "true"),
    ];
    match set.into_iter().find(|s| s.1) {
        Some((key, _, given)) => Err(PipelineError::invalid(
            format!("method.train.{key}"),
            format!(
                "{given} would be ignored: {method} trains a field of one instant, which has no frames to batch or \
                 count by; leave it out, or use a time-resolved method (tr-fast, tr-fluidnerf)"
            ),
        )),
        None => Ok(()),
    }
}

/// Checks a field's settings before any run builds it.
fn validate_field(field: &FieldConfig) -> Result<(), PipelineError> {
    match field {
        FieldConfig::Mlp(c) => c.validate(),
        FieldConfig::HashGrid(c) => c.validate(),
        FieldConfig::Dense(c) => c.validate(),
    }
    .map_err(|e| under("method.field", e))
}

/// The rule that ends a run, besides the iteration cap and the time budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StopRule {
    /// [`StopRule::HeldOut`] when the scene has held-out views and the method is static,
    /// otherwise [`StopRule::Own`]; decided when the run starts ([`RunConfig::resolved`]), and
    /// `config.json` records the rule decided.
    #[default]
    Auto,
    /// The method's own convergence rule: the residual plateau of the voxel methods (§6.4.1),
    /// the smoothed-loss rule of the neural ones (§5.1.5).
    Own,
    /// No convergence rule: run to the iteration cap or the time budget.
    Budget,
    /// Held-out early stopping: evaluate the loss on the scene's held-out views every
    /// `holdout_every` iterations and keep the iterate where it was lowest; stop after
    /// `patience` evaluations without improvement. Uses no ground truth; needs held-out views.
    HeldOut,
}

/// When every method of a run stops, applied on top of the method's own parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StoppingPolicy {
    pub rule: StopRule,
    /// Iteration cap (per window for time-resolved runs), 1 to
    /// [`fluidnerf_core::MAX_ITERATIONS`]; None: the method's own.
    pub max_iterations: Option<usize>,
    /// Seconds of the method's own work (evaluations excluded); None: unlimited. Per window
    /// for time-resolved runs (each window trains for up to this long; the voxel runs that
    /// start a window, at most half of it, and the fit to them count against it), as
    /// `max_iterations`; a resumed run counts from the resume.
    pub time_budget_s: Option<f64>,
    /// Held-out rule: iterations between evaluations, at most
    /// [`fluidnerf_neural::train::MAX_ITERATION_SPAN`]; None: 1 for voxel methods (each
    /// iteration is a full sweep), [`NEURAL_INTERVAL`] (25) for neural ones.
    pub holdout_every: Option<usize>,
    /// Held-out rule: evaluations without a new best before stopping, at most
    /// [`fluidnerf_neural::train::MAX_ITERATION_SPAN`]; 0 never stops early. Default 10.
    pub patience: usize,
}

impl Default for StoppingPolicy {
    fn default() -> Self {
        StoppingPolicy {
            rule: StopRule::Auto,
            max_iterations: None,
            time_budget_s: None,
            holdout_every: None,
            patience: 10,
        }
    }
}

/// Iterations between a neural method's held-out evaluations unless `holdout_every` says
/// otherwise. Under the held-out rule its NRMSE against ground truth is evaluated at the same
/// iterations unless `eval_every` says otherwise, so that the curve has a point at every
/// iterate the rule can keep, the kept one included. (Voxel methods evaluate both after every
/// iteration.)
pub const NEURAL_INTERVAL: usize = 25;

/// Iterations between a neural method's NRMSE evaluations under the other rules, which keep
/// the last iterate (evaluated at the end in any case).
pub const NEURAL_EVAL_INTERVAL: usize = 100;

impl StoppingPolicy {
    /// Iterations between held-out evaluations for a method of `family`.
    pub fn holdout_interval(&self, family: Family) -> usize {
        self.holdout_every.unwrap_or(if family == Family::Classical { 1 } else { NEURAL_INTERVAL })
    }

    fn validate(&self) -> Result<(), PipelineError> {
        let cap = fluidnerf_core::MAX_ITERATIONS;
        if let Some(n) = self.max_iterations.filter(|n| !(1..=cap).contains(n)) {
            return Err(PipelineError::invalid(
                "stopping.max_iterations",
                format!("must be 1 to {cap} iterations, got {n}"),
            ));
        }
        if let Some(t) = self.time_budget_s {
            if !(t > 0.0 && t.is_finite()) {
                return Err(PipelineError::invalid(
                    "stopping.time_budget_s",
                    format!("must be a positive, finite number of seconds, got {}", num(t)),
                ));
            }
        }
        if self.holdout_every == Some(0) {
            return Err(PipelineError::invalid("stopping.holdout_every", "must be at least 1"));
        }
        // An interval longer than any run would never evaluate the held-out views.
        let max = fluidnerf_neural::train::MAX_ITERATION_SPAN;
        if let Some(n) = self.holdout_every.filter(|&n| n > max) {
            return Err(PipelineError::invalid(
                "stopping.holdout_every",
                format!("must be at most {max} iterations, got {n}"),
            ));
        }
        // A run evaluates at most once an iteration: more evaluations than any span of a run
        // would never stop it.
        if self.patience > max {
            return Err(PipelineError::invalid(
                "stopping.patience",
                format!("must be at most {max} evaluations (0: never stop early), got {}", self.patience),
            ));
        }
        Ok(())
    }

    /// The policy in words without the method-specific evaluation interval, for a comparison
    /// of methods: "held-out early stopping (patience 10)".
    pub fn describe_rule(&self) -> String {
        let mut s = match self.rule {
            StopRule::Auto => {
                "held-out early stopping where there are held-out views, else each method's own rule".to_string()
            }
            StopRule::Own => "each method's own convergence rule".to_string(),
            StopRule::Budget => "iteration cap or time budget only".to_string(),
            StopRule::HeldOut => format!("held-out early stopping (patience {})", self.patience),
        };
        if let Some(n) = self.max_iterations {
            s += &format!(", at most {n} iterations");
        }
        if let Some(t) = self.time_budget_s {
            s += &format!(", at most {} s", num(t));
        }
        s
    }

    /// A short description for reports: "held-out early stopping (every 25 iterations,
    /// patience 10), at most 300 iterations".
    pub fn describe(&self, family: Family) -> String {
        let mut s = match self.rule {
            StopRule::Auto => {
                "held-out early stopping where there are held-out views, else the method's own rule".to_string()
            }
            StopRule::Own => "the method's own convergence rule".to_string(),
            StopRule::Budget => "iteration cap or time budget only".to_string(),
            StopRule::HeldOut => format!(
                "held-out early stopping (every {} iterations, patience {})",
                self.holdout_interval(family),
                self.patience
            ),
        };
        if let Some(n) = self.max_iterations {
            s += &format!(", at most {n} iterations");
        }
        if let Some(t) = self.time_budget_s {
            s += &format!(", at most {} s", num(t));
        }
        s
    }
}

fn default_resolution() -> usize {
    128
}

fn default_checkpoint_every() -> usize {
    500
}

fn default_format() -> u32 {
    CONFIG_FORMAT
}

/// Everything a run is configured by (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Layout version of this file ([`CONFIG_FORMAT`]).
    #[serde(default = "default_format")]
    pub format: u32,
    /// The version that wrote the file (information only).
    #[serde(default)]
    pub fluidnerf_version: String,
    /// The scene: a folder holding `transforms.json`, or the file itself.
    pub scene: PathBuf,
    pub method: MethodConfig,
    /// Seed of every random choice. Default 0.
    #[serde(default)]
    pub seed: u64,
    /// Voxels along the box's longest side of the output volume (and of the working grid of
    /// the voxel methods); cells are cubic. Default 128.
    #[serde(default = "default_resolution")]
    pub resolution: usize,
    #[serde(default)]
    pub stopping: StoppingPolicy,
    /// Neural methods: a resumable checkpoint every N iterations, at most
    /// [`fluidnerf_neural::train::MAX_ITERATION_SPAN`] (0: only at the end and when stopped).
    /// Default 500.
    #[serde(default = "default_checkpoint_every")]
    pub checkpoint_every: usize,
    /// With ground truth: volume NRMSE every N iterations for the time-to-accuracy curve, at
    /// most [`fluidnerf_neural::train::MAX_ITERATION_SPAN`] (0: only at the end); None: every
    /// iteration for voxel methods; for neural ones where the held-out rule evaluates the
    /// held-out loss ([`NEURAL_INTERVAL`]), else every [`NEURAL_EVAL_INTERVAL`].
    #[serde(default)]
    pub eval_every: Option<usize>,
    /// Refuse runs whose estimated memory exceeds this many GiB; None: the memory available
    /// when the run starts.
    #[serde(default)]
    pub memory_limit_gib: Option<f64>,
    /// Per-camera intensity calibration ([`GainConfig`]). Default auto.
    #[serde(default)]
    pub gains: GainConfig,
}

/// How the cameras' relative sensitivities are handled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GainMode {
    /// When the training images' total intensities differ between cameras as differing gains
    /// make them ([`crate::gain_hint`]: an image more than [`crate::GAIN_HINT_RATIO`] off the
    /// median of its time, for its distance and lens): `fit` for a static run, `balance` for a
    /// time-resolved one, which fits no gains (with a warning). `none` otherwise. The run's
    /// report records the mode it took.
    #[default]
    Auto,
    /// Images are taken as they are.
    None,
    /// Every image is scaled to the same total intensity as the others of its time (masked
    /// pixels left out), as in the dissertation's experiments (§8.5).
    Balance,
    /// Balanced first, then a gain per training image (and an offset with
    /// [`GainConfig::offset`]) is fitted with the field: for the neural methods refitted by
    /// least squares against the field's renders every [`GainConfig::every`] iterations; for
    /// the voxel methods in [`GainConfig::rounds`] rounds of `every` iterations, each followed
    /// by a least-squares fit of every view to its reprojection. Gains are normalised to mean 1
    /// over the training images (the absolute scale is the field's).
    Fit,
}

impl FromStr for GainMode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(GainMode::Auto),
            "none" => Ok(GainMode::None),
            "balance" => Ok(GainMode::Balance),
            "fit" => Ok(GainMode::Fit),
            other => Err(format!("`{other}` is not a gain mode: use auto, none, balance or fit")),
        }
    }
}

impl std::fmt::Display for GainMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            GainMode::Auto => "auto",
            GainMode::None => "none",
            GainMode::Balance => "balance",
            GainMode::Fit => "fit",
        })
    }
}

/// Per-camera gains (key `gains` of [`RunConfig`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GainConfig {
    pub mode: GainMode,
    /// With `fit` (or `auto` when it fits): also fit a per-image offset (`pixel = gain × model
    /// + offset`). Default false.
    pub offset: bool,
    /// With `fit` (or `auto`): iterations between refits, 1 to
    /// [`fluidnerf_neural::train::MAX_ITERATION_SPAN`]; None: 25 for the neural methods, 5 for
    /// the voxel methods.
    pub every: Option<usize>,
    /// With `fit` (or `auto`), voxel methods: refits before the final solve, at most
    /// [`fluidnerf_neural::train::MAX_ITERATION_SPAN`]. Default 4.
    pub rounds: usize,
}

impl Default for GainConfig {
    fn default() -> Self {
        GainConfig { mode: GainMode::Auto, offset: false, every: None, rounds: 4 }
    }
}

impl GainConfig {
    /// Whether a run may fit gains: `fit`, or `auto` (when the images ask for it).
    pub fn may_fit(&self) -> bool {
        matches!(self.mode, GainMode::Fit | GainMode::Auto)
    }

    /// Iterations between refits for `family`.
    pub fn interval(&self, family: Family) -> usize {
        self.every.unwrap_or(if family == Family::Classical { 5 } else { 25 })
    }

    fn validate(&self) -> Result<(), PipelineError> {
        let max = fluidnerf_neural::train::MAX_ITERATION_SPAN;
        if let Some(n) = self.every.filter(|n| !(1..=max).contains(n)) {
            return Err(PipelineError::invalid("gains.every", format!("must be 1 to {max} iterations, got {n}")));
        }
        if self.may_fit() && self.rounds == 0 {
            return Err(PipelineError::invalid(
                "gains.rounds",
                format!("must be at least 1 with gains.mode {}", self.mode),
            ));
        }
        // Each refit takes at least an iteration: more refits than any span of a run could never
        // happen, and 2⁶⁴ − 1 overflowed the count of the solve's segments, which ran none.
        if self.rounds > max {
            return Err(PipelineError::invalid(
                "gains.rounds",
                format!("must be at most {max} refits, got {}", self.rounds),
            ));
        }
        if self.offset && !self.may_fit() {
            return Err(PipelineError::invalid("gains.offset", "is fitted only with gains.mode fit (or auto)"));
        }
        // Refits happen only when the gains are fitted; the interval would be ignored.
        if let (Some(every), false) = (self.every, self.may_fit()) {
            return Err(PipelineError::invalid(
                "gains.every",
                format!(
                    "{every} iterations between gain refits, but gains.mode is {}, which fits no gains; set \
                     gains.mode fit (or auto), or leave gains.every out",
                    self.mode
                ),
            ));
        }
        Ok(())
    }
}

impl RunConfig {
    /// The defaults of `method` on `scene`.
    pub fn new(scene: impl Into<PathBuf>, method: Method) -> Self {
        RunConfig {
            format: CONFIG_FORMAT,
            fluidnerf_version: env!("CARGO_PKG_VERSION").to_string(),
            scene: scene.into(),
            method: method.default_config(),
            seed: 0,
            resolution: default_resolution(),
            stopping: StoppingPolicy::default(),
            checkpoint_every: default_checkpoint_every(),
            eval_every: None,
            memory_limit_gib: None,
            gains: GainConfig::default(),
        }
    }

    /// Reads a `config.json`; errors name the file and the key path.
    ///
    /// ```
    /// use fluidnerf_pipeline::{Method, PipelineError, RunConfig};
    /// # fn main() -> Result<(), Box<dyn std::error::Error>> {
    /// # let tmp = tempfile::tempdir()?;
    /// let path = tmp.path().join("config.json");
    /// let mut config = RunConfig::new("/data/jet15", Method::Fast);
    /// config.seed = 7;
    /// std::fs::write(&path, serde_json::to_string_pretty(&config)?)?;
    /// assert_eq!(RunConfig::read(&path)?, config);
    ///
    /// // A misspelt key is refused, naming the file and the key.
    /// let mut value = serde_json::to_value(&config)?;
    /// value["resolutoin"] = 64.into();
    /// std::fs::write(&path, value.to_string())?;
    /// let e = RunConfig::read(&path).unwrap_err();
    /// assert!(matches!(e, PipelineError::File { .. }) && e.to_string().contains("resolutoin"), "{e}");
    ///
    /// // Settings out of range are refused by their key before any work.
    /// config.resolution = 1;
    /// match config.validate() {
    ///     Err(PipelineError::Invalid { key, .. }) => assert_eq!(key, "resolution"),
    ///     other => panic!("{other:?}"),
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn read(path: &Path) -> Result<Self, PipelineError> {
        let config: RunConfig = crate::rundir::read_json(path).map_err(|e| {
            // Another fluidnerf file is named for what it is, not by the first key it has.
            let value: Option<serde_json::Value> = crate::rundir::read_json(path).ok();
            match value.as_ref().and_then(crate::rundir::JsonFileKind::of) {
                Some(kind) if kind != crate::rundir::JsonFileKind::RunConfig => PipelineError::File {
                    path: path.to_path_buf(),
                    why: format!("is {}, not a run's configuration (a run folder's config.json)", kind.describe()),
                },
                _ => e,
            }
        })?;
        if config.format != CONFIG_FORMAT {
            return Err(PipelineError::File {
                path: path.to_path_buf(),
                why: format!(
                    "configuration format {} is not the format {CONFIG_FORMAT} this version reads",
                    config.format
                ),
            });
        }
        Ok(config)
    }

    pub fn method(&self) -> Method {
        self.method.method()
    }

    /// Iterations between NRMSE evaluations (see `eval_every`), for a configuration whose
    /// stopping rule is decided (not `auto`).
    pub fn eval_interval(&self) -> usize {
        self.eval_every.unwrap_or(match self.method().family() {
            Family::Classical => 1,
            _ if self.stopping.rule == StopRule::HeldOut => self.stopping.holdout_interval(Family::Neural),
            _ => NEURAL_EVAL_INTERVAL,
        })
    }

    /// Rejects settings no run can use, before any work starts.
    pub fn validate(&self) -> Result<(), PipelineError> {
        if !(2..=4096).contains(&self.resolution) {
            return Err(PipelineError::invalid(
                "resolution",
                format!("must be between 2 and 4096 voxels along the longest side, got {}", self.resolution),
            ));
        }
        if let Some(g) = self.memory_limit_gib {
            if !(g > 0.0 && g.is_finite()) {
                return Err(PipelineError::invalid("memory_limit_gib", format!("must be positive, got {}", num(g))));
            }
        }
        // An interval longer than any run would never act (no evaluation, no checkpoint).
        let max = fluidnerf_neural::train::MAX_ITERATION_SPAN;
        for (key, n) in [("eval_every", self.eval_every.unwrap_or(0)), ("checkpoint_every", self.checkpoint_every)] {
            if n > max {
                return Err(PipelineError::invalid(
                    key,
                    format!("must be at most {max} iterations (0: only at the end), got {n}"),
                ));
            }
        }
        self.stopping.validate()?;
        self.gains.validate()?;
        if self.method().family() == Family::Temporal {
            if self.gains.mode == GainMode::Fit {
                return Err(PipelineError::invalid(
                    "gains.mode",
                    "gain fitting is available for static methods; use balance for time-resolved runs",
                ));
            }
            // `auto` fits no gains in a time-resolved run: the fit's settings would be ignored.
            let fit_only = [("gains.offset", self.gains.offset), ("gains.every", self.gains.every.is_some())];
            if let Some((key, _)) = fit_only.into_iter().find(|k| k.1) {
                return Err(PipelineError::invalid(
                    key,
                    "applies to fitted gains, and a time-resolved run fits none (with gains auto it balances \
                     its images where they ask for it); leave it out",
                ));
            }
        }
        // A time-resolved run scores its frames once, at its end: an interval would be recorded
        // and never act.
        if self.method().family() == Family::Temporal && self.eval_every.is_some_and(|n| n > 0) {
            return Err(PipelineError::invalid(
                "eval_every",
                "time-resolved runs score their frames once, at the end (NRMSE curves during training are \
                 recorded by static methods); leave it out, or give 0",
            ));
        }
        if self.stopping.rule == StopRule::HeldOut && self.method().family() == Family::Temporal {
            return Err(PipelineError::invalid(
                "stopping.rule",
                "held-out early stopping is available for static methods only; time-resolved runs hold out \
                 whole times with holdout_times",
            ));
        }
        if let MethodConfig::Neural(_, NeuralSpec { train, .. }) = &self.method {
            if self.stopping.rule == StopRule::HeldOut && train.validate_pixels == 0 {
                return Err(PipelineError::invalid(
                    "method.train.validate_pixels",
                    "0 renders no held-out pixels, so held-out early stopping (the rule for scenes with held-out \
                     views) could never judge the field: give at least 1 (default 4096) or choose another \
                     stopping.rule",
                ));
            }
        }
        self.effective_method().validate()
    }

    /// This configuration for `scene`: [`StopRule::Auto`] decided (held-out early stopping when
    /// the scene has held-out views and the method is static, the method's own rule
    /// otherwise), the scene's and a start run's paths made absolute; every other setting as
    /// it is.
    pub fn resolved(&self, scene: &fluidnerf_core::Scene) -> RunConfig {
        let mut c = self.clone();
        // Recorded absolute, as the command line records it, so that `config.json` reruns from
        // any working directory (a relative path would name another folder, or none).
        if let Ok(abs) = std::path::absolute(&c.scene) {
            c.scene = abs;
        }
        if c.stopping.rule == StopRule::Auto {
            let held_out = scene.holdout_frames().next().is_some();
            c.stopping.rule =
                if held_out && self.method().family() != Family::Temporal { StopRule::HeldOut } else { StopRule::Own };
        }
        // A start's run folder is recorded absolute, as the scene is, so the saved
        // configuration reruns from any working directory.
        if let MethodConfig::Neural(_, NeuralSpec { start: Some(StartSpec { run: Some(run), .. }), .. }) = &mut c.method
        {
            if let Ok(abs) = std::path::absolute(&*run) {
                *run = abs;
            }
        }
        c
    }

    /// The method's parameters with the stopping policy applied: the iteration cap and time
    /// budget replace the method's own, the convergence rule is kept only under
    /// [`StopRule::Own`] (and [`StopRule::Auto`] before it is decided), and the held-out rule
    /// sets the neural evaluation interval.
    pub fn effective_method(&self) -> MethodConfig {
        let mut m = self.method.clone();
        let policy = &self.stopping;
        let family = self.method().family();
        match &mut m {
            MethodConfig::Classical(c) => {
                let s = c.method.stopping_mut();
                if let Some(n) = policy.max_iterations {
                    s.max_iterations = n;
                }
                if !matches!(policy.rule, StopRule::Own | StopRule::Auto) {
                    s.plateau = None;
                }
                c.method.set_seed(self.seed);
            }
            MethodConfig::Neural(_, NeuralSpec { train, .. })
            | MethodConfig::Temporal(_, TemporalSpec { train, .. }) => {
                if let Some(n) = policy.max_iterations {
                    train.max_iterations = n;
                }
                if policy.time_budget_s.is_some() {
                    train.time_budget_s = policy.time_budget_s;
                }
                if !matches!(policy.rule, StopRule::Own | StopRule::Auto) {
                    train.stop.window = 0;
                }
                if policy.rule == StopRule::HeldOut {
                    train.validate_every = policy.holdout_interval(family);
                }
            }
        }
        m
    }
}

/// Read by `name` first, then the rest as that method's settings, so that an error names the
/// key inside `method` where it is (serde's tagged enums read the block as a whole and name
/// only `method`). [`METHOD_NAMES`] lists the names, which the round-trip test holds to
/// [`Method::ALL`].
impl<'de> Deserialize<'de> for MethodConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let mut map = serde_json::Map::<String, serde_json::Value>::deserialize(d)?;
        let name = match map.remove("name") {
            Some(serde_json::Value::String(name)) => name,
            Some(other) => return Err(D::Error::custom(format!("`name` must be a method's name, got {other}"))),
            None => return Err(D::Error::missing_field("name")),
        };
        let rest = serde_json::Value::Object(map);
        fn settings<T: serde::de::DeserializeOwned>(rest: serde_json::Value) -> Result<T, String> {
            serde_path_to_error::deserialize(rest).map_err(|e| {
                let (path, why) = (e.path().to_string(), e.inner().to_string());
                if path.is_empty() || path == "." {
                    why
                } else {
                    format!("{NESTED_KEY}{path}`: {why}")
                }
            })
        }
        let wire = match name.as_str() {
            "asart" => settings(rest).map(WireMethod::Asart),
            "art" => settings(rest).map(WireMethod::Art),
            "sart" => settings(rest).map(WireMethod::Sart),
            "mart" => settings(rest).map(WireMethod::Mart),
            "smart" => settings(rest).map(WireMethod::Smart),
            "mlem" => settings(rest).map(WireMethod::Mlem),
            "tv" => settings(rest).map(WireMethod::Tv),
            "tikhonov" => settings(rest).map(WireMethod::Tikhonov),
            "fluidnerf" => settings(rest).map(WireMethod::Fluidnerf),
            "fast" => settings(rest).map(WireMethod::Fast),
            "voxel" => settings(rest).map(WireMethod::Voxel),
            "hybrid" => settings(rest).map(WireMethod::Hybrid),
            "tr-fluidnerf" => settings(rest).map(WireMethod::TrFluidnerf),
            "tr-fast" => settings(rest).map(WireMethod::TrFast),
            "static-per-frame" => settings(rest).map(WireMethod::StaticPerFrame),
            other => return Err(D::Error::unknown_variant(other, METHOD_NAMES)),
        }
        .map_err(D::Error::custom)?;
        Ok(wire.into())
    }
}

/// How a key inside `method` is named in its error, for [`crate::rundir`] to join to `method`.
pub(crate) const NESTED_KEY: &str = "at key `";

/// Every `name` of [`WireMethod`].
const METHOD_NAMES: &[&str] = &[
    "asart",
    "art",
    "sart",
    "mart",
    "smart",
    "mlem",
    "tv",
    "tikhonov",
    "fluidnerf",
    "fast",
    "voxel",
    "hybrid",
    "tr-fluidnerf",
    "tr-fast",
    "static-per-frame",
];

/// The on-disk form of [`MethodConfig`]: tagged by `name`, one variant per method.
#[derive(Serialize)]
#[serde(tag = "name", rename_all = "kebab-case")]
enum WireMethod {
    Asart(Voxel<AsartParams>),
    Art(Voxel<ArtParams>),
    Sart(Voxel<SartParams>),
    Mart(Voxel<MartParams>),
    Smart(Voxel<SmartParams>),
    Mlem(Voxel<MlemParams>),
    Tv(Voxel<TvParams>),
    Tikhonov(Voxel<TikhonovParams>),
    Fluidnerf(NeuralSpec),
    Fast(NeuralSpec),
    Voxel(NeuralSpec),
    Hybrid(NeuralSpec),
    TrFluidnerf(TemporalSpec),
    TrFast(TemporalSpec),
    StaticPerFrame(TemporalSpec),
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Voxel<P> {
    #[serde(default)]
    projector: ProjectorConfig,
    #[serde(default)]
    params: P,
}

impl From<MethodConfig> for WireMethod {
    fn from(m: MethodConfig) -> Self {
        match m {
            MethodConfig::Classical(ClassicalSpec { projector, method }) => match method {
                ClassicalMethod::Asart(params) => WireMethod::Asart(Voxel { projector, params }),
                ClassicalMethod::Art(params) => WireMethod::Art(Voxel { projector, params }),
                ClassicalMethod::Sart(params) => WireMethod::Sart(Voxel { projector, params }),
                ClassicalMethod::Mart(params) => WireMethod::Mart(Voxel { projector, params }),
                ClassicalMethod::Smart(params) => WireMethod::Smart(Voxel { projector, params }),
                ClassicalMethod::Mlem(params) => WireMethod::Mlem(Voxel { projector, params }),
                ClassicalMethod::Tv(params) => WireMethod::Tv(Voxel { projector, params }),
                ClassicalMethod::Tikhonov(params) => WireMethod::Tikhonov(Voxel { projector, params }),
            },
            MethodConfig::Neural(Method::Fluidnerf, n) => WireMethod::Fluidnerf(n),
            MethodConfig::Neural(Method::Voxel, n) => WireMethod::Voxel(n),
            MethodConfig::Neural(Method::Hybrid, n) => WireMethod::Hybrid(n),
            MethodConfig::Neural(_, n) => WireMethod::Fast(n),
            MethodConfig::Temporal(Method::TrFluidnerf, t) => WireMethod::TrFluidnerf(t),
            MethodConfig::Temporal(Method::TrFast, t) => WireMethod::TrFast(t),
            MethodConfig::Temporal(_, t) => WireMethod::StaticPerFrame(t),
        }
    }
}

impl From<WireMethod> for MethodConfig {
    fn from(w: WireMethod) -> Self {
        let c = |projector, method| MethodConfig::Classical(ClassicalSpec { projector, method });
        match w {
            WireMethod::Asart(v) => c(v.projector, ClassicalMethod::Asart(v.params)),
            WireMethod::Art(v) => c(v.projector, ClassicalMethod::Art(v.params)),
            WireMethod::Sart(v) => c(v.projector, ClassicalMethod::Sart(v.params)),
            WireMethod::Mart(v) => c(v.projector, ClassicalMethod::Mart(v.params)),
            WireMethod::Smart(v) => c(v.projector, ClassicalMethod::Smart(v.params)),
            WireMethod::Mlem(v) => c(v.projector, ClassicalMethod::Mlem(v.params)),
            WireMethod::Tv(v) => c(v.projector, ClassicalMethod::Tv(v.params)),
            WireMethod::Tikhonov(v) => c(v.projector, ClassicalMethod::Tikhonov(v.params)),
            WireMethod::Fluidnerf(n) => MethodConfig::Neural(Method::Fluidnerf, n),
            WireMethod::Fast(n) => MethodConfig::Neural(Method::Fast, n),
            WireMethod::Voxel(n) => MethodConfig::Neural(Method::Voxel, n),
            WireMethod::Hybrid(n) => MethodConfig::Neural(Method::Hybrid, n),
            WireMethod::TrFluidnerf(t) => MethodConfig::Temporal(Method::TrFluidnerf, t),
            WireMethod::TrFast(t) => MethodConfig::Temporal(Method::TrFast, t),
            WireMethod::StaticPerFrame(t) => MethodConfig::Temporal(Method::StaticPerFrame, t),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_method_round_trips_through_json() {
        for m in Method::ALL {
            let mut c = RunConfig::new("scene", m);
            c.seed = 7;
            c.validate().unwrap_or_else(|e| panic!("{m}: {e}"));
            let text = serde_json::to_string_pretty(&c).unwrap();
            assert!(text.contains(&format!("\"name\": \"{}\"", m.name())), "{text}");
            let back: RunConfig = serde_json::from_str(&text).unwrap();
            assert_eq!(back, c, "{m}");
            assert_eq!(back.method(), m);
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
        }
    }

    #[test]
    fn a_preset_no_such_method_starts_from_is_refused_naming_the_key_and_the_known_presets() {
        for (m, preset) in [(Method::Fast, "nope"), (Method::Fast, "tr-fast"), (Method::TrFast, "nope")] {
            let mut c = RunConfig::new("scene", m);
            match &mut c.method {
                MethodConfig::Neural(_, n) => n.preset = Some(preset.into()),
                MethodConfig::Temporal(_, t) => t.preset = Some(preset.into()),
                MethodConfig::Classical(_) => unreachable!(),
            }
            let e = c.validate().expect_err(preset).to_string();
            assert!(e.contains("method.preset") && e.contains(&format!("{preset:?}")), "{m} {preset}: {e}");
            assert!(e.contains("faithful, ch7"), "{m} {preset}: {e}");
        }
        // Every preset a method starts from stays accepted, and so does none.
        for m in Method::ALL.into_iter().filter(|m| m.family() != Family::Classical) {
            let names = TEMPORAL_PRESETS.iter().chain(PRESETS.iter());
            for p in names.filter(|p| MethodConfig::with_preset(m, p).is_ok()) {
                let mut c = RunConfig::new("scene", m);
                c.method = MethodConfig::with_preset(m, p).unwrap();
                // (Some are refused for other reasons, as a dense grid for a field of time.)
                if let Err(e) = c.validate() {
                    assert!(!e.to_string().contains("method.preset"), "{m} {p}: {e}");
                }
            }
            let mut c = RunConfig::new("scene", m);
            if let MethodConfig::Neural(_, NeuralSpec { preset, .. })
            | MethodConfig::Temporal(_, TemporalSpec { preset, .. }) = &mut c.method
            {
                *preset = None;
            }
            c.validate().unwrap_or_else(|e| panic!("{m} without a preset: {e}"));
        }
    }

    #[test]
    fn a_wrong_type_inside_method_is_named_by_its_whole_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.json");
        for (method, key, value, says) in [
            (Method::Fast, "/method/train/coarse_samples", serde_json::json!(-5), "method.train.coarse_samples"),
            (Method::Fast, "/method/field/hash-grid/activation", serde_json::json!("tanhh"), "hash-grid.activation"),
            (Method::Asart, "/method/params/relaxation", serde_json::json!("0.5"), "method.params.relaxation"),
            (Method::TrFast, "/method/windows/frames", serde_json::json!(2.5), "method.windows.frames"),
        ] {
            let mut v = serde_json::to_value(RunConfig::new("scene", method)).unwrap();
            *v.pointer_mut(key).unwrap_or_else(|| panic!("{key}")) = value;
            std::fs::write(&path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
            let e = crate::rundir::read_json::<RunConfig>(&path).unwrap_err().to_string();
            assert!(e.contains(&format!("at `{says}")) || e.contains(says), "{key}: {e}");
            assert!(e.contains("config.json") && !e.contains(" at line "), "{key}: {e}");
        }
        for m in Method::ALL {
            assert!(METHOD_NAMES.contains(&m.name()), "{m} is not read back");
        }
        assert_eq!(METHOD_NAMES.len(), Method::ALL.len());
    }

    #[test]
    fn unknown_keys_are_refused_with_their_path() {
        let mut v = serde_json::to_value(RunConfig::new("scene", Method::Asart)).unwrap();
        v["method"]["params"]["relaxaton"] = 0.3.into();
        let e = crate::rundir::from_json_value::<RunConfig>(v).unwrap_err().to_string();
        assert!(e.contains("method") && e.contains("relaxaton"), "{e}");
        let mut v = serde_json::to_value(RunConfig::new("scene", Method::Fast)).unwrap();
        v["sed"] = 1.into();
        let e = crate::rundir::from_json_value::<RunConfig>(v).unwrap_err().to_string();
        assert!(e.contains("sed"), "{e}");
    }

    #[test]
    fn the_policy_overrides_every_family() {
        let mut c = RunConfig::new("scene", Method::Asart);
        c.stopping = StoppingPolicy { rule: StopRule::HeldOut, max_iterations: Some(7), ..Default::default() };
        let MethodConfig::Classical(spec) = c.effective_method() else { panic!() };
        assert_eq!(spec.method.stopping().max_iterations, 7);
        assert!(spec.method.stopping().plateau.is_none());
        let mut c = RunConfig::new("scene", Method::Fast);
        c.stopping = StoppingPolicy { rule: StopRule::HeldOut, time_budget_s: Some(3.0), ..Default::default() };
        let train = c.effective_method().train().unwrap().clone();
        assert_eq!((train.stop.window, train.validate_every, train.time_budget_s), (0, 25, Some(3.0)));
        let mut c = RunConfig::new("scene", Method::TrFast);
        c.stopping.rule = StopRule::HeldOut;
        assert!(c.validate().unwrap_err().to_string().contains("stopping.rule"));
    }

    #[test]
    fn out_of_range_settings_are_refused() {
        let mut c = RunConfig::new("scene", Method::Fast);
        c.resolution = 1;
        assert!(c.validate().unwrap_err().to_string().contains("resolution"));
        let mut c = RunConfig::new("scene", Method::Fast);
        c.stopping.max_iterations = Some(0);
        assert!(c.validate().unwrap_err().to_string().contains("max_iterations"));
    }

    /// Spans of iterations beyond any run's cap are refused naming their key: they could never
    /// act, and a stopping window of 2⁶⁴ − 1 overflowed the rule's sums (the voxel methods'
    /// plateau window and smoothing were taken unbounded and overflowed their rule).
    #[test]
    fn iteration_spans_beyond_any_run_are_refused_by_key() {
        use fluidnerf_neural::train::MAX_ITERATION_SPAN;
        type Edit = fn(&mut RunConfig, usize);
        let edits: [(Method, &str, Edit); 6] = [
            (Method::Asart, "stopping.holdout_every", |c, n| c.stopping.holdout_every = Some(n)),
            (Method::Fast, "method.train.stop.window", |c, n| {
                let MethodConfig::Neural(_, spec) = &mut c.method else { unreachable!("fast is neural") };
                spec.train.stop.window = n;
            }),
            (Method::TrFast, "method.train.stop.smoothing", |c, n| {
                let MethodConfig::Temporal(_, spec) = &mut c.method else { unreachable!("tr-fast is time-resolved") };
                spec.train.stop.smoothing = n;
            }),
            (Method::Asart, "method.params.stopping.plateau.window", |c, n| {
                let MethodConfig::Classical(m) = &mut c.method else { unreachable!("asart is classical") };
                m.method.stopping_mut().plateau.as_mut().expect("asart stops on a plateau").window = n;
            }),
            (Method::Sart, "method.params.stopping.plateau.smoothing", |c, n| {
                let MethodConfig::Classical(m) = &mut c.method else { unreachable!("sart is classical") };
                m.method.stopping_mut().plateau.as_mut().expect("sart stops on a plateau").smoothing = n;
            }),
            (Method::Fast, "method.field.hash-grid.coarse_to_fine", |c, n| {
                let MethodConfig::Neural(_, spec) = &mut c.method else { unreachable!("fast is neural") };
                let FieldConfig::HashGrid(grid) = &mut spec.field else { unreachable!("fast is a hash grid") };
                grid.coarse_to_fine = n;
            }),
        ];
        let edits = edits.map(|(method, key, edit)| (method, key, MAX_ITERATION_SPAN, edit));
        refused_past_their_bounds(&edits);
    }

    /// A setting of a run of a method, its key and bound, and how to set it.
    type Bounded<'a> = (Method, &'a str, usize, fn(&mut RunConfig, usize));

    /// Each setting that `edit` sets in a run of `method` validates at its bound; one past it
    /// and `usize::MAX` are refused, the message naming `key` first and the bound.
    fn refused_past_their_bounds(edits: &[Bounded<'_>]) {
        for &(method, key, bound, edit) in edits {
            let mut c = RunConfig::new("scene", method);
            edit(&mut c, bound);
            c.validate().unwrap_or_else(|e| panic!("{key} at its bound: {e}"));
            for n in [bound + 1, usize::MAX] {
                edit(&mut c, n);
                let e = c.validate().expect_err(key).to_string();
                assert!(e.starts_with(&format!("{key}: ")) && e.contains(&bound.to_string()), "{e}");
            }
        }
    }

    /// A run's intervals (evaluation, checkpoints, held-out evaluations, gain refits), its
    /// patience, its gain refits and its iteration caps are bounded and refused naming their
    /// key: 2⁶⁴ − 1 was taken, an interval never acted, a cap overflowed the progress total of a
    /// run of several windows, and as many refits ran a voxel solve of no iterations.
    #[test]
    fn intervals_patience_and_caps_beyond_any_run_are_refused_by_key() {
        use fluidnerf_core::MAX_ITERATIONS;
        use fluidnerf_neural::train::MAX_ITERATION_SPAN;
        type Edit = fn(&mut RunConfig, usize);
        let fit = |c: &mut RunConfig, n| {
            c.gains.mode = GainMode::Fit;
            c.gains.every = Some(n);
        };
        let edits: [(Method, &str, usize, Edit); 10] = [
            (Method::Fast, "eval_every", MAX_ITERATION_SPAN, |c, n| c.eval_every = Some(n)),
            (Method::Fast, "checkpoint_every", MAX_ITERATION_SPAN, |c, n| c.checkpoint_every = n),
            (Method::Fast, "method.train.validate_every", MAX_ITERATION_SPAN, |c, n| {
                let MethodConfig::Neural(_, spec) = &mut c.method else { unreachable!("fast is neural") };
                spec.train.validate_every = n;
            }),
            (Method::Asart, "gains.every", MAX_ITERATION_SPAN, fit),
            (Method::Asart, "gains.rounds", MAX_ITERATION_SPAN, |c, n| {
                c.gains.mode = GainMode::Fit;
                c.gains.rounds = n;
            }),
            (Method::Fast, "stopping.patience", MAX_ITERATION_SPAN, |c, n| c.stopping.patience = n),
            (Method::TrFast, "stopping.max_iterations", MAX_ITERATIONS, |c, n| c.stopping.max_iterations = Some(n)),
            (Method::Fast, "method.train.max_iterations", MAX_ITERATIONS, |c, n| {
                let MethodConfig::Neural(_, spec) = &mut c.method else { unreachable!("fast is neural") };
                spec.train.max_iterations = n;
            }),
            (Method::Sart, "method.params.stopping.max_iterations", MAX_ITERATIONS, |c, n| {
                let MethodConfig::Classical(m) = &mut c.method else { unreachable!("sart is classical") };
                m.method.stopping_mut().max_iterations = n;
            }),
            (Method::TrFast, "method.windows.warm_max_iterations", MAX_ITERATIONS, |c, n| {
                let MethodConfig::Temporal(_, spec) = &mut c.method else { unreachable!("tr-fast is time-resolved") };
                spec.windows.warm_max_iterations = Some(n);
            }),
        ];
        refused_past_their_bounds(&edits);
    }

    /// A weight or tolerance of a run of a method, its key and bound, and how to set it.
    type BoundedValue<'a> = (Method, &'a str, f64, fn(&mut RunConfig, f64));

    /// Each value that `edit` sets in a run of `method` validates at its bound; beyond it
    /// (twice it, and 10³⁰) it is refused, the message naming `key` first and the bound.
    fn refused_beyond_their_bounds(edits: &[BoundedValue<'_>]) {
        for &(method, key, bound, edit) in edits {
            let mut c = RunConfig::new("scene", method);
            edit(&mut c, bound);
            c.validate().unwrap_or_else(|e| panic!("{key} at its bound: {e}"));
            for v in [2.0 * bound, 1e30] {
                edit(&mut c, v);
                let e = c.validate().expect_err(key).to_string();
                let says = format!("{key}: must be at most {}", fluidnerf_core::num(bound));
                assert!(e.starts_with(&says), "{e}");
            }
        }
    }

    /// The priors' weights are bounded where they stop meaning anything: 10³⁰ trained a flat
    /// field without a word, 3·10³⁸ diverged and blamed the learning rate. So is Adam's ε: at
    /// 10³⁰ training made no progress. And so are the stopping rules' relative tolerances: at
    /// 10³⁰⁰ a voxel run stopped right after its plateau window.
    #[test]
    fn weights_and_tolerances_beyond_their_meaning_are_refused_by_key() {
        use fluidnerf_neural::train::MAX_PRIOR_WEIGHT;
        type Edit = fn(&mut RunConfig, f64);
        fn train(c: &mut RunConfig) -> &mut fluidnerf_neural::train::TrainConfig {
            match &mut c.method {
                MethodConfig::Neural(_, spec) => &mut spec.train,
                MethodConfig::Temporal(_, spec) => &mut spec.train,
                MethodConfig::Classical(_) => unreachable!("a neural method"),
            }
        }
        let prior = f64::from(MAX_PRIOR_WEIGHT);
        let eps = f64::from(fluidnerf_neural::optim::MAX_ADAM_EPS);
        let plateau = fluidnerf_classical::MAX_PLATEAU_TOLERANCE;
        let stop = fluidnerf_neural::train::MAX_STOP_TOLERANCE;
        let edits: [(Method, &str, f64, Edit); 8] = [
            (Method::Asart, "method.params.stopping.plateau.tolerance", plateau, |c, t| {
                let MethodConfig::Classical(m) = &mut c.method else { unreachable!("asart is classical") };
                m.method.stopping_mut().plateau.as_mut().expect("asart stops on a plateau").tolerance = t;
            }),
            (Method::Fast, "method.train.stop.tolerance", stop, |c, t| train(c).stop.tolerance = t),
            (Method::TrFast, "method.train.stop.tolerance", stop, |c, t| train(c).stop.tolerance = t),
            (Method::Fast, "method.train.adam.eps", eps, |c, e| train(c).adam.eps = e as f32),
            (Method::TrFast, "method.train.adam.eps", eps, |c, e| train(c).adam.eps = e as f32),
            (Method::Fast, "method.train.prior.tv", prior, |c, w| train(c).prior.tv = w as f32),
            (Method::Voxel, "method.train.prior.smooth", prior, |c, w| train(c).prior.smooth = w as f32),
            (Method::TrFast, "method.train.prior.sparsity", prior, |c, w| train(c).prior.sparsity = w as f32),
        ];
        refused_beyond_their_bounds(&edits);
    }

    /// The validation of a run of `method` with the classical settings `params`.
    fn validate_classical(method: Method, params: ClassicalMethod) -> Result<(), String> {
        let mut c = RunConfig::new("scene", method);
        let MethodConfig::Classical(spec) = &mut c.method else { unreachable!("{method} is classical") };
        spec.method = params;
        c.validate().map_err(|e| e.to_string())
    }

    /// SART-TV's TV step is at most the SART step (beyond it the iteration diverges), and its
    /// TV steps per iteration are bounded (a huge count never finishes an iteration).
    #[test]
    fn sart_tv_steps_too_large_or_too_many_are_refused() {
        use fluidnerf_classical::TvParams;
        let tv = |p: TvParams| validate_classical(Method::Tv, ClassicalMethod::Tv(p));
        tv(TvParams { tv_weight: 1.0, tv_steps: 1000, ..Default::default() }).expect("the largest step and count");
        for weight in [2.0, 1e300] {
            let e = tv(TvParams { tv_weight: weight, ..Default::default() }).unwrap_err();
            assert!(e.starts_with("method.params.tv_weight: must be at most 1"), "{e}");
        }
        let e = tv(TvParams { tv_steps: 1_000_000_000_000, ..Default::default() }).unwrap_err();
        assert!(e.starts_with("method.params.tv_steps: must be at most 1000"), "{e}");
    }

    /// A Tikhonov weight whose smoothing passes would never end is refused.
    #[test]
    fn a_tikhonov_weight_without_end_is_refused() {
        use fluidnerf_classical::TikhonovParams;
        let tik = |weight| {
            validate_classical(
                Method::Tikhonov,
                ClassicalMethod::Tikhonov(TikhonovParams { weight, ..Default::default() }),
            )
        };
        tik(10.0).expect("the largest weight");
        for weight in [10.5, 1e30] {
            let e = tik(weight).unwrap_err();
            assert!(e.starts_with("method.params.weight: must be at most 10"), "{e}");
        }
    }

    /// A start's fit is named by its key under `method.start.fit`, and points beyond what one
    /// step can hold are refused.
    #[test]
    fn a_start_fit_setting_is_named_by_its_key() {
        for (edit, says) in [
            (
                (|f: &mut StartFit| f.iterations = 0) as fn(&mut StartFit),
                "method.start.fit.iterations: must be 1 to 1000000000 steps, got 0",
            ),
            (
                |f| f.iterations = 1 << 40,
                "method.start.fit.iterations: must be 1 to 1000000000 steps, got 1099511627776",
            ),
            (|f| f.points = usize::MAX, "method.start.fit.points: must be 1 to 1048576 points per step"),
            (|f| f.learning_rate = 0.0, "method.start.fit.learning_rate: must be positive"),
        ] {
            let mut c = RunConfig::new("scene", Method::Hybrid);
            let MethodConfig::Neural(_, spec) = &mut c.method else { unreachable!("hybrid is neural") };
            edit(&mut spec.start.as_mut().expect("the hybrid starts").fit);
            let e = c.validate().expect_err("refused").to_string();
            assert!(e.starts_with(says), "{e}");
        }
    }

    /// A dense grid's settings are named by their key before any run builds it, and a grid of
    /// space alone is refused for a field of space and time.
    #[test]
    fn a_dense_grid_setting_is_named_by_its_key() {
        use fluidnerf_neural::trained::DenseConfig;
        for (dense, says) in [
            (DenseConfig { resolution: 0, initial: 0.05 }, "method.field.dense.resolution: must be 1 to 1024"),
            (DenseConfig { resolution: 100_000, initial: 0.05 }, "method.field.dense.resolution: must be 1 to 1024"),
            (DenseConfig { resolution: 64, initial: -1.0 }, "method.field.dense.initial: must be a positive value"),
            (DenseConfig { resolution: 64, initial: f32::NAN }, "method.field.dense.initial"),
        ] {
            let mut c = RunConfig::new("scene", Method::Voxel);
            let MethodConfig::Neural(_, spec) = &mut c.method else { unreachable!("voxel is neural") };
            spec.field = FieldConfig::Dense(dense);
            let e = c.validate().expect_err("refused").to_string();
            assert!(e.starts_with(says), "{e}");
        }
        let mut c = RunConfig::new("scene", Method::TrFast);
        let MethodConfig::Temporal(_, spec) = &mut c.method else { unreachable!("tr-fast is time-resolved") };
        spec.field = FieldConfig::Dense(DenseConfig::default());
        let e = c.validate().expect_err("refused").to_string();
        assert!(e.starts_with("method.field.dense: tr-fast trains a field of space and time"), "{e}");
        let mut c = RunConfig::new("scene", Method::StaticPerFrame);
        let MethodConfig::Temporal(_, spec) = &mut c.method else { unreachable!("time-resolved") };
        spec.field = FieldConfig::Dense(DenseConfig::default());
        c.validate().expect("a static field per frame may be a dense grid");
    }

    /// Time frequencies of a field of space alone would be ignored: refused naming the key.
    #[test]
    fn time_frequencies_of_a_static_field_are_refused() {
        for method in [Method::Fluidnerf, Method::StaticPerFrame, Method::TrFluidnerf] {
            let mut c = RunConfig::new("scene", method);
            let field = match &mut c.method {
                MethodConfig::Neural(_, n) => &mut n.field,
                MethodConfig::Temporal(_, t) => &mut t.field,
                MethodConfig::Classical(_) => unreachable!("{method} has a field"),
            };
            let FieldConfig::Mlp(mlp) = field else { unreachable!("{method} is an MLP") };
            mlp.time_freqs = 4;
            match (method, c.validate()) {
                (Method::TrFluidnerf, r) => r.expect("a field of space and time encodes time"),
                (_, r) => {
                    let e = r.expect_err("refused").to_string();
                    assert!(e.starts_with("method.field.mlp.time_freqs: 4 time frequencies, but"), "{method}: {e}");
                }
            }
        }
        // A time-resolved preset for fields of one frame each drops its time encoding.
        for preset in TEMPORAL_PRESETS {
            let method = MethodConfig::with_preset(Method::StaticPerFrame, preset).expect("a preset");
            let c = RunConfig { method, ..RunConfig::new("scene", Method::StaticPerFrame) };
            c.validate().unwrap_or_else(|e| panic!("{preset}: {e}"));
        }
    }

    /// The frame batching of time-resolved training, edited into a static method's
    /// configuration, changed nothing: refused naming the key; time-resolved methods keep it.
    #[test]
    fn frame_batching_of_a_static_method_is_refused() {
        type Edit = fn(&mut TrainConfig);
        let edits: [(&str, Edit); 3] = [
            ("batching: one-time-step", |t| t.batching = Batching::OneTimeStep),
            ("schedule_per_frame: true", |t| t.schedule_per_frame = true),
            ("stop_per_frame: true", |t| t.stop_per_frame = true),
        ];
        for method in [Method::Fluidnerf, Method::Fast, Method::Voxel, Method::Hybrid] {
            for (says, edit) in edits {
                let mut c = RunConfig::new("scene", method);
                edit(c.method.train_mut().expect("a neural method trains"));
                let e = c.validate().expect_err("refused").to_string();
                let (key, given) = says.split_once(": ").expect("key: value");
                assert!(e.starts_with(&format!("method.train.{key}: {given} would be ignored: {method}")), "{e}");
            }
        }
        let mut c = RunConfig::new("scene", Method::TrFast);
        let train = c.method.train_mut().expect("trains");
        (train.batching, train.schedule_per_frame, train.stop_per_frame) = (Batching::OneTimeStep, true, true);
        c.validate().expect("time-resolved training batches by frame");
    }

    /// A hash grid's time axis in a field of space alone would be ignored: each of its keys,
    /// set off its default, is refused naming it; at its default it is accepted.
    #[test]
    fn the_time_axis_of_a_static_hash_grid_is_refused() {
        type Edit = fn(&mut HashGridConfig);
        let edits: [(&str, Edit); 3] = [
            ("time_span", |g| g.time_span = 5.0),
            ("time_resolution", |g| g.time_resolution = 4),
            ("time_base_resolution", |g| g.time_base_resolution = 2),
        ];
        for method in [Method::Fast, Method::StaticPerFrame] {
            for (key, edit) in edits {
                let mut c = RunConfig::new("scene", method);
                let field = match &mut c.method {
                    MethodConfig::Neural(_, n) => &mut n.field,
                    MethodConfig::Temporal(_, t) => &mut t.field,
                    MethodConfig::Classical(_) => unreachable!("{method} has a field"),
                };
                let mut grid = HashGridConfig::default();
                if let FieldConfig::HashGrid(g) = field {
                    grid = g.clone();
                }
                *field = FieldConfig::HashGrid(grid);
                c.validate().unwrap_or_else(|e| panic!("{method} at the defaults: {e}"));
                let (MethodConfig::Neural(_, NeuralSpec { field: FieldConfig::HashGrid(g), .. })
                | MethodConfig::Temporal(_, TemporalSpec { field: FieldConfig::HashGrid(g), .. })) = &mut c.method
                else {
                    unreachable!("a hash grid")
                };
                edit(g);
                let e = c.validate().expect_err("refused").to_string();
                assert!(
                    e.starts_with(&format!("method.field.hash-grid.{key}: ")) && e.contains("field of space alone"),
                    "{method}: {e}"
                );
            }
        }
    }

    /// A refit interval without fitted gains would be ignored.
    #[test]
    fn a_gain_refit_interval_needs_fitted_gains() {
        let mut c = RunConfig::new("scene", Method::Asart);
        c.gains.every = Some(5);
        c.validate().expect("auto may fit");
        c.gains.mode = GainMode::None;
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("gains.every") && e.contains("gains.mode is none"), "{e}");
        c.gains.mode = GainMode::Balance;
        assert!(c.validate().unwrap_err().to_string().contains("gains.every"));
        c.gains.mode = GainMode::Fit;
        c.validate().expect("refits of fitted gains");
    }

    #[test]
    fn the_automatic_rule_holds_out_where_it_can() {
        use fluidnerf_core::glam::DVec3;
        use fluidnerf_core::{Aabb, Camera, Frame, Intrinsics, Scene};
        let k = Intrinsics { width: 8, height: 8, fx: 10.0, fy: 10.0, cx: 3.5, cy: 3.5, skew: 0.0 };
        let scene = |holdout: bool| Scene {
            root: "scene".into(),
            aabb: Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0)),
            units: "mm".into(),
            intensity_scale: 1.0,
            frames: (0..3)
                .map(|i| Frame {
                    file_path: format!("c{i}.tiff").into(),
                    camera: Camera::look_at(k, DVec3::new(5.0, i as f64, 0.0), DVec3::ZERO, DVec3::Y),
                    time: None,
                    camera_name: None,
                    holdout: holdout && i == 2,
                })
                .collect(),
            truth: Vec::new(),
        };
        let rule = |m: Method, holdout: bool| RunConfig::new("scene", m).resolved(&scene(holdout)).stopping.rule;
        assert_eq!(RunConfig::new("scene", Method::Fast).stopping.rule, StopRule::Auto);
        for m in [Method::Fast, Method::Asart, Method::Voxel] {
            assert_eq!(rule(m, true), StopRule::HeldOut, "{m}");
            assert_eq!(rule(m, false), StopRule::Own, "{m}");
        }
        assert_eq!(rule(Method::TrFast, true), StopRule::Own);
        // A rule given explicitly is kept.
        let mut c = RunConfig::new("scene", Method::Fast);
        c.stopping.rule = StopRule::Budget;
        assert_eq!(c.resolved(&scene(true)).stopping.rule, StopRule::Budget);
        // Held-out stopping needs held-out pixels to judge by: refused once the rule is decided.
        let mut c = RunConfig::new("scene", Method::Fast);
        let MethodConfig::Neural(_, spec) = &mut c.method else { panic!() };
        spec.train.validate_pixels = 0;
        c.validate().expect("without held-out views the rule is the method's own");
        c.resolved(&scene(false)).validate().expect("no held-out views");
        let e = c.resolved(&scene(true)).validate().unwrap_err().to_string();
        assert!(e.contains("method.train.validate_pixels") && e.contains("held-out"), "{e}");
    }

    #[test]
    fn a_start_run_is_resolved_to_an_absolute_folder() {
        let scene = fluidnerf_core::Scene {
            root: "scene".into(),
            aabb: fluidnerf_core::Aabb::new(
                fluidnerf_core::glam::DVec3::splat(-1.0),
                fluidnerf_core::glam::DVec3::splat(1.0),
            ),
            units: "mm".into(),
            intensity_scale: 1.0,
            frames: Vec::new(),
            truth: Vec::new(),
        };
        let mut c = RunConfig::new("scene", Method::Fast);
        let MethodConfig::Neural(_, spec) = &mut c.method else { unreachable!("fast is neural") };
        spec.start = Some(StartSpec { run: Some("runs/asart".into()), ..StartSpec::default() });
        let r = c.resolved(&scene);
        let MethodConfig::Neural(_, spec) = &r.method else { unreachable!("fast is neural") };
        let run = spec.start.as_ref().and_then(|s| s.run.clone()).expect("kept");
        assert!(run.is_absolute() && run.ends_with("runs/asart"), "{}", run.display());
        // The hybrid's default start names no run, and stays so.
        let h = RunConfig::new("scene", Method::Hybrid).resolved(&scene);
        let MethodConfig::Neural(_, spec) = &h.method else { unreachable!("hybrid is neural") };
        assert_eq!(spec.start, Some(StartSpec::default()));
    }

    /// `method.start.method` is `"auto"` or a voxel method's name, both ways; `auto` picks by
    /// the images' noise, and a missing estimate counts as noisy.
    #[test]
    fn a_start_method_is_auto_or_a_voxel_method() {
        let spec: StartSpec = serde_json::from_str("{}").expect("defaults");
        assert_eq!(spec.method, StartMethod::Auto);
        assert_eq!(serde_json::to_value(&spec).expect("json")["method"], "auto");
        let spec: StartSpec = serde_json::from_str(r#"{"method": "mlem"}"#).expect("a voxel method");
        assert_eq!(spec.method, StartMethod::Method(Method::Mlem));
        assert_eq!(serde_json::to_value(&spec).expect("json")["method"], "mlem");
        let e = serde_json::from_str::<StartSpec>(r#"{"method": "sirt"}"#).expect_err("unknown");
        assert!(e.to_string().contains("sirt") && e.to_string().contains("auto"), "{e}");
        let fast: StartSpec = serde_json::from_str(r#"{"method": "fast"}"#).expect("a method");
        let e = fast.validate().expect_err("not a voxel method");
        assert!(e.to_string().contains("method.start.method"), "{e}");
        let edge = fluidnerf_core::image::NOISY_ABOVE;
        assert_eq!(StartMethod::Auto.resolve(Some(0.0)).0, Method::Asart);
        assert_eq!(StartMethod::Auto.resolve(Some(edge)).0, Method::Asart);
        assert_eq!(StartMethod::Auto.resolve(Some(1.5 * edge)).0, Method::Tv);
        assert_eq!(StartMethod::Auto.resolve(None).0, Method::Tv);
        assert_eq!(StartMethod::Method(Method::Sart).resolve(Some(0.5)).0, Method::Sart);
    }
}
