//! Lag-1 correlation of the residuals of a fit, corrected for the fit's own bias.
//!
//! Fitting columns removes part of the noise's slow variation: the lag-1 correlation of
//! residuals reads low, the more so the more the fit can follow (an offset per cycle takes
//! out the mean of every cycle). The estimate here is by moments for the actual design: with
//! residuals r = P⊥e of noise e that is AR(1) with coefficient ρ, the expected lag-1 product
//! over the expected square is tr(P⊥AP⊥Σρ) / tr(P⊥Σρ) (A the symmetric lag-1 operator, Σρ the
//! AR(1) correlation matrix); ρ is the value at which that ratio equals the observed one.
//! Kendall's (1 + 3ρ)/N correction is this for a design that is a single mean.

#![allow(clippy::needless_range_loop)]

use nalgebra::DMatrix;

use super::obs::Obs;
use super::projector::dot;

/// Lag-1 correlation of `resid` in time order (rows with weight > 0) for the fit of the
/// per-target, per-direction constants and `cols`, corrected for the bias of that fit.
pub(super) fn design_lag1(obs: &Obs, w: &[f64], cols: &[Vec<f64>], resid: &[f64]) -> f64 {
    let rows: Vec<usize> = obs
        .time_order
        .iter()
        .copied()
        .filter(|&j| w[j] > 0.0)
        .collect();
    let r: Vec<f64> = rows.iter().map(|&j| resid[j]).collect();
    let ss: f64 = r.iter().map(|x| x * x).sum();
    if r.len() < 3 || ss <= 0.0 {
        return 0.0;
    }
    let raw = r.windows(2).map(|p| p[0] * p[1]).sum::<f64>() / ss;
    let groups = Groups::new(rows.iter().map(|&j| obs.group[j]).collect(), obs.n_groups);
    let extras = extra_basis(&groups, &rows, cols);
    let design = Design::new(groups, extras);
    solve(|rho| design.expected_ratio(rho) - raw)
}

/// The root of an increasing `f` on [−0.9, 0.95] (the ends where it has none there), by
/// regula falsi with the Illinois step: the ratio is nearly linear in ρ, so a few
/// evaluations do.
fn solve(f: impl Fn(f64) -> f64) -> f64 {
    let (mut a, mut b) = (-0.9, 0.95);
    let (mut fa, mut fb) = (f(a), f(b));
    if fa >= 0.0 {
        return a;
    }
    if fb <= 0.0 {
        return b;
    }
    let mut side = 0;
    for _ in 0..40 {
        let c = (a * fb - b * fa) / (fb - fa);
        let fc = f(c);
        if fc.abs() < 1e-9 || b - a < 1e-7 {
            return c;
        }
        if fc < 0.0 {
            (a, fa) = (c, fc);
            if side == -1 {
                fb *= 0.5;
            }
            side = -1;
        } else {
            (b, fb) = (c, fc);
            if side == 1 {
                fa *= 0.5;
            }
            side = 1;
        }
    }
    0.5 * (a + b)
}

/// The (target, direction) group of each reading in time order: the design's indicator
/// columns, orthogonal to each other (disjoint readings) and held implicitly.
struct Groups {
    /// Group of each position.
    of: Vec<usize>,
    /// Readings in each group.
    count: Vec<f64>,
    /// 1 / count (0 for an empty group).
    inv: Vec<f64>,
}

impl Groups {
    fn new(of: Vec<usize>, n_groups: usize) -> Self {
        let mut count = vec![0.0; n_groups];
        of.iter().for_each(|&k| count[k] += 1.0);
        let inv = count
            .iter()
            .map(|c| if *c > 0.0 { 1.0 / c } else { 0.0 })
            .collect();
        Groups { of, count, inv }
    }

    fn len(&self) -> usize {
        self.count.len()
    }

    /// Sums of `v` by group.
    fn sums(&self, v: &[f64]) -> Vec<f64> {
        let mut s = vec![0.0; self.len()];
        self.of.iter().zip(v).for_each(|(&k, x)| s[k] += x);
        s
    }
}

/// Orthonormal basis of `cols` on `rows` beside the group indicators: the columns are centred
/// within the groups, then orthonormalised (modified Gram–Schmidt, twice), and those the
/// others span are dropped.
fn extra_basis(groups: &Groups, rows: &[usize], cols: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let mut extra = Vec::new();
    for c in cols {
        let v: Vec<f64> = rows.iter().map(|&j| c[j]).collect();
        let norm0 = dot(&v, &v).sqrt();
        let sum = groups.sums(&v);
        let centred = groups
            .of
            .iter()
            .zip(&v)
            .map(|(&k, x)| x - sum[k] * groups.inv[k])
            .collect();
        push_orthonormal(&mut extra, centred, norm0);
    }
    extra
}

/// Appends `v` orthonormalised against `q` unless `q` spans it (what is left is below 1e-9
/// of `norm0`, the norm of the column it came from).
fn push_orthonormal(q: &mut Vec<Vec<f64>>, mut v: Vec<f64>, norm0: f64) {
    if norm0 <= 0.0 {
        return;
    }
    for _ in 0..2 {
        for b in q.iter() {
            let c = dot(&v, b);
            v.iter_mut().zip(b).for_each(|(x, y)| *x -= c * y);
        }
    }
    let norm = dot(&v, &v).sqrt();
    if norm > 1e-9 * norm0 {
        v.iter_mut().for_each(|x| *x /= norm);
        q.push(v);
    }
}

/// Σρ·v for the AR(1) correlation matrix (ρ^|i−j|), by a forward and a backward pass, into
/// `out`.
fn ar1_into(v: &[f64], rho: f64, out: &mut [f64]) {
    let n = v.len();
    let mut f = 0.0;
    for i in 0..n {
        f = v[i] + rho * f;
        out[i] = f;
    }
    let mut b = 0.0;
    for i in (0..n).rev() {
        b = v[i] + rho * b;
        out[i] += b - v[i];
    }
}

/// A·v for the symmetric lag-1 operator (½ on both off-diagonals): v'Av = Σ v_i v_{i+1}.
fn lag_times(v: &[f64]) -> Vec<f64> {
    let n = v.len();
    (0..n)
        .map(|i| {
            let a = if i > 0 { v[i - 1] } else { 0.0 };
            let b = if i + 1 < n { v[i + 1] } else { 0.0 };
            0.5 * (a + b)
        })
        .collect()
}

/// What tr(P⊥AP⊥Σρ) / tr(P⊥Σρ) needs that does not depend on ρ. With U the normalised
/// group indicators and Q the other columns' orthonormal basis (Q ⊥ U), P⊥ = I − UU' − QQ'.
struct Design {
    groups: Groups,
    q: Vec<Vec<f64>>,
    /// A·q_c.
    aq: Vec<Vec<f64>>,
    /// Q(Q'AQ), column by column.
    qm: Vec<Vec<f64>>,
    /// Sums of A·q_c by group.
    aq_by_group: Vec<Vec<f64>>,
    /// Σ_k 1[g(k) = g(k−1)]/n_g(k−1) + Σ_k 1[g(k) = g(k+1)]/n_g(k+1): the diagonal of Σρ in
    /// the sums of [`Design::group_terms`].
    same_neighbour: f64,
    n: usize,
}

impl Design {
    fn new(groups: Groups, q: Vec<Vec<f64>>) -> Self {
        let n = groups.of.len();
        let aq: Vec<Vec<f64>> = q.iter().map(|c| lag_times(c)).collect();
        // Q(Q'AQ) by matrix products (a hundred columns with offsets per cycle).
        let qmat = DMatrix::from_fn(n, q.len(), |i, c| q[c][i]);
        let aqmat = DMatrix::from_fn(n, q.len(), |i, c| aq[c][i]);
        let qm_mat = &qmat * (qmat.transpose() * &aqmat);
        let qm = qm_mat
            .column_iter()
            .map(|c| c.iter().copied().collect())
            .collect();
        let aq_by_group = aq.iter().map(|v| groups.sums(v)).collect();
        let g = &groups.of;
        let same_neighbour = (1..n)
            .map(|k| {
                let (a, b) = (g[k - 1], g[k]);
                if a == b { 2.0 * groups.inv[a] } else { 0.0 }
            })
            .sum();
        Design {
            groups,
            q,
            aq,
            qm,
            aq_by_group,
            same_neighbour,
            n,
        }
    }

    /// The group indicators' part of the traces: (tr(UU'AΣ), tr(UU'AUU'Σ), tr(UU'Σ)).
    ///
    /// With s_k = (Σ·1_g)_k for every group g at once (a forward and a backward pass of the
    /// AR(1) recursion over the positions, a vector over the groups): K_gh = 1_g'Σ1_h is the
    /// sum of the forward part over h's positions plus its transpose; 1_g'AΣ1_g sums s_k at
    /// the neighbours k of g's positions; 1_g'A1_h counts the neighbouring positions of g and
    /// h. The indicators as dense columns needed Q(Q'AQ) over all of them, O(N·G²) to set up.
    fn group_terms(&self, rho: f64) -> (f64, f64, f64) {
        let (g, inv) = (&self.groups.of, &self.groups.inv);
        let (n, ng) = (self.n, self.groups.len());
        // fsum[h * ng + a]: sum over h's positions k of (forward part of Σ·1_a)_k.
        let mut fsum = vec![0.0; ng * ng];
        let mut f = vec![0.0; ng];
        let mut shifted = 0.0;
        for k in 0..n {
            f.iter_mut().for_each(|x| *x *= rho);
            f[g[k]] += 1.0;
            fsum[g[k] * ng..(g[k] + 1) * ng]
                .iter_mut()
                .zip(&f)
                .for_each(|(s, x)| *s += x);
            shifted += neighbours(g, k, |a| f[a] * inv[a]);
        }
        let mut b = vec![0.0; ng];
        for k in (0..n).rev() {
            b.iter_mut().for_each(|x| *x *= rho);
            b[g[k]] += 1.0;
            shifted += neighbours(g, k, |a| b[a] * inv[a]);
        }
        let t_uas = 0.5 * (shifted - self.same_neighbour);
        let k_of = |a: usize, h: usize| {
            fsum[h * ng + a] + fsum[a * ng + h] - if a == h { self.groups.count[a] } else { 0.0 }
        };
        let t_uauus = (1..n)
            .map(|k| k_of(g[k - 1], g[k]) * inv[g[k - 1]] * inv[g[k]])
            .sum();
        let t_us = (0..ng).map(|a| k_of(a, a) * inv[a]).sum();
        (t_uas, t_uauus, t_us)
    }

    /// tr(AΣ) = (N − 1)ρ; with B = [U Q] the orthonormal basis of the design,
    /// tr(BB'AΣ) = Σ_c (Ab_c)'(Σb_c), tr(BB'ABB'Σ) = tr((B'AB)(B'ΣB)) and
    /// tr(P⊥Σ) = N − tr(B'ΣB); the group indicators' parts come from
    /// [`Design::group_terms`], the cross terms of U and Q from sums by group.
    fn expected_ratio(&self, rho: f64) -> f64 {
        let (t_uas, t_uauus, t_us) = self.group_terms(rho);
        let mut num = (self.n as f64 - 1.0) * rho - 2.0 * t_uas + t_uauus;
        let mut den = self.n as f64 - t_us;
        let mut s = vec![0.0; self.n];
        for c in 0..self.q.len() {
            ar1_into(&self.q[c], rho, &mut s);
            let by_group = self.groups.sums(&s);
            // (U'Aq_c)'(U'Σq_c), this column's share of tr(Q'AUU'ΣQ), which tr(BB'ABB'Σ)
            // holds twice.
            let cross: f64 = (0..self.groups.len())
                .map(|k| self.aq_by_group[c][k] * by_group[k] * self.groups.inv[k])
                .sum();
            num += dot(&self.qm[c], &s) - 2.0 * (dot(&self.aq[c], &s) - cross);
            den -= dot(&self.q[c], &s);
        }
        if den > 0.0 { num / den } else { 0.0 }
    }
}

/// `f` at the groups of position k's neighbours (k − 1 and k + 1, where they exist), summed.
fn neighbours(g: &[usize], k: usize, f: impl Fn(usize) -> f64) -> f64 {
    let before = if k > 0 { f(g[k - 1]) } else { 0.0 };
    let after = if k + 1 < g.len() { f(g[k + 1]) } else { 0.0 };
    before + after
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With a single mean, the moment correction is close to Kendall's: an AR(1) series of
    /// 50 with ρ = 0.6 reads about 0.6 − (1 + 3·0.6)/50 = 0.544 (Kendall's also holds the
    /// ratio estimator's own small bias, about 0.01 here, which moments of the numerator and
    /// denominator leave out).
    #[test]
    fn a_single_mean_gives_about_kendalls_bias() {
        let n = 50;
        let d = Design::new(Groups::new(vec![0; n], 1), Vec::new());
        let r = d.expected_ratio(0.6);
        assert!((r - 0.544).abs() < 0.015, "{r}");
    }

    /// The trace formula against a dense computation of tr(P⊥AP⊥Σ)/tr(P⊥Σ) (nalgebra), the
    /// group indicators there explicit columns: three groups interleaved in time (neighbours
    /// within and across groups, one group at both ends) and two other columns.
    #[test]
    fn the_traces_match_dense_matrices() {
        use nalgebra::DMatrix;
        let of = vec![0, 1, 2, 0, 1, 2, 2, 1, 0, 0, 1, 2, 1, 0];
        let n = of.len();
        let cols = vec![
            (0..n).map(|i| (i as f64 * 0.7).sin()).collect::<Vec<f64>>(),
            (0..n).map(|i| (i as f64 * 0.3).powi(2)).collect(),
        ];
        let groups = Groups::new(of.clone(), 3);
        let rows: Vec<usize> = (0..n).collect();
        let design = Design::new(
            groups,
            extra_basis(&Groups::new(of.clone(), 3), &rows, &cols),
        );
        let mut q = Vec::new();
        for g in 0..3 {
            push_v(&mut q, of.iter().map(|&k| f64::from(k == g)).collect());
        }
        for c in &cols {
            push_v(&mut q, c.clone());
        }
        let qm = DMatrix::from_fn(n, q.len(), |i, c| q[c][i]);
        let p = DMatrix::identity(n, n) - &qm * qm.transpose();
        let a = DMatrix::from_fn(n, n, |i, j| if i.abs_diff(j) == 1 { 0.5 } else { 0.0 });
        for rho in [-0.3_f64, 0.0, 0.55, 0.9] {
            let s = DMatrix::from_fn(n, n, |i, j| rho.powi(i.abs_diff(j) as i32));
            let want = (&p * &a * &p * &s).trace() / (&p * &s).trace();
            let got = design.expected_ratio(rho);
            assert!((got - want).abs() < 1e-12, "ρ {rho}: {got} vs {want}");
        }
    }

    fn push_v(q: &mut Vec<Vec<f64>>, v: Vec<f64>) {
        let n0 = dot(&v, &v).sqrt();
        push_orthonormal(q, v, n0);
    }

    /// A second method, by simulation: AR(1) noise with ρ = 0.6 on a 5 × 5 bidirectional run,
    /// fitted with the per-target, per-direction constants and an offset per cycle (14
    /// columns on 50 readings). The plain lag-1 correlation of the residuals reads far low;
    /// the moment estimate recovers ρ to within the ratio estimator's own small bias.
    #[test]
    fn ar1_noise_under_offsets_per_cycle_reads_near_its_rho() {
        use crate::axis::family::Family;
        use crate::axis::fit::in_sample_residuals;
        use positioning::axis_model::Direction;
        use positioning::positioning_data::{PositioningData, Reading};
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};

        let mut readings = Vec::new();
        for cycle in 1..=5 {
            for (dir, order) in [
                (Direction::Up, [1, 2, 3, 4, 5]),
                (Direction::Down, [5, 4, 3, 2, 1]),
            ] {
                for index in order {
                    readings.push(Reading {
                        cycle,
                        direction: dir,
                        index,
                        target_mm: 100.0 * index as f64,
                        deviation_um: 0.0,
                        time_s: 60.0 * readings.len() as f64,
                        air_c: None,
                        material_c: None,
                    });
                }
            }
        }
        let mut data = PositioningData {
            has_times: true,
            readings,
            ..Default::default()
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let rho: f64 = 0.6;
        let (mut plain, mut moment) = (0.0, 0.0);
        let sims = 2000;
        for _ in 0..sims {
            let mut e: f64 = StandardNormal.sample(&mut rng);
            for r in data.readings.iter_mut() {
                r.deviation_um = e;
                let z: f64 = StandardNormal.sample(&mut rng);
                e = rho * e + (1.0 - rho * rho).sqrt() * z;
            }
            let obs = Obs::new(&data, 5);
            let cols = Family::CycleOffsets.compute_columns(&obs, 0.0);
            let w = vec![1.0; obs.len()];
            let (_, r) = in_sample_residuals(&obs, &w, &cols);
            let ss: f64 = r.iter().map(|x| x * x).sum();
            plain += r.windows(2).map(|p| p[0] * p[1]).sum::<f64>() / ss / sims as f64;
            moment += design_lag1(&obs, &w, &cols, &r) / sims as f64;
        }
        eprintln!("plain {plain:.3}, moment {moment:.3}");
        assert!(plain < 0.4, "plain {plain}");
        assert!((moment - rho).abs() < 0.04, "moment {moment}");
    }

    #[test]
    fn the_root_is_found() {
        let r = solve(|x| 0.8 * x - 0.1 + 0.05 * x * x - 0.3);
        assert!((0.8 * r + 0.05 * r * r - 0.4).abs() < 1e-8, "{r}");
        assert_eq!(solve(|x| x + 2.0), -0.9);
        assert_eq!(solve(|x| x - 2.0), 0.95);
    }

    #[test]
    fn ar1_product_matches_the_matrix() {
        let v = [1.0, -2.0, 0.5, 3.0];
        let rho: f64 = 0.7;
        let mut got = [0.0; 4];
        ar1_into(&v, rho, &mut got);
        for i in 0..4 {
            let want: f64 = (0..4)
                .map(|j| rho.powi((i as i32 - j as i32).abs()) * v[j])
                .sum();
            assert!((got[i] - want).abs() < 1e-12);
        }
    }
}
