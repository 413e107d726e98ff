//! HEIDENHAIN nonlinear axis error compensation, MANUALplus 620 generation (the controls
//! configured with machine parameters of the `CfgAxes` / `MP_refPosition` kind; the TNC 4xx
//! generation with MP730 and power-of-two spacing is **not** what this writes).
//!
//! Source: HEIDENHAIN Technical Manual MANUALplus 620, "Nonlinear axis error compensation",
//! pp. 716–718: a compensation-value table `*.COM` per axis with the column AXISPOS (the
//! compensation points, with respect to the machine datum `MP_refPosition`), a column named
//! after the compensated axis (its key in `CfgAxes/axisList`) holding the compensation values,
//! and, if required, BACKLASH holding the values measured in the negative direction of
//! traverse; the spacing is free (the manual's example: Y from −90 mm and Z from −200 mm,
//! 5 mm spacing, 500 mm / 5 mm = 100 and 800 mm / 5 mm = 160 compensation points); the tables
//! are assigned in a `*.CMA` table (standard name `config.cma`) with one column per axis
//! holding the `.COM` names, and a line is activated with `*` in its ACTIVE column.
//!
//! Not stated on those pages, and assumed here (confirm on the control before loading): the
//! values are the error (actual − nominal, as measured, like the TNC 4xx "error curve"), the
//! control interpolates linearly between points, and the file layout is the TNC table format
//! (`BEGIN … MM`, column header, rows, `[END]`).

use std::fmt::Write;

use super::{CompensationError, CompensationTable, Curve, Dialect, Mode};

fn q(v_um: f64) -> f64 {
    let v = (v_um * 10.0).round() / 10.0;
    if v == 0.0 { 0.0 } else { v }
}

pub(crate) fn write(c: &Curve) -> Result<CompensationTable, CompensationError> {
    c.check_finite()?;
    let n = c.points_mm.len();
    let up: Vec<f64> = c.up_um.iter().map(|&v| q(v)).collect();
    let down: Vec<f64> = c.down_um.iter().map(|&v| q(v)).collect();
    let with_down = c.mode != Mode::Mean;
    let ax = c.axis.to_ascii_uppercase();
    let mut com = format!("BEGIN {ax}.COM MM\nNR AXISPOS {ax}");
    com.push_str(if with_down { " BACKLASH\n" } else { "\n" });
    for (i, p) in c.points_mm.iter().enumerate() {
        let _ = write!(com, "{i} {p:+.4} {:+.4}", up[i] * 1e-3);
        if with_down {
            let _ = write!(com, " {:+.4}", down[i] * 1e-3);
        }
        com.push('\n');
    }
    com.push_str("[END]\n");
    let cma = format!("BEGIN CONFIG.CMA\nNR ACTIVE {ax}\n0 * {ax}.COM\n[END]\n");
    let notes = vec![
        format!(
            "MANUALplus 620 generation: AXISPOS from the machine datum, {n} points from {:+.4} mm, spacing {:.4} mm, 0 at the reference point {:+.4} mm",
            c.points_mm[0], c.spacing_mm, c.reference_mm
        ),
        format!(
            "enter {ax}.COM in the {ax} column of config.cma and mark the line ACTIVE (*); the column names must be the axis keys of CfgAxes/axisList"
        ),
        "assumed, not stated in the manual pages read: values = error (actual − nominal) in mm, linear interpolation; compare with a table exported by the control before loading".into(),
    ];
    let corr_up: Vec<f64> = up.iter().map(|v| -v).collect();
    let corr_down: Vec<f64> = if with_down {
        down.iter().map(|v| -v).collect()
    } else {
        corr_up.clone()
    };
    Ok(CompensationTable {
        dialect: Dialect::Heidenhain,
        mode: c.mode,
        reference_mm: c.reference_mm,
        points_mm: c.points_mm.clone(),
        correction_up_um: corr_up,
        correction_down_um: corr_down,
        backlash_um: c.backlash_um.map(q),
        files: vec![(format!("{ax}.COM"), com), ("config.cma".into(), cma)],
        notes,
    })
}
