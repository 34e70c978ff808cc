//! Subcommands. Each module holds a clap `Args` struct and a `run` function.

use clap::Subcommand;

pub mod compare;
pub mod demo;
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

/// The subcommands of `fluidnerf`. Each one's help text is the doc comment of its `Args`.
#[derive(Subcommand)]
pub enum Command {
    Demo(demo::Args),
    Info(info::Args),
    Import(import::Args),
    Reconstruct(reconstruct::Args),
    Eval(eval::Args),
    Compare(compare::Args),
    Export(export::Args),
    Render(render::Args),
    Synth(synth::Args),
}

/// Runs a parsed subcommand.
pub fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Demo(args) => demo::run(args),
        Command::Info(args) => info::run(args),
        Command::Import(args) => import::run(args),
        Command::Reconstruct(args) => reconstruct::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Export(args) => export::run(args),
        Command::Render(args) => render::run(args),
        Command::Synth(args) => synth::run(args),
    }
}
