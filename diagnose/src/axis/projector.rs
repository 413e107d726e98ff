//! Least squares with the baseline's per-target, per-direction constants profiled out
//! (Frisch–Waugh–Lovell): a [`Projector`] holds fixed columns centred within those groups and
//! takes the groups and the columns out of any vector; [`Projector::fit_cols`] gives the RSS
//! of y once further columns are added, without forming their residuals.
//!
//! Offsets per cycle (`Family::CycleOffsets`: one indicator column per cycle, a hundred on a
//! long run) are held as cycle numbers ([`Fixed::Cycle`]): their products with other columns
//! are sums by cycle and their Gram matrix follows from weights counted by group and cycle, so
//! all of them together cost about one pass over the readings, not one pass each. The values
//! are those of the dense columns (the same sums, in another order).

#![allow(clippy::needless_range_loop)]

use std::sync::OnceLock;

use nalgebra::{DMatrix, DVector};

use super::obs::Obs;

/// Sum of the products of `a` and `b` (four partial sums, so that the loop vectorises).
pub(super) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..4 {
            acc[i] += x[i] * y[i];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Weighted sum of the products of `a` and `b`.
pub(super) fn dotw(a: &[f64], b: &[f64], w: &[f64]) -> f64 {
    a.iter().zip(b).zip(w).map(|((a, b), w)| a * b * w).sum()
}

/// Weights counted by group and by cycle: what the centred cycle indicators are made of.
pub(super) struct Counts {
    /// Weight of each (target, direction) group.
    pub(super) group: Vec<f64>,
    /// Weight of each cycle.
    cycle: Vec<f64>,
    /// Weight of each (group, cycle), `gc[g * n_cycles + c]`.
    gc: Vec<f64>,
    n_cycles: usize,
    /// [`Counts::share`] of every (group, cycle), computed when first needed.
    shares: OnceLock<Vec<f64>>,
}

impl Counts {
    pub(super) fn new(obs: &Obs, w: &[f64]) -> Self {
        let nc = obs.n_cycles;
        let mut c = Counts {
            group: vec![0.0; obs.n_groups],
            cycle: vec![0.0; nc],
            gc: vec![0.0; obs.n_groups * nc],
            n_cycles: nc,
            shares: OnceLock::new(),
        };
        for j in 0..obs.len() {
            let (g, k) = (obs.group[j], obs.cycle[j]);
            c.group[g] += w[j];
            c.cycle[k] += w[j];
            c.gc[g * nc + k] += w[j];
        }
        c
    }

    /// Weight of cycle `c`.
    pub(super) fn cycle_weight(&self, c: usize) -> f64 {
        self.cycle[c]
    }

    /// Group g's mean of the indicator of cycle `c` (the share of its weight in that cycle).
    pub(super) fn share(&self, g: usize, c: usize) -> f64 {
        let nc = self.n_cycles;
        self.shares.get_or_init(|| {
            (0..self.gc.len())
                .map(|i| {
                    let n = self.group[i / nc];
                    if n > 0.0 { self.gc[i] / n } else { 0.0 }
                })
                .collect()
        })[g * nc + c]
    }

    /// Weighted product of cycle `c`'s centred indicator with a column whose weighted sums by
    /// group and by cycle are `by_group` and `by_cycle`.
    pub(super) fn cycle_product(&self, c: usize, by_group: &[f64], by_cycle: &[f64]) -> f64 {
        by_cycle[c]
            - (0..by_group.len())
                .map(|g| self.share(g, c) * by_group[g])
                .sum::<f64>()
    }

    /// Weighted product of the indicators of cycles `c` and `d`, both centred within the
    /// groups: δ_cd·n_c − Σ_g n_gc·n_gd / n_g.
    fn cycle_gram(&self, c: usize, d: usize) -> f64 {
        let mut s = if c == d { self.cycle[c] } else { 0.0 };
        for g in 0..self.group.len() {
            s -= self.gc[g * self.n_cycles + c] * self.share(g, d);
        }
        s
    }
}

/// A column centred within the groups.
pub(super) enum Fixed {
    /// Any column: its centred values and their weighted sums by cycle.
    Dense {
        zc: Vec<f64>,
        /// Weighted sums of `zc` by cycle (when first needed, against a cycle's indicator).
        by_cycle: OnceLock<Vec<f64>>,
    },
    /// The indicator of a cycle (0-based).
    Cycle(usize),
}

/// The cycle whose indicator `col` is (1 on that cycle's readings, 0 elsewhere), if it is one.
fn cycle_indicator(obs: &Obs, col: &[f64]) -> Option<usize> {
    let j = col.iter().position(|v| *v != 0.0)?;
    let c = obs.cycle[j];
    col.iter()
        .zip(&obs.cycle)
        .all(|(v, &k)| *v == f64::from(k == c))
        .then_some(c)
}

/// Weighted sums of `v` by cycle.
fn cycle_sums(obs: &Obs, w: &[f64], v: &[f64]) -> Vec<f64> {
    let mut s = vec![0.0; obs.n_cycles];
    for j in 0..obs.len() {
        s[obs.cycle[j]] += w[j] * v[j];
    }
    s
}

/// Group means of `v` (weights `w`, groups of weight `n`); 0 for an empty group.
fn group_means(obs: &Obs, n: &[f64], w: &[f64], v: &[f64]) -> Vec<f64> {
    let mut s = vec![0.0; obs.n_groups];
    for (j, &g) in obs.group.iter().enumerate() {
        s[g] += w[j] * v[j];
    }
    s.iter()
        .zip(n)
        .map(|(s, n)| if *n > 0.0 { s / n } else { 0.0 })
        .collect()
}

/// `cols` centred within the groups.
fn centre_all(obs: &Obs, c: &Counts, w: &[f64], cols: &[Vec<f64>]) -> Vec<Fixed> {
    cols.iter()
        .map(|col| match cycle_indicator(obs, col) {
            Some(k) => Fixed::Cycle(k),
            None => {
                let m = group_means(obs, &c.group, w, col);
                let zc: Vec<f64> = col.iter().zip(&obs.group).map(|(v, &g)| v - m[g]).collect();
                Fixed::Dense {
                    zc,
                    by_cycle: OnceLock::new(),
                }
            }
        })
        .collect()
}

/// Weighted product of two centred columns.
fn gram(obs: &Obs, c: &Counts, w: &[f64], a: &Fixed, b: &Fixed) -> f64 {
    match (a, b) {
        (Fixed::Dense { zc: x, .. }, Fixed::Dense { zc: y, .. }) => dotw(x, y, w),
        (Fixed::Dense { zc, by_cycle }, Fixed::Cycle(k))
        | (Fixed::Cycle(k), Fixed::Dense { zc, by_cycle }) => {
            by_cycle.get_or_init(|| cycle_sums(obs, w, zc))[*k]
        }
        (Fixed::Cycle(k), Fixed::Cycle(l)) => c.cycle_gram(*k, *l),
    }
}

/// A column is collinear with the ones before it when less than this share of its weighted
/// sum of squares is left after them (a Cholesky pivot over its diagonal element).
const COLLINEAR: f64 = 1e-10;

/// Inverse of a Gram matrix; a pseudo-inverse when columns are collinear.
///
/// Whether an LU or Cholesky inversion of a singular Gram matrix fails or returns huge values
/// depends on rounding, so a matrix whose smallest Cholesky pivot is below [`COLLINEAR`] of
/// its diagonal element is inverted in its eigenvectors, scaled to a unit diagonal (each
/// column's own units), with eigenvalues below [`COLLINEAR`] of the largest dropped: collinear
/// columns share their coefficient, a column of zeros gets 0, and the fit is the same.
pub(super) fn gram_inverse(g: DMatrix<f64>) -> DMatrix<f64> {
    let k = g.nrows();
    let full_rank = g.clone().cholesky().filter(|ch| {
        let l = ch.l_dirty();
        (0..k).all(|i| l[(i, i)] * l[(i, i)] > COLLINEAR * g[(i, i)])
    });
    if let Some(ch) = full_rank {
        return ch.inverse();
    }
    let top = (0..k).map(|i| g[(i, i)]).fold(0.0, f64::max);
    let scale: Vec<f64> = (0..k)
        .map(|i| {
            let d = g[(i, i)];
            if d > COLLINEAR * top {
                1.0 / d.sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let scaled = DMatrix::from_fn(k, k, |a, b| g[(a, b)] * scale[a] * scale[b]);
    let eig = scaled.symmetric_eigen();
    let lmax = eig.eigenvalues.iter().fold(0.0, |m: f64, v| m.max(*v));
    let mut inv = DMatrix::zeros(k, k);
    for (i, &l) in eig.eigenvalues.iter().enumerate() {
        if l > COLLINEAR * lmax {
            let v = eig.eigenvectors.column(i);
            inv += (v * v.transpose()) / l;
        }
    }
    DMatrix::from_fn(k, k, |a, b| inv[(a, b)] * scale[a] * scale[b])
}

/// Least squares of y on group constants plus fixed columns, over rows with weight > 0.
pub(super) struct Projector {
    pub(super) w: Vec<f64>,
    pub(super) counts: Counts,
    fixed: Vec<Fixed>,
    /// Inverse of the fixed columns' Gram matrix (a pseudo-inverse when it is singular).
    pub(super) ginv: DMatrix<f64>,
}

impl Projector {
    pub(super) fn new(obs: &Obs, w: &[f64], cols: &[Vec<f64>]) -> Self {
        let counts = Counts::new(obs, w);
        let fixed = centre_all(obs, &counts, w, cols);
        let k = fixed.len();
        let mut g = DMatrix::zeros(k, k);
        for a in 0..k {
            for b in a..k {
                let v = gram(obs, &counts, w, &fixed[a], &fixed[b]);
                g[(a, b)] = v;
                g[(b, a)] = v;
            }
        }
        let ginv = gram_inverse(g);
        Projector {
            w: w.to_vec(),
            counts,
            fixed,
            ginv,
        }
    }

    fn has_cycles(&self) -> bool {
        self.fixed.iter().any(|f| matches!(f, Fixed::Cycle(_)))
    }

    /// Weight of each group.
    pub(super) fn gsum(&self) -> &[f64] {
        &self.counts.group
    }

    pub(super) fn group_means(&self, obs: &Obs, v: &[f64]) -> Vec<f64> {
        group_means(obs, &self.counts.group, &self.w, v)
    }

    /// Group means of fixed column `k` (`col` its values).
    pub(super) fn fixed_group_means(&self, obs: &Obs, k: usize, col: &[f64]) -> Vec<f64> {
        match self.fixed[k] {
            Fixed::Cycle(c) => (0..obs.n_groups).map(|g| self.counts.share(g, c)).collect(),
            Fixed::Dense { .. } => self.group_means(obs, col),
        }
    }

    pub(super) fn center(&self, obs: &Obs, v: &[f64]) -> Vec<f64> {
        let m = self.group_means(obs, v);
        v.iter().zip(&obs.group).map(|(v, &g)| v - m[g]).collect()
    }

    /// Weighted products of the fixed columns with `vc` (centred).
    fn dots(&self, obs: &Obs, vc: &[f64]) -> DVector<f64> {
        let by_cycle = if self.has_cycles() {
            cycle_sums(obs, &self.w, vc)
        } else {
            Vec::new()
        };
        DVector::from_iterator(
            self.fixed.len(),
            self.fixed.iter().map(|f| match f {
                Fixed::Dense { zc, .. } => dotw(zc, vc, &self.w),
                Fixed::Cycle(c) => by_cycle[*c],
            }),
        )
    }

    /// Coefficients of the fixed columns for `vc` (already centred).
    pub(super) fn coef(&self, obs: &Obs, vc: &[f64]) -> DVector<f64> {
        &self.ginv * self.dots(obs, vc)
    }

    /// `v` with the groups and the fixed columns taken out.
    pub(super) fn residualize(&self, obs: &Obs, v: &[f64]) -> Vec<f64> {
        let mut vc = self.center(obs, v);
        let c = self.coef(obs, &vc);
        // The cycles' part: coefficient of the row's cycle minus its group's mean.
        let mut per_cycle = vec![0.0; obs.n_cycles];
        for (k, z) in self.fixed.iter().enumerate() {
            match z {
                Fixed::Dense { zc, .. } => {
                    for (a, b) in vc.iter_mut().zip(zc) {
                        *a -= c[k] * b;
                    }
                }
                Fixed::Cycle(l) => per_cycle[*l] += c[k],
            }
        }
        if self.has_cycles() {
            let per_group: Vec<f64> = (0..obs.n_groups)
                .map(|g| {
                    (0..obs.n_cycles)
                        .map(|l| per_cycle[l] * self.counts.share(g, l))
                        .sum()
                })
                .collect();
            for j in 0..vc.len() {
                vc[j] -= per_cycle[obs.cycle[j]] - per_group[obs.group[j]];
            }
        }
        vc
    }

    /// The fixed columns.
    pub(super) fn fixed(&self) -> &[Fixed] {
        &self.fixed
    }

    /// RSS once columns C are added, from their products: `centred` = C'WC (C centred),
    /// `u` = Z'WC with the fixed columns Z, `b` = C'Wy⊥, `y2` = y⊥'Wy⊥. The residuals of C
    /// have the Gram matrix A = C'WC − U'(Z'WZ)⁻¹U, and RSS = y2 − b'A⁻¹b; the coefficients of
    /// C are A⁻¹b (None, and no gain, when A is not positive definite: collinear columns).
    pub(super) fn rss_from(
        &self,
        y2: f64,
        centred: DMatrix<f64>,
        u: &DMatrix<f64>,
        b: &DVector<f64>,
    ) -> (f64, Option<DVector<f64>>) {
        let a = centred - u.transpose() * (&self.ginv * u);
        match a.cholesky() {
            Some(ch) => {
                let x = ch.solve(b);
                ((y2 - b.dot(&x)).max(0.0), Some(x))
            }
            None => (y2, None),
        }
    }

    /// RSS of y on the groups, the fixed columns and `cols`, and the coefficients of `cols`
    /// (None when they are collinear); `y_perp` is y residualized ([`Projector::rss_from`]).
    pub(super) fn fit_cols(
        &self,
        obs: &Obs,
        y_perp: &[f64],
        cols: &[Vec<f64>],
    ) -> (f64, Option<DVector<f64>>) {
        let w = &self.w;
        let new = centre_all(obs, &self.counts, w, cols);
        let (k, m) = (self.fixed.len(), new.len());
        let u = DMatrix::from_fn(k, m, |a, b| {
            gram(obs, &self.counts, w, &self.fixed[a], &new[b])
        });
        let centred = DMatrix::from_fn(m, m, |i, j| gram(obs, &self.counts, w, &new[i], &new[j]));
        let y_cycles = if new.iter().any(|f| matches!(f, Fixed::Cycle(_))) {
            cycle_sums(obs, w, y_perp)
        } else {
            Vec::new()
        };
        let b = DVector::from_iterator(
            m,
            new.iter().map(|f| match f {
                Fixed::Dense { zc, .. } => dotw(zc, y_perp, w),
                Fixed::Cycle(c) => y_cycles[*c],
            }),
        );
        self.rss_from(dotw(y_perp, y_perp, w), centred, &u, &b)
    }

    /// RSS with a step added at each of `times` (ascending; the step column is 1 from that
    /// time on), as [`Projector::fit_cols`] gives for each, in one pass over the readings
    /// from the latest back: with a step the column's products are sums over the readings
    /// from its time on (of w, of w·y⊥, of w·z by fixed column, of w by group and by cycle),
    /// which grow by one reading at a time. O(N·k + times·(G + k²)) instead of O(N·k) each.
    pub(super) fn step_rss(&self, obs: &Obs, y_perp: &[f64], times: &[f64]) -> Vec<f64> {
        let w = &self.w;
        let k = self.fixed.len();
        let y2 = dotw(y_perp, y_perp, w);
        let (mut sw, mut sy) = (0.0, 0.0);
        let mut by_group = vec![0.0; obs.n_groups];
        let mut by_cycle = vec![0.0; obs.n_cycles];
        let mut sz = vec![0.0; k];
        let order = &obs.time_order;
        let mut pos = order.len();
        let mut out = vec![y2; times.len()];
        for (i, &th) in times.iter().enumerate().rev() {
            while pos > 0 && obs.t[order[pos - 1]] >= th {
                pos -= 1;
                let j = order[pos];
                sw += w[j];
                sy += w[j] * y_perp[j];
                by_group[obs.group[j]] += w[j];
                by_cycle[obs.cycle[j]] += w[j];
                for (s, f) in sz.iter_mut().zip(&self.fixed) {
                    if let Fixed::Dense { zc, .. } = f {
                        *s += w[j] * zc[j];
                    }
                }
            }
            let u = DMatrix::from_iterator(
                k,
                1,
                self.fixed.iter().zip(&sz).map(|(f, s)| match f {
                    Fixed::Dense { .. } => *s,
                    Fixed::Cycle(c) => self.counts.cycle_product(*c, &by_group, &by_cycle),
                }),
            );
            let centred: f64 = (0..obs.n_groups)
                .filter(|&g| self.counts.group[g] > 0.0)
                .map(|g| by_group[g] * by_group[g] / self.counts.group[g])
                .sum();
            let centred = DMatrix::from_element(1, 1, sw - centred);
            out[i] = self
                .rss_from(y2, centred, &u, &DVector::from_element(1, sy))
                .0;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axis::family::Family;
    use crate::axis::obs::tests::run;

    /// The RSS by dense columns, residualized one by one (the definition).
    fn rss_dense(obs: &Obs, w: &[f64], fixed: &[Vec<f64>], cols: &[Vec<f64>]) -> f64 {
        let mut all = fixed.to_vec();
        all.extend(cols.iter().cloned());
        let p = Projector::new(obs, w, &all);
        let r = p.residualize(obs, &obs.y);
        dotw(&r, &r, w)
    }

    /// Offsets per cycle held as cycle numbers fit as the same columns held dense do (a weight
    /// 0 reading and a drift column beside them).
    #[test]
    fn cycle_columns_fit_as_dense_ones() {
        let obs = run();
        let mut w = vec![1.0; obs.len()];
        w[5] = 0.0;
        let offsets = Family::CycleOffsets.compute_columns(&obs, f64::NAN);
        let drift = Family::Linear.compute_columns(&obs, f64::NAN);
        let p = Projector::new(&obs, &w, &drift);
        let y = p.residualize(&obs, &obs.y);
        let (rss, x) = p.fit_cols(&obs, &y, &offsets);
        // Dense: the indicators nudged off 0/1 by nothing a fit sees, so they are not
        // recognised as cycles.
        let dense: Vec<Vec<f64>> = offsets
            .iter()
            .map(|c| c.iter().map(|v| v * (1.0 + 1e-15)).collect())
            .collect();
        let want = rss_dense(&obs, &w, &drift, &dense);
        assert!((rss - want).abs() < 1e-9 * want, "{rss} vs {want}");
        assert_eq!(x.map(|x| x.len()), Some(offsets.len()));
        // Residuals with the offsets as fixed columns are orthogonal to every indicator.
        let p2 = Projector::new(&obs, &w, &offsets);
        let r = p2.residualize(&obs, &obs.y);
        for c in &offsets {
            assert!(dotw(c, &r, &w).abs() < 1e-12);
        }
        assert!((dotw(&r, &r, &w) - rss_dense(&obs, &w, &[], &dense)).abs() < 1e-9);
    }

    /// The step sweep gives the RSS of each step column fitted on its own, with and without
    /// offsets per cycle in the model.
    #[test]
    fn the_step_sweep_matches_each_step_fitted() {
        let obs = run();
        let w: Vec<f64> = (0..obs.len())
            .map(|j| if j == 9 { 0.0 } else { 1.0 })
            .collect();
        let mut fixed = Family::Linear.compute_columns(&obs, f64::NAN);
        for with_offsets in [false, true] {
            if with_offsets {
                fixed.extend(Family::CycleOffsets.compute_columns(&obs, f64::NAN));
            }
            let p = Projector::new(&obs, &w, &fixed);
            let y = p.residualize(&obs, &obs.y);
            let times = Family::Step.grid(&obs);
            let sweep = p.step_rss(&obs, &y, &times);
            for (th, got) in times.iter().zip(&sweep) {
                let (want, _) = p.fit_cols(&obs, &y, &Family::Step.compute_columns(&obs, *th));
                assert!(
                    (got - want).abs() < 1e-9 * want.max(1.0),
                    "{th}: {got} vs {want}"
                );
            }
        }
    }

    /// Collinear columns (one a sum of others, one all zeros) fit as the columns they span,
    /// and the full-rank path gives the inverse.
    #[test]
    fn collinear_columns_fit_as_their_span() {
        let obs = run();
        let w = vec![1.0; obs.len()];
        let a = Family::Linear.compute_columns(&obs, f64::NAN).remove(0);
        let b: Vec<f64> = obs.t.iter().map(|t| (t / 700.0).sin()).collect();
        let sum: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 3.0 * x - y).collect();
        let zero = vec![0.0; obs.len()];
        let span = Projector::new(&obs, &w, &[a.clone(), b.clone()]);
        let want = span.residualize(&obs, &obs.y);
        let p = Projector::new(&obs, &w, &[a.clone(), sum, b, zero]);
        let got = p.residualize(&obs, &obs.y);
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() < 1e-9, "{g} vs {w}");
        }
        let g = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 3.0]);
        let inv = gram_inverse(g.clone());
        assert!((g * inv - DMatrix::identity(2, 2)).norm() < 1e-12);
    }
}
