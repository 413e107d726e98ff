//! The candidate mean effects: their regressors (columns) and the grids their non-linear
//! parameter is searched on (names and parameters of `docs/datasets.md`).

use super::fit::Obs;

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Family {
    Linear,
    Warmup,
    Cyclic,
    Thermal,
    ThermalTemp,
}

impl Family {
    pub(super) fn name(self) -> &'static str {
        match self {
            Family::Linear => "linear_drift",
            Family::Warmup => "exponential_warmup",
            Family::Cyclic => "cyclic_drift",
            Family::Thermal | Family::ThermalTemp => "thermal_expansion",
        }
    }
    /// Parameters counted by the BIC (grid-searched ones included).
    pub(super) fn n_params(self) -> usize {
        match self {
            Family::Linear | Family::ThermalTemp => 1,
            Family::Warmup | Family::Thermal => 2,
            Family::Cyclic => 3,
        }
    }
    pub(super) fn slot(self) -> usize {
        match self {
            Family::Linear => 0,
            Family::Warmup => 1,
            Family::Cyclic => 2,
            Family::Thermal | Family::ThermalTemp => 3,
        }
    }

    pub(super) fn columns(self, obs: &Obs, theta: f64) -> Vec<Vec<f64>> {
        let warm = |t: f64| 1.0 - (-t / theta).exp();
        match self {
            Family::Linear => vec![obs.t.iter().map(|t| t / 3600.0).collect()],
            Family::Warmup => vec![obs.t.iter().map(|&t| warm(t)).collect()],
            Family::Cyclic => {
                let om = std::f64::consts::TAU / theta;
                vec![
                    obs.t.iter().map(|t| (om * t).sin()).collect(),
                    obs.t.iter().map(|t| (om * t).cos()).collect(),
                ]
            }
            // Shift in µm of a scale of 1 ppm at position x: x_mm · 1e-3.
            Family::Thermal => {
                vec![
                    obs.t
                        .iter()
                        .zip(&obs.x_mm)
                        .map(|(&t, x)| x * 1e-3 * warm(t))
                        .collect(),
                ]
            }
            // α [µm/(m·K)] · x [m] · T [°C]; the constant part falls into the baseline.
            Family::ThermalTemp => match &obs.temp_c {
                Some(tc) => vec![
                    tc.iter()
                        .zip(&obs.x_mm)
                        .map(|(c, x)| x * 1e-3 * c)
                        .collect(),
                ],
                None => vec![vec![0.0; obs.len()]],
            },
        }
    }

    pub(super) fn grid(self, obs: &Obs) -> Vec<f64> {
        let d = obs.duration_s;
        match self {
            Family::Linear | Family::ThermalTemp => vec![f64::NAN],
            Family::Warmup | Family::Thermal => {
                let (lo, hi) = ((d / 100.0).max(obs.dt_s), 3.0 * d);
                let n = 48;
                (0..n)
                    .map(|k| lo * (hi / lo).powf(k as f64 / (n - 1) as f64))
                    .collect()
            }
            Family::Cyclic => {
                // Periods from three reading intervals (and at least 2 min: no thermal cycle of
                // a machine is faster) to 1/1.2 of the run, uniform in frequency at 1/(3T).
                let p_min = (3.0 * obs.dt_s).max(120.0_f64.min(d / 10.0));
                let p_max = d / 1.2;
                if p_min >= p_max {
                    return Vec::new();
                }
                let (f_lo, f_hi) = (1.0 / p_max, 1.0 / p_min);
                let df = 1.0 / (3.0 * d);
                let n = (((f_hi - f_lo) / df).ceil() as usize).clamp(2, 4000);
                (0..=n)
                    .map(|k| 1.0 / (f_lo + (f_hi - f_lo) * k as f64 / n as f64))
                    .collect()
            }
        }
    }
}
