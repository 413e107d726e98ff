//! `metrolog diagnose`: find what the simulation's model gets wrong in measured data, name the
//! cause, and write the extended model. The input decides the family: a positioning run
//! ([`positioning`], the axis model) or CapBall data ([`capball`], the 14-parameter link/setup
//! model); `cmd::input` tells them apart.

pub mod capball;
pub mod positioning;

use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Positioning dataset (CSV, see datasets.md) or MCAP log of a run.
    pub input: PathBuf,
    #[command(flatten)]
    pub units: crate::cmd::input::UnitArgs,
    /// Print the JSON report (datasets.md, "Diagnosis report") instead of text.
    #[arg(long)]
    pub json: bool,
    /// Write the extended axis model to FILE: the `[axis]` table of a simulator scenario
    /// (TOML).
    #[arg(long, value_name = "FILE")]
    pub write_model: Option<PathBuf>,
    /// Draw the residual views (.svg or .png).
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
    /// Seeds averaged when checking that the extended model reproduces the run (1 to 100;
    /// each costs one simulated run and one diagnosis of it).
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub check_seeds: u64,
    /// Read the input as CapBall data (automatic for a CSV whose header names `ex_um`).
    #[arg(long)]
    pub capball: bool,
    /// CapBall: a drift record at one fixed pose (`time_s,ex_um,ey_um,ez_um`, datasets.md).
    #[arg(long, value_name = "FILE")]
    pub drift_record: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.capball || crate::cmd::input::is_capball_csv(&args.input) {
        return capball::run(
            &args.input,
            args.drift_record.as_deref(),
            args.write_model.as_deref(),
            args.json,
        );
    }
    positioning::run(positioning::Request {
        input: &args.input,
        units: &args.units,
        json: args.json,
        write_model: args.write_model.as_deref(),
        plot: args.plot.as_deref(),
        check_seeds: args.check_seeds as usize,
    })
}
