//! LinuxCNC screw compensation (`[JOINT_n] COMP_FILE`, `COMP_FILE_TYPE = 1`).
//!
//! Sources, read in LinuxCNC's own code (not copied):
//! - `src/emc/motion/usrmotintf.cc`, `usrmotLoadComp`: a type-1 file holds
//!   `nominal forward_trim reverse_trim` per line with `forward_trim = nominal − forward` and
//!   `reverse_trim = nominal − reverse` (forward/reverse: where the joint actually is when
//!   commanded to `nominal` moving up/down); the loader reads lines with `sscanf("%lf %lf
//!   %lf")` and **stops at the first line that is not three numbers**, so the file carries no
//!   comment or header line.
//! - `src/emc/motion/control.c`, `compute_screw_comp`: the trim of the current direction is
//!   interpolated linearly between entries, held from the nearest entry outside them, kept
//!   while the joint stands still, and `motor-pos-cmd = pos-cmd + trim (+ homing offset)`:
//!   the trims are *corrections*, the negative of the measured error.
//! - `src/emc/motion/command.c` (`EMCMOT_SET_JOINT_COMP`): nominals must increase;
//!   at most `EMCMOT_COMP_SIZE` (256) entries per joint.
//! - `docs/src/config/ini-config.adoc` `[JOINT_n]`: "If COMP_FILE is specified for a joint,
//!   BACKLASH is not used", so a backlash goes into the reverse trims.

use std::fmt::Write;

use super::{CompensationError, CompensationTable, Curve, Dialect};

const MAX_TRIPLETS: usize = 256;

/// 1 nm: the file's six decimals of mm.
fn q(v_um: f64) -> f64 {
    let v = (v_um * 1e3).round() / 1e3;
    if v == 0.0 { 0.0 } else { v }
}

pub(crate) fn write(c: &Curve) -> Result<CompensationTable, CompensationError> {
    c.check_finite()?;
    let n = c.points_mm.len();
    if n > MAX_TRIPLETS {
        return Err(CompensationError::Limit {
            dialect: Dialect::LinuxCnc,
            message: format!(
                "{n} points exceed the 256 triplets per joint: choose a larger --spacing"
            ),
        });
    }
    // Trims are corrections: nominal − actual = −error.
    let fwd: Vec<f64> = c.up_um.iter().map(|&v| q(-v)).collect();
    let rev: Vec<f64> = c.down_um.iter().map(|&v| q(-v)).collect();
    let mut comp = String::new();
    for ((p, f), r) in c.points_mm.iter().zip(&fwd).zip(&rev) {
        let _ = writeln!(comp, "{p:.6} {:.6} {:.6}", f * 1e-3, r * 1e-3);
    }
    let name = format!("{}_comp.txt", c.axis.to_ascii_lowercase());
    let j = c.axis_number - 1;
    let mut ini = format!(
        "# metrolog: screw compensation of {} (joint {j}), {n} points; {name} holds `nominal forward_trim reverse_trim` in mm, trims = nominal - actual (the correction, -measured error), 0 at the reference point {:.4} mm\n",
        c.axis, c.reference_mm
    );
    let _ = writeln!(ini, "[JOINT_{j}]\nCOMP_FILE = {name}\nCOMP_FILE_TYPE = 1");
    let mut notes = vec![
        format!("add the [JOINT_{j}] lines to the machine's INI file next to {name}"),
        format!(
            "home the joint at the reference point {:.4} mm (HOME): the table is 0 there",
            c.reference_mm
        ),
        format!(
            "do not add comment lines to {name}: LinuxCNC stops reading at the first line that is not three numbers"
        ),
    ];
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
        correction_up_um: fwd,
        correction_down_um: rev,
        backlash_um: c.backlash_um.map(q),
        files: vec![(name, comp), ("joint.ini".into(), ini)],
        notes,
    })
}
