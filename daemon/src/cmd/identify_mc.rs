//! `metrolog identify capball --uncertainty mc`: the adaptive Monte Carlo of paper 001 on a
//! measured CapBall dataset (docs/methods.md, CapBall uncertainty): sensor noise,
//! frame-transform uncertainty and the measuring loop's drift — cyclic (fitted from a drift
//! record, random start phase per trial) or the ISO/TR 230-9 statistical term — with the
//! coverage-interval width of each source alone (paper 001 Table 5) and, when the dataset holds
//! several runs, the check whether the intervals cover the repeated identifications.

use std::path::{Path, PathBuf};

use anyhow::Context;
use geometry::capball::CapballRecord;
use geometry::kinematics::Machine;
use serde::Serialize;
use uncertainty::capball::{
    self as ucb, CapballSources, CoverageCheck, CyclicDrift, DriftModel, MeasuredCapball,
    SourceWidths,
};
use uncertainty::mc::{McOptions, McResult};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum UncertaintyMethod {
    /// Monte Carlo (JCGM 101): for `capball` adaptive (§7.9) over sensor noise, frame
    /// transform and drift; for `psd` paper 003's study over the reading budget.
    Mc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "snake_case")]
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
    /// Harmonics of the cyclic drift's shape.
    #[arg(long, default_value_t = 3)]
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
    /// Significant digits of the adaptive procedure's tolerance (JCGM 101 §7.9.2).
    #[arg(long, default_value_t = 2)]
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
        [x, y, z] if v.iter().all(|u| u.is_finite() && *u >= 0.0) => Ok([*x, *y, *z]),
        _ => anyhow::bail!("{what} `{s}`: expected three numbers x,y,z ≥ 0 (µm)"),
    }
}

#[derive(Debug, Serialize)]
struct McReport {
    kept_runs: Vec<u32>,
    warmup_runs: Vec<u32>,
    drift_model: Option<DriftKind>,
    cyclic_drift: Option<CyclicDrift>,
    statistical_drift_u_um: Option<[f64; 3]>,
    sensor_u_um: [f64; 3],
    frame_u_um: [f64; 3],
    residual_sigma_um: f64,
    monte_carlo: McResult,
    /// Paper 001 Table 5: 95 % interval widths with all sources and each alone.
    source_widths: Vec<SourceWidths>,
    /// Paper 001: do the intervals cover the repeated identifications (several runs only)?
    coverage_check: Option<CoverageCheck>,
}

fn drift_model(a: &CapballMcArgs) -> anyhow::Result<(DriftModel, Option<DriftKind>)> {
    let Some(p) = &a.drift_record else {
        eprintln!(
            "no --drift-record: the drift is left out of the Monte Carlo (paper 001 found it \
             dominates every parameter); record the ball at one fixed pose to include it"
        );
        return Ok((DriftModel::None, None));
    };
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    let rec = ucb::parse_drift_record(&text).with_context(|| p.display().to_string())?;
    let m = match a.drift {
        DriftKind::Cyclic => DriftModel::Cyclic(
            CyclicDrift::fit(&rec, a.drift_harmonics).with_context(|| p.display().to_string())?,
        ),
        DriftKind::Statistical => DriftModel::statistical_from_range(ucb::drift_range_um(&rec)),
    };
    Ok((m, Some(a.drift)))
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
    let (drift, kind) = drift_model(a)?;
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
    let bar = super::uncertainty::progress_bar(&opts);
    let cb = |p: &uncertainty::McProgress| super::uncertainty::update_bar(&bar, p);
    // The per-point Gaussian noise is drawn in parameter space: the same distribution of the
    // outputs at a fraction of the cost (CapballMc::with_reduced_noise).
    let build = |s: &CapballSources| measured.model(s).map(|m| m.with_reduced_noise());
    let (total, widths) = ucb::source_widths(&build, &sources, &opts, Some(&cb))?;
    bar.finish_and_clear();
    let coverage_check =
        (measured.runs.len() >= 2).then(|| ucb::coverage_check(&total, &measured.run_params()));
    let report = McReport {
        kept_runs: measured.runs.iter().map(|r| r.0).collect(),
        warmup_runs: measured.warmup.clone(),
        drift_model: kind,
        cyclic_drift: match &sources.drift {
            DriftModel::Cyclic(c) => Some(c.clone()),
            _ => None,
        },
        statistical_drift_u_um: match &sources.drift {
            DriftModel::Statistical { u_um } => Some(*u_um),
            _ => None,
        },
        sensor_u_um: sources.sensor_u_um,
        frame_u_um: sources.frame_u_um,
        residual_sigma_um: measured.residual_sigma_um,
        monte_carlo: total,
        source_widths: widths,
        coverage_check,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", render(&report));
    }
    Ok(())
}

fn render(r: &McReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let m = &r.monte_carlo;
    let _ = writeln!(
        s,
        "CapBall Monte Carlo (paper 001, JCGM 101 §7.9): runs {:?} kept{}, centred on their mean",
        r.kept_runs,
        if r.warmup_runs.is_empty() {
            String::new()
        } else {
            format!(", warm-up runs {:?} left out", r.warmup_runs)
        }
    );
    let _ = writeln!(
        s,
        "sources: sensor u {:?} µm, frame u {:?} µm per point; identification residual s = {:.3} µm",
        r.sensor_u_um, r.frame_u_um, r.residual_sigma_um
    );
    match (&r.cyclic_drift, &r.statistical_drift_u_um) {
        (Some(c), _) => {
            let p = c.peak_to_valley_um();
            let _ = writeln!(
                s,
                "drift: cyclic, period {:.0} s, peak to valley x {:.2} y {:.2} z {:.2} µm, {} harmonics, random start phase per trial",
                c.period_s,
                p[0],
                p[1],
                p[2],
                c.harmonics.len()
            );
        }
        (None, Some(u)) => {
            let _ = writeln!(
                s,
                "drift: statistical (ISO/TR 230-9), u = {:.3}/{:.3}/{:.3} µm per point",
                u[0], u[1], u[2]
            );
        }
        _ => {
            let _ = writeln!(s, "drift: not included (no drift record)");
        }
    }
    let _ = writeln!(
        s,
        "{} trials in {} sequences{}",
        m.trials,
        m.sequences,
        if m.converged {
            ""
        } else {
            " — NOT stabilised: the trial limit was reached first"
        }
    );
    let _ = writeln!(
        s,
        "  {:<11} {:>9} {:>8} {:>21}   95 % widths: {:>7} {:>7} {:>7} {:>7} {:>7}",
        "parameter", "value", "u", "95 % interval", "total", "drift", "sensor", "frame", "quad"
    );
    for (o, w) in m.outputs.iter().zip(&r.source_widths) {
        let _ = writeln!(
            s,
            "  {:<11} {:>9.3} {:>8.3} [{:>9.3}, {:>9.3}]   {:>19.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3}",
            o.name,
            o.estimate,
            o.standard_uncertainty,
            o.symmetric_interval[0],
            o.symmetric_interval[1],
            w.total,
            w.drift,
            w.sensor,
            w.frame,
            w.quadrature
        );
    }
    let _ = writeln!(
        s,
        "  (quad = √(drift² + sensor² + frame²): widths of a cyclic drift do not add in quadrature)"
    );
    if let Some(c) = &r.coverage_check {
        let _ = writeln!(
            s,
            "repeated identifications inside the 95 % intervals: {:.0} % overall ({} runs)",
            100.0 * c.overall,
            r.kept_runs.len()
        );
        for (o, (f, q)) in m
            .outputs
            .iter()
            .zip(c.per_parameter.iter().zip(&c.spread_ratio))
        {
            let _ = writeln!(
                s,
                "  {:<11} inside {:>5.0} %   spread of runs / u = {q:.2}",
                o.name,
                100.0 * f
            );
        }
    }
    s
}
