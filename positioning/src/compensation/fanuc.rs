//! FANUC Series 0i / 16i / 18i / 30i stored pitch error compensation.
//!
//! Source: FANUC Series 0i-PB Parameter Manual B-63980EN/01, §4 "Description of parameters",
//! Nos. 3620–3624, with the example of compensation values on p. 100 (points 33…49, reference
//! position at point 40): the values are *incremental*; the value of point N is output for
//! the section between points N − 1 and N, points lie at reference position +
//! (N − No.3620) × interval (No.3624), No.3621/3622 are the farthest points on the − and +
//! sides, No.3623 the magnification, the values are in detection units × magnification.
//! The absolute compensation at a point is the sum of the values from the reference position
//! to it (the example's "pitch error compensation amount (absolute value)" curve). A value
//! moves the axis (it is output to the servo), so the values are corrections (−error).
//! FANUC technical report A-77810E: bidirectional pitch error compensation (3605#0, 3626,
//! 3627), not written here. Backlash: No.1851, detection units, output on negative moves
//! after a reference return in the positive direction.
//!
//! The values are the running sum of the correction rounded at every point, so a slope
//! smaller than one detection unit per interval is still corrected (the remainders carry to
//! the next point); the magnification is the smallest one that keeps every value within the
//! control's per-point limit. Assumed and stated in the notes: detection unit 1 µm (IS-B,
//! metric), point numbers 128 × (axis − 1) … so that axes do not overlap.

use std::fmt::Write;

use super::{CompensationError, CompensationTable, Curve, Dialect, Mode};

const UNIT_UM: f64 = 1.0;
const POINTS_PER_AXIS: usize = 128;
/// No.3623's range.
const MAX_MAGNIFICATION: u32 = 100;

/// The interval must be a whole number of detection units.
pub(crate) fn spacing_mm(requested: f64) -> f64 {
    ((requested * 1e3 / UNIT_UM).round().max(1.0)) * UNIT_UM * 1e-3
}

fn limit(message: String) -> CompensationError {
    CompensationError::Limit {
        dialect: Dialect::Fanuc,
        message,
    }
}

/// Values per point (index k: the section k − 1 → k; index 0 holds none) for a correction
/// curve that is 0 at the reference, quantised as a running sum in units of `unit` µm.
fn values(corr: &[f64], unit: f64) -> Vec<i64> {
    let sums: Vec<i64> = corr.iter().map(|c| (c / unit).round() as i64).collect();
    (0..sums.len())
        .map(|k| if k == 0 { 0 } else { sums[k] - sums[k - 1] })
        .collect()
}

/// The smallest magnification whose values all fit the per-point limit.
fn magnification(corr: &[f64], point_limit: u32) -> Result<(u32, Vec<i64>), CompensationError> {
    for m in 1..=MAX_MAGNIFICATION {
        let v = values(corr, UNIT_UM * m as f64);
        if v.iter().all(|x| x.unsigned_abs() <= point_limit as u64) {
            return Ok((m, v));
        }
    }
    let steepest = corr
        .windows(2)
        .fold(0.0f64, |a, w| a.max((w[1] - w[0]).abs()));
    Err(limit(format!(
        "a change of {steepest:.1} µm between points needs more than {point_limit} × {MAX_MAGNIFICATION} detection units per point: choose a smaller --spacing"
    )))
}

/// The correction the control builds from the values: 0 at the reference point, the sum of
/// the values from there (the manual's absolute value).
fn absolute(v: &[i64], r: usize, unit: f64) -> Vec<f64> {
    let mut a = vec![0.0; v.len()];
    for k in r + 1..v.len() {
        a[k] = a[k - 1] + v[k] as f64 * unit;
    }
    for k in (0..r).rev() {
        a[k] = a[k + 1] - v[k + 1] as f64 * unit;
    }
    a
}

/// Refuses a table that leaves more than half of the correction in its rounding.
fn check_holds(corr: &[f64], got: &[f64], unit: f64) -> Result<(), CompensationError> {
    let biggest = corr.iter().fold(0.0f64, |a, c| a.max(c.abs()));
    let lost = corr
        .iter()
        .zip(got)
        .fold(0.0f64, |a, (c, g)| a.max((c - g).abs()));
    if lost > 0.5 * biggest {
        return Err(limit(format!(
            "the table cannot hold the correction: it is at most {biggest:.2} µm and the values, in units of {unit} µm, would leave {lost:.2} µm of it"
        )));
    }
    Ok(())
}

fn tapes(c: &Curve, v: &[i64], mag: u32, b_units: Option<i64>) -> (String, String) {
    let (n, r, a) = (v.len(), c.reference_index, c.axis_number);
    let base = POINTS_PER_AXIS * (a - 1);
    let mut pitch = String::from("%\n");
    for (k, val) in v.iter().enumerate().skip(1) {
        let _ = writeln!(pitch, "N{}P{val}", 10000 + base + k);
    }
    pitch.push_str("%\n");
    let mut params = String::from("%\n");
    for (no, val) in [
        (3620, (base + r) as i64),
        (3621, (base + 1) as i64),
        (3622, (base + n - 1) as i64),
        (3623, mag as i64),
        (3624, (c.spacing_mm * 1e3 / UNIT_UM).round() as i64),
    ] {
        let _ = writeln!(params, "N{no:05}A{a}P{val}");
    }
    if let Some(b) = b_units {
        let _ = writeln!(params, "N01851A{a}P{b}");
    }
    params.push_str("%\n");
    (params, pitch)
}

pub(crate) fn write(c: &Curve, point_limit: u32) -> Result<CompensationTable, CompensationError> {
    c.check_finite()?;
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
    if n < 2 {
        return Err(limit("a table needs two points or more".into()));
    }
    let corr: Vec<f64> = c.up_um.iter().map(|e| -e).collect();
    let (mag, v) = magnification(&corr, point_limit)?;
    let unit = UNIT_UM * mag as f64;
    let up = absolute(&v, c.reference_index, unit);
    check_holds(&corr, &up, unit)?;
    let b_units = c.backlash_um.map(|b| (b / UNIT_UM).round() as i64);
    let (params, pitch) = tapes(c, &v, mag, b_units);
    let down = match b_units {
        Some(b) => up.iter().map(|u| u - b as f64 * UNIT_UM).collect(),
        None => up.clone(),
    };
    let base = POINTS_PER_AXIS * (c.axis_number - 1);
    let notes = vec![
        format!(
            "axis {} ({}): reference position {:.4} mm = point {}, points {}…{} (the first section starts at {:.4} mm), interval {:.3} mm, magnification {mag}",
            c.axis_number,
            c.axis,
            c.reference_mm,
            base + c.reference_index,
            base + 1,
            base + n - 1,
            c.points_mm[0],
            c.spacing_mm
        ),
        "input the parameters (PARAM tape) and the pitch data (PITCH tape) with parameter write enabled, then power off and on and return to the reference position".into(),
        format!("assumed: detection unit 1 µm, ±{point_limit} per point (give the model's limit with --point-limit); confirm on the control"),
    ];
    Ok(CompensationTable {
        dialect: Dialect::Fanuc,
        mode: c.mode,
        reference_mm: c.reference_mm,
        points_mm: c.points_mm.clone(),
        correction_up_um: up,
        correction_down_um: down,
        backlash_um: b_units.map(|b| b as f64 * UNIT_UM),
        files: vec![
            (format!("{}_PARAM.TXT", c.axis), params),
            (format!("{}_PITCH.TXT", c.axis), pitch),
        ],
        notes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn remainders_carry_so_a_small_slope_is_kept() {
        // 20 µm/m at 10 mm: 0.2 µm per section, every single increment rounds to 0.
        let corr: Vec<f64> = (0..101).map(|k| -0.2 * k as f64).collect();
        let v = values(&corr, 1.0);
        assert_eq!(v.iter().sum::<i64>(), -20);
        let a = absolute(&v, 0, 1.0);
        assert!(a.iter().zip(&corr).all(|(a, c)| (a - c).abs() <= 0.5));
    }

    #[test]
    fn magnification_keeps_values_within_the_limit() {
        let corr: Vec<f64> = (0..11).map(|k| 20.0 * k as f64).collect();
        let (m, v) = magnification(&corr, 7).unwrap();
        assert_eq!(m, 3, "{v:?}");
        assert!(v.iter().all(|x| x.abs() <= 7));
        assert!(magnification(&corr, 0).is_err());
    }
}
