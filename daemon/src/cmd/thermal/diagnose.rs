//! `metrolog thermal diagnose DATA.csv`: what the static all-temperature regression misses.

use std::path::PathBuf;

use anyhow::Context as _;

use crate::cmd::input::{load_thermal, print_out};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Thermal test (CSV: `time_s`, temperatures `_c`, displacements `_um`, optional
    /// `spindle_rpm`), or a run's log (.mcap: `/temperature` and the measuring pose's values).
    pub input: PathBuf,
    /// Print the diagnosis as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let ds = load_thermal(&a.input)?;
    anyhow::ensure!(
        !ds.channel_names.is_empty(),
        "{}: no displacement column (a name ending `_um`, e.g. `x_um`); the diagnosis explains \
         measured displacements",
        a.input.display()
    );
    let mut opts = thermal::DiagnoseOptions::default();
    opts.fit.blocks = super::blocks_for(ds.len(), None);
    let d = thermal::diagnose(&ds, &opts)
        .with_context(|| format!("diagnosing {}", a.input.display()))?;
    let text = if a.json {
        let v = serde_json::to_value(&d)?;
        serde_json::to_string_pretty(&v)? + "\n"
    } else {
        d.render()
    };
    print_out(&text)
}
