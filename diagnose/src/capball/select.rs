//! Fitting a set of effects on the identification run, screening candidates against the
//! current model, and the validation-run check (method in the parent module's docs).

use nalgebra::{DMatrix, DVector};

use super::model::{Candidate, CapballRun, Fit, design, lstsq};
use geometry::capball::{CapballSetup, N_PARAMS};
use geometry::capball_effects::{Channel, RotaryAxis};

/// An accepted effect with the combinations of its columns the data can determine
/// (`basis`: n_cols × r; the other combinations are taken up by the model already there).
#[derive(Debug, Clone)]
pub(crate) struct Term {
    pub cand: Candidate,
    pub basis: DMatrix<f64>,
}

impl Term {
    pub(super) fn rank(&self) -> usize {
        self.basis.ncols()
    }
    /// The term's reduced columns for a run, given the current 14 parameters.
    pub(super) fn columns(
        &self,
        setup: &CapballSetup,
        run: &CapballRun,
        p: &DVector<f64>,
    ) -> DMatrix<f64> {
        let model = run.jac(setup) * p;
        self.cand.columns(run, &model) * &self.basis
    }
}

/// A model fitted on the identification run.
#[derive(Debug, Clone)]
pub(crate) struct ModelFit {
    pub terms: Vec<Term>,
    pub fit: Fit,
    /// The 14 parameters.
    pub p: DVector<f64>,
    /// Each term's coefficients in its full column space (`basis · reduced coefficients`) and
    /// their covariance (unscaled), in the same space.
    pub coefs: Vec<(DVector<f64>, DMatrix<f64>)>,
}

impl ModelFit {
    pub(super) fn n_params(&self) -> usize {
        N_PARAMS + self.terms.iter().map(Term::rank).sum::<usize>()
    }
}

/// Fit the 14 parameters with `terms` on the identification run; a sensor gain's column
/// depends on the parameters, so the fit is repeated (Gauss–Newton on the bilinear model).
pub(crate) fn fit_terms(
    setup: &CapballSetup,
    run: &CapballRun,
    keep: &[bool],
    terms: Vec<Term>,
    p_start: &DVector<f64>,
) -> Option<ModelFit> {
    let y = run.rhs();
    let has_gain = terms
        .iter()
        .any(|t| matches!(t.cand, Candidate::SensorGain { .. }));
    let mut p = p_start.clone();
    let mut last = None;
    for _ in 0..if has_gain { 4 } else { 1 } {
        let cols: Vec<DMatrix<f64>> = terms.iter().map(|t| t.columns(setup, run, &p)).collect();
        let a = design(setup, run, &cols);
        let fit = lstsq(&a, &y, keep)?;
        p = fit.coef.rows(0, N_PARAMS).into_owned();
        last = Some(fit);
    }
    let fit = last?;
    let mut coefs = Vec::new();
    let mut c = N_PARAMS;
    for t in &terms {
        let r = t.rank();
        let b = fit.coef.rows(c, r).into_owned();
        let cov = fit.cov_unscaled.view((c, c), (r, r)).into_owned();
        coefs.push((&t.basis * b, &t.basis * cov * t.basis.transpose()));
        c += r;
    }
    Some(ModelFit {
        terms,
        fit,
        p,
        coefs,
    })
}

/// Orthonormal basis of the current model's column space over the kept rows.
pub(crate) fn model_basis(
    setup: &CapballSetup,
    run: &CapballRun,
    mf: &ModelFit,
    keep: &[bool],
) -> DMatrix<f64> {
    let cols: Vec<DMatrix<f64>> = mf
        .terms
        .iter()
        .map(|t| t.columns(setup, run, &mf.p))
        .collect();
    let mut a = design(setup, run, &cols);
    zero_rows(&mut a, keep);
    a.qr().q()
}

pub(crate) fn zero_rows(a: &mut DMatrix<f64>, keep: &[bool]) {
    for (r, k) in keep.iter().enumerate() {
        if !k {
            a.row_mut(r).fill(0.0);
        }
    }
}

/// A candidate screened against the current model: its identifiable basis, the decrease of
/// the residual sum of squares it brings, and its reduced columns projected off the model.
pub(crate) struct Screened {
    pub term: Term,
    pub drss: f64,
}

/// Screen one candidate (Frisch–Waugh–Lovell: project its columns off the model, regress the
/// model's residual on them). `None` when the model takes it up entirely.
pub(crate) fn screen(
    setup: &CapballSetup,
    run: &CapballRun,
    keep: &[bool],
    mf: &ModelFit,
    q: &DMatrix<f64>,
    cand: Candidate,
) -> Option<Screened> {
    let model = run.jac(setup) * &mf.p;
    let mut x = cand.columns(run, &model);
    zero_rows(&mut x, keep);
    let xt = &x - q * (q.transpose() * &x);
    let (basis, _) = identifiable_basis(&x, &xt);
    if basis.ncols() == 0 {
        return None;
    }
    let xr = &xt * &basis;
    let f = lstsq(&xr, &mf.fit.resid, keep)?;
    Some(Screened {
        term: Term { cand, basis },
        drss: mf.fit.rss - f.rss,
    })
}

/// Right singular vectors of the projected columns `xt` whose singular value is not
/// negligible against the raw columns `x`: the combinations the data can tell from the model.
pub(crate) fn identifiable_basis(x: &DMatrix<f64>, xt: &DMatrix<f64>) -> (DMatrix<f64>, usize) {
    let k = x.ncols();
    let scale: DVector<f64> =
        DVector::from_iterator(k, (0..k).map(|c| x.column(c).norm().max(1e-300)));
    let mut xs = xt.clone();
    for c in 0..k {
        xs.column_mut(c).unscale_mut(scale[c]);
    }
    let Some(svd) = geometry::linalg::svd(xs, false, true) else {
        return (DMatrix::zeros(k, 0), k);
    };
    let Some(vt) = svd.v_t else {
        return (DMatrix::zeros(k, 0), k);
    };
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&i| svd.singular_values[i] > 1e-4)
        .collect();
    let mut b = DMatrix::zeros(k, keep.len());
    for (j, &i) in keep.iter().enumerate() {
        for c in 0..k {
            b[(c, j)] = vt[(i, c)] / scale[c];
        }
    }
    (b, k - keep.len())
}

/// RSS of the validation runs under a model, with the time effects (and one offset per
/// channel) fitted again on each run; returns (RSS, equations, refitted parameters, residuals).
pub(crate) fn validate(
    setup: &CapballSetup,
    runs: &[CapballRun],
    keeps: &[Vec<bool>],
    mf: &ModelFit,
) -> (f64, usize, usize, Vec<DVector<f64>>) {
    let (mut rss, mut neq, mut k_refit) = (0.0, 0, 0);
    let mut out = Vec::new();
    for (run, keep) in runs.iter().zip(keeps) {
        let model = run.jac(setup) * &mf.p;
        let mut pred = model.clone();
        let mut time_cols: Vec<DMatrix<f64>> = Vec::new();
        for (t, (b, _)) in mf.terms.iter().zip(&mf.coefs) {
            let x = t.cand.columns(run, &model);
            if t.cand.is_time_effect() {
                time_cols.push(x);
            } else {
                pred += x * b;
            }
        }
        let mut r = run.rhs() - pred;
        if !time_cols.is_empty() {
            let mut offs = DMatrix::zeros(3 * run.len(), 3);
            for i in 0..run.len() {
                for k in 0..3 {
                    offs[(3 * i + k, k)] = 1.0;
                }
            }
            time_cols.push(offs);
            let ncol: usize = time_cols.iter().map(|x| x.ncols()).sum();
            let mut a = DMatrix::zeros(3 * run.len(), ncol);
            let mut c = 0;
            for x in &time_cols {
                a.columns_mut(c, x.ncols()).copy_from(x);
                c += x.ncols();
            }
            if let Some(f) = lstsq(&a, &r, keep) {
                r = f.resid;
                k_refit += ncol;
            }
        }
        for (i, k) in keep.iter().enumerate() {
            if !k {
                r[i] = 0.0;
            }
        }
        rss += r.norm_squared();
        neq += keep.iter().filter(|k| **k).count();
        out.push(r);
    }
    (rss, neq, k_refit, out)
}

/// The candidates to screen against a model that already holds `have`.
pub(crate) fn candidate_list(
    have: &[Candidate],
    periods: &[f64],
    max_harmonic: u32,
) -> Vec<Vec<Candidate>> {
    let has = |f: &dyn Fn(&Candidate) -> bool| have.iter().any(f);
    let mut families = Vec::new();
    if !has(&|c| matches!(c, Candidate::LinearDrift)) {
        families.push(vec![Candidate::LinearDrift]);
    }
    if !periods.is_empty() && !has(&|c| matches!(c, Candidate::CyclicDrift { .. })) {
        families.push(
            periods
                .iter()
                .map(|&period_s| Candidate::CyclicDrift { period_s })
                .collect(),
        );
    }
    if !has(&|c| matches!(c, Candidate::SensorGain { .. })) {
        families.push(
            Channel::ALL
                .map(|channel| Candidate::SensorGain { channel })
                .into(),
        );
    }
    let mut axis = Vec::new();
    for a in [RotaryAxis::A, RotaryAxis::C] {
        for harmonic in 1..=max_harmonic {
            let c = Candidate::AxisError { axis: a, harmonic };
            if !have.contains(&c) {
                axis.push(c);
            }
        }
    }
    if !axis.is_empty() {
        families.push(axis);
    }
    families
}
