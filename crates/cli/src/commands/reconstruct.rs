//! `fluidnerf reconstruct`: maps the command line onto a [`RunConfig`] and the run's events
//! onto a progress bar; the run itself is [`fluidnerf_pipeline::reconstruct`].
//!
//! Every option is optional on the command line so that an option given explicitly always
//! overrides `--config`, even when it equals the default.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use clap::builder::PossibleValue;
use fluidnerf_classical::{Plateau, ProjectorKind};
use fluidnerf_neural::occupancy::OccupancyConfig;
use fluidnerf_neural::temporal::TimeOrigin;
use fluidnerf_pipeline::{
    Family, Method, MethodConfig, Overwrite, RunConfig, RunDir, RunEvent, RunStatus, StartMethod, StartSpec, StopRule,
};

/// `--method` values, with their help.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MethodArg(pub Method);

impl clap::ValueEnum for MethodArg {
    fn value_variants<'a>() -> &'a [Self] {
        const ALL: [MethodArg; 15] = [
            MethodArg(Method::Asart),
            MethodArg(Method::Art),
            MethodArg(Method::Sart),
            MethodArg(Method::Mart),
            MethodArg(Method::Smart),
            MethodArg(Method::Mlem),
            MethodArg(Method::Tv),
            MethodArg(Method::Tikhonov),
            MethodArg(Method::Fluidnerf),
            MethodArg(Method::Fast),
            MethodArg(Method::Voxel),
            MethodArg(Method::Hybrid),
            MethodArg(Method::TrFluidnerf),
            MethodArg(Method::TrFast),
            MethodArg(Method::StaticPerFrame),
        ];
        &ALL
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        Some(PossibleValue::new(self.0.name()).help(self.0.summary()))
    }
}

/// `--stop` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum StopArg {
    /// Held-out early stopping when the scene has held-out views and the method is static,
    /// otherwise the method's own rule.
    Auto,
    /// The method's own convergence rule (residual plateau, smoothed-loss rule).
    Own,
    /// Only the iteration cap and the time budget.
    Budget,
    /// Keep the iterate with the lowest loss on the held-out views (no ground truth used).
    HeldOut,
}

impl From<StopArg> for StopRule {
    fn from(a: StopArg) -> Self {
        match a {
            StopArg::Auto => StopRule::Auto,
            StopArg::Own => StopRule::Own,
            StopArg::Budget => StopRule::Budget,
            StopArg::HeldOut => StopRule::HeldOut,
        }
    }
}

/// `--projector` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ProjectorArg {
    Auto,
    Footprint,
    Splat,
    Ray,
}

/// `--tv-step-rule` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TvStepRuleArg {
    Auto,
    Data,
    Balanced,
}

impl From<TvStepRuleArg> for fluidnerf_classical::TvStepRule {
    fn from(rule: TvStepRuleArg) -> Self {
        match rule {
            TvStepRuleArg::Auto => fluidnerf_classical::TvStepRule::Auto,
            TvStepRuleArg::Data => fluidnerf_classical::TvStepRule::Data,
            TvStepRuleArg::Balanced => fluidnerf_classical::TvStepRule::Balanced,
        }
    }
}

/// `--time-origin` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TimeOriginArg {
    Recording,
    Window,
}

/// Reconstruct a scalar field from a scene's images.
///
/// Writes into OUT: the volume (`volume.npy`, `volume.vti`; time-resolved runs one per frame
/// under `frames/` and `volumes.pvd`), the resolved settings (`config.json`: rerun with
/// `--config OUT/config.json`), `report.json` (iterations, why it stopped, loss or residual
/// history, held-out and NRMSE curves, time, memory, metrics against the truth when the scene
/// has one) and `report.html`. Neural methods also write their weights and checkpoints.
///
/// Every method stops by the same policy (`--stop`): its own convergence rule, the budget
/// alone, or held-out early stopping. Ctrl-C stops after the current iteration, writes the
/// results and exits with status 130.
#[derive(clap::Args, Debug)]
#[command(after_long_help = "Settings not given on the command line come from --config, else from the method's \
                             defaults (for neural methods, its --preset).")]
pub struct Args {
    /// The scene: a folder holding `transforms.json`, or the file itself [default with
    /// --config, or --resume: the scene the configuration names].
    #[arg(required_unless_present_any = ["config", "finish", "resume"])]
    pub scene: Option<PathBuf>,
    /// Output directory; created if missing. One that holds a run needs --force (or --resume).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Reconstruction method [default: the --config's, or with --resume the resumed run's;
    /// else hybrid, or tr-fast when the scene's frames hold several times]. `hybrid` was the
    /// most accurate method in every comparison measured (docs/claims.md); `fast` alone trains
    /// the field from a uniform start.
    #[arg(short, long, value_enum)]
    pub method: Option<MethodArg>,
    /// Voxels along the longest side of the reconstruction box for the output volume (and the
    /// working grid of voxel methods), 2 to 4096; cells are cubic [default: 128].
    #[arg(long)]
    pub resolution: Option<usize>,
    /// Seed for every random choice; the same seed gives the same result [default: 0].
    #[arg(long, allow_negative_numbers = true, value_parser = super::parse_seed)]
    pub seed: Option<u64>,
    /// Rerun from a `config.json` written by an earlier run; options given here override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Replace a run already in OUT. The earlier run is kept aside until the new one has passed
    /// its checks and written its configuration: a refused run leaves it as it was, and one
    /// killed before that leaves it in OUT/.replaced, put back by the next command that reads
    /// OUT or runs in it.
    #[arg(long, conflicts_with = "resume")]
    pub force: bool,
    /// Continue the neural or time-resolved run in OUT from its checkpoints, with the settings
    /// it was started with (OUT/config.json; options given here override them).
    #[arg(long)]
    pub resume: bool,
    /// Refuse runs whose estimated memory exceeds this many GiB [default: the memory
    /// available when the run starts].
    #[arg(long, value_name = "GIB")]
    pub memory_limit: Option<f64>,
    /// With ground truth: volume NRMSE every N iterations for the time-to-accuracy curve (0:
    /// only at the end; its time is not counted as training time) [default: every iteration
    /// for voxel methods; for neural ones, under --stop held-out where they evaluate the
    /// held-out loss (every 25 iterations), so that the curve shows every iterate the rule can
    /// keep, else every 100].
    #[arg(long)]
    pub eval_every: Option<usize>,
    /// Neural methods: a resumable checkpoint every N iterations (0: only at the end and on
    /// Ctrl-C) [default: 500].
    #[arg(long)]
    pub checkpoint_every: Option<usize>,
    #[command(flatten)]
    pub split: SplitArgs,
    #[command(flatten)]
    pub stop: StopArgs,
    #[command(flatten)]
    pub classical: ClassicalArgs,
    #[command(flatten)]
    pub neural: NeuralArgs,
    #[command(flatten)]
    pub temporal: TemporalArgs,
    #[command(flatten)]
    pub gains: GainArgs,
}

/// Per-camera intensity calibration (real recordings).
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Camera gains (every static method)")]
pub struct GainArgs {
    /// `auto`: when the training images' total intensities differ between cameras as differing
    /// gains make them (an image more than 15 % off its time's median, for its distance and
    /// lens), `fit`, or `balance` in time-resolved runs, which fit no gains; else `none`. `none`:
    /// images as they are; `balance`: every image scaled to the same total intensity as the
    /// others of its time; `fit`: balanced, then a gain per camera fitted with the field
    /// (neural) or between rounds of iterations (voxel methods), normalised to mean 1. The
    /// report records the mode taken. `none` or `balance` over a --config that fitted gains
    /// drops that fit's settings (offset, refits) too [default: auto].
    #[arg(long, value_name = "MODE", value_parser = ["auto", "none", "balance", "fit"])]
    pub gains: Option<String>,
    /// With --gains fit (or auto, where it fits): also fit an offset per camera (a background
    /// level left in the images); `--gain-offset false` turns off a configuration's offset.
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL")]
    pub gain_offset: Option<bool>,
    /// With --gains fit (or auto, where it fits): iterations between gain refits [default: 25
    /// neural, 5 voxel methods].
    #[arg(long, value_name = "N")]
    pub gain_every: Option<usize>,
    /// With --gains fit (or auto, where it fits), voxel methods: gain refits before the final
    /// solve [default: 4].
    #[arg(long, value_name = "N")]
    pub gain_rounds: Option<usize>,
}

/// Splitting a time-resolved run over processes (a Slurm job array, a Dask cluster).
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Splitting a time-resolved run (tr-fluidnerf, tr-fast, static-per-frame)")]
pub struct SplitArgs {
    /// Train only window K (0-based) of the run's window plan into OUT, and stop. A window
    /// already finished in OUT is left as it is; one that died continues from its checkpoint;
    /// with warm starts, window K starts from window K−1's final checkpoint, which must be
    /// in OUT. Finish the run with --finish once every window is done. (`--window` is the
    /// window length.)
    #[arg(long, value_name = "K", conflicts_with_all = ["force", "resume", "finish", "frames"])]
    pub window_index: Option<usize>,
    /// Train only the windows whose frames lie in A..B (frame indices, B exclusive; for
    /// static-per-frame one window per frame), in order, as --window-index does each.
    #[arg(long, value_name = "A..B", value_parser = parse_frames, conflicts_with_all = ["force", "resume", "finish"])]
    pub frames: Option<std::ops::Range<usize>>,
    /// Finish a run whose windows were trained with --window-index or --frames: stitch the
    /// windows and write the volumes and reports, as the run in one piece would. Without a
    /// scene or --config, the settings come from OUT/config.json. Refused, naming them, while
    /// windows are missing (--resume trains them here instead).
    #[arg(long, conflicts_with_all = ["force", "resume"])]
    pub finish: bool,
}

/// `A..B` as a frame range.
fn parse_frames(s: &str) -> Result<std::ops::Range<usize>, String> {
    let (a, b) = s.split_once("..").ok_or_else(|| format!("expected A..B (e.g. 0..8), got {s:?}"))?;
    let a: usize = a.trim().parse().map_err(|_| format!("{a:?} is not a frame index"))?;
    let b: usize = b.trim().parse().map_err(|_| format!("{b:?} is not a frame index"))?;
    if a >= b {
        return Err(format!("{s}: the range is empty (A must be less than B)"));
    }
    Ok(a..b)
}

/// A learning rate, refused as typed when it is out of (0, 1] or does not survive the
/// training's f32 (before, 1e300 read as infinity and 1e-50 as 0, and the refusal named those).
fn parse_learning_rate(s: &str) -> Result<f32, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("{s:?} is not a number"))?;
    let rule = "a learning rate must be positive and at most 1 (an Adam step moves each parameter by about the rate)";
    if !(v > 0.0 && v <= 1.0) {
        return Err(format!("{rule}, got {s}"));
    }
    let rate = v as f32;
    if !rate.is_normal() {
        return Err(format!("{rule}; {s} is below the smallest the training's f32 holds ({:e})", f32::MIN_POSITIVE));
    }
    Ok(rate)
}

/// A plateau tolerance, refused as typed unless it is 0 (no plateau rule) or a positive
/// fraction up to [`fluidnerf_classical::MAX_PLATEAU_TOLERANCE`]: a NaN or a negative one turned
/// the rule off as 0 does, without a word, and 1e300 stopped the run right after its window.
fn parse_plateau_tolerance(s: &str) -> Result<f64, String> {
    let max = fluidnerf_classical::MAX_PLATEAU_TOLERANCE;
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=max).contains(&v) => Ok(v),
        Ok(_) => Err(format!(
            "{s}: the tolerance is a positive fraction of the residual, at most {max} (e.g. 0.02), or 0 to run to \
             the iteration cap"
        )),
        Err(_) => Err(format!("{s:?} is not a number")),
    }
}

/// The stopping policy, one for every method.
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Stopping (every method)")]
pub struct StopArgs {
    /// What ends the run besides the caps: `own` (the method's convergence rule), `budget`
    /// (only --max-iterations and --time-budget), `held-out` (keep the iterate with the
    /// lowest loss on the scene's held-out views; needs held-out frames) or `auto` (`held-out`
    /// when the scene has held-out views and the method is static, else `own`; config.json
    /// records the rule decided). Over a --config, a rule given puts the settings of the rules
    /// it does not use (patience, held-out interval, plateau) back to their defaults
    /// [default: auto].
    #[arg(long, value_enum, value_name = "RULE")]
    pub stop: Option<StopArg>,
    /// Iteration cap (per window for time-resolved methods) [default: the method's own].
    #[arg(long)]
    pub max_iterations: Option<usize>,
    /// Stop after this many seconds of the method's own work (evaluations excluded). For a
    /// time-resolved method the budget is per window, not per run: each window trains for up
    /// to this long (a run of N windows up to N times as long; static-per-frame: per frame),
    /// and the voxel runs that start a window (--start-method, at most half of it) and the fit
    /// to them count against that window's. A static run continued with --resume trains only
    /// for what is left of its budget (the time its checkpoint trained is spent, so its
    /// config.json reruns it; a budget already spent is refused); a time-resolved window
    /// continued with --resume has its budget again for what is left of it.
    #[arg(long, value_name = "SECONDS")]
    pub time_budget: Option<f64>,
    /// Same as `--stop held-out`.
    #[arg(long, conflicts_with = "stop")]
    pub keep_best_holdout: bool,
    /// Held-out rule: iterations between evaluations [default: 1 for voxel methods, 25 for
    /// neural ones].
    #[arg(long, value_name = "N")]
    pub holdout_every: Option<usize>,
    /// Held-out rule: evaluations without improvement before stopping (0: never stop early)
    /// [default: 10].
    #[arg(long, value_name = "N")]
    pub patience: Option<usize>,
}

/// Options of the voxel methods.
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Voxel methods (asart, art, sart, mart, smart, mlem, tv, tikhonov)")]
pub struct ClassicalArgs {
    /// Relaxation factor μ, in (0, 2) for art/sart/asart/tv/tikhonov and (0, 1] for mart/smart
    /// [default: asart 0.5, the others 1].
    #[arg(long, value_name = "MU")]
    pub relaxation: Option<f64>,
    /// Projector: `auto` (the footprint projector unless voxels image wider than ~60 px, then
    /// `ray`), `footprint` (voxel-driven separable footprint), `splat` (voxel-driven bilinear
    /// splat, the dissertation's) or `ray` (ray-driven trilinear line integrals). Over a
    /// --config, the settings of a projector no longer used go back to their defaults
    /// [default: auto].
    #[arg(long, value_enum)]
    pub projector: Option<ProjectorArg>,
    /// Splat only: split each voxel into N³ sub-voxels so voxels imaging larger than a pixel
    /// leave no gaps; 1 is the dissertation's splat, 0 chooses N from the voxel's image size
    /// (⌈pixels / 1.5⌉) [default: 0].
    #[arg(long, value_name = "N")]
    pub splat_subdivisions: Option<usize>,
    /// Ray projector only: sampling step along each ray, in voxel sides [default: 0.5].
    #[arg(long, value_name = "VOXELS")]
    pub ray_step: Option<f64>,
    /// Hold voxels at zero whose centre projects onto a dark pixel in any view (visual hull).
    /// `--visual-hull false` turns off a configuration's hull, with its settings.
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL")]
    pub visual_hull: Option<bool>,
    /// Dark threshold of --visual-hull, as a fraction of each image's maximum [default: 0.02].
    /// A pixel also counts as dark up to the image's background plus --hull-noise-sigmas deviations
    /// of its noise, when that is higher.
    #[arg(long, value_name = "FRACTION")]
    pub hull_threshold: Option<f64>,
    /// Noise deviations above each image's background that still count as dark for --visual-hull,
    /// so that noisy images carve their background too; 0 leaves --hull-threshold alone
    /// [default: 4].
    #[arg(long, value_name = "SIGMAS")]
    pub hull_noise_sigmas: Option<f64>,
    /// Voxels by which --visual-hull's hull is dilated after carving, so that it keeps the
    /// object's faint rim [default: 1].
    #[arg(long, value_name = "VOXELS")]
    pub hull_dilation: Option<usize>,
    /// Method tv: size of each total-variation step relative to the SART step, at most 1 (0
    /// turns the steps off, leaving SART) [default: 0.2].
    #[arg(long, value_name = "WEIGHT")]
    pub tv_weight: Option<f64>,
    /// Method tv: total-variation descent steps per iteration, at most 1000 (0 leaves SART)
    /// [default: 20].
    #[arg(long, value_name = "N")]
    pub tv_steps: Option<usize>,
    /// Method tv: how each total-variation step's length follows the SART step's: `data`
    /// (tv-weight × the SART step, every iteration), `balanced` (that, shrunk by 0.95 after
    /// every iteration whose TV steps moved the volume more than the SART step did, as
    /// ASD-POCS does), or `auto`: balanced inside a visual hull, data without [default: auto].
    #[arg(long, value_name = "RULE")]
    pub tv_step_rule: Option<TvStepRuleArg>,
    /// Method tikhonov: weight λ of the smoothness penalty λ‖∇²g‖² (Eq. 2.35, Laplacian in
    /// voxel units). Larger is smoother; 0 is plain SART. It pays off with noisy images: on
    /// the demo jet (15 views, 64³ voxels) the default lowered SART's NRMSE from 0.381 to 0.326
    /// with 10 % noise and from 0.256 to 0.247 with 5 %, but raised it from 0.177 to 0.204
    /// without noise [default: 0.003].
    #[arg(long, value_name = "LAMBDA")]
    pub tikhonov_weight: Option<f64>,
    /// The `own` rule of voxel methods: stop when the residual (sliding mean of 4) varies by
    /// less than this fraction (at most 1) over 20 iterations; 0 runs to the cap. Refused for a
    /// run that stops by another rule (--stop), which would ignore it [default: 0.02].
    #[arg(long, value_name = "FRACTION", value_parser = parse_plateau_tolerance)]
    pub plateau_tolerance: Option<f64>,
}

/// Options of the neural methods.
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Neural methods (fluidnerf, fast, voxel, hybrid and the time-resolved ones)")]
pub struct NeuralArgs {
    /// Named configuration: faithful (Table 5.1: 8 × 256 MLP, L 8, ReLU, N_c = N_f = 128),
    /// ch7 (as faithful with N_c = N_f = 64), experimental (Table 8.3), fast (hash grid + tiny
    /// MLP + empty-space skipping), dense (voxel grid + skipping), voxel (dense with a
    /// total-variation prior); time-resolved: tr-faithful, tr-table-5.2, tr-experimental,
    /// tr-fast, tr-small, static-swish, static-small (the time-resolved methods take the static
    /// ones too). With --config it replaces the configured field, training and windows, and
    /// keeps the start, --holdout-times and --time-step [default: faithful for fluidnerf, fast
    /// for fast and hybrid, voxel for voxel, tr-faithful for tr-fluidnerf, tr-fast for tr-fast,
    /// static-swish for static-per-frame].
    #[arg(long)]
    pub preset: Option<String>,
    /// Random pixels per training image per iteration (N_pix/img) [default: the preset's].
    #[arg(long)]
    pub rays_per_image: Option<usize>,
    /// Stratified samples per ray (N_c) [default: the preset's].
    #[arg(long)]
    pub coarse_samples: Option<usize>,
    /// Hierarchical feature samples per ray (N_f; 0 disables) [default: the preset's].
    #[arg(long)]
    pub fine_samples: Option<usize>,
    /// Initial learning rate (the schedule keeps its decay ratio), in (0, 1] [default: the
    /// preset's].
    #[arg(long, value_parser = parse_learning_rate)]
    pub learning_rate: Option<f32>,
    /// Empty-space skipping: drop rays through dark pixels and never evaluate the field in
    /// space some camera sees dark (a visual hull carved from the images). Several times
    /// faster for the faithful MLP on jets and plumes, at the risk of cutting faint parts
    /// [default: the preset's: on for fast and dense, off for the dissertation's].
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL")]
    pub skip_empty: Option<bool>,
    /// Weight of the total-variation prior on the field: on the grid's cells for voxel grids
    /// (--method voxel, --preset dense), on 2048 random points per iteration with the step
    /// of a 128-cell grid for the other fields [default: voxel 0.0001, otherwise 0].
    #[arg(long, value_name = "WEIGHT")]
    pub tv_prior: Option<f32>,
    /// Weight of the smoothness prior |∇E|² on the field (as --tv-prior) [default: 0].
    #[arg(long, value_name = "WEIGHT")]
    pub smooth_prior: Option<f32>,
    /// Weight of the sparsity prior (the mean of E, an L1 norm: dark space stays dark; as
    /// --tv-prior) [default: 0].
    #[arg(long, value_name = "WEIGHT")]
    pub sparsity_prior: Option<f32>,
    /// Start the field from another run's reconstruction (a run folder of any static
    /// method on the same box, e.g. an ASART run of the same scene) instead of a uniform
    /// field: the field is first fitted to it on random points (300 Adam steps of 16384
    /// points, fewer if --time-budget runs out first; that time counts against it, the other
    /// run's does not), then
    /// trained on the images at a quarter of the learning rate. `--method hybrid` does this
    /// with a voxel run of its own (see --start-method). Static neural methods only.
    #[arg(long, value_name = "RUN")]
    pub start_from: Option<PathBuf>,
    /// Start from a voxel method (asart, art, sart, mart, smart, mlem, tv, tikhonov) run first
    /// on the same images: for a static field one run into OUT/start/ (what --method hybrid
    /// does), for a time-resolved one a run per instant into OUT/start/tNN/ for every window
    /// that does not continue the previous one. Its time counts against the time budget.
    /// `auto` (hybrid's default) runs asart when the training images are clean and tv when
    /// their estimated noise exceeds 1.5 % of their range: an unregularised start passes the
    /// noise on to the field.
    #[arg(long, value_name = "METHOD", value_parser = parse_start_method)]
    pub start_method: Option<StartMethod>,
    /// Adam steps of the field's fit to its start (--method hybrid, --start-from,
    /// --start-method; `method.start.fit.iterations`) [default: 300]: fewer for a quick look
    /// (the fit costs about as much per step at any grid size), more when the field should
    /// follow the start more closely before it trains on the images.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=fluidnerf_core::MAX_ITERATIONS as u64))]
    pub start_fit_steps: Option<u64>,
}

/// Options of the time-resolved methods.
#[derive(clap::Args, Debug)]
#[command(next_help_heading = "Time-resolved methods (tr-fluidnerf, tr-fast, static-per-frame)")]
pub struct TemporalArgs {
    /// Frames per sliding window (0: one field for all frames) [default: the preset's].
    #[arg(long)]
    pub window: Option<usize>,
    /// Frames shared by consecutive windows, cross-faded linearly in time [default: the
    /// preset's].
    #[arg(long)]
    pub overlap: Option<usize>,
    /// Train every window from scratch instead of from the previous window's weights;
    /// `--no-warm-start false` warm-starts a configuration's windows that did not [default: the
    /// preset's: tr-fluidnerf's windows are warm-started, tr-fast's are not].
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL")]
    pub no_warm_start: Option<bool>,
    /// Frame times whose images are NOT trained on (comma separated, the scene's time unit);
    /// volumes and metrics are still produced there. A time whose every frame the scene holds
    /// out (`"holdout": true`) is treated as one of them, with a warning; a time at which the
    /// scene has no frame holds no image out and only adds a volume there, with a warning.
    #[arg(long, value_delimiter = ',')]
    pub holdout_times: Option<Vec<f64>>,
    /// Frame spacing Δt of the networks' t' = (t − t₀)/Δt [default: the smallest gap between
    /// training times]. tr-fast does not use it: its grid reads time as the frame position in
    /// each window, one time vertex per frame however the frames are spaced.
    #[arg(long)]
    pub time_step: Option<f64>,
    /// Origin t₀ of each window's time: `window` (each window's first frame; the hash grid
    /// needs it) or `recording` (MLP only) [default: the preset's (window)].
    #[arg(long, value_enum)]
    pub time_origin: Option<TimeOriginArg>,
}

/// The options of one group that were given, by flag name.
fn given(flags: &[(&'static str, bool)]) -> Vec<&'static str> {
    flags.iter().filter(|(_, g)| *g).map(|(n, _)| *n).collect()
}

/// Refuses options that do not apply to the method.
fn check_applicable(args: &Args, method: Method) -> anyhow::Result<()> {
    let c = &args.classical;
    let n = &args.neural;
    let t = &args.temporal;
    let family = method.family();
    let mut wrong = Vec::new();
    if family != Family::Classical {
        wrong.extend(given(&[
            ("--relaxation", c.relaxation.is_some()),
            ("--projector", c.projector.is_some()),
            ("--splat-subdivisions", c.splat_subdivisions.is_some()),
            ("--ray-step", c.ray_step.is_some()),
            ("--visual-hull", c.visual_hull.is_some()),
            ("--hull-threshold", c.hull_threshold.is_some()),
            ("--hull-noise-sigmas", c.hull_noise_sigmas.is_some()),
            ("--hull-dilation", c.hull_dilation.is_some()),
            ("--plateau-tolerance", c.plateau_tolerance.is_some()),
        ]));
    }
    if method != Method::Tv {
        wrong.extend(given(&[
            ("--tv-weight", c.tv_weight.is_some()),
            ("--tv-steps", c.tv_steps.is_some()),
            ("--tv-step-rule", c.tv_step_rule.is_some()),
        ]));
    }
    if method != Method::Tikhonov {
        wrong.extend(given(&[("--tikhonov-weight", c.tikhonov_weight.is_some())]));
    }
    if method == Method::Mlem {
        wrong.extend(given(&[("--relaxation", c.relaxation.is_some())]));
    }
    if family == Family::Classical {
        wrong.extend(given(&[
            ("--preset", n.preset.is_some()),
            ("--rays-per-image", n.rays_per_image.is_some()),
            ("--coarse-samples", n.coarse_samples.is_some()),
            ("--fine-samples", n.fine_samples.is_some()),
            ("--learning-rate", n.learning_rate.is_some()),
            ("--skip-empty", n.skip_empty.is_some()),
            ("--tv-prior", n.tv_prior.is_some()),
            ("--smooth-prior", n.smooth_prior.is_some()),
            ("--sparsity-prior", n.sparsity_prior.is_some()),
            ("--checkpoint-every", args.checkpoint_every.is_some()),
            ("--resume", args.resume),
        ]));
    }
    if family != Family::Neural {
        wrong.extend(given(&[("--start-from", n.start_from.is_some())]));
    }
    // Neural methods refit their gains as they train, in no rounds.
    if family != Family::Classical {
        wrong.extend(given(&[("--gain-rounds", args.gains.gain_rounds.is_some())]));
    }
    if family == Family::Classical {
        wrong.extend(given(&[
            ("--start-method", n.start_method.is_some()),
            ("--start-fit-steps", n.start_fit_steps.is_some()),
        ]));
    }
    if family != Family::Temporal {
        wrong.extend(given(&[
            ("--window", t.window.is_some()),
            ("--overlap", t.overlap.is_some()),
            ("--no-warm-start", t.no_warm_start.is_some()),
            ("--holdout-times", t.holdout_times.is_some()),
            ("--time-step", t.time_step.is_some()),
            ("--time-origin", t.time_origin.is_some()),
        ]));
    }
    if family != Family::Temporal {
        let sp = &args.split;
        wrong.extend(given(&[
            ("--window-index", sp.window_index.is_some()),
            ("--frames", sp.frames.is_some()),
            ("--finish", sp.finish),
        ]));
    }
    if method == Method::StaticPerFrame {
        // A static field per frame reads no time.
        wrong.extend(given(&[
            ("--window", t.window.is_some()),
            ("--overlap", t.overlap.is_some()),
            ("--time-step", t.time_step.is_some()),
            ("--time-origin", t.time_origin.is_some()),
        ]));
    }
    wrong.dedup();
    if !wrong.is_empty() {
        let verb = if wrong.len() == 1 { "does" } else { "do" };
        bail!("{} {verb} not apply to --method {method}", wrong.join(", "));
    }
    Ok(())
}

/// The method of a run given neither `--method` nor a configuration: `hybrid` for a scene of
/// one instant (the most accurate method in every comparison measured, docs/claims.md), and
/// `tr-fast` for a scene whose frames hold several times, which a static method would mix into
/// one field.
fn default_method(scene: &std::path::Path) -> anyhow::Result<Method> {
    // Only the frames' times are needed here; the run checks the whole scene.
    let draft = fluidnerf_io::scene::read_scene_draft(scene)?;
    let instants = fluidnerf_core::scene::frame_times(&draft.frames).len();
    Ok(if instants > 1 { Method::TrFast } else { Method::Hybrid })
}

/// Refuses to continue the run in `out`, made from the scene `saved`, on another scene
/// (`given`): its field was trained on the other's box and images. A saved scene that no
/// longer exists (moved) is taken to be the one given.
fn same_scene(given: &std::path::Path, saved: &std::path::Path, out: &std::path::Path) -> anyhow::Result<()> {
    match (super::scene_folder(given), super::scene_folder(saved)) {
        (Some(a), Some(b)) if a != b => bail!(
            "{} holds a run of the scene {}, not {}; leave out the scene to continue it, or use --force to start a \
             new run there",
            out.display(),
            saved.display(),
            given.display()
        ),
        (Some(_), None) => {
            log::warn!("the run's scene {} is gone; continuing on {}", saved.display(), given.display());
            Ok(())
        }
        _ => Ok(()),
    }
}

/// The run's configuration: `--config` (or the method's defaults), then every option given.
pub fn resolve(args: &Args) -> anyhow::Result<RunConfig> {
    // A resumed or finished run continues with the settings it was started with (options
    // given here still override them), not with the defaults of some method.
    let continued = match &args.config {
        None if args.resume || args.split.finish => {
            // A run a killed --force left aside is the run to continue: put back first.
            if args.out.is_dir() {
                fluidnerf_pipeline::rundir::RunDir::recover_replaced(&args.out);
            }
            let path = args.out.join("config.json");
            if !path.is_file() {
                bail!(
                    "{}: {} holds no run to continue (no config.json)",
                    if args.resume { "--resume" } else { "--finish" },
                    args.out.display()
                );
            }
            Some(path)
        }
        _ => None,
    };
    let resume_config = continued.as_ref().filter(|_| args.resume);
    let mut cfg = match args.config.as_ref().or(continued.as_ref()) {
        Some(path) => {
            let cfg = RunConfig::read(path)?;
            if let Some(MethodArg(m)) = args.method {
                if m != cfg.method() {
                    if resume_config.is_some() {
                        bail!(
                            "{} holds a --method {} run, which --resume continues with its own settings; leave out \
                             --method {m} (or use --force to replace it with a new run)",
                            args.out.display(),
                            cfg.method()
                        );
                    }
                    bail!(
                        "{} was written for --method {}; to run --method {m}, leave out --config",
                        path.display(),
                        cfg.method()
                    );
                }
            }
            cfg
        }
        None => {
            let scene = args.scene.clone().context("a scene (or --config) is needed")?;
            let method = match args.method {
                Some(MethodArg(m)) => m,
                None => default_method(&scene)?,
            };
            RunConfig::new(scene, method)
        }
    };
    let method = cfg.method();
    check_applicable(args, method)?;
    if let Some(scene) = &args.scene {
        if continued.is_some() {
            same_scene(scene, &cfg.scene, &args.out)?;
        }
        cfg.scene = scene.clone();
    } else if let Some(file) = args.config.as_ref().or(continued.as_ref()) {
        if !cfg.scene.exists() {
            bail!(
                "{}: its `scene`, {}, does not exist{}; give the scene on the command line",
                file.display(),
                cfg.scene.display(),
                if cfg.scene.is_relative() { " (a relative path is read from the working directory)" } else { "" }
            );
        }
        fluidnerf_io::scene::check_scene_path(&cfg.scene)
            .with_context(|| format!("{}: its `scene`", file.display()))?;
    }
    // Recorded absolute, so the config reruns from any working directory.
    if let Ok(abs) = std::path::absolute(&cfg.scene) {
        cfg.scene = abs;
    }
    if cfg.scene.to_str().is_none() {
        bail!(
            "the scene path {} is not valid UTF-8, so config.json (JSON text) cannot record it for reruns; rename \
             the folder",
            cfg.scene.display()
        );
    }
    cfg.fluidnerf_version = env!("CARGO_PKG_VERSION").to_string();
    if let Some(p) = &args.neural.preset {
        cfg.method = cfg.method.with_preset_kept(p)?;
    }
    if let Some(v) = args.seed {
        cfg.seed = v;
    }
    if let Some(v) = args.resolution {
        cfg.resolution = v;
    }
    if let Some(v) = args.memory_limit {
        cfg.memory_limit_gib = Some(v);
    }
    if let Some(v) = args.eval_every {
        cfg.eval_every = Some(v);
    }
    if let Some(v) = args.checkpoint_every {
        cfg.checkpoint_every = v;
    }
    let s = &args.stop;
    let rule = if s.keep_best_holdout { Some(StopRule::HeldOut) } else { s.stop.map(StopRule::from) };
    if let Some(rule) = rule {
        // The settings of a rule the run no longer stops by go with it, as the gain fit's go
        // with --gains: a configuration's patience or plateau tolerance was recorded and
        // ignored, where the same options on one command line are refused.
        if rule != cfg.stopping.rule {
            drop_idle_stop_settings(&mut cfg, rule);
        }
        cfg.stopping.rule = rule;
    }
    if let Some(v) = s.max_iterations {
        cfg.stopping.max_iterations = Some(v);
    }
    if let Some(v) = s.time_budget {
        cfg.stopping.time_budget_s = Some(v);
    }
    if let Some(v) = s.holdout_every {
        cfg.stopping.holdout_every = Some(v);
    }
    if let Some(v) = s.patience {
        cfg.stopping.patience = v;
    }
    let g = &args.gains;
    if let Some(mode) = &g.gains {
        cfg.gains.mode = mode.parse().map_err(anyhow::Error::msg)?;
        // The fit's own settings go with a mode that fits: one given here that fits no gains
        // replaces them too, or a configuration's offset or refit interval would refuse it.
        if !cfg.gains.may_fit() {
            cfg.gains = fluidnerf_pipeline::GainConfig { mode: cfg.gains.mode, ..Default::default() };
        }
    }
    if let Some(v) = g.gain_offset {
        cfg.gains.offset = v;
    }
    if let Some(v) = g.gain_every {
        cfg.gains.every = Some(v);
    }
    if let Some(v) = g.gain_rounds {
        cfg.gains.rounds = v;
    }
    apply_method_options(args, &mut cfg.method)?;
    // A window option the run would not take as given is named by its option.
    fluidnerf_pipeline::check_given_windows(&cfg, None, &given_windows(args)).map_err(|e| {
        let flag = match &e {
            fluidnerf_pipeline::PipelineError::Invalid { key, .. } => flag_of(args, key),
            _ => None,
        };
        match flag {
            Some(flag) => anyhow::Error::new(e).context(format!("{flag} on the command line")),
            None => e.into(),
        }
    })?;
    // The rounds, the refit interval and the offset belong to fitted gains; with others they
    // would be ignored.
    let fit_only = given(&[
        ("--gain-every", g.gain_every.is_some()),
        ("--gain-rounds", g.gain_rounds.is_some()),
        ("--gain-offset", g.gain_offset == Some(true)),
    ]);
    if !fit_only.is_empty() && !cfg.gains.may_fit() {
        let (verb, them) = if fit_only.len() == 1 { ("applies", "it") } else { ("apply", "them") };
        bail!(
            "{} {verb} only to fitted gains, but the gains are `{}`; give --gains fit (or auto), or leave {them} out",
            fit_only.join(", "),
            cfg.gains.mode
        );
    }
    stop_options_apply(args, &cfg)?;
    if args.eval_every.is_some() && fluidnerf_io::scene::read_scene_draft(&cfg.scene)?.truth.is_empty() {
        // The run would record the interval and evaluate nothing.
        bail!(
            "--eval-every evaluates the volume NRMSE against the scene's ground truth, and the scene {} has none; \
             leave it out (held-out views are scored by --stop held-out)",
            cfg.scene.display()
        );
    }
    // Before the configuration's own check, which refuses the same settings set in a file
    // by their keys: an option is named as an option. After the projector's ranges: a value
    // out of range is named as such, whether used or not.
    if let MethodConfig::Classical(spec) = &cfg.method {
        if spec.projector.validate_ranges().is_ok() {
            refuse_idle_projector_options(args, &spec.projector)?;
        }
    }
    if let Err(e) = cfg.validate() {
        // A value from the command line is named by its option, one from a file by the file.
        let flag = match &e {
            fluidnerf_pipeline::PipelineError::Invalid { key, .. } => flag_of(args, key),
            _ => None,
        };
        return Err(match (flag, args.config.as_ref().or(continued.as_ref())) {
            (Some(flag), _) => anyhow::Error::new(e).context(format!("{flag} on the command line")),
            (None, Some(file)) => anyhow::Error::new(e).context(format!("the settings of {}", file.display())),
            (None, None) => e.into(),
        });
    }
    // Its checkpoint holds the saved field's parameters: another field cannot take them.
    if let Some(saved) = resume_config {
        let field = |m: &MethodConfig| match m {
            MethodConfig::Neural(_, s) => Some(s.field.clone()),
            MethodConfig::Temporal(_, t) => Some(t.field.clone()),
            MethodConfig::Classical(_) => None,
        };
        if field(&cfg.method) != field(&RunConfig::read(saved)?.method) {
            bail!(
                "the options given change the field of the run in {} (its architecture or its grid), so its \
                 checkpoint cannot continue it; leave them out to resume, or use --force to start a new run",
                args.out.display()
            );
        }
    }
    Ok(cfg)
}

/// Puts back to their defaults the settings in `cfg` of the stopping rules that `rule`, given on
/// the command line, does not use: held-out early stopping's interval and patience for a run
/// that stops by its own rule or its budget, and a voxel method's plateau for one that stops
/// by its budget or its held-out views. `auto`, decided as the run starts, keeps them all.
fn drop_idle_stop_settings(cfg: &mut RunConfig, rule: StopRule) {
    if matches!(rule, StopRule::Own | StopRule::Budget) {
        let defaults = fluidnerf_pipeline::StoppingPolicy::default();
        cfg.stopping.holdout_every = defaults.holdout_every;
        cfg.stopping.patience = defaults.patience;
    }
    if let (StopRule::HeldOut | StopRule::Budget, MethodConfig::Classical(spec)) = (rule, &mut cfg.method) {
        let own = fluidnerf_classical::ClassicalMethod::default_for(spec.method.algorithm());
        spec.method.stopping_mut().plateau = own.stopping().plateau;
    }
}

/// Refuses the options of a stopping rule the run will not stop by, which it would record and
/// ignore: --holdout-every and --patience (held-out early stopping) for a run that stops by its
/// own rule or its budget, a time-resolved one, or one whose rule `auto` finds no held-out view
/// in the scene; --plateau-tolerance (the voxel methods' own rule) for one that stops by its
/// budget or by held-out views, `auto` included where the scene holds views out. `auto` is
/// decided as the run decides it ([`RunConfig::resolved`]).
fn stop_options_apply(args: &Args, cfg: &RunConfig) -> anyhow::Result<()> {
    let s = &args.stop;
    let held_out = given(&[("--holdout-every", s.holdout_every.is_some()), ("--patience", s.patience.is_some())]);
    let own = given(&[("--plateau-tolerance", args.classical.plateau_tolerance.is_some())]);
    if held_out.is_empty() && own.is_empty() {
        return Ok(());
    }
    let temporal = cfg.method().family() == Family::Temporal;
    let (rule, why) = match cfg.stopping.rule {
        StopRule::Own => (StopRule::Own, "the run stops by the method's own rule (--stop own)".to_string()),
        StopRule::Budget => (StopRule::Budget, "the run stops by its budget alone (--stop budget)".to_string()),
        StopRule::HeldOut => (
            StopRule::HeldOut,
            "the run keeps the iterate best on the held-out views (--stop held-out), which replaces the method's \
             own rule"
                .to_string(),
        ),
        StopRule::Auto if temporal => {
            (StopRule::Own, "a time-resolved run holds out whole times, and does not stop early on them".to_string())
        }
        StopRule::Auto => {
            let scene = cfg.scene.display();
            if fluidnerf_io::scene::read_scene_draft(&cfg.scene)?.frames.iter().any(|f| f.holdout) {
                let why = format!(
                    "the scene {scene} holds out views, so --stop auto keeps the iterate best on them, which \
                     replaces the method's own rule"
                );
                (StopRule::HeldOut, why)
            } else {
                let why =
                    format!("the scene {scene} holds out no views, so --stop auto stops by the method's own rule");
                (StopRule::Own, why)
            }
        }
    };
    if !held_out.is_empty() && rule != StopRule::HeldOut {
        let (verb, them) = verb_them(&held_out);
        bail!(
            "{} {verb} held-out early stopping, which this run does not use: {why}; use --stop held-out on a scene \
             with held-out views, or leave {them} out",
            held_out.join(", ")
        );
    }
    if !own.is_empty() && rule != StopRule::Own {
        let (verb, them) = verb_them(&own);
        bail!(
            "{} {verb} the method's own stopping rule, which this run does not use: {why}; use --stop own, or leave \
             {them} out",
            own.join(", ")
        );
    }
    Ok(())
}

/// The verb and pronoun for a list of options: "sets … it" for one, "set … them" for several.
fn verb_them(options: &[&str]) -> (&'static str, &'static str) {
    if options.len() == 1 {
        ("sets", "it")
    } else {
        ("set", "them")
    }
}

/// Refuses a projector's option given for a run that uses another projector (`--ray-step`
/// beside the footprint or splat projector, `--splat-subdivisions` beside any but the splat),
/// and the hull's options for a run without the visual hull: each would be ignored. The
/// projector and the hull are the run's, from --config or the options.
fn refuse_idle_projector_options(args: &Args, projector: &fluidnerf_classical::ProjectorConfig) -> anyhow::Result<()> {
    let c = &args.classical;
    let kind = match projector.kind {
        ProjectorKind::Auto => "auto",
        ProjectorKind::Footprint => "footprint",
        ProjectorKind::Splat => "splat",
        ProjectorKind::Ray => "ray",
    };
    // `auto` chooses the ray projector where voxels image wide, never the splat.
    if c.ray_step.is_some() && !matches!(projector.kind, ProjectorKind::Ray | ProjectorKind::Auto) {
        bail!(
            "--ray-step sets the ray projector's step, but this run uses the {kind} projector, which casts no rays: \
             it would be ignored; use --projector ray (or auto), or leave it out"
        );
    }
    if c.splat_subdivisions.is_some() && projector.kind != ProjectorKind::Splat {
        bail!(
            "--splat-subdivisions sets the splat projector's sub-voxels, but this run uses the {kind} projector: it \
             would be ignored; use --projector splat, or leave it out"
        );
    }
    if !projector.visual_hull {
        let hull = given(&[
            ("--hull-threshold", c.hull_threshold.is_some()),
            ("--hull-noise-sigmas", c.hull_noise_sigmas.is_some()),
            ("--hull-dilation", c.hull_dilation.is_some()),
        ]);
        if !hull.is_empty() {
            let (verb, them) = if hull.len() == 1 { ("sets", "it") } else { ("set", "them") };
            bail!(
                "{} {verb} the visual hull, which this run does not use: add --visual-hull, or leave {them} out",
                hull.join(", ")
            );
        }
    }
    Ok(())
}

fn apply_method_options(args: &Args, method: &mut MethodConfig) -> anyhow::Result<()> {
    let c = &args.classical;
    if let MethodConfig::Classical(spec) = method {
        let defaults = fluidnerf_classical::ProjectorConfig::default();
        if let Some(p) = c.projector {
            spec.projector.kind = match p {
                ProjectorArg::Auto => ProjectorKind::Auto,
                ProjectorArg::Footprint => ProjectorKind::Footprint,
                ProjectorArg::Splat => ProjectorKind::Splat,
                ProjectorArg::Ray => ProjectorKind::Ray,
            };
            // The settings of a projector the run no longer uses go with it: a configuration's
            // sub-voxels refused the switch away from the splat.
            if spec.projector.kind != ProjectorKind::Splat {
                spec.projector.splat_subdivisions = defaults.splat_subdivisions;
            }
            if !matches!(spec.projector.kind, ProjectorKind::Ray | ProjectorKind::Auto) {
                spec.projector.ray_step = defaults.ray_step;
            }
        }
        if let Some(n) = c.splat_subdivisions {
            spec.projector.splat_subdivisions = n;
        }
        if let Some(s) = c.ray_step {
            spec.projector.ray_step = s;
        }
        if let Some(v) = c.visual_hull {
            spec.projector.visual_hull = v;
            // `--visual-hull false` turns a configuration's hull off with its settings, which
            // refused it before.
            if !v {
                spec.projector.hull_threshold = defaults.hull_threshold;
                spec.projector.hull_noise_sigmas = defaults.hull_noise_sigmas;
                spec.projector.hull_dilation = defaults.hull_dilation;
            }
        }
        if let Some(t) = c.hull_threshold {
            spec.projector.hull_threshold = t;
        }
        if let Some(k) = c.hull_noise_sigmas {
            spec.projector.hull_noise_sigmas = k;
        }
        if let Some(d) = c.hull_dilation {
            spec.projector.hull_dilation = d;
        }
        if let Some(mu) = c.relaxation {
            if let Some(r) = spec.method.relaxation_mut() {
                *r = mu;
            }
        }
        if let Some(tol) = c.plateau_tolerance {
            spec.method.stopping_mut().plateau =
                if tol > 0.0 { Some(Plateau { tolerance: tol, ..Plateau::default() }) } else { None };
        }
        match &mut spec.method {
            fluidnerf_classical::ClassicalMethod::Tv(p) => {
                if let Some(w) = c.tv_weight {
                    p.tv_weight = w;
                }
                if let Some(n) = c.tv_steps {
                    p.tv_steps = n;
                }
                if let Some(rule) = c.tv_step_rule {
                    p.step_rule = rule.into();
                }
            }
            fluidnerf_classical::ClassicalMethod::Tikhonov(p) => {
                if let Some(w) = c.tikhonov_weight {
                    p.weight = w;
                }
            }
            _ => {}
        }
    }
    let n = &args.neural;
    if let Some(train) = method.train_mut() {
        if let Some(v) = n.rays_per_image {
            train.rays_per_image = v;
        }
        if let Some(v) = n.coarse_samples {
            train.coarse_samples = v;
        }
        if let Some(v) = n.fine_samples {
            train.fine_samples = v;
        }
        if let Some(lr) = n.learning_rate {
            let ratio = train.schedule.at_decay_iters / train.schedule.initial;
            train.schedule.initial = lr;
            train.schedule.at_decay_iters = lr * ratio;
        }
        match n.skip_empty {
            Some(true) if train.occupancy.is_none() => train.occupancy = Some(OccupancyConfig::default()),
            Some(false) => train.occupancy = None,
            _ => {}
        }
        if let Some(w) = n.tv_prior {
            train.prior.tv = w;
        }
        if let Some(w) = n.smooth_prior {
            train.prior.smooth = w;
        }
        if let Some(w) = n.sparsity_prior {
            train.prior.sparsity = w;
        }
    }
    if let (MethodConfig::Neural(_, spec), Some(run)) = (&mut *method, &n.start_from) {
        let start = spec.start.get_or_insert_with(StartSpec::default);
        start.run = Some(run.clone());
        // The run given is the start: a configuration's voxel method to run first goes with it.
        start.method = fluidnerf_pipeline::StartMethod::Auto;
    }
    if n.start_from.is_some() && n.start_method.is_some() {
        bail!("--start-from and --start-method: give one (a run to start from, or a voxel method to run first)");
    }
    if let Some(m) = n.start_method {
        let start = match method {
            MethodConfig::Neural(_, spec) => spec.start.get_or_insert_with(StartSpec::default),
            MethodConfig::Temporal(_, spec) => spec.start.get_or_insert_with(StartSpec::default),
            MethodConfig::Classical(_) => unreachable!("refused above"),
        };
        start.method = m;
    }
    if let Some(steps) = n.start_fit_steps {
        let start = match method {
            MethodConfig::Neural(_, spec) => spec.start.as_mut(),
            MethodConfig::Temporal(_, spec) => spec.start.as_mut(),
            MethodConfig::Classical(_) => unreachable!("refused above"),
        };
        let Some(start) = start else {
            bail!(
                "--start-fit-steps: the run has no start to fit the field to (give --start-from or --start-method, \
                 or use --method hybrid)"
            );
        };
        start.fit.iterations = steps as usize;
    }
    let t = &args.temporal;
    if let MethodConfig::Temporal(_, spec) = method {
        if let Some(w) = t.window {
            spec.windows.frames = w;
        }
        if let Some(o) = t.overlap {
            spec.windows.overlap = o;
        }
        if let Some(v) = t.no_warm_start {
            spec.windows.warm_start = !v;
        }
        if let Some(h) = &t.holdout_times {
            spec.holdout_times = h.clone();
        }
        if let Some(dt) = t.time_step {
            spec.time_step = Some(dt);
        }
        if let Some(o) = t.time_origin {
            spec.windows.time_origin = match o {
                TimeOriginArg::Recording => TimeOrigin::Recording,
                TimeOriginArg::Window => TimeOrigin::Window,
            };
        }
    }
    Ok(())
}

/// Draws a run's events: one progress bar, with the loss, the latest evaluation and the rate.
pub struct ProgressView {
    bar: Option<indicatif::ProgressBar>,
    /// Shown from the end of training until the run has written its files (sampling a
    /// faithful network's volume takes a while).
    writing: Option<indicatif::ProgressBar>,
    /// When the run's time budget ends, once its estimate has said so.
    deadline: crate::progress::Deadline,
    per_window: u64,
    rate: (Instant, u64, f64),
    evaluation: String,
    /// The bar shows the fit of a field to its start ([`RunEvent::StartFit`]).
    fitting: bool,
}

impl Default for ProgressView {
    fn default() -> Self {
        ProgressView {
            bar: None,
            writing: None,
            deadline: crate::progress::Deadline::default(),
            per_window: 0,
            rate: (Instant::now(), 0, 0.0),
            evaluation: String::new(),
            fitting: false,
        }
    }
}

impl ProgressView {
    /// Handles one event; breaks when the user pressed Ctrl-C.
    pub fn on_event(&mut self, event: &RunEvent) -> ControlFlow<()> {
        match event {
            RunEvent::Started { method, max_iterations, windows, start_iteration } => {
                if std::mem::take(&mut self.fitting) {
                    if let Some(bar) = self.bar.take() {
                        bar.finish_and_clear();
                    }
                }
                self.per_window = *max_iterations as u64;
                // A hybrid's voxel start reports its own run first, with its own budget.
                self.deadline = crate::progress::Deadline::default();
                if let Some(spinner) = self.writing.take() {
                    spinner.finish_and_clear();
                }
                let bar = crate::progress::bar_until(self.per_window * *windows as u64, method.name(), &self.deadline);
                bar.set_position(*start_iteration as u64);
                // A resumed run's jump to its iteration is not a rate.
                bar.reset_eta();
                self.rate = (Instant::now(), *start_iteration as u64, 0.0);
                self.bar = Some(bar);
            }
            RunEvent::StartFit { step, steps } => {
                // Between the voxel start's bar and the field's: the fit's own.
                if !self.fitting {
                    if let Some(bar) = self.bar.take() {
                        bar.finish_and_clear();
                    }
                    if let Some(spinner) = self.writing.take() {
                        spinner.finish_and_clear();
                    }
                    self.bar = Some(crate::progress::bar_until(*steps as u64, "fit to start", &self.deadline));
                    self.fitting = true;
                }
                if let Some(bar) = &self.bar {
                    bar.set_position(*step as u64);
                }
            }
            RunEvent::Iteration { window, iteration, loss, smoothed, .. } => {
                if let Some(bar) = &self.bar {
                    let pos = window.map_or(0, |w| w.index as u64 * self.per_window) + *iteration as u64;
                    bar.set_position(pos);
                    let elapsed = self.rate.0.elapsed().as_secs_f64();
                    if elapsed > 1.0 {
                        self.rate = (Instant::now(), pos, pos.saturating_sub(self.rate.1) as f64 / elapsed);
                    }
                    let what = match smoothed {
                        Some(s) => format!("loss {loss:.3e} (avg {s:.3e})"),
                        None => format!("residual {loss:.4}"),
                    };
                    let win = window.map(|w| format!("window {}/{} ", w.index + 1, w.count)).unwrap_or_default();
                    bar.set_message(format!("{win}{what}{} {:.1} it/s", self.evaluation, self.rate.2));
                }
            }
            RunEvent::Evaluation { nrmse, holdout, .. } => {
                let mut s = String::new();
                if let Some(h) = holdout {
                    s += &format!(", held-out {h:.3e}");
                }
                if let Some(n) = nrmse {
                    s += &format!(", NRMSE {n:.4}");
                }
                self.evaluation = s;
            }
            RunEvent::Estimate { seconds_left, budget_limited, .. } => {
                if *budget_limited {
                    self.deadline.set(Instant::now() + std::time::Duration::from_secs_f64(seconds_left.max(0.0)));
                }
                if let Some(text) = event.describe_estimate() {
                    let long = *seconds_left > 1800.0;
                    let show = || {
                        if long {
                            log::warn!(
                                "{text}; stop it with Ctrl-C (the results so far are written), or set \
                                 --time-budget, or choose a faster method (--method fast)"
                            );
                        }
                    };
                    match &self.bar {
                        Some(bar) if !bar.is_hidden() => {
                            bar.suspend(show);
                            bar.println(format!("estimate: {text}"));
                        }
                        _ if long => show(),
                        _ => log::info!("estimate: {text}"),
                    }
                }
            }
            RunEvent::Checkpoint { path } => log::debug!("wrote {}", path.display()),
            RunEvent::WindowFinished(w) => log::info!("window {}/{} finished", w.index + 1, w.count),
            RunEvent::Warning(message) => {
                let show = || log::warn!("{message}");
                match &self.bar {
                    Some(bar) => bar.suspend(show),
                    None => show(),
                }
            }
            RunEvent::Writing => {
                if let Some(bar) = self.bar.take() {
                    bar.finish_and_clear();
                }
                if let Some(old) =
                    self.writing.replace(crate::progress::spinner("writing", "volumes, metrics, reports"))
                {
                    old.finish_and_clear();
                }
            }
        }
        if crate::interrupt::requested() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    }
}

impl Drop for ProgressView {
    fn drop(&mut self) {
        for bar in [self.bar.take(), self.writing.take()].into_iter().flatten() {
            bar.finish_and_clear();
        }
    }
}

/// Runs `config` into `out` with a progress bar; returns the report.
pub fn run_config(
    config: &RunConfig,
    out: &std::path::Path,
    overwrite: Overwrite,
) -> anyhow::Result<fluidnerf_pipeline::RunReport> {
    crate::interrupt::install();
    let scene = fluidnerf_io::scene::load_scene(&config.scene)?;
    fluidnerf_pipeline::rundir::check_start_outside(config, out, overwrite)?;
    let dir = RunDir::create(out, overwrite, Some(&scene.root))?;
    let mut view = ProgressView::default();
    let report = fluidnerf_pipeline::reconstruct(&scene, config, &dir, |e| view.on_event(e))?;
    Ok(report)
}

/// The window options given on the command line, for [`fluidnerf_pipeline::check_given_windows`].
fn given_windows(args: &Args) -> fluidnerf_pipeline::GivenWindows<'static> {
    fluidnerf_pipeline::GivenWindows {
        frames: args.temporal.window,
        overlap: args.temporal.overlap,
        frames_name: "--window",
        overlap_name: "--overlap",
        overlap_from: if args.config.is_some() || args.resume { "the configuration's" } else { "the preset's" },
    }
}

/// Refuses an `--overlap` given for windows that hold every training frame of the scene in one
/// (`--window` at least the frame count), as it is refused with `--window 0`: there are no
/// windows to overlap, and the option would be recorded and ignored.
fn refuse_moot_overlap(args: &Args, config: &RunConfig) -> anyhow::Result<()> {
    if args.temporal.overlap.is_none_or(|o| o == 0) || !matches!(config.method, MethodConfig::Temporal(..)) {
        return Ok(());
    }
    let scene = fluidnerf_io::scene::load_scene(&config.scene)?;
    Ok(fluidnerf_pipeline::check_given_windows(config, Some(&scene), &given_windows(args))?)
}

pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let config = resolve(&args)?;
    refuse_moot_overlap(&args, &config)?;
    if args.split.window_index.is_some() || args.split.frames.is_some() || args.split.finish {
        return run_split(&args, &config);
    }
    let overwrite = match (args.force, args.resume) {
        (true, _) => Overwrite::Force,
        (_, true) => Overwrite::Resume,
        _ => Overwrite::Refuse,
    };
    let report = run_config(&config, &args.out, overwrite).map_err(|e| {
        // The start run is checked with the scene, as the run begins: named by its option too.
        let key = e.downcast_ref::<fluidnerf_pipeline::PipelineError>().and_then(|p| match p {
            fluidnerf_pipeline::PipelineError::Invalid { key, .. } => Some(key.as_str()),
            _ => None,
        });
        match (key, &args.neural.start_from) {
            (Some("method.start.run"), Some(_)) => e.context("--start-from on the command line"),
            _ => e,
        }
    })?;
    #[allow(clippy::print_stdout)]
    {
        println!("{}", report.summary_line());
        if let Some(p) = &report.preprocessing {
            for line in p.summary_lines() {
                println!("{line}");
            }
        }
        println!("wrote {} ({})", args.out.display(), run_outputs(&args.out));
    }
    Ok(match report.status {
        RunStatus::Finished => std::process::ExitCode::SUCCESS,
        RunStatus::Interrupted => std::process::ExitCode::from(130),
    })
}

/// The files a run wrote in its folder `out`, in words: its settings and report, and what it
/// made (its volume, a field's weights and checkpoint, a time-resolved run's frames, their
/// ParaView collection and its windows); it named the settings and reports alone.
fn run_outputs(out: &Path) -> String {
    let listed: Vec<String> = fluidnerf_pipeline::rundir::run_outputs()
        .filter_map(|name| {
            let path = out.join(name);
            if path.is_file() {
                return Some(name.to_string());
            }
            // A folder: a time-resolved run's frames, counted, and its windows.
            let entries = std::fs::read_dir(&path).ok()?.filter_map(|e| e.ok());
            if name != "frames" {
                return Some(format!("{name}/"));
            }
            let frames = entries.filter(|e| e.path().extension().is_some_and(|x| x == "npy")).count();
            (frames > 0).then(|| format!("frames/ ({frames} volumes, .npy and .vti)"))
        })
        .collect();
    listed.join(", ")
}

/// `--window-index`, `--frames` and `--finish`: part of a time-resolved run, or its end.
fn run_split(args: &Args, config: &RunConfig) -> anyhow::Result<std::process::ExitCode> {
    crate::interrupt::install();
    let scene = fluidnerf_io::scene::load_scene(&config.scene)?;
    let mut view = ProgressView::default();
    if args.split.finish {
        let report = fluidnerf_pipeline::finish_windows(&scene, config, &args.out, |e| view.on_event(e))?;
        #[allow(clippy::print_stdout)]
        {
            println!("{}", report.summary_line());
            println!("wrote {} ({})", args.out.display(), run_outputs(&args.out));
        }
        return Ok(match report.status {
            RunStatus::Finished => std::process::ExitCode::SUCCESS,
            RunStatus::Interrupted => std::process::ExitCode::from(130),
        });
    }
    let plan = fluidnerf_pipeline::window_plan(&scene, config)?;
    // A folder of other settings is named first: its windows are not this plan's.
    fluidnerf_pipeline::check_window_folder(&scene, config, &args.out)?;
    let windows = match (args.split.window_index, &args.split.frames) {
        (Some(k), _) if k >= plan.windows.len() => bail!(
            "--window-index {k}: the run has {} window(s), numbered 0 to {} (its frames and --window / --overlap \
             make the plan)",
            plan.windows.len(),
            plan.windows.len().saturating_sub(1)
        ),
        (Some(k), _) => k..k + 1,
        (None, Some(frames)) => plan.windows_in(frames.clone())?,
        (None, None) => unreachable!("run_split is called with --window-index or --frames"),
    };
    let outcomes = fluidnerf_pipeline::reconstruct_windows(&scene, config, &args.out, windows, |e| view.on_event(e))?;
    let mut interrupted = false;
    #[allow(clippy::print_stdout)]
    for o in &outcomes {
        let what = match (o.reused, o.status) {
            (true, _) => "finished earlier, left as it is".to_string(),
            (false, RunStatus::Finished) => format!("trained, {} iterations, loss {:.3e}", o.iterations, o.final_loss),
            (false, RunStatus::Interrupted) => {
                interrupted = true;
                format!("interrupted at iteration {} (rerun to continue)", o.iterations)
            }
        };
        println!("window {} of {} (frames {}..{}): {what}", o.index, plan.windows.len(), o.frames[0], o.frames[1]);
    }
    #[allow(clippy::print_stdout)]
    {
        println!(
            "wrote {}; when every window is done: fluidnerf reconstruct --finish -o {}",
            args.out.display(),
            args.out.display()
        );
    }
    Ok(if interrupted { std::process::ExitCode::from(130) } else { std::process::ExitCode::SUCCESS })
}

/// `--start-method`: `auto` or a voxel method.
fn parse_start_method(s: &str) -> Result<StartMethod, String> {
    const VOXEL: &str = "auto, asart, art, sart, mart, smart, mlem, tv, tikhonov";
    match s.parse::<StartMethod>() {
        Ok(StartMethod::Method(m)) if m.family() != Family::Classical => {
            Err(format!("{m} is not a voxel method (one of {VOXEL})"))
        }
        Ok(m) => Ok(m),
        Err(_) => Err(format!("unknown start method {s:?} (one of {VOXEL})")),
    }
}

/// The command-line option that set the configuration key `key` in this invocation, if one did.
fn flag_of(args: &Args, key: &str) -> Option<&'static str> {
    let s = &args.stop;
    let (c, n, t) = (&args.classical, &args.neural, &args.temporal);
    let given = [
        ("seed", "--seed", args.seed.is_some()),
        ("resolution", "--resolution", args.resolution.is_some()),
        ("memory_limit_gib", "--memory-limit", args.memory_limit.is_some()),
        ("eval_every", "--eval-every", args.eval_every.is_some()),
        ("checkpoint_every", "--checkpoint-every", args.checkpoint_every.is_some()),
        ("stopping.max_iterations", "--max-iterations", s.max_iterations.is_some()),
        ("stopping.time_budget_s", "--time-budget", s.time_budget.is_some()),
        ("stopping.holdout_every", "--holdout-every", s.holdout_every.is_some()),
        ("stopping.patience", "--patience", s.patience.is_some()),
        ("stopping.rule", "--stop", s.stop.is_some() || s.keep_best_holdout),
        ("gains.mode", "--gains", args.gains.gains.is_some()),
        ("gains.offset", "--gain-offset", args.gains.gain_offset.is_some()),
        ("gains.every", "--gain-every", args.gains.gain_every.is_some()),
        ("gains.rounds", "--gain-rounds", args.gains.gain_rounds.is_some()),
        ("method.holdout_times", "--holdout-times", t.holdout_times.is_some()),
        ("method.time_step", "--time-step", t.time_step.is_some()),
        ("method.projector.kind", "--projector", c.projector.is_some()),
        ("method.projector.visual_hull", "--visual-hull", c.visual_hull.is_some()),
        ("method.projector.splat_subdivisions", "--splat-subdivisions", c.splat_subdivisions.is_some()),
        ("method.projector.ray_step", "--ray-step", c.ray_step.is_some()),
        ("method.projector.hull_threshold", "--hull-threshold", c.hull_threshold.is_some()),
        ("method.projector.hull_noise_sigmas", "--hull-noise-sigmas", c.hull_noise_sigmas.is_some()),
        ("method.projector.hull_dilation", "--hull-dilation", c.hull_dilation.is_some()),
        ("method.params.relaxation", "--relaxation", c.relaxation.is_some()),
        ("method.params.stopping.plateau", "--plateau-tolerance", c.plateau_tolerance.is_some()),
        ("method.params.tv_weight", "--tv-weight", c.tv_weight.is_some()),
        ("method.params.tv_steps", "--tv-steps", c.tv_steps.is_some()),
        ("method.params.step_rule", "--tv-step-rule", c.tv_step_rule.is_some()),
        ("method.params.weight", "--tikhonov-weight", c.tikhonov_weight.is_some()),
        ("method.train.rays_per_image", "--rays-per-image", n.rays_per_image.is_some()),
        ("method.train.coarse_samples", "--coarse-samples", n.coarse_samples.is_some()),
        // Coarse and fine samples together are capped, under the coarse samples' key.
        ("method.train.coarse_samples", "--fine-samples", n.fine_samples.is_some()),
        ("method.train.prior.tv", "--tv-prior", n.tv_prior.is_some()),
        ("method.train.prior.smooth", "--smooth-prior", n.smooth_prior.is_some()),
        ("method.train.prior.sparsity", "--sparsity-prior", n.sparsity_prior.is_some()),
        ("method.windows.overlap", "--overlap", t.overlap.is_some()),
        // The overlap must be shorter than the window, which --window may have shortened.
        ("method.windows.overlap", "--window", t.window.is_some()),
        ("method.windows.time_origin", "--time-origin", t.time_origin.is_some()),
        ("method.windows.time_origin", "--window", t.window.is_some()),
        // --learning-rate sets the schedule's both ends, keeping their ratio.
        ("method.train.schedule.initial", "--learning-rate", n.learning_rate.is_some()),
        ("method.train.schedule.at_decay_iters", "--learning-rate", n.learning_rate.is_some()),
    ];
    given.into_iter().find(|&(k, _, set)| set && k == key).map(|(_, flag, _)| flag)
}
