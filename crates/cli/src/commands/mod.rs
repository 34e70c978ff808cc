//! Subcommands. Each module holds a clap `Args` struct and a `run` function.

use clap::Subcommand;

/// The subcommands of `fluidnerf`.
#[derive(Subcommand)]
pub enum Command {}

/// Runs a parsed subcommand.
pub fn run(command: Command) -> anyhow::Result<()> {
    match command {}
}
