//! `metrolog volumetric` (not written yet).

#[derive(Debug, clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`metrolog volumetric` is not implemented yet")
}
