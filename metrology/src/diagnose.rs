//! Diagnosis of a positioning run: what the simulation's baseline (a static systematic
//! deviation per target and direction plus stationary noise, i.e. an [`AxisModel`] without
//! effects) gets wrong, which effect explains it, and the extended model.
//!
//! Method (written down because the issue leaves it open):
//! - Mean effects (`linear_drift`, `exponential_warmup`, `cyclic_drift`, `thermal_expansion`)
//!   add a function of time (and position) to the per-(target, direction) constants. They are
//!   fitted by least squares with the constants profiled out (Frisch–Waugh–Lovell: every
//!   regressor is centred within its target/direction group), their non-linear parameter
//!   (τ, period) by a grid search refined locally. Forward selection: at each step the
//!   candidate with the lowest BIC is added if it lowers the BIC by more than
//!   [`Options::min_bic_gain`] ("very strong" evidence on the Kass–Raftery scale; the grid
//!   search is counted as a parameter) **and** lowers the prediction error on held-out cycles
//!   (cycles dealt into up to five interleaved folds). Noise alone then yields no finding.
//! - Outliers are readings beyond a Bonferroni bound (family-wise 0.5 %) of a robust scale
//!   (MAD) of their target's residuals; they are left out of every fit.
//! - `local_anomaly`: one target with its own variance, compared with a common variance by the
//!   profile likelihood with the same BIC rule (index search and ratio counted as two
//!   parameters). Its held-out gain is measured on the per-target scatter of held-out cycles
//!   (predicted vs observed RMS residual per target), as it changes no predicted mean.
//! - Without real times (no `time_s` column) row numbers stand in for seconds: the report says
//!   so, and rates, periods and time constants are then per reading.

// Row-indexed numerics over several parallel arrays read clearest with indices.
#![allow(clippy::needless_range_loop)]

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, Normal};

use crate::axis_model::{AxisModel, Effect};
use crate::iso230;
use crate::positioning_data::{PositioningData, dir_slot, schedule_of, simulate};

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
}

// ---------------------------------------------------------------------------------------
// Observations and the least-squares machinery.

struct Obs {
    y: Vec<f64>,
    t: Vec<f64>,
    x_mm: Vec<f64>,
    temp_c: Option<Vec<f64>>,
    group: Vec<usize>,
    n_groups: usize,
    target: Vec<usize>,
    fold: Vec<usize>,
    n_folds: usize,
    duration_s: f64,
    dt_s: f64,
}

impl Obs {
    fn new(data: &PositioningData, max_folds: usize) -> Self {
        let r = &data.readings;
        let t0 = r.iter().map(|r| r.time_s).fold(f64::INFINITY, f64::min);
        let t1 = r.iter().map(|r| r.time_s).fold(f64::NEG_INFINITY, f64::max);
        let mut ts: Vec<f64> = r.iter().map(|r| r.time_s).collect();
        ts.sort_by(f64::total_cmp);
        let mut gaps: Vec<f64> = ts
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|g| *g > 0.0)
            .collect();
        gaps.sort_by(f64::total_cmp);
        let dt_s = gaps.get(gaps.len() / 2).copied().unwrap_or(1.0);
        let n_folds = data.n_cycles().clamp(2, max_folds.max(2));
        let temp_c = r
            .iter()
            .all(|r| r.material_c.is_some())
            .then(|| r.iter().map(|r| r.material_c.unwrap_or(0.0)).collect());
        Obs {
            y: r.iter().map(|r| r.deviation_um).collect(),
            t: r.iter().map(|r| r.time_s).collect(),
            x_mm: r.iter().map(|r| r.target_mm).collect(),
            temp_c,
            group: r
                .iter()
                .map(|r| 2 * (r.index - 1) + dir_slot(r.direction))
                .collect(),
            n_groups: 2 * data.n_targets(),
            target: r.iter().map(|r| r.index - 1).collect(),
            fold: r.iter().map(|r| (r.cycle - 1) % n_folds).collect(),
            n_folds,
            duration_s: (t1 - t0).max(1.0),
            dt_s,
        }
    }
    fn len(&self) -> usize {
        self.y.len()
    }
}

/// Least squares of y on group constants plus fixed columns, over rows with weight > 0.
struct Projector {
    w: Vec<f64>,
    gsum: Vec<f64>,
    zc: Vec<Vec<f64>>,
    ginv: DMatrix<f64>,
}

impl Projector {
    fn new(obs: &Obs, w: &[f64], cols: &[Vec<f64>]) -> Self {
        let mut gsum = vec![0.0; obs.n_groups];
        for (j, &g) in obs.group.iter().enumerate() {
            gsum[g] += w[j];
        }
        let mut p = Projector {
            w: w.to_vec(),
            gsum,
            zc: Vec::new(),
            ginv: DMatrix::zeros(0, 0),
        };
        let zc: Vec<Vec<f64>> = cols.iter().map(|c| p.center(obs, c)).collect();
        let k = zc.len();
        let mut g = DMatrix::zeros(k, k);
        for a in 0..k {
            for b in a..k {
                let v = dotw(&zc[a], &zc[b], w);
                g[(a, b)] = v;
                g[(b, a)] = v;
            }
        }
        p.ginv = if k == 0 {
            DMatrix::zeros(0, 0)
        } else {
            g.clone()
                .try_inverse()
                .or_else(|| g.pseudo_inverse(1e-12).ok())
                .unwrap_or_else(|| DMatrix::zeros(k, k))
        };
        p.zc = zc;
        p
    }

    fn group_means(&self, obs: &Obs, v: &[f64]) -> Vec<f64> {
        let mut s = vec![0.0; obs.n_groups];
        for (j, &g) in obs.group.iter().enumerate() {
            s[g] += self.w[j] * v[j];
        }
        s.iter()
            .zip(&self.gsum)
            .map(|(s, n)| if *n > 0.0 { s / n } else { 0.0 })
            .collect()
    }

    fn center(&self, obs: &Obs, v: &[f64]) -> Vec<f64> {
        let m = self.group_means(obs, v);
        v.iter().zip(&obs.group).map(|(v, &g)| v - m[g]).collect()
    }

    /// Coefficients of the fixed columns for `v` (already centred).
    fn coef(&self, vc: &[f64]) -> DVector<f64> {
        let b = DVector::from_iterator(self.zc.len(), self.zc.iter().map(|z| dotw(z, vc, &self.w)));
        &self.ginv * b
    }

    fn residualize(&self, obs: &Obs, v: &[f64]) -> Vec<f64> {
        let mut vc = self.center(obs, v);
        let c = self.coef(&vc);
        for (k, z) in self.zc.iter().enumerate() {
            for (a, b) in vc.iter_mut().zip(z) {
                *a -= c[k] * b;
            }
        }
        vc
    }
}

fn dotw(a: &[f64], b: &[f64], w: &[f64]) -> f64 {
    a.iter().zip(b).zip(w).map(|((a, b), w)| a * b * w).sum()
}

/// A fitted mean model: group intercepts and column coefficients; predicts any row.
struct MeanFit {
    alpha: Vec<f64>,
    has_group: Vec<bool>,
    beta: DVector<f64>,
    cov_unscaled: DMatrix<f64>,
}

fn fit_mean(obs: &Obs, w: &[f64], cols: &[Vec<f64>]) -> MeanFit {
    let p = Projector::new(obs, w, cols);
    let yc = p.center(obs, &obs.y);
    let beta = p.coef(&yc);
    let gy = p.group_means(obs, &obs.y);
    let mut alpha = gy;
    for (k, c) in cols.iter().enumerate() {
        let gc = p.group_means(obs, c);
        for (a, g) in alpha.iter_mut().zip(gc) {
            *a -= beta[k] * g;
        }
    }
    MeanFit {
        alpha,
        has_group: p.gsum.iter().map(|s| *s > 0.0).collect(),
        beta,
        cov_unscaled: p.ginv,
    }
}

impl MeanFit {
    fn predict(&self, obs: &Obs, cols: &[Vec<f64>], j: usize) -> Option<f64> {
        let g = obs.group[j];
        if !self.has_group[g] {
            return None;
        }
        Some(
            self.alpha[g]
                + cols
                    .iter()
                    .enumerate()
                    .map(|(k, c)| self.beta[k] * c[j])
                    .sum::<f64>(),
        )
    }
}

/// Held-out residuals: each fold predicted from a fit on the others (non-linear parameters
/// kept). Returns `(residual, row)` for rows with `eval[j]`.
fn heldout_residuals(obs: &Obs, w: &[f64], cols: &[Vec<f64>], eval: &[bool]) -> Vec<(f64, usize)> {
    let mut out = Vec::new();
    for f in 0..obs.n_folds {
        let wt: Vec<f64> = w
            .iter()
            .zip(&obs.fold)
            .map(|(w, &k)| if k == f { 0.0 } else { *w })
            .collect();
        let fit = fit_mean(obs, &wt, cols);
        for j in 0..obs.len() {
            if obs.fold[j] == f
                && eval[j]
                && let Some(p) = fit.predict(obs, cols, j)
            {
                out.push((obs.y[j] - p, j));
            }
        }
    }
    out
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x * x;
        n += 1;
    }
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

fn heldout_rms(obs: &Obs, w: &[f64], cols: &[Vec<f64>], eval: &[bool]) -> f64 {
    rms(heldout_residuals(obs, w, cols, eval)
        .into_iter()
        .map(|r| r.0))
}

// ---------------------------------------------------------------------------------------
// Candidate effects.

#[derive(Debug, Clone, Copy, PartialEq)]
enum Family {
    Linear,
    Warmup,
    Cyclic,
    Thermal,
    ThermalTemp,
}

impl Family {
    fn name(self) -> &'static str {
        match self {
            Family::Linear => "linear_drift",
            Family::Warmup => "exponential_warmup",
            Family::Cyclic => "cyclic_drift",
            Family::Thermal | Family::ThermalTemp => "thermal_expansion",
        }
    }
    /// Parameters counted by the BIC (grid-searched ones included).
    fn n_params(self) -> usize {
        match self {
            Family::Linear | Family::ThermalTemp => 1,
            Family::Warmup | Family::Thermal => 2,
            Family::Cyclic => 3,
        }
    }
    fn slot(self) -> usize {
        match self {
            Family::Linear => 0,
            Family::Warmup => 1,
            Family::Cyclic => 2,
            Family::Thermal | Family::ThermalTemp => 3,
        }
    }

    fn columns(self, obs: &Obs, theta: f64) -> Vec<Vec<f64>> {
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

    fn grid(self, obs: &Obs) -> Vec<f64> {
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

#[derive(Debug, Clone)]
struct Selected {
    family: Family,
    theta: f64,
    cols: Vec<Vec<f64>>,
}

struct Candidate {
    theta: f64,
    rss: f64,
}

/// RSS of y on baseline + `base` columns + the family's columns at θ.
fn candidate_rss(obs: &Obs, p: &Projector, y_perp: &[f64], fam: Family, theta: f64) -> f64 {
    let cols = fam.columns(obs, theta);
    let cp: Vec<Vec<f64>> = cols.iter().map(|c| p.residualize(obs, c)).collect();
    let k = cp.len();
    let mut a = DMatrix::zeros(k, k);
    let mut b = DVector::zeros(k);
    for i in 0..k {
        b[i] = dotw(&cp[i], y_perp, &p.w);
        for j in i..k {
            let v = dotw(&cp[i], &cp[j], &p.w);
            a[(i, j)] = v;
            a[(j, i)] = v;
        }
    }
    let y2 = dotw(y_perp, y_perp, &p.w);
    match a.clone().cholesky() {
        Some(ch) => {
            let x = ch.solve(&b);
            (y2 - b.dot(&x)).max(0.0)
        }
        None => y2,
    }
}

fn search(obs: &Obs, p: &Projector, y_perp: &[f64], fam: Family) -> Option<Candidate> {
    let grid = fam.grid(obs);
    if grid.is_empty() {
        return None;
    }
    let rss: Vec<f64> = grid
        .par_iter()
        .map(|&th| candidate_rss(obs, p, y_perp, fam, th))
        .collect();
    let (mut best_k, mut best) = (0, f64::INFINITY);
    for (k, r) in rss.iter().enumerate() {
        if *r < best {
            best = *r;
            best_k = k;
        }
    }
    let mut theta = grid[best_k];
    if grid.len() > 2 {
        // Refine between the neighbours of the best grid point.
        let lo = grid[best_k.saturating_sub(1)];
        let hi = grid[(best_k + 1).min(grid.len() - 1)];
        for s in 0..=24 {
            let th = lo + (hi - lo) * s as f64 / 24.0;
            let r = candidate_rss(obs, p, y_perp, fam, th);
            if r < best {
                best = r;
                theta = th;
            }
        }
    }
    Some(Candidate { theta, rss: best })
}

/// Uncertainty of a grid-searched parameter from the curvature of the RSS profile:
/// u² = 2σ² / RSS''(θ).
fn theta_uncertainty(
    obs: &Obs,
    p: &Projector,
    y_perp: &[f64],
    fam: Family,
    c: &Candidate,
    s2: f64,
) -> Option<f64> {
    if !c.theta.is_finite() {
        return None;
    }
    let h = c.theta * 0.01;
    let r_lo = candidate_rss(obs, p, y_perp, fam, c.theta - h);
    let r_hi = candidate_rss(obs, p, y_perp, fam, c.theta + h);
    let curv = (r_lo - 2.0 * c.rss + r_hi) / (h * h);
    (curv > 0.0).then(|| (2.0 * s2 / curv).sqrt())
}

fn robust_scale(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    for x in v.iter_mut() {
        *x = x.abs();
    }
    v.sort_by(f64::total_cmp);
    1.4826 * v[v.len() / 2]
}

/// Flags outliers among `resid` (rows with `active`): beyond z·max(global, own target) robust
/// scale, z the Bonferroni bound of a family-wise `alpha` over the readings.
fn flag_outliers(obs: &Obs, resid: &[f64], alpha: f64, n_targets: usize) -> Vec<bool> {
    let n = obs.len();
    let z = Normal::new(0.0, 1.0)
        .map(|d| d.inverse_cdf(1.0 - alpha / (2.0 * n as f64)))
        .unwrap_or(4.5)
        .max(4.0);
    let global = robust_scale(&mut resid.to_vec());
    let mut per = vec![Vec::new(); n_targets];
    for j in 0..n {
        per[obs.target[j]].push(resid[j]);
    }
    let per_s: Vec<f64> = per
        .iter_mut()
        .map(|v| if v.len() >= 5 { robust_scale(v) } else { 0.0 })
        .collect();
    (0..n)
        .map(|j| global > 0.0 && resid[j].abs() > z * global.max(per_s[obs.target[j]]))
        .collect()
}

fn group_median_residuals(obs: &Obs) -> Vec<f64> {
    let mut per = vec![Vec::new(); obs.n_groups];
    for j in 0..obs.len() {
        per[obs.group[j]].push(obs.y[j]);
    }
    let med: Vec<f64> = per
        .iter_mut()
        .map(|v| {
            v.sort_by(f64::total_cmp);
            if v.is_empty() {
                0.0
            } else if v.len() % 2 == 1 {
                v[v.len() / 2]
            } else {
                0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
            }
        })
        .collect();
    (0..obs.len())
        .map(|j| obs.y[j] - med[obs.group[j]])
        .collect()
}

fn all_cols(sel: &[Selected]) -> Vec<Vec<f64>> {
    sel.iter().flat_map(|s| s.cols.iter().cloned()).collect()
}

fn in_sample_residuals(obs: &Obs, w: &[f64], cols: &[Vec<f64>]) -> (MeanFit, Vec<f64>) {
    let fit = fit_mean(obs, w, cols);
    let r = (0..obs.len())
        .map(|j| obs.y[j] - fit.predict(obs, cols, j).unwrap_or(obs.y[j]))
        .collect();
    (fit, r)
}

// ---------------------------------------------------------------------------------------

/// A duration for a sentence: minutes, or readings when the dataset has no real times.
fn dur(s: f64, has_times: bool) -> String {
    if has_times {
        format!("{:.1} min", s / 60.0)
    } else {
        format!("{s:.0} readings (no real times)")
    }
}

/// Diagnoses a positioning run against the static baseline.
pub fn diagnose(data: &PositioningData, opt: &Options) -> Result<Diagnosis, DiagnoseError> {
    let m = data.n_targets();
    if data.n_cycles() < 3 || m < 2 || data.readings.len() < 12 {
        return Err(DiagnoseError::TooFewReadings);
    }
    let obs = Obs::new(data, opt.max_folds);
    let n = obs.len();
    let ln_n = (n as f64).ln();
    let mut notes = Vec::new();
    let missing = data.missing();
    if !missing.is_empty() {
        notes.push(format!(
            "{} reading(s) missing (beam interruption?): {}; the diagnosis uses the others",
            missing.len(),
            missing
                .iter()
                .take(10)
                .map(|(c, d, i)| format!(
                    "cycle {c} {} target {i}",
                    crate::positioning_data::dir_sign(*d)
                ))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    if !data.has_times {
        notes.push(
            "the dataset has no time_s column: row order stands in for time (one reading = 1 s), \
             so drift rates, periods and time constants are per reading, not real times"
                .into(),
        );
    }
    let use_temp = obs.temp_c.is_some() && !data.material_compensation;

    // Baseline on everything.
    let ones = vec![1.0; n];
    let (_, r0) = in_sample_residuals(&obs, &ones, &[]);
    let baseline_rms = rms(r0.iter().copied());

    // Outliers: a first screen around the group medians, refined after each step.
    let mut out = flag_outliers(&obs, &group_median_residuals(&obs), opt.outlier_alpha, m);
    let weights = |out: &[bool], var: &[f64]| -> Vec<f64> {
        (0..n)
            .map(|j| {
                if out[j] {
                    0.0
                } else {
                    1.0 / var[obs.target[j]]
                }
            })
            .collect()
    };
    let var_factor = vec![1.0; m];

    struct Step {
        sel: Selected,
        significance: f64,
        u: Vec<(String, f64)>,
        before_cols: Vec<Vec<f64>>,
        alpha_temp: bool,
    }
    let mut selected: Vec<Selected> = Vec::new();
    let mut steps: Vec<Step> = Vec::new();
    loop {
        let w = weights(&out, &var_factor);
        let n_eff = w.iter().filter(|w| **w > 0.0).count() as f64;
        let cols = all_cols(&selected);
        let p = Projector::new(&obs, &w, &cols);
        let y_perp = p.residualize(&obs, &obs.y);
        let rss0 = dotw(&y_perp, &y_perp, &w);
        if rss0 <= 0.0 {
            break;
        }
        let mut best: Option<(Family, Candidate, f64)> = None;
        let mut fams = vec![Family::Linear, Family::Warmup, Family::Cyclic];
        if obs.x_mm.iter().any(|x| (x - obs.x_mm[0]).abs() > 1e-9) {
            fams.push(Family::Thermal);
            if use_temp {
                fams.push(Family::ThermalTemp);
            }
        }
        let mut temp_rss = None;
        for fam in fams {
            if selected.iter().any(|s| s.family.slot() == fam.slot()) {
                continue;
            }
            let Some(c) = search(&obs, &p, &y_perp, fam) else {
                continue;
            };
            if fam == Family::ThermalTemp {
                temp_rss = Some(c.rss);
            }
            let dbic = n_eff * (c.rss / rss0).ln() + fam.n_params() as f64 * ln_n;
            if best.as_ref().is_none_or(|b| dbic < b.2) {
                best = Some((fam, c, dbic));
            }
        }
        let Some((fam, cand, dbic)) = best else { break };
        if -dbic < opt.min_bic_gain {
            break;
        }
        let new = Selected {
            family: fam,
            theta: cand.theta,
            cols: fam.columns(&obs, cand.theta),
        };
        let mut cols_after = cols.clone();
        cols_after.extend(new.cols.iter().cloned());
        let eval: Vec<bool> = out.iter().map(|o| !o).collect();
        let before = heldout_rms(&obs, &w, &cols, &eval);
        let after = heldout_rms(&obs, &w, &cols_after, &eval);
        if after >= before {
            break;
        }
        let s2 = cand.rss / (n_eff - (obs.n_groups + cols_after.len()) as f64).max(1.0);
        let mut u = Vec::new();
        if let Some(ut) = theta_uncertainty(&obs, &p, &y_perp, fam, &cand, s2) {
            u.push(("theta".to_string(), ut));
        }
        // A temperature-driven scale change reported as such when the temperatures explain
        // it at least as well as the time-constant form.
        let alpha_temp = fam == Family::Thermal && temp_rss.is_some_and(|t| t <= cand.rss * 1.05);
        steps.push(Step {
            sel: new.clone(),
            significance: -dbic,
            u,
            before_cols: cols,
            alpha_temp,
        });
        selected.push(new);
        // Re-flag outliers against the richer model.
        let (_, r) = in_sample_residuals(&obs, &weights(&out, &var_factor), &all_cols(&selected));
        out = flag_outliers(&obs, &r, opt.outlier_alpha, m);
    }
    // Settle the outlier flags against the final mean model.
    let final_cols = all_cols(&selected);
    for _ in 0..2 {
        let (_, r) = in_sample_residuals(&obs, &weights(&out, &var_factor), &final_cols);
        out = flag_outliers(&obs, &r, opt.outlier_alpha, m);
    }
    let w_final = weights(&out, &var_factor);
    let eval: Vec<bool> = out.iter().map(|o| !o).collect();
    let (fit, resid) = in_sample_residuals(&obs, &w_final, &final_cols);
    let n_eff = eval.iter().filter(|e| **e).count() as f64;
    let dof = (n_eff - (obs.n_groups + final_cols.len()) as f64).max(1.0);
    let rss: f64 = (0..n)
        .filter(|&j| eval[j])
        .map(|j| resid[j] * resid[j])
        .sum();
    let sigma2 = rss / dof;

    let ones_eval: Vec<bool> = vec![true; n];
    let baseline_heldout = heldout_rms(&obs, &ones, &[], &ones_eval);

    let mut findings = Vec::new();
    let mut effects = Vec::new();
    let t_end = obs.t.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    // Mean effects: parameters from the final joint fit.
    let mut col0 = 0;
    for st in &steps {
        let k = st.sel.cols.len();
        let beta: Vec<f64> = (0..k).map(|i| fit.beta[col0 + i]).collect();
        let ub: Vec<f64> = (0..k)
            .map(|i| {
                (sigma2 * fit.cov_unscaled[(col0 + i, col0 + i)])
                    .max(0.0)
                    .sqrt()
            })
            .collect();
        let cov01 = if k == 2 {
            sigma2 * fit.cov_unscaled[(col0, col0 + 1)]
        } else {
            0.0
        };
        col0 += k;
        let th = st.sel.theta;
        let u_th = st.u.first().map(|x| x.1);
        let before = heldout_rms(&obs, &w_final, &st.before_cols, &eval);
        let mut after_cols = st.before_cols.clone();
        after_cols.extend(st.sel.cols.iter().cloned());
        let after = heldout_rms(&obs, &w_final, &after_cols, &eval);
        let mut params = BTreeMap::new();
        let mut params_u = BTreeMap::new();
        let (cause, effect) = match st.sel.family {
            Family::Linear => {
                params.insert("rate_um_per_h".into(), beta[0]);
                params_u.insert("rate_um_per_h".into(), ub[0]);
                (
                    format!(
                        "steady drift of every target, {:.2} µm {}: the measuring loop warms or \
                         cools steadily — ball-screw heating or a slow change of the room \
                         temperature; check the screw nut/bearing and air temperature records",
                        beta[0],
                        if data.has_times {
                            "per hour"
                        } else {
                            "per 3600 readings (no real times)"
                        }
                    ),
                    Effect::LinearDrift {
                        rate_um_per_h: beta[0],
                    },
                )
            }
            Family::Warmup => {
                params.insert("amplitude_um".into(), beta[0]);
                params_u.insert("amplitude_um".into(), ub[0]);
                params.insert("tau_s".into(), th);
                if let Some(u) = u_th {
                    params_u.insert("tau_s".into(), u);
                }
                (
                    format!(
                        "warm-up: every target settles by {:.2} µm with a time constant of \
                         {} — the machine (spindle, drives, ball screw) was not at thermal \
                         equilibrium at the start; warm it up for at least 3 time constants ({}) \
                         before measuring",
                        beta[0],
                        dur(th, data.has_times),
                        dur(3.0 * th, data.has_times)
                    ),
                    Effect::ExponentialWarmup {
                        amplitude_um: beta[0],
                        tau_s: th,
                    },
                )
            }
            Family::Cyclic => {
                let (a, b) = (beta[0], beta[1]);
                let amp = a.hypot(b);
                let u_amp = if amp > 0.0 {
                    ((a * a * ub[0] * ub[0] + b * b * ub[1] * ub[1] + 2.0 * a * b * cov01)
                        / (amp * amp))
                        .max(0.0)
                        .sqrt()
                } else {
                    0.0
                };
                params.insert("period_s".into(), th);
                params.insert("amplitude_um".into(), amp);
                params_u.insert("amplitude_um".into(), u_amp);
                if let Some(u) = u_th {
                    params_u.insert("period_s".into(), u);
                }
                (
                    format!(
                        "periodic drift of the measuring loop, period {}, {:.2} µm \
                         amplitude: a spindle or coolant temperature cycle (check the cooling \
                         unit's on/off cycle and the spindle/coolant temperatures)",
                        dur(th, data.has_times),
                        amp
                    ),
                    Effect::CyclicDrift {
                        period_s: th,
                        amplitude_um: amp,
                        phase_rad: b.atan2(a),
                    },
                )
            }
            Family::Thermal => {
                let end = beta[0] * (1.0 - (-t_end / th).exp());
                params.insert("scale_ppm".into(), end);
                params_u.insert("scale_ppm".into(), ub[0] * (1.0 - (-t_end / th).exp()));
                params.insert("tau_s".into(), th);
                if let Some(u) = u_th {
                    params_u.insert("tau_s".into(), u);
                }
                let mut cause = format!(
                    "scale change growing to {end:.1} µm/m by the end of the run (time constant \
                     {}): the axis expands as it heats — ball-screw heating, or an \
                     uncompensated material temperature",
                    dur(th, data.has_times)
                );
                if st.alpha_temp {
                    // α from the regression on the measured material temperature.
                    let tc = Family::ThermalTemp.columns(&obs, f64::NAN);
                    let mut cols = st.before_cols.clone();
                    cols.extend(tc);
                    let f2 = fit_mean(&obs, &w_final, &cols);
                    let alpha = f2.beta[cols.len() - 1];
                    let ua = (sigma2 * f2.cov_unscaled[(cols.len() - 1, cols.len() - 1)])
                        .max(0.0)
                        .sqrt();
                    params.insert("alpha_um_per_m_k".into(), alpha);
                    params_u.insert("alpha_um_per_m_k".into(), ua);
                    cause = format!(
                        "uncompensated material temperature: the file says material_compensation: \
                         off and the measured material temperature explains the scale change \
                         ({end:.1} µm/m by the end) with an expansion coefficient of {alpha:.1} ± \
                         {ua:.1} µm/(m·K){}; normalise the readings to 20 °C",
                        data.alpha_um_per_m_k
                            .map(|a| format!(" (the file states {a} µm/(m·K))"))
                            .unwrap_or_default()
                    );
                }
                (
                    cause,
                    Effect::ThermalExpansion {
                        scale_ppm: beta[0],
                        tau_s: th,
                    },
                )
            }
            Family::ThermalTemp => {
                // The measured material temperature explains the scale change better than a
                // time constant: α is the coefficient of x·T.
                let (alpha, ua) = (beta[0], ub[0]);
                let tc = obs.temp_c.as_deref().unwrap_or(&[]);
                let (mut j0, mut j1) = (0, 0);
                for j in 0..tc.len() {
                    if obs.t[j] < obs.t[j0] {
                        j0 = j;
                    }
                    if obs.t[j] > obs.t[j1] {
                        j1 = j;
                    }
                }
                let dt_k = tc.get(j1).copied().unwrap_or(0.0) - tc.get(j0).copied().unwrap_or(0.0);
                let end = alpha * dt_k;
                params.insert("scale_ppm".into(), end);
                params_u.insert("scale_ppm".into(), ua * dt_k.abs());
                params.insert("alpha_um_per_m_k".into(), alpha);
                params_u.insert("alpha_um_per_m_k".into(), ua);
                // The simulator's form (scale with a time constant) fitted for the model.
                let p = Projector::new(&obs, &w_final, &st.before_cols);
                let y_perp = p.residualize(&obs, &obs.y);
                let (scale, tau) = match search(&obs, &p, &y_perp, Family::Thermal) {
                    Some(c) => {
                        let mut cols = st.before_cols.clone();
                        cols.extend(Family::Thermal.columns(&obs, c.theta));
                        let f2 = fit_mean(&obs, &w_final, &cols);
                        (f2.beta[cols.len() - 1], c.theta)
                    }
                    None => (end, obs.duration_s),
                };
                params.insert("tau_s".into(), tau);
                let cause = format!(
                    "uncompensated material temperature: the file says material_compensation: off \
                     and the measured material temperature ({dt_k:+.2} K over the run) explains \
                     the scale change ({end:.1} µm/m by the end) with an expansion coefficient of \
                     {alpha:.1} ± {ua:.1} µm/(m·K){}; normalise the readings to 20 °C",
                    data.alpha_um_per_m_k
                        .map(|a| format!(" (the file states {a} µm/(m·K))"))
                        .unwrap_or_default()
                );
                (
                    cause,
                    Effect::ThermalExpansion {
                        scale_ppm: scale,
                        tau_s: tau,
                    },
                )
            }
        };
        findings.push(Finding {
            effect: st.sel.family.name().into(),
            params,
            params_u,
            significance: st.significance,
            heldout_rms_before_um: before,
            heldout_rms_after_um: after,
            cause,
        });
        effects.push(effect);
    }

    // Local anomaly: one target with its own variance.
    let mut ss_t = vec![0.0; m];
    let mut n_t = vec![0usize; m];
    for j in 0..n {
        if eval[j] {
            ss_t[obs.target[j]] += resid[j] * resid[j];
            n_t[obs.target[j]] += 1;
        }
    }
    let groups_t: Vec<f64> = (0..m)
        .map(|t| (0..2).filter(|d| fit.has_group[2 * t + d]).count() as f64)
        .collect();
    let ss_all: f64 = ss_t.iter().sum();
    let dof_all: f64 =
        (0..m).map(|t| n_t[t] as f64 - groups_t[t]).sum::<f64>() - final_cols.len() as f64;
    let mut anomaly: Option<(usize, f64, f64)> = None;
    if dof_all > 2.0 && ss_all > 0.0 {
        for t in 0..m {
            let dk = n_t[t] as f64 - groups_t[t];
            let dr = dof_all - dk;
            if dk < 2.0 || dr < 2.0 || ss_t[t] <= 0.0 {
                continue;
            }
            let (vk, vr) = (ss_t[t] / dk, (ss_all - ss_t[t]) / dr);
            if vk <= vr {
                continue;
            }
            // Profile log-likelihood ratio of separate vs common variance (×2).
            let lr = dof_all * (ss_all / dof_all).ln() - dk * vk.ln() - dr * vr.ln();
            let dbic = -lr + 2.0 * ln_n;
            if -dbic >= opt.min_bic_gain && anomaly.is_none_or(|a| -dbic > a.2) {
                anomaly = Some((t, (vk / vr).sqrt(), -dbic));
            }
        }
    }
    if let Some((t, ratio, sig)) = anomaly {
        // Gain on held-out cycles: predicted vs observed per-target RMS residual.
        let ho = heldout_residuals(&obs, &w_final, &final_cols, &eval);
        let mut sse = vec![vec![0.0; m]; obs.n_folds];
        let mut cnt = vec![vec![0usize; m]; obs.n_folds];
        for &(r, j) in &ho {
            sse[obs.fold[j]][obs.target[j]] += r * r;
            cnt[obs.fold[j]][obs.target[j]] += 1;
        }
        let (mut e_before, mut e_after, mut k) = (0.0, 0.0, 0usize);
        for f in 0..obs.n_folds {
            let (mut s_other, mut c_other, mut s_t, mut c_t) = (0.0, 0usize, 0.0, 0usize);
            for g in 0..obs.n_folds {
                if g == f {
                    continue;
                }
                for tt in 0..m {
                    if tt == t {
                        s_t += sse[g][tt];
                        c_t += cnt[g][tt];
                    } else {
                        s_other += sse[g][tt];
                        c_other += cnt[g][tt];
                    }
                }
            }
            if c_other == 0 || c_t == 0 {
                continue;
            }
            let common = ((s_other + s_t) / (c_other + c_t) as f64).sqrt();
            let (sig_o, sig_t) = ((s_other / c_other as f64).sqrt(), (s_t / c_t as f64).sqrt());
            for tt in 0..m {
                if cnt[f][tt] == 0 {
                    continue;
                }
                let obs_s = (sse[f][tt] / cnt[f][tt] as f64).sqrt();
                let pred_after = if tt == t { sig_t } else { sig_o };
                e_before += (common - obs_s).powi(2);
                e_after += (pred_after - obs_s).powi(2);
                k += 1;
            }
        }
        let k = k.max(1) as f64;
        // Ratio uncertainty from the F distribution's log-variance: u(ln v) ≈ √(2/dof).
        let dk = (n_t[t] as f64 - groups_t[t]).max(1.0);
        let dr = (dof_all - dk).max(1.0);
        let u_ratio = ratio * 0.5 * (2.0 / dk + 2.0 / dr).sqrt();
        let x_mm = data.targets_mm()[t];
        findings.push(Finding {
            effect: "local_anomaly".into(),
            params: BTreeMap::from([
                ("index".into(), (t + 1) as f64),
                ("std_ratio".into(), ratio),
            ]),
            params_u: BTreeMap::from([("std_ratio".into(), u_ratio)]),
            significance: sig,
            heldout_rms_before_um: (e_before / k).sqrt(),
            heldout_rms_after_um: (e_after / k).sqrt(),
            cause: format!(
                "target {} ({x_mm:.3} mm) scatters {ratio:.1}× more than the others: a local \
                 structural fault (damaged screw thread or guide, loose scale or fixture) or a \
                 local heat source near that position; inspect the axis there",
                t + 1
            ),
        });
        effects.push(Effect::LocalAnomaly {
            index: t + 1,
            std_ratio: ratio,
        });
    }

    // Outliers.
    let n_out = out.iter().filter(|o| **o).count();
    if n_out > 0 {
        let mut var_t = vec![sigma2; m];
        if let Some((t, ratio, _)) = anomaly {
            var_t[t] = sigma2 * ratio * ratio;
        }
        let mags: Vec<f64> = (0..n).filter(|&j| out[j]).map(|j| resid[j].abs()).collect();
        let sig: f64 = (0..n)
            .filter(|&j| out[j])
            .map(|j| resid[j] * resid[j] / var_t[obs.target[j]] - ln_n)
            .sum();
        let before = heldout_rms(
            &obs,
            &weights(&vec![false; n], &var_factor),
            &final_cols,
            &eval,
        );
        let after = heldout_rms(&obs, &w_final, &final_cols, &eval);
        let mean_mag = mags.iter().sum::<f64>() / mags.len() as f64;
        findings.push(Finding {
            effect: "outliers".into(),
            params: BTreeMap::from([("count".into(), n_out as f64)]),
            params_u: BTreeMap::new(),
            significance: sig,
            heldout_rms_before_um: before,
            heldout_rms_after_um: after,
            cause: format!(
                "{n_out} isolated reading(s) off their target's trend by {mean_mag:.1} µm on \
                 average: a beam interruption, air turbulence or a vibration during the \
                 reading; repeat those points"
            ),
        });
        effects.push(Effect::Outliers {
            rate: n_out as f64 / n as f64,
            magnitude_um: mean_mag,
        });
    }

    let mut order: Vec<usize> = (0..findings.len()).collect();
    order.sort_by(|&a, &b| {
        findings[b]
            .significance
            .total_cmp(&findings[a].significance)
    });
    let findings: Vec<Finding> = order.iter().map(|&i| findings[i].clone()).collect();
    let effects: Vec<Effect> = order.iter().map(|&i| effects[i].clone()).collect();

    let targets_mm = data.targets_mm();
    let model = AxisModel {
        axis: data.axis.clone().unwrap_or_else(|| "X".into()),
        targets_mm: targets_mm
            .iter()
            .map(|x| if x.is_finite() { *x } else { 0.0 })
            .collect(),
        systematic_up_um: (0..m).map(|t| fit.alpha[2 * t]).collect(),
        systematic_down_um: (0..m).map(|t| fit.alpha[2 * t + 1]).collect(),
        noise_um: {
            // Noise of the ordinary targets (the anomalous one has its own factor).
            match anomaly {
                Some((t, _, _)) => {
                    let dk = n_t[t] as f64 - groups_t[t];
                    ((ss_all - ss_t[t]) / (dof_all - dk).max(1.0)).sqrt()
                }
                None => sigma2.sqrt(),
            }
        },
        effects,
    };
    Ok(Diagnosis {
        report: DiagnosisReport {
            kind: "positioning".into(),
            baseline: Baseline {
                model: "static".into(),
                rms_um: baseline_rms,
                heldout_rms_um: baseline_heldout,
            },
            findings,
            extended_model: None,
            reproduction: None,
            notes,
        },
        model,
        baseline_residuals_um: r0,
        residuals_um: resid,
        outlier: out,
    })
}

/// An [`AxisModel`] as the `[axis]` table of a simulator scenario: what
/// `diagnose --write-model` writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisTable {
    pub axis: AxisModel,
}

/// Reads an axis model from TOML: an `[axis]` table (as written by `--write-model` and found
/// in scenarios; other tables are ignored) or a bare model.
pub fn axis_model_from_toml(text: &str) -> Result<AxisModel, toml::de::Error> {
    #[derive(Deserialize)]
    struct Any {
        axis: toml::Value,
    }
    // A bare model has `axis = "X"` (its name); a scenario has an `[axis]` table.
    match toml::from_str::<Any>(text) {
        Ok(Any {
            axis: toml::Value::Table(t),
        }) => toml::Value::Table(t).try_into(),
        _ => toml::from_str::<AxisModel>(text),
    }
}

/// The baseline model fitted from the data: per-target, per-direction means and the pooled
/// noise, no effects.
pub fn baseline_model(data: &PositioningData) -> AxisModel {
    let rep = iso230::evaluate(data);
    let mut ss = 0.0;
    let mut dof = 0.0;
    for t in &rep.targets {
        for (s, n) in [(t.s_up_um, t.n_up), (t.s_down_um, t.n_down)] {
            if let Some(s) = s {
                ss += s * s * (n as f64 - 1.0);
                dof += n as f64 - 1.0;
            }
        }
    }
    AxisModel {
        axis: data.axis.clone().unwrap_or_else(|| "X".into()),
        targets_mm: data
            .targets_mm()
            .iter()
            .map(|x| if x.is_finite() { *x } else { 0.0 })
            .collect(),
        systematic_up_um: rep
            .targets
            .iter()
            .map(|t| t.mean_up_um.unwrap_or(0.0))
            .collect(),
        systematic_down_um: rep
            .targets
            .iter()
            .map(|t| t.mean_down_um.unwrap_or(0.0))
            .collect(),
        noise_um: if dof > 0.0 { (ss / dof).sqrt() } else { 0.0 },
        effects: Vec::new(),
    }
}

/// Simulates `model` over the same readings (cycles, directions, times) as `data`, with
/// `seeds` seeds, and measures how closely the simulated per-target ISO 230-2 statistics
/// (x̄↑ x̄↓ s↑ s↓) match the measured ones; the baseline model is scored the same way.
pub fn reproduction_check(data: &PositioningData, model: &AxisModel, seeds: usize) -> Reproduction {
    let measured = iso230::evaluate(data);
    let schedule = schedule_of(data);
    let base = baseline_model(data);
    let score = |m: &AxisModel| {
        let (mut em, mut es) = (0.0, 0.0);
        for seed in 0..seeds.max(1) {
            let sim = iso230::evaluate(&simulate(m, &schedule, 0x5eed + seed as u64));
            let (mut sm, mut nm, mut ss, mut ns) = (0.0, 0usize, 0.0, 0usize);
            for (a, b) in sim.targets.iter().zip(&measured.targets) {
                for (x, y) in [
                    (a.mean_up_um, b.mean_up_um),
                    (a.mean_down_um, b.mean_down_um),
                ] {
                    if let (Some(x), Some(y)) = (x, y) {
                        sm += (x - y).powi(2);
                        nm += 1;
                    }
                }
                for (x, y) in [(a.s_up_um, b.s_up_um), (a.s_down_um, b.s_down_um)] {
                    if let (Some(x), Some(y)) = (x, y) {
                        ss += (x - y).powi(2);
                        ns += 1;
                    }
                }
            }
            em += (sm / nm.max(1) as f64).sqrt();
            es += (ss / ns.max(1) as f64).sqrt();
        }
        let k = seeds.max(1) as f64;
        (em / k, es / k)
    };
    let (mean_rms_um, s_rms_um) = score(model);
    let (baseline_mean_rms_um, baseline_s_rms_um) = score(&base);
    Reproduction {
        mean_rms_um,
        s_rms_um,
        baseline_mean_rms_um,
        baseline_s_rms_um,
        seeds: seeds.max(1),
    }
}
