//! Before/after check of measured parts (paper 004, section III): means, standard deviations,
//! Welch's t-test of the mean shift, and the reject rate predicted by a normal fit against the
//! tolerance. Their example: 50 thread gauges, reject 10.6 % before correction, 0.52 % after,
//! scatter unchanged (only systematic errors are corrected).

use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

/// Errors of the parts check.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PartsError {
    /// sample `{which}` has {n} values: at least 2 are needed for a standard deviation
    #[error("sample `{which}` has {n} values: at least 2 are needed for a standard deviation")]
    TooFew { which: String, n: usize },
    /// sample `{which}`, value {index}: not a finite number
    #[error("sample `{which}`, value {index}: not a finite number")]
    NonFinite { which: String, index: usize },
    /// tolerance: lower limit {lo} must be below upper limit {hi}
    #[error("tolerance: lower limit {lo} must be below upper limit {hi}")]
    BadTolerance { lo: f64, hi: f64 },
    /// both samples have zero scatter: the t-test is undefined
    #[error("both samples have zero scatter: the t-test is undefined")]
    NoScatter,
    /// sample `{which}`: {msg}
    #[error("sample `{which}`: {msg}")]
    Parse { which: String, msg: String },
}

/// Statistics of one sample against the tolerance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SampleStats {
    pub n: usize,
    pub mean: f64,
    /// Sample standard deviation (n − 1).
    pub std_dev: f64,
    /// Fraction outside the tolerance predicted by N(mean, std_dev), percent.
    pub predicted_reject_pct: f64,
    /// Fraction of the sample actually outside the tolerance, percent.
    pub observed_reject_pct: f64,
}

/// The before/after comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PartsReport {
    pub tolerance: [f64; 2],
    pub before: SampleStats,
    pub after: SampleStats,
    /// `mean_after − mean_before`.
    pub mean_shift: f64,
    /// Welch's t statistic of the mean shift.
    pub t: f64,
    /// Welch–Satterthwaite degrees of freedom.
    pub dof: f64,
    /// Two-sided p-value.
    pub p_value: f64,
    /// Significant at 5 % (two-sided).
    pub significant: bool,
    /// F = s_after² / s_before² (scatter ratio; the correction should leave it near 1);
    /// `None` when it is not a finite number (the before sample has no scatter).
    pub variance_ratio: Option<f64>,
}

fn stats(which: &str, x: &[f64], lo: f64, hi: f64) -> Result<SampleStats, PartsError> {
    if x.len() < 2 {
        return Err(PartsError::TooFew {
            which: which.into(),
            n: x.len(),
        });
    }
    if let Some(i) = x.iter().position(|v| !v.is_finite()) {
        return Err(PartsError::NonFinite {
            which: which.into(),
            index: i + 1,
        });
    }
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let sd = var.sqrt();
    let predicted = if sd > 0.0 {
        let nd = Normal::new(mean, sd).map_err(|e| PartsError::Parse {
            which: which.into(),
            msg: e.to_string(),
        })?;
        nd.cdf(lo) + (1.0 - nd.cdf(hi))
    } else if mean < lo || mean > hi {
        1.0
    } else {
        0.0
    };
    let observed = x.iter().filter(|&&v| v < lo || v > hi).count() as f64 / n;
    Ok(SampleStats {
        n: x.len(),
        mean,
        std_dev: sd,
        predicted_reject_pct: predicted * 100.0,
        observed_reject_pct: observed * 100.0,
    })
}

/// Compare two samples of a part dimension against the tolerance `[lo, hi]`.
pub fn compare(before: &[f64], after: &[f64], lo: f64, hi: f64) -> Result<PartsReport, PartsError> {
    if !lo.is_finite() || !hi.is_finite() || lo >= hi {
        return Err(PartsError::BadTolerance { lo, hi });
    }
    let b = stats("before", before, lo, hi)?;
    let a = stats("after", after, lo, hi)?;
    let vb = b.std_dev.powi(2) / b.n as f64;
    let va = a.std_dev.powi(2) / a.n as f64;
    if vb + va <= 0.0 {
        return Err(PartsError::NoScatter);
    }
    let t = (a.mean - b.mean) / (vb + va).sqrt();
    // Welch–Satterthwaite.
    let dof = (vb + va).powi(2) / (vb * vb / (b.n as f64 - 1.0) + va * va / (a.n as f64 - 1.0));
    let td = StudentsT::new(0.0, 1.0, dof).map_err(|_| PartsError::NoScatter)?;
    let p = 2.0 * (1.0 - td.cdf(t.abs()));
    let variance_ratio = Some((a.std_dev / b.std_dev).powi(2)).filter(|f| f.is_finite());
    Ok(PartsReport {
        tolerance: [lo, hi],
        mean_shift: a.mean - b.mean,
        t,
        dof,
        p_value: p,
        significant: p < 0.05,
        variance_ratio,
        before: b,
        after: a,
    })
}

/// Read a sample: one number per line, or a CSV whose first numeric column (or the column
/// named `value`) holds the dimension; `#` lines and a header line are skipped.
pub fn parse_sample(which: &str, text: &str) -> Result<Vec<f64>, PartsError> {
    let mut col: Option<usize> = None;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if col.is_none() && out.is_empty() {
            if let Some(k) = fields
                .iter()
                .position(|f| *f == "value" || f.ends_with("_mm") || f.ends_with("_um"))
            {
                col = Some(k);
                continue;
            }
            if fields.iter().all(|f| f.parse::<f64>().is_err()) {
                continue; // header without a recognised name: take the first column
            }
        }
        let k = col.unwrap_or(0);
        let s = fields.get(k).copied().unwrap_or("");
        let v: f64 = s.parse().map_err(|_| PartsError::Parse {
            which: which.into(),
            msg: format!("line {}: `{s}` is not a number", i + 1),
        })?;
        out.push(v);
    }
    Ok(out)
}
