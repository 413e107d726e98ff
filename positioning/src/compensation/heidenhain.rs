//! HEIDENHAIN TNC nonlinear axis error compensation (compensation value table `*.COM`,
//! assigned to the axis in a `*.CMA` file, enabled per axis by MP730).
//!
//! Sources: HEIDENHAIN TNC 407/415/425 Technical Manual (01.98) §"Nonlinear axis error
//! compensation": one `.COM` table per axis assigned in the `.CMA` file, at most 256 entries
//! per table, point spacing a power of two (example 2^16 → 6.5536 mm, i.e. in 0.1 µm units);
//! TNC 335/360 Technical Manual: "the error curve must always start with correction value = 0
//! at the datum point" and continues in the positive direction; the entries are the error
//! curve (error, mm). MANUALplus 620 Technical Manual: columns AXISPOS (compensation points
//! from the machine datum), one column named after the compensated axis, and BACKLASH for
//! the values measured in the negative direction of traverse.
//!
//! The exact column layout of the `.COM` file written here (`NR AXISPOS <axis> BACKLASH`,
//! `BEGIN`/`[END]` lines as in other TNC tables) was not checked against a control's own
//! export: compare with one before loading.

use std::fmt::Write;

use super::{CompensationError, CompensationTable, Curve, Dialect, Mode};

const MAX_POINTS: usize = 256;

/// The largest power of two of 0.1 µm not above the requested spacing.
pub(crate) fn spacing_mm(requested: f64) -> f64 {
    let units = (requested * 1e4).max(1.0);
    2f64.powi(units.log2().floor() as i32) * 1e-4
}

fn q(v_um: f64) -> f64 {
    (v_um * 10.0).round() / 10.0
}

pub(crate) fn write(c: &Curve) -> Result<CompensationTable, CompensationError> {
    let n = c.points_mm.len();
    if n > MAX_POINTS {
        return Err(CompensationError::Limit {
            dialect: Dialect::Heidenhain,
            message: format!("{n} points exceed the 256 per .COM table: choose a larger --spacing"),
        });
    }
    // The curve starts at the datum (first point) with 0: shift by the first value (a constant
    // does not change the positioning result).
    let (u0, bidir) = (c.up_um[0], c.mode == Mode::Bidirectional);
    let up: Vec<f64> = c.up_um.iter().map(|v| q(v - u0)).collect();
    let down: Vec<f64> = if bidir {
        c.down_um.iter().map(|v| q(v - u0)).collect()
    } else {
        up.clone()
    };
    let ax = c.axis.to_ascii_uppercase();
    let mut com = format!("BEGIN {ax}.COM MM\nNR AXISPOS {ax}");
    com.push_str(if bidir { " BACKLASH\n" } else { "\n" });
    for (i, p) in c.points_mm.iter().enumerate() {
        let _ = write!(com, "{i} {p:+.4} {:+.4}", up[i] * 1e-3);
        if bidir {
            let _ = write!(com, " {:+.4}", down[i] * 1e-3);
        }
        com.push('\n');
    }
    com.push_str("[END]\n");
    let cma = format!("BEGIN AXISCOMP.CMA\nNR {ax}\n0 {ax}.COM\n[END]\n");
    let mut notes = vec![
        format!(
            "datum {:+.4} mm (first point), spacing {:.4} mm = 2^{} × 0.1 µm, {n} points",
            c.points_mm[0],
            c.spacing_mm,
            (c.spacing_mm * 1e4).log2().round()
        ),
        format!(
            "assign {ax}.COM in the .CMA file and set the {ax} bit of MP730 (nonlinear compensation)"
        ),
    ];
    let down = match c.backlash_um {
        Some(b) => {
            notes.push(format!(
                "enter the backlash {:.4} mm in the control's backlash compensation (MP710 on TNC 4xx)",
                q(b) * 1e-3
            ));
            up.iter().map(|u| u + q(b)).collect()
        }
        None => down,
    };
    Ok(CompensationTable {
        dialect: Dialect::Heidenhain,
        mode: c.mode,
        reference_mm: c.points_mm[0],
        points_mm: c.points_mm.clone(),
        error_up_um: up,
        error_down_um: down,
        backlash_um: c.backlash_um.map(q),
        files: vec![(format!("{ax}.COM"), com), ("AXISCOMP.CMA".into(), cma)],
        notes,
    })
}
