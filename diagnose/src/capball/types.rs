//! What the CapBall diagnosis takes and shares between its steps: its options, a drift
//! record, the periods a cyclic drift is tried at and an accepted step of the selection.

use super::model::Candidate;
use super::select::ModelFit;

/// Tuning of the CapBall diagnosis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// BIC decrease an effect needs on the identification run.
    pub min_bic_gain: f64,
    /// Decrease of the validation RSS, in noise variances beyond the refit penalty.
    pub min_validation_gain: f64,
    /// Family-wise false-alarm probability of the outlier test.
    pub outlier_alpha: f64,
    /// Highest harmonic of the A and C angles tried.
    pub max_harmonic: u32,
    /// Most effects accepted.
    pub max_effects: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            min_bic_gain: 10.0,
            min_validation_gain: 10.0,
            // Family-wise over ~2 400 residuals per run: a 4.8 σ departure.
            outlier_alpha: 0.001,
            max_harmonic: 4,
            max_effects: 3,
        }
    }
}

/// A drift record at one fixed pose (`docs/datasets.md`: `time_s,ex_um,ey_um,ez_um`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DriftRecord {
    pub time_s: Vec<f64>,
    pub e_um: Vec<[f64; 3]>,
}

/// The periods tried for a cyclic drift: from a drift record when one is given (its best
/// period only), otherwise a log grid from 60 s to four times the span of all runs.
pub(crate) struct Periods {
    pub grid: Vec<f64>,
    /// Period and its standard uncertainty found in the drift record.
    pub from_record: Option<(f64, f64)>,
}

/// One accepted step of the forward selection.
#[derive(Debug, Clone)]
pub(crate) struct Step {
    /// Fits on the identification run (the 14 parameters' shift, the validation check).
    pub before: ModelFit,
    pub after: ModelFit,
    /// Fits on all runs (the evidence and the effect's parameters).
    pub joint_before: ModelFit,
    pub joint_after: ModelFit,
    pub bic_drop: f64,
    pub val_before: (f64, usize, usize),
    pub val_after: (f64, usize, usize),
    /// Other effects whose evidence came within [`Options::min_bic_gain`] of this one's: the
    /// data cannot tell them apart.
    pub rivals: Vec<Candidate>,
}

/// Parameters of the 14 that shift by more than this many baseline standard uncertainties are
/// named in a finding's cause.
pub(crate) const SHIFT_NAMED_SIGMA: f64 = 2.0;
