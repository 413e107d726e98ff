//! What a positioning diagnosis gives and takes: its options, the report
//! (`docs/datasets.md`, "Diagnosis report"), the extended model and why a run cannot be
//! diagnosed.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use positioning::axis_model::{AxisModel, Effect, EffectKind};

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

/// What a finding names, with its fitted parameters as typed fields.
#[derive(Debug, Clone, PartialEq)]
pub enum Found {
    /// An effect of the axis model, as fitted: what the extended model simulates.
    Effect(Effect),
    /// Structure left that no effect of the vocabulary explains (not simulated): the RMS of
    /// what is left, µm.
    Unexplained { rms_um: f64 },
}

impl Found {
    /// The name of the report (`docs/datasets.md`).
    pub fn name(&self) -> &'static str {
        match self {
            Found::Effect(e) => e.kind().name(),
            Found::Unexplained { .. } => "unexplained",
        }
    }

    /// The model effect's kind (None for `unexplained`).
    pub fn kind(&self) -> Option<EffectKind> {
        match self {
            Found::Effect(e) => Some(e.kind()),
            Found::Unexplained { .. } => None,
        }
    }

    /// The effect of the model, if this is one.
    pub fn model_effect(&self) -> Option<&Effect> {
        match self {
            Found::Effect(e) => Some(e),
            Found::Unexplained { .. } => None,
        }
    }
}

impl std::fmt::Display for Found {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What a finding states beside its effect's model parameters (`docs/datasets.md`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Stated {
    /// A scale change: the scale reached by the end of the run, µm/m (the model's
    /// `scale_ppm` is the scale it tends to).
    pub scale_end_ppm: Option<f64>,
    /// A scale change the measured material temperature explains: the expansion coefficient,
    /// µm/(m·K).
    pub alpha_um_per_m_k: Option<f64>,
    /// Outliers: the number of readings flagged.
    pub count: Option<usize>,
}

/// The parameters a report states for an effect (`params` of `docs/datasets.md`): the
/// model's, where the report states them differently the report's.
fn stated_params(effect: &Found, stated: &Stated) -> BTreeMap<&'static str, f64> {
    let e = match effect {
        Found::Unexplained { rms_um } => return BTreeMap::from([("rms_um", *rms_um)]),
        Found::Effect(e) => *e,
    };
    let mut p = match e {
        Effect::LinearDrift { rate_um_per_h } => BTreeMap::from([("rate_um_per_h", rate_um_per_h)]),
        Effect::ExponentialWarmup {
            amplitude_um,
            tau_s,
        } => BTreeMap::from([("amplitude_um", amplitude_um), ("tau_s", tau_s)]),
        Effect::CyclicDrift {
            period_s,
            amplitude_um,
            ..
        } => BTreeMap::from([("period_s", period_s), ("amplitude_um", amplitude_um)]),
        Effect::ThermalExpansion { scale_ppm, tau_s } => BTreeMap::from([
            ("scale_ppm", stated.scale_end_ppm.unwrap_or(scale_ppm)),
            ("tau_s", tau_s),
        ]),
        Effect::LocalAnomaly { index, std_ratio } => {
            BTreeMap::from([("index", index as f64), ("std_ratio", std_ratio)])
        }
        Effect::Outliers { .. } => BTreeMap::new(),
        Effect::Step { time_s, size_um } => {
            BTreeMap::from([("size_um", size_um), ("time_s", time_s)])
        }
        Effect::ReversalDrift { change_um, .. } => BTreeMap::from([("change_um", change_um)]),
        Effect::CycleOffsets { std_um } => BTreeMap::from([("std_um", std_um)]),
    };
    if let Some(a) = stated.alpha_um_per_m_k {
        p.insert("alpha_um_per_m_k", a);
    }
    if let Some(n) = stated.count {
        p.insert("count", n as f64);
    }
    p
}

/// One effect found in the data. Serialised with the report's fields (`effect` its name,
/// `params` the parameters it states).
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// What was found, with its fitted parameters.
    pub effect: Found,
    /// What the report states beside the model's parameters.
    pub stated: Stated,
    /// Standard uncertainties of the stated parameters (by their names, where one exists).
    pub params_u: BTreeMap<&'static str, f64>,
    /// Evidence: decrease of the BIC when the effect is added.
    pub significance: f64,
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
    /// The physical cause a metrologist would check.
    pub cause: String,
    /// Other effects that explain the run about as well in this one's place: the data cannot
    /// tell them apart (BIC within 6; within 2 for one with more parameters).
    pub alternatives: Vec<Alternative>,
}

impl Finding {
    /// The parameters the report states, by name (`docs/datasets.md`).
    pub fn params(&self) -> BTreeMap<&'static str, f64> {
        stated_params(&self.effect, &self.stated)
    }
}

/// A finding's or an alternative's `effect`, `params` and `params_u`, as the report writes
/// them.
#[derive(Serialize)]
struct Named<'a> {
    effect: &'static str,
    params: BTreeMap<&'static str, f64>,
    params_u: &'a BTreeMap<&'static str, f64>,
}

impl<'a> Named<'a> {
    fn new(effect: &Found, stated: &Stated, params_u: &'a BTreeMap<&'static str, f64>) -> Self {
        Named {
            effect: effect.name(),
            params: stated_params(effect, stated),
            params_u,
        }
    }
}

impl Serialize for Finding {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Repr<'a> {
            #[serde(flatten)]
            named: Named<'a>,
            significance: f64,
            heldout_rms_before_um: f64,
            heldout_rms_after_um: f64,
            cause: &'a str,
            #[serde(skip_serializing_if = "<[_]>::is_empty")]
            alternatives: &'a [Alternative],
        }
        Repr {
            named: Named::new(&self.effect, &self.stated, &self.params_u),
            significance: self.significance,
            heldout_rms_before_um: self.heldout_rms_before_um,
            heldout_rms_after_um: self.heldout_rms_after_um,
            cause: &self.cause,
            alternatives: &self.alternatives,
        }
        .serialize(s)
    }
}

/// An effect the data cannot tell from a finding's (`Finding::alternatives`). Serialised as
/// the report's `effect`, `params`, `params_u` and `delta_bic`.
#[derive(Debug, Clone, PartialEq)]
pub struct Alternative {
    /// The effect, its parameters fitted in the finding's place, the rest of the model kept.
    pub effect: Found,
    pub stated: Stated,
    pub params_u: BTreeMap<&'static str, f64>,
    /// Its BIC minus the finding's (under 6, or 2 with more parameters; negative: it fits
    /// better but was not selected first).
    pub delta_bic: f64,
}

impl Alternative {
    /// The parameters the report states, by name.
    pub fn params(&self) -> BTreeMap<&'static str, f64> {
        stated_params(&self.effect, &self.stated)
    }
}

impl Serialize for Alternative {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Repr<'a> {
            #[serde(flatten)]
            named: Named<'a>,
            delta_bic: f64,
        }
        Repr {
            named: Named::new(&self.effect, &self.stated, &self.params_u),
            delta_bic: self.delta_bic,
        }
        .serialize(s)
    }
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
#[derive(Debug, Clone, PartialEq, Serialize)]
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
    pub conclusion: String,
}

impl DiagnosisReport {
    /// The findings' effect names, in report order.
    pub fn effects(&self) -> Vec<&str> {
        self.findings.iter().map(|f| f.effect.name()).collect()
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
    /// The run is too large for the diagnosis's memory: readings × (targets + cycles) past
    /// [`super::MAX_SIZE`].
    #[error(
        "{readings} readings of {targets} targets in {cycles} cycles are too many to diagnose: \
         readings × (targets + cycles) = {size} is past {max} (about 1 GB of memory; a million \
         rows grew to 21 GB); diagnose a part of the run (fewer cycles or targets)"
    )]
    TooLarge {
        readings: usize,
        targets: usize,
        cycles: usize,
        size: usize,
        max: usize,
    },
}
