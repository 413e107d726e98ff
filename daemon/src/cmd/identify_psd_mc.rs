//! `metrolog identify psd --uncertainty mc --budget FILE`: the Monte Carlo of paper 003 §5 for
//! the 13 errors of the PSD laser frame (docs/methods.md, "PSD frame Monte Carlo"): the
//! position-dependent reading budget of the file, all 21 errors randomised, a noisy reference
//! run subtracted. Prints the expanded uncertainty of every derived value beside the run's
//! errors, and our Table 4 beside the published one.

use std::path::PathBuf;

use anyhow::Context;
use geometry::psd_frame::{PsdErrors, PsdLayout};
use serde::Serialize;
use uncertainty::mc::McOptions;
use uncertainty::psd::{self, Table4Study};
use uncertainty::psd_budget::PsdBudget;

use super::identify_mc::UncertaintyMethod;

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
    /// Monte Carlo trials (paper 003 ran 30 000).
    #[arg(long, default_value_t = 30_000)]
    pub trials: usize,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Lever turning angles into lengths for the Table 4 comparison, mm (default: the largest
    /// travel of the layout).
    #[arg(long)]
    pub lever_mm: Option<f64>,
}

#[derive(Debug, Serialize)]
struct RunResult<'a> {
    run: u32,
    errors: &'a PsdErrors,
}

#[derive(Debug, Serialize)]
struct PsdMcReport<'a> {
    reference: u32,
    budget: String,
    /// Per derived value (names as in `names`): half-width of the 95 % interval.
    names: Vec<String>,
    expanded_uncertainty: Vec<f64>,
    runs: Vec<RunResult<'a>>,
    study: Table4Study,
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
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
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
    let bar = super::uncertainty::progress_bar(&opts);
    let cb = |p: &uncertainty::McProgress| super::uncertainty::update_bar(&bar, p);
    let study = psd::table4(layout, &budget, &opts, lever, Some(&cb))
        .with_context(|| path.display().to_string())?;
    bar.finish_and_clear();
    let outputs = &study.monte_carlo.outputs;
    let report = PsdMcReport {
        reference,
        budget: budget.title.clone(),
        names: outputs.iter().map(|o| o.name.clone()).collect(),
        expanded_uncertainty: outputs
            .iter()
            .map(|o| 0.5 * (o.symmetric_interval[1] - o.symmetric_interval[0]))
            .collect(),
        runs: runs
            .iter()
            .map(|(run, errors)| RunResult { run: *run, errors })
            .collect(),
        study,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", render(&report));
    }
    Ok(())
}

fn render(r: &PsdMcReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let st = &r.study;
    let _ = writeln!(
        s,
        "PSD frame Monte Carlo (paper 003 §5): {} trials, budget \"{}\"",
        st.monte_carlo.trials, r.budget
    );
    let _ = writeln!(
        s,
        "reading u (one run) {:.3}–{:.3} µm by segment and point; a noisy reference run is subtracted; all 21 errors randomised",
        st.reading_u_um[1], st.reading_u_um[0]
    );
    let _ = writeln!(
        s,
        "  {:<6} {:>14} {:>12} {:>10}",
        "error", "U (95 %)", "as length", "paper 003"
    );
    for row in &st.rows {
        let _ = writeln!(
            s,
            "  {:<6} {:>9.2} {:<4} {:>9.2} µm {:>7.1} µm{}",
            row.error,
            row.expanded,
            row.unit,
            row.expanded_um,
            row.published_um,
            match row.per_point_um {
                Some(p) => format!("   (change over the travel; at a point ±{p:.2} µm)"),
                None => String::new(),
            }
        );
    }
    let _ = writeln!(
        s,
        "  (angles as lengths over {:.0} mm; U = largest 95 % half-width over the error's points)",
        st.lever_mm
    );
    let u = |name: &str| {
        r.names
            .iter()
            .position(|n| n == name)
            .map(|k| r.expanded_uncertainty[k])
            .unwrap_or(f64::NAN)
    };
    for run in &r.runs {
        let e = run.errors;
        let _ = writeln!(s, "run {} − run {}:", run.run, r.reference);
        let _ = writeln!(
            s,
            "  squareness EC0Y {:.2} ± {:.2}, EB0Z {:.2} ± {:.2}, EA0Z {:.2} ± {:.2} µrad",
            e.ec0y_urad,
            u("EC0Y_urad"),
            e.eb0z_urad,
            u("EB0Z_urad"),
            e.ea0z_urad,
            u("EA0Z_urad")
        );
        let travel = |v: &[f64]| v.last().unwrap_or(&0.0) - v.first().unwrap_or(&0.0);
        let _ = writeln!(
            s,
            "  positioning change over the travel X {:.2} ± {:.2} µm, Y {:.2} ± {:.2} µm",
            travel(&e.exx_um),
            u(psd::TRAVEL_OUTPUTS[0]),
            travel(&e.eyy_um),
            u(psd::TRAVEL_OUTPUTS[1])
        );
        // (label, values, unit, unit in the output names of `PsdErrors::names`)
        for (label, v, unit, tag) in [
            ("EYX", &e.eyx_um, "µm", "um"),
            ("EZX", &e.ezx_um, "µm", "um"),
            ("EXY", &e.exy_um, "µm", "um"),
            ("EZY", &e.ezy_um, "µm", "um"),
            ("EXZ", &e.exz_um, "µm", "um"),
            ("EYZ", &e.eyz_um, "µm", "um"),
            ("EAX", &e.eax_urad, "µrad", "urad"),
            ("EBY", &e.eby_urad, "µrad", "urad"),
        ] {
            let line: Vec<String> = v
                .iter()
                .enumerate()
                .map(|(i, x)| format!("{x:.2}±{:.2}", u(&format!("{label}_{tag}[{}]", i + 1))))
                .collect();
            let _ = writeln!(s, "  {label} ({unit}): {}", line.join(" "));
        }
    }
    s
}
