//! Position-dependent reading budget of the PSD laser frame (paper 003 Tables 2 and 3) and the
//! amplitudes of the random thermo-elastic errors its Monte Carlo draws. The file format is
//! documented in docs/methods.md ("PSD reading budget file"); the shipped example is
//! `examples/budgets/psd_frame_readings.toml`.
//!
//! One reading's standard uncertainty (one run, before the reference subtraction) is
//!
//! ```text
//! u² = Σ constant² + u_defl(s)² + u_PSD(t)²
//! u_defl(s) = min(u_at · (s / s_at)², max)          (beam deflection, paper 003 eq. 6)
//! u_PSD(t)  = √((lin · |2t − 1| / (2√3))² + rep²)   (paper 003 eq. 11, Table 2)
//! ```
//!
//! with `s` the beam path from the source to the point and `t ∈ [0, 1]` the point's place
//! along its segment: the spot walks linearly across the PSD and is centred in the middle of
//! the segment (paper 003 §4.3), so the linearity deviation grows from zero in the middle to
//! Table 2's value at both ends.

use serde::{Deserialize, Serialize};

use super::UncertaintyError;
use geometry::psd_frame::PsdLayout;

/// A position-independent term of Table 3 (sensitivity 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstantTerm {
    pub name: String,
    pub u_um: f64,
    #[serde(default)]
    pub description: Option<String>,
}

/// Beam deflection by air-temperature gradients: `u = u_at·(s/s_at)²`, at most `max_um`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BeamDeflection {
    pub u_at_um: f64,
    pub at_path_mm: f64,
    #[serde(default)]
    pub max_um: Option<f64>,
}

/// PSD calibration terms of one segment (Table 2) and where its points lie on the beam path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentBudget {
    /// 1..=5 as in `psd_frame`.
    pub segment: u8,
    /// Linearity deviation at the ends of the segment for the readings (r1, r2), µm.
    pub linearity_um: [f64; 2],
    /// Beam path from the source at the segment's first and last point (ascending machine
    /// coordinate, as the points are numbered), mm; points in between are interpolated.
    pub path_mm: [f64; 2],
}

/// Peak amplitudes of the random thermo-elastic errors of the Monte Carlo (paper 003 §5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalErrors {
    /// Chain string of the machine (paper 003: wbXYZt = `WFXYZT`).
    #[serde(default = "default_chain")]
    pub chain: String,
    /// Position of the PSD centre in the Z carriage's frame, mm: the lever arm of the Z axis'
    /// angular errors (the unmeasured ones alias through it).
    #[serde(default)]
    pub tool_offset_mm: [f64; 3],
    pub positioning_um: f64,
    pub straightness_um: f64,
    /// Rolls of X and Y (EAX, EBY), which the frame measures.
    pub roll_urad: f64,
    /// Pitches and yaws of X and Y and the three angles of Z, which it does not measure.
    pub angular_urad: f64,
    pub squareness_urad: f64,
    /// Positioning of Z, which the frame does not measure.
    pub ezz_um: f64,
}

fn default_chain() -> String {
    "WFXYZT".into()
}

/// The budget file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PsdBudget {
    pub title: String,
    #[serde(default)]
    pub description: Option<String>,
    /// Repeatability of the PSD calibration (displacement sensor), µm.
    pub psd_repeatability_um: f64,
    pub beam_deflection: BeamDeflection,
    #[serde(rename = "constant")]
    pub constants: Vec<ConstantTerm>,
    #[serde(rename = "segment")]
    pub segments: Vec<SegmentBudget>,
    pub thermal_errors: ThermalErrors,
}

/// The terms of one reading's budget, µm (one run).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReadingTerms {
    pub constant: f64,
    pub deflection: f64,
    pub psd: f64,
    pub total: f64,
}

impl PsdBudget {
    /// Reads and checks a budget file.
    pub fn from_toml(s: &str) -> Result<Self, UncertaintyError> {
        let b: PsdBudget =
            toml::from_str(s).map_err(|e| UncertaintyError::Format(e.to_string()))?;
        b.check()?;
        Ok(b)
    }

    fn check(&self) -> Result<(), UncertaintyError> {
        let bad = |what: &str, v: f64| {
            UncertaintyError::Invalid(format!(
                "PSD budget: {what} = {v} must be a finite number ≥ 0"
            ))
        };
        let nonneg = |what: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(bad(what, v))
            }
        };
        nonneg("psd_repeatability_um", self.psd_repeatability_um)?;
        let d = &self.beam_deflection;
        nonneg("beam_deflection.u_at_um", d.u_at_um)?;
        nonneg("beam_deflection.max_um", d.max_um.unwrap_or(0.0))?;
        if !(d.at_path_mm.is_finite() && d.at_path_mm > 0.0) {
            return Err(UncertaintyError::Invalid(format!(
                "PSD budget: beam_deflection.at_path_mm = {} must be > 0",
                d.at_path_mm
            )));
        }
        for c in &self.constants {
            nonneg(&format!("constant `{}` u_um", c.name), c.u_um)?;
        }
        for seg in 1..=5u8 {
            let n = self.segments.iter().filter(|s| s.segment == seg).count();
            if n != 1 {
                return Err(UncertaintyError::Invalid(format!(
                    "PSD budget: segment {seg} must be given exactly once ([[segment]] with segment = {seg}), found {n}"
                )));
            }
        }
        for s in &self.segments {
            if !(1..=5).contains(&s.segment) {
                return Err(UncertaintyError::Invalid(format!(
                    "PSD budget: segment {} is not 1..5",
                    s.segment
                )));
            }
            for v in s.linearity_um.iter().chain(&s.path_mm) {
                nonneg(&format!("segment {} linearity_um/path_mm", s.segment), *v)?;
            }
        }
        let t = &self.thermal_errors;
        for (what, v) in [
            ("positioning_um", t.positioning_um),
            ("straightness_um", t.straightness_um),
            ("roll_urad", t.roll_urad),
            ("angular_urad", t.angular_urad),
            ("squareness_urad", t.squareness_urad),
            ("ezz_um", t.ezz_um),
        ] {
            nonneg(&format!("thermal_errors.{what}"), v)?;
        }
        if t.tool_offset_mm.iter().any(|v| !v.is_finite()) {
            return Err(UncertaintyError::Invalid(
                "PSD budget: thermal_errors.tool_offset_mm must be finite".into(),
            ));
        }
        Ok(())
    }

    fn segment(&self, seg: u8) -> &SegmentBudget {
        // `check` guarantees one entry per segment.
        self.segments
            .iter()
            .find(|s| s.segment == seg)
            .unwrap_or(&self.segments[0])
    }

    /// Budget of reading `k` (0: r1, 1: r2) of point `i` of segment `seg` among `n` points.
    pub fn reading_terms(&self, seg: u8, i: usize, n: usize, k: usize) -> ReadingTerms {
        let s = self.segment(seg);
        let t = if n > 1 {
            i as f64 / (n - 1) as f64
        } else {
            0.5
        };
        let path = s.path_mm[0] + (s.path_mm[1] - s.path_mm[0]) * t;
        let d = &self.beam_deflection;
        let mut deflection = d.u_at_um * (path / d.at_path_mm).powi(2);
        if let Some(m) = d.max_um {
            deflection = deflection.min(m);
        }
        let lin = s.linearity_um[k] * (2.0 * t - 1.0).abs();
        let psd = (lin / (2.0 * 3f64.sqrt())).hypot(self.psd_repeatability_um);
        let constant = self
            .constants
            .iter()
            .map(|c| c.u_um * c.u_um)
            .sum::<f64>()
            .sqrt();
        let total = (constant * constant + deflection * deflection + psd * psd).sqrt();
        ReadingTerms {
            constant,
            deflection,
            psd,
            total,
        }
    }

    /// Standard uncertainty of every reading of one run, in the order of
    /// [`geometry::psd_frame::PsdReadings::to_vec`].
    pub fn reading_u_um(&self, layout: &PsdLayout) -> Vec<f64> {
        let mut u = Vec::new();
        for seg in 1..=5u8 {
            let n = if seg == 1 {
                layout.n_s1
            } else {
                layout.n_points
            };
            for i in 0..n {
                for k in 0..2 {
                    u.push(self.reading_terms(seg, i, n, k).total);
                }
            }
        }
        u
    }
}
