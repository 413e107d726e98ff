//! The grid searches' columns and their weighted sums, kept for the run ([`Cache`]).
//!
//! A diagnosis tries the same parameter values of a cyclic drift, a warm-up or a scale change
//! many times: at each step of the selection, for each effect put in another's place and at
//! each point of a parameter's spread, mostly with the same weights and only the other
//! effects' columns changed. What depends on the column and the weights alone — the column
//! itself (its sines, cosines or exponentials), its weighted sums by group and by cycle and its
//! weighted products with itself — is computed once ([`ColSums`]); each try then costs one pass
//! over the readings per fixed column of the model ([`DenseSearch::rss`]). The values are those
//! of [`Projector::fit_cols`] on the same columns (the same products, summed in another order).

#![allow(clippy::needless_range_loop)]

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use nalgebra::{DMatrix, DVector};

use rayon::prelude::*;

use super::family::{Family, cyclic_frequencies};
use super::obs::Obs;
use super::projector::{Counts, Fixed, Projector, dot, dotw};

/// Most bytes of columns [`Cache`] keeps (each column 8·N bytes); beyond, columns are
/// computed each time.
const COLUMN_CACHE_BYTES: usize = 128 << 20;

/// Most sets of weights whose sums [`Cache`] keeps (the oldest is dropped).
const WEIGHT_SETS: usize = 8;

/// A family's columns at one parameter value.
type Columns = Arc<Vec<Vec<f64>>>;

/// Key of a family's columns: the family and the parameter's bits.
type Key = (u8, u64);

/// Columns and sums of the searched families for one run.
#[derive(Default)]
pub(super) struct Cache {
    columns: Mutex<HashMap<Key, Columns>>,
    weight_sets: Mutex<Vec<Arc<WeightSums>>>,
    /// The cyclic drift's grid columns are in `columns` ([`Cache::fill_cyclic_grid`]).
    cyclic_filled: OnceLock<()>,
}

/// Frequencies of the cyclic grid whose sines and cosines [`Cache::fill_cyclic_grid`] takes
/// from one direct computation by rotation (the error of a rotation, ~1e-16, then adds up to
/// ~1e-14 of the values).
const ROTATIONS: usize = 64;

impl Cache {
    /// The sines and cosines of every period of the cyclic drift's grid, by rotating each
    /// reading's phasor from one grid frequency to the next (a complex product instead of a
    /// sine and a cosine: the grid is uniform in frequency), computed directly every
    /// [`ROTATIONS`] frequencies. A period off the grid is computed directly when asked for.
    pub(super) fn fill_cyclic_grid(&self, obs: &Obs) {
        self.cyclic_filled.get_or_init(|| {
            let Some(f) = cyclic_frequencies(obs) else {
                return;
            };
            let per = 2 * obs.len().max(1) * 8;
            if (f.n + 1) * per > COLUMN_CACHE_BYTES / 2 {
                return;
            }
            let step = std::f64::consts::TAU * (f.hi - f.lo) / f.n as f64;
            let (rs, rc): (Vec<f64>, Vec<f64>) = obs.t.iter().map(|t| (step * t).sin_cos()).unzip();
            let starts: Vec<usize> = (0..=f.n).step_by(ROTATIONS).collect();
            let filled: Vec<(f64, Vec<Vec<f64>>)> = starts
                .par_iter()
                .flat_map_iter(|&k0| {
                    let mut cur = Family::Cyclic.compute_columns(obs, f.period(k0));
                    let mut out = Vec::new();
                    for k in k0..(k0 + ROTATIONS).min(f.n + 1) {
                        if let (true, [s, c]) = (k > k0, &mut cur[..]) {
                            for j in 0..obs.len() {
                                let (a, b) = (s[j], c[j]);
                                s[j] = a * rc[j] + b * rs[j];
                                c[j] = b * rc[j] - a * rs[j];
                            }
                        }
                        out.push((f.period(k), cur.clone()));
                    }
                    out
                })
                .collect();
            if let Ok(mut m) = self.columns.lock() {
                for (p, cols) in filled {
                    m.entry((Family::Cyclic as u8, p.to_bits()))
                        .or_insert_with(|| Arc::new(cols));
                }
            }
        });
    }

    /// `fam`'s columns at `theta`, computed once (within [`COLUMN_CACHE_BYTES`]).
    pub(super) fn columns(&self, obs: &Obs, fam: Family, theta: f64) -> Columns {
        let key = (fam as u8, theta.to_bits());
        if let Some(c) = self.columns.lock().ok().and_then(|m| m.get(&key).cloned()) {
            return c;
        }
        let cols = Arc::new(fam.compute_columns(obs, theta));
        if let Ok(mut m) = self.columns.lock() {
            let per = cols.len().max(1) * obs.len().max(1) * 8;
            if (m.len() + 1) * per <= COLUMN_CACHE_BYTES {
                m.insert(key, Arc::clone(&cols));
            }
        }
        cols
    }

    /// `fam`'s columns at `theta`: kept for a grid-searched family, computed otherwise.
    pub(super) fn columns_shared(&self, obs: &Obs, fam: Family, theta: f64) -> Columns {
        if fam.is_searched_dense() {
            self.columns(obs, fam, theta)
        } else {
            Arc::new(fam.compute_columns(obs, theta))
        }
    }

    /// The sums kept for the weights `w`.
    fn for_weights(&self, obs: &Obs, w: &[f64]) -> Arc<WeightSums> {
        let Ok(mut sets) = self.weight_sets.lock() else {
            return Arc::new(WeightSums::new(obs, w));
        };
        if let Some(s) = sets.iter().find(|s| s.w == w) {
            return Arc::clone(s);
        }
        if sets.len() >= WEIGHT_SETS {
            sets.remove(0);
        }
        let s = Arc::new(WeightSums::new(obs, w));
        sets.push(Arc::clone(&s));
        s
    }
}

/// A family's columns at one parameter value and what the weights make of them alone.
pub(super) struct ColSums {
    cols: Columns,
    /// Weighted sums of each column by group.
    by_group: Vec<Vec<f64>>,
    /// Weighted products of the columns, centred within the groups.
    centred: DMatrix<f64>,
    /// Weighted products of each column with every cycle's centred indicator (when first
    /// needed: a model with offsets per cycle).
    cycle_products: OnceLock<Vec<Vec<f64>>>,
}

impl ColSums {
    fn new(obs: &Obs, w: &[f64], counts: &Counts, cols: Columns) -> Self {
        let m = cols.len();
        let weighted: Vec<Vec<f64>> = cols
            .iter()
            .map(|c| c.iter().zip(w).map(|(c, w)| c * w).collect())
            .collect();
        let by_group: Vec<Vec<f64>> = weighted
            .iter()
            .map(|wc| {
                let mut s = vec![0.0; obs.n_groups];
                obs.group.iter().zip(wc).for_each(|(&g, x)| s[g] += x);
                s
            })
            .collect();
        let n_g = &counts.group;
        let centred = DMatrix::from_fn(m, m, |a, b| {
            let within: f64 = (0..obs.n_groups)
                .filter(|&g| n_g[g] > 0.0)
                .map(|g| by_group[a][g] * by_group[b][g] / n_g[g])
                .sum();
            dot(&weighted[a], &cols[b]) - within
        });
        ColSums {
            cols,
            by_group,
            centred,
            cycle_products: OnceLock::new(),
        }
    }

    /// [`ColSums::cycle_products`] (`w` and `counts` those of its weights).
    fn cycle_products(&self, obs: &Obs, w: &[f64], counts: &Counts) -> &[Vec<f64>] {
        self.cycle_products.get_or_init(|| {
            (0..self.cols.len())
                .map(|i| {
                    let mut by_cycle = vec![0.0; obs.n_cycles];
                    for j in 0..obs.len() {
                        by_cycle[obs.cycle[j]] += w[j] * self.cols[i][j];
                    }
                    (0..obs.n_cycles)
                        .map(|c| counts.cycle_product(c, &self.by_group[i], &by_cycle))
                        .collect()
                })
                .collect()
        })
    }
}

/// The sums kept for one set of weights, by family and parameter value.
struct WeightSums {
    w: Vec<f64>,
    counts: Counts,
    by_key: Mutex<HashMap<Key, Arc<ColSums>>>,
}

impl WeightSums {
    fn new(obs: &Obs, w: &[f64]) -> Self {
        WeightSums {
            w: w.to_vec(),
            counts: Counts::new(obs, w),
            by_key: Mutex::default(),
        }
    }

    fn get(&self, obs: &Obs, cache: &Cache, fam: Family, theta: f64) -> Arc<ColSums> {
        let key = (fam as u8, theta.to_bits());
        if let Some(s) = self.by_key.lock().ok().and_then(|m| m.get(&key).cloned()) {
            return s;
        }
        let cols = cache.columns_shared(obs, fam, theta);
        let s = Arc::new(ColSums::new(obs, &self.w, &self.counts, cols));
        if let Ok(mut m) = self.by_key.lock() {
            m.insert(key, Arc::clone(&s));
        }
        s
    }
}

/// A grid search of a family with dense columns (a cyclic drift, a warm-up, a scale change)
/// against one projector: y⊥ and the fixed dense columns weighted once.
pub(super) struct DenseSearch<'a> {
    obs: &'a Obs,
    cache: &'a Cache,
    p: &'a Projector,
    sums: Arc<WeightSums>,
    /// w·y⊥.
    wy: Vec<f64>,
    /// w·z for each dense fixed column (None for a cycle's indicator).
    wz: Vec<Option<Vec<f64>>>,
    /// y⊥'Wy⊥.
    y2: f64,
}

impl<'a> DenseSearch<'a> {
    pub(super) fn new(obs: &'a Obs, cache: &'a Cache, p: &'a Projector, y_perp: &[f64]) -> Self {
        let w = &p.w;
        let weigh = |v: &[f64]| -> Vec<f64> { v.iter().zip(w).map(|(v, w)| v * w).collect() };
        DenseSearch {
            obs,
            cache,
            p,
            sums: cache.for_weights(obs, w),
            wy: weigh(y_perp),
            wz: p
                .fixed()
                .iter()
                .map(|f| match f {
                    Fixed::Dense { zc, .. } => Some(weigh(zc)),
                    Fixed::Cycle(_) => None,
                })
                .collect(),
            y2: dotw(y_perp, y_perp, w),
        }
    }

    /// RSS with `fam`'s columns at `theta` added (as [`Projector::fit_cols`]).
    pub(super) fn rss(&self, fam: Family, theta: f64) -> f64 {
        let (obs, p) = (self.obs, self.p);
        let s = self.sums.get(obs, self.cache, fam, theta);
        let m = s.cols.len();
        let u = DMatrix::from_fn(p.fixed().len(), m, |k, i| {
            match (&p.fixed()[k], &self.wz[k]) {
                (_, Some(wz)) => dot(&s.cols[i], wz),
                (Fixed::Cycle(c), None) => {
                    s.cycle_products(obs, &self.sums.w, &self.sums.counts)[i][*c]
                }
                (Fixed::Dense { .. }, None) => 0.0,
            }
        });
        let b = DVector::from_iterator(m, s.cols.iter().map(|c| dot(c, &self.wy)));
        p.rss_from(self.y2, s.centred.clone(), &u, &b).0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axis::obs::tests::run;

    /// The cached sums give the RSS of the columns fitted directly, with a drift and offsets
    /// per cycle in the model and a reading left out, for every searched dense family.
    #[test]
    fn cached_sums_give_the_direct_rss() {
        let obs = run();
        let w: Vec<f64> = (0..obs.len())
            .map(|j| if j == 4 { 0.0 } else { 1.0 })
            .collect();
        let mut fixed = Family::Linear.compute_columns(&obs, f64::NAN);
        fixed.extend(Family::CycleOffsets.compute_columns(&obs, f64::NAN));
        let p = Projector::new(&obs, &w, &fixed);
        let y = p.residualize(&obs, &obs.y);
        let cache = Cache::default();
        let d = DenseSearch::new(&obs, &cache, &p, &y);
        for (fam, theta) in [
            (Family::Cyclic, 700.0),
            (Family::Cyclic, 1234.5),
            (Family::Warmup, 900.0),
            (Family::Thermal, 3000.0),
        ] {
            for _ in 0..2 {
                let got = d.rss(fam, theta);
                let (want, _) = p.fit_cols(&obs, &y, &fam.compute_columns(&obs, theta));
                assert!(
                    (got - want).abs() < 1e-9 * want,
                    "{fam:?} {theta}: {got} vs {want}"
                );
            }
        }
    }
}
