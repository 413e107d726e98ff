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

use positioning::axis_model::AxisModel;
use positioning::positioning_data::PositioningData;

mod alternatives;
mod blocks;
mod correlation;
mod family;
mod fit;
mod model;
mod obs;
mod outliers;
mod projector;
mod report;
mod run;
mod search;
mod sums;
mod tails;
mod types;
mod verdict;

pub use model::{AxisTable, axis_model_from_toml, baseline_model, reproduction_check};
pub use types::{
    Alternative, Baseline, DiagnoseError, Diagnosis, DiagnosisReport, Finding, Found, Options,
    Reproduction, Stated,
};

use fit::{FinalFit, heldout_rms, in_sample_residuals, rms};
use obs::Obs;
use outliers::{flag_outliers, group_median_residuals, weights};
use projector::Projector;
use run::Run;
use search::all_cols;

/// The largest run the diagnosis takes, as readings × (targets + cycles): its candidate
/// columns grow with the targets and the cycles, each as long as the readings. Memory is about
/// 60 bytes per unit for a run of many targets in few cycles (10 000 readings of 1 000 targets
/// in 5 cycles, 0.54 GB) and up to 160 for as many cycles as targets (`tests/sweep/
/// largest_inputs.py`: 70 × 70, 1.4·10⁶ units, 0.22 GB; 122 × 122, 7.3·10⁶ units, past 1 GiB).
/// This bound keeps every shape under about 0.8 GB; an ISO 230-2 run is a few thousand units.
pub const MAX_SIZE: usize = 5_000_000;

/// Diagnoses a positioning run against the static baseline.
pub fn diagnose(data: &PositioningData, opt: &Options) -> Result<Diagnosis, DiagnoseError> {
    let m = data.n_targets();
    let (readings, cycles) = (data.readings.len(), data.n_cycles());
    let size = readings.saturating_mul(m.saturating_add(cycles));
    if size > MAX_SIZE {
        return Err(DiagnoseError::TooLarge {
            readings,
            targets: m,
            cycles,
            size,
            max: MAX_SIZE,
        });
    }
    if data.n_cycles() < 3 && m >= 2 {
        return Err(DiagnoseError::Sweep {
            cycles: data.n_cycles(),
        });
    }
    if m < 2 || data.readings.len() < 12 {
        return Err(DiagnoseError::TooFewReadings);
    }
    let obs = Run::new(Obs::new(data, opt.max_folds));
    let n = obs.len();
    let mut notes = input_notes(data);
    let use_temp = obs.temp_c.is_some() && !data.material_compensation;

    // Baseline on everything.
    let ones = vec![1.0; n];
    let (_, r0) = in_sample_residuals(&obs, &ones, &[]);
    let baseline_rms = rms(r0.iter().copied());
    let baseline_heldout = heldout_rms(&obs, &ones, &[], &vec![true; n]);

    // Outliers: a first screen around the group medians, refined after each step. A screen
    // that flags more than a tenth of the readings sees structure (a large step moves half
    // the run off its medians), not isolated events: the search then starts without it.
    let mut out = flag_outliers(&obs, &group_median_residuals(&obs), opt.outlier_alpha, m);
    if out.iter().filter(|o| **o).count() as f64 > verdict::MAX_OUTLIER_SHARE * n as f64 {
        out = vec![false; n];
    }
    let mut steps = search::forward_select(&obs, opt, use_temp, &mut out, &mut notes);
    if !steps.is_empty() {
        let cols = all_cols(&steps.iter().map(|s| s.sel.clone()).collect::<Vec<_>>());
        let fin0 = settle(&obs, opt, out.clone(), cols);
        alternatives::refine(&obs, opt, use_temp, &mut steps, &fin0);
    }
    let cols = all_cols(&steps.iter().map(|s| s.sel.clone()).collect::<Vec<_>>());
    let fin = settle(&obs, opt, out, cols);

    // Mean effects: parameters from the final joint fit.
    let rivals = alternatives::rivals(&obs, opt, use_temp, &steps, &fin);
    let mut found = Vec::new();
    let mut col0 = 0;
    for (i, (st, rv)) in steps.iter().zip(&rivals).enumerate() {
        let spread = spread_of(&obs, &fin, &steps, i);
        let mut f = report::mean_finding(&obs, data, &fin, st, col0, spread.as_ref());
        for r in rv {
            f.alternatives.push(rival_finding(&obs, data, opt, &fin, r));
        }
        note_alternatives(&mut f);
        found.push(f);
        col0 += st.sel.cols.len();
    }
    let anomaly = report::local_anomaly(&obs, data, &fin, opt);
    if let Some(a) = &anomaly {
        found.push(a.finding.clone());
    }
    let res = verdict::residue(&obs, &fin);
    // Parameters fitted in correlated noise are less certain than white noise implies.
    for f in found.iter_mut() {
        for u in f.params_u.values_mut() {
            *u *= res.u_factor();
        }
    }
    if res.rho > 0.3 {
        let at_least = if res.rho >= 0.95 { "at least " } else { "" };
        notes.push(format!(
            "consecutive readings correlate (lag-1 correlation of the noise {at_least}{:.2}, \
             allowing for what the fit takes out of the residuals; air turbulence, a slow \
             reference or slow structure no effect models): the evidence for every effect and \
             its uncertainties allow for it",
            res.rho.min(0.95)
        ));
    }
    notes.extend(blocks::within_block_trend(&obs, &fin));
    let unexplained = res.unexplained();
    match report::outlier_finding(&obs, &fin, anomaly.as_ref()) {
        Some(o) if !res.heavy_tails && !unexplained => found.push(o),
        Some(_) if res.heavy_tails && !unexplained => notes.push(
            "the noise is heavier-tailed than normal: the readings far off their trend are its \
             tail, not isolated events, so they are left out of the fits but not reported as \
             outliers"
                .into(),
        ),
        _ => {}
    }
    if unexplained {
        let demoted = verdict::demoted_next_to_unexplained(&found, res.rms_left_um);
        for &(i, why) in demoted.iter().rev() {
            let f = found.remove(i);
            let change = if f.heldout_rms_after_um < f.heldout_rms_before_um {
                "would lower"
            } else {
                "would not lower"
            };
            notes.push(format!(
                "{} {change} the held-out error ({:.2} → {:.2} µm): not reported, {why}",
                f.effect, f.heldout_rms_before_um, f.heldout_rms_after_um
            ));
        }
    }
    // Most significant first (a stable sort keeps the order of ties).
    found.sort_by(|a, b| b.significance.total_cmp(&a.significance));
    let effects = found
        .iter()
        .filter_map(|f| f.effect.model_effect().copied())
        .collect();
    let mut findings = found;
    if unexplained {
        // Not a model effect: the extended model does not simulate it.
        findings.push(verdict::unexplained_finding(&obs, &fin, &res));
    }
    let conclusion = verdict::conclusion(&findings, baseline_heldout, fin.sigma2.sqrt());

    let model = AxisModel {
        axis: data.axis.clone().unwrap_or_else(|| "X".into()),
        targets_mm: data
            .targets_mm()
            .iter()
            .map(|x| if x.is_finite() { *x } else { 0.0 })
            .collect(),
        systematic_up_um: (0..m).map(|t| fin.fit.alpha[2 * t]).collect(),
        systematic_down_um: (0..m).map(|t| fin.fit.alpha[2 * t + 1]).collect(),
        // Noise of the ordinary targets (the anomalous one has its own factor).
        noise_um: anomaly
            .as_ref()
            .map_or(fin.sigma2.sqrt(), |a| a.noise_others_um),
        effects,
    };
    let units = data.units();
    for f in findings.iter_mut() {
        f.cause = units.relabel(&f.cause);
    }
    let notes = notes.iter().map(|n| units.relabel(n)).collect();
    let conclusion = units.relabel(&conclusion);
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
            conclusion,
        },
        model,
        baseline_residuals_um: r0,
        residuals_um: fin.resid,
        outlier: fin.out,
    })
}

/// The spread of step `i`'s searched parameter in the final fit (the other effects in). At
/// each value tried, the other effects' searched parameters (a warm-up's τ, a cycle's period,
/// a step's moment) are searched again: a period and a τ fitted together trade off, and the
/// spread of one with the other held fixed is too narrow.
fn spread_of(
    obs: &Run,
    fin: &FinalFit,
    steps: &[search::Step],
    i: usize,
) -> Option<search::Spread> {
    let st = &steps[i];
    let fam = st.sel.family;
    let searched: Vec<usize> = (0..steps.len())
        .filter(|&j| j != i && steps[j].sel.theta.is_finite())
        .collect();
    let fit_all = |ts: &[f64]| {
        let cols_i: Vec<Vec<Vec<f64>>> = ts.iter().map(|&t| fam.columns(obs, t)).collect();
        // The model's columns by step, for each value of `ts`.
        let mut cols: Vec<Vec<Vec<Vec<f64>>>> = ts
            .iter()
            .map(|_| steps.iter().map(|s| s.sel.cols.clone()).collect())
            .collect();
        for &j in &searched {
            let fits: Vec<(Projector, Vec<f64>)> = (0..ts.len())
                .map(|k| {
                    let mut base: Vec<Vec<f64>> = (0..steps.len())
                        .filter(|&q| q != i && q != j)
                        .flat_map(|q| cols[k][q].clone())
                        .collect();
                    base.extend(cols_i[k].iter().cloned());
                    let p = Projector::new(obs, &fin.w, &base);
                    let y = p.residualize(obs, &obs.y);
                    (p, y)
                })
                .collect();
            let refs: Vec<(&Projector, &[f64])> =
                fits.iter().map(|(p, y)| (p, y.as_slice())).collect();
            let fam_j = steps[j].sel.family;
            for (k, c) in search::search_many(obs, &refs, fam_j)
                .into_iter()
                .enumerate()
            {
                if let Some(c) = c {
                    cols[k][j] = fam_j.columns(obs, c.theta);
                }
            }
        }
        (0..ts.len())
            .map(|k| {
                let others: Vec<Vec<f64>> = (0..steps.len())
                    .filter(|&q| q != i)
                    .flat_map(|q| cols[k][q].clone())
                    .collect();
                let p = Projector::new(obs, &fin.w, &others);
                let y = p.residualize(obs, &obs.y);
                let (rss, x) = search::cols_fit(obs, &p, &y, &cols_i[k]);
                x.map(|x| (rss, x))
            })
            .collect()
    };
    search::theta_spread(obs, &fit_all, fam, st.sel.theta, st.u_theta, fin.sigma2)
}

/// A rival fitted in a finding's place, the rest of the model kept.
fn rival_finding(
    obs: &Run,
    data: &PositioningData,
    opt: &Options,
    fin: &FinalFit,
    r: &alternatives::Rival,
) -> Alternative {
    let mut cols = r.step.before_cols.clone();
    cols.extend(r.step.sel.cols.iter().cloned());
    let fin_r = settle(obs, opt, fin.out.clone(), cols);
    let f = report::mean_finding(obs, data, &fin_r, &r.step, r.step.before_cols.len(), None);
    Alternative {
        effect: f.effect,
        stated: f.stated,
        params_u: f.params_u,
        delta_bic: r.delta_bic,
    }
}

/// Says in the finding's cause which effects the data cannot tell it from.
fn note_alternatives(f: &mut Finding) {
    for a in &f.alternatives {
        f.cause.push_str(&format!(
            " The data cannot tell it from {} (BIC {:+.1}): {}.",
            a.effect,
            a.delta_bic,
            alternatives::tell_apart(f.effect.kind(), a.effect.kind())
        ));
    }
}

/// Caveats about the input: missing readings, no real times.
fn input_notes(data: &PositioningData) -> Vec<String> {
    let mut notes: Vec<String> = data.units().note().into_iter().collect();
    let missing = data.missing();
    let damage = data
        .metadata
        .get(positioning::positioning_data::LOG_DAMAGE_KEY);
    if let Some(d) = damage {
        notes.insert(
            0,
            format!(
                "BUILT ON PART OF THE RUN: the log is damaged: {d}; the diagnosis uses the \
                 readings before the damage only"
            ),
        );
    }
    if !missing.is_empty() {
        let why = if damage.is_some() {
            "lost with the damaged part of the log, or a beam interruption"
        } else {
            "beam interruption?"
        };
        notes.push(format!(
            "{} reading(s) missing ({why}): {}; the diagnosis uses the others",
            missing.len(),
            missing
                .iter()
                .take(10)
                .map(|(c, d, i)| format!(
                    "cycle {c} {} target {i}",
                    positioning::positioning_data::dir_sign(*d)
                ))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    if let Some(n) = data.direction_target_note() {
        notes.push(n);
    }
    if !data.has_times {
        notes.push(
            "the dataset has no time_s column: row order stands in for time (one reading = 1 s), \
             so drift rates, periods and time constants are per reading, not real times"
                .into(),
        );
    }
    notes
}

/// Settles the outlier flags against the final mean model and fits it.
fn settle(obs: &Run, opt: &Options, mut out: Vec<bool>, cols: Vec<Vec<f64>>) -> FinalFit {
    let n = obs.len();
    let var_factor = vec![1.0; obs.n_targets];
    for _ in 0..2 {
        let (_, r) = in_sample_residuals(obs, &weights(obs, &out, &var_factor), &cols);
        out = flag_outliers(obs, &r, opt.outlier_alpha, obs.n_targets);
    }
    let w = weights(obs, &out, &var_factor);
    let eval: Vec<bool> = out.iter().map(|o| !o).collect();
    let (fit, resid) = in_sample_residuals(obs, &w, &cols);
    let n_eff = eval.iter().filter(|e| **e).count() as f64;
    let dof = (n_eff - (obs.n_groups + cols.len()) as f64).max(1.0);
    let rss: f64 = (0..n)
        .filter(|&j| eval[j])
        .map(|j| resid[j] * resid[j])
        .sum();
    FinalFit {
        out,
        w,
        eval,
        cols,
        fit,
        resid,
        sigma2: rss / dof,
    }
}
