//! The reports of `metrolog identify`: the validation warning of a CapBall identification, the
//! CapBall Monte Carlo of paper 001 and the PSD frame Monte Carlo of paper 003 (report types,
//! serialised as the commands' JSON, and their text).

use geometry::capball::ValidationExcess;
use geometry::psd_frame::PsdErrors;
use serde::Serialize;
use uncertainty::capball::{
    CapballSources, CoverageCheck, CyclicDrift, DriftModel, MeasuredCapball, SourceWidths,
};
use uncertainty::mc::McResult;
use uncertainty::psd::{self, Table4Study};

/// The sentence for a validation residual white noise does not explain
/// ([`geometry::capball::Identification::validation_excess`]), and what to do.
pub fn validation_excess_warning(e: &ValidationExcess) -> String {
    format!(
        "the validation residual RMS ({:.3} µm) is {:.2}× the identification's ({:.3} µm); white noise explains at most {:.2}×: the 14-parameter model misses something that differs between the runs (a drift of the measuring loop, a sensor gain, an axis error). Run `metrolog diagnose` on a dataset holding both runs (run 1 identification, run 2 validation)",
        e.validation_rms_um,
        e.ratio.sqrt(),
        e.identification_sigma_um,
        e.bound.sqrt()
    )
}

/// How the drift entered a CapBall Monte Carlo.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DriftKind {
    /// Periodic function of time fitted from the drift record, random start phase per trial.
    Cyclic,
    /// ISO/TR 230-9: a normal term per point from the record's range.
    Statistical,
}

/// `identify capball --uncertainty mc`: the Monte Carlo of paper 001 on a measured dataset.
#[derive(Debug, Serialize)]
pub struct CapballMcReport {
    pub kept_runs: Vec<u32>,
    pub warmup_runs: Vec<u32>,
    pub drift_model: Option<DriftKind>,
    pub cyclic_drift: Option<CyclicDrift>,
    pub statistical_drift_u_um: Option<[f64; 3]>,
    pub sensor_u_um: [f64; 3],
    pub frame_u_um: [f64; 3],
    pub residual_sigma_um: f64,
    pub monte_carlo: McResult,
    /// Paper 001 Table 5: 95 % interval widths with all sources and each alone.
    pub source_widths: Vec<SourceWidths>,
    /// Paper 001: do the intervals cover the repeated identifications (several runs only)?
    pub coverage_check: Option<CoverageCheck>,
}

impl CapballMcReport {
    /// The report of a Monte Carlo on `measured` with `sources`: `total` with every source,
    /// `widths` each alone, `coverage_check` when there were repeated runs.
    pub fn new(
        measured: &MeasuredCapball,
        sources: &CapballSources,
        total: McResult,
        widths: Vec<SourceWidths>,
        coverage_check: Option<CoverageCheck>,
    ) -> CapballMcReport {
        CapballMcReport {
            kept_runs: measured.runs.iter().map(|r| r.0).collect(),
            warmup_runs: measured.warmup.clone(),
            drift_model: match &sources.drift {
                DriftModel::None => None,
                DriftModel::Cyclic(_) => Some(DriftKind::Cyclic),
                DriftModel::Statistical { .. } => Some(DriftKind::Statistical),
            },
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
        }
    }
}

/// One run's derived errors in a [`PsdMcReport`].
#[derive(Debug, Serialize)]
pub struct PsdRunResult<'a> {
    pub run: u32,
    pub errors: &'a PsdErrors,
}

/// `identify psd --uncertainty mc`: the Monte Carlo of paper 003 §5 beside the runs' errors.
#[derive(Debug, Serialize)]
pub struct PsdMcReport<'a> {
    pub reference: u32,
    pub budget: String,
    /// Per derived value (names as in `names`): half-width of the 95 % interval.
    pub names: Vec<String>,
    pub expanded_uncertainty: Vec<f64>,
    pub runs: Vec<PsdRunResult<'a>>,
    pub study: Table4Study,
}

impl<'a> PsdMcReport<'a> {
    /// The report of `study` (budget titled `budget`) for the errors of `runs` against the
    /// reference run.
    pub fn new(
        reference: u32,
        budget: String,
        runs: &'a [(u32, PsdErrors)],
        study: Table4Study,
    ) -> PsdMcReport<'a> {
        let outputs = &study.monte_carlo.outputs;
        PsdMcReport {
            reference,
            budget,
            names: outputs.iter().map(|o| o.name.clone()).collect(),
            expanded_uncertainty: outputs
                .iter()
                .map(|o| 0.5 * (o.symmetric_interval[1] - o.symmetric_interval[0]))
                .collect(),
            runs: runs
                .iter()
                .map(|(run, errors)| PsdRunResult { run: *run, errors })
                .collect(),
            study,
        }
    }
}

/// The text of a CapBall Monte Carlo: the sources, the trials, each parameter's interval
/// with the width of each source alone, and the coverage of the repeated identifications.
pub fn capball_mc_text(r: &CapballMcReport) -> String {
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

/// The text of the PSD frame Monte Carlo: Table 4 beside the published one, then each run's
/// errors with their expanded uncertainty.
pub fn psd_mc_text(r: &PsdMcReport) -> String {
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
