//! FANUC Series 0i / 16i / 18i / 30i stored pitch error compensation.
//!
//! Sources: FANUC Series 0i-PB Parameter Manual B-63980EN/01, parameters 3620–3624: the
//! compensation values are *incremental*: the value at compensation point N is output for the
//! section between point N − 1 and point N, and the points lie at
//! reference position + (N − No.3620) × interval (No.3624); No.3621/3622 are the most
//! negative/positive point numbers, No.3623 the magnification; values are in detection units.
//! FANUC technical report A-77810E (bidirectional pitch error compensation, parameters
//! 3605#0, 3626, 3627), not written here. Backlash: No.1851, detection units. Data files are
//! FANUC parameter tapes: `%`, `N<number>A<axis>P<value>` for axis parameters, `N<10000 +
//! point>P<value>` for pitch data, `%`.
//!
//! Conventions this writer assumes and the commissioning engineer must confirm: detection
//! unit 1 µm (IS-B, metric), compensation values are corrections (−error), a value range of
//! −127…+127 per point (older controls allow −7…+7: check yours), point numbers
//! 128 × (axis − 1) … so that axes do not overlap in the 0…1023 range.

use std::fmt::Write;

use super::{CompensationError, CompensationTable, Curve, Dialect, Mode};

const UNIT_UM: f64 = 1.0;
const MAX_VALUE: f64 = 127.0;
const POINTS_PER_AXIS: usize = 128;

/// The interval must be a whole number of detection units.
pub(crate) fn spacing_mm(requested: f64) -> f64 {
    ((requested * 1e3 / UNIT_UM).round().max(1.0)) * UNIT_UM * 1e-3
}

pub(crate) fn write(c: &Curve) -> Result<CompensationTable, CompensationError> {
    let limit = |message: String| CompensationError::Limit {
        dialect: Dialect::Fanuc,
        message,
    };
    if c.mode == Mode::Bidirectional {
        return Err(CompensationError::Unsupported {
            dialect: Dialect::Fanuc,
            message: "bidirectional pitch error compensation (option, parameters 3605#0, 3626, 3627) is not written; use --backlash".into(),
        });
    }
    let n = c.points_mm.len();
    if n > POINTS_PER_AXIS {
        return Err(limit(format!(
            "{n} points exceed the {POINTS_PER_AXIS} this writer gives an axis: choose a larger --spacing"
        )));
    }
    // Corrections (−error) and their increments per section.
    let corr: Vec<f64> = c.up_um.iter().map(|e| -e).collect();
    let steps: Vec<f64> = (0..n)
        .map(|k| if k == 0 { 0.0 } else { corr[k] - corr[k - 1] })
        .collect();
    let biggest = steps.iter().fold(0.0f64, |a, s| a.max(s.abs()));
    let mag = (1..=100)
        .find(|&m| (biggest / (UNIT_UM * m as f64)).round() <= MAX_VALUE)
        .ok_or_else(|| limit(format!("a step of {biggest:.1} µm between points is beyond the magnification range: choose a smaller --spacing")))?;
    let unit = UNIT_UM * mag as f64;
    let v: Vec<i64> = steps.iter().map(|s| (s / unit).round() as i64).collect();
    // The correction the control builds from the integers, 0 at the reference point.
    let r = c.reference_index;
    let mut cq = vec![0.0; n];
    for k in r + 1..n {
        cq[k] = cq[k - 1] + v[k] as f64 * unit;
    }
    for k in (0..r).rev() {
        cq[k] = cq[k + 1] - v[k + 1] as f64 * unit;
    }
    let up: Vec<f64> = cq.iter().map(|x| -x).collect();
    let base = POINTS_PER_AXIS * (c.axis_number - 1);
    let a = c.axis_number;
    let mut pitch = String::from("%\n");
    for (k, val) in v.iter().enumerate() {
        let _ = writeln!(pitch, "N{}P{val}", 10000 + base + k);
    }
    pitch.push_str("%\n");
    let mut params = String::from("%\n");
    for (no, val) in [
        (3620, (base + r) as i64),
        (3621, base as i64),
        (3622, (base + n - 1) as i64),
        (3623, mag as i64),
        (3624, (c.spacing_mm * 1e3 / UNIT_UM).round() as i64),
    ] {
        let _ = writeln!(params, "N{no:05}A{a}P{val}");
    }
    let b_units = c.backlash_um.map(|b| (b / UNIT_UM).round() as i64);
    if let Some(b) = b_units {
        let _ = writeln!(params, "N01851A{a}P{b}");
    }
    params.push_str("%\n");
    let down = match b_units {
        Some(b) => up.iter().map(|u| u + b as f64 * UNIT_UM).collect(),
        None => up.clone(),
    };
    let notes = vec![
        format!(
            "axis {a} ({}): reference position {:.4} mm = point {}, points {}…{}, interval {:.3} mm, magnification {mag}",
            c.axis,
            c.reference_mm,
            base + r,
            base,
            base + n - 1,
            c.spacing_mm
        ),
        "input the parameters (PARAM tape) and the pitch data (PITCH tape) with parameter write enabled, then power off and on and return to the reference position".into(),
        "assumed: detection unit 1 µm, values are corrections (−error), ±127 per point; confirm on the control".into(),
    ];
    Ok(CompensationTable {
        dialect: Dialect::Fanuc,
        mode: c.mode,
        reference_mm: c.reference_mm,
        points_mm: c.points_mm.clone(),
        error_up_um: up,
        error_down_um: down,
        backlash_um: b_units.map(|b| b as f64 * UNIT_UM),
        files: vec![
            (format!("{}_PARAM.TXT", c.axis), params),
            (format!("{}_PITCH.TXT", c.axis), pitch),
        ],
        notes,
    })
}
