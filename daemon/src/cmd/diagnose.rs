//! `metrolog diagnose`: find what the simulation's baseline model gets wrong in a measured
//! positioning run, name the cause, and write the extended model.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use metrology::diagnose::{self, Diagnosis, Options};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Positioning dataset (CSV, see datasets.md) or MCAP log of a run.
    pub input: PathBuf,
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
    let data = crate::cmd::input::load_positioning(&args.input)?;
    let mut d: Diagnosis = diagnose::diagnose(&data, &Options::default())
        .with_context(|| format!("diagnosing {}", args.input.display()))?;
    d.report.reproduction = Some(diagnose::reproduction_check(
        &data,
        &d.model,
        args.check_seeds,
    ));
    if let Some(p) = &args.write_model {
        // The `[axis]` table of a simulator scenario (sim's `Scenario::axis`), so it can
        // replace that table as it is.
        let toml = toml::to_string_pretty(&metrology::diagnose::AxisTable {
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
                d.report
                    .findings
                    .iter()
                    .map(|f| f.effect.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
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
        render_text(&d)
    };
    crate::cmd::input::print_out(&text)
}

/// The human-readable diagnosis.
pub fn render_text(d: &Diagnosis) -> String {
    let r = &d.report;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Baseline (static deviation per target and direction + stationary noise): RMS residual \
         {:.3} µm, held-out cycles {:.3} µm",
        r.baseline.rms_um, r.baseline.heldout_rms_um
    );
    if r.findings.is_empty() {
        let _ = writeln!(
            s,
            "No finding: the baseline explains the data (noise {:.3} µm).",
            d.model.noise_um
        );
    }
    for (k, f) in r.findings.iter().enumerate() {
        let params: Vec<String> = f
            .params
            .iter()
            .map(|(name, v)| match f.params_u.get(name) {
                Some(u) => format!("{name} = {v:.4} ± {u:.2}"),
                None => format!("{name} = {v:.4}"),
            })
            .collect();
        write_finding(
            &mut s,
            (k + 1, &f.effect, f.significance),
            &params,
            ("held-out", f.heldout_rms_before_um, f.heldout_rms_after_um),
            &f.cause,
        );
    }
    if !r.conclusion.is_empty() {
        let _ = writeln!(s, "\nConclusion: {}", r.conclusion);
    }
    if let Some(rep) = &r.reproduction {
        let _ = writeln!(
            s,
            "\nSimulating the same run ({} seeds) — RMS of simulated − measured per-target statistics:\n   \
             extended model: x̄ {:.3} µm, s {:.3} µm\n   baseline model: x̄ {:.3} µm, s {:.3} µm",
            rep.seeds,
            rep.mean_rms_um,
            rep.s_rms_um,
            rep.baseline_mean_rms_um,
            rep.baseline_s_rms_um
        );
    }
    if let Some(p) = &r.extended_model {
        let _ = writeln!(s, "\nExtended model written to {p}");
    }
    for n in &r.notes {
        let _ = writeln!(s, "Note: {n}");
    }
    s
}

/// One finding of a diagnosis report as text: number, effect and significance, parameters,
/// the error before → after on the run the effect was checked against, and the cause.
pub(crate) fn write_finding(
    s: &mut String,
    (number, effect, significance): (usize, &str, f64),
    params: &[String],
    (checked_on, before_um, after_um): (&str, f64, f64),
    cause: &str,
) {
    let _ = writeln!(s, "\n{number}. {effect} (significance {significance:.1})");
    let _ = writeln!(s, "   {}", params.join(", "));
    let _ = writeln!(s, "   {checked_on} error {before_um:.3} → {after_um:.3} µm");
    let _ = writeln!(s, "   cause: {cause}");
}
