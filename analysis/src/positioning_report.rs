//! The evaluation of a positioning run as `analyze positioning` reports it: ISO 230-2 results,
//! thermal-drift elimination (Stejskal et al. 2017), the LI-80 length budget per target, and
//! the text rendering of all of it.

use std::fmt::Write as _;

use positioning::conformance::{self, Conformance, Decision, Tolerance};
use positioning::drift::{self, DriftReport};
use positioning::iso230::{self, Iso230Report};
use positioning::iso230_uncertainty::{self, Iso230Uncertainty, Origin, Sensor, Setup};
use positioning::positioning_data::{PositioningData, dir_sign};

/// Everything `analyze positioning` computes.
#[derive(Debug, Clone, serde::Serialize)]
pub struct PositioningAnalysis {
    pub axis: Option<String>,
    pub n_cycles: usize,
    pub n_targets: usize,
    /// Readings absent from the run: `cycle`, `direction`, `index`.
    pub missing: Vec<MissingReading>,
    /// ISO 230-2 axis results, µm.
    pub iso230_2: iso230::AxisStats,
    /// ISO 230-2 per-target results, µm.
    pub targets: Vec<iso230::TargetStats>,
    pub drift_elimination: DriftReport,
    /// Uncertainty (k = 2) of the results E, M, A, B, R from the contributors ISO 230-2
    /// Annex A / ISO/TR 230-9 name, each recorded, assumed (with its source) or missing
    /// (`positioning::iso230_uncertainty`).
    pub uncertainty: Iso230Uncertainty,
    /// ISO 14253-1 decisions of the results a tolerance was given for ([`decide_tolerances`]).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub conformance: Vec<ResultConformance>,
    pub notes: Vec<String>,
    /// Where the log the data came from is damaged: the results are built on part of the run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub log_damage: Option<String>,
}

/// What measured the positions, from the dataset's metadata: `sensor` (a log's positions are
/// the interferometer's: its reader sets it), else an `instrument*` / `reference` value that
/// names an interferometer, else the `reference` (the measuring device). Anything else is another sensor, by the name it is given: nothing
/// of an interferometer's budget (air compensation, dead path) is applied to it.
pub fn sensor_of(data: &PositioningData) -> Sensor {
    let m = &data.metadata;
    let named = m.get("sensor").cloned().or_else(|| {
        m.iter()
            .find(|(k, v)| {
                (k.starts_with("instrument") || k.as_str() == "reference")
                    && v.to_lowercase().contains("interferometer")
            })
            .map(|(_, v)| v.clone())
            .or_else(|| m.get("reference").cloned())
    });
    match named {
        Some(n) if n.to_lowercase().contains("interferometer") => Sensor::LaserInterferometer,
        Some(n) => Sensor::Other(n),
        None => Sensor::Other("not stated (no `sensor` metadata)".into()),
    }
}

/// The budget of the run's results with what the dataset records ([`Setup::from_data`]) and
/// the values the operator gives (`assumed`, applied over the recorded ones).
pub fn uncertainty_of(
    data: &PositioningData,
    iso: &Iso230Report,
    assumed: impl FnOnce(&mut Setup),
) -> Iso230Uncertainty {
    let mut setup = Setup::from_data(sensor_of(data), data);
    assumed(&mut setup);
    iso230_uncertainty::evaluate(data, iso, &setup)
}

/// The ISO 14253-1 decision of one result against its tolerance (upper limit, µm).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ResultConformance {
    pub parameter: String,
    pub tolerance_um: f64,
    /// `None` when the run does not define the result (e.g. R from one cycle).
    pub decision: Option<Conformance>,
    /// Contributors missing from U: a pass is then not proven by a complete budget.
    pub missing: Vec<String>,
    pub reason: String,
}

/// The rule the decisions follow, for the report.
pub const DECISION_RULE: &str = "ISO 14253-1:2017 default rule: conformance (pass) is proven \
    when the result lies below its tolerance by at least its expanded uncertainty U (k = 2), \
    non-conformance (fail) when it exceeds the tolerance by more than U; within U of the limit \
    the result is not decidable";

/// Decide each `(symbol, tolerance)` (E, M, A, B or R; an upper limit in the deviation unit).
pub fn decide_tolerances(
    an: &PositioningAnalysis,
    tolerances: &[(String, f64)],
) -> Vec<ResultConformance> {
    tolerances
        .iter()
        .map(|(p, t)| {
            let r = an.uncertainty.results.iter().find(|r| &r.parameter == p);
            let decision = r.and_then(|r| {
                conformance::decide(r.value_um?, Tolerance::upper(*t), r.expanded_um).ok()
            });
            let missing = r.map(|r| r.missing.clone()).unwrap_or_default();
            let mut reason = match &decision {
                Some(d) => d.reason.clone(),
                None => format!("{p} is not defined for this run: no decision"),
            };
            if decision.as_ref().is_some_and(|d| d.decision == Decision::Pass) && !missing.is_empty() {
                reason.push_str(&format!(
                    "; U is a lower bound ({} missing): the pass holds for the known contributors only",
                    missing.join(", ")
                ));
            }
            ResultConformance {
                parameter: p.clone(),
                tolerance_um: *t,
                decision,
                missing,
                reason,
            }
        })
        .collect()
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct MissingReading {
    pub cycle: usize,
    pub direction: &'static str,
    pub index: usize,
}

/// The analysis of a run (pure; what `demo` and `replay` can call too).
/// One row of the ISO 230-2 results block the charts carry (the report's SVG chart and the
/// `--plot` charts): the standard's symbol, a short name and the value in µm with two
/// decimals as [`crate::export::num`] prints it ("—" when the run does not define it).
#[derive(Debug, Clone, PartialEq)]
pub struct ResultRow {
    pub symbol: &'static str,
    pub name: &'static str,
    pub value: String,
}

impl PositioningAnalysis {
    /// The results block A, E, R, B, M of ISO 230-2 (`docs/methods.md`), from `iso230_2`.
    pub fn results_block(&self) -> Vec<ResultRow> {
        let a = &self.iso230_2;
        [
            ("A", "accuracy", a.a),
            ("E", "systematic deviation", a.e),
            ("R", "repeatability", a.r),
            ("B", "reversal value", a.b),
            ("M", "range of mean deviation", a.m),
        ]
        .into_iter()
        .map(|(symbol, name, v)| ResultRow {
            symbol,
            name,
            value: v
                .map(|v| crate::export::num(v, 2))
                .unwrap_or_else(|| "—".into()),
        })
        .collect()
    }
}

pub fn analyze_positioning(
    data: &PositioningData,
    reference_cycle: Option<usize>,
) -> PositioningAnalysis {
    analyze_positioning_given(data, reference_cycle, |_| {})
}

/// [`analyze_positioning`] with contributors the operator gives (`assumed`, applied to the
/// budget's [`Setup`] over what the dataset records).
pub fn analyze_positioning_given(
    data: &PositioningData,
    reference_cycle: Option<usize>,
    assumed: impl FnOnce(&mut Setup),
) -> PositioningAnalysis {
    let iso: Iso230Report = iso230::evaluate(data);
    let ref_cycle = reference_cycle.unwrap_or_else(|| drift::default_reference_cycle(data));
    let drift = drift::eliminate(data, ref_cycle);
    let missing: Vec<MissingReading> = data
        .missing()
        .into_iter()
        .map(|(cycle, d, index)| MissingReading {
            cycle,
            direction: dir_sign(d),
            index,
        })
        .collect();
    let mut notes = Vec::new();
    let log_damage = data
        .metadata
        .get(positioning::positioning_data::LOG_DAMAGE_KEY)
        .cloned();
    if !missing.is_empty() {
        let why = if log_damage.is_some() {
            "lost with the damaged part of the log, or a beam interruption"
        } else {
            "beam interruption?"
        };
        notes.push(format!(
            "{} reading(s) missing ({why}); the statistics of those targets use the remaining \
             cycles",
            missing.len()
        ));
    }
    for key in [
        crate::positioning::DATUM_NOTE_KEY,
        crate::positioning::OFF_TARGET_NOTE_KEY,
    ] {
        if let Some(n) = data.metadata.get(key) {
            notes.push(n.clone());
        }
    }
    if !data.has_times {
        notes.push(
            "no time_s column: row order stands in for time; the default reference cycle is the \
             last one (the 2-hour warm-up rule needs real times)"
                .into(),
        );
    }
    if let Some(n) = data.direction_target_note() {
        notes.push(n);
    }
    if data.n_cycles() < 2 {
        notes.push(
            "a single pass per direction: the repeatability values (s, R↑, R↓, R, A and the \
             expanded uncertainties) need repeated approaches and are not given; the mean \
             deviations, B, E and M are from single readings"
                .into(),
        );
    }
    if data.n_cycles() < 5 {
        notes.push(format!(
            "ISO 230-2 asks for at least 5 cycles; this run has {}",
            data.n_cycles()
        ));
    }
    let uncertainty = uncertainty_of(data, &iso, assumed);
    PositioningAnalysis {
        axis: data.axis.clone(),
        n_cycles: data.n_cycles(),
        n_targets: data.n_targets(),
        missing,
        iso230_2: iso.axis,
        targets: iso.targets,
        drift_elimination: drift,
        uncertainty,
        conformance: Vec::new(),
        notes,
        log_damage,
    }
}

thread_local! {
    // Decimals of the tables: enough for three significant digits of the run's scatter
    // (a nanometre stage and a large machine both read well).
    static DECIMALS: std::cell::Cell<usize> = const { std::cell::Cell::new(2) };
}

fn f(v: Option<f64>, w: usize) -> String {
    let p = DECIMALS.with(|d| d.get());
    // A value that is not finite (a ratio over a zero scatter) is not determined: "—", as a
    // value that could not be computed at all.
    match v.filter(|v| v.is_finite()) {
        Some(v) => format!("{v:>w$.p$}"),
        None => format!("{:>w$}", "—"),
    }
}

fn choose_decimals(an: &PositioningAnalysis) -> usize {
    let smallest = an
        .targets
        .iter()
        .flat_map(|t| [t.s_up_um, t.s_down_um])
        .flatten()
        .filter(|s| *s > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !smallest.is_finite() {
        return 2;
    }
    (2.0 - smallest.log10().floor()).clamp(2.0, 5.0) as usize
}

/// The human-readable report.
pub fn render_text(an: &PositioningAnalysis) -> String {
    DECIMALS.with(|d| d.set(choose_decimals(an)));
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Positioning accuracy (ISO 230-2), axis {}: {} cycles × {} targets, bidirectional",
        an.axis.as_deref().unwrap_or("?"),
        an.n_cycles,
        an.n_targets
    );
    if let Some(d) = &an.log_damage {
        let _ = writeln!(
            s,
            "BUILT ON PART OF THE RUN: the log is damaged: {d}; what follows uses the readings \
             before the damage only"
        );
    }
    if !an.missing.is_empty() {
        let list: Vec<String> = an
            .missing
            .iter()
            .map(|m| format!("cycle {} {} target {}", m.cycle, m.direction, m.index))
            .collect();
        let _ = writeln!(s, "Missing readings ({}): {}", list.len(), list.join(", "));
    }
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "{:>3} {:>10} {:>3} {:>3} {:>8} {:>8} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "i", "target", "n↑", "n↓", "x̄↑", "x̄↓", "s↑", "s↓", "B_i", "R↑_i", "R↓_i", "R_i", "x̄_i"
    );
    let _ = writeln!(
        s,
        "{:>3} {:>10} {:>3} {:>3} {:>8} {:>8} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "", "mm", "", "", "µm", "µm", "µm", "µm", "µm", "µm", "µm", "µm", "µm"
    );
    for t in &an.targets {
        let _ = writeln!(
            s,
            "{:>3} {:>10.3} {:>3} {:>3} {} {} {} {} {} {} {} {} {}",
            t.index,
            t.target_mm,
            t.n_up,
            t.n_down,
            f(t.mean_up_um, 8),
            f(t.mean_down_um, 8),
            f(t.s_up_um, 7),
            f(t.s_down_um, 7),
            f(t.b_um, 8),
            f(t.r_up_um, 8),
            f(t.r_down_um, 8),
            f(t.r_um, 8),
            f(t.mean_um, 8)
        );
    }
    let a = &an.iso230_2;
    let _ = writeln!(s, "\nAxis (µm):");
    let rows = [
        ("B", "reversal value", a.b),
        ("B̄", "mean reversal value", a.b_mean),
        ("R↑", "unidirectional repeatability +", a.r_up),
        ("R↓", "unidirectional repeatability −", a.r_down),
        ("R", "bidirectional repeatability", a.r),
        ("E↑", "unidirectional systematic deviation +", a.e_up),
        ("E↓", "unidirectional systematic deviation −", a.e_down),
        ("E", "bidirectional systematic deviation", a.e),
        ("M", "range of mean bidirectional deviation", a.m),
        ("A↑", "unidirectional accuracy +", a.a_up),
        ("A↓", "unidirectional accuracy −", a.a_down),
        ("A", "bidirectional accuracy", a.a),
    ];
    for (sym, name, v) in rows {
        let _ = writeln!(s, "  {sym:<3} {name:<40} {} µm", f(v, 8));
    }
    render_uncertainty(&mut s, an);
    render_drift(&mut s, an);
    for n in an.drift_elimination.notes.iter().chain(&an.notes) {
        let _ = writeln!(s, "Note: {n}");
    }
    s
}

/// How a contributor's origin reads in a report: its status and its note.
pub fn origin_text(o: &Origin) -> (&'static str, &str) {
    match o {
        Origin::Recorded(n) => ("recorded", n),
        Origin::Assumed(n) => ("assumed", n),
        Origin::Missing(n) => ("MISSING", n),
        Origin::NotApplicable(n) => ("not applicable", n),
    }
}

/// The sentence under a budget with missing contributors, `None` when complete.
pub fn lower_bound_note(u: &Iso230Uncertainty) -> Option<String> {
    let missing: Vec<&str> = u
        .contributors
        .iter()
        .filter(|c| matches!(c.origin, Origin::Missing(_)))
        .map(|c| c.symbol.as_str())
        .collect();
    (!missing.is_empty()).then(|| {
        format!(
            "{} not recorded and not given: U is a lower bound (the uncertainty of the known \
             contributors only)",
            missing.join(", ")
        )
    })
}

/// The sensor's name for a report.
pub fn sensor_text(s: &Sensor) -> String {
    match s {
        Sensor::LaserInterferometer => "laser interferometer".into(),
        Sensor::Other(n) => n.clone(),
    }
}

/// The uncertainty budget of the results and the decisions, as text.
fn render_uncertainty(s: &mut String, an: &PositioningAnalysis) {
    let u = &an.uncertainty;
    let _ = writeln!(
        s,
        "\nUncertainty of the results (ISO 230-2 Annex A / ISO/TR 230-9), sensor: {}, measured \
         length L = {:.3} mm:",
        sensor_text(&u.sensor),
        u.length_mm
    );
    for c in &u.contributors {
        let (status, note) = origin_text(&c.origin);
        let _ = writeln!(
            s,
            "  {:<15} {} µm  {status}: {note}",
            c.symbol,
            f(c.u_um, 8)
        );
    }
    for r in &u.results {
        let _ = writeln!(
            s,
            "  {} = {} µm, U (k = {}) = {} µm{}",
            r.parameter,
            f(r.value_um, 0).trim(),
            r.k,
            f(Some(r.expanded_um), 0).trim(),
            if r.missing.is_empty() {
                String::new()
            } else {
                format!(" (lower bound: {} missing)", r.missing.join(", "))
            }
        );
    }
    if let Some(n) = lower_bound_note(u) {
        let _ = writeln!(s, "  {n}");
    }
    if !an.conformance.is_empty() {
        let _ = writeln!(s, "\nConformance ({DECISION_RULE}):");
        for c in &an.conformance {
            let _ = writeln!(
                s,
                "  {} ≤ {} µm: {} — {}",
                c.parameter,
                crate::export::num(c.tolerance_um, 3),
                c.decision
                    .as_ref()
                    .map_or("no decision", |d| d.decision.label()),
                c.reason
            );
        }
    }
}

/// The thermal-drift elimination part of the text report.
fn render_drift(s: &mut String, an: &PositioningAnalysis) {
    let d = &an.drift_elimination;
    let _ = writeln!(
        s,
        "\nThermal-drift elimination (Stejskal et al. 2017, adjacent-target differences, eq. 4–6)"
    );
    let _ = writeln!(
        s,
        "  borders ±k·s_diff with k = {:.2}{}",
        d.k,
        if d.n_cycles < 30 {
            format!(" (Student t, {} cycles < 30)", d.n_cycles)
        } else {
            String::new()
        }
    );
    for dd in &d.directions {
        render_drift_direction(s, an, dd);
    }
    if d.anomalous_targets.is_empty() {
        let _ = writeln!(s, "\n  No target's adjacent-difference scatter stands out.");
    } else {
        let _ = writeln!(
            s,
            "\n  ANOMALY at target(s) {:?}: the adjacent-difference scatter stands out — a local \
             heat source or a structural fault near there",
            d.anomalous_targets
        );
    }
}

/// One direction's adjacent-target differences and drift-free chart.
fn render_drift_direction(s: &mut String, an: &PositioningAnalysis, dd: &drift::DirectionDrift) {
    let sign = dir_sign(dd.direction);
    let _ = writeln!(
        s,
        "\n  direction {sign}, chart anchored on target 1 of cycle {}",
        dd.reference_cycle
            .map(|c| c.to_string())
            .unwrap_or_else(|| "—".into())
    );
    let _ = writeln!(
        s,
        "  {:>7} {:>11} {:>9} {:>13} {:>11} {:>7}   {:>3} {:>11} {:>9}",
        "pair", "x̄_i−x̄_i+1", "s_diff", "s classic", "ratio", "stands", "i", "drift-free", "±border"
    );
    let _ = writeln!(
        s,
        "  {:>7} {:>11} {:>9} {:>13} {:>11} {:>7}   {:>3} {:>11} {:>9}",
        "", "µm", "µm", "µm (i+1)", "classic/df", "out", "", "µm", "µm"
    );
    let classic = |i: usize| {
        an.targets.get(i).and_then(|t| {
            if dd.direction == positioning::axis_model::Direction::Up {
                t.s_up_um
            } else {
                t.s_down_um
            }
        })
    };
    for (k, pt) in dd.chart.iter().enumerate() {
        if k == 0 {
            let _ = writeln!(
                s,
                "  {:>7} {:>11} {:>9} {:>13} {:>11} {:>7}   {:>3} {} {}",
                "",
                "",
                "",
                "",
                "",
                "",
                pt.index,
                f(pt.deviation_um, 11),
                f(pt.border_um, 9)
            );
            continue;
        }
        let p = &dd.pairs[k - 1];
        let _ = writeln!(
            s,
            "  {:>7} {} {} {} {} {:>7}   {:>3} {} {}",
            format!("{}–{}", p.index, p.index + 1),
            f(p.mean_diff_um, 11),
            f(p.s_diff_um, 9),
            f(classic(k), 13),
            f(p.ratio_classic_to_drift_free, 11),
            if p.stands_out { "YES" } else { "" },
            pt.index,
            f(pt.deviation_um, 11),
            f(pt.border_um, 9)
        );
    }
    if let Some(r) = dd.mean_ratio {
        let r = crate::export::result_or(r, 2, "the drift-free differences do not scatter");
        let _ = writeln!(
            s,
            "  mean classic s / mean drift-free s_diff = {r} (≈ 0.71 = 1/√2 without drift: a difference of two readings scatters √2 times more)"
        );
    }
}
