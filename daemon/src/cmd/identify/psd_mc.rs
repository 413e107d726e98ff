//! `metrolog identify psd --uncertainty mc --budget FILE`: the Monte Carlo of paper 003 §5 for
//! the 13 errors of the PSD laser frame (docs/methods.md, "PSD frame Monte Carlo"): the
//! position-dependent reading budget of the file, all 21 errors randomised, a noisy reference
//! run subtracted. Prints the expanded uncertainty of every derived value beside the run's
//! errors, and our Table 4 beside the published one. The report and its text are
//! `metrolog_analysis::identify_text`.

use std::path::PathBuf;

use anyhow::Context;
use geometry::psd_frame::{PsdErrors, PsdLayout};
use metrolog_analysis::identify_text::{PsdMcReport, psd_mc_text};
use uncertainty::mc::McOptions;
use uncertainty::psd;
use uncertainty::psd_budget::PsdBudget;

use super::capball_mc::UncertaintyMethod;
use crate::cmd::progress::{mc_progress_bar, update_mc_bar};

/// Options of `identify psd` for the Monte Carlo uncertainty.
#[derive(Debug, Clone, clap::Args)]
pub struct PsdMcArgs {
    /// Uncertainty of the derived errors: `mc` runs paper 003's Monte Carlo with the reading
    /// budget of `--budget` instead of one `--sigma-um` for every reading.
    #[arg(long, value_enum)]
    pub uncertainty: Option<UncertaintyMethod>,
    /// Reading budget per segment and point and thermal-error amplitudes (TOML, format in
    /// docs/methods.md; example: examples/budgets/psd_frame_readings.toml).
    #[arg(long)]
    pub budget: Option<PathBuf>,
    /// Monte Carlo trials (paper 003 ran 30 000), 1 to 20 000 000.
    #[arg(long, default_value_t = 30_000, value_parser = crate::cmd::input::trials_arg)]
    pub trials: usize,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Lever turning angles into lengths for the Table 4 comparison, mm (default: the largest
    /// travel of the layout).
    #[arg(long)]
    pub lever_mm: Option<f64>,
}

/// Runs the Monte Carlo for `layout` and prints it with the derived errors of each run.
pub fn run(
    layout: &PsdLayout,
    reference: u32,
    runs: &[(u32, PsdErrors)],
    a: &PsdMcArgs,
    json: bool,
) -> anyhow::Result<()> {
    let Some(path) = &a.budget else {
        anyhow::bail!(
            "--uncertainty mc needs --budget FILE: the reading budget per segment \
             (docs/methods.md; example examples/budgets/psd_frame_readings.toml)"
        );
    };
    if a.trials < 100 {
        anyhow::bail!(
            "--trials {}: use at least 100 (paper 003: 30 000)",
            a.trials
        );
    }
    let text = crate::cmd::input::read_text(path)?;
    let budget = PsdBudget::from_toml(&text).with_context(|| path.display().to_string())?;
    let lever = a.lever_mm.unwrap_or_else(|| {
        (layout.x_hi - layout.x_lo)
            .max(layout.y_hi - layout.y_lo)
            .max(layout.z1 - layout.z0)
    });
    let opts = McOptions {
        fixed_trials: Some(a.trials),
        seed: a.seed,
        ..McOptions::default()
    };
    let bar = mc_progress_bar(&opts);
    let cb = |p: &uncertainty::McProgress| update_mc_bar(&bar, p);
    let study = psd::table4(layout, &budget, &opts, lever, Some(&cb))
        .with_context(|| path.display().to_string())?;
    bar.finish_and_clear();
    let report = PsdMcReport::new(reference, budget.title.clone(), runs, study);
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        out!("{}", psd_mc_text(&report))?;
    }
    Ok(())
}
