//! Least-squares machinery of the diagnosis: the observations, the baseline's per-target,
//! per-direction constants profiled out of every fit (Frisch–Waugh–Lovell), and held-out
//! prediction errors on cycles dealt into folds (`docs/datasets.md`, "Diagnosis report").

#![allow(clippy::needless_range_loop)]

use std::sync::OnceLock;

use nalgebra::{DMatrix, DVector};

use super::blocks::block_pair_s;
use super::family::{cycle_length_s, median_step};
use super::projector::{Fixed, Projector};
use super::sums::Cache;
use positioning::positioning_data::{PositioningData, dir_slot};

pub(super) struct Obs {
    pub(super) y: Vec<f64>,
    pub(super) t: Vec<f64>,
    pub(super) x_mm: Vec<f64>,
    pub(super) temp_c: Option<Vec<f64>>,
    pub(super) group: Vec<usize>,
    pub(super) n_groups: usize,
    pub(super) n_targets: usize,
    pub(super) target: Vec<usize>,
    pub(super) fold: Vec<usize>,
    pub(super) n_folds: usize,
    pub(super) duration_s: f64,
    pub(super) dt_s: f64,
    /// Start of the run, s.
    pub(super) t0: f64,
    /// +½ for positive approaches, −½ for negative ones: B = x̄↑ − x̄↓ changes by the
    /// coefficient of a column `dir_half · f(t)` when f goes from 0 to 1 (`docs/datasets.md`).
    pub(super) dir_half: Vec<f64>,
    /// 0-based cycle of every row.
    pub(super) cycle: Vec<usize>,
    pub(super) n_cycles: usize,
    /// Rows in time order (ties in row order).
    pub(super) time_order: Vec<usize>,
    /// Columns of the searched effects and their weighted sums, kept for the run.
    pub(super) cache: Cache,
    /// Length of one bidirectional cycle, s ([`cycle_length_s`]), or of a pair of blocks in a
    /// run measured in blocks ([`block_pair_s`]): every period of a cyclic drift's grid is
    /// checked against it.
    pub(super) cycle_s: Option<f64>,
    /// The same observations with diagonal folds ([`Obs::diagonal`]).
    diagonal: OnceLock<Box<Obs>>,
}

impl Obs {
    pub(super) fn new(data: &PositioningData, max_folds: usize) -> Self {
        let r = &data.readings;
        let t0 = r.iter().map(|r| r.time_s).fold(f64::INFINITY, f64::min);
        let t1 = r.iter().map(|r| r.time_s).fold(f64::NEG_INFINITY, f64::max);
        let mut ts: Vec<f64> = r.iter().map(|r| r.time_s).collect();
        ts.sort_by(f64::total_cmp);
        let dt_s = median_step(&ts).unwrap_or(1.0);
        let n_folds = data.n_cycles().clamp(2, max_folds.max(2));
        let temp_c = r
            .iter()
            .all(|r| r.material_c.is_some())
            .then(|| r.iter().map(|r| r.material_c.unwrap_or(0.0)).collect());
        let mut obs = Obs {
            y: r.iter().map(|r| r.deviation_um).collect(),
            t: r.iter().map(|r| r.time_s).collect(),
            x_mm: r.iter().map(|r| r.target_mm).collect(),
            temp_c,
            group: r
                .iter()
                .map(|r| 2 * (r.index - 1) + dir_slot(r.direction))
                .collect(),
            n_groups: 2 * data.n_targets(),
            n_targets: data.n_targets(),
            target: r.iter().map(|r| r.index - 1).collect(),
            fold: r.iter().map(|r| (r.cycle - 1) % n_folds).collect(),
            n_folds,
            duration_s: (t1 - t0).max(1.0),
            dt_s,
            t0,
            dir_half: r
                .iter()
                .map(|r| 0.5 - dir_slot(r.direction) as f64)
                .collect(),
            cycle: r.iter().map(|r| r.cycle - 1).collect(),
            n_cycles: data.n_cycles(),
            time_order: {
                let mut o: Vec<usize> = (0..r.len()).collect();
                o.sort_by(|&a, &b| r[a].time_s.total_cmp(&r[b].time_s));
                o
            },
            cache: Cache::default(),
            cycle_s: None,
            diagonal: OnceLock::new(),
        };
        obs.cycle_s = block_pair_s(&obs).or_else(|| cycle_length_s(&obs));
        obs
    }

    /// The same observations with folds dealt diagonally over (cycle, target), made when
    /// first needed: every held-out reading then has readings of its own cycle and of its
    /// own target in the training set, which an effect per cycle (`cycle_offsets`) needs to
    /// be checked on at all.
    pub(super) fn diagonal(&self) -> &Obs {
        self.diagonal.get_or_init(|| {
            let fold = (0..self.len())
                .map(|j| (self.cycle[j] + self.target[j]) % self.n_folds)
                .collect();
            Box::new(Obs {
                y: self.y.clone(),
                t: self.t.clone(),
                x_mm: self.x_mm.clone(),
                temp_c: self.temp_c.clone(),
                group: self.group.clone(),
                target: self.target.clone(),
                fold,
                dir_half: self.dir_half.clone(),
                cycle: self.cycle.clone(),
                time_order: self.time_order.clone(),
                cache: Cache::default(),
                diagonal: OnceLock::new(),
                ..*self
            })
        })
    }

    pub(super) fn len(&self) -> usize {
        self.y.len()
    }
}

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
