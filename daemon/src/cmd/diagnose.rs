//! `metrolog diagnose`: find what the simulation's baseline model gets wrong in a measured
//! positioning run, name the cause, and write the extended model.

use std::path::PathBuf;

use anyhow::Context as _;
use diagnose::axis::{self, Diagnosis, Options};

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
    /// Seeds averaged when checking that the extended model reproduces the run.
    #[arg(long, default_value_t = 8)]
    pub check_seeds: usize,
    /// Read the input as CapBall data (automatic for a CSV whose header names `ex_um`).
    #[arg(long)]
    pub capball: bool,
    /// CapBall: a drift record at one fixed pose (`time_s,ex_um,ey_um,ez_um`, datasets.md).
    #[arg(long, value_name = "FILE")]
    pub drift_record: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.capball || crate::cmd::diagnose_capball::is_capball_csv(&args.input) {
        return crate::cmd::diagnose_capball::run(&args);
    }
    let mut data = crate::cmd::input::load_positioning(&args.input)?;
    args.units.apply(&mut data)?;
    let mut d: Diagnosis = axis::diagnose(&data, &Options::default())
        .with_context(|| format!("diagnosing {}", args.input.display()))?;
    d.report.reproduction = Some(axis::reproduction_check(&data, &d.model, args.check_seeds));
    if let Some(p) = &args.write_model {
        // The `[axis]` table of a simulator scenario (sim's `Scenario::axis`), so it can
        // replace that table as it is.
        let toml = toml::to_string_pretty(&axis::AxisTable {
            axis: d.model.clone(),
        })
        .context("serialising the model")?;
        let header = format!(
            "# Axis model extended by `metrolog diagnose {}`: baseline fitted from the data plus\n\
             # the effects found ({}).\n",
            args.input.display(),
            if d.report.findings.is_empty() {
                "none".to_string()
            } else {
                d.report.effects().join(", ")
            }
        );
        std::fs::write(p, header + &toml).with_context(|| format!("writing {}", p.display()))?;
        d.report.extended_model = Some(p.display().to_string());
    }
    if let Some(p) = &args.plot {
        crate::cmd::plots::draw_diagnosis(p, &data, &d)
            .with_context(|| format!("drawing {}", p.display()))?;
    }
    let text = if args.json {
        serde_json::to_string_pretty(&d.report)? + "\n"
    } else {
        data.units()
            .relabel(&metrolog_analysis::diagnosis_text::positioning_text(&d))
    };
    crate::cmd::input::print_out(&text)
}
