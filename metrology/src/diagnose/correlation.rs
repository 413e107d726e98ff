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

use super::fit::Obs;

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
    let design = Design::new(basis(obs, &rows, cols), rows.len());
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

/// Orthonormal basis of the group indicators and `cols` on `rows`: the indicators are
/// orthogonal already (disjoint rows); the columns are centred within the groups, then
/// orthonormalised (modified Gram–Schmidt, twice), and those the others span are dropped.
fn basis(obs: &Obs, rows: &[usize], cols: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let g: Vec<usize> = rows.iter().map(|&j| obs.group[j]).collect();
    let mut count = vec![0.0; obs.n_groups];
    g.iter().for_each(|&k| count[k] += 1.0);
    let mut q: Vec<Vec<f64>> = (0..obs.n_groups)
        .filter(|&k| count[k] > 0.0)
        .map(|k| {
            let s = 1.0 / f64::sqrt(count[k]);
            g.iter().map(|&gi| if gi == k { s } else { 0.0 }).collect()
        })
        .collect();
    let mut extra = Vec::new();
    for c in cols {
        let v: Vec<f64> = rows.iter().map(|&j| c[j]).collect();
        let norm0 = dot(&v, &v).sqrt();
        let mut sum = vec![0.0; obs.n_groups];
        g.iter().zip(&v).for_each(|(&k, x)| sum[k] += x);
        let centred = g
            .iter()
            .zip(&v)
            .map(|(&k, x)| x - sum[k] / count[k])
            .collect();
        push_orthonormal(&mut extra, centred, norm0);
    }
    q.append(&mut extra);
    q
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

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Σρ·v for the AR(1) correlation matrix (ρ^|i−j|), by a forward and a backward pass.
fn ar1_times(v: &[f64], rho: f64) -> Vec<f64> {
    let n = v.len();
    let mut f = vec![0.0; n];
    let mut b = vec![0.0; n];
    for i in 0..n {
        f[i] = v[i] + if i > 0 { rho * f[i - 1] } else { 0.0 };
    }
    for i in (0..n).rev() {
        b[i] = v[i] + if i + 1 < n { rho * b[i + 1] } else { 0.0 };
    }
    (0..n).map(|i| f[i] + b[i] - v[i]).collect()
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

/// What tr(P⊥AP⊥Σρ) / tr(P⊥Σρ) (P⊥ = I − QQ') needs that does not depend on ρ.
struct Design {
    q: Vec<Vec<f64>>,
    /// A·q_c.
    aq: Vec<Vec<f64>>,
    /// Q(Q'AQ), column by column.
    qm: Vec<Vec<f64>>,
    n: usize,
}

impl Design {
    fn new(q: Vec<Vec<f64>>, n: usize) -> Self {
        let k = q.len();
        let aq: Vec<Vec<f64>> = q.iter().map(|c| lag_times(c)).collect();
        let qm = (0..k)
            .map(|a| {
                let mut v = vec![0.0; n];
                for b in 0..k {
                    let m_ab = dot(&q[b], &aq[a]);
                    v.iter_mut().zip(&q[b]).for_each(|(x, y)| *x += m_ab * y);
                }
                v
            })
            .collect();
        Design { q, aq, qm, n }
    }

    /// tr(AΣ) = (N − 1)ρ; tr(QQ'AΣ) = tr(AQQ'Σ) = Σ_c (Aq_c)'(Σq_c);
    /// tr(QQ'AQQ'Σ) = Σ_a (Σq_a)'(QM)_a with M = Q'AQ symmetric; tr(P⊥Σ) = N − tr(Q'ΣQ).
    fn expected_ratio(&self, rho: f64) -> f64 {
        let (mut num, mut den) = ((self.n as f64 - 1.0) * rho, self.n as f64);
        for c in 0..self.q.len() {
            let s = ar1_times(&self.q[c], rho);
            num += dot(&self.qm[c], &s) - 2.0 * dot(&self.aq[c], &s);
            den -= dot(&self.q[c], &s);
        }
        if den > 0.0 { num / den } else { 0.0 }
    }
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
        let d = Design::new(vec![vec![1.0 / (n as f64).sqrt(); n]], n);
        let r = d.expected_ratio(0.6);
        assert!((r - 0.544).abs() < 0.015, "{r}");
        // No columns: the ratio is ρ exactly but for the one product fewer than squares.
        let d0 = Design::new(Vec::new(), n);
        assert!((d0.expected_ratio(0.6) - 0.6 * 49.0 / 50.0).abs() < 1e-12);
    }

    /// The trace formula against a dense computation of tr(P⊥AP⊥Σ)/tr(P⊥Σ) (nalgebra).
    #[test]
    fn the_traces_match_dense_matrices() {
        use nalgebra::DMatrix;
        let n = 12;
        let rho: f64 = 0.55;
        let mut q = Vec::new();
        push_v(
            &mut q,
            (0..n).map(|i| if i < 6 { 1.0 } else { 0.0 }).collect(),
        );
        push_v(
            &mut q,
            (0..n).map(|i| if i >= 6 { 1.0 } else { 0.0 }).collect(),
        );
        push_v(&mut q, (0..n).map(|i| (i as f64 * 0.7).sin()).collect());
        let qm = DMatrix::from_fn(n, q.len(), |i, c| q[c][i]);
        let p = DMatrix::identity(n, n) - &qm * qm.transpose();
        let a = DMatrix::from_fn(n, n, |i, j| if i.abs_diff(j) == 1 { 0.5 } else { 0.0 });
        let s = DMatrix::from_fn(n, n, |i, j| rho.powi(i.abs_diff(j) as i32));
        let want = (&p * &a * &p * &s).trace() / (&p * &s).trace();
        let got = Design::new(q, n).expected_ratio(rho);
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
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
        use crate::axis_model::Direction;
        use crate::diagnose::family::Family;
        use crate::diagnose::fit::in_sample_residuals;
        use crate::positioning_data::{PositioningData, Reading};
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
            let cols = Family::CycleOffsets.columns(&obs, 0.0);
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
        let got = ar1_times(&v, rho);
        for i in 0..4 {
            let want: f64 = (0..4)
                .map(|j| rho.powi((i as i32 - j as i32).abs()) * v[j])
                .sum();
            assert!((got[i] - want).abs() < 1e-12);
        }
    }
}
