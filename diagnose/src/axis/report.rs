//! The findings of the diagnosis in the report's words: parameters, their uncertainties, the
//! held-out gain and the cause a metrologist would check (`docs/datasets.md`, "Diagnosis
//! report").

#![allow(clippy::needless_range_loop)]

use std::collections::BTreeMap;

use super::family::Family;
use super::fit::{FinalFit, fit_mean, heldout_residuals, heldout_rms};
use super::outliers::weights;
use super::projector::Projector;
use super::run::Run;
use super::search::{Spread, Step, search};
use super::types::{Finding, Found, Options, Stated};
use positioning::axis_model::Effect;
use positioning::positioning_data::PositioningData;

/// A duration for a sentence: minutes, or readings when the dataset has no real times.
pub(super) fn dur(s: f64, has_times: bool) -> String {
    if has_times {
        format!("{:.1} min", s / 60.0)
    } else {
        format!("{s:.0} readings (no real times)")
    }
}

/// An effect's coefficients in the final joint fit.
struct Coefs {
    beta: Vec<f64>,
    /// Standard uncertainties of `beta`.
    ub: Vec<f64>,
    /// Covariance of the first two coefficients (the cyclic drift's sine and cosine).
    cov01: f64,
    /// The non-linear parameter and its uncertainty.
    theta: f64,
    u_theta: Option<f64>,
}

/// The model effect of one finding, what the report states beside its parameters, their
/// uncertainties and a cause.
type Described = (Effect, Stated, BTreeMap<&'static str, f64>, String);

/// The finding of a mean effect added by the forward selection; `col0` is its first column
/// in the final fit.
pub(super) fn mean_finding(
    obs: &Run,
    data: &PositioningData,
    fin: &FinalFit,
    st: &Step,
    col0: usize,
    spread: Option<&Spread>,
) -> Finding {
    let k = st.sel.cols.len();
    let sigma2 = fin.sigma2;
    let extra = |i: usize| {
        spread
            .and_then(|s| s.coef_var.get(i))
            .copied()
            .unwrap_or(0.0)
    };
    let u_theta = match (st.sel.family, st.u_theta, spread) {
        (Family::Step, _, s) => s.map(|s| s.u_theta),
        (_, Some(u), Some(s)) => Some(u.max(s.u_theta)),
        (_, u, _) => u,
    };
    let c = Coefs {
        beta: (0..k).map(|i| fin.fit.beta[col0 + i]).collect(),
        ub: (0..k)
            .map(|i| {
                (sigma2 * fin.fit.cov_unscaled[(col0 + i, col0 + i)] + extra(i))
                    .max(0.0)
                    .sqrt()
            })
            .collect(),
        cov01: if k == 2 {
            sigma2 * fin.fit.cov_unscaled[(col0, col0 + 1)]
        } else {
            0.0
        },
        theta: st.sel.theta,
        u_theta,
    };
    let mut after_cols = st.before_cols.clone();
    after_cols.extend(st.sel.cols.iter().cloned());
    let ho = if st.sel.family == Family::CycleOffsets {
        obs.diagonal()
    } else {
        obs
    };
    let before = heldout_rms(ho, &fin.w, &st.before_cols, &fin.eval);
    let after = heldout_rms(ho, &fin.w, &after_cols, &fin.eval);
    let (effect, stated, params_u, cause) = match st.sel.family {
        Family::Linear => linear(&c, data.has_times),
        Family::Warmup => warmup(&c, data.has_times),
        Family::Cyclic => cyclic(obs, &c, data.has_times),
        Family::Step => step(obs, &c, data.has_times),
        Family::ReversalDrift => reversal_drift(obs, &c, data.has_times),
        Family::CycleOffsets => cycle_offsets(&c),
        Family::Thermal => thermal(obs, data, fin, st, &c),
        Family::ThermalTemp => thermal_temp(obs, data, fin, st, &c),
    };
    Finding {
        effect: Found::Effect(effect),
        stated,
        params_u,
        significance: st.significance,
        heldout_rms_before_um: before,
        heldout_rms_after_um: after,
        cause,
        alternatives: Vec::new(),
    }
}

/// The sentence that says what the file states about α, if anything.
fn stated_alpha(data: &PositioningData) -> String {
    data.alpha_um_per_m_k
        .map(|a| format!(" (the file states {a} µm/(m·K))"))
        .unwrap_or_default()
}

fn linear(c: &Coefs, has_times: bool) -> Described {
    let rate = c.beta[0];
    let cause = format!(
        "steady drift of every target, {rate:.2} µm {}: the measuring loop warms or cools \
         steadily — ball-screw heating or a slow change of the room temperature; check the screw \
         nut/bearing and air temperature records",
        if has_times {
            "per hour"
        } else {
            "per 3600 readings (no real times)"
        }
    );
    (
        Effect::LinearDrift {
            rate_um_per_h: rate,
        },
        Stated::default(),
        BTreeMap::from([("rate_um_per_h", c.ub[0])]),
        cause,
    )
}

fn warmup(c: &Coefs, has_times: bool) -> Described {
    let (amp, th) = (c.beta[0], c.theta);
    let mut params_u = BTreeMap::from([("amplitude_um", c.ub[0])]);
    if let Some(u) = c.u_theta {
        params_u.insert("tau_s", u);
    }
    let cause = format!(
        "warm-up: every target settles by {amp:.2} µm with a time constant of {} — the machine \
         (spindle, drives, ball screw) was not at thermal equilibrium at the start; warm it up \
         for at least 3 time constants ({}) before measuring",
        dur(th, has_times),
        dur(3.0 * th, has_times)
    );
    (
        Effect::ExponentialWarmup {
            amplitude_um: amp,
            tau_s: th,
        },
        Stated::default(),
        params_u,
        cause,
    )
}

fn cyclic(obs: &Run, c: &Coefs, has_times: bool) -> Described {
    let (a, b, ub) = (c.beta[0], c.beta[1], &c.ub);
    let th = c.theta;
    let amp = a.hypot(b);
    let u_amp = if amp > 0.0 {
        ((a * a * ub[0] * ub[0] + b * b * ub[1] * ub[1] + 2.0 * a * b * c.cov01) / (amp * amp))
            .max(0.0)
            .sqrt()
    } else {
        0.0
    };
    let mut params_u = BTreeMap::from([("amplitude_um", u_amp)]);
    if let Some(u) = c.u_theta {
        params_u.insert("period_s", u);
    }
    // Worded from the evidence: the period is not tied to the run's structure, but without
    // temperatures a coolant cycle is a hypothesis to confirm, not a finding.
    let cycle = obs
        .cycle_length_s()
        .map(|pc| format!(" (one measuring cycle lasts {})", dur(pc, has_times)))
        .unwrap_or_default();
    let temps = if obs.temp_c.is_some() {
        "compare the file's temperatures with this period"
    } else {
        "the file holds no temperatures, so this is not established"
    };
    let cause = format!(
        "periodic drift of the measuring loop, period {}, {amp:.2} µm amplitude, not tied to the \
         run's structure{cycle}: a spindle or coolant temperature cycle with this period would \
         explain it; {temps} — to confirm, log the coolant and spindle temperatures (or the \
         cooling unit's on/off times) during a run and check that they cycle with the same period",
        dur(th, has_times)
    );
    (
        Effect::CyclicDrift {
            period_s: th,
            amplitude_um: amp,
            phase_rad: b.atan2(a),
        },
        Stated::default(),
        params_u,
        cause,
    )
}

fn thermal(obs: &Run, data: &PositioningData, fin: &FinalFit, st: &Step, c: &Coefs) -> Described {
    let th = c.theta;
    let t_end = obs.t.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let grown = 1.0 - (-t_end / th).exp();
    let end = c.beta[0] * grown;
    let mut stated = Stated {
        scale_end_ppm: Some(end),
        ..Stated::default()
    };
    let mut params_u = BTreeMap::from([("scale_ppm", c.ub[0] * grown)]);
    if let Some(u) = c.u_theta {
        params_u.insert("tau_s", u);
    }
    let mut cause = format!(
        "scale change growing to {end:.1} µm/m by the end of the run (time constant {}): the \
         axis expands as it heats — ball-screw heating, or an uncompensated material temperature",
        dur(th, data.has_times)
    );
    if st.alpha_temp {
        // α from the regression on the measured material temperature.
        let tc = Family::ThermalTemp.columns(obs, f64::NAN);
        let mut cols = st.before_cols.clone();
        cols.extend(tc);
        let f2 = fit_mean(obs, &fin.w, &cols);
        let alpha = f2.beta[cols.len() - 1];
        let ua = (fin.sigma2 * f2.cov_unscaled[(cols.len() - 1, cols.len() - 1)])
            .max(0.0)
            .sqrt();
        stated.alpha_um_per_m_k = Some(alpha);
        params_u.insert("alpha_um_per_m_k", ua);
        cause = format!(
            "uncompensated material temperature: the file says material_compensation: off and \
             the measured material temperature explains the scale change ({end:.1} µm/m by the \
             end) with an expansion coefficient of {alpha:.1} ± {ua:.1} µm/(m·K){}; normalise \
             the readings to 20 °C",
            stated_alpha(data)
        );
    }
    let effect = Effect::ThermalExpansion {
        scale_ppm: c.beta[0],
        tau_s: th,
    };
    (effect, stated, params_u, cause)
}

fn step(obs: &Run, c: &Coefs, has_times: bool) -> Described {
    let (size, t_s) = (c.beta[0], c.theta);
    let first = obs
        .time_order
        .iter()
        .position(|&j| obs.t[j] >= t_s)
        .map_or(0, |k| k + 1);
    // The moment is known to the reading at best (half an interval either way), and to the
    // spread of the plausible moments when neighbouring readings fit nearly as well.
    let params_u = BTreeMap::from([
        ("size_um", c.ub[0]),
        ("time_s", (0.5 * obs.dt_s).max(c.u_theta.unwrap_or(0.0))),
    ]);
    let at = if has_times {
        format!("{:.1} min into the run", (t_s - obs.t0) / 60.0)
    } else {
        "(no real times)".into()
    };
    let cause = format!(
        "every reading from reading {first} on {at} is shifted by {size:+.2} µm: a sudden change \
         of the measuring set-up or the axis — a bumped optic, tripod or sensor bracket, a \
         re-datum or a slipped coupling; check the run's log for an event at that moment and \
         repeat the run"
    );
    (
        Effect::Step {
            time_s: t_s,
            size_um: size,
        },
        Stated::default(),
        params_u,
        cause,
    )
}

fn reversal_drift(obs: &Run, c: &Coefs, has_times: bool) -> Described {
    let change = c.beta[0];
    let cause = format!(
        "the reversal value B = x̄↑ − x̄↓ changes by {change:+.2} µm from the start to the end of \
         the run ({}): backlash that changes as the screw nut, drive or guide warms; measure \
         B again after a warm-up and check the nut preload",
        dur(obs.duration_s, has_times)
    );
    (
        Effect::ReversalDrift {
            change_um: change,
            duration_s: obs.duration_s,
        },
        Stated::default(),
        BTreeMap::from([("change_um", c.ub[0])]),
        cause,
    )
}

fn cycle_offsets(c: &Coefs) -> Described {
    // Offsets relative to the first cycle (whose offset the baseline holds).
    let mut off = vec![0.0];
    off.extend(c.beta.iter().copied());
    let n = off.len() as f64;
    let mean = off.iter().sum::<f64>() / n;
    let sd = (off.iter().map(|o| (o - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
    // A standard deviation from n values: u ≈ s/√(2(n − 1)).
    let u = sd / (2.0 * (n - 1.0).max(1.0)).sqrt();
    let list = off
        .iter()
        .map(|o| format!("{:+.1}", o - mean))
        .collect::<Vec<_>>()
        .join(", ");
    let cause = format!(
        "each cycle is shifted by its own amount (standard deviation {sd:.2} µm; offsets {list} \
         µm): the reference was re-mounted, re-zeroed or moved between cycles, or the axis was \
         re-homed; check the set-up's stability and keep the reference untouched during a run"
    );
    (
        Effect::CycleOffsets { std_um: sd },
        Stated::default(),
        BTreeMap::from([("std_um", u)]),
        cause,
    )
}

/// The measured material temperature explains the scale change better than a time constant:
/// α is the coefficient of x·T.
fn thermal_temp(
    obs: &Run,
    data: &PositioningData,
    fin: &FinalFit,
    st: &Step,
    c: &Coefs,
) -> Described {
    let (alpha, ua) = (c.beta[0], c.ub[0]);
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
    // The simulator's form (scale with a time constant) fitted for the model.
    let p = Projector::new(obs, &fin.w, &st.before_cols);
    let y_perp = p.residualize(obs, &obs.y);
    let (scale, tau) = match search(obs, &p, &y_perp, Family::Thermal) {
        Some(cand) => {
            let mut cols = st.before_cols.clone();
            cols.extend(Family::Thermal.columns(obs, cand.theta));
            let f2 = fit_mean(obs, &fin.w, &cols);
            (f2.beta[cols.len() - 1], cand.theta)
        }
        None => (end, obs.duration_s),
    };
    let stated = Stated {
        scale_end_ppm: Some(end),
        alpha_um_per_m_k: Some(alpha),
        count: None,
    };
    let params_u = BTreeMap::from([("scale_ppm", ua * dt_k.abs()), ("alpha_um_per_m_k", ua)]);
    let cause = format!(
        "uncompensated material temperature: the file says material_compensation: off and the \
         measured material temperature ({dt_k:+.2} K over the run) explains the scale change \
         ({end:.1} µm/m by the end) with an expansion coefficient of {alpha:.1} ± {ua:.1} \
         µm/(m·K){}; normalise the readings to 20 °C",
        stated_alpha(data)
    );
    let effect = Effect::ThermalExpansion {
        scale_ppm: scale,
        tau_s: tau,
    };
    (effect, stated, params_u, cause)
}

/// A target that scatters more than the others.
pub(super) struct Anomaly {
    /// 0-based target.
    pub(super) target: usize,
    pub(super) ratio: f64,
    /// Noise of the ordinary targets, µm.
    pub(super) noise_others_um: f64,
    pub(super) finding: Finding,
}

/// Per-target residual sums of squares and degrees of freedom of the final fit.
struct TargetScatter {
    ss_t: Vec<f64>,
    /// Residual degrees of freedom per target.
    dof_t: Vec<f64>,
    ss_all: f64,
    dof_all: f64,
}

/// `trim`: each target's largest squared residual left out (and one degree of freedom).
fn target_scatter(obs: &Run, fin: &FinalFit, trim: bool) -> TargetScatter {
    let m = obs.n_targets;
    let mut ss_t = vec![0.0; m];
    let mut max_t = vec![0.0_f64; m];
    let mut n_t = vec![0usize; m];
    for j in 0..obs.len() {
        if fin.eval[j] {
            let r2 = fin.resid[j] * fin.resid[j];
            ss_t[obs.target[j]] += r2;
            max_t[obs.target[j]] = max_t[obs.target[j]].max(r2);
            n_t[obs.target[j]] += 1;
        }
    }
    if trim {
        for t in 0..m {
            if n_t[t] > 0 {
                ss_t[t] -= max_t[t];
                n_t[t] -= 1;
            }
        }
    }
    let dof_t: Vec<f64> = (0..m)
        .map(|t| n_t[t] as f64 - (0..2).filter(|d| fin.fit.has_group[2 * t + d]).count() as f64)
        .collect();
    TargetScatter {
        ss_all: ss_t.iter().sum(),
        dof_all: dof_t.iter().sum::<f64>() - fin.cols.len() as f64,
        ss_t,
        dof_t,
    }
}

/// Evidence (BIC decrease) for target `t` having its own, larger variance, and the ratio of
/// its standard deviation to the others'.
fn anomaly_evidence(sc: &TargetScatter, t: usize, ln_n: f64) -> Option<(f64, f64)> {
    let (ss_all, dof_all) = (sc.ss_all, sc.dof_all);
    let dk = sc.dof_t[t];
    let dr = dof_all - dk;
    if dof_all <= 2.0 || ss_all <= 0.0 || dk < 2.0 || dr < 2.0 || sc.ss_t[t] <= 0.0 {
        return None;
    }
    let (vk, vr) = (sc.ss_t[t] / dk, (ss_all - sc.ss_t[t]) / dr);
    // The other targets without scatter (readings repeated exactly): no ratio to state, and
    // the likelihood ratio would be infinite ("significance inf", found by the hostile sweep).
    if vk <= vr || vr <= 0.0 {
        return None;
    }
    // Profile log-likelihood ratio of separate vs common variance (×2).
    let lr = dof_all * (ss_all / dof_all).ln() - dk * vk.ln() - dr * vr.ln();
    let ratio = (vk / vr).sqrt();
    (ratio.is_finite() && lr.is_finite()).then_some((ratio, lr - 2.0 * ln_n))
}

/// Local anomaly: one target with its own variance (module docs).
pub(super) fn local_anomaly(
    obs: &Run,
    data: &PositioningData,
    fin: &FinalFit,
    opt: &Options,
) -> Option<Anomaly> {
    let ln_n = (obs.len() as f64).ln();
    let sc = target_scatter(obs, fin, false);
    let (ss_all, dof_all) = (sc.ss_all, sc.dof_all);
    let mut best: Option<(usize, f64, f64)> = None;
    for t in 0..obs.n_targets {
        if let Some((ratio, sig)) = anomaly_evidence(&sc, t, ln_n)
            && sig >= opt.min_bic_gain
            && best.is_none_or(|a| sig > a.2)
        {
            best = Some((t, ratio, sig));
        }
    }
    let (t, ratio, sig) = best?;
    // A scatter of its own is a property of the target's readings, not of one of them: the
    // evidence must survive leaving out every target's largest residual (one draw from the
    // tail of heavy-tailed noise can otherwise make an ordinary target look scattered).
    let trimmed = target_scatter(obs, fin, true);
    if anomaly_evidence(&trimmed, t, ln_n).is_none_or(|(_, s)| s < opt.min_bic_gain) {
        return None;
    }
    let (e_before, e_after) = anomaly_heldout_gain(obs, fin, t);
    // Ratio uncertainty from the F distribution's log-variance: u(ln v) ≈ √(2/dof), so
    // u(ln ratio) = c = ½√(2/dk + 2/dr). The ratio's interval is skewed (r·e^(±2c)); the
    // stated u is half the way to its upper end, so that ratio ± 2u covers it (the lower
    // side is then wider than it need be). With u = c·ratio, 8 % of issue 11's hidden
    // ratios were above ratio + 2u.
    let dk = sc.dof_t[t].max(1.0);
    let dr = (dof_all - dk).max(1.0);
    let c = 0.5 * (2.0 / dk + 2.0 / dr).sqrt();
    let u_ratio = ratio * ((2.0 * c).exp() - 1.0) / 2.0;
    let x_mm = data.targets_mm()[t];
    let finding = Finding {
        effect: Found::Effect(Effect::LocalAnomaly {
            index: t + 1,
            std_ratio: ratio,
        }),
        stated: Stated::default(),
        params_u: BTreeMap::from([("std_ratio", u_ratio)]),
        significance: sig,
        heldout_rms_before_um: e_before,
        heldout_rms_after_um: e_after,
        cause: format!(
            "target {} ({x_mm:.3} mm) scatters {ratio:.1}× more than the others: a local \
             structural fault (damaged screw thread or guide, loose scale or fixture) or a local \
             heat source near that position; inspect the axis there",
            t + 1
        ),
        alternatives: Vec::new(),
    };
    let dk = sc.dof_t[t];
    Some(Anomaly {
        target: t,
        ratio,
        noise_others_um: ((ss_all - sc.ss_t[t]) / (dof_all - dk).max(1.0)).sqrt(),
        finding,
    })
}

/// Gain of a local anomaly at target `t` on held-out cycles: predicted vs observed per-target
/// RMS residual, with a common scatter (before) and the target's own (after).
fn anomaly_heldout_gain(obs: &Run, fin: &FinalFit, t: usize) -> (f64, f64) {
    let m = obs.n_targets;
    let ho = heldout_residuals(obs, &fin.w, &fin.cols, &fin.eval);
    let mut sse = vec![vec![0.0; m]; obs.n_folds];
    let mut cnt = vec![vec![0usize; m]; obs.n_folds];
    for &(r, j) in &ho {
        sse[obs.fold[j]][obs.target[j]] += r * r;
        cnt[obs.fold[j]][obs.target[j]] += 1;
    }
    let (mut e_before, mut e_after, mut k) = (0.0, 0.0, 0usize);
    for f in 0..obs.n_folds {
        let (mut s_other, mut c_other, mut s_t, mut c_t) = (0.0, 0usize, 0.0, 0usize);
        for g in (0..obs.n_folds).filter(|g| *g != f) {
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
    ((e_before / k).sqrt(), (e_after / k).sqrt())
}

/// The outliers finding, if any reading was flagged.
pub(super) fn outlier_finding(
    obs: &Run,
    fin: &FinalFit,
    anomaly: Option<&Anomaly>,
) -> Option<Finding> {
    let n = obs.len();
    let ln_n = (n as f64).ln();
    let out = &fin.out;
    let n_out = out.iter().filter(|o| **o).count();
    if n_out == 0 {
        return None;
    }
    let mut var_t = vec![fin.sigma2; obs.n_targets];
    if let Some(a) = anomaly {
        var_t[a.target] = fin.sigma2 * a.ratio * a.ratio;
    }
    let resid = &fin.resid;
    let mags: Vec<f64> = (0..n).filter(|&j| out[j]).map(|j| resid[j].abs()).collect();
    let sig: f64 = (0..n)
        .filter(|&j| out[j])
        .map(|j| resid[j] * resid[j] / var_t[obs.target[j]] - ln_n)
        .sum();
    let var_factor = vec![1.0; obs.n_targets];
    let before = heldout_rms(
        obs,
        &weights(obs, &vec![false; n], &var_factor),
        &fin.cols,
        &fin.eval,
    );
    let after = heldout_rms(obs, &fin.w, &fin.cols, &fin.eval);
    let mean_mag = mags.iter().sum::<f64>() / mags.len() as f64;
    Some(Finding {
        effect: Found::Effect(Effect::Outliers {
            rate: n_out as f64 / n as f64,
            magnitude_um: mean_mag,
        }),
        stated: Stated {
            count: Some(n_out),
            ..Stated::default()
        },
        params_u: BTreeMap::new(),
        significance: sig,
        heldout_rms_before_um: before,
        heldout_rms_after_um: after,
        cause: format!(
            "{n_out} isolated reading(s) off their target's trend by {mean_mag:.1} µm on \
             average: a beam interruption, air turbulence or a vibration during the reading; \
             repeat those points"
        ),
        alternatives: Vec::new(),
    })
}
