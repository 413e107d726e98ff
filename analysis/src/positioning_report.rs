//! The evaluation of a positioning run as `analyze positioning` reports it: ISO 230-2 results,
//! thermal-drift elimination (Stejskal et al. 2017), the LI-80 length budget per target, and
//! the text rendering of all of it.

use std::fmt::Write as _;

use positioning::drift::{self, DriftReport};
use positioning::iso230::{self, Iso230Report};
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
    /// Uncertainty of one LI-80 reading at each target (ISO/TR 230-9 style length budget).
    pub measurement_uncertainty: Option<MeasurementUncertainty>,
    pub notes: Vec<String>,
}

/// The LI-80 length budget attached to the ISO 230-2 results: the uncertainty of a single
/// compensated reading at each target from the environment sensors, the expansion coefficient,
/// the dead path and the cosine error (`uncertainty::length`). The budget's sensor
/// accuracies are the defaults documented there; the material temperature and α are the run's.
#[derive(Debug, Clone, serde::Serialize)]
pub struct MeasurementUncertainty {
    pub budget: uncertainty::length::LengthBudget,
    /// Per target (in target order): standard uncertainty u and expanded U (k = 2), µm.
    pub u_um: Vec<f64>,
    #[serde(rename = "U_k2_um")]
    pub u_k2_um: Vec<f64>,
}

fn measurement_uncertainty(data: &PositioningData) -> Option<MeasurementUncertainty> {
    // A length budget of a laser interferometer: nothing to say for other units (a rotary
    // axis in degrees).
    if !data.units().is_default() {
        return None;
    }
    let mut budget = uncertainty::length::LengthBudget::default();
    if let Some(a) = data.alpha_um_per_m_k {
        budget.alpha_per_k = a * 1e-6;
    }
    let temps: Vec<f64> = data.readings.iter().filter_map(|r| r.material_c).collect();
    if !temps.is_empty() {
        budget.material_temp_c = temps.iter().sum::<f64>() / temps.len() as f64;
    }
    let mut targets: Vec<(usize, f64)> = data
        .readings
        .iter()
        .map(|r| (r.index, r.target_mm))
        .collect();
    targets.sort_by_key(|t| t.0);
    targets.dedup_by_key(|t| t.0);
    let u_um: Vec<f64> = targets
        .iter()
        .map(|t| budget.standard_uncertainty_um(t.1.abs()).ok())
        .collect::<Option<Vec<f64>>>()?;
    let u_k2_um = u_um.iter().map(|u| 2.0 * u).collect();
    Some(MeasurementUncertainty {
        budget,
        u_um,
        u_k2_um,
    })
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
    if !missing.is_empty() {
        notes.push(format!(
            "{} reading(s) missing (beam interruption?); the statistics of those targets use \
             the remaining cycles",
            missing.len()
        ));
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
    PositioningAnalysis {
        axis: data.axis.clone(),
        n_cycles: data.n_cycles(),
        n_targets: data.n_targets(),
        missing,
        iso230_2: iso.axis,
        targets: iso.targets,
        drift_elimination: drift,
        measurement_uncertainty: measurement_uncertainty(data),
        notes,
    }
}

thread_local! {
    // Decimals of the tables: enough for three significant digits of the run's scatter
    // (a nanometre stage and a large machine both read well).
    static DECIMALS: std::cell::Cell<usize> = const { std::cell::Cell::new(2) };
}

fn f(v: Option<f64>, w: usize) -> String {
    let p = DECIMALS.with(|d| d.get());
    match v {
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
    if let Some(mu) = an
        .measurement_uncertainty
        .as_ref()
        .filter(|m| !m.u_k2_um.is_empty())
    {
        let max = mu.u_k2_um.iter().copied().fold(0.0, f64::max);
        let min = mu.u_k2_um.iter().copied().fold(f64::INFINITY, f64::min);
        let _ = writeln!(
            s,
            "\nUncertainty of one LI-80 reading (ISO/TR 230-9 style budget, α {:.1} µm/(m·K), \
             material {:.2} °C): U (k = 2) from {min:.2} to {max:.2} µm over the targets \
             (per target in --json: measurement_uncertainty)",
            mu.budget.alpha_per_k * 1e6,
            mu.budget.material_temp_c
        );
    }
    render_drift(&mut s, an);
    for n in an.drift_elimination.notes.iter().chain(&an.notes) {
        let _ = writeln!(s, "Note: {n}");
    }
    s
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
        let _ = writeln!(
            s,
            "  mean classic s / mean drift-free s_diff = {r:.2} (≈ 0.71 = 1/√2 without drift: a difference of two readings scatters √2 times more)"
        );
    }
}
