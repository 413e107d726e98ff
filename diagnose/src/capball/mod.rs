//! Diagnosis of CapBall data (paper 001): what the 14-parameter link/setup model plus white
//! sensor noise gets wrong, which effect explains it, and how much the model gains.
//!
//! Method (the issue leaves it open; `docs/datasets.md`, "CapBall effects", documents it):
//! - Baseline: the 14 parameters identified on the identification run (run 1); its residual
//!   and the residual it leaves on the validation runs (A reversed) are the "before".
//! - White-noise level per channel from second differences of the residuals in measuring
//!   order (smooth effects nearly cancel there), with a robust scale.
//! - Outlying poses: departures from the running median of the neighbouring poses beyond a
//!   Bonferroni bound; they are left out of every fit.
//! - Candidate effects are extra columns of the identification least squares
//!   ([`model::Candidate`]). Columns (or combinations of them) that the 14 parameters take up
//!   exactly are dropped and reported as absorbed: the data cannot show them. Forward
//!   selection: the candidate with the largest BIC decrease (its grid search — period,
//!   channel, axis and harmonic — counted as one parameter) is accepted when the decrease
//!   exceeds [`Options::min_bic_gain`] **and** the validation runs' residual sum of squares
//!   drops by more than [`Options::min_validation_gain`] noise variances beyond the BIC
//!   penalty of what is fitted again there. On the validation runs the 14 parameters, the
//!   sensor gain and the axis errors carry over unchanged; a drift of the measuring loop is a
//!   function of time belonging to one run, so its coefficients (period kept) and one offset
//!   per channel are fitted again.
//! - `unexplained`: what is left exceeds the white-noise level by more than five standard
//!   deviations of that comparison, on the identification or the validation run.

// Row-indexed numerics over several parallel arrays (rows 3 i + k) read clearest with indices.
#![allow(clippy::needless_range_loop)]

mod checks;
mod model;
mod report;
mod select;

mod types;

pub use checks::{Profile, ResidualSummary};
pub use model::{Candidate, CapballRun};
pub use report::{
    Absorption, CapballBaseline, CapballDiagnosis, CapballDiagnosisReport, CapballFinding,
    CapballFound, ParameterShift,
};

use nalgebra::DVector;

use geometry::capball::{CapballError, CapballRecord, CapballSetup};
use model::log_grid;
use select::{ModelFit, candidate_list, fit_terms, model_basis, screen, validate};
pub use types::{DriftRecord, Options};
use types::{Periods, Step};

/// The runs of a parsed dataset: run 1 identifies, the others validate. Without a `time_s`
/// column the pose number stands in for the time (the caller notes it).
pub fn runs_from_records(
    records: &[CapballRecord],
) -> Result<(CapballRun, Vec<CapballRun>), CapballError> {
    let mut ids: Vec<u32> = records.iter().map(|r| r.run).collect();
    ids.sort_unstable();
    ids.dedup();
    let mut runs = Vec::new();
    for id in ids {
        let recs: Vec<&CapballRecord> = records.iter().filter(|r| r.run == id).collect();
        runs.push(CapballRun::new(
            recs.iter().map(|r| r.pose).collect(),
            recs.iter()
                .map(|r| r.time_s.unwrap_or(r.pose_index as f64))
                .collect(),
            recs.iter().map(|r| r.e_um).collect(),
        ));
    }
    if runs.len() < 2 {
        return Err(CapballError::Dataset(
            "the diagnosis needs an identification run (run 1) and a validation run (run 2, e.g. A reversed) in the `run` column".into(),
        ));
    }
    let id = runs.remove(0);
    Ok((id, runs))
}

/// Parse a drift record (`time_s,ex_um,ey_um,ez_um`, `#` comments).
pub fn parse_drift_record(text: &str) -> Result<DriftRecord, CapballError> {
    let err = |m: String| CapballError::Dataset(format!("drift record: {m}"));
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let h = rdr.headers().map_err(|e| err(e.to_string()))?.clone();
    let need = ["time_s", "ex_um", "ey_um", "ez_um"];
    let mut idx = Vec::new();
    for n in need {
        idx.push(
            h.iter()
                .position(|x| x == n)
                .ok_or_else(|| err(format!("missing column `{n}` (header must name {need:?})")))?,
        );
    }
    let mut out = DriftRecord::default();
    for (line, rec) in rdr.records().enumerate() {
        let rec = rec.map_err(|e| err(e.to_string()))?;
        let v: Vec<f64> = idx
            .iter()
            .map(|&i| {
                let s = rec.get(i).unwrap_or("");
                s.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| err(format!("row {}: `{s}` is not a finite number", line + 2)))
            })
            .collect::<Result<_, _>>()?;
        out.time_s.push(v[0]);
        out.e_um.push([v[1], v[2], v[3]]);
    }
    if out.time_s.len() < 20 {
        return Err(err(format!(
            "{} rows: a drift record needs at least 20 readings",
            out.time_s.len()
        )));
    }
    Ok(out)
}

fn check_run(run: &CapballRun, what: &str) -> Result<(), CapballError> {
    let n = run.len();
    if run.time_s.len() != n || run.e_um.len() != n {
        return Err(CapballError::LengthMismatch {
            poses: n,
            values: run.e_um.len().min(run.time_s.len()),
        });
    }
    if n < 30 {
        return Err(CapballError::Dataset(format!(
            "the {what} run has {n} poses: the diagnosis needs at least 30"
        )));
    }
    if run.time_s.iter().any(|t| !t.is_finite()) {
        return Err(CapballError::Dataset(format!(
            "the {what} run has a time that is not a finite number"
        )));
    }
    Ok(())
}

/// Rows (3 per pose) kept when the poses flagged in `out` are left out.
fn row_mask(out: &[bool]) -> Vec<bool> {
    out.iter().flat_map(|o| [!o, !o, !o]).collect()
}

/// Diagnose an identification run against one or more validation runs.
pub fn diagnose(
    setup: &CapballSetup,
    ident: &CapballRun,
    validation: &[CapballRun],
    drift: Option<&DriftRecord>,
    opt: &Options,
) -> Result<CapballDiagnosis, CapballError> {
    check_run(ident, "identification")?;
    for v in validation {
        check_run(v, "validation")?;
    }
    // Own copies: their cached Jacobians belong to this setup.
    let ident = &ident.fresh();
    let validation: &[CapballRun] = &validation.iter().map(CapballRun::fresh).collect::<Vec<_>>();
    if validation.is_empty() {
        return Err(CapballError::Dataset(
            "no validation run: the diagnosis measures each effect's gain on a second run (A reversed)".into(),
        ));
    }
    let base = setup.identify(&ident.poses, &ident.e_um)?;
    let p0 = DVector::from_column_slice(&base.params);
    let all_rows = vec![true; 3 * ident.len()];
    let baseline =
        fit_terms(setup, ident, &all_rows, Vec::new(), &p0).ok_or(CapballError::Singular {
            condition: base.condition_number,
            worst: "?".into(),
        })?;
    // Outliers: judged on the baseline residuals of every run, then again on the final model's:
    // a pose that only looked far off because an effect was not yet modelled (a cooling cycle
    // at its peak) is not an outlier, and the selection runs again without leaving it out.
    let out_id = checks::outlier_poses(&baseline.fit.resid, ident.len(), opt.outlier_alpha);
    let val_all: Vec<Vec<bool>> = validation.iter().map(|v| vec![true; 3 * v.len()]).collect();
    let (_, _, _, val_res0) = validate(setup, validation, &val_all, &baseline);
    let out_val: Vec<Vec<bool>> = validation
        .iter()
        .zip(&val_res0)
        .map(|(v, r)| checks::outlier_poses(r, v.len(), opt.outlier_alpha))
        .collect();
    let inputs = Inputs {
        setup,
        ident,
        validation,
        drift,
        opt,
        base: &base,
        baseline: &baseline,
        p0: &p0,
    };
    let (d, fin) = select_with_outliers(&inputs, &out_id, &out_val)?;
    let any = |o: &[bool]| o.iter().any(|&x| x);
    if fin.terms.is_empty() || !(any(&out_id) || out_val.iter().any(|o| any(o))) {
        return Ok(d);
    }
    let still = |was: &[bool], resid: &DVector<f64>| -> Vec<bool> {
        let now = checks::outlier_poses(resid, was.len(), opt.outlier_alpha);
        was.iter().zip(now).map(|(a, b)| *a && b).collect()
    };
    let (_, _, _, r_id) = validate(setup, std::slice::from_ref(ident), &[all_rows], &fin);
    let id2 = still(&out_id, &r_id[0]);
    let (_, _, _, r_val) = validate(setup, validation, &val_all, &fin);
    let val2: Vec<Vec<bool>> = out_val
        .iter()
        .zip(&r_val)
        .map(|(o, r)| still(o, r))
        .collect();
    if id2 == out_id && val2 == out_val {
        return Ok(d);
    }
    Ok(select_with_outliers(&inputs, &id2, &val2)?.0)
}

/// What every pass of the selection shares.
struct Inputs<'a> {
    setup: &'a CapballSetup,
    ident: &'a CapballRun,
    validation: &'a [CapballRun],
    drift: Option<&'a DriftRecord>,
    opt: &'a Options,
    base: &'a geometry::capball::Identification,
    baseline: &'a ModelFit,
    p0: &'a DVector<f64>,
}

/// The forward selection with the poses flagged in `out_id` / `out_val` left out, and the
/// report it gives.
fn select_with_outliers(
    inp: &Inputs,
    out_id: &[bool],
    out_val: &[Vec<bool>],
) -> Result<(CapballDiagnosis, ModelFit), CapballError> {
    let Inputs {
        setup,
        ident,
        validation,
        drift,
        opt,
        base,
        baseline,
        p0,
    } = *inp;
    let keep = row_mask(out_id);
    let val_keep: Vec<Vec<bool>> = out_val.iter().map(|o| row_mask(o)).collect();
    // All runs on one clock, for the evidence (information criterion) and the effect's
    // parameters: the reversed A of the validation run separates a drift from the A angle.
    let mut joint = ident.fresh();
    let mut joint_keep = keep.clone();
    for (v, k) in validation.iter().zip(&val_keep) {
        joint.poses.extend_from_slice(&v.poses);
        joint.time_s.extend_from_slice(&v.time_s);
        joint.e_um.extend_from_slice(&v.e_um);
        joint_keep.extend_from_slice(k);
    }
    let periods = drift_periods(&joint, drift);
    let ctx = report::Context {
        setup,
        ident,
        validation,
        joint: &joint,
        joint_keep: &joint_keep,
        keep: &keep,
        val_keep: &val_keep,
        out_id,
        out_val,
        opt,
        record_period: periods.from_record,
    };
    let singular = || CapballError::Singular {
        condition: base.condition_number,
        worst: "?".into(),
    };
    let start = fit_terms(setup, ident, &keep, Vec::new(), p0).ok_or_else(singular)?;
    let start_joint = fit_terms(setup, &joint, &joint_keep, Vec::new(), p0).ok_or_else(singular)?;
    let (mut fin, mut steps) = forward_select(&ctx, start.clone(), start_joint.clone(), &periods)?;
    // A cyclic drift whose period the runs cannot bound also fits a steady drift plus
    // whatever else is unmodelled early in the selection: when a steady drift does at least as
    // well (BIC on all runs) with the other effects found, select again without the cyclic one.
    if periods.from_record.is_none() && steadier_drift_fits(&ctx, &steps) {
        let no_cyclic = Periods {
            grid: Vec::new(),
            from_record: None,
        };
        (fin, steps) = forward_select(&ctx, start.clone(), start_joint, &no_cyclic)?;
    }
    let d = report::assemble(&ctx, base, baseline, &start, &fin, &steps, &periods);
    Ok((d, fin))
}

fn drift_periods(joint: &CapballRun, drift: Option<&DriftRecord>) -> Periods {
    if let Some(rec) = drift
        && let Some(p) = report::record_period(rec)
    {
        return Periods {
            grid: vec![p.0],
            from_record: Some(p),
        };
    }
    let t0 = joint.time_s.iter().copied().fold(f64::INFINITY, f64::min);
    let t1 = joint
        .time_s
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    Periods {
        grid: log_grid(60.0, (4.0 * (t1 - t0)).max(120.0), 48),
        from_record: None,
    }
}

/// Whether the final model's cyclic drift (if any, and no linear one) can be replaced by a
/// linear drift without raising the BIC on all runs.
fn steadier_drift_fits(ctx: &report::Context, steps: &[Step]) -> bool {
    let Some(last) = steps.last() else {
        return false;
    };
    let terms = &last.joint_after.terms;
    let has = |f: fn(&Candidate) -> bool| terms.iter().any(|t| f(&t.cand));
    if !has(|c| matches!(c, Candidate::CyclicDrift { .. }))
        || has(|c| matches!(c, Candidate::LinearDrift))
    {
        return false;
    }
    let others: Vec<select::Term> = terms
        .iter()
        .filter(|t| !matches!(t.cand, Candidate::CyclicDrift { .. }))
        .cloned()
        .collect();
    let Some(base) = fit_terms(
        ctx.setup,
        ctx.joint,
        ctx.joint_keep,
        others,
        &last.joint_after.p,
    ) else {
        return false;
    };
    let q = model_basis(ctx.setup, ctx.joint, &base, ctx.joint_keep);
    let Some(lin) = screen(
        ctx.setup,
        ctx.joint,
        ctx.joint_keep,
        &base,
        &q,
        Candidate::LinearDrift,
    ) else {
        return false;
    };
    let mut t = base.terms.clone();
    t.push(lin.term);
    let Some(with_lin) = fit_terms(ctx.setup, ctx.joint, ctx.joint_keep, t, &base.p) else {
        return false;
    };
    let n = ctx.joint_keep.iter().filter(|k| **k).count() as f64;
    let bic = |m: &ModelFit| n * (m.fit.rss / n).ln() + m.n_params() as f64 * n.ln();
    // The period search counts as one more parameter of the cyclic model.
    bic(&with_lin) <= bic(&last.joint_after) + n.ln()
}

/// A candidate fitted in full: evidence on the identification run (BIC decrease) and on the
/// validation runs (RSS decrease in noise variances, less the refit penalty).
struct Tried {
    next: ModelFit,
    next_joint: ModelFit,
    bic: f64,
    val: (f64, usize, usize),
    stat: f64,
}

/// Screen every candidate family against the current model; the best two of each family by
/// BIC decrease (grid search counted as one parameter) above the threshold.
fn shortlist(ctx: &report::Context, cur: &ModelFit, periods: &Periods) -> Vec<select::Term> {
    let (setup, ident, keep, opt) = (ctx.setup, ctx.joint, ctx.joint_keep, ctx.opt);
    let n_eq = keep.iter().filter(|k| **k).count() as f64;
    let grid_penalty = |c: &Candidate| match c {
        Candidate::LinearDrift => 0.0,
        Candidate::CyclicDrift { .. } if periods.from_record.is_some() => 0.0,
        _ => 1.0,
    };
    let q = model_basis(setup, ident, cur, keep);
    let have: Vec<Candidate> = cur.terms.iter().map(|t| t.cand).collect();
    let mut out = Vec::new();
    for fam in candidate_list(&have, &periods.grid, opt.max_harmonic) {
        let mut scored: Vec<(f64, select::Screened)> = fam
            .into_iter()
            .filter_map(|c| screen(setup, ident, keep, cur, &q, c))
            .map(|s| {
                let k = s.term.rank() as f64 + grid_penalty(&s.term.cand);
                let bic =
                    n_eq * (cur.fit.rss / (cur.fit.rss - s.drss).max(1e-300)).ln() - k * n_eq.ln();
                (bic, s)
            })
            .filter(|(bic, _)| *bic >= opt.min_bic_gain)
            .collect();
        scored.sort_by(|a, b| b.0.total_cmp(&a.0));
        // Grid neighbours of the best (nearby periods) are the same effect: keep one per kind.
        let same = |a: &Candidate, b: &Candidate| match (a, b) {
            (Candidate::CyclicDrift { .. }, Candidate::CyclicDrift { .. }) => true,
            _ => a == b,
        };
        let mut kinds: Vec<Candidate> = Vec::new();
        for (_, s) in scored {
            let kind = s.term.cand;
            if kinds.iter().any(|k| same(k, &kind)) {
                continue;
            }
            kinds.push(kind);
            out.push(refine(ctx, cur, &q, s.term));
            if kinds.len() == 2 {
                break;
            }
        }
    }
    out
}

fn forward_select(
    ctx: &report::Context,
    start: ModelFit,
    start_joint: ModelFit,
    periods: &Periods,
) -> Result<(ModelFit, Vec<Step>), CapballError> {
    let (setup, ident, keep, opt) = (ctx.setup, ctx.ident, ctx.keep, ctx.opt);
    let n_joint = ctx.joint_keep.iter().filter(|k| **k).count() as f64;
    let sigma2_val = ctx.val_noise_var();
    let mut cur = start;
    let mut cur_joint = start_joint;
    let mut steps = Vec::new();
    while steps.len() < opt.max_effects {
        let vb = validate(setup, ctx.validation, ctx.val_keep, &cur);
        let mut tried: Vec<Tried> = Vec::new();
        for term in shortlist(ctx, &cur_joint, periods) {
            let mut terms = cur_joint.terms.clone();
            terms.push(term.clone());
            let Some(next_joint) = fit_terms(setup, ctx.joint, ctx.joint_keep, terms, &cur_joint.p)
            else {
                continue;
            };
            let bic = n_joint * (cur_joint.fit.rss / next_joint.fit.rss).ln()
                - (next_joint.n_params() - cur_joint.n_params()) as f64 * n_joint.ln();
            let mut terms = cur.terms.clone();
            terms.push(term);
            let Some(next) = fit_terms(setup, ident, keep, terms, &cur.p) else {
                continue;
            };
            let va = validate(setup, ctx.validation, ctx.val_keep, &next);
            let stat =
                (vb.0 - va.0) / sigma2_val - (va.2 as f64 - vb.2 as f64) * (va.1 as f64).ln();
            if bic >= opt.min_bic_gain && stat >= opt.min_validation_gain {
                tried.push(Tried {
                    next,
                    next_joint,
                    bic,
                    val: (va.0, va.1, va.2),
                    stat,
                });
            }
        }
        // The reversed-A validation is what tells a drift from an error of the A axis: the
        // choice weighs the evidence of all runs and the held-out gain.
        tried.sort_by(|a, b| (b.bic + b.stat).total_cmp(&(a.bic + a.stat)));
        let Some(best) = tried.first() else {
            break;
        };
        let top = best.bic + best.stat;
        let rivals = tried[1..]
            .iter()
            .filter(|t| top - (t.bic + t.stat) < opt.min_bic_gain)
            .filter_map(|t| t.next.terms.last().map(|x| x.cand))
            .filter(|c| Some(c.kind()) != best.next.terms.last().map(|x| x.cand.kind()))
            .collect();
        steps.push(Step {
            before: cur.clone(),
            after: best.next.clone(),
            joint_before: cur_joint.clone(),
            joint_after: best.next_joint.clone(),
            bic_drop: best.bic,
            val_before: (vb.0, vb.1, vb.2),
            val_after: best.val,
            rivals,
        });
        cur = best.next.clone();
        cur_joint = best.next_joint.clone();
    }
    Ok((cur, steps))
}

/// Refine a cyclic drift's period (golden-section search between the grid neighbours, on the
/// screened RSS decrease); other candidates are returned as they are.
fn refine(
    ctx: &report::Context,
    cur: &ModelFit,
    q: &nalgebra::DMatrix<f64>,
    term: select::Term,
) -> select::Term {
    let Candidate::CyclicDrift { period_s } = term.cand else {
        return term;
    };
    if ctx_has_record(ctx) {
        return term;
    }
    let f = |p: f64| {
        screen(
            ctx.setup,
            ctx.joint,
            ctx.joint_keep,
            cur,
            q,
            Candidate::CyclicDrift { period_s: p },
        )
        .map(|s| s.drss)
        .unwrap_or(f64::NEG_INFINITY)
    };
    let ratio = 1.1f64;
    let (mut a, mut b) = ((period_s / ratio).ln(), (period_s * ratio).ln());
    let g = 0.618_033_988_75;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c.exp()), f(d.exp()));
    for _ in 0..25 {
        if fc > fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c.exp());
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d.exp());
        }
    }
    let p = (0.5 * (a + b)).exp();
    screen(
        ctx.setup,
        ctx.joint,
        ctx.joint_keep,
        cur,
        q,
        Candidate::CyclicDrift { period_s: p },
    )
    .map(|s| s.term)
    .unwrap_or(term)
}

fn ctx_has_record(ctx: &report::Context) -> bool {
    ctx.record_period.is_some()
}
