//! Search of a candidate effect's non-linear parameter and its uncertainty, and the forward
//! selection of effects.

#![allow(clippy::needless_range_loop)]

use nalgebra::DVector;
use rayon::prelude::*;

use super::correlation::design_lag1;
use super::family::{Family, aliases_structure};
use super::fit::{heldout_rms, in_sample_residuals};
use super::outliers::{flag_outliers, weights};
use super::projector::{Projector, dotw};
use super::run::Run;
use super::sums::DenseSearch;
use super::types::Options;

#[derive(Debug, Clone)]
pub(super) struct Selected {
    pub(super) family: Family,
    pub(super) theta: f64,
    pub(super) cols: Vec<Vec<f64>>,
}

pub(super) struct Candidate {
    pub(super) theta: f64,
    pub(super) rss: f64,
}

/// RSS of y on baseline + `base` columns + the family's columns at θ.
pub(super) fn candidate_rss(
    obs: &Run,
    p: &Projector,
    y_perp: &[f64],
    fam: Family,
    theta: f64,
) -> f64 {
    if fam.is_searched_dense() {
        DenseSearch::new(obs, &obs.cache, p, y_perp).rss(fam, theta)
    } else {
        cols_rss(obs, p, y_perp, &fam.columns(obs, theta))
    }
}

/// RSS of y on baseline + `p`'s columns + `cols`.
pub(super) fn cols_rss(obs: &Run, p: &Projector, y_perp: &[f64], cols: &[Vec<f64>]) -> f64 {
    cols_fit(obs, p, y_perp, cols).0
}

/// RSS of y on baseline + `p`'s columns + `cols`, and the coefficients of `cols` (None when
/// they are collinear).
pub(super) fn cols_fit(
    obs: &Run,
    p: &Projector,
    y_perp: &[f64],
    cols: &[Vec<f64>],
) -> (f64, Option<DVector<f64>>) {
    p.fit_cols(obs, y_perp, cols)
}

/// What not knowing a searched parameter exactly adds to the uncertainties: the parameter
/// averaged over its plausible values with weights exp(−(RSS − RSS_min)/2σ²) (the likelihood
/// with a flat prior over the points tried), and the spread of the linear coefficients over
/// them. A step's moment can be one reading either way, and its size changes with it; the
/// uncertainty at the best moment alone misses that.
pub(super) struct Spread {
    /// Standard deviation of the parameter over the weights.
    pub(super) u_theta: f64,
    /// Variance of each linear coefficient over the weights.
    pub(super) coef_var: Vec<f64>,
}

/// A parameter value tried, the RSS there and the linear coefficients.
type TriedPoint = (f64, f64, DVector<f64>);

/// What [`theta_spread`] fits at a batch of parameter values: the RSS and the effect's linear
/// coefficients at each (None where they cannot be fitted).
pub(super) type FitAll<'a> = dyn Fn(&[f64]) -> Vec<Option<(f64, DVector<f64>)>> + Sync + 'a;

/// Most parameter values [`theta_spread`] hands its fit at once (a step's spread tries every
/// reading; each value holds a model's columns).
const SPREAD_BATCH: usize = 64;

/// [`Spread`] of `fam` at `theta`: over its own grid for a step (every reading), over ±4
/// curvature uncertainties (`u_theta`) around `theta` otherwise. `fit_all(ts)` is the RSS and
/// the effect's linear coefficients with its parameter at each of `ts` (the rest of the model
/// refitted as the caller decides).
pub(super) fn theta_spread(
    obs: &Run,
    fit_all: &FitAll,
    fam: Family,
    theta: f64,
    u_theta: Option<f64>,
    s2: f64,
) -> Option<Spread> {
    let points: Vec<f64> = match (fam, u_theta) {
        (Family::Step, _) => fam.grid(obs),
        (_, Some(u)) if theta.is_finite() && u > 0.0 => (-16..=16)
            .map(|k| theta + u * k as f64 / 4.0)
            .filter(|t| *t > 0.0)
            .collect(),
        _ => return None,
    };
    let fits: Vec<TriedPoint> = points
        .chunks(SPREAD_BATCH)
        .flat_map(|ts| {
            ts.iter()
                .zip(fit_all(ts))
                .filter_map(|(&t, f)| f.map(|(rss, x)| (t, rss, x)))
                .collect::<Vec<_>>()
        })
        .collect();
    let rss_min = fits.iter().map(|f| f.1).fold(f64::INFINITY, f64::min);
    if !(rss_min.is_finite() && s2 > 0.0) {
        return None;
    }
    let w: Vec<f64> = fits
        .iter()
        .map(|f| (-(f.1 - rss_min) / (2.0 * s2)).exp())
        .collect();
    let sw: f64 = w.iter().sum();
    let mean = |v: &dyn Fn(&TriedPoint) -> f64| {
        fits.iter().zip(&w).map(|(f, w)| w * v(f)).sum::<f64>() / sw
    };
    let var = |v: &dyn Fn(&TriedPoint) -> f64| {
        let m = mean(v);
        mean(&|f| (v(f) - m).powi(2))
    };
    let k = fits.first()?.2.len();
    Some(Spread {
        u_theta: var(&|f| f.0).sqrt(),
        coef_var: (0..k).map(|i| var(&|f| f.2[i])).collect(),
    })
}

/// Two effects can explain together what neither explains alone (a step and a drift look like
/// offsets per cycle): when the best pair, each at the parameter of its own search, beats the
/// best single candidate by more than `margin`, its better member is tried first (the other
/// follows at the next step).
fn prefer_pair(
    obs: &Run,
    p: &Projector,
    y_perp: &[f64],
    rss0: f64,
    cands: &mut [(Family, Candidate, f64)],
    margin: f64,
) {
    let Some(best_single) = cands.first().map(|c| c.2) else {
        return;
    };
    let n_eff = p.w.iter().filter(|w| **w > 0.0).count() as f64;
    let ln_n = (obs.len() as f64).ln();
    let mut best: Option<(usize, f64)> = None;
    for a in 0..cands.len() {
        for b in a + 1..cands.len() {
            let (fa, fb) = (cands[a].0, cands[b].0);
            if fa.kind() == fb.kind() {
                continue;
            }
            let mut cols = fa.columns(obs, cands[a].1.theta);
            cols.extend(fb.columns(obs, cands[b].1.theta));
            let rss = cols_rss(obs, p, y_perp, &cols);
            if rss <= 0.0 {
                continue;
            }
            let dbic =
                n_eff * (rss / rss0).ln() + (fa.n_params(obs) + fb.n_params(obs)) as f64 * ln_n;
            // `a` < `b` in BIC order: `a` is the better member.
            if b > 0 && best.is_none_or(|x| dbic < x.1) {
                best = Some((a, dbic));
            }
        }
    }
    if let Some((a, dbic)) = best
        && a > 0
        && dbic < best_single - margin
    {
        cands[..=a].rotate_right(1);
    }
}

/// The best value of `fam`'s parameter: the lowest RSS over its grid, refined between the
/// grid points either side of the best one.
pub(super) fn search(obs: &Run, p: &Projector, y_perp: &[f64], fam: Family) -> Option<Candidate> {
    search_many(obs, &[(p, y_perp)], fam).pop().flatten()
}

/// [`search`] for several fits (a projector and its y⊥) at once: the grid's values are
/// visited once for all of them, so that a period's columns are read from memory once, not
/// once per fit (a parameter's spread searches another effect beside 33 values of it).
pub(super) fn search_many(
    obs: &Run,
    fits: &[(&Projector, &[f64])],
    fam: Family,
) -> Vec<Option<Candidate>> {
    let grid = fam.grid(obs);
    if grid.is_empty() {
        return fits.iter().map(|_| None).collect();
    }
    if fam.is_searched_dense() {
        if fam == Family::Cyclic {
            obs.cache.fill_cyclic_grid(obs);
        }
        let ds: Vec<DenseSearch> = fits
            .iter()
            .map(|(p, y)| DenseSearch::new(obs, &obs.cache, p, y))
            .collect();
        let table: Vec<Vec<f64>> = grid
            .par_iter()
            .map(|&th| ds.iter().map(|d| d.rss(fam, th)).collect())
            .collect();
        return ds
            .iter()
            .enumerate()
            .map(|(k, d)| {
                let rss: Vec<f64> = table.iter().map(|r| r[k]).collect();
                let best = refine_best(&grid, &rss, true, |th| d.rss(fam, th));
                // What fits best at a period tied to the run's structure is that structure
                // (the baseline absorbs it, or a pattern per target mimics it); a period just
                // beside it would only be its leakage: no cycle is proposed.
                (fam != Family::Cyclic || !aliases_structure(obs, best.theta)).then_some(best)
            })
            .collect();
    }
    fits.iter()
        .map(|&(p, y_perp)| {
            let eval = |th: f64| candidate_rss(obs, p, y_perp, fam, th);
            let rss: Vec<f64> = if fam == Family::Step {
                p.step_rss(obs, y_perp, &grid)
            } else {
                grid.iter().map(|&th| eval(th)).collect()
            };
            // A step from any time up to the last grid time is the step at the next grid
            // time (the grid holds every reading time in between): its RSS is the grid's.
            let rss_at = |th: f64| match grid.partition_point(|g| *g < th) {
                i if fam == Family::Step && i < grid.len() => rss[i],
                _ => eval(th),
            };
            Some(refine_best(&grid, &rss, fam != Family::Step, rss_at))
        })
        .collect()
}

/// The grid value of the lowest RSS (`rss` on `grid`), refined between the grid values
/// either side of it (`eval` the RSS at any value): the best of 25 values there, then, for a
/// `smooth` RSS profile, the minimum between that value's neighbours by golden-section search
/// (the 25 values alone leave a period as coarse as its own uncertainty on a long run).
fn refine_best(grid: &[f64], rss: &[f64], smooth: bool, eval: impl Fn(f64) -> f64) -> Candidate {
    let (mut best_k, mut best) = (0, f64::INFINITY);
    for (k, r) in rss.iter().enumerate() {
        if *r < best {
            best = *r;
            best_k = k;
        }
    }
    let mut theta = grid[best_k];
    if grid.len() > 2 {
        let lo = grid[best_k.saturating_sub(1)];
        let hi = grid[(best_k + 1).min(grid.len() - 1)];
        let step = (hi - lo) / 24.0;
        for s in 0..=24 {
            let th = lo + step * s as f64;
            let r = eval(th);
            if r < best {
                best = r;
                theta = th;
            }
        }
        if smooth && step.abs() > 0.0 {
            let (th, r) = golden_min(theta - step, theta + step, &eval);
            if r < best {
                best = r;
                theta = th;
            }
        }
    }
    Candidate { theta, rss: best }
}

/// The minimum of `f` between `a` and `b` by golden-section search, and the value there: 12
/// steps shrink the interval to 0.3 % (between a grid value's neighbours after the scan, that
/// is 1/2000 of a grid spacing, far below a parameter's uncertainty).
fn golden_min(mut a: f64, mut b: f64, f: &impl Fn(f64) -> f64) -> (f64, f64) {
    let g = (5.0_f64.sqrt() - 1.0) / 2.0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    for _ in 0..12 {
        if fc < fd {
            (b, d, fd) = (d, c, fc);
            c = b - g * (b - a);
            fc = f(c);
        } else {
            (a, c, fc) = (c, d, fd);
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    if fc < fd { (c, fc) } else { (d, fd) }
}

/// Uncertainty of a grid-searched parameter from the curvature of the RSS profile:
/// u² = 2σ² / RSS''(θ).
pub(super) fn theta_uncertainty(
    obs: &Run,
    p: &Projector,
    y_perp: &[f64],
    fam: Family,
    c: &Candidate,
    s2: f64,
) -> Option<f64> {
    if !c.theta.is_finite() {
        return None;
    }
    let h = c.theta * 0.01;
    let r_lo = candidate_rss(obs, p, y_perp, fam, c.theta - h);
    let r_hi = candidate_rss(obs, p, y_perp, fam, c.theta + h);
    let curv = (r_lo - 2.0 * c.rss + r_hi) / (h * h);
    (curv > 0.0).then(|| (2.0 * s2 / curv).sqrt())
}

pub(super) fn all_cols(sel: &[Selected]) -> Vec<Vec<f64>> {
    sel.iter().flat_map(|s| s.cols.iter().cloned()).collect()
}

/// One effect added by the forward selection.
pub(super) struct Step {
    pub(super) sel: Selected,
    /// BIC decrease when it was added.
    pub(super) significance: f64,
    /// Uncertainty of the non-linear parameter, when the RSS profile has one.
    pub(super) u_theta: Option<f64>,
    /// Columns of the model before it was added.
    pub(super) before_cols: Vec<Vec<f64>>,
    /// A thermal expansion the measured material temperature explains as well.
    pub(super) alpha_temp: bool,
}

/// Forward selection of mean effects (module docs): at each step the candidates are tried in
/// order of their BIC; the first that beats [`Options::min_bic_gain`] once its evidence is
/// discounted for correlated noise, is not absorbed by the baseline and lowers the held-out
/// error is added. `out` holds the outlier flags and is refined after each step.
pub(super) fn forward_select(
    obs: &Run,
    opt: &Options,
    use_temp: bool,
    out: &mut Vec<bool>,
    notes: &mut Vec<String>,
) -> Vec<Step> {
    let m = obs.n_targets;
    let var_factor = vec![1.0; m];
    let mut selected: Vec<Selected> = Vec::new();
    let mut steps: Vec<Step> = Vec::new();
    loop {
        let w = weights(obs, out, &var_factor);
        let cols = all_cols(&selected);
        let p = Projector::new(obs, &w, &cols);
        let y_perp = p.residualize(obs, &obs.y);
        let rss0 = dotw(&y_perp, &y_perp, &w);
        if rss0 <= 0.0 {
            break;
        }
        let mut cands = candidates(obs, &p, &y_perp, rss0, use_temp, &selected);
        cands.sort_by(|a, b| a.2.total_cmp(&b.2));
        prefer_pair(obs, &p, &y_perp, rss0, &mut cands, opt.min_bic_gain);
        let temp_rss = cands
            .iter()
            .find(|c| c.0 == Family::ThermalTemp)
            .map(|c| c.1.rss);
        let partners: Vec<(Family, f64)> = cands.iter().map(|c| (c.0, c.1.theta)).collect();
        let mut added = None;
        for (fam, cand, _) in cands {
            // Short of the threshold whatever the noise's correlation (the discount is at most
            // 1): its ρ, and the partner that ρ is also read with, need not be computed.
            if cand.rss > 0.0
                && (0..2)
                    .map(|k| gain_at(obs, &w, rss0, &cand, fam, 0.95 * k as f64))
                    .fold(f64::NEG_INFINITY, f64::max)
                    < opt.min_bic_gain
            {
                continue;
            }
            let new = Selected {
                family: fam,
                theta: cand.theta,
                cols: fam.columns(obs, cand.theta),
            };
            let mut cols_after = cols.clone();
            cols_after.extend(new.cols.iter().cloned());
            // The residual correlation is read after this effect and, where another candidate
            // explains what is left (two effects at once), after both: structure of a second
            // effect is not correlated noise. The partner is the candidate that best explains
            // the data together with this one (the lowest BIC of the pair), not the best one
            // alone: a flexible effect (an offset per cycle) can rank high alone by absorbing
            // part of two effects, yet leave the structure of either as "correlation".
            let partner =
                best_partner(obs, &p, &y_perp, rss0, fam, &new.cols, &partners).map(|pf| {
                    let mut c = cols_after.clone();
                    c.extend(partner_given(obs, &w, &cols_after, pf));
                    c
                });
            let Some(significance) =
                discounted_gain(obs, &w, &cols_after, partner.as_deref(), rss0, &cand, fam)
            else {
                continue;
            };
            if significance < opt.min_bic_gain {
                continue;
            }
            // A scale change varies with position by definition: its spread over the targets
            // is not a sign of the baseline absorbing it.
            let by_position = matches!(fam, Family::Thermal | Family::ThermalTemp);
            if !by_position && absorbed_by_baseline(obs, &p, &new.cols) {
                let note = format!(
                    "{} would fit, but the per-target, per-direction baseline absorbs most of \
                     it (each target is measured over a short part of the run, or the pattern \
                     follows the run's own order of targets): the data cannot tell it from the \
                     baseline, so it is not reported",
                    fam.kind()
                );
                if !notes.contains(&note) {
                    notes.push(note);
                }
                continue;
            }
            let eval: Vec<bool> = out.iter().map(|o| !o).collect();
            // An offset per cycle cannot be predicted for a cycle held out whole.
            let ho = if fam == Family::CycleOffsets {
                obs.diagonal()
            } else {
                obs
            };
            if heldout_rms(ho, &w, &cols_after, &eval) >= heldout_rms(ho, &w, &cols, &eval) {
                continue;
            }
            let n_eff = w.iter().filter(|w| **w > 0.0).count() as f64;
            let s2 = cand.rss / (n_eff - (obs.n_groups + cols_after.len()) as f64).max(1.0);
            let u_theta = theta_uncertainty(obs, &p, &y_perp, fam, &cand, s2);
            // A temperature-driven scale change reported as such when the temperatures
            // explain it at least as well as the time-constant form.
            let alpha_temp =
                fam == Family::Thermal && temp_rss.is_some_and(|t| t <= cand.rss * 1.05);
            added = Some(Step {
                sel: new,
                significance,
                u_theta,
                before_cols: cols.clone(),
                alpha_temp,
            });
            break;
        }
        let Some(step) = added else { break };
        selected.push(step.sel.clone());
        steps.push(step);
        // Re-flag outliers against the richer model.
        let (_, r) =
            in_sample_residuals(obs, &weights(obs, out, &var_factor), &all_cols(&selected));
        *out = flag_outliers(obs, &r, opt.outlier_alpha, m);
    }
    steps
}

/// Columns of the candidate of another slot, not absorbed by the baseline, that, fitted
/// together with `fam`'s `cols`, gives the lowest BIC (each at the parameter of its own
/// search).
fn best_partner(
    obs: &Run,
    p: &Projector,
    y_perp: &[f64],
    rss0: f64,
    fam: Family,
    cols: &[Vec<f64>],
    partners: &[(Family, f64)],
) -> Option<(Family, f64)> {
    let n_eff = p.w.iter().filter(|w| **w > 0.0).count() as f64;
    let ln_n = (obs.len() as f64).ln();
    partners
        .iter()
        // Offsets per cycle (one per cycle) whiten correlated noise as well as they explain a
        // second effect: they are no partner (1000 correlated-noise runs naming an effect:
        // 2.9 → 2.2 %, two-effect classes unchanged).
        .filter(|(f, _)| f.kind() != fam.kind() && *f != Family::CycleOffsets)
        .filter_map(|&(f, th)| {
            let pc = f.columns(obs, th);
            // Only an effect the data can report is credited with the structure it explains:
            // one the baseline absorbs (tested as for the candidates) is no partner.
            let by_position = matches!(f, Family::Thermal | Family::ThermalTemp);
            if !by_position && absorbed_by_baseline(obs, p, &pc) {
                return None;
            }
            let mut both = cols.to_vec();
            both.extend(pc.iter().cloned());
            let rss = cols_rss(obs, p, y_perp, &both);
            (rss > 0.0).then(|| {
                let dbic =
                    n_eff * (rss / rss0).ln() + (fam.n_params(obs) + f.n_params(obs)) as f64 * ln_n;
                ((f, th), dbic)
            })
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|x| x.0)
}

/// The partner's columns with its parameter searched again beside the candidate (`cols`):
/// searched alone, a partner's parameter (a τ, a period) bends to take part of the
/// candidate's structure, and what the pair leaves then looks correlated.
fn partner_given(obs: &Run, w: &[f64], cols: &[Vec<f64>], pf: (Family, f64)) -> Vec<Vec<f64>> {
    let (f, th) = pf;
    let p = Projector::new(obs, w, cols);
    let y = p.residualize(obs, &obs.y);
    let th = search(obs, &p, &y, f).map_or(th, |c| c.theta);
    f.columns(obs, th)
}

/// Every family not yet selected, searched, with its BIC change.
fn candidates(
    obs: &Run,
    p: &Projector,
    y_perp: &[f64],
    rss0: f64,
    use_temp: bool,
    selected: &[Selected],
) -> Vec<(Family, Candidate, f64)> {
    let ln_n = (obs.len() as f64).ln();
    let n_eff = p.w.iter().filter(|w| **w > 0.0).count() as f64;
    families(obs, use_temp)
        .into_iter()
        .filter(|f| selected.iter().all(|s| s.family.kind() != f.kind()))
        .filter_map(|fam| {
            let c = search(obs, p, y_perp, fam)?;
            let dbic = n_eff * (c.rss / rss0).ln() + fam.n_params(obs) as f64 * ln_n;
            Some((fam, c, dbic))
        })
        .collect()
}

/// The mean effects the run can show: a scale change only when the positions vary, its
/// temperature form only with material temperatures.
pub(super) fn families(obs: &Run, use_temp: bool) -> Vec<Family> {
    let mut fams = vec![
        Family::Linear,
        Family::Warmup,
        Family::Cyclic,
        Family::Step,
        Family::ReversalDrift,
        Family::CycleOffsets,
    ];
    if obs.x_mm.iter().any(|x| (x - obs.x_mm[0]).abs() > 1e-9) {
        fams.push(Family::Thermal);
        if use_temp {
            fams.push(Family::ThermalTemp);
        }
    }
    fams
}

/// The BIC gain of a candidate with its likelihood-ratio part discounted for correlated
/// noise: with a lag-1 correlation ρ of what is left, consecutive readings carry about
/// (1 − ρ)/(1 + ρ) of the information of independent ones (air turbulence, `docs/methods.md`).
fn discounted_gain(
    obs: &Run,
    w: &[f64],
    cols_after: &[Vec<f64>],
    with_partner: Option<&[Vec<f64>]>,
    rss0: f64,
    cand: &Candidate,
    fam: Family,
) -> Option<f64> {
    if cand.rss <= 0.0 {
        return None;
    }
    let (_, r) = in_sample_residuals(obs, w, cols_after);
    let mut rho = design_lag1(obs, w, cols_after, &r);
    if let Some(cols) = with_partner {
        let (_, r2) = in_sample_residuals(obs, w, cols);
        rho = rho.min(design_lag1(obs, w, cols, &r2));
    }
    Some(gain_at(obs, w, rss0, cand, fam, rho.clamp(0.0, 0.95)))
}

/// The BIC gain of a candidate with a lag-1 correlation `rho` of the noise (in [0, 0.95]; the
/// most it can be is at one end).
fn gain_at(obs: &Run, w: &[f64], rss0: f64, cand: &Candidate, fam: Family, rho: f64) -> f64 {
    let n_eff = w.iter().filter(|w| **w > 0.0).count() as f64;
    let lr = n_eff * (rss0 / cand.rss).ln();
    lr * (1.0 - rho) / (1.0 + rho) - fam.n_params(obs) as f64 * (obs.len() as f64).ln()
}

/// An effect the per-target, per-direction constants mostly absorb: less than 30 % of its
/// columns' variation within each direction is left once they are centred within their
/// (target, direction) groups (the reference is per direction, so that an effect that differs
/// by direction by definition, like `reversal_drift`, is measured on its variation in time).
pub(super) fn absorbed_by_baseline(obs: &Run, p: &Projector, cols: &[Vec<f64>]) -> bool {
    let (mut kept, mut total) = (0.0, 0.0);
    for c in cols {
        let (mut s, mut n) = ([0.0; 2], [0.0; 2]);
        for j in 0..obs.len() {
            let d = usize::from(obs.dir_half[j] < 0.0);
            s[d] += p.w[j] * c[j];
            n[d] += p.w[j];
        }
        for j in 0..obs.len() {
            let d = usize::from(obs.dir_half[j] < 0.0);
            let m = if n[d] > 0.0 { s[d] / n[d] } else { 0.0 };
            total += p.w[j] * (c[j] - m).powi(2);
        }
        let cc = p.center(obs, c);
        kept += dotw(&cc, &cc, &p.w);
    }
    total > 0.0 && kept < 0.3 * total
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a grid as coarse as the parameter's uncertainty, the 25 values between the best
    /// one's neighbours leave the minimum up to 1/24 of a spacing off; the golden-section
    /// search finds it, and a profile that is not smooth (a step's) keeps the scan's value.
    #[test]
    fn a_smooth_profile_is_refined_to_its_minimum() {
        let grid: Vec<f64> = (0..10).map(f64::from).collect();
        let f = |x: f64| 1.0 + (x - 4.0137).powi(2);
        let rss: Vec<f64> = grid.iter().map(|&x| f(x)).collect();
        let c = refine_best(&grid, &rss, true, f);
        assert!((c.theta - 4.0137).abs() < 2e-3, "{}", c.theta);
        assert!((c.rss - 1.0).abs() < 4e-6);
        let coarse = refine_best(&grid, &rss, false, f);
        assert!((coarse.theta - 4.0).abs() < 1e-12, "{}", coarse.theta);
        let (x, fx) = golden_min(-3.0, 2.0, &|x: f64| (x + 1.25).powi(2));
        assert!((x + 1.25).abs() < 0.02 && fx < 4e-4, "{x} {fx}");
    }
}
