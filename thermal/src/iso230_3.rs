//! ISO 230-3 evaluations: environmental temperature variation error (ETVE) and the thermal
//! distortion caused by a rotating spindle (five probes on a test mandrel).
//!
//! All readings are relative displacements in µm, sampled together over the test.

use crate::error::ThermalError;
use serde::{Deserialize, Serialize};

/// ETVE of one axis: the largest range of the relative displacement over the test, µm.
pub fn etve(displacement_um: &[f64]) -> Result<f64, ThermalError> {
    check_series("displacement", displacement_um, displacement_um.len())?;
    let (lo, hi) = min_max(displacement_um);
    Ok(hi - lo)
}

/// The five probe readings of ISO 230-3's spindle test, µm.
///
/// X1 and Y1 read the mandrel near the spindle nose, X2 and Y2 the same directions
/// `probe_spacing_mm` further along it; Z reads its end face (axial).
#[derive(Debug, Clone, Copy)]
pub struct FiveProbes<'a> {
    pub x1_um: &'a [f64],
    pub x2_um: &'a [f64],
    pub y1_um: &'a [f64],
    pub y2_um: &'a [f64],
    pub z_um: &'a [f64],
}

/// Drift and tilt series relative to the first sample, and their largest values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpindleDistortion {
    /// X drift at the probe near the nose, µm.
    pub x_um: Vec<f64>,
    /// Y drift at the probe near the nose, µm.
    pub y_um: Vec<f64>,
    /// Z (axial) drift, µm.
    pub z_um: Vec<f64>,
    /// Tilt A in the YZ plane, µrad: (Y2 − Y1) / spacing, positive when the far probe reads more.
    pub a_urad: Vec<f64>,
    /// Tilt B in the XZ plane, µrad: (X2 − X1) / spacing, positive when the far probe reads more.
    pub b_urad: Vec<f64>,
    /// Largest absolute value of each series over the run.
    pub max: DistortionMaxima,
}

/// Largest absolute drift and tilt over the run (ISO 230-3's maximum values).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DistortionMaxima {
    pub x_um: f64,
    pub y_um: f64,
    pub z_um: f64,
    pub a_urad: f64,
    pub b_urad: f64,
}

/// Thermal distortion caused by a rotating spindle from the five probes.
pub fn spindle_distortion(
    p: FiveProbes<'_>,
    probe_spacing_mm: f64,
) -> Result<SpindleDistortion, ThermalError> {
    if !(probe_spacing_mm.is_finite() && probe_spacing_mm > 0.0) {
        return Err(ThermalError::Parameter {
            what: format!("probe spacing {probe_spacing_mm} mm must be positive"),
        });
    }
    let n = p.x1_um.len();
    let named = [
        ("X1", p.x1_um),
        ("X2", p.x2_um),
        ("Y1", p.y1_um),
        ("Y2", p.y2_um),
        ("Z", p.z_um),
    ];
    for (name, s) in named {
        check_series(name, s, n)?;
    }
    let rel = |s: &[f64]| s.iter().map(|v| v - s[0]).collect::<Vec<f64>>();
    let tilt = |far: &[f64], near: &[f64]| {
        (0..n)
            .map(|i| ((far[i] - far[0]) - (near[i] - near[0])) / probe_spacing_mm * 1000.0)
            .collect::<Vec<f64>>()
    };
    let (x, y, z) = (rel(p.x1_um), rel(p.y1_um), rel(p.z_um));
    let (a, b) = (tilt(p.y2_um, p.y1_um), tilt(p.x2_um, p.x1_um));
    let max = DistortionMaxima {
        x_um: max_abs(&x),
        y_um: max_abs(&y),
        z_um: max_abs(&z),
        a_urad: max_abs(&a),
        b_urad: max_abs(&b),
    };
    Ok(SpindleDistortion {
        x_um: x,
        y_um: y,
        z_um: z,
        a_urad: a,
        b_urad: b,
        max,
    })
}

fn check_series(name: &str, s: &[f64], n: usize) -> Result<(), ThermalError> {
    if s.len() != n || n < 2 {
        return Err(ThermalError::TooFewSamples {
            what: format!(
                "probe {name} has {} readings; every probe needs the same number, at least 2 ({n})",
                s.len()
            ),
        });
    }
    if let Some(i) = s.iter().position(|v| !v.is_finite()) {
        return Err(ThermalError::Parameter {
            what: format!("probe {name}, reading {}: not a finite number", i + 1),
        });
    }
    Ok(())
}

fn min_max(s: &[f64]) -> (f64, f64) {
    s.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        })
}

fn max_abs(s: &[f64]) -> f64 {
    s.iter().fold(0.0, |m, v| m.max(v.abs()))
}
