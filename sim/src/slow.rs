//! A slowly varying quantity of a scenario (environment, drift, ambient temperature), shared by
//! the scenario and the thermal machine.

use serde::{Deserialize, Serialize};

/// A slowly varying quantity: `mean + drift·t/3600 + amplitude·sin(2πt/period + phase)` at
/// scaled time `t` in s.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Slow {
    pub mean: f64,
    #[serde(default)]
    pub amplitude: f64,
    #[serde(default = "hour")]
    pub period_s: f64,
    #[serde(default)]
    pub phase_rad: f64,
    #[serde(default)]
    pub drift_per_h: f64,
}

fn hour() -> f64 {
    3600.0
}

impl Slow {
    pub const fn constant(mean: f64) -> Slow {
        Slow {
            mean,
            amplitude: 0.0,
            period_s: 3600.0,
            phase_rad: 0.0,
            drift_per_h: 0.0,
        }
    }
    pub fn at(&self, t_s: f64) -> f64 {
        let cyc = if self.period_s > 0.0 {
            self.amplitude * (std::f64::consts::TAU * t_s / self.period_s + self.phase_rad).sin()
        } else {
            0.0
        };
        self.mean + self.drift_per_h * t_s / 3600.0 + cyc
    }
}
