//! Least-squares machinery of the diagnosis: the observations, the baseline's per-target,
//! per-direction constants profiled out of every fit (Frisch–Waugh–Lovell), and held-out
//! prediction errors on cycles dealt into folds (`docs/datasets.md`, "Diagnosis report").

#![allow(clippy::needless_range_loop)]

use nalgebra::{DMatrix, DVector};

use super::obs::Obs;
use super::projector::{Fixed, Projector};

/// A fitted mean model: group intercepts and column coefficients; predicts any row.
pub(super) struct MeanFit {
    pub(super) alpha: Vec<f64>,
    pub(super) has_group: Vec<bool>,
    pub(super) beta: DVector<f64>,
    pub(super) cov_unscaled: DMatrix<f64>,
    /// With offsets per cycle in the model: the column of each cycle's offset (None for the
    /// reference cycle), the cycles with weight in the fit, and the mean offset of those.
    cycles: Option<CycleFit>,
}

/// Offsets per cycle in a fitted model ([`MeanFit`]).
struct CycleFit {
    column: Vec<Option<usize>>,
    seen: Vec<bool>,
    mean: f64,
}

pub(super) fn fit_mean(obs: &Obs, w: &[f64], cols: &[Vec<f64>]) -> MeanFit {
    let p = Projector::new(obs, w, cols);
    let yc = p.center(obs, &obs.y);
    let beta = p.coef(obs, &yc);
    let gy = p.group_means(obs, &obs.y);
    let mut alpha = gy;
    for (k, c) in cols.iter().enumerate() {
        let gc = p.fixed_group_means(obs, k, c);
        for (a, g) in alpha.iter_mut().zip(gc) {
            *a -= beta[k] * g;
        }
    }
    let cycles = cycle_fit(obs, &p, &beta);
    MeanFit {
        alpha,
        has_group: p.gsum().iter().map(|s| *s > 0.0).collect(),
        beta,
        cov_unscaled: p.ginv,
        cycles,
    }
}

/// The offsets per cycle of a fit, if its model has them. A cycle without weight in the fit
/// (held out whole) has no offset of its own there: it is predicted at the mean offset of the
/// cycles fitted, which is identified even where the training cycles' indicators add up to
/// the group constants (the reference cycle held out).
fn cycle_fit(obs: &Obs, p: &Projector, beta: &DVector<f64>) -> Option<CycleFit> {
    let mut column = vec![None; obs.n_cycles];
    for (k, f) in p.fixed().iter().enumerate() {
        if let Fixed::Cycle(c) = f {
            column[*c] = Some(k);
        }
    }
    if column.iter().all(Option::is_none) {
        return None;
    }
    let seen: Vec<bool> = (0..obs.n_cycles)
        .map(|c| p.counts.cycle_weight(c) > 0.0)
        .collect();
    let offsets: Vec<f64> = (0..obs.n_cycles)
        .filter(|c| seen[*c])
        .map(|c| column[c].map_or(0.0, |k| beta[k]))
        .collect();
    let mean = offsets.iter().sum::<f64>() / offsets.len().max(1) as f64;
    Some(CycleFit { column, seen, mean })
}

impl MeanFit {
    pub(super) fn predict(&self, obs: &Obs, cols: &[Vec<f64>], j: usize) -> Option<f64> {
        let g = obs.group[j];
        if !self.has_group[g] {
            return None;
        }
        let mut v = self.alpha[g]
            + cols
                .iter()
                .enumerate()
                .map(|(k, c)| self.beta[k] * c[j])
                .sum::<f64>();
        if let Some(cy) = &self.cycles
            && !cy.seen[obs.cycle[j]]
        {
            let own = cy.column[obs.cycle[j]].map_or(0.0, |k| self.beta[k]);
            v += cy.mean - own;
        }
        Some(v)
    }
}

/// Held-out residuals: each fold predicted from a fit on the others (non-linear parameters
/// kept). Returns `(residual, row)` for rows with `eval[j]`.
pub(super) fn heldout_residuals(
    obs: &Obs,
    w: &[f64],
    cols: &[Vec<f64>],
    eval: &[bool],
) -> Vec<(f64, usize)> {
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

pub(super) fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x * x;
        n += 1;
    }
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

pub(super) fn heldout_rms(obs: &Obs, w: &[f64], cols: &[Vec<f64>], eval: &[bool]) -> f64 {
    rms(heldout_residuals(obs, w, cols, eval)
        .into_iter()
        .map(|r| r.0))
}

pub(super) fn in_sample_residuals(obs: &Obs, w: &[f64], cols: &[Vec<f64>]) -> (MeanFit, Vec<f64>) {
    let fit = fit_mean(obs, w, cols);
    let r = (0..obs.len())
        .map(|j| obs.y[j] - fit.predict(obs, cols, j).unwrap_or(obs.y[j]))
        .collect();
    (fit, r)
}

/// The final joint fit of the selected mean effects, outliers settled.
pub(super) struct FinalFit {
    /// Outlier flags.
    pub(super) out: Vec<bool>,
    /// Weights of the fit (outliers left out).
    pub(super) w: Vec<f64>,
    /// Rows the held-out errors are evaluated on (not outliers).
    pub(super) eval: Vec<bool>,
    /// Columns of every selected effect, in selection order.
    pub(super) cols: Vec<Vec<f64>>,
    pub(super) fit: MeanFit,
    /// In-sample residuals of every row.
    pub(super) resid: Vec<f64>,
    /// Residual variance of the non-outliers.
    pub(super) sigma2: f64,
}
