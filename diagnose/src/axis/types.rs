//! What a positioning diagnosis gives and takes: its options, the report
//! (`docs/datasets.md`, "Diagnosis report"), the extended model and why a run cannot be
//! diagnosed.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use positioning::axis_model::AxisModel;

/// Tuning of the diagnosis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// BIC decrease an effect needs to be reported.
    pub min_bic_gain: f64,
    /// Largest number of held-out folds (cycles are dealt into them).
    pub max_folds: usize,
    /// Family-wise false-alarm probability of the outlier test.
    pub outlier_alpha: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            min_bic_gain: 10.0,
            max_folds: 5,
            outlier_alpha: 0.005,
        }
    }
}

/// What the baseline achieves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Baseline {
    /// Always `static`.
    pub model: String,
    /// RMS residual of the baseline fitted to all readings, µm.
    pub rms_um: f64,
    /// RMS prediction error on held-out cycles, µm.
    pub heldout_rms_um: f64,
}

/// One effect found in the data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finding {
    /// Effect name (`docs/datasets.md`).
    pub effect: String,
    /// Fitted parameters.
    pub params: BTreeMap<String, f64>,
    /// Standard uncertainties of the parameters (same keys, where one exists).
    pub params_u: BTreeMap<String, f64>,
    /// Evidence: decrease of the BIC when the effect is added.
    pub significance: f64,
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
    /// The physical cause a metrologist would check.
    pub cause: String,
    /// Other effects that explain the run about as well in this one's place: the data cannot
    /// tell them apart (BIC within 6; within 2 for one with more parameters).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub alternatives: Vec<Alternative>,
}

/// An effect the data cannot tell from a finding's (`Finding::alternatives`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Alternative {
    pub effect: String,
    /// Its parameters fitted in the finding's place, the rest of the model kept.
    pub params: BTreeMap<String, f64>,
    pub params_u: BTreeMap<String, f64>,
    /// Its BIC minus the finding's (under 6, or 2 with more parameters; negative: it fits
    /// better but was not selected first).
    pub delta_bic: f64,
}

/// How closely a model reproduces the measured per-target statistics when simulated over the
/// same run (mean of several seeds).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reproduction {
    /// RMS over targets and directions of simulated − measured mean deviation x̄, µm.
    pub mean_rms_um: f64,
    /// RMS over targets and directions of simulated − measured `s`, µm.
    pub s_rms_um: f64,
    /// The same for the baseline model (no effects).
    pub baseline_mean_rms_um: f64,
    pub baseline_s_rms_um: f64,
    /// Seeds averaged.
    pub seeds: usize,
}

/// The diagnosis report (`docs/datasets.md`, "Diagnosis report").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnosisReport {
    pub kind: String,
    pub baseline: Baseline,
    /// Most significant first; empty when the baseline explains the data.
    pub findings: Vec<Finding>,
    /// Path of the extended model when one was written.
    pub extended_model: Option<String>,
    /// Simulated vs measured, when checked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reproduction: Option<Reproduction>,
    /// Caveats (missing readings, no real times, ...).
    pub notes: Vec<String>,
    /// Which combination of effects explains the run, or that something is unexplained.
    #[serde(default)]
    pub conclusion: String,
}

impl DiagnosisReport {
    /// The findings' effect names, in report order.
    pub fn effects(&self) -> Vec<&str> {
        self.findings.iter().map(|f| f.effect.as_str()).collect()
    }
}

/// A diagnosis: the report and the extended model.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnosis {
    pub report: DiagnosisReport,
    /// Baseline fitted from the data plus the found effects.
    pub model: AxisModel,
    /// Per reading (order of `data.readings`): residual from the baseline, µm.
    pub baseline_residuals_um: Vec<f64>,
    /// Per reading: residual from the extended model's mean, µm.
    pub residuals_um: Vec<f64>,
    /// Per reading: flagged as an outlier.
    pub outlier: Vec<bool>,
}

/// Why a dataset cannot be diagnosed.
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    /// too few readings to diagnose: need at least 3 cycles of at least 2 targets
    #[error("too few readings to diagnose: need at least 3 cycles of at least 2 targets")]
    TooFewReadings,
    /// A sweep (fewer than 3 cycles) cannot show what the diagnosis looks for.
    #[error(
        "only {cycles} cycle(s): a sweep shows the systematic deviation along the travel and the \
         reversal at each target (see `analyze positioning`), but not the repeatability, a drift \
         or any other effect over time, which need repeated approaches; diagnosis needs at least \
         3 cycles of at least 2 targets"
    )]
    Sweep { cycles: usize },
}
