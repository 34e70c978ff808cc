//! Subcommands. Each module holds a clap `Args` struct and a `run` function.

use clap::Subcommand;

pub mod eval;
pub mod export;
pub mod import;
pub mod info;
pub mod reconstruct;
pub mod reconstruct_classical;
pub mod reconstruct_neural;
pub mod reconstruct_temporal;
pub mod render;
pub mod synth;

/// The subcommands of `fluidnerf`.
#[derive(Subcommand)]
pub enum Command {
    /// Validate a scene and describe its cameras, images, box coverage, times and truth.
    Info(info::Args),
    /// Build a scene from an OpenCV or COLMAP calibration and a folder of images.
    Import(import::Args),
    /// Reconstruct the field from a scene's images with a classical or a neural method.
    Reconstruct(reconstruct::Args),
    /// Score a reconstruction against ground truth and held-out camera images.
    Eval(eval::Args),
    /// Sample a reconstruction onto any grid and export volumes (.npy, .vti, raw), slice
    /// pictures, truth | reconstruction | difference panels and isosurface meshes.
    Export(export::Args),
    /// Render a reconstruction from scene cameras or an orbit, to 16-bit PNG or float TIFF,
    /// with a turntable GIF.
    Render(render::Args),
    /// Generate a synthetic data set with known ground truth: jet phantoms, camera rigs,
    /// pinhole or thin-lens images, sensor noise.
    Synth(synth::Args),
}

/// Runs a parsed subcommand.
pub fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Info(args) => info::run(args),
        Command::Import(args) => import::run(args),
        Command::Reconstruct(args) => reconstruct::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Export(args) => export::run(args),
        Command::Render(args) => render::run(args),
        Command::Synth(args) => synth::run(args),
    }
}
