//! Steady-value detection: one value per programmed pose from a sampled signal.
//!
//! Public surface (used by the daemon and replay):
//! - [`PoseValue`], [`PoseStatus`]: the result for one instrument at one pose;
//! - `SteadyDetector`: fed samples `(t_ns, values, valid)` and triggers in time order, it
//!   emits `PoseValue`s.

use serde::{Deserialize, Serialize};

/// Why a pose could not be measured, or `Ok`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseStatus {
    Ok,
    /// The signal did not settle before the next motion.
    NeverSteady,
    /// Too few valid samples (beam interrupted, over-range, off the diode).
    BeamInvalid,
    /// The device delivered no samples during the dwell (unplugged, stopped).
    DeviceAway,
    /// An exact-stop trigger was expected but missing (detected from motion/dwell triggers).
    TriggerMissing,
}

/// One steady value of one instrument at one pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseValue {
    pub pose: u32,
    pub status: PoseStatus,
    /// Samples averaged (0 when not ok).
    pub n: usize,
    /// Per channel mean, in the channel order the detector was built with (empty when not ok).
    pub mean: Vec<f64>,
    /// Per channel sample standard deviation.
    pub std: Vec<f64>,
    /// Host times of the first and last averaged sample, ns since the Unix epoch (or the dwell
    /// bounds when not ok).
    pub t_first_ns: u64,
    pub t_last_ns: u64,
}
