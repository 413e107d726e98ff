//! Forward selection of lagged inputs judged on held-out time blocks.

use crate::cv::{BlockStats, Blocks, CvScore, GainRule, HeldOutGain};
use crate::inputs::{Inputs, Key, Spec, Src};
use rustc_hash::FxHashMap as HashMap;
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// Which terms a selection may use.
#[derive(Debug, Clone)]
pub(crate) struct Pool {
    pub(crate) sensors: Vec<usize>,
    pub(crate) spindle_exponents: Vec<u32>,
    pub(crate) asymmetric: bool,
    /// Most spindle terms in a model (the fit: any; the diagnosis: one heat source).
    pub(crate) max_spindle_terms: usize,
}

/// The search for one displacement channel.
pub(crate) struct Search<'a> {
    pub(crate) inputs: &'a Inputs,
    pub(crate) y: &'a [f64],
    pub(crate) blocks: Blocks,
    pub(crate) grid: Vec<f64>,
    pub(crate) rule: GainRule,
    /// Whether sensor terms may have a lag (their τ is searched).
    pub(crate) sensor_lags: bool,
    /// Scores already computed for these inputs, displacement and blocks; shared by every
    /// search of the channel (the diagnosis' many greedy paths try the same models again).
    pub(crate) memo: Rc<ScoreMemo>,
}

/// Held-out scores of models already scored, keyed by their terms in order (the order of
/// the sums, so a score read back is the one computed, bit for bit). At most
/// [`MEMO_MAX_ENTRIES`]; past that, scores are computed and not kept.
#[derive(Default)]
pub(crate) struct ScoreMemo {
    map: RefCell<HashMap<Vec<Key>, CvScore>>,
    hits: Cell<u64>,
    misses: Cell<u64>,
}

/// Bounds a channel's memo to some tens of MB (a key of a few terms and a score of a few
/// blocks: about 300 bytes an entry).
const MEMO_MAX_ENTRIES: usize = 100_000;

impl ScoreMemo {
    fn key(base: &[Spec], cand: &Spec) -> Vec<Key> {
        base.iter()
            .chain(std::iter::once(cand))
            .map(Spec::key)
            .collect()
    }

    fn get(&self, key: &[Key]) -> Option<CvScore> {
        let found = self.map.borrow().get(key).cloned();
        let counter = if found.is_some() {
            &self.hits
        } else {
            &self.misses
        };
        counter.set(counter.get() + 1);
        found
    }

    fn put(&self, key: Vec<Key>, score: &CvScore) {
        let mut map = self.map.borrow_mut();
        if map.len() < MEMO_MAX_ENTRIES {
            map.insert(key, score.clone());
        }
    }
}

/// A selected model: its terms, held-out score and the gain of each step.
#[derive(Debug, Clone)]
pub(crate) struct Selection {
    pub(crate) specs: Vec<Spec>,
    pub(crate) score: CvScore,
}

impl<'a> Search<'a> {
    pub(crate) fn columns(&self, specs: &[Spec]) -> Option<Vec<Rc<Vec<f64>>>> {
        specs.iter().map(|s| self.inputs.column(s)).collect()
    }

    fn stats(&self, specs: &[Spec]) -> Option<BlockStats> {
        let cols = self.columns(specs)?;
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        Some(BlockStats::new(&refs, self.y, &self.blocks))
    }

    /// Forward-in-time score of a model: each block of the second half predicted by a fit
    /// on the blocks before it.
    pub(crate) fn forward_score(&self, specs: &[Spec]) -> Option<CvScore> {
        self.stats(specs)?.forward_score(self.blocks.0.len() / 2)
    }

    /// Held-out score of a model.
    pub(crate) fn score(&self, specs: &[Spec]) -> Option<CvScore> {
        self.stats(specs)?.score()
    }

    /// Scores of `base` plus each of `cands` in turn (those that can be scored, in order).
    fn scores_with(&self, base: &[Spec], cands: &[Spec]) -> Vec<(Spec, CvScore)> {
        let mut out: Vec<(Spec, Option<CvScore>)> = cands
            .iter()
            .map(|c| (*c, self.memo.get(&ScoreMemo::key(base, c))))
            .collect();
        if out.iter().any(|(_, s)| s.is_none()) {
            self.score_missing(base, &mut out);
        }
        out.into_iter().filter_map(|(c, s)| Some((c, s?))).collect()
    }

    /// The scores `out` lacks, computed from one fit of `base`'s statistics and kept.
    fn score_missing(&self, base: &[Spec], out: &mut [(Spec, Option<CvScore>)]) {
        let (Some(stats), Some(cols)) = (self.stats(base), self.columns(base)) else {
            return;
        };
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        for (c, slot) in out.iter_mut().filter(|(_, s)| s.is_none()) {
            let Some(col) = self.inputs.column(c) else {
                continue;
            };
            *slot = stats.with_column(&refs, &col, self.y, &self.blocks).score();
            if let Some(s) = slot {
                self.memo.put(ScoreMemo::key(base, c), s);
            }
        }
    }

    fn symmetric_candidates(&self, sel: &[Spec], pool: &Pool) -> Vec<Spec> {
        let mut out = vec![];
        for &i in &pool.sensors {
            out.push(Spec::symmetric(Src::Sensor(i), 0.0));
            if self.sensor_lags {
                out.extend(
                    self.grid
                        .iter()
                        .map(|&t| Spec::symmetric(Src::Sensor(i), t)),
                );
            }
        }
        if self.inputs.has_spindle() && spindle_terms(sel) < pool.max_spindle_terms {
            for &p in &pool.spindle_exponents {
                out.push(Spec::symmetric(Src::Spindle(p), 0.0));
                out.extend(
                    self.grid
                        .iter()
                        .map(|&t| Spec::symmetric(Src::Spindle(p), t)),
                );
            }
        }
        out
    }

    fn asymmetric_candidates(&self, p: u32) -> Vec<Spec> {
        let coarse: Vec<f64> = self.grid.iter().copied().step_by(2).collect();
        let mut out = vec![];
        for &h in &coarse {
            for &c in coarse.iter().filter(|&&c| c != h) {
                out.push(Spec {
                    src: Src::Spindle(p),
                    tau_heat_s: h,
                    tau_cool_s: c,
                });
            }
        }
        out
    }

    /// The best term to add to `sel`: an asymmetric spindle term only when it gains on
    /// the best symmetric one of the same input.
    fn best_addition(&self, sel: &[Spec], pool: &Pool) -> Option<(Spec, CvScore)> {
        let cands: Vec<Spec> = self
            .symmetric_candidates(sel, pool)
            .into_iter()
            .filter(|c| !sel.contains(c))
            .collect();
        let scored = self.scores_with(sel, &cands);
        let mut best = best_of(scored.iter().cloned())?;
        if let (Src::Spindle(p), true) = (best.0.src, pool.asymmetric) {
            let asym = self.scores_with(sel, &self.asymmetric_candidates(p));
            if let Some(a) = best_of(asym.into_iter()) {
                let mut trial = sel.to_vec();
                trial.push(a.0);
                let refined = self.refine(&trial, trial.len() - 1);
                if HeldOutGain::between(&best.1, &refined.1, &self.rule).significant {
                    best = refined;
                }
            }
        }
        Some(best)
    }

    /// Term `idx` of `specs` with its time constant(s) searched, the others fixed.
    pub(crate) fn refine(&self, specs: &[Spec], idx: usize) -> (Spec, CvScore) {
        let others: Vec<Spec> = specs
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != idx)
            .map(|(_, s)| *s)
            .collect();
        let mut cur = specs[idx];
        let mut best = self.scores_with(&others, &[cur]).pop();
        if cur.is_asymmetric() {
            for heat in [true, false] {
                let cands: Vec<Spec> = self.grid.iter().map(|&t| with_tau(cur, t, heat)).collect();
                if let Some(b) = best_of(
                    self.scores_with(&others, &cands)
                        .into_iter()
                        .chain(best.clone()),
                ) {
                    cur = b.0;
                    best = Some(self.golden(&others, b, heat));
                    cur = best.as_ref().map_or(cur, |b| b.0);
                }
            }
        } else {
            if matches!(cur.src, Src::Sensor(_)) && !self.sensor_lags {
                return best.unwrap_or_else(|| (cur, self.worst()));
            }
            let taus = std::iter::once(0.0).chain(self.grid.iter().copied());
            let cands: Vec<Spec> = taus.map(|t| Spec::symmetric(cur.src, t)).collect();
            if let Some(b) = best_of(
                self.scores_with(&others, &cands)
                    .into_iter()
                    .chain(best.clone()),
            ) {
                best = Some(self.golden(&others, b, true));
            }
        }
        best.unwrap_or_else(|| (cur, self.worst()))
    }

    fn worst(&self) -> CvScore {
        let k = self.blocks.0.len();
        CvScore {
            sse: vec![f64::MAX / (k as f64 + 1.0); k],
            n: vec![1; k],
        }
    }

    /// Golden-section search of log τ between the grid neighbours of the best value.
    fn golden(&self, others: &[Spec], best: (Spec, CvScore), heat: bool) -> (Spec, CvScore) {
        let tau = if heat {
            best.0.tau_heat_s
        } else {
            best.0.tau_cool_s
        };
        if tau <= 0.0 {
            return best;
        }
        // Between the grid's neighbours of τ: the grid value's two neighbours, or the two grid
        // values around a τ an earlier search left between them (which, when it beats every
        // grid value, would otherwise never be searched again as the other terms change).
        let lo = self
            .grid
            .iter()
            .copied()
            .rev()
            .find(|&g| g < tau)
            .unwrap_or(tau / 1.5);
        let hi = self
            .grid
            .iter()
            .copied()
            .find(|&g| g > tau)
            .unwrap_or(tau * 1.5);
        let symmetric = !best.0.is_asymmetric();
        let start = best.0;
        let make = |t: f64| {
            if symmetric {
                Spec::symmetric(start.src, t)
            } else {
                with_tau(start, t, heat)
            }
        };
        let eval = |x: f64| self.scores_with(others, &[make(x.exp())]).pop();
        let r = 0.618_033_988_749_895;
        let (mut a, mut b) = (lo.ln(), hi.ln());
        let (mut x1, mut x2) = (b - r * (b - a), a + r * (b - a));
        let (Some(mut f1), Some(mut f2)) = (eval(x1), eval(x2)) else {
            return best;
        };
        let mut out = best;
        // Ten brackets compared, nine shrinks, one new point each: the inner point kept is
        // already scored (r² = 1 − r).
        for step in 0..10 {
            let f1_lower = f1.1.total() < f2.1.total();
            let better = if f1_lower { &f1 } else { &f2 };
            if better.1.total() < out.1.total() {
                out = better.clone();
            }
            if step == 9 {
                break;
            }
            if f1_lower {
                (b, x2, f2) = (x2, x1, f1);
                x1 = b - r * (b - a);
                let Some(f) = eval(x1) else { break };
                f1 = f;
            } else {
                (a, x1, f1) = (x1, x2, f2);
                x2 = a + r * (b - a);
                let Some(f) = eval(x2) else { break };
                f2 = f;
            }
        }
        out
    }

    /// Each term's time constant searched again with the others in (one pass).
    pub(crate) fn backfit(&self, specs: &mut [Spec]) -> Option<CvScore> {
        let mut score = self.score(specs)?;
        for idx in 0..specs.len() {
            let (spec, s) = self.refine(specs, idx);
            if s.total() < score.total() {
                specs[idx] = spec;
                score = s;
            }
        }
        Some(score)
    }

    /// [`Search::backfit`] repeated, at most `passes` times, until a pass lowers the held-out
    /// score by less than a millionth: one pass is one step of a coordinate descent, short of
    /// the least in a narrow valley where two time constants trade off.
    pub(crate) fn backfit_settled(&self, specs: &mut [Spec], passes: usize) -> Option<CvScore> {
        let mut score = self.backfit(specs)?;
        for _ in 1..passes {
            let next = self.backfit(specs)?;
            let settled = next.total() >= score.total() * (1.0 - 1e-6);
            score = next;
            if settled {
                break;
            }
        }
        Some(score)
    }

    /// Forward selection from `start`, each step kept when it gains on held-out blocks.
    pub(crate) fn forward(
        &self,
        start: Vec<Spec>,
        pool: &Pool,
        max_terms: usize,
    ) -> Option<Selection> {
        let mut specs = start;
        let mut score = self.score(&specs)?;
        while specs.len() < max_terms {
            let Some((cand, _)) = self.best_addition(&specs, pool) else {
                break;
            };
            let mut trial = specs.clone();
            trial.push(cand);
            let (refined, s) = self.refine(&trial, trial.len() - 1);
            if specs.contains(&refined) {
                // Refined onto a term the model has: nothing new to add.
                break;
            }
            *trial.last_mut()? = refined;
            let gain = HeldOutGain::between(&score, &s, &self.rule);
            if !gain.significant {
                break;
            }
            let s = self.backfit(&mut trial).unwrap_or(s);
            specs = trial;
            score = s;
        }
        Some(Selection { specs, score })
    }
}

impl Search<'_> {
    /// `sel` with its terms exchanged one at a time for the pool's best other term (its time
    /// constant searched, then every term's), while an exchange lowers the held-out score, at
    /// most `passes` times. A greedy path can keep a term that stands in for two: an ambient
    /// lag in place of the column beside a housing lag whose τ it then pulls off.
    pub(crate) fn exchange(&self, mut sel: Selection, pool: &Pool, passes: usize) -> Selection {
        for _ in 0..passes {
            let Some(better) = (0..sel.specs.len())
                .filter_map(|idx| self.exchanged(&sel, idx, pool))
                .min_by(|a, b| a.score.total().total_cmp(&b.score.total()))
                .filter(|b| b.score.total() < sel.score.total())
            else {
                break;
            };
            sel = better;
        }
        sel
    }

    /// `sel` with term `idx` replaced by the pool's best other term, refitted.
    fn exchanged(&self, sel: &Selection, idx: usize, pool: &Pool) -> Option<Selection> {
        let others = without(&sel.specs, idx);
        let cands: Vec<Spec> = self
            .symmetric_candidates(&others, pool)
            .into_iter()
            .filter(|c| !others.contains(c) && c.src != sel.specs[idx].src)
            .collect();
        let (c, _) = best_of(self.scores_with(&others, &cands).into_iter())?;
        let mut specs = others;
        specs.push(c);
        self.refitted(specs)
    }
}

impl Search<'_> {
    /// `m` with its symmetric spindle term made asymmetric: heating and cooling time
    /// constants searched with the other terms fixed, then every term's searched again. The
    /// asymmetry is then judged on the same other terms, not on whatever a greedy path took
    /// before the spindle term came in as symmetric (and stayed so).
    pub(crate) fn asymmetric_variant(&self, m: &Selection) -> Option<Selection> {
        let idx = m
            .specs
            .iter()
            .position(|s| matches!(s.src, Src::Spindle(_)) && !s.is_asymmetric())?;
        let Src::Spindle(p) = m.specs[idx].src else {
            return None;
        };
        let mut specs = without(&m.specs, idx);
        let (a, _) = best_of(
            self.scores_with(&specs, &self.asymmetric_candidates(p))
                .into_iter(),
        )?;
        specs.push(a);
        self.refitted(specs)
    }

    /// `m` with its asymmetric spindle term made symmetric (one time constant searched), then
    /// every term's searched again: the asymmetry's counterpart on the same other terms.
    pub(crate) fn symmetric_variant(&self, m: &Selection) -> Option<Selection> {
        let idx = m
            .specs
            .iter()
            .position(|s| matches!(s.src, Src::Spindle(_)) && s.is_asymmetric())?;
        let sym = Spec::symmetric(m.specs[idx].src, m.specs[idx].tau_heat_s);
        let mut specs = without(&m.specs, idx);
        specs.push(sym);
        self.refitted(specs)
    }

    /// `m` with every static sensor term smoothed without delay, each smoothing's time
    /// constant searched (zero: the reading itself).
    pub(crate) fn smoothed_variant(&self, m: &Selection) -> Option<Selection> {
        if !m
            .specs
            .iter()
            .any(|s| matches!(s.src, Src::Sensor(_)) && s.tau_heat_s == 0.0)
        {
            return None;
        }
        let mut specs: Vec<Spec> = m
            .specs
            .iter()
            .map(|s| match s.src {
                Src::Sensor(i) if s.tau_heat_s == 0.0 => Spec::symmetric(Src::Smoothed(i), 0.0),
                _ => *s,
            })
            .collect();
        let score = self.backfit(&mut specs)?;
        Some(Selection { specs, score })
    }

    /// The last term's time constants searched, then every term's.
    fn refitted(&self, mut specs: Vec<Spec>) -> Option<Selection> {
        let last = specs.len().checked_sub(1)?;
        let (r, _) = self.refine(&specs, last);
        specs[last] = r;
        let score = self.backfit(&mut specs)?;
        Some(Selection { specs, score })
    }
}

impl Search<'_> {
    /// Each static sensor term of `base` in turn lagged beside one spindle term, the two time
    /// constants searched together on the grid, then every term's searched again. A greedy
    /// path adds one term at a time, and the first (a spindle term of some τ, or a lag) can
    /// stand in for both: a mass heated through a sensed part lags it by τ_L, which reads
    /// like the sensed part plus a heat source of about τ_L beside the real one.
    /// The spindle term is searched symmetric, and asymmetric when the pool allows it.
    pub(crate) fn lag_beside_spindle(&self, base: &[Spec], pool: &Pool) -> Vec<Selection> {
        if !self.sensor_lags || !self.inputs.has_spindle() || pool.max_spindle_terms == 0 {
            return vec![];
        }
        // Per spindle exponent, the symmetric terms on the grid and, when the pool allows
        // it, the asymmetric ones: made asymmetric only after a symmetric joint search, the
        // spindle term would start from a lag τ that was standing in for the asymmetry.
        let mut spindle_sets: Vec<Vec<Spec>> = vec![];
        for &p in &pool.spindle_exponents {
            let symmetric = self
                .grid
                .iter()
                .map(|&t| Spec::symmetric(Src::Spindle(p), t));
            spindle_sets.push(symmetric.collect());
            if pool.asymmetric {
                spindle_sets.push(self.asymmetric_candidates(p));
            }
        }
        let mut out = vec![];
        for (idx, term) in base.iter().enumerate() {
            let Src::Sensor(i) = term.src else { continue };
            if term.tau_heat_s != 0.0 {
                continue;
            }
            for terms in &spindle_sets {
                out.extend(self.joint_lag_spindle(base, idx, i, terms));
            }
        }
        out
    }

    /// `base` with term `idx` (sensor `i`) lagged and the best of the `spindle` terms added,
    /// the lag's τ on the grid searched together with the spindle term's, then backfitted.
    fn joint_lag_spindle(
        &self,
        base: &[Spec],
        idx: usize,
        i: usize,
        spindle: &[Spec],
    ) -> Option<Selection> {
        let (mut specs, _) = self
            .grid
            .iter()
            .filter_map(|&tau_lag| {
                let mut specs = base.to_vec();
                specs[idx] = Spec::symmetric(Src::Sensor(i), tau_lag);
                // The spindle term's τ searched between its grid neighbours for each lag: the
                // valley is narrow, and a grid τ 20-30 % off made a wrong lag look best.
                let best = best_of(self.scores_with(&specs, spindle).into_iter())?;
                let (sp, sc) = self.golden(&specs, best, true);
                specs.push(sp);
                Some((specs, sc))
            })
            .min_by(|a, b| a.1.total().total_cmp(&b.1.total()))?;
        let score = self.backfit_settled(&mut specs, JOINT_BACKFIT_PASSES)?;
        Some(Selection { specs, score })
    }
}

/// Most backfit passes of the joint lag-and-spindle search. A sensor's lag and the spindle
/// term's time constant trade off along a narrow valley (the mass heated through the
/// housing reads as the housing plus a heat source of about its τ): one pass left the lag
/// 20-30 % off, the model judged worse than spindle heat alone, which hid the lag and chose
/// the wrong timing of the speed readings. Repeating it alone took the reporting seeds'
/// lag+unseen from 93 to 95 of 100; with the spindle τ searched at each trial lag, 96 with or
/// without it (docs/methods.md, twenty-eighth round). It stops after one pass when nothing
/// moves.
const JOINT_BACKFIT_PASSES: usize = 4;

fn without(specs: &[Spec], idx: usize) -> Vec<Spec> {
    specs
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != idx)
        .map(|(_, s)| *s)
        .collect()
}

impl Search<'_> {
    /// The better on held-out blocks of two paths: forward selection over the whole pool, and
    /// sensors first (with their lags) then the whole pool from there. A greedy path that takes
    /// spindle heat first can end worse than sensors alone.
    pub(crate) fn select(&self, pool: &Pool, max_terms: usize) -> Option<Selection> {
        let direct = self.forward(vec![], pool, max_terms);
        let sensors_only = Pool {
            spindle_exponents: vec![],
            asymmetric: false,
            ..pool.clone()
        };
        let first = self.forward(vec![], &sensors_only, max_terms)?;
        let staged = self.forward(first.specs, pool, max_terms);
        // A greedy path that keeps few sensors can end worse than the static fit on every
        // sensor it should improve on: a path starts from that static fit too, and the static
        // fit itself is a candidate. Held-out blocks between fitted ones favour many collinear
        // sensors that extrapolate badly, so the candidate is chosen by predicting forward in
        // time (each later block from the blocks before it), the model's use.
        let all: Vec<Spec> = pool
            .sensors
            .iter()
            .map(|&i| Spec::symmetric(Src::Sensor(i), 0.0))
            .collect();
        let stat = self.score(&all).map(|score| Selection {
            specs: all.clone(),
            score,
        });
        [direct, staged, stat]
            .into_iter()
            .flatten()
            .filter_map(|c| Some((self.forward_score(&c.specs)?.total(), c)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, c)| c)
    }
}

impl<'a> Search<'a> {
    /// The same search without sensor lags (static terms of the sensors), sharing the memo.
    pub(crate) fn without_lags(&self) -> Search<'a> {
        Search {
            inputs: self.inputs,
            y: self.y,
            blocks: self.blocks.clone(),
            grid: self.grid.clone(),
            rule: self.rule,
            sensor_lags: false,
            memo: Rc::clone(&self.memo),
        }
    }
}

impl Search<'_> {
    /// The coefficients of `specs`' terms fitted on every block (the intercept left out).
    pub(crate) fn coefficients(&self, specs: &[Spec]) -> Option<Vec<f64>> {
        let cols = self.columns(specs)?;
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        let k = BlockStats::new(&refs, self.y, &self.blocks).coefficients(None)?;
        Some(k.iter().skip(1).copied().collect())
    }
}

fn spindle_terms(specs: &[Spec]) -> usize {
    specs
        .iter()
        .filter(|s| matches!(s.src, Src::Spindle(_)))
        .count()
}

fn with_tau(s: Spec, tau: f64, heat: bool) -> Spec {
    if heat {
        Spec {
            tau_heat_s: tau,
            ..s
        }
    } else {
        Spec {
            tau_cool_s: tau,
            ..s
        }
    }
}

fn best_of(it: impl Iterator<Item = (Spec, CvScore)>) -> Option<(Spec, CvScore)> {
    it.min_by(|a, b| a.1.total().total_cmp(&b.1.total()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::ThermalDataset;
    use crate::model::{FitOptions, reference_temperatures, searcher};

    /// A displacement that is a housing sensor lagged by 50 min plus a heat source no sensor
    /// reads (speed² through 20 min), written with its own fine Euler steps: the joint search
    /// from the static housing term finds both time constants.
    #[test]
    fn the_joint_search_finds_a_lag_beside_a_spindle_term() {
        let (dt, n, sub) = (60.0, 1200usize, 20);
        let (tau_lag, tau_sp) = (3000.0, 1200.0);
        let mut csv = String::from("time_s,spindle_rpm,x_um,housing_c\n");
        let (mut lagged, mut heat) = (0.0f64, 0.0f64);
        for k in 0..n {
            let t = k as f64 * dt;
            // Speed steps every 2.5 h; the housing a slow drift with a kink per step.
            let krpm = [0.0, 4.0, 0.0, 6.0, 2.0, 0.0, 5.0, 0.0][(k / 150) % 8];
            let housing = |t: f64| 2.0 * (t / 20_000.0).sin() + 0.3 * (t / 3_000.0).sin();
            let y = 3.0 * lagged + 2.0 * heat + 0.002 * (((k * 7919) % 13) as f64 - 6.0);
            csv += &format!("{t},{},{y},{}\n", krpm * 1000.0, 20.0 + housing(t));
            for j in 0..sub {
                let h = dt / sub as f64;
                let tt = t + j as f64 * h;
                lagged += (housing(tt) - lagged) * h / tau_lag;
                heat += (krpm * krpm - heat) * h / tau_sp;
            }
        }
        let ds = ThermalDataset::from_csv(&csv).expect("reads");
        let inputs = Inputs::new(&ds, &reference_temperatures(&ds)).with_spindle_hold(1.0);
        let s = searcher(&inputs, &ds.displacements_um[0], &FitOptions::default());
        let pool = Pool {
            sensors: vec![0],
            spindle_exponents: vec![2],
            asymmetric: false,
            max_spindle_terms: 1,
        };
        let found = s.lag_beside_spindle(&[Spec::symmetric(Src::Sensor(0), 0.0)], &pool);
        assert_eq!(found.len(), 1);
        let m = &found[0];
        let tau_of = |pred: fn(&Src) -> bool| {
            m.specs
                .iter()
                .find(|sp| pred(&sp.src))
                .map(|sp| sp.tau_heat_s)
        };
        let lag = tau_of(|s| matches!(s, Src::Sensor(_))).expect("a sensor term");
        let sp = tau_of(|s| matches!(s, Src::Spindle(_))).expect("a spindle term");
        assert!(
            (lag / tau_lag - 1.0).abs() < 0.15,
            "lag τ {lag} s: {:?}",
            m.specs
        );
        assert!(
            (sp / tau_sp - 1.0).abs() < 0.15,
            "spindle τ {sp} s: {:?}",
            m.specs
        );
        assert!(m.score.rms() < 0.05, "held-out RMS {}", m.score.rms());
    }

    /// The golden-section search scores two points, then one new point per shrink of its
    /// bracket (eleven models in all; it scored two per shrink before, twenty), and finds a
    /// lag off the grid; a
    /// model scored again is read from the memo, the same score bit for bit.
    #[test]
    fn the_golden_search_scores_one_new_point_per_shrink_and_the_memo_reads_back() {
        let tau: f64 = 1900.0;
        let mut csv = String::from("time_s,x_um,housing_c\n");
        let mut lagged = 0.0f64;
        for k in 0..800 {
            let t = k as f64 * 60.0;
            let housing = (t / 9_000.0).sin() + 0.4 * (t / 2_500.0).sin();
            csv += &format!("{t},{},{}\n", 2.0 * lagged, 20.0 + housing);
            lagged += (housing - lagged) * (1.0 - (-60.0 / tau).exp());
        }
        let ds = ThermalDataset::from_csv(&csv).expect("reads");
        let inputs = Inputs::new(&ds, &reference_temperatures(&ds));
        let s = searcher(&inputs, &ds.displacements_um[0], &FitOptions::default());
        let start = Spec::symmetric(Src::Sensor(0), 1800.0);
        let first = s.scores_with(&[], &[start]).pop().expect("scored");
        let misses = s.memo.misses.get();
        let (found, score) = s.golden(&[], first.clone(), true);
        assert_eq!(
            s.memo.misses.get() - misses,
            11,
            "models scored by the search"
        );
        assert!(
            (found.tau_heat_s / tau - 1.0).abs() < 0.05,
            "τ {}",
            found.tau_heat_s
        );
        assert!(score.total() < first.1.total());
        let hits = s.memo.hits.get();
        let again = s.scores_with(&[], &[start]).pop().expect("scored");
        assert_eq!(s.memo.hits.get(), hits + 1);
        assert_eq!(again.1, first.1);
    }

    /// As the generator's lag+unseen runs: a mass heated only through the housing (its lag
    /// off the grid, 43 min), the housing heated by the motor, and a heat source no sensor
    /// reads (speed² through 23 min, off the grid too). The two time constants trade off
    /// along a narrow valley: with the spindle τ only on the grid at each trial lag, the
    /// search settled on the housing lagged 79 min and the column 28 min, at 12× the held-out
    /// RMS of the model it finds now (lag 44.9 min, spindle 22.9 min, within the 5 % asked;
    /// the generator's Euler steps and the analysis' exact steps differ that much).
    #[test]
    fn the_joint_search_settles_two_time_constants_that_trade_off() {
        let (dt, n, sub) = (60.0, 1200usize, 20);
        let (tau_lag, tau_sp, tau_h) = (2600.0, 1380.0, 7200.0);
        let mut csv = String::from("time_s,spindle_rpm,x_um,housing_c,column_c\n");
        let (mut housing, mut lagged, mut heat) = (0.0f64, 0.0f64, 0.0f64);
        let column = |t: f64| 0.8 * (t / 15_000.0).sin();
        for k in 0..n {
            let t = k as f64 * dt;
            let krpm = [0.0, 4.0, 0.0, 6.0, 2.0, 0.0, 5.0, 0.0][(k / 150) % 8];
            let noise = 0.002 * (((k * 7919) % 13) as f64 - 6.0);
            let y = -3.0 * lagged + 3.0 * column(t) + 2.0 * heat + noise;
            csv += &format!(
                "{t},{},{y},{},{}\n",
                krpm * 1000.0,
                20.0 + housing,
                20.0 + column(t)
            );
            for j in 0..sub {
                let h = dt / sub as f64;
                let tt = t + j as f64 * h;
                let drive = 0.1 * krpm * krpm + 0.5 * column(tt);
                housing += (drive - housing) * h / tau_h;
                lagged += (housing - lagged) * h / tau_lag;
                heat += (krpm * krpm - heat) * h / tau_sp;
            }
        }
        let ds = ThermalDataset::from_csv(&csv).expect("reads");
        let inputs = Inputs::new(&ds, &reference_temperatures(&ds)).with_spindle_hold(1.0);
        let s = searcher(&inputs, &ds.displacements_um[0], &FitOptions::default());
        let pool = Pool {
            sensors: vec![0, 1],
            spindle_exponents: vec![2],
            asymmetric: false,
            max_spindle_terms: 1,
        };
        let base = [
            Spec::symmetric(Src::Sensor(0), 0.0),
            Spec::symmetric(Src::Sensor(1), 0.0),
        ];
        let found = s.lag_beside_spindle(&base, &pool);
        let m = found
            .iter()
            .find(|m| {
                m.specs
                    .iter()
                    .any(|sp| sp.src == Src::Sensor(0) && sp.tau_heat_s > 0.0)
            })
            .expect("the housing lagged");
        let tau_of = |src: Src| {
            m.specs
                .iter()
                .find(|sp| sp.src == src)
                .map(|sp| sp.tau_heat_s)
        };
        let (lag, sp) = (tau_of(Src::Sensor(0)), tau_of(Src::Spindle(2)));
        assert!(
            lag.is_some_and(|t| (t / tau_lag - 1.0).abs() < 0.05),
            "lag τ {lag:?}: {:?}",
            m.specs
        );
        assert!(
            sp.is_some_and(|t| (t / tau_sp - 1.0).abs() < 0.05),
            "spindle τ {sp:?}: {:?}",
            m.specs
        );
        assert!(m.score.rms() < 0.02, "held-out RMS {}", m.score.rms());
    }

    /// A displacement that lags the housing by 50 min and follows the column, and a start
    /// that holds an ambient lag in the column's place (a greedy path's stand-in): the
    /// exchange puts the column in and the housing's τ back where it belongs.
    #[test]
    fn an_exchange_replaces_a_stand_in_term() {
        let (dt, n, sub, tau_lag) = (60.0, 1200usize, 20, 3000.0);
        let mut csv = String::from("time_s,x_um,housing_c,column_c,ambient_c\n");
        let housing = |t: f64| 2.0 * (t / 9_000.0).sin() + 0.5 * (t / 2_000.0).cos();
        // The lagged mass starts at rest with the housing, as the analysis' lag does.
        let (mut lagged, mut column) = (housing(0.0), 0.0f64);
        let ambient = |t: f64| (t / 15_000.0).sin() + 0.2 * (t / 1_500.0).sin();
        for k in 0..n {
            let t = k as f64 * dt;
            let y = 3.0 * lagged + 2.0 * column + 0.002 * (((k * 7919) % 13) as f64 - 6.0);
            csv += &format!(
                "{t},{y},{},{},{}\n",
                20.0 + housing(t),
                20.0 + column,
                20.0 + ambient(t)
            );
            for j in 0..sub {
                let h = dt / sub as f64;
                let tt = t + j as f64 * h;
                lagged += (housing(tt) - lagged) * h / tau_lag;
                column += (ambient(tt) + 0.3 * housing(tt) - column) * h / 7200.0;
            }
        }
        let ds = ThermalDataset::from_csv(&csv).expect("reads");
        let inputs = Inputs::new(&ds, &reference_temperatures(&ds));
        let s = searcher(&inputs, &ds.displacements_um[0], &FitOptions::default());
        let pool = Pool {
            sensors: vec![0, 1, 2],
            spindle_exponents: vec![],
            asymmetric: false,
            max_spindle_terms: 0,
        };
        let mut start = vec![
            Spec::symmetric(Src::Sensor(0), 1200.0),
            Spec::symmetric(Src::Sensor(2), 7200.0),
        ];
        let score = s.backfit(&mut start).expect("scores");
        let start = Selection {
            specs: start,
            score,
        };
        let m = s.exchange(start.clone(), &pool, 3);
        assert!(
            m.score.rms() < 0.2 * start.score.rms() && m.score.rms() < 0.01,
            "held-out RMS {} from {}: {:?}",
            m.score.rms(),
            start.score.rms(),
            m.specs
        );
        let lag = m
            .specs
            .iter()
            .find(|sp| sp.src == Src::Sensor(0))
            .map(|sp| sp.tau_heat_s);
        assert!(
            lag.is_some_and(|t| (t / tau_lag - 1.0).abs() < 0.1),
            "{:?}",
            m.specs
        );
        assert!(
            m.specs.iter().any(|sp| sp.src == Src::Sensor(1)),
            "{:?}",
            m.specs
        );
    }
}
