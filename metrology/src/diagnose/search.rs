//! Search of a candidate effect's non-linear parameter and its uncertainty.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::Options;
use super::family::Family;
use super::fit::{Obs, Projector, dotw, heldout_rms, in_sample_residuals};
use super::outliers::{flag_outliers, weights};

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
    obs: &Obs,
    p: &Projector,
    y_perp: &[f64],
    fam: Family,
    theta: f64,
) -> f64 {
    let cols = fam.columns(obs, theta);
    let cp: Vec<Vec<f64>> = cols.iter().map(|c| p.residualize(obs, c)).collect();
    let k = cp.len();
    let mut a = DMatrix::zeros(k, k);
    let mut b = DVector::zeros(k);
    for i in 0..k {
        b[i] = dotw(&cp[i], y_perp, &p.w);
        for j in i..k {
            let v = dotw(&cp[i], &cp[j], &p.w);
            a[(i, j)] = v;
            a[(j, i)] = v;
        }
    }
    let y2 = dotw(y_perp, y_perp, &p.w);
    match a.clone().cholesky() {
        Some(ch) => {
            let x = ch.solve(&b);
            (y2 - b.dot(&x)).max(0.0)
        }
        None => y2,
    }
}

pub(super) fn search(obs: &Obs, p: &Projector, y_perp: &[f64], fam: Family) -> Option<Candidate> {
    let grid = fam.grid(obs);
    if grid.is_empty() {
        return None;
    }
    let rss: Vec<f64> = grid
        .par_iter()
        .map(|&th| candidate_rss(obs, p, y_perp, fam, th))
        .collect();
    let (mut best_k, mut best) = (0, f64::INFINITY);
    for (k, r) in rss.iter().enumerate() {
        if *r < best {
            best = *r;
            best_k = k;
        }
    }
    let mut theta = grid[best_k];
    if grid.len() > 2 {
        // Refine between the neighbours of the best grid point.
        let lo = grid[best_k.saturating_sub(1)];
        let hi = grid[(best_k + 1).min(grid.len() - 1)];
        for s in 0..=24 {
            let th = lo + (hi - lo) * s as f64 / 24.0;
            let r = candidate_rss(obs, p, y_perp, fam, th);
            if r < best {
                best = r;
                theta = th;
            }
        }
    }
    Some(Candidate { theta, rss: best })
}

/// Uncertainty of a grid-searched parameter from the curvature of the RSS profile:
/// u² = 2σ² / RSS''(θ).
pub(super) fn theta_uncertainty(
    obs: &Obs,
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

/// Forward selection of mean effects (module docs): at each step the candidate with the
/// lowest BIC is added if it beats [`Options::min_bic_gain`] and lowers the held-out error.
/// `out` holds the outlier flags and is refined after each step.
pub(super) fn forward_select(
    obs: &Obs,
    opt: &Options,
    use_temp: bool,
    out: &mut Vec<bool>,
) -> Vec<Step> {
    let n = obs.len();
    let ln_n = (n as f64).ln();
    let m = obs.n_targets;
    let var_factor = vec![1.0; m];
    let mut selected: Vec<Selected> = Vec::new();
    let mut steps: Vec<Step> = Vec::new();
    loop {
        let w = weights(obs, out, &var_factor);
        let n_eff = w.iter().filter(|w| **w > 0.0).count() as f64;
        let cols = all_cols(&selected);
        let p = Projector::new(obs, &w, &cols);
        let y_perp = p.residualize(obs, &obs.y);
        let rss0 = dotw(&y_perp, &y_perp, &w);
        if rss0 <= 0.0 {
            break;
        }
        let mut best: Option<(Family, Candidate, f64)> = None;
        let mut fams = vec![Family::Linear, Family::Warmup, Family::Cyclic];
        if obs.x_mm.iter().any(|x| (x - obs.x_mm[0]).abs() > 1e-9) {
            fams.push(Family::Thermal);
            if use_temp {
                fams.push(Family::ThermalTemp);
            }
        }
        let mut temp_rss = None;
        for fam in fams {
            if selected.iter().any(|s| s.family.slot() == fam.slot()) {
                continue;
            }
            let Some(c) = search(obs, &p, &y_perp, fam) else {
                continue;
            };
            if fam == Family::ThermalTemp {
                temp_rss = Some(c.rss);
            }
            let dbic = n_eff * (c.rss / rss0).ln() + fam.n_params() as f64 * ln_n;
            if best.as_ref().is_none_or(|b| dbic < b.2) {
                best = Some((fam, c, dbic));
            }
        }
        let Some((fam, cand, dbic)) = best else { break };
        if -dbic < opt.min_bic_gain {
            break;
        }
        let new = Selected {
            family: fam,
            theta: cand.theta,
            cols: fam.columns(obs, cand.theta),
        };
        let mut cols_after = cols.clone();
        cols_after.extend(new.cols.iter().cloned());
        let eval: Vec<bool> = out.iter().map(|o| !o).collect();
        let before = heldout_rms(obs, &w, &cols, &eval);
        let after = heldout_rms(obs, &w, &cols_after, &eval);
        if after >= before {
            break;
        }
        let s2 = cand.rss / (n_eff - (obs.n_groups + cols_after.len()) as f64).max(1.0);
        let u_theta = theta_uncertainty(obs, &p, &y_perp, fam, &cand, s2);
        // A temperature-driven scale change reported as such when the temperatures explain
        // it at least as well as the time-constant form.
        let alpha_temp = fam == Family::Thermal && temp_rss.is_some_and(|t| t <= cand.rss * 1.05);
        steps.push(Step {
            sel: new.clone(),
            significance: -dbic,
            u_theta,
            before_cols: cols,
            alpha_temp,
        });
        selected.push(new);
        // Re-flag outliers against the richer model.
        let (_, r) =
            in_sample_residuals(obs, &weights(obs, out, &var_factor), &all_cols(&selected));
        *out = flag_outliers(obs, &r, opt.outlier_alpha, m);
    }
    steps
}
