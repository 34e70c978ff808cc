//! `fluidnerf reconstruct` for the classical methods.

/// Options of the classical methods.
#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(args: &super::reconstruct::Args) -> anyhow::Result<()> {
    anyhow::bail!("method {:?} is not available in this build", args.method)
}
