//! The CapBall effects beyond the 14 link/setup parameters of [`crate::capball`]
//! (`docs/datasets.md`, "CapBall effects"): what a CapBall diagnosis looks for and finds, what
//! its extended model holds and what the simulator adds to the machine's true error. One type
//! for all of them, so that an effect's parameters travel typed from the search to the
//! simulator.

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::kinematics::Pose;

/// A CapBall effect with its parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CapballEffect {
    /// The measuring loop moves steadily with time, the same at every pose: `rate_um_per_h`
    /// per machine direction (x, y, z).
    LinearDrift { rate_um_per_h: [f64; 3] },
    /// The measuring loop moves periodically with time, the same at every pose.
    CyclicDrift(CyclicDrift),
    /// The channel along one machine direction reads `(1 + gain_pct/100)` times what the
    /// machine presents to it.
    SensorGain { channel: Channel, gain_pct: f64 },
    /// A motion error of a rotary axis, a harmonic of its angle.
    AxisError(AxisHarmonic),
}

/// Which CapBall effect, without its parameters: what a search tries and a report names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CapballEffectKind {
    LinearDrift,
    CyclicDrift,
    SensorGain,
    AxisError,
}

impl CapballEffectKind {
    /// The effect's name in reports (`docs/datasets.md`).
    pub fn name(self) -> &'static str {
        match self {
            CapballEffectKind::LinearDrift => "linear_drift",
            CapballEffectKind::CyclicDrift => "cyclic_drift",
            CapballEffectKind::SensorGain => "sensor_gain",
            CapballEffectKind::AxisError => "axis_error",
        }
    }
}

impl std::fmt::Display for CapballEffectKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl CapballEffect {
    /// Which effect this is.
    pub fn kind(&self) -> CapballEffectKind {
        match self {
            CapballEffect::LinearDrift { .. } => CapballEffectKind::LinearDrift,
            CapballEffect::CyclicDrift(_) => CapballEffectKind::CyclicDrift,
            CapballEffect::SensorGain { .. } => CapballEffectKind::SensorGain,
            CapballEffect::AxisError(_) => CapballEffectKind::AxisError,
        }
    }
}

/// A periodic drift of the measuring loop: `amplitude_um[k] · sin(2π t / period_s +
/// phase_rad[k])` in machine direction k (x, y, z). `amplitude_um` is half the peak-to-valley
/// (`docs/datasets.md`, `cyclic_drift`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CyclicDrift {
    pub period_s: f64,
    pub amplitude_um: [f64; 3],
    #[serde(default)]
    pub phase_rad: [f64; 3],
}

impl CyclicDrift {
    /// The drift at time `t_s`, µm, machine frame.
    pub fn at_um(&self, t_s: f64) -> [f64; 3] {
        let w = std::f64::consts::TAU * t_s / self.period_s;
        std::array::from_fn(|k| self.amplitude_um[k] * (w + self.phase_rad[k]).sin())
    }
}

/// A motion error of a rotary axis as harmonic `harmonic` of its angle θ, as the change of the
/// volumetric error `cos_um · cos(kθ) + sin_um · sin(kθ)` in the axis's housing frame (for C
/// the A cradle, for A the machine frame), µm (`docs/datasets.md`, `axis_error`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisHarmonic {
    pub axis: RotaryAxis,
    pub harmonic: u32,
    pub cos_um: [f64; 3],
    pub sin_um: [f64; 3],
}

impl AxisHarmonic {
    /// The change of the volumetric error at `pose`, µm, machine frame.
    pub fn error_um(&self, pose: &Pose) -> [f64; 3] {
        let (theta, frame) = housing(self.axis, pose);
        let arg = self.harmonic as f64 * theta;
        let v = frame
            * (Vector3::from(self.cos_um) * arg.cos() + Vector3::from(self.sin_um) * arg.sin());
        [v.x, v.y, v.z]
    }
}

/// A rotary axis of the CapBall machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum RotaryAxis {
    A,
    C,
}

impl RotaryAxis {
    pub fn name(self) -> &'static str {
        match self {
            RotaryAxis::A => "A",
            RotaryAxis::C => "C",
        }
    }
}

/// A reading channel of the CapBall, named by the machine direction it reads (`x`, `y`, `z`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    X,
    Y,
    Z,
}

impl Channel {
    pub const ALL: [Channel; 3] = [Channel::X, Channel::Y, Channel::Z];

    /// 0, 1, 2 for x, y, z.
    pub fn index(self) -> usize {
        self as usize
    }

    pub fn name(self) -> &'static str {
        match self {
            Channel::X => "x",
            Channel::Y => "y",
            Channel::Z => "z",
        }
    }
}

/// Angle (rad) of a rotary axis and the rotation of its housing frame into the machine frame.
/// The A cradle turns by −A about x (a workpiece-side axis, [`crate::kinematics`] conventions).
pub fn housing(axis: RotaryAxis, pose: &Pose) -> (f64, Matrix3<f64>) {
    match axis {
        RotaryAxis::A => (pose.a_deg.to_radians(), Matrix3::identity()),
        RotaryAxis::C => (
            pose.c_deg.to_radians(),
            *Rotation3::from_axis_angle(&Vector3::x_axis(), -pose.a_deg.to_radians()).matrix(),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The names are those serde writes.
    #[test]
    fn names_are_the_serialised_ones() {
        for k in [
            CapballEffectKind::LinearDrift,
            CapballEffectKind::CyclicDrift,
            CapballEffectKind::SensorGain,
            CapballEffectKind::AxisError,
        ] {
            assert_eq!(serde_json::to_value(k).ok(), Some(k.name().into()));
        }
        for c in Channel::ALL {
            assert_eq!(serde_json::to_value(c).ok(), Some(c.name().into()));
        }
        for a in [RotaryAxis::A, RotaryAxis::C] {
            assert_eq!(serde_json::to_value(a).ok(), Some(a.name().into()));
        }
    }
}
