//! Uncertainty of an LI-80 position reading (ISO/TR 230-9 style budget) from the environment
//! sensors' uncertainties through the air and material compensation, the expansion
//! coefficient's uncertainty, the dead path and the cosine error.
//!
//! The LI-80 reading is compensated on the host (`L = raw/n`, then `L20 = L·(1 − α·(T_mat − 20
//! °C))`, see instruments.md). An error δT in the air temperature the compensation used changes
//! n by (∂n/∂T)·δT, and the compensated length by −L·(∂n/∂T)·δT; likewise for pressure and
//! humidity. The refractive-index sensitivities are those of the Edlén equation as revised by
//! Birch and Downs (1993, 1994) at 20 °C, 101.325 kPa, 50 % RH, 633 nm — the rule-of-thumb
//! figures of laser-interferometer practice (e.g. the NIST Engineering Metrology Toolbox):
//! about −0.93 ppm/K, +2.7 ppm/kPa and −0.0085 ppm/%RH. They are constants here so that
//! `metrology` need not depend on `protocol`'s Edlén function; over 15–25 °C, 95–105 kPa they
//! stay within about 5 % of these values, which changes the uncertainty by less than that.
//!
//! The dead path (optics to reflector at the datum) sees the same air but is not part of the
//! displacement: the compensation error acts on `position + dead_path`.
//! The cosine error is second order in the misalignment angle θ (rectangular on ±θ_max): it
//! has zero first-order sensitivity, so it enters the GUM budget as its own term with the
//! exact mean −L·θ_max²/6 and standard deviation L·θ_max²/(3√5) (moments of L·θ²/2).

use serde::Serialize;

use super::gum::{self, Coverage, GumInput, GumOutput};
use super::{FnModel, UncertaintyError};

/// ∂n/∂T of air, 1/K (Edlén / Birch & Downs at standard conditions).
pub const DN_DT_PER_K: f64 = -0.93e-6;
/// ∂n/∂p of air, 1/kPa.
pub const DN_DP_PER_KPA: f64 = 2.7e-6;
/// ∂n/∂RH of air, 1/%.
pub const DN_DRH_PER_PCT: f64 = -0.0085e-6;

/// The inputs of a length budget; accuracies are half-widths of rectangular distributions
/// (data-sheet "±" figures), as ISO/TR 230-9 treats them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LengthBudget {
    pub air_temp_accuracy_c: f64,
    pub pressure_accuracy_kpa: f64,
    pub humidity_accuracy_pct: f64,
    pub material_temp_accuracy_c: f64,
    /// Expansion coefficient used by the compensation, 1/K.
    pub alpha_per_k: f64,
    /// Half-width of the expansion coefficient's uncertainty, 1/K.
    pub alpha_accuracy_per_k: f64,
    /// Material temperature during the measurement, °C.
    pub material_temp_c: f64,
    pub dead_path_mm: f64,
    /// Largest misalignment of the beam to the axis, rad.
    pub misalignment_rad: f64,
}

impl Default for LengthBudget {
    /// A steel axis at 22 °C, sensors of ±0.1 K (air), ±0.1 kPa, ±5 %RH, ±0.1 K (material),
    /// α = 11.7 ± 1 µm/(m·K), 100 mm dead path, 100 µrad misalignment.
    fn default() -> Self {
        LengthBudget {
            air_temp_accuracy_c: 0.1,
            pressure_accuracy_kpa: 0.1,
            humidity_accuracy_pct: 5.0,
            material_temp_accuracy_c: 0.1,
            alpha_per_k: 11.7e-6,
            alpha_accuracy_per_k: 1.0e-6,
            material_temp_c: 22.0,
            dead_path_mm: 100.0,
            misalignment_rad: 100e-6,
        }
    }
}

const NAMES: [&str; 6] = [
    "air_temperature",
    "air_pressure",
    "humidity",
    "material_temperature",
    "expansion_coefficient",
    "cosine_error",
];

impl LengthBudget {
    /// The GUM budget of the error (µm) of a reading at `position_mm` from the datum.
    pub fn gum(&self, position_mm: f64) -> Result<GumOutput, UncertaintyError> {
        let vals = [
            self.air_temp_accuracy_c,
            self.pressure_accuracy_kpa,
            self.humidity_accuracy_pct,
            self.material_temp_accuracy_c,
            self.alpha_accuracy_per_k,
            self.misalignment_rad,
            self.dead_path_mm,
            position_mm,
        ];
        if vals.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(UncertaintyError::Invalid(
                "length budget: accuracies, dead path and position must be finite and ≥ 0".into(),
            ));
        }
        let rect = |a: f64| a / 3f64.sqrt();
        let l_um = position_mm * 1e3;
        let th2 = self.misalignment_rad.powi(2);
        let inputs = vec![
            (self.air_temp_accuracy_c, rect(self.air_temp_accuracy_c)),
            (self.pressure_accuracy_kpa, rect(self.pressure_accuracy_kpa)),
            (self.humidity_accuracy_pct, rect(self.humidity_accuracy_pct)),
            (
                self.material_temp_accuracy_c,
                rect(self.material_temp_accuracy_c),
            ),
            (self.alpha_accuracy_per_k, rect(self.alpha_accuracy_per_k)),
            (0.0, l_um * th2 / (3.0 * 5f64.sqrt())),
        ]
        .into_iter()
        .zip(NAMES)
        .enumerate()
        .map(|(i, ((_, u), name))| GumInput {
            group: None,
            name: name.to_string(),
            estimate: if i == 5 { -l_um * th2 / 6.0 } else { 0.0 },
            standard_uncertainty: u,
            dof: f64::INFINITY,
        })
        .collect::<Vec<_>>();
        let path_um = (position_mm + self.dead_path_mm) * 1e3;
        let dt_mat = self.material_temp_c - 20.0;
        let alpha = self.alpha_per_k;
        // x = [δT_air, δp, δRH, δT_mat, δα, e_cos]; error of the compensated reading in µm.
        let model = FnModel {
            n_outputs: 1,
            f: move |x: &[f64], y: &mut [f64]| {
                let dn = DN_DT_PER_K * x[0] + DN_DP_PER_KPA * x[1] + DN_DRH_PER_PCT * x[2];
                y[0] = -path_um * dn - l_um * (alpha * x[3] + x[4] * (dt_mat + x[3])) + x[5];
            },
        };
        let r = gum::propagate(
            &model,
            &["position_error".to_string()],
            &inputs,
            None,
            Coverage {
                probability: 0.95,
                factor: Some(2.0),
            },
        )?;
        r.outputs
            .into_iter()
            .next()
            .ok_or_else(|| UncertaintyError::Invalid("no output".into()))
    }

    /// Standard uncertainty (µm) of a reading at `position_mm`.
    pub fn standard_uncertainty_um(&self, position_mm: f64) -> Result<f64, UncertaintyError> {
        Ok(self.gum(position_mm)?.standard_uncertainty)
    }

    /// Expanded uncertainty U (k = 2, µm) at each target position, to attach to ISO 230-2
    /// results.
    pub fn expanded_uncertainty_um(
        &self,
        targets_mm: &[f64],
    ) -> Result<Vec<f64>, UncertaintyError> {
        targets_mm
            .iter()
            .map(|t| Ok(2.0 * self.standard_uncertainty_um(t.abs())?))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_worked_budget_at_one_metre() {
        // Hand calculation, L = 1000 mm, dead path 100 mm (path 1.1e6 µm):
        //   air T:  1.1e6 · 0.93e-6 · 0.1/√3        = 0.05906 µm
        //   p:      1.1e6 · 2.7e-6 · 0.1/√3         = 0.17147
        //   RH:     1.1e6 · 0.0085e-6 · 5/√3        = 0.02699
        //   T_mat:  1e6 · 11.7e-6 · 0.1/√3          = 0.67550
        //   α:      1e6 · 2 K · 1e-6/√3             = 1.15470
        //   cosine: 1e6 · (1e-4)² / (3√5)           = 0.00149
        // u = √Σ² = 1.35028 µm.
        let b = LengthBudget::default();
        let g = b.gum(1000.0).unwrap();
        assert!(
            (g.standard_uncertainty - 1.35028).abs() < 5e-5,
            "{}",
            g.standard_uncertainty
        );
        let c = |n: &str| {
            g.budget
                .iter()
                .find(|l| l.input == n)
                .unwrap()
                .contribution
                .abs()
        };
        assert!((c("air_pressure") - 0.17147).abs() < 1e-4);
        assert!((c("expansion_coefficient") - 1.15470).abs() < 1e-4);
        // The cosine error's mean shifts the estimate: −1e6·1e-8/6 µm.
        assert!((g.estimate + 1e-2 / 6.0).abs() < 1e-9);
        let u = b.expanded_uncertainty_um(&[0.0, 1000.0]).unwrap();
        assert!((u[1] - 2.0 * 1.35028).abs() < 1e-3);
        // At the datum only the dead path remains.
        assert!(u[0] > 0.0 && u[0] < 0.5);
    }
}
