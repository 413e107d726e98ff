//! `metrolog identify capball --uncertainty mc`: the adaptive Monte Carlo of paper 001 on a
//! measured CapBall dataset (docs/methods.md, CapBall uncertainty): sensor noise,
//! frame-transform uncertainty and the measuring loop's drift — cyclic (fitted from a drift
//! record, random start phase per trial) or the ISO/TR 230-9 statistical term — with the
//! coverage-interval width of each source alone (paper 001 Table 5) and, when the dataset holds
//! several runs, the check whether the intervals cover the repeated identifications. The report
//! and its text are `metrolog_analysis::identify_text`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use geometry::capball::CapballRecord;
use geometry::kinematics::Machine;
use metrolog_analysis::identify_text::{CapballMcReport, capball_mc_text};
use uncertainty::capball::{self as ucb, CapballSources, CyclicDrift, DriftModel, MeasuredCapball};
use uncertainty::mc::McOptions;

use crate::cmd::progress::{mc_progress_bar, update_mc_bar};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum UncertaintyMethod {
    /// Monte Carlo (JCGM 101): for `capball` adaptive (§7.9) over sensor noise, frame
    /// transform and drift; for `psd` paper 003's study over the reading budget.
    Mc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DriftKind {
    /// Periodic function of time fitted from the drift record, random start phase per trial.
    Cyclic,
    /// ISO/TR 230-9: a normal term per point from the record's range E_VE (u = E_VE/(2√3)).
    Statistical,
}

/// Options of `identify capball` for the Monte Carlo uncertainty.
#[derive(Debug, Clone, clap::Args)]
pub struct CapballMcArgs {
    /// Uncertainty of the identified errors: `mc` runs paper 001's Monte Carlo instead of
    /// printing s²(JᵀJ)⁻¹ (which ignores the drift).
    #[arg(long, value_enum)]
    pub uncertainty: Option<UncertaintyMethod>,
    /// Drift record taken at one fixed pose: CSV `time_s,ex_um,ey_um,ez_um` (docs/datasets.md).
    #[arg(long)]
    pub drift_record: Option<PathBuf>,
    /// How the drift enters the Monte Carlo.
    #[arg(long, value_enum, default_value = "cyclic")]
    pub drift: DriftKind,
    /// Harmonics of the cyclic drift's shape, 1 to 20.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=20))]
    pub drift_harmonics: u32,
    /// Standard uncertainty of the sensor outputs `x,y,z` (µm, per point).
    #[arg(long, default_value = "0.1,0.1,0.1")]
    pub sensor_u_um: String,
    /// Standard uncertainty of the sensor-to-machine frame transform `x,y,z` (µm, per point).
    #[arg(long, default_value = "0.3,0.3,0.3")]
    pub frame_u_um: String,
    /// Leading runs left out as warm-up (paper 001 dropped 5 of 15).
    #[arg(long, default_value_t = 0)]
    pub warmup_runs: usize,
    /// Significant digits of the adaptive procedure's tolerance (JCGM 101 §7.9.2), 1 to 4.
    #[arg(long, default_value_t = 2, value_parser = crate::cmd::input::ndig_arg)]
    pub ndig: u32,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

fn triple(s: &str, what: &str) -> anyhow::Result<[f64; 3]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("{what} `{s}`: expected three numbers x,y,z (µm)"))?;
    match v.as_slice() {
        // A standard uncertainty beyond 10 mm is no CapBall's (its sensors span a few 100 µm).
        [x, y, z]
            if v.iter()
                .all(|u| u.is_finite() && (0.0..=10_000.0).contains(u)) =>
        {
            Ok([*x, *y, *z])
        }
        _ => anyhow::bail!("{what} `{s}`: expected three numbers x,y,z from 0 to 10000 µm"),
    }
}

fn drift_model(a: &CapballMcArgs) -> anyhow::Result<DriftModel> {
    let Some(p) = &a.drift_record else {
        errln!(
            "no --drift-record: the drift is left out of the Monte Carlo (paper 001 found it \
             dominates every parameter); record the ball at one fixed pose to include it"
        );
        return Ok(DriftModel::None);
    };
    let text = crate::cmd::input::read_text(p)?;
    let rec = ucb::parse_drift_record(&text).with_context(|| p.display().to_string())?;
    let m = match a.drift {
        DriftKind::Cyclic => DriftModel::Cyclic(
            CyclicDrift::fit(&rec, a.drift_harmonics).with_context(|| p.display().to_string())?,
        ),
        DriftKind::Statistical => DriftModel::statistical_from_range(ucb::drift_range_um(&rec)),
    };
    Ok(m)
}

/// Runs the Monte Carlo on the records of `data` and prints (or writes as JSON) the result.
pub fn run(
    data: &Path,
    machine: &Machine,
    recs: &[CapballRecord],
    a: &CapballMcArgs,
    json: bool,
) -> anyhow::Result<()> {
    let measured = MeasuredCapball::from_records(machine, recs, a.warmup_runs)
        .with_context(|| data.display().to_string())?;
    let drift = drift_model(a)?;
    let sources = CapballSources {
        sensor_u_um: triple(&a.sensor_u_um, "--sensor-u-um")?,
        frame_u_um: triple(&a.frame_u_um, "--frame-u-um")?,
        drift,
    };
    let opts = McOptions {
        ndig: a.ndig,
        seed: a.seed,
        ..McOptions::default()
    };
    let bar = mc_progress_bar(&opts);
    let cb = |p: &uncertainty::McProgress| update_mc_bar(&bar, p);
    // The per-point Gaussian noise is drawn in parameter space: the same distribution of the
    // outputs at a fraction of the cost (CapballMc::with_reduced_noise).
    let build = |s: &CapballSources| measured.model(s).map(|m| m.with_reduced_noise());
    let (total, widths) = ucb::source_widths(&build, &sources, &opts, Some(&cb))?;
    bar.finish_and_clear();
    let coverage_check =
        (measured.runs.len() >= 2).then(|| ucb::coverage_check(&total, &measured.run_params()));
    let report = CapballMcReport::new(&measured, &sources, total, widths, coverage_check);
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        out!("{}", capball_mc_text(&report))?;
    }
    Ok(())
}
