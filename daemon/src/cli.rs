//! Command line: one subcommand per job; each lives in its own module under `cmd/`. `demo` and
//! `sim` exist with the feature `sim` (on by default; a service build leaves it out).

use clap::{Parser, Subcommand};

use crate::cmd;

/// metrolog — data acquisition and analysis for machine-tool metrology.
#[derive(Debug, Parser)]
#[command(name = "metrolog", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the acquisition service from a config file (what systemd starts).
    Run(cmd::run::Args),
    /// Run a complete measurement on simulated instruments and report it.
    #[cfg(feature = "sim")]
    Demo(cmd::demo::Args),
    /// Start only the simulated instruments and print their port paths.
    #[cfg(feature = "sim")]
    Sim(cmd::sim::Args),
    /// Re-run steady-value detection (and analysis) from the raw topics of a log.
    Replay(cmd::replay::Args),
    /// Show what a log holds.
    Info(cmd::info::Args),
    /// Rewrite the intact part of a torn or killed log into a valid, indexed file.
    Recover(cmd::recover::Args),
    /// Evaluate a measurement (ISO 230-2 positioning accuracy, ...).
    #[command(subcommand)]
    Analyze(cmd::analyze::Command),
    /// Find what the simulation model gets wrong in measured data, and extend the model.
    Diagnose(cmd::diagnose::Args),
    /// Volumetric error of a three-axis machine and its compensation table.
    Volumetric(cmd::volumetric::Args),
    /// Identify machine errors from CapBall or PSD measurements.
    #[command(subcommand)]
    Identify(cmd::identify::Command),
    /// Before/after check of measured parts (means, Welch t-test, reject rates).
    Parts(cmd::parts::Args),
    /// Evaluate an uncertainty budget by GUM and/or Monte Carlo.
    Uncertainty(cmd::uncertainty::Args),
    /// Plan a test: targets, trajectory and part program.
    #[command(subcommand)]
    Plan(cmd::plan::Command),
    /// Write a controller's compensation table from a measurement.
    #[command(subcommand)]
    Compensate(cmd::compensate::Command),
    /// Thermal model of a machine tool from a thermal test: fit, predict, diagnose.
    #[command(subcommand)]
    Thermal(cmd::thermal::Command),
    /// The positioning report a customer signs (self-contained HTML, or PDF printed by Chromium).
    Report(cmd::report::Args),
}

impl Command {
    /// Whether the command acquires (the service, the demo, the simulator): a closed socket
    /// or pipe must be an error there, never a signal that ends it.
    fn acquires(&self) -> bool {
        match self {
            Command::Run(_) => true,
            #[cfg(feature = "sim")]
            Command::Demo(_) | Command::Sim(_) => true,
            _ => false,
        }
    }
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    if !cli.command.acquires() {
        stop_quietly_on_closed_pipe();
    }
    match cli.command {
        Command::Run(a) => cmd::run::run(a),
        #[cfg(feature = "sim")]
        Command::Demo(a) => cmd::demo::run(a),
        #[cfg(feature = "sim")]
        Command::Sim(a) => cmd::sim::run(a),
        Command::Replay(a) => cmd::replay::run(a),
        Command::Info(a) => cmd::info::run(a),
        Command::Recover(a) => cmd::recover::run(a),
        Command::Analyze(c) => cmd::analyze::run(c),
        Command::Diagnose(a) => cmd::diagnose::run(a),
        Command::Volumetric(a) => cmd::volumetric::run(a),
        Command::Identify(c) => cmd::identify::run(c),
        Command::Parts(a) => cmd::parts::run(a),
        Command::Uncertainty(a) => cmd::uncertainty::run(a),
        Command::Plan(c) => cmd::plan::run(c),
        Command::Compensate(c) => cmd::compensate::run(c),
        Command::Report(a) => cmd::report::run(a),
        Command::Thermal(c) => cmd::thermal::run(c),
    }
}

/// A report command piped into `head` ends quietly when the reader goes, as Unix tools do,
/// instead of panicking in `println!` (Rust ignores SIGPIPE by default). Not for `run`, `demo`
/// and `sim`: the acquisition and the live view must see a closed socket as an error, never be
/// killed by it.
fn stop_quietly_on_closed_pipe() {
    // SAFETY: called before any other thread exists in these commands; SIG_DFL for SIGPIPE
    // is the default disposition of every Unix process.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
