//! Settings of the steady-value detector (docs/design.md; their meaning in `metrolog-detect`).

use serde::{Deserialize, Serialize};

/// What delimits the poses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DetectorMode {
    /// The CNC's triggers (exact stop opens a dwell; motion start / dwell end close it).
    #[default]
    Triggers,
    /// No triggers: standstill plateaus found in the signal, numbered 1, 2, 3, …; triggers
    /// pushed in this mode are ignored.
    Plateaus,
}

/// Settings of the steady-value detector (see the module documentation for their meaning and
/// the reasons for the defaults).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SteadyConfig {
    pub mode: DetectorMode,
    /// Samples averaged per pose (and size of the tested window).
    pub samples: usize,
    /// Largest R statistic of a steady window.
    pub r_crit: f64,
    /// Largest deviation from the window mean, in units of the successive-difference sigma.
    pub outlier_k: f64,
    /// A channel whose window std is at most this (channel units) is stationary.
    pub std_floor: f64,
    /// Trigger-free mode: smallest move of the mean that ends a plateau (channel units).
    pub min_step: f64,
    /// Most samples kept for late triggers and missing-trigger recovery (2¹⁸: 13 s at
    /// 20 kHz, 260 s at 1 kHz — longer than a motion plus dwell).
    pub max_history: usize,
}

impl Default for SteadyConfig {
    fn default() -> Self {
        SteadyConfig {
            mode: DetectorMode::Triggers,
            samples: 150,
            r_crit: 1.5,
            outlier_k: 5.0,
            std_floor: 0.0,
            min_step: 0.0,
            max_history: 1 << 18,
        }
    }
}

/// A detector setting that cannot work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SteadyError {
    /// detector `samples` is {0}; it must be at least 3 (the steady test needs a variance of
    /// successive differences)
    #[error(
        "detector `samples` is {0}; it must be at least 3 (the steady test needs a variance of successive differences)"
    )]
    TooFewSamples(usize),
    /// detector `{0}` is {1}; it must be a finite number > 0
    #[error("detector `{0}` is {1}; it must be a finite number > 0")]
    BadThreshold(&'static str, f64),
    /// detector `{0}` is {1}; it must be a finite number >= 0
    #[error("detector `{0}` is {1}; it must be a finite number >= 0")]
    Negative(&'static str, f64),
    /// detector `max_history` is {0}; it must be at least `samples` ({1})
    #[error("detector `max_history` is {0}; it must be at least `samples` ({1})")]
    HistoryTooShort(usize, usize),
    /// the detector needs at least one channel
    #[error("the detector needs at least one channel")]
    NoChannels,
}

impl SteadyConfig {
    pub fn validate(&self) -> Result<(), SteadyError> {
        if self.samples < 3 {
            return Err(SteadyError::TooFewSamples(self.samples));
        }
        for (name, v) in [("r_crit", self.r_crit), ("outlier_k", self.outlier_k)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SteadyError::BadThreshold(name, v));
            }
        }
        for (name, v) in [("std_floor", self.std_floor), ("min_step", self.min_step)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SteadyError::Negative(name, v));
            }
        }
        if self.max_history < self.samples {
            return Err(SteadyError::HistoryTooShort(self.max_history, self.samples));
        }
        Ok(())
    }
}

/// Steady-value detector settings of each instrument.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorSettings {
    /// The instruments of the run: only these get pose values (an instrument that is not
    /// part of the run would otherwise get a `device_away` at every pose).
    pub instruments: Vec<crate::Instrument>,
    pub interferometer: SteadyConfig,
    pub capball: SteadyConfig,
    pub psd: SteadyConfig,
    /// Which time of a CNC trigger opens and closes the dwells. Logs written before this
    /// setting existed used the arrival time, and replay must reproduce them: a missing key
    /// reads as [`TriggerTime::Arrival`]; new runs write [`TriggerTime::NcClockSettled`].
    #[serde(default = "TriggerTime::arrival")]
    pub trigger_time: TriggerTime,
    /// Datum epochs of the interferometer (docs/design.md, "Datum epochs"): a run whose first
    /// trigger is not its program start (the service started or restarted mid-program) has no
    /// datum of its own, and a re-reference's first pose value is the reference visit, not a
    /// measurement. Logs written before this setting did neither: a missing key reads `false`
    /// so replay reproduces them; new runs write `true`.
    #[serde(default)]
    pub datum_epochs: bool,
    /// Where the interferometer must read at each pose (docs/design.md, "Values off their
    /// target"): an `ok` value farther than the tolerance from its pose's target becomes
    /// `off_target`. Runs without a trajectory, and logs written before this setting, have
    /// none (a missing key reads `None`, so replay reproduces them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_targets: Option<PositionTargets>,
}

/// Largest distance of an `ok` interferometer value from its pose's target, µm: machine errors
/// are micrometres to tenths of a millimetre; 2 mm more is a value from another pose (a dwell
/// placed on the wrong samples) or a zero that is not the datum.
pub const OFF_TARGET_TOL_UM: f64 = 2000.0;

/// Least tolerance of a pose near another target, µm: below half a millimetre a worn
/// machine's own error could be read as a misplaced dwell.
pub const OFF_TARGET_FLOOR_UM: f64 = 500.0;

/// The interferometer reading each pose of the trajectory should give, µm: `(x_mm − datum
/// X)·1000` of pose 1, 2, 3, … in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionTargets {
    /// Pose k's target is `targets_um[k − 1]`; poses past the end have none.
    pub targets_um: Vec<f64>,
    /// Largest distance of an `ok` value from its target, µm.
    pub tol_um: f64,
    /// When set, a pose's tolerance is also at most half the distance to the nearest other
    /// target, but not below this (µm; targets closer than it count as the same position):
    /// a dwell placed on the samples of a pose 1.2 mm away is caught, not only of one 2 mm
    /// away. Logs written before this key have `tol_um` for every pose (a missing key reads
    /// `None`, so replay reproduces them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub floor_um: Option<f64>,
}

impl PositionTargets {
    /// The target of pose `pose` (1-based), if it has one.
    pub fn target_um(&self, pose: u32) -> Option<f64> {
        let k = usize::try_from(pose).ok()?.checked_sub(1)?;
        self.targets_um.get(k).copied()
    }

    /// Largest distance of an `ok` value of pose `pose` from its target, µm, if it has one.
    pub fn tolerance_um(&self, pose: u32) -> Option<f64> {
        let want = self.target_um(pose)?;
        let Some(floor) = self.floor_um else {
            return Some(self.tol_um);
        };
        let nearest = self
            .targets_um
            .iter()
            .map(|t| (t - want).abs())
            .filter(|d| *d > floor)
            .fold(f64::INFINITY, f64::min);
        Some((nearest / 2.0).min(self.tol_um).max(floor.min(self.tol_um)))
    }

    pub fn validate(&self) -> Result<(), SteadyError> {
        if !(self.tol_um.is_finite() && self.tol_um > 0.0) {
            return Err(SteadyError::BadThreshold(
                "position_targets.tol_um",
                self.tol_um,
            ));
        }
        if let Some(f) = self.floor_um.filter(|f| !(f.is_finite() && *f > 0.0)) {
            return Err(SteadyError::BadThreshold("position_targets.floor_um", f));
        }
        match self.targets_um.iter().find(|t| !t.is_finite()) {
            Some(t) => Err(SteadyError::BadThreshold("position_targets.targets_um", *t)),
            None => Ok(()),
        }
    }
}

/// Which time of a CNC trigger places the dwells on the host axis, where the samples sit at
/// their clock-fitted device times (docs/design.md, timing model).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TriggerTime {
    /// The frame's NC clock (`nc_ms`) fitted against the host clock (`metrolog_detect::NcClock`):
    /// when the NC says the event happened; each trigger placed with the fit as it stood when
    /// its frame came. Runs of version 0.1 before the settled placement.
    NcClock,
    /// As [`TriggerTime::NcClock`], but a trigger is placed once the fit is settled (it has its
    /// line) or the NC clock has run [`NC_SETTLE_US`] past it, with the fit as it then stands:
    /// frames that came in one late burst at the start of a program, before any prompt frame,
    /// are placed by the later prompt ones instead of at the burst's arrival.
    #[default]
    NcClockSettled,
    /// The host arrival time of the frame: late by the adapter's, the link's and the
    /// scheduler's delays (hundreds of ms on a loaded host). Only for replaying old logs.
    Arrival,
}

/// How far the NC clock must run past an unsettled trigger before it is placed anyway, µs:
/// one window of the NC clock fit.
pub const NC_SETTLE_US: u64 = 2_000_000;

impl TriggerTime {
    fn arrival() -> TriggerTime {
        TriggerTime::Arrival
    }
}

impl Default for DetectorSettings {
    fn default() -> Self {
        DetectorSettings {
            instruments: crate::Instrument::POSE_VALUED.to_vec(),
            interferometer: SteadyConfig::default(),
            capball: SteadyConfig::default(),
            psd: SteadyConfig::default(),
            trigger_time: TriggerTime::NcClockSettled,
            datum_epochs: true,
            position_targets: None,
        }
    }
}

impl DetectorSettings {
    /// Same settings, `samples` changed for every instrument.
    pub fn with_samples(mut self, samples: usize) -> Self {
        self.interferometer.samples = samples;
        self.capball.samples = samples;
        self.psd.samples = samples;
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn targets(floor_um: Option<f64>) -> PositionTargets {
        PositionTargets {
            // Poses 1-5: an overtravel 3 mm before, targets 1.2 mm apart, a repeat of the
            // last (the same position counts once), then one far away.
            targets_um: vec![-3000.0, 0.0, 1200.0, 1200.0, 50_000.0, 50_100.0],
            tol_um: OFF_TARGET_TOL_UM,
            floor_um,
        }
    }

    #[test]
    fn a_poses_tolerance_is_half_the_way_to_its_nearest_other_target_within_floor_and_limit() {
        let t = targets(Some(OFF_TARGET_FLOOR_UM));
        let tol: Vec<Option<f64>> = (1..=7).map(|k| t.tolerance_um(k)).collect();
        assert_eq!(
            tol,
            vec![
                Some(1500.0),
                Some(600.0),
                Some(600.0),
                Some(600.0),
                Some(2000.0),
                Some(2000.0),
                None
            ]
        );
        // Without the floor (logs written before it), the fixed tolerance for every pose.
        let old = targets(None);
        assert!((1..=6).all(|k| old.tolerance_um(k) == Some(OFF_TARGET_TOL_UM)));
        assert_eq!(old.tolerance_um(0), None);
        // A floor above the limit does not raise the limit.
        let mut high = targets(Some(5000.0));
        high.tol_um = 1000.0;
        assert_eq!(high.tolerance_um(2), Some(1000.0));
        // A floor that is not a positive number is refused.
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(targets(Some(bad)).validate().is_err(), "{bad}");
        }
        assert!(t.validate().is_ok());
    }
}
