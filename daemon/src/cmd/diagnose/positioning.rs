//! `metrolog diagnose` on a positioning run: what the simulation's baseline axis model gets
//! wrong, the cause, and the extended model.

use std::path::Path;

use anyhow::Context as _;
use diagnose::axis::{self, Diagnosis, Options};

/// What `diagnose` asks of a positioning run.
pub struct Request<'a> {
    pub input: &'a Path,
    pub units: &'a crate::cmd::input::UnitArgs,
    /// The JSON report instead of text.
    pub json: bool,
    /// Where to write the extended axis model.
    pub write_model: Option<&'a Path>,
    /// Where to draw the residual views.
    pub plot: Option<&'a Path>,
    /// Seeds averaged in the reproduction check.
    pub check_seeds: usize,
}

pub fn run(args: Request) -> anyhow::Result<()> {
    let mut data = crate::cmd::input::load_positioning(args.input)?;
    args.units.apply(&mut data)?;
    let mut d: Diagnosis = axis::diagnose(&data, &Options::default())
        .with_context(|| format!("diagnosing {}", args.input.display()))?;
    d.report.reproduction = Some(axis::reproduction_check(&data, &d.model, args.check_seeds));
    if let Some(p) = args.write_model {
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
    if let Some(p) = args.plot {
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
