//! LinuxCNC screw compensation (`[JOINT_n] COMP_FILE`, `COMP_FILE_TYPE`).
//!
//! Source: LinuxCNC INI configuration documentation (`docs/src/config/ini-config.adoc`,
//! `[JOINT_n]` section): triplets per line in machine units; `COMP_FILE_TYPE = 1` gives
//! "nominal forward-trim reverse-trim", the trims being how far from nominal the axis is
//! while travelling forward / in reverse (the error, actual − nominal); at most 256 triplets
//! per joint; "if COMP_FILE is specified, BACKLASH is ignored", so a backlash is written into
//! the reverse trims. Interpolation between entries is linear (motion controller).

use std::fmt::Write;

use super::{CompensationError, CompensationTable, Curve, Dialect};

const MAX_TRIPLETS: usize = 256;

fn q(v_um: f64) -> f64 {
    (v_um * 1e3).round() / 1e3
}

pub(crate) fn write(c: &Curve) -> Result<CompensationTable, CompensationError> {
    let n = c.points_mm.len();
    if n > MAX_TRIPLETS {
        return Err(CompensationError::Limit {
            dialect: Dialect::LinuxCnc,
            message: format!(
                "{n} points exceed the 256 triplets per joint: choose a larger --spacing"
            ),
        });
    }
    let up: Vec<f64> = c.up_um.iter().map(|&v| q(v)).collect();
    let down: Vec<f64> = c.down_um.iter().map(|&v| q(v)).collect();
    let mut comp = String::new();
    for ((p, u), d) in c.points_mm.iter().zip(&up).zip(&down) {
        let _ = writeln!(comp, "{p:.6} {:.6} {:.6}", u * 1e-3, d * 1e-3);
    }
    let name = format!("{}_comp.txt", c.axis.to_ascii_lowercase());
    let j = c.axis_number - 1;
    let mut ini = format!(
        "# metrolog: screw compensation of {} (joint {j}), {n} points, trims = measured error (actual - nominal) in mm, 0 at the reference point {:.4} mm\n",
        c.axis, c.reference_mm
    );
    let _ = writeln!(ini, "[JOINT_{j}]\nCOMP_FILE = {name}\nCOMP_FILE_TYPE = 1");
    let mut notes = vec![format!(
        "add the [JOINT_{j}] lines to the machine's INI file next to {name}"
    )];
    if let Some(b) = c.backlash_um {
        notes.push(format!(
            "the backlash ({:.3} µm) is in the reverse trims: LinuxCNC ignores BACKLASH when COMP_FILE is set",
            q(b)
        ));
    }
    Ok(CompensationTable {
        dialect: Dialect::LinuxCnc,
        mode: c.mode,
        reference_mm: c.reference_mm,
        points_mm: c.points_mm.clone(),
        error_up_um: up,
        error_down_um: down,
        backlash_um: c.backlash_um.map(q),
        files: vec![(name, comp), ("joint.ini".into(), ini)],
        notes,
    })
}
