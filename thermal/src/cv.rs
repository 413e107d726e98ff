//! Least squares with an intercept, checked on contiguous time blocks held out in turn.

use nalgebra::{DMatrix, DMatrixView, DVector, DVectorView};
use std::ops::Range;
use std::rc::Rc;

/// Contiguous blocks of samples, held out one at a time.
#[derive(Debug, Clone)]
pub(crate) struct Blocks(pub(crate) Vec<Range<usize>>);

impl Blocks {
    /// `k` blocks of (nearly) equal length over `n` samples.
    pub(crate) fn contiguous(n: usize, k: usize) -> Self {
        let k = k.clamp(2, n.max(2));
        Self((0..k).map(|i| i * n / k..(i + 1) * n / k).collect())
    }
}

/// Products of the design (intercept first) with itself and the data, per block: block `k`'s
/// p × p matrix is columns `k·p..(k+1)·p` of `g`, its right-hand side column `k` of `b` (one
/// allocation each for all blocks; a candidate's stats are built thousands of times a run).
#[derive(Debug, Clone)]
pub(crate) struct BlockStats {
    p: usize,
    g: DMatrix<f64>,
    b: DMatrix<f64>,
    yy: Rc<[f64]>,
    n: Rc<[usize]>,
}

/// Held-out sums of squares per block.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CvScore {
    pub(crate) sse: Vec<f64>,
    pub(crate) n: Vec<usize>,
}

impl CvScore {
    /// RMS of all held-out residuals.
    pub(crate) fn rms(&self) -> f64 {
        let n: usize = self.n.iter().sum();
        (self.sse.iter().sum::<f64>() / n.max(1) as f64).sqrt()
    }

    pub(crate) fn total(&self) -> f64 {
        self.sse.iter().sum()
    }
}

impl BlockStats {
    /// Products for the intercept and `cols`.
    pub(crate) fn new(cols: &[&[f64]], y: &[f64], blocks: &Blocks) -> Self {
        let mut s = Self::intercept(y, blocks);
        for c in 0..cols.len() {
            s = s.with_column(&cols[..c], cols[c], y, blocks);
        }
        s
    }

    fn intercept(y: &[f64], blocks: &Blocks) -> Self {
        let k_all = blocks.0.len();
        let (mut g, mut b) = (DMatrix::zeros(1, k_all), DMatrix::zeros(1, k_all));
        let (mut yy, mut n) = (vec![], vec![]);
        for (k, r) in blocks.0.iter().enumerate() {
            let ys = &y[r.clone()];
            g[(0, k)] = ys.len() as f64;
            b[(0, k)] = ys.iter().sum();
            yy.push(ys.iter().map(|v| v * v).sum());
            n.push(ys.len());
        }
        Self {
            p: 1,
            g,
            b,
            yy: yy.into(),
            n: n.into(),
        }
    }

    /// Block `k`'s products of the design with itself.
    fn g_block(&self, k: usize) -> DMatrixView<'_, f64> {
        self.g.columns(k * self.p, self.p)
    }

    /// Block `k`'s products of the design with the data.
    fn b_block(&self, k: usize) -> DVectorView<'_, f64> {
        self.b.column(k)
    }

    /// The products once column `c` is added after `cols` (the columns these stats hold).
    pub(crate) fn with_column(
        &self,
        cols: &[&[f64]],
        c: &[f64],
        y: &[f64],
        blocks: &Blocks,
    ) -> Self {
        let p = self.p + 1;
        let k_all = blocks.0.len();
        let mut out = Self {
            p,
            g: DMatrix::zeros(p, p * k_all),
            b: DMatrix::zeros(p, k_all),
            yy: self.yy.clone(),
            n: self.n.clone(),
        };
        for (k, r) in blocks.0.iter().enumerate() {
            let mut g = out.g.columns_mut(k * p, p);
            g.view_mut((0, 0), (p - 1, p - 1))
                .copy_from(&self.g_block(k));
            let cs = &c[r.clone()];
            g[(0, p - 1)] = sum(cs);
            for (j, col) in cols.iter().enumerate() {
                g[(j + 1, p - 1)] = dot(&col[r.clone()], cs);
            }
            g[(p - 1, p - 1)] = dot(cs, cs);
            for j in 0..p - 1 {
                g[(p - 1, j)] = g[(j, p - 1)];
            }
            let mut b = out.b.column_mut(k);
            b.rows_mut(0, p - 1).copy_from(&self.b_block(k));
            b[p - 1] = dot(cs, &y[r.clone()]);
        }
        out
    }

    /// The number of blocks.
    fn blocks(&self) -> usize {
        self.b.ncols()
    }

    fn totals(&self) -> (DMatrix<f64>, DVector<f64>) {
        let mut g = DMatrix::zeros(self.p, self.p);
        let mut b = DVector::zeros(self.p);
        for k in 0..self.blocks() {
            g += &self.g_block(k);
            b += &self.b_block(k);
        }
        (g, b)
    }

    /// Coefficients (intercept first) fitted on every block but `k`, or on all with `None`.
    pub(crate) fn coefficients(&self, held_out: Option<usize>) -> Option<DVector<f64>> {
        let mut solver = Solver::new(self.p);
        solver.coefficients(self, &self.totals(), held_out).cloned()
    }

    /// Sums of squares of each block from `first` on predicted by a fit on the blocks
    /// before it only: the model's use, forward in time and beyond the fitted range.
    pub(crate) fn forward_score(&self, first: usize) -> Option<CvScore> {
        let k_all = self.blocks();
        let first = first.clamp(1, k_all - 1);
        let mut g = DMatrix::zeros(self.p, self.p);
        let mut b = DVector::zeros(self.p);
        for k in 0..first {
            g += &self.g_block(k);
            b += &self.b_block(k);
        }
        let mut sse = vec![];
        let mut solver = Solver::new(self.p);
        for k in first..k_all {
            let fitted = solver.solve(&g, &b)?.dot(&self.b_block(k));
            let s = self.yy[k] - 2.0 * fitted + solver.quadratic_form(&self.g_block(k));
            sse.push(s.max(0.0));
            g += &self.g_block(k);
            b += &self.b_block(k);
        }
        sse.iter().all(|v| v.is_finite()).then(|| CvScore {
            sse,
            n: self.n[first..].to_vec(),
        })
    }

    /// Held-out sums of squares, each block predicted from the others.
    pub(crate) fn score(&self) -> Option<CvScore> {
        let mut sse = Vec::with_capacity(self.blocks());
        let totals = self.totals();
        let mut solver = Solver::new(self.p);
        for k in 0..self.blocks() {
            let fitted = solver
                .coefficients(self, &totals, Some(k))?
                .dot(&self.b_block(k));
            let s = self.yy[k] - 2.0 * fitted + solver.quadratic_form(&self.g_block(k));
            sse.push(s.max(0.0));
        }
        sse.iter().all(|v| v.is_finite()).then(|| CvScore {
            sse,
            n: self.n.to_vec(),
        })
    }
}

/// The normal equations solved by Cholesky, with a tiny ridge on a near-singular matrix, in
/// buffers kept from one solve to the next: a score solves them once per held-out block, and
/// on small inputs allocating them took a quarter of the diagnosis (twenty-fifth round).
struct Solver {
    /// The system, scaled to a unit diagonal in place.
    a: DMatrix<f64>,
    /// The right-hand side, then scaled.
    b: DVector<f64>,
    scale: DVector<f64>,
    /// The matrix factorised (with its ridge); empty after a factorisation failed.
    m: DMatrix<f64>,
    /// The solution.
    x: DVector<f64>,
    /// The block's matrix times the solution.
    gx: DVector<f64>,
}

impl Solver {
    fn new(p: usize) -> Self {
        Self {
            a: DMatrix::zeros(p, p),
            b: DVector::zeros(p),
            scale: DVector::zeros(p),
            m: DMatrix::zeros(p, p),
            x: DVector::zeros(p),
            gx: DVector::zeros(p),
        }
    }

    /// Coefficients from `stats`' `totals` (summed once by the caller) without block `k`.
    fn coefficients(
        &mut self,
        stats: &BlockStats,
        totals: &(DMatrix<f64>, DVector<f64>),
        held_out: Option<usize>,
    ) -> Option<&DVector<f64>> {
        self.a.copy_from(&totals.0);
        self.b.copy_from(&totals.1);
        if let Some(k) = held_out {
            self.a -= &stats.g_block(k);
            self.b -= &stats.b_block(k);
        }
        self.solve_loaded()
    }

    /// The solution of `g x = b`.
    fn solve(&mut self, g: &DMatrix<f64>, b: &DVector<f64>) -> Option<&DVector<f64>> {
        self.a.copy_from(g);
        self.b.copy_from(b);
        self.solve_loaded()
    }

    /// xᵀ g x for the last solution x.
    fn quadratic_form(&mut self, g: &DMatrixView<f64>) -> f64 {
        self.gx.gemv(1.0, g, &self.x, 0.0);
        self.gx.dot(&self.x)
    }

    /// Solves the system loaded in `a` and `b` (both overwritten).
    fn solve_loaded(&mut self) -> Option<&DVector<f64>> {
        let n = self.a.nrows();
        for i in 0..n {
            self.scale[i] = self.a[(i, i)].max(1e-300).sqrt();
        }
        let scale = self.scale.as_slice();
        for (col, sj) in self.a.as_mut_slice().chunks_exact_mut(n).zip(scale) {
            for (v, si) in col.iter_mut().zip(scale) {
                *v /= si * sj;
            }
        }
        self.b.component_div_assign(&self.scale);
        for ridge in [0.0, 1e-12, 1e-9, 1e-6] {
            if self.m.shape() == self.a.shape() {
                self.m.copy_from(&self.a);
            } else {
                self.m = self.a.clone();
            }
            for i in 0..n {
                self.m[(i, i)] += ridge;
            }
            let Some(ch) = std::mem::replace(&mut self.m, DMatrix::zeros(0, 0)).cholesky() else {
                continue;
            };
            self.x.copy_from(&self.b);
            ch.solve_mut(&mut self.x);
            self.m = ch.unpack();
            self.x.component_div_assign(&self.scale);
            if self.x.iter().all(|v| v.is_finite()) {
                return Some(&self.x);
            }
        }
        None
    }
}

/// Σ aᵢ, in eight interleaved partial sums (as [`dot`]).
fn sum(a: &[f64]) -> f64 {
    const L: usize = 8;
    let mut acc = [0.0; L];
    let chunks = a.chunks_exact(L);
    let tail: f64 = chunks.remainder().iter().sum();
    for x in chunks {
        for k in 0..L {
            acc[k] += x[k];
        }
    }
    acc.iter().sum::<f64>() + tail
}

/// Σ aᵢbᵢ over the shorter of the two, in eight interleaved partial sums: independent
/// additions the compiler can vectorise (a single running sum cannot be reordered). With
/// the twenty-fourth round's other changes it took the real spindle file's diagnosis from 47
/// to 18 s (docs/methods.md).
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    const L: usize = 8;
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0; L];
    let (ac, bc) = (a.chunks_exact(L), b.chunks_exact(L));
    let tail: f64 = ac
        .remainder()
        .iter()
        .zip(bc.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ac.zip(bc) {
        for k in 0..L {
            acc[k] += x[k] * y[k];
        }
    }
    acc.iter().sum::<f64>() + tail
}

/// Residuals of `y` held out block by block (each block predicted by a fit on the others).
pub(crate) fn heldout_residuals(cols: &[&[f64]], y: &[f64], blocks: &Blocks) -> Option<Vec<f64>> {
    let stats = BlockStats::new(cols, y, blocks);
    let mut res = vec![0.0; y.len()];
    let totals = stats.totals();
    let mut solver = Solver::new(stats.p);
    for (k, r) in blocks.0.iter().enumerate() {
        let beta = solver.coefficients(&stats, &totals, Some(k))?;
        for i in r.clone() {
            res[i] = y[i] - predict_row(beta, cols, i);
        }
    }
    Some(res)
}

/// Residuals of the blocks from `first` on, each predicted by a fit on the blocks before it
/// (forward in time); the block ranges are those of `blocks` from `first` on.
pub(crate) fn forward_residuals(
    cols: &[&[f64]],
    y: &[f64],
    blocks: &Blocks,
    first: usize,
) -> Option<(Vec<f64>, Blocks)> {
    let k_all = blocks.0.len();
    let first = first.clamp(1, k_all - 1);
    let mut res = vec![];
    let mut ranges = vec![];
    for k in first..k_all {
        let train = Blocks(std::iter::once(0..blocks.0[k].start).collect());
        let beta = BlockStats::new(cols, y, &train).coefficients(None)?;
        let start = res.len();
        for i in blocks.0[k].clone() {
            res.push(y[i] - predict_row(&beta, cols, i));
        }
        ranges.push(start..res.len());
    }
    Some((res, Blocks(ranges)))
}

pub(crate) fn predict_row(beta: &DVector<f64>, cols: &[&[f64]], i: usize) -> f64 {
    beta[0]
        + cols
            .iter()
            .enumerate()
            .map(|(j, c)| beta[j + 1] * c[i])
            .sum::<f64>()
}

/// The rule that decides whether a change of model gains on held-out blocks.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GainRule {
    /// Least relative fall of the held-out RMS (0.05: 5 %).
    pub min_relative_gain: f64,
    /// Least t value of the per-block log ratio of held-out mean squares.
    pub min_t: f64,
}

impl Default for GainRule {
    fn default() -> Self {
        Self {
            min_relative_gain: 0.05,
            min_t: 3.0,
        }
    }
}

/// A change of model measured on held-out blocks.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HeldOutGain {
    /// Held-out RMS before, µm.
    pub rms_before_um: f64,
    /// Held-out RMS after, µm.
    pub rms_after_um: f64,
    /// t value of the per-block log ratio of held-out mean squares (positive: after is better).
    pub t: f64,
    /// Whether the gain passes the rule.
    pub significant: bool,
}

impl HeldOutGain {
    /// The smallest held-out RMS gain that counts, µm.
    pub const MIN_GAIN_UM: f64 = 1e-6;

    pub(crate) fn between(before: &CvScore, after: &CvScore, rule: &GainRule) -> Self {
        let floor =
            1e-12 * (before.total() + after.total()) / before.sse.len().max(1) as f64 + 1e-300;
        let r: Vec<f64> = before
            .sse
            .iter()
            .zip(&after.sse)
            .map(|(b, a)| ((b + floor) / (a + floor)).ln())
            .collect();
        let k = r.len() as f64;
        let mean = r.iter().sum::<f64>() / k;
        let var = r.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0).max(1.0);
        let se = (var / k).sqrt();
        let t = if se > 0.0 {
            mean / se
        } else if mean > 0.0 {
            f64::MAX
        } else {
            0.0
        };
        let (rb, ra) = (before.rms(), after.rms());
        // A gain below a picometre is rounding: no displacement sensor resolves it, and a
        // constant channel (RMS 1e-12 µm) would otherwise take terms that fit its noise.
        let significant = t >= rule.min_t
            && ra <= (1.0 - rule.min_relative_gain) * rb
            && rb - ra > Self::MIN_GAIN_UM;
        Self {
            rms_before_um: rb,
            rms_after_um: ra,
            t: t.min(1e6),
            significant,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solver_recovers_after_a_singular_system() {
        let mut solver = Solver::new(2);
        // Not positive definite: every ridge fails, and the factor's buffer is lost.
        let bad = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
        assert!(
            solver
                .solve(&bad, &DVector::from_vec(vec![1.0, 1.0]))
                .is_none()
        );
        // Singular (a column twice): the ridge gives the minimum-norm split.
        let singular = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 1.0, 1.0]);
        let x = solver.solve(&singular, &DVector::from_vec(vec![2.0, 2.0]));
        let x = x.cloned().expect("ridge solves a singular system");
        assert!(
            (x[0] - 1.0).abs() < 1e-5 && (x[1] - 1.0).abs() < 1e-5,
            "{x}"
        );
        let g = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 3.0]);
        let x = solver
            .solve(&g, &DVector::from_vec(vec![1.0, 2.0]))
            .cloned();
        let x = x.expect("a regular system solves");
        assert!((x[0] - 1.0 / 11.0).abs() < 1e-14 && (x[1] - 7.0 / 11.0).abs() < 1e-14);
        assert!((solver.quadratic_form(&g.columns(0, 2)) - x.dot(&(&g * &x))).abs() < 1e-15);
    }

    fn naive_heldout(cols: &[Vec<f64>], y: &[f64], blocks: &Blocks) -> Vec<f64> {
        let n = y.len();
        let p = cols.len() + 1;
        let x = DMatrix::from_fn(n, p, |i, j| if j == 0 { 1.0 } else { cols[j - 1][i] });
        let mut out = vec![];
        for r in &blocks.0 {
            let keep: Vec<usize> = (0..n).filter(|i| !r.contains(i)).collect();
            let xt = x.select_rows(&keep);
            let yt = DVector::from_iterator(keep.len(), keep.iter().map(|&i| y[i]));
            let beta = xt.clone().svd(true, true).solve(&yt, 1e-14).unwrap();
            out.push(
                r.clone()
                    .map(|i| (y[i] - (x.row(i) * &beta)[0]).powi(2))
                    .sum(),
            );
        }
        out
    }

    #[test]
    fn block_cv_matches_refitting_each_fold() {
        let n = 97;
        let a: Vec<f64> = (0..n).map(|i| (i as f64 * 0.1).sin()).collect();
        let b: Vec<f64> = (0..n)
            .map(|i| (i as f64 * 0.037).cos() + 0.01 * i as f64)
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|i| 1.0 + 2.0 * a[i] - b[i] + 0.1 * ((i * 7919) % 13) as f64)
            .collect();
        let blocks = Blocks::contiguous(n, 5);
        let s = BlockStats::new(&[&a, &b], &y, &blocks).score().unwrap();
        let naive = naive_heldout(&[a.clone(), b.clone()], &y, &blocks);
        for (x, z) in s.sse.iter().zip(&naive) {
            assert!((x - z).abs() < 1e-8 * z.max(1.0), "{x} vs {z}");
        }
        let res = heldout_residuals(&[&a, &b], &y, &blocks).unwrap();
        let sse: f64 = res.iter().map(|r| r * r).sum();
        assert!((sse - naive.iter().sum::<f64>()).abs() < 1e-8);
    }

    #[test]
    fn partial_sums_match_a_running_sum_at_every_length() {
        for n in 0..40 {
            let a: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin() + 1.0).collect();
            let b: Vec<f64> = (0..n + 3).map(|i| (i as f64 * 0.3).cos()).collect();
            let plain: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            assert!((dot(&a, &b) - plain).abs() < 1e-12, "dot, n = {n}");
            assert!((dot(&b, &a) - plain).abs() < 1e-12, "dot reversed, n = {n}");
            let total: f64 = a.iter().sum();
            assert!((sum(&a) - total).abs() < 1e-12, "sum, n = {n}");
        }
    }

    #[test]
    fn gain_rule_needs_consistent_gain() {
        let before = CvScore {
            sse: vec![4.0; 8],
            n: vec![10; 8],
        };
        let after = CvScore {
            sse: vec![1.0, 1.1, 0.9, 1.0, 1.2, 0.8, 1.0, 1.0],
            n: vec![10; 8],
        };
        assert!(HeldOutGain::between(&before, &after, &GainRule::default()).significant);
        let mixed = CvScore {
            sse: vec![1.0, 8.0, 1.0, 8.0, 1.0, 8.0, 1.0, 4.0],
            n: vec![10; 8],
        };
        assert!(!HeldOutGain::between(&before, &mixed, &GainRule::default()).significant);
    }
}
