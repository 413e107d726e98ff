//! `metrolog identify` (not written yet).

#[derive(Debug, clap::Subcommand)]
pub enum Command {}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {}
}
