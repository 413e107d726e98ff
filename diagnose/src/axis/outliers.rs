//! Outlier screening: readings beyond a Bonferroni bound of a robust scale of their target's
//! residuals are left out of every fit.

#![allow(clippy::needless_range_loop)]

use statrs::distribution::{ContinuousCDF, Normal};

use super::obs::Obs;

pub(super) fn robust_scale(v: &mut [f64]) -> f64 {
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
pub(super) fn flag_outliers(obs: &Obs, resid: &[f64], alpha: f64, n_targets: usize) -> Vec<bool> {
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

pub(super) fn group_median_residuals(obs: &Obs) -> Vec<f64> {
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

/// Least-squares weights: outliers left out, every other reading weighted by the inverse of
/// its target's variance factor.
pub(super) fn weights(obs: &Obs, out: &[bool], var: &[f64]) -> Vec<f64> {
    (0..obs.len())
        .map(|j| {
            if out[j] {
                0.0
            } else {
                1.0 / var[obs.target[j]]
            }
        })
        .collect()
}
