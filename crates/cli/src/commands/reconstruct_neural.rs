//! `fluidnerf reconstruct` for the neural methods.

/// Options of the neural methods.
#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(args: &super::reconstruct::Args) -> anyhow::Result<()> {
    anyhow::bail!("method {:?} is not available in this build", args.method)
}
