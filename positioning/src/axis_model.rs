//! The simulation model of one linear axis measured by an interferometer: what `sim/` uses to
//! produce the interferometer's readings, and what `diagnose --write-model` extends with the
//! effects it found. Stored as TOML (the `[axis]` table of a scenario file).
//!
//! The baseline (what the simulation assumed before any diagnosis) is a static systematic
//! deviation per target and approach direction plus stationary white noise. Effects add
//! behaviour the baseline lacks; their vocabulary is that of `docs/datasets.md`.

use serde::{Deserialize, Serialize};

/// One linear axis: targets, static deviations, noise, and extra effects.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisModel {
    /// Axis name, e.g. "X".
    pub axis: String,
    /// Programmed targets, mm (machine coordinates; the interferometer datum is at 0 mm).
    pub targets_mm: Vec<f64>,
    /// Static systematic deviation per target for positive approaches, µm.
    pub systematic_up_um: Vec<f64>,
    /// Static systematic deviation per target for negative approaches, µm.
    pub systematic_down_um: Vec<f64>,
    /// Standard deviation of the stationary reading noise, µm.
    pub noise_um: f64,
    /// Effects beyond the baseline, each adding to the deviation.
    #[serde(default)]
    pub effects: Vec<Effect>,
}

/// An effect beyond the static baseline (names and parameters of `docs/datasets.md`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "effect", rename_all = "snake_case", deny_unknown_fields)]
pub enum Effect {
    /// Every target shifts steadily with time: `rate · t`.
    LinearDrift { rate_um_per_h: f64 },
    /// Every target shifts by `A·(1 − e^(−t/τ))`.
    ExponentialWarmup { amplitude_um: f64, tau_s: f64 },
    /// Every target shifts by `A·sin(2π t / P + φ)`.
    CyclicDrift {
        period_s: f64,
        amplitude_um: f64,
        #[serde(default)]
        phase_rad: f64,
    },
    /// A scale change growing with time, shift proportional to position:
    /// `scale_ppm·1e-6 · x_µm · (1 − e^(−t/τ))`; `scale_ppm` is the asymptotic scale.
    ThermalExpansion { scale_ppm: f64, tau_s: f64 },
    /// One target (1-based `index`) scatters `std_ratio` times more than the others.
    LocalAnomaly { index: usize, std_ratio: f64 },
    /// Isolated readings off by about `magnitude_um`, with probability `rate` per reading.
    Outliers { rate: f64, magnitude_um: f64 },
    /// Every reading from `time_s` on shifts by `size_um`.
    Step { time_s: f64, size_um: f64 },
    /// The reversal value B = x̄↑ − x̄↓ changes by `change_um` over `duration_s` from the start:
    /// positive approaches shift by `+change·t/(2·duration)`, negative ones by the opposite.
    ReversalDrift { change_um: f64, duration_s: f64 },
    /// Each cycle is shifted by its own offset, drawn with standard deviation `std_um` when
    /// simulated (the reference re-mounted between cycles).
    CycleOffsets { std_um: f64 },
}

/// Which effect an [`Effect`] is, without its parameters: what a search tries and a report
/// names (the names are those of the TOML `effect` tag and of `docs/datasets.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EffectKind {
    LinearDrift,
    ExponentialWarmup,
    CyclicDrift,
    ThermalExpansion,
    LocalAnomaly,
    Outliers,
    Step,
    ReversalDrift,
    CycleOffsets,
}

impl EffectKind {
    /// The effect's name, as in the TOML `effect` tag and the diagnosis report.
    pub fn name(self) -> &'static str {
        match self {
            EffectKind::LinearDrift => "linear_drift",
            EffectKind::ExponentialWarmup => "exponential_warmup",
            EffectKind::CyclicDrift => "cyclic_drift",
            EffectKind::ThermalExpansion => "thermal_expansion",
            EffectKind::LocalAnomaly => "local_anomaly",
            EffectKind::Outliers => "outliers",
            EffectKind::Step => "step",
            EffectKind::ReversalDrift => "reversal_drift",
            EffectKind::CycleOffsets => "cycle_offsets",
        }
    }
}

impl std::fmt::Display for EffectKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Effect {
    /// Which effect this is.
    pub fn kind(&self) -> EffectKind {
        match self {
            Effect::LinearDrift { .. } => EffectKind::LinearDrift,
            Effect::ExponentialWarmup { .. } => EffectKind::ExponentialWarmup,
            Effect::CyclicDrift { .. } => EffectKind::CyclicDrift,
            Effect::ThermalExpansion { .. } => EffectKind::ThermalExpansion,
            Effect::LocalAnomaly { .. } => EffectKind::LocalAnomaly,
            Effect::Outliers { .. } => EffectKind::Outliers,
            Effect::Step { .. } => EffectKind::Step,
            Effect::ReversalDrift { .. } => EffectKind::ReversalDrift,
            Effect::CycleOffsets { .. } => EffectKind::CycleOffsets,
        }
    }
}

/// Direction of approach to a target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Direction {
    #[serde(rename = "+")]
    Up,
    #[serde(rename = "-")]
    Down,
}

impl AxisModel {
    /// The deterministic part of the deviation at target `index` (0-based), direction `dir`,
    /// time `t_s` since the start of the run, µm.
    pub fn deterministic_um(&self, index: usize, dir: Direction, t_s: f64) -> f64 {
        let sys = match dir {
            Direction::Up => self.systematic_up_um.get(index),
            Direction::Down => self.systematic_down_um.get(index),
        }
        .copied()
        .unwrap_or(0.0);
        let x_mm = self.targets_mm.get(index).copied().unwrap_or(0.0);
        let mut d = sys;
        for e in &self.effects {
            d += match *e {
                Effect::LinearDrift { rate_um_per_h } => rate_um_per_h * t_s / 3600.0,
                Effect::ExponentialWarmup {
                    amplitude_um,
                    tau_s,
                } => amplitude_um * (1.0 - (-t_s / tau_s).exp()),
                Effect::CyclicDrift {
                    period_s,
                    amplitude_um,
                    phase_rad,
                } => amplitude_um * (std::f64::consts::TAU * t_s / period_s + phase_rad).sin(),
                Effect::ThermalExpansion { scale_ppm, tau_s } => {
                    scale_ppm * 1e-6 * x_mm * 1e3 * (1.0 - (-t_s / tau_s).exp())
                }
                Effect::Step { time_s, size_um } => {
                    if t_s >= time_s {
                        size_um
                    } else {
                        0.0
                    }
                }
                Effect::ReversalDrift {
                    change_um,
                    duration_s,
                } => {
                    let half = match dir {
                        Direction::Up => 0.5,
                        Direction::Down => -0.5,
                    };
                    half * change_um * t_s / duration_s.max(f64::MIN_POSITIVE)
                }
                Effect::LocalAnomaly { .. }
                | Effect::Outliers { .. }
                | Effect::CycleOffsets { .. } => 0.0,
            };
        }
        d
    }

    /// Standard deviation of the random part of a reading at target `index` (0-based), µm.
    pub fn noise_std_um(&self, index: usize) -> f64 {
        let mut s = self.noise_um;
        for e in &self.effects {
            if let Effect::LocalAnomaly {
                index: i,
                std_ratio,
            } = *e
                && i == index + 1
            {
                s *= std_ratio;
            }
        }
        s
    }

    /// Standard deviation of the offsets between cycles, if the model has them.
    pub fn cycle_offsets_std_um(&self) -> Option<f64> {
        self.effects.iter().find_map(|e| match *e {
            Effect::CycleOffsets { std_um } => Some(std_um),
            _ => None,
        })
    }

    /// Probability and size of an outlier per reading, if the model has outliers.
    pub fn outliers(&self) -> Option<(f64, f64)> {
        self.effects.iter().find_map(|e| match *e {
            Effect::Outliers { rate, magnitude_um } => Some((rate, magnitude_um)),
            _ => None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> AxisModel {
        AxisModel {
            axis: "X".into(),
            targets_mm: vec![0.0, 100.0],
            systematic_up_um: vec![1.0, 2.0],
            systematic_down_um: vec![-1.0, -2.0],
            noise_um: 0.5,
            effects: vec![
                Effect::LinearDrift { rate_um_per_h: 3.6 },
                Effect::ThermalExpansion {
                    scale_ppm: 10.0,
                    tau_s: 1.0e-9,
                },
                Effect::LocalAnomaly {
                    index: 2,
                    std_ratio: 4.0,
                },
            ],
        }
    }

    #[test]
    fn deterministic_part_adds_effects() {
        let m = model();
        // 1000 s of 3.6 µm/h = 1 µm; 10 ppm of 100 mm = 1 µm once warmed up.
        assert!((m.deterministic_um(1, Direction::Up, 1000.0) - 4.0).abs() < 1e-12);
        assert!((m.deterministic_um(0, Direction::Down, 0.0) + 1.0).abs() < 1e-12);
        assert_eq!(m.noise_std_um(1), 2.0);
        assert_eq!(m.noise_std_um(0), 0.5);
    }

    /// A kind's name is the `effect` tag its effect is written with.
    #[test]
    fn kind_names_are_the_toml_tags() {
        let all = [
            Effect::LinearDrift { rate_um_per_h: 1.0 },
            Effect::ExponentialWarmup {
                amplitude_um: 1.0,
                tau_s: 1.0,
            },
            Effect::CyclicDrift {
                period_s: 1.0,
                amplitude_um: 1.0,
                phase_rad: 0.0,
            },
            Effect::ThermalExpansion {
                scale_ppm: 1.0,
                tau_s: 1.0,
            },
            Effect::LocalAnomaly {
                index: 1,
                std_ratio: 2.0,
            },
            Effect::Outliers {
                rate: 0.1,
                magnitude_um: 1.0,
            },
            Effect::Step {
                time_s: 1.0,
                size_um: 1.0,
            },
            Effect::ReversalDrift {
                change_um: 1.0,
                duration_s: 1.0,
            },
            Effect::CycleOffsets { std_um: 1.0 },
        ];
        for e in all {
            let v = toml::Value::try_from(e).expect("serialise");
            assert_eq!(v["effect"].as_str(), Some(e.kind().name()));
            let k = toml::Value::try_from(e.kind()).expect("serialise");
            assert_eq!(k.as_str(), Some(e.kind().name()));
        }
    }

    #[test]
    fn toml_round_trip() {
        let m = model();
        let s = toml::to_string(&m).expect("serialise");
        let back: AxisModel = toml::from_str(&s).expect("parse");
        assert_eq!(back, m);
    }
}
