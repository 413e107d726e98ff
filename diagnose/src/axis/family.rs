//! The forms in which the mean effects of the axis model are searched: their regressors
//! (columns) and the grids their non-linear parameter is searched on. Each is a form of one
//! [`EffectKind`] (names and parameters of `docs/datasets.md`).

use positioning::axis_model::EffectKind;

use super::obs::Obs;

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Family {
    Linear,
    Warmup,
    Cyclic,
    Thermal,
    ThermalTemp,
    Step,
    ReversalDrift,
    CycleOffsets,
}

impl Family {
    /// The model effect this family fits (a scale change fitted to the material temperature
    /// is a scale change): two families of one kind are never in a model together.
    pub(super) fn kind(self) -> EffectKind {
        match self {
            Family::Linear => EffectKind::LinearDrift,
            Family::Warmup => EffectKind::ExponentialWarmup,
            Family::Cyclic => EffectKind::CyclicDrift,
            Family::Thermal | Family::ThermalTemp => EffectKind::ThermalExpansion,
            Family::Step => EffectKind::Step,
            Family::ReversalDrift => EffectKind::ReversalDrift,
            Family::CycleOffsets => EffectKind::CycleOffsets,
        }
    }
    /// Parameters counted by the BIC (grid-searched ones included).
    pub(super) fn n_params(self, obs: &Obs) -> usize {
        match self {
            Family::Linear | Family::ThermalTemp | Family::ReversalDrift => 1,
            Family::Warmup | Family::Thermal => 2,
            // A change point searched over every reading costs more than a smooth parameter
            // (its likelihood ratio is a maximum over many nearly independent positions).
            Family::Cyclic | Family::Step => 3,
            Family::CycleOffsets => obs.n_cycles.saturating_sub(1).max(1),
        }
    }
    /// A grid-searched family, whose columns are kept for the run (the search's cache).
    pub(super) fn is_searched_dense(self) -> bool {
        matches!(self, Family::Warmup | Family::Cyclic | Family::Thermal)
    }

    /// The regressors of the effect with its parameter at `theta`, computed (the search reads
    /// them through its cache).
    pub(super) fn compute_columns(self, obs: &Obs, theta: f64) -> Vec<Vec<f64>> {
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
            // Readings from θ on shift by the coefficient.
            Family::Step => vec![obs.t.iter().map(|&t| f64::from(t >= theta)).collect()],
            // The coefficient is B at the end minus B at the start (ISO 230-2 sign).
            Family::ReversalDrift => vec![
                obs.t
                    .iter()
                    .zip(&obs.dir_half)
                    .map(|(t, h)| h * (t - obs.t0) / obs.duration_s)
                    .collect(),
            ],
            // One offset per cycle after the first (the first is the baseline's).
            Family::CycleOffsets => (1..obs.n_cycles)
                .map(|c| obs.cycle.iter().map(|&k| f64::from(k == c)).collect())
                .collect(),
        }
    }

    pub(super) fn grid(self, obs: &Obs) -> Vec<f64> {
        let d = obs.duration_s;
        match self {
            Family::Linear | Family::ThermalTemp | Family::ReversalDrift | Family::CycleOffsets => {
                vec![f64::NAN]
            }
            // The first shifted reading: any reading but the first and last two in time.
            Family::Step => {
                let o = &obs.time_order;
                let mut ts: Vec<f64> = o
                    .iter()
                    .skip(2)
                    .take(o.len().saturating_sub(4))
                    .map(|&j| obs.t[j])
                    .collect();
                ts.dedup();
                ts
            }
            Family::Warmup | Family::Thermal => {
                let (lo, hi) = ((d / 100.0).max(obs.dt_s), 3.0 * d);
                let n = 48;
                (0..n)
                    .map(|k| lo * (hi / lo).powf(k as f64 / (n - 1) as f64))
                    .collect()
            }
            // Periods tied to the run's structure are searched too: when one of them fits
            // best, the search gives no cycle.
            Family::Cyclic => match cyclic_frequencies(obs) {
                Some(f) => (0..=f.n).map(|k| f.period(k)).collect(),
                None => Vec::new(),
            },
        }
    }
}

/// The frequencies a cyclic drift's period is searched over: periods from three reading
/// intervals (and at least 2 min: no thermal cycle of a machine is faster) to 1/1.2 of the
/// run, uniform in frequency at 1/(3T); a best period that aliases the run's structure
/// ([`aliases_structure`]) is no cycle.
pub(super) struct Frequencies {
    pub(super) lo: f64,
    pub(super) hi: f64,
    /// Steps from `lo` to `hi`.
    pub(super) n: usize,
}

impl Frequencies {
    /// The k-th period, s.
    pub(super) fn period(&self, k: usize) -> f64 {
        1.0 / (self.lo + (self.hi - self.lo) * k as f64 / self.n as f64)
    }
}

/// [`Frequencies`] of the run (None when the run is too short for any).
pub(super) fn cyclic_frequencies(obs: &Obs) -> Option<Frequencies> {
    let d = obs.duration_s;
    let p_min = (3.0 * obs.dt_s).max(120.0_f64.min(d / 10.0));
    let p_max = d / 1.2;
    if p_min >= p_max {
        return None;
    }
    let (lo, hi) = (1.0 / p_max, 1.0 / p_min);
    let df = 1.0 / (3.0 * d);
    let n = (((hi - lo) / df).ceil() as usize).clamp(2, 4000);
    Some(Frequencies { lo, hi, n })
}

/// A period tied to the run's structure rather than to time: within half a beat over the run
/// of a harmonic of the cycle length (the pass is half a cycle; a run measured in blocks
/// repeats with each pair of blocks), where the per-target,
/// per-direction baseline absorbs the sinusoid or turns it into a slow per-target pattern
/// (`docs/methods.md`, "Diagnosis").
pub(super) fn aliases_structure(obs: &Obs, period_s: f64) -> bool {
    let Some(pc) = obs.cycle_s else {
        return false;
    };
    let (f, fc) = (1.0 / period_s, 1.0 / pc);
    let k = (f / fc).round();
    k >= 1.0 && (f - k * fc).abs() < 0.5 / obs.duration_s
}
