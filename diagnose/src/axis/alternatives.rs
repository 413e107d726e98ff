//! Which other effect of the vocabulary would explain a run about as well as a selected one.
//!
//! The forward selection names the effect with the lowest BIC, but a short run often cannot
//! tell effects over time apart: on 5 cycles a warm-up with a long time constant is nearly a
//! straight line, and a step or a drift looks like offsets per cycle. For each selected effect
//! every other effect is put in its place (the rest of the model kept, its parameter searched
//! afresh); one that would itself be reported (the same evidence threshold, not absorbed by the
//! baseline, a held-out gain) and whose BIC is within [`MARGIN`] of the selected one is a
//! rival: the report names it, with its parameters, and says the data cannot tell them apart.
//! A rival with more parameters must come within [`MARGIN_RICHER`]: one whose better fit only
//! pays for its extra parameters shows no more than that they are not supported.

use positioning::axis_model::EffectKind;

use super::correlation::design_lag1;
use super::family::Family;
use super::fit::{FinalFit, heldout_rms};
use super::projector::{Projector, dotw};
use super::run::Run;
use super::search::{
    Selected, Step, absorbed_by_baseline, cols_rss, families, search, theta_uncertainty,
};
use super::types::Options;

/// BIC difference below which two effects are not told apart: under 6 is at most "positive"
/// evidence on the Kass–Raftery scale, short of "strong".
pub(super) const MARGIN: f64 = 6.0;

/// The same for a rival with more parameters than the selected effect: under 2 is "not worth
/// more than a bare mention" for the simpler one, i.e. the richer one's better fit has some
/// support beyond what its extra parameters cost.
pub(super) const MARGIN_RICHER: f64 = 2.0;

/// An effect that explains the run about as well as a selected one, in its place.
pub(super) struct Rival {
    /// The rival as a step of a model holding the other selected effects.
    pub(super) step: Step,
    /// Its BIC minus the selected effect's (negative: the rival fits slightly better).
    pub(super) delta_bic: f64,
}

/// The rivals of each selected step (same order as `steps`).
pub(super) fn rivals(
    obs: &Run,
    opt: &Options,
    use_temp: bool,
    steps: &[Step],
    fin: &FinalFit,
) -> Vec<Vec<Rival>> {
    let ctx = Context::new(obs, opt, fin);
    (0..steps.len())
        .map(|i| {
            families(obs, use_temp)
                .into_iter()
                .filter(|g| steps.iter().all(|s| s.sel.family.kind() != g.kind()))
                .filter_map(|g| ctx.in_place(steps, i, g))
                .filter(|r| {
                    let richer =
                        r.step.sel.family.n_params(obs) > steps[i].sel.family.n_params(obs);
                    r.delta_bic < if richer { MARGIN_RICHER } else { MARGIN }
                })
                .collect()
        })
        .collect()
}

/// BIC decrease a replacement must bring in [`refine`].
const REFINE_MIN: f64 = 2.0;

/// Backfitting after the forward selection: each selected effect is searched afresh with the
/// others in the model (its parameter was found before they were), and replaced by another
/// effect of the vocabulary where that lowers the BIC by more than [`REFINE_MIN`] (a warm-up
/// that the first effect's biased period left looking like a step). Repeated until nothing
/// changes (at most three rounds); `before_cols` are rebuilt in selection order. First, offsets
/// per cycle are split into two smooth effects where those explain the run better
/// ([`Context::split_offsets`]).
pub(super) fn refine(
    obs: &Run,
    opt: &Options,
    use_temp: bool,
    steps: &mut Vec<Step>,
    fin: &FinalFit,
) {
    let ctx = Context::new(obs, opt, fin);
    // Offsets per cycle, and a cycle seen for less than two periods: neither shows more than
    // that the run's mean path bends, which a pair of smooth effects may explain better (a
    // step up and a drift down look like half a cycle).
    let splittable = |s: &Step| match s.sel.family {
        Family::CycleOffsets => true,
        Family::Cyclic => 2.0 * s.sel.theta > obs.duration_s,
        _ => false,
    };
    let order: Vec<usize> = (0..steps.len())
        .filter(|&i| splittable(&steps[i]))
        .collect();
    for i in order {
        let fams: Vec<Family> = families(obs, use_temp)
            .into_iter()
            .filter(|g| *g != Family::CycleOffsets)
            .filter(|g| steps.iter().all(|s| s.sel.family.kind() != g.kind()))
            .collect();
        if let Some([a, b]) = ctx.split_offsets(steps, i, &fams) {
            steps[i] = a;
            steps.insert(i + 1, b);
            break;
        }
    }
    for _ in 0..3 {
        let mut changed = false;
        for i in 0..steps.len() {
            let best = families(obs, use_temp)
                .into_iter()
                .filter(|g| {
                    steps
                        .iter()
                        .enumerate()
                        .all(|(k, s)| k == i || s.sel.family.kind() != g.kind())
                })
                .filter_map(|g| ctx.in_place(steps, i, g))
                .min_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic));
            if let Some(r) = best.filter(|r| r.delta_bic < -REFINE_MIN) {
                steps[i].sel = r.step.sel;
                steps[i].u_theta = r.step.u_theta;
                steps[i].significance = r.step.significance;
                steps[i].alpha_temp = false;
                changed = true;
            } else if let Some(j) = ctx.best_joint(steps, i, use_temp) {
                for (k, s) in j.others {
                    steps[k].sel = s.sel;
                    steps[k].u_theta = s.u_theta;
                    steps[k].significance = s.significance;
                    steps[k].alpha_temp = false;
                }
                steps[i].sel = j.step.sel;
                steps[i].u_theta = j.step.u_theta;
                steps[i].significance = j.step.significance;
                steps[i].alpha_temp = false;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let mut before = Vec::new();
    for s in steps.iter_mut() {
        s.before_cols = before.clone();
        before.extend(s.sel.cols.iter().cloned());
    }
}

/// A replacement of one step with the others refitted around it ([`Context::joint_in_place`]).
struct Joint {
    step: Step,
    /// The other steps as refitted, by index.
    others: Vec<(usize, Step)>,
    /// BIC of the whole model with the replacement minus without.
    delta_bic: f64,
}

struct Context<'a> {
    obs: &'a Run,
    opt: &'a Options,
    fin: &'a FinalFit,
    /// Share of the likelihood ratio counted with correlated noise ((1 − ρ)/(1 + ρ)).
    discount: f64,
    n_eff: f64,
    ln_n: f64,
}

impl<'a> Context<'a> {
    fn new(obs: &'a Run, opt: &'a Options, fin: &'a FinalFit) -> Self {
        let rho = design_lag1(obs, &fin.w, &fin.cols, &fin.resid).clamp(0.0, 0.95);
        Context {
            obs,
            opt,
            fin,
            discount: (1.0 - rho) / (1.0 + rho),
            n_eff: fin.w.iter().filter(|w| **w > 0.0).count() as f64,
            ln_n: (obs.len() as f64).ln(),
        }
    }

    /// `g` in place of step `i`, its parameter searched with the others in the model, when
    /// it would be reported there (the evidence threshold, not absorbed by the baseline, a
    /// held-out gain).
    fn in_place(&self, steps: &[Step], i: usize, g: Family) -> Option<Rival> {
        let others = cols_except(steps, &[i]);
        let sel = &steps[i].sel;
        let (step, rss) = self.fit_in(&others, g)?;
        let p = Projector::new(self.obs, &self.fin.w, &others);
        let y_perp = p.residualize(self.obs, &self.obs.y);
        let rss_sel = cols_rss(self.obs, &p, &y_perp, &sel.cols);
        if rss_sel <= 0.0 {
            return None;
        }
        let delta_bic = self.discount * self.n_eff * (rss / rss_sel).ln()
            + (g.n_params(self.obs) as f64 - sel.family.n_params(self.obs) as f64) * self.ln_n;
        Some(Rival { step, delta_bic })
    }

    /// The best other effect in place of step `i` with the other steps' parameters searched
    /// again around it ([`Context::joint_in_place`]), when that lowers the BIC of the whole
    /// model by more than [`REFINE_MIN`].
    fn best_joint(&self, steps: &[Step], i: usize, use_temp: bool) -> Option<Joint> {
        families(self.obs, use_temp)
            .into_iter()
            .filter(|g| steps.iter().all(|s| s.sel.family.kind() != g.kind()))
            .filter_map(|g| self.joint_in_place(steps, i, g))
            .filter(|j| j.delta_bic < -REFINE_MIN)
            .min_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic))
    }

    /// `g` in place of step `i`, and each other step's parameter searched again with `g` in
    /// the model (one round of backfitting), then `g`'s once more. The others' parameters
    /// were found with step `i`'s effect in the model: a cycle's period fitted beside a step
    /// can leave a warm-up looking like that step, and the swap alone does not show it.
    fn joint_in_place(&self, steps: &[Step], i: usize, g: Family) -> Option<Joint> {
        let (mut cur, _) = self.fit_in(&cols_except(steps, &[i]), g)?;
        let mut others: Vec<(usize, Step)> = Vec::new();
        for k in (0..steps.len()).filter(|&k| k != i) {
            let mut base: Vec<Vec<f64>> = (0..steps.len())
                .filter(|&q| q != i && q != k)
                .flat_map(|q| {
                    let done = others.iter().find(|(o, _)| *o == q);
                    done.map_or(&steps[q].sel.cols, |(_, s)| &s.sel.cols)
                        .clone()
                })
                .collect();
            base.extend(cur.sel.cols.iter().cloned());
            let (s, _) = self.fit_in(&base, steps[k].sel.family)?;
            others.push((k, s));
        }
        let base: Vec<Vec<f64>> = others
            .iter()
            .flat_map(|(_, s)| s.sel.cols.iter().cloned())
            .collect();
        let rss;
        (cur, rss) = self.fit_in(&base, g)?;
        let all = cols_except(steps, &[]);
        let p = Projector::new(self.obs, &self.fin.w, &all);
        let r = p.residualize(self.obs, &self.obs.y);
        let rss_now = dotw(&r, &r, &self.fin.w);
        if rss_now <= 0.0 || rss <= 0.0 {
            return None;
        }
        let extra = g.n_params(self.obs) as f64 - steps[i].sel.family.n_params(self.obs) as f64;
        let delta_bic = self.discount * self.n_eff * (rss / rss_now).ln() + extra * self.ln_n;
        Some(Joint {
            step: cur,
            others,
            delta_bic,
        })
    }

    /// Two smooth effects in place of the offsets per cycle of step `i` (a step and a drift
    /// together shift each cycle by its own amount), each searched with the other in the model
    /// (one round of backfitting), when both would be reported and together they lower the
    /// BIC by more than [`REFINE_MIN`]: the pair of the lowest BIC.
    fn split_offsets(&self, steps: &[Step], i: usize, fams: &[Family]) -> Option<[Step; 2]> {
        let obs = self.obs;
        let others = cols_except(steps, &[i]);
        let p = Projector::new(obs, &self.fin.w, &others);
        let y_perp = p.residualize(obs, &obs.y);
        let rss_off = cols_rss(obs, &p, &y_perp, &steps[i].sel.cols);
        let p_off = steps[i].sel.family.n_params(obs) as f64;
        let mut best: Option<([Step; 2], f64)> = None;
        for (a, &g1) in fams.iter().enumerate() {
            for &g2 in &fams[a + 1..] {
                // Alone, g1 need not be reportable: a step up and a drift down can cancel.
                let Some(c1) = search(obs, &p, &y_perp, g1) else {
                    continue;
                };
                let s1 = Selected {
                    family: g1,
                    theta: c1.theta,
                    cols: g1.columns(obs, c1.theta),
                };
                let Some((s2, _)) = self.fit_in(&[&others[..], &s1.cols[..]].concat(), g2) else {
                    continue;
                };
                let Some((s1, rss)) = self.fit_in(&[&others[..], &s2.sel.cols[..]].concat(), g1)
                else {
                    continue;
                };
                let k = (g1.n_params(obs) + g2.n_params(obs)) as f64;
                let d = self.discount * self.n_eff * (rss / rss_off).ln() + (k - p_off) * self.ln_n;
                if d < -REFINE_MIN && best.as_ref().is_none_or(|b| d < b.1) {
                    best = Some(([s1, s2], d));
                }
            }
        }
        best.map(|b| b.0)
    }

    /// `g` searched with `base` in the model, when it would be reported there; the step and
    /// the RSS with it.
    fn fit_in(&self, base: &[Vec<f64>], g: Family) -> Option<(Step, f64)> {
        let (obs, fin) = (self.obs, self.fin);
        let p = Projector::new(obs, &fin.w, base);
        let y_perp = p.residualize(obs, &obs.y);
        let rss0 = dotw(&y_perp, &y_perp, &fin.w);
        let c = search(obs, &p, &y_perp, g)?;
        if c.rss <= 0.0 {
            return None;
        }
        let gain =
            self.discount * self.n_eff * (rss0 / c.rss).ln() - g.n_params(obs) as f64 * self.ln_n;
        if gain < self.opt.min_bic_gain {
            return None;
        }
        let cols = g.columns(obs, c.theta);
        let by_position = matches!(g, Family::Thermal | Family::ThermalTemp);
        if !by_position && absorbed_by_baseline(obs, &p, &cols) {
            return None;
        }
        let with = [base, &cols[..]].concat();
        let ho = if g == Family::CycleOffsets {
            obs.diagonal()
        } else {
            obs
        };
        if heldout_rms(ho, &fin.w, &with, &fin.eval) >= heldout_rms(ho, &fin.w, base, &fin.eval) {
            return None;
        }
        let dof = (self.n_eff - (obs.n_groups + with.len()) as f64).max(1.0);
        let u_theta = theta_uncertainty(obs, &p, &y_perp, g, &c, c.rss / dof);
        let step = Step {
            sel: Selected {
                family: g,
                theta: c.theta,
                cols,
            },
            significance: gain,
            u_theta,
            before_cols: base.to_vec(),
            alpha_temp: false,
        };
        Some((step, c.rss))
    }
}

/// The columns of every step but those listed.
pub(super) fn cols_except(steps: &[Step], skip: &[usize]) -> Vec<Vec<f64>> {
    steps
        .iter()
        .enumerate()
        .filter(|(k, _)| !skip.contains(k))
        .flat_map(|(_, s)| s.sel.cols.iter().cloned())
        .collect()
}

/// What would tell two effects over time apart, for the report's sentence.
pub(super) fn tell_apart(a: Option<EffectKind>, b: Option<EffectKind>) -> &'static str {
    use EffectKind::{CycleOffsets, ExponentialWarmup, LinearDrift, Step};
    let pair = |x: EffectKind, y: EffectKind| {
        (a == Some(x) && b == Some(y)) || (a == Some(y) && b == Some(x))
    };
    if pair(ExponentialWarmup, LinearDrift) {
        "a warm-up levels off and a linear drift does not: a longer run, or a temperature record \
         of the axis, shows which"
    } else if pair(Step, CycleOffsets) || pair(LinearDrift, CycleOffsets) {
        "offsets per cycle change from one cycle to the next at random; more cycles, or the \
         machine's log of re-datums and interruptions, show which"
    } else if pair(Step, LinearDrift) || pair(Step, ExponentialWarmup) {
        "a step happens between two readings; the machine's log at that time (a re-datum, a \
         bumped optic) or a repeat of the run shows which"
    } else {
        "a longer run or more cycles would tell them apart"
    }
}
