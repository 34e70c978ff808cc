//! `fluidnerf reconstruct`: one entry point for every reconstruction method. The options all
//! methods share are here; each family adds its own group (`reconstruct_classical`,
//! `reconstruct_neural`).

use std::path::PathBuf;

use clap::ValueEnum;
use serde::{Deserialize, Serialize};

use super::{reconstruct_classical, reconstruct_neural, reconstruct_temporal};

/// Reconstruction methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Adaptive simultaneous ART, the dissertation's baseline (Eq. 2.29–2.30).
    Asart,
    /// Algebraic reconstruction technique, row by row (Kaczmarz, Eq. 2.21).
    Art,
    /// Simultaneous ART, view by view (Eq. 2.27).
    Sart,
    /// Multiplicative ART (Eq. 2.25).
    Mart,
    /// Simultaneous multiplicative ART (Eq. 2.28).
    Smart,
    /// Maximum-likelihood expectation maximisation (Eq. 2.33).
    Mlem,
    /// SART with total-variation regularisation (edge preserving).
    Tv,
    /// SART with second-order Tikhonov regularisation (smoothness, Eq. 2.35).
    Tikhonov,
    /// FluidNeRF as in the dissertation: positional encoding + MLP (chapter 5.1).
    Fluidnerf,
    /// A multiresolution grid encoding with a tiny MLP: the same method, much faster.
    Fast,
    /// Time-resolved FluidNeRF (chapter 5.2): one MLP E(x, y, z, t') for all frames.
    TrFluidnerf,
    /// Time-resolved, with a space–time hash grid and a tiny MLP, in sliding windows.
    TrFast,
    /// Static FluidNeRF trained separately on each frame (the baseline of TR-FluidNeRF).
    StaticPerFrame,
}

impl Method {
    /// Whether the method is one of the classical voxel methods.
    pub fn is_classical(self) -> bool {
        !matches!(self, Method::Fluidnerf | Method::Fast) && !self.is_temporal()
    }

    /// Whether the method reconstructs every frame of a time-resolved scene.
    pub fn is_temporal(self) -> bool {
        matches!(self, Method::TrFluidnerf | Method::TrFast | Method::StaticPerFrame)
    }
}

/// Reconstruct a scalar field from a scene's images.
///
/// Writes into OUT: the volume (`volume.npy`, `volume.vti`), the resolved settings
/// (`config.json`, rerun with `--config`), `report.json` (iterations, loss or residual
/// history, time, memory) and `report.html` (settings, metrics against the truth when the scene
/// has one, slices and convergence plots). Neural methods also write their weights.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The scene: a folder holding `transforms.json`, or the file itself.
    pub scene: PathBuf,
    /// Output directory; created if missing. An existing one with results needs --force (or
    /// --resume for neural methods).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Reconstruction method.
    #[arg(short, long, value_enum, default_value = "fast")]
    pub method: Method,
    /// Voxels along the longest side of the reconstruction box for the output volume (and the
    /// working grid of classical methods); cells are cubic.
    #[arg(long, default_value_t = 128)]
    pub resolution: usize,
    /// Iteration cap (default: the method's own).
    #[arg(long)]
    pub max_iterations: Option<usize>,
    /// Seed for every random choice; the same seed gives the same result.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Rerun from a `config.json` written by an earlier run (options given here override it).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Overwrite results already in OUT.
    #[arg(long)]
    pub force: bool,
    /// Continue from the checkpoint in OUT (neural methods).
    #[arg(long)]
    pub resume: bool,
    #[command(flatten)]
    pub classical: reconstruct_classical::Args,
    #[command(flatten)]
    pub neural: reconstruct_neural::Args,
    #[command(flatten)]
    pub temporal: reconstruct_temporal::Args,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    crate::interrupt::install();
    if args.method.is_temporal() {
        reconstruct_temporal::run(&args)?;
    } else if args.method.is_classical() {
        reconstruct_classical::run(&args)?;
    } else {
        reconstruct_neural::run(&args)?;
    }
    write_report(&args);
    Ok(())
}

/// Adds `report.html` to a run directory holding a single volume. A failure here must not
/// turn a finished reconstruction into an error, so it is a warning.
fn write_report(args: &Args) {
    if !args.out.join("volume.npy").exists() {
        return;
    }
    let label = format!("{:?}", args.method);
    let written = fluidnerf_io::scene::load_scene(&args.scene)
        .map_err(anyhow::Error::from)
        .and_then(|scene| crate::run_report::write_run_report(&args.out, &scene, &label));
    match written {
        Ok(path) => log::info!("wrote {}", path.display()),
        Err(e) => log::warn!("could not write the run report in {}: {e:#}", args.out.display()),
    }
}
