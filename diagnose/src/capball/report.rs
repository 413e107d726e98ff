//! The CapBall diagnosis report: same field names as the positioning report
//! (`docs/datasets.md`, "Diagnosis report"), its own type, plus what the 14 parameters absorb,
//! their shift once the effects are modelled, and residual profiles.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::checks::{self, ResidualSummary};
use super::model::{Candidate, CapballRun, absorbed_fraction, log_grid, lstsq};
use super::select::{ModelFit, identifiable_basis, model_basis, screen, validate, zero_rows};
use super::types::{DriftRecord, Options, Periods, SHIFT_NAMED_SIGMA, Step};
use geometry::capball::{CapballSetup, Identification, N_PARAMS, PARAM_NAMES};
use geometry::capball_effects::{
    AxisHarmonic, CapballEffect, CapballEffectKind, Channel, CyclicDrift, RotaryAxis,
};

/// What the baseline achieves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CapballBaseline {
    /// `14-parameter link/setup model + white noise`.
    pub model: String,
    /// RMS residual on the identification run, µm (all channels).
    pub rms_um: f64,
    /// RMS residual on the validation runs with the identified parameters, µm.
    pub heldout_rms_um: f64,
}

/// What a CapBall finding names, with its fitted parameters as typed fields.
#[derive(Debug, Clone, PartialEq)]
pub enum CapballFound {
    /// An effect of the CapBall table, as fitted: what the extended model holds.
    Effect(CapballEffect),
    /// Poses far off their neighbours, left out of every fit: how many (all runs), and which
    /// of the identification run (1-based).
    Outliers {
        count: usize,
        identification_poses: Vec<usize>,
    },
    /// Structure left beyond the white sensor noise that no effect explains: its RMS, µm.
    Unexplained { rms_um: f64 },
}

impl CapballFound {
    /// The name of the report (`docs/datasets.md`, CapBall effects).
    pub fn name(&self) -> &'static str {
        match self {
            CapballFound::Effect(e) => e.kind().name(),
            CapballFound::Outliers { .. } => "outliers",
            CapballFound::Unexplained { .. } => "unexplained",
        }
    }

    /// The effect of the CapBall table, if this is one.
    pub fn effect(&self) -> Option<&CapballEffect> {
        match self {
            CapballFound::Effect(e) => Some(e),
            _ => None,
        }
    }
}

impl std::fmt::Display for CapballFound {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// An axis error as the report states it: the direction that carries more (`radial` or
/// `axial`), its amplitude, and the radial and axial amplitudes, µm.
fn radial_axial(h: &AxisHarmonic) -> (&'static str, f64, f64, f64) {
    let ax = if h.axis == RotaryAxis::C { 2 } else { 0 };
    let comp: [f64; 3] = std::array::from_fn(|d| {
        let (c, s) = (h.cos_um[d], h.sin_um[d]);
        (c * c + s * s).sqrt()
    });
    let axial = comp[ax];
    let radial = (0..3)
        .filter(|&d| d != ax)
        .map(|d| comp[d] * comp[d])
        .sum::<f64>()
        .sqrt();
    if axial > radial {
        ("axial", axial, radial, axial)
    } else {
        ("radial", radial, radial, axial)
    }
}

/// One effect found in the data. Serialised with the report's fields (`effect` its name,
/// `params` the parameters it states).
#[derive(Debug, Clone, PartialEq)]
pub struct CapballFinding {
    /// What was found, with its fitted parameters.
    pub effect: CapballFound,
    /// Standard uncertainties of the stated parameters (by their names, where one exists).
    pub params_u: BTreeMap<&'static str, Value>,
    /// Evidence: decrease of the BIC on the identification run.
    pub significance: f64,
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
    /// The physical cause a metrologist would check, and what would confirm it.
    pub cause: String,
    /// Share of the effect's signal on the identification run that the 14 parameters take up.
    pub absorbed_fraction: f64,
    /// Shift of each identified parameter once the effect is modelled, in baseline standard
    /// uncertainties.
    pub param_shift_sigma: BTreeMap<String, f64>,
}

impl CapballFinding {
    /// The parameters the report states, by name (numbers, or names such as `channel`,
    /// `axis`, `direction`; `docs/datasets.md`).
    pub fn params(&self) -> BTreeMap<&'static str, Value> {
        self.stated(true)
    }

    /// [`CapballFinding::params`] without the long ones a reader skims past: an axis error's
    /// coefficients in the housing frame and the outlying poses' numbers.
    pub fn summary_params(&self) -> BTreeMap<&'static str, Value> {
        self.stated(false)
    }

    fn stated(&self, full: bool) -> BTreeMap<&'static str, Value> {
        let mut p = BTreeMap::new();
        match &self.effect {
            CapballFound::Effect(CapballEffect::LinearDrift { rate_um_per_h }) => {
                p.insert("rate_um_per_h", xyz(*rate_um_per_h));
            }
            CapballFound::Effect(CapballEffect::CyclicDrift(c)) => {
                p.insert("period_s", json!(c.period_s));
                p.insert("amplitude_um", xyz(c.amplitude_um));
                p.insert("phase_rad", xyz(c.phase_rad));
            }
            CapballFound::Effect(CapballEffect::SensorGain { channel, gain_pct }) => {
                p.insert("channel", json!(channel.name()));
                p.insert("gain_pct", json!(gain_pct));
            }
            CapballFound::Effect(CapballEffect::AxisError(h)) => {
                let (dir, a, radial, axial) = radial_axial(h);
                p.insert("axis", json!(h.axis.name()));
                p.insert("harmonic", json!(h.harmonic));
                p.insert("direction", json!(dir));
                p.insert("amplitude_um", json!(a));
                p.insert("radial_um", json!(radial));
                p.insert("axial_um", json!(axial));
                if full {
                    // The coefficients in the housing frame, as the simulator's scenario takes
                    // them.
                    p.insert("cos_um", xyz(h.cos_um));
                    p.insert("sin_um", xyz(h.sin_um));
                }
            }
            CapballFound::Outliers {
                count,
                identification_poses,
            } => {
                p.insert("count", json!(count));
                if full {
                    p.insert("identification_poses", json!(identification_poses));
                }
            }
            CapballFound::Unexplained { rms_um } => {
                p.insert("rms_um", json!(rms_um));
            }
        }
        p
    }
}

impl Serialize for CapballFinding {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Repr<'a> {
            effect: &'static str,
            params: BTreeMap<&'static str, Value>,
            params_u: &'a BTreeMap<&'static str, Value>,
            significance: f64,
            heldout_rms_before_um: f64,
            heldout_rms_after_um: f64,
            cause: &'a str,
            absorbed_fraction: f64,
            param_shift_sigma: &'a BTreeMap<String, f64>,
        }
        Repr {
            effect: self.effect.name(),
            params: self.params(),
            params_u: &self.params_u,
            significance: self.significance,
            heldout_rms_before_um: self.heldout_rms_before_um,
            heldout_rms_after_um: self.heldout_rms_after_um,
            cause: &self.cause,
            absorbed_fraction: self.absorbed_fraction,
            param_shift_sigma: &self.param_shift_sigma,
        }
        .serialize(s)
    }
}

/// An effect the 14 parameters take up wholly or partly on this trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Absorption {
    pub effect: CapballEffectKind,
    /// Which form (e.g. `C harmonic 1`, `channel x`).
    pub detail: String,
    /// Column combinations of the effect the parameters reproduce exactly (invisible).
    pub invisible: usize,
    pub of: usize,
    /// Share of the effect's energy the parameters take up (all combinations), 0..1.
    pub energy_absorbed: f64,
    /// The parameters that take up the invisible combinations.
    pub taken_by: Vec<String>,
}

/// One identified parameter before and after modelling the found effects.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParameterShift {
    pub name: String,
    pub baseline: f64,
    pub extended: f64,
    pub u_baseline: f64,
    pub shift_sigma: f64,
}

/// The CapBall diagnosis report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CapballDiagnosisReport {
    /// Always `capball`.
    pub kind: String,
    pub baseline: CapballBaseline,
    /// In the order found (most significant first); empty when the baseline explains the data.
    pub findings: Vec<CapballFinding>,
    /// Path of the extended model when one was written.
    pub extended_model: Option<String>,
    /// Effects this trajectory cannot show (or shows only in part).
    pub absorbed: Vec<Absorption>,
    pub parameters: Vec<ParameterShift>,
    /// Residuals of the final model per run and channel, against time, A and C.
    pub residuals: Vec<ResidualSummary>,
    pub notes: Vec<String>,
}

impl CapballDiagnosisReport {
    /// The findings' effect names, in report order.
    pub fn effects(&self) -> Vec<&str> {
        self.findings.iter().map(|f| f.effect.name()).collect()
    }
}

/// A diagnosis: the report and what a caller needs to write the extended model.
#[derive(Debug, Clone, PartialEq)]
pub struct CapballDiagnosis {
    pub report: CapballDiagnosisReport,
    /// The baseline identification (identification run, no effects).
    pub baseline: Identification,
    /// The 14 parameters identified with the found effects modelled.
    pub params_extended: Vec<f64>,
    /// Per pose of the identification run: residual of the baseline and of the final model.
    pub baseline_residuals_um: Vec<[f64; 3]>,
    pub residuals_um: Vec<[f64; 3]>,
}

/// What the assembly needs from the diagnosis.
pub(crate) struct Context<'a> {
    pub setup: &'a CapballSetup,
    pub ident: &'a CapballRun,
    pub validation: &'a [CapballRun],
    /// All runs concatenated (one clock) and their kept rows.
    pub joint: &'a CapballRun,
    pub joint_keep: &'a [bool],
    pub keep: &'a [bool],
    pub val_keep: &'a [Vec<bool>],
    pub out_id: &'a [bool],
    pub out_val: &'a [Vec<bool>],
    pub opt: &'a Options,
    pub record_period: Option<(f64, f64)>,
}

impl Context<'_> {
    /// White-noise variance on the validation runs (pooled over channels), from the baseline.
    pub(super) fn val_noise_var(&self) -> f64 {
        let p = DVector::from_column_slice(&self.ident_params());
        let mut acc = 0.0;
        for (run, keep) in self.validation.iter().zip(self.val_keep) {
            let r = run.rhs() - run.jac(self.setup) * &p;
            let kp: Vec<bool> = keep.chunks(3).map(|c| c[0]).collect();
            let s = checks::noise_sigma(&r, &kp);
            acc += s.iter().map(|v| v * v).sum::<f64>() / 3.0;
        }
        (acc / self.validation.len().max(1) as f64).max(1e-12)
    }
    fn ident_params(&self) -> Vec<f64> {
        self.setup
            .identify(&self.ident.poses, &self.ident.e_um)
            .map(|i| i.params)
            .unwrap_or_else(|_| vec![0.0; N_PARAMS])
    }
}

fn to_triplets(r: &DVector<f64>) -> Vec<[f64; 3]> {
    r.as_slice().chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn rms(rss: f64, n: usize) -> f64 {
    (rss / n.max(1) as f64).sqrt()
}

/// Period (and its standard uncertainty) of a cyclic drift in a drift record, when a sine
/// plus a line fits clearly better (BIC) than a line alone.
pub(crate) fn record_period(rec: &DriftRecord) -> Option<(f64, f64)> {
    let n = rec.time_s.len();
    let t0 = rec.time_s.iter().copied().fold(f64::INFINITY, f64::min);
    let span = rec.time_s.iter().copied().fold(f64::NEG_INFINITY, f64::max) - t0;
    if n < 20 || span <= 0.0 {
        return None;
    }
    let y = DVector::from_iterator(3 * n, rec.e_um.iter().flat_map(|e| e.iter().copied()));
    let keep = vec![true; 3 * n];
    let rss_at = |period: Option<f64>| -> f64 {
        let k = if period.is_some() { 4 } else { 2 };
        let mut a = DMatrix::zeros(3 * n, 3 * k);
        for (i, t) in rec.time_s.iter().enumerate() {
            let tt = (t - t0) / 3600.0;
            for c in 0..3 {
                a[(3 * i + c, k * c)] = 1.0;
                a[(3 * i + c, k * c + 1)] = tt;
                if let Some(p) = period {
                    let w = std::f64::consts::TAU * (t - t0) / p;
                    a[(3 * i + c, k * c + 2)] = w.sin();
                    a[(3 * i + c, k * c + 3)] = w.cos();
                }
            }
        }
        lstsq(&a, &y, &keep).map(|f| f.rss).unwrap_or(f64::INFINITY)
    };
    let grid = log_grid(60.0, 2.0 * span, 60);
    let (best, rss) = grid
        .iter()
        .map(|&p| (p, rss_at(Some(p))))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let ne = (3 * n) as f64;
    let bic = ne * (rss_at(None) / rss).ln() - 7.0 * ne.ln();
    if !bic.is_finite() || bic < 10.0 {
        return None;
    }
    let (mut lo, mut hi) = (best / 1.2, best * 1.2);
    for _ in 0..40 {
        let (m1, m2) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
        if rss_at(Some(m1)) < rss_at(Some(m2)) {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    let p = 0.5 * (lo + hi);
    let h = p * 1e-3;
    let (r0, rp, rm) = (rss_at(Some(p)), rss_at(Some(p + h)), rss_at(Some(p - h)));
    let curv = (rp + rm - 2.0 * r0) / (h * h);
    let s2 = r0 / (ne - 12.0);
    let u = if curv > 0.0 {
        (2.0 * s2 / curv).sqrt()
    } else {
        f64::NAN
    };
    Some((p, u))
}

pub(crate) fn assemble(
    ctx: &Context,
    base: &Identification,
    baseline: &ModelFit,
    start: &ModelFit,
    fin: &ModelFit,
    steps: &[Step],
    periods: &Periods,
) -> CapballDiagnosis {
    let n_all = 3 * ctx.ident.len();
    let val_all: Vec<Vec<bool>> = ctx
        .validation
        .iter()
        .map(|v| vec![true; 3 * v.len()])
        .collect();
    let (vrss0, vn0, _, _) = validate(ctx.setup, ctx.validation, &val_all, baseline);
    let mut findings = Vec::new();
    if let Some(f) = outlier_finding(ctx, baseline, start, (vrss0, vn0)) {
        findings.push(f);
    }
    for s in steps {
        findings.extend(effect_finding(ctx, base, s, periods));
    }
    let (vrss, vn, _, vres) = validate(ctx.setup, ctx.validation, ctx.val_keep, fin);
    if let Some(f) = unexplained(ctx, fin, (vrss, vn), &vres) {
        findings.push(f);
    }
    let mut residuals = vec![checks::summarise(
        "identification",
        ctx.ident,
        &fin.fit.resid,
        &ctx.keep.chunks(3).map(|c| c[0]).collect::<Vec<_>>(),
    )];
    for ((run, r), k) in ctx.validation.iter().zip(&vres).zip(ctx.val_keep) {
        let kp: Vec<bool> = k.chunks(3).map(|c| c[0]).collect();
        residuals.push(checks::summarise("validation", run, r, &kp));
    }
    let parameters = (0..N_PARAMS)
        .map(|i| ParameterShift {
            name: PARAM_NAMES[i].into(),
            baseline: base.params[i],
            extended: fin.p[i],
            u_baseline: base.std_uncertainty[i],
            shift_sigma: (fin.p[i] - base.params[i]) / base.std_uncertainty[i].max(1e-12),
        })
        .collect();
    let mut notes = Vec::new();
    if let Some((p, u)) = periods.from_record {
        let u = if u.is_finite() {
            format!("± {u:.0} s")
        } else {
            "s (its uncertainty not determined: the fit's residual does not rise on either side of this period)".into()
        };
        notes.push(format!(
            "drift record: cyclic drift with period {p:.0} {u}; the cyclic candidate uses this period"
        ));
    }
    let absorbed = absorption_probes(ctx, start, periods);
    for a in &absorbed {
        if a.invisible > 0 {
            notes.push(format!(
                "{} ({}): {} of {} forms are reproduced exactly by {} and cannot be seen in this data",
                a.effect,
                a.detail,
                a.invisible,
                a.of,
                a.taken_by.join(", ")
            ));
        }
    }
    let baseline_residuals_um = to_triplets(&baseline.fit.resid);
    CapballDiagnosis {
        report: CapballDiagnosisReport {
            kind: "capball".into(),
            baseline: CapballBaseline {
                model: "14-parameter link/setup model + white noise".into(),
                rms_um: rms(baseline.fit.rss, n_all),
                heldout_rms_um: rms(vrss0, vn0),
            },
            findings,
            extended_model: None,
            absorbed,
            parameters,
            residuals,
            notes,
        },
        baseline: base.clone(),
        params_extended: fin.p.iter().copied().collect(),
        baseline_residuals_um,
        residuals_um: to_triplets(&fin.fit.resid),
    }
}

fn outlier_finding(
    ctx: &Context,
    baseline: &ModelFit,
    start: &ModelFit,
    val0: (f64, usize),
) -> Option<CapballFinding> {
    let n_id = ctx.out_id.iter().filter(|o| **o).count();
    let n_val: usize = ctx
        .out_val
        .iter()
        .map(|o| o.iter().filter(|v| **v).count())
        .sum();
    if n_id + n_val == 0 {
        return None;
    }
    let (vrss, vn, _, _) = validate(ctx.setup, ctx.validation, ctx.val_keep, start);
    let identification_poses: Vec<usize> = ctx
        .out_id
        .iter()
        .enumerate()
        .filter(|(_, o)| **o)
        .map(|(i, _)| i + 1)
        .collect();
    let s2 = start.fit.rss / (ctx.keep.iter().filter(|k| **k).count().max(1) as f64);
    let excess: f64 = baseline.fit.rss - start.fit.rss;
    Some(CapballFinding {
        effect: CapballFound::Outliers {
            count: n_id + n_val,
            identification_poses,
        },
        params_u: BTreeMap::new(),
        significance: excess / s2.max(1e-12) - (n_id as f64) * (3.0 * ctx.ident.len() as f64).ln(),
        heldout_rms_before_um: rms(val0.0, val0.1),
        heldout_rms_after_um: rms(vrss, vn),
        cause: format!(
            "{n_id} identification and {n_val} validation poses lie far off their neighbours (left out of every fit): a chip or coolant drop on the ball, a vibration during the reading, or a steady-value window cut short; repeat those poses to confirm"
        ),
        absorbed_fraction: 0.0,
        param_shift_sigma: BTreeMap::new(),
    })
}

fn shift_sigma(
    base: &Identification,
    before: &DVector<f64>,
    after: &DVector<f64>,
) -> BTreeMap<String, f64> {
    (0..N_PARAMS)
        .map(|i| {
            (
                PARAM_NAMES[i].to_string(),
                (after[i] - before[i]) / base.std_uncertainty[i].max(1e-12),
            )
        })
        .collect()
}

fn effect_finding(
    ctx: &Context,
    base: &Identification,
    s: &Step,
    periods: &Periods,
) -> Option<CapballFinding> {
    let c = s.after.terms.last().map(|t| t.cand)?;
    // The effect's parameters come from all runs (one clock), the 14 parameters' shift from
    // the identification run.
    let (b, cov) = s.joint_after.coefs.last().cloned().unwrap_or_default();
    let n_eq = ctx.joint_keep.iter().filter(|k| **k).count();
    let s2 = s.joint_after.fit.rss / (n_eq.saturating_sub(s.joint_after.n_params())).max(1) as f64;
    let cov = cov * s2;
    let model = ctx.ident.jac(ctx.setup) * &s.after.p;
    let signal = c.columns(ctx.ident, &model) * &b;
    let j = ctx.ident.jac(ctx.setup);
    let absorbed = absorbed_fraction(j, &signal, ctx.keep);
    let shift = shift_sigma(base, &s.before.p, &s.after.p);
    let effect = c.effect(&b);
    let (params_u, what) = describe(ctx, &effect, &b, &cov, s, periods);
    let mut named: Vec<(&String, &f64)> = shift
        .iter()
        .filter(|(_, v)| v.abs() >= SHIFT_NAMED_SIGMA)
        .collect();
    named.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    let shift_text = if named.is_empty() {
        "no identified parameter moves by 2 σ or more once it is modelled".to_string()
    } else {
        let list: Vec<String> = named
            .iter()
            .take(4)
            .map(|(n, v)| format!("{n} {v:+.1} σ"))
            .collect();
        format!("modelling it moves {}", list.join(", "))
    };
    let rivals = if s.rivals.is_empty() {
        String::new()
    } else {
        let r: Vec<String> = s.rivals.iter().map(short_name).collect();
        format!(
            ". The data explain it almost as well by {} (evidence within the BIC threshold): they cannot tell these apart; a sensor-frame cube calibration, a runout test of the rotary axes or a drift record at one fixed pose does",
            r.join(" or ")
        )
    };
    Some(CapballFinding {
        effect: CapballFound::Effect(effect),
        params_u,
        significance: s.bic_drop,
        heldout_rms_before_um: rms(s.val_before.0, s.val_before.1),
        heldout_rms_after_um: rms(s.val_after.0, s.val_after.1),
        cause: format!(
            "{what}. The 14 parameters take up {:.0} % of its signal on the identification run; {shift_text}{rivals}",
            100.0 * absorbed
        ),
        absorbed_fraction: absorbed,
        param_shift_sigma: shift,
    })
}

fn short_name(c: &Candidate) -> String {
    match c {
        Candidate::SensorGain { channel } => {
            format!("a gain error of channel {}", channel.name())
        }
        Candidate::AxisError { axis, harmonic } => {
            format!(
                "an error motion of {} at {harmonic} per revolution",
                axis.name()
            )
        }
        Candidate::LinearDrift => "a linear drift".into(),
        Candidate::CyclicDrift { period_s } => {
            format!("a cyclic drift ({:.1} min)", period_s / 60.0)
        }
    }
}

/// Amplitude of a (sin, cos) pair and its standard uncertainty.
fn amp(b: &DVector<f64>, cov: &DMatrix<f64>, i: usize) -> (f64, f64) {
    let (s, c) = (b[i], b[i + 1]);
    let a = (s * s + c * c).sqrt();
    if a <= 0.0 {
        return (0.0, cov[(i, i)].max(0.0).sqrt());
    }
    let var = (s * s * cov[(i, i)] + c * c * cov[(i + 1, i + 1)] + 2.0 * s * c * cov[(i, i + 1)])
        / (a * a);
    (a, var.max(0.0).sqrt())
}

fn xyz(v: [f64; 3]) -> Value {
    json!({"x": v[0], "y": v[1], "z": v[2]})
}

/// The uncertainties of a found effect's stated parameters and the sentence on its cause.
type Described = (BTreeMap<&'static str, Value>, String);

/// `effect` fitted with the columns' coefficients `b` (covariance `cov`).
fn describe(
    ctx: &Context,
    effect: &CapballEffect,
    b: &DVector<f64>,
    cov: &DMatrix<f64>,
    s: &Step,
    periods: &Periods,
) -> Described {
    let mut u = BTreeMap::new();
    let text = match effect {
        CapballEffect::LinearDrift { rate_um_per_h: r } => {
            u.insert(
                "rate_um_per_h",
                xyz(std::array::from_fn(|k| cov[(k, k)].max(0.0).sqrt())),
            );
            format!(
                "steady drift of the measuring loop, {:+.2}/{:+.2}/{:+.2} µm/h in x/y/z, the same at every pose: the spindle or the structure warming; a drift record at one fixed pose confirms it",
                r[0], r[1], r[2]
            )
        }
        CapballEffect::CyclicDrift(CyclicDrift {
            period_s,
            amplitude_um: a,
            ..
        }) => {
            let period_s = *period_s;
            let ua: [f64; 3] = std::array::from_fn(|k| amp(b, cov, 2 * k).1);
            let up = periods
                .from_record
                .map(|r| r.1)
                .unwrap_or_else(|| period_u(ctx, s, period_s));
            u.insert("period_s", json!(up));
            u.insert("amplitude_um", xyz(ua));
            let span = span_s(ctx.joint);
            let caveat = if period_s > 1.5 * span && periods.from_record.is_none() {
                format!(
                    " (the period is longer than the {:.1} min the runs cover and poorly determined: a drift record over two periods fixes it)",
                    span / 60.0
                )
            } else {
                String::new()
            };
            format!(
                "periodic drift of the measuring loop, period {:.1} min{caveat}, amplitude {:.2}/{:.2}/{:.2} µm in x/y/z (half peak to valley), the same at every pose: the spindle's cooling cycle (paper 001); a drift record at one fixed pose confirms it",
                period_s / 60.0,
                a[0],
                a[1],
                a[2]
            )
        }
        CapballEffect::SensorGain { channel, gain_pct } => {
            u.insert("gain_pct", json!(100.0 * cov[(0, 0)].max(0.0).sqrt()));
            format!(
                "the {} capacitive channel reads {:+.2} % off: its gain in the sensor-frame transform is wrong; a new 125-point cube calibration (paper 001, eq. 8) confirms it",
                channel.name(),
                gain_pct
            )
        }
        CapballEffect::AxisError(h) => {
            let (dir, a, _, _) = radial_axial(h);
            let uu = (0..6).map(|i| cov[(i, i)]).sum::<f64>().max(0.0).sqrt() / 6f64.sqrt();
            u.insert("amplitude_um", json!(uu));
            format!(
                "{dir} error motion of the {} axis at {} per revolution, {a:.2} µm, which the link-error model lacks (bearing runout or wobble); a runout test of the {} axis (ISO 230-7) confirms it",
                h.axis.name(),
                h.harmonic,
                h.axis.name()
            )
        }
    };
    (u, text)
}

fn span_s(run: &CapballRun) -> f64 {
    let t0 = run.time_s.iter().copied().fold(f64::INFINITY, f64::min);
    run.time_s.iter().copied().fold(f64::NEG_INFINITY, f64::max) - t0
}

/// Standard uncertainty of a fitted period from the curvature of the RSS around it.
fn period_u(ctx: &Context, s: &Step, period: f64) -> f64 {
    let q = model_basis(ctx.setup, ctx.joint, &s.joint_before, ctx.joint_keep);
    let drss = |p: f64| {
        screen(
            ctx.setup,
            ctx.joint,
            ctx.joint_keep,
            &s.joint_before,
            &q,
            Candidate::CyclicDrift { period_s: p },
        )
        .map(|x| x.drss)
        .unwrap_or(0.0)
    };
    let h = period * 2e-3;
    let curv = -(drss(period + h) + drss(period - h) - 2.0 * drss(period)) / (h * h);
    let n_eq = ctx.joint_keep.iter().filter(|k| **k).count();
    let s2 = s.joint_after.fit.rss / (n_eq.saturating_sub(s.joint_after.n_params())).max(1) as f64;
    if curv > 0.0 {
        (2.0 * s2 / curv).sqrt()
    } else {
        f64::NAN
    }
}

/// `unexplained`: the final model's residual exceeds the white-noise level by more than five
/// standard deviations of that comparison, on the identification or a validation run.
fn unexplained(
    ctx: &Context,
    fin: &ModelFit,
    val: (f64, usize),
    vres: &[DVector<f64>],
) -> Option<CapballFinding> {
    let kp: Vec<bool> = ctx.keep.chunks(3).map(|c| c[0]).collect();
    let sig = checks::noise_sigma(&fin.fit.resid, &kp);
    let s2 = sig.iter().map(|v| v * v).sum::<f64>() / 3.0;
    let n_eq = ctx.keep.iter().filter(|k| **k).count();
    let var_id = fin.fit.rss / (n_eq.saturating_sub(fin.n_params())).max(1) as f64;
    let sd = |n: usize| (2.0 / (0.37 * n as f64) + 2.0 / n as f64).sqrt();
    let z_id = (var_id / s2.max(1e-12) - 1.0) / sd(n_eq);
    let mut s2v = 0.0;
    for (r, k) in vres.iter().zip(ctx.val_keep) {
        let kp: Vec<bool> = k.chunks(3).map(|c| c[0]).collect();
        s2v += checks::noise_sigma(r, &kp)
            .iter()
            .map(|v| v * v)
            .sum::<f64>()
            / 3.0;
    }
    let s2v = s2v / vres.len().max(1) as f64;
    let var_v = val.0 / val.1.max(1) as f64;
    let z_v = (var_v / s2v.max(1e-12) - 1.0) / sd(val.1);
    let z = z_id.max(z_v);
    if z < 5.0 {
        return None;
    }
    let left = (var_id - s2).max(var_v - s2v).max(0.0).sqrt();
    Some(CapballFinding {
        effect: CapballFound::Unexplained { rms_um: left },
        params_u: BTreeMap::new(),
        significance: z,
        heldout_rms_before_um: rms(val.0, val.1),
        heldout_rms_after_um: rms(val.0, val.1),
        cause: format!(
            "structure of {left:.2} µm RMS is left beyond the white sensor noise ({:.2} µm from pose-to-pose differences) that no effect of the CapBall table explains; the residual profiles against time, A and C show where it lies: a drift record at one fixed pose separates a drift of the measuring loop from a machine error, a repeated run with the same trajectory separates repeatable errors from random ones",
            s2.sqrt()
        ),
        absorbed_fraction: 0.0,
        param_shift_sigma: BTreeMap::new(),
    })
}

/// Which candidate effects the 14 parameters take up on this identification trajectory.
fn absorption_probes(ctx: &Context, start: &ModelFit, periods: &Periods) -> Vec<Absorption> {
    let j = ctx.ident.jac(ctx.setup);
    let mut jk = j.clone();
    zero_rows(&mut jk, ctx.keep);
    let q = jk.clone().qr().q();
    let model = j * &start.p;
    let mut probes: Vec<(Candidate, String)> = vec![
        (Candidate::LinearDrift, "x, y, z".into()),
        (
            Candidate::CyclicDrift {
                period_s: periods.grid.last().copied().unwrap_or(600.0),
            },
            "longest period tried".into(),
        ),
    ];
    for channel in Channel::ALL {
        probes.push((
            Candidate::SensorGain { channel },
            format!("channel {}", channel.name()),
        ));
    }
    for axis in [RotaryAxis::A, RotaryAxis::C] {
        for harmonic in 1..=ctx.opt.max_harmonic {
            probes.push((
                Candidate::AxisError { axis, harmonic },
                format!("{} harmonic {harmonic}", axis.name()),
            ));
        }
    }
    let mut out = Vec::new();
    for (c, detail) in probes {
        let mut x = c.columns(ctx.ident, &model);
        zero_rows(&mut x, ctx.keep);
        let proj = &q * (q.transpose() * &x);
        let xt = &x - &proj;
        let energy = proj.norm_squared() / x.norm_squared().max(1e-300);
        let (basis, invisible) = identifiable_basis(&x, &xt);
        if invisible == 0 && energy < 0.5 {
            continue;
        }
        let taken_by = if invisible > 0 {
            taken_by(&jk, &x, &basis, ctx.keep)
        } else {
            Vec::new()
        };
        out.push(Absorption {
            effect: c.kind(),
            detail,
            invisible,
            of: x.ncols(),
            energy_absorbed: energy,
            taken_by,
        });
    }
    out
}

/// Parameters that reproduce the combinations of `x` outside `basis` (the invisible ones).
fn taken_by(
    j: &DMatrix<f64>,
    x: &DMatrix<f64>,
    basis: &DMatrix<f64>,
    keep: &[bool],
) -> Vec<String> {
    let k = x.ncols();
    // Complement of the identifiable basis: project the unit vectors off it.
    let bq = if basis.ncols() > 0 {
        basis.clone().qr().q()
    } else {
        DMatrix::zeros(k, 0)
    };
    let mut names: Vec<String> = Vec::new();
    for c in 0..k {
        let mut e = DVector::zeros(k);
        e[c] = 1.0;
        let v = &e - &bq * (bq.transpose() * &e);
        if v.norm() < 1e-6 {
            continue;
        }
        let sig = x * v;
        if let Some(f) = lstsq(j, &sig, keep) {
            let w: Vec<f64> = (0..N_PARAMS)
                .map(|i| (f.coef[i] * j.column(i).norm()).abs())
                .collect();
            let tot: f64 = w.iter().sum();
            for i in 0..N_PARAMS {
                if w[i] > 0.2 * tot && !names.contains(&PARAM_NAMES[i].to_string()) {
                    names.push(PARAM_NAMES[i].into());
                }
            }
        }
    }
    names
}
