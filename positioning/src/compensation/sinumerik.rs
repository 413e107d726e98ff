//! SINUMERIK 840D sl / 828D / 808D leadscrew error compensation (LEC, "SSFK").
//!
//! Source: SINUMERIK 840D sl Function Manual Extended Functions, K3 Compensation, §4.4.2
//! "Measuring system error compensation / LEC" and its example §4.4.2.3, p. 242, for the
//! machine axis `X1` (6FC5397-1BP40-3BA1, 03/2013):
//! file `%_N_AX_EEC_INI` under `CHANDATA(1)`, `$AA_ENC_COMP[e,N,axis]` (compensation value in
//! mm at interpolation point N of encoder e), `$AA_ENC_COMP_STEP`, `_MIN`, `_MAX`,
//! `_IS_MODULO`, ended by `M17`; point N lies at `_MIN + N·_STEP`, the last at `_MAX`
//! (example: 801 points from −200 to +600 mm, step 1 mm, MD38000 ≥ 801); the compensation
//! curve is the linear interpolation between points (the example's figure); MD38000
//! `$MA_MM_ENC_COMP_MAX_POINTS` ≥ number of points (power on, reformats the static memory);
//! tables load only while MD32700 `$MA_ENC_COMP_ENABLE` = 0, then MD32700 = 1 enables them.
//! SINUMERIK 808D Function Manual (01/2017): the compensation modifies the actual value, "a
//! positive compensation value causes the machine axis to move in the negative direction",
//! so the table holds the error (actual − nominal); the value at the reference point should
//! be zero; up to 200 points on the 808D. Backlash: MD32450 `$MA_BACKLASH` (mm, positive in
//! the normal case where the machine lags the encoder on reversal).

use std::fmt::Write;

use super::{CompensationError, CompensationTable, Curve, Dialect, Mode};

/// 1 nm: the file's six decimals of mm.
fn q(v_um: f64) -> f64 {
    let v = (v_um * 1e3).round() / 1e3;
    if v == 0.0 { 0.0 } else { v }
}

pub(crate) fn write(c: &Curve) -> Result<CompensationTable, CompensationError> {
    c.check_finite()?;
    if c.mode == Mode::Bidirectional {
        return Err(CompensationError::Unsupported {
            dialect: Dialect::Sinumerik,
            message: "direction-dependent LEC needs interpolatory (CEC) tables with $AN_CEC_DIRECTION, which this writer does not produce; use --backlash".into(),
        });
    }
    let up: Vec<f64> = c.up_um.iter().map(|&v| q(v)).collect();
    let ax = &c.axis;
    let n = up.len();
    let mut f = String::from("%_N_AX_EEC_INI\n");
    let _ = writeln!(
        f,
        "; metrolog: leadscrew error compensation of {ax}, {n} points, values = measured error (actual - nominal) in mm, 0 at the reference point {:.4} mm",
        c.reference_mm
    );
    f.push_str("CHANDATA(1)\n");
    for (i, v) in up.iter().enumerate() {
        let _ = writeln!(f, "$AA_ENC_COMP[0,{i},{ax}]={:.6}", v * 1e-3);
    }
    let (min, max) = (c.points_mm[0], c.points_mm[n - 1]);
    let _ = writeln!(f, "$AA_ENC_COMP_STEP[0,{ax}]={:.6}", c.spacing_mm);
    let _ = writeln!(f, "$AA_ENC_COMP_MIN[0,{ax}]={min:.6}");
    let _ = writeln!(f, "$AA_ENC_COMP_MAX[0,{ax}]={max:.6}");
    let _ = writeln!(f, "$AA_ENC_COMP_IS_MODULO[0,{ax}]=0");
    f.push_str("M17\n");
    let mut notes = vec![
        format!(
            "set MD38000 $MA_MM_ENC_COMP_MAX_POINTS[0,{ax}] >= {n} (power on; reformats the static user memory)"
        ),
        format!(
            "load the file with MD32700 $MA_ENC_COMP_ENABLE[0,{ax}] = 0, then set it to 1 and reference the axis"
        ),
    ];
    if n > 200 {
        notes.push(format!("{n} points: more than the 808D's 200"));
    }
    // The control corrects its actual value by the table: the axis moves by −value.
    let corr_up: Vec<f64> = up.iter().map(|v| -v).collect();
    let corr_down = match c.backlash_um {
        Some(b) => {
            notes.push(format!(
                "set MD32450 $MA_BACKLASH[0,{ax}] = {:.6} mm (the table holds the positive-direction curve; the control adds the backlash on negative moves after referencing in the positive direction)",
                q(b) * 1e-3
            ));
            up.iter().map(|u| -(u + q(b))).collect()
        }
        None => corr_up.clone(),
    };
    Ok(CompensationTable {
        dialect: Dialect::Sinumerik,
        mode: c.mode,
        reference_mm: c.reference_mm,
        points_mm: c.points_mm.clone(),
        correction_up_um: corr_up,
        correction_down_um: corr_down,
        backlash_um: c.backlash_um.map(q),
        files: vec![(format!("{ax}_EEC.INI"), f)],
        notes,
    })
}
