//! `metrolog uncertainty` (not written yet).

#[derive(Debug, clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`metrolog uncertainty` is not implemented yet")
}
