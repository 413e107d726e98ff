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

use nalgebra::{DMatrix, DVector};

use super::fit::Obs;

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
}

impl Counts {
    pub(super) fn new(obs: &Obs, w: &[f64]) -> Self {
        let nc = obs.n_cycles;
        let mut c = Counts {
            group: vec![0.0; obs.n_groups],
            cycle: vec![0.0; nc],
            gc: vec![0.0; obs.n_groups * nc],
            n_cycles: nc,
        };
        for j in 0..obs.len() {
            let (g, k) = (obs.group[j], obs.cycle[j]);
            c.group[g] += w[j];
            c.cycle[k] += w[j];
            c.gc[g * nc + k] += w[j];
        }
        c
    }

    /// Group g's mean of the indicator of cycle `c` (the share of its weight in that cycle).
    pub(super) fn share(&self, g: usize, c: usize) -> f64 {
        if self.group[g] > 0.0 {
            self.gc[g * self.n_cycles + c] / self.group[g]
        } else {
            0.0
        }
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
    Dense { zc: Vec<f64>, by_cycle: Vec<f64> },
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

/// `cols` centred within the groups; the sums by cycle of the dense ones only with
/// `by_cycle` (they are needed against a cycle's indicator).
fn centre_all(obs: &Obs, c: &Counts, w: &[f64], cols: &[Vec<f64>], by_cycle: bool) -> Vec<Fixed> {
    cols.iter()
        .map(|col| match cycle_indicator(obs, col) {
            Some(k) => Fixed::Cycle(k),
            None => {
                let m = group_means(obs, &c.group, w, col);
                let zc: Vec<f64> = col.iter().zip(&obs.group).map(|(v, &g)| v - m[g]).collect();
                let by_cycle = if by_cycle {
                    cycle_sums(obs, w, &zc)
                } else {
                    Vec::new()
                };
                Fixed::Dense { zc, by_cycle }
            }
        })
        .collect()
}

/// Weighted product of two centred columns.
fn gram(c: &Counts, w: &[f64], a: &Fixed, b: &Fixed) -> f64 {
    match (a, b) {
        (Fixed::Dense { zc: x, .. }, Fixed::Dense { zc: y, .. }) => dotw(x, y, w),
        (Fixed::Dense { by_cycle, .. }, Fixed::Cycle(k))
        | (Fixed::Cycle(k), Fixed::Dense { by_cycle, .. }) => by_cycle[*k],
        (Fixed::Cycle(k), Fixed::Cycle(l)) => c.cycle_gram(*k, *l),
    }
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
        let fixed = centre_all(obs, &counts, w, cols, true);
        let k = fixed.len();
        let mut g = DMatrix::zeros(k, k);
        for a in 0..k {
            for b in a..k {
                let v = gram(&counts, w, &fixed[a], &fixed[b]);
                g[(a, b)] = v;
                g[(b, a)] = v;
            }
        }
        let ginv = if k == 0 {
            DMatrix::zeros(0, 0)
        } else {
            g.clone()
                .try_inverse()
                .or_else(|| g.pseudo_inverse(1e-12).ok())
                .unwrap_or_else(|| DMatrix::zeros(k, k))
        };
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

    /// RSS of y on the groups, the fixed columns and `cols`, and the coefficients of `cols`
    /// (None when they are collinear); `y_perp` is y residualized. With Z the fixed columns
    /// and C the new ones, both centred: RSS = y⊥'Wy⊥ − b'A⁻¹b with b = C'Wy⊥ and
    /// A = C'WC − (Z'WC)'(Z'WZ)⁻¹(Z'WC), the Gram matrix of C's residuals.
    pub(super) fn fit_cols(
        &self,
        obs: &Obs,
        y_perp: &[f64],
        cols: &[Vec<f64>],
    ) -> (f64, Option<DVector<f64>>) {
        let w = &self.w;
        let need_cycles =
            self.has_cycles() || cols.iter().any(|c| cycle_indicator(obs, c).is_some());
        let new = centre_all(obs, &self.counts, w, cols, need_cycles);
        let (k, m) = (self.fixed.len(), new.len());
        let u = DMatrix::from_fn(k, m, |a, b| gram(&self.counts, w, &self.fixed[a], &new[b]));
        let gu = &self.ginv * &u;
        let mut a = DMatrix::zeros(m, m);
        for i in 0..m {
            for j in i..m {
                let v = gram(&self.counts, w, &new[i], &new[j]) - u.column(i).dot(&gu.column(j));
                a[(i, j)] = v;
                a[(j, i)] = v;
            }
        }
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
        let y2 = dotw(y_perp, y_perp, w);
        match a.cholesky() {
            Some(ch) => {
                let x = ch.solve(&b);
                ((y2 - b.dot(&x)).max(0.0), Some(x))
            }
            None => (y2, None),
        }
    }
}
