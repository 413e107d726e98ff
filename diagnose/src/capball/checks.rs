//! Model-free checks of CapBall residuals: the white-noise level from pose-to-pose
//! differences, outlying poses, and residual profiles against time, A and C.

use nalgebra::DVector;
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, Normal};

use super::model::CapballRun;

/// Median of a slice (NaN-free input); 0 for an empty slice.
pub(crate) fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Standard deviation of the white noise per channel, µm, from the second differences of the
/// residuals in measuring order, `r_i − (r_{i−1} + r_{i+1})/2` (variance 1.5 σ² for white
/// noise; smooth effects — drift, low harmonics of the angles — nearly cancel), with a robust
/// scale (MAD) so that outliers do not inflate it.
pub(crate) fn noise_sigma(resid: &DVector<f64>, keep_pose: &[bool]) -> [f64; 3] {
    let n = keep_pose.len();
    let mut out = [0.0; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut d: Vec<f64> = (1..n.saturating_sub(1))
            .filter(|&i| keep_pose[i - 1] && keep_pose[i] && keep_pose[i + 1])
            .map(|i| {
                (resid[3 * i + k] - 0.5 * (resid[3 * (i - 1) + k] + resid[3 * (i + 1) + k])).abs()
            })
            .collect();
        *o = 1.4826 * median(&mut d) / 1.5f64.sqrt();
    }
    out
}

/// Poses whose residual on some channel departs from the running median of its neighbours
/// (±3 poses) by more than a Bonferroni bound (family-wise `alpha` over all residuals) of the
/// robust scale of those departures. Smooth effects pass through the running median, so a
/// drift or an axis error does not raise false outliers.
pub(crate) fn outlier_poses(resid: &DVector<f64>, n: usize, alpha: f64) -> Vec<bool> {
    let mut flag = vec![false; n];
    if n < 8 {
        return flag;
    }
    let z = Normal::new(0.0, 1.0)
        .map(|d| d.inverse_cdf(1.0 - alpha / (2.0 * 3.0 * n as f64)))
        .unwrap_or(4.5);
    for k in 0..3 {
        let h: Vec<f64> = (0..n)
            .map(|i| {
                let lo = i.saturating_sub(3);
                let hi = (i + 4).min(n);
                let mut w: Vec<f64> = (lo..hi)
                    .filter(|&j| j != i)
                    .map(|j| resid[3 * j + k])
                    .collect();
                resid[3 * i + k] - median(&mut w)
            })
            .collect();
        let mut a: Vec<f64> = h.iter().map(|v| v.abs()).collect();
        // The departure from a 6-point median has variance ≈ σ² (1 + π/(2·6)).
        let scale = 1.4826 * median(&mut a);
        if scale <= 0.0 {
            continue;
        }
        for i in 0..n {
            if h[i].abs() > z * scale {
                flag[i] = true;
            }
        }
    }
    flag
}

/// Residual means in bins of one variable, per channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    /// `time_s`, `a_deg` or `c_deg`.
    pub against: String,
    /// Bin centres.
    pub at: Vec<f64>,
    /// Mean residual per bin, µm, x / y / z.
    pub mean_um: [Vec<f64>; 3],
}

/// Per channel RMS and binned profiles of one run's residuals.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualSummary {
    /// `identification` or `validation`.
    pub run: String,
    pub rms_um: [f64; 3],
    /// White-noise level from pose-to-pose differences, µm.
    pub noise_um: [f64; 3],
    pub profiles: Vec<Profile>,
}

/// Summary of a run's residuals (`keep` per pose), 12 bins per profile.
pub(crate) fn summarise(
    name: &str,
    run: &CapballRun,
    resid: &DVector<f64>,
    keep: &[bool],
) -> ResidualSummary {
    let n = run.len();
    let cnt = keep.iter().filter(|k| **k).count().max(1) as f64;
    let mut rms = [0.0; 3];
    for i in (0..n).filter(|&i| keep[i]) {
        for (k, r) in rms.iter_mut().enumerate() {
            *r += resid[3 * i + k].powi(2);
        }
    }
    let rms = rms.map(|v| (v / cnt).sqrt());
    let vars: [(&str, Vec<f64>); 3] = [
        ("time_s", run.time_s.clone()),
        ("a_deg", run.poses.iter().map(|p| p.a_deg).collect()),
        ("c_deg", run.poses.iter().map(|p| p.c_deg).collect()),
    ];
    let profiles = vars
        .into_iter()
        .map(|(name, v)| binned(name, &v, resid, keep, 12))
        .collect();
    ResidualSummary {
        run: name.into(),
        rms_um: rms,
        noise_um: noise_sigma(resid, keep),
        profiles,
    }
}

fn binned(name: &str, v: &[f64], resid: &DVector<f64>, keep: &[bool], bins: usize) -> Profile {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w = ((hi - lo) / bins as f64).max(1e-12);
    let mut sum = [vec![0.0; bins], vec![0.0; bins], vec![0.0; bins]];
    let mut cnt = vec![0usize; bins];
    for (i, x) in v.iter().enumerate() {
        if !keep[i] {
            continue;
        }
        let b = (((x - lo) / w) as usize).min(bins - 1);
        cnt[b] += 1;
        for (k, s) in sum.iter_mut().enumerate() {
            s[b] += resid[3 * i + k];
        }
    }
    let mean_um = sum.map(|s| {
        s.iter()
            .zip(&cnt)
            .map(|(s, c)| if *c > 0 { s / *c as f64 } else { 0.0 })
            .collect()
    });
    Profile {
        against: name.into(),
        at: (0..bins).map(|b| lo + (b as f64 + 0.5) * w).collect(),
        mean_um,
    }
}
