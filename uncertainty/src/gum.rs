//! The GUM law of propagation of uncertainty (JCGM 100 §5, annex G) for models with several
//! outputs (the covariance form of JCGM 102 §6.2).

use nalgebra::DMatrix;
use serde::Serialize;

use super::dist::{std_normal_quantile, t_quantile};
use super::{Model, UncertaintyError};

/// One input quantity as the GUM sees it: an estimate, a standard uncertainty, and degrees of
/// freedom (`f64::INFINITY` for a Type B evaluation taken as exactly known).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GumInput {
    pub name: String,
    pub estimate: f64,
    pub standard_uncertainty: f64,
    #[serde(serialize_with = "ser_dof")]
    pub dof: f64,
    /// Inputs evaluated together (e.g. the intercept and slope of one least-squares fit) share a
    /// group: their correlated contributions form one component of the Welch–Satterthwaite
    /// formula with the group's degrees of freedom (JCGM 100 H.3), see [`effective_dof`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
}

/// How the expanded uncertainty is formed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Coverage {
    /// Coverage probability p, e.g. 0.95.
    pub probability: f64,
    /// A fixed coverage factor (e.g. k = 2 as paper 003 uses); `None` derives k from the
    /// t distribution with the Welch–Satterthwaite degrees of freedom (JCGM 100 G.4).
    pub factor: Option<f64>,
}

impl Default for Coverage {
    fn default() -> Self {
        Coverage {
            probability: 0.95,
            factor: None,
        }
    }
}

/// One line of the uncertainty budget of one output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BudgetLine {
    pub input: String,
    pub estimate: f64,
    pub standard_uncertainty: f64,
    #[serde(serialize_with = "ser_dof")]
    pub dof: f64,
    /// Sensitivity coefficient c_i = ∂f/∂x_i at the estimates (central difference).
    pub sensitivity: f64,
    /// Uncertainty contribution u_i(y) = c_i·u(x_i) (signed; JCGM 100 eq. 11a).
    pub contribution: f64,
}

/// The GUM result for one output quantity.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GumOutput {
    pub name: String,
    pub estimate: f64,
    /// Combined standard uncertainty u_c(y) (JCGM 100 eq. 13, with correlations).
    pub standard_uncertainty: f64,
    /// Welch–Satterthwaite effective degrees of freedom (JCGM 100 eq. G.2b); `None` = infinite.
    pub dof_eff: Option<f64>,
    pub coverage_factor: f64,
    pub expanded_uncertainty: f64,
    /// `[y − U, y + U]`.
    pub interval: [f64; 2],
    pub budget: Vec<BudgetLine>,
}

/// GUM results for all outputs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GumResult {
    pub coverage_probability: f64,
    pub outputs: Vec<GumOutput>,
    /// Correlation coefficients between the outputs, r(y_i, y_j) (JCGM 100 H.2.3).
    pub output_correlation: Vec<Vec<f64>>,
}

fn ser_dof<S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_finite() {
        s.serialize_some(v)
    } else {
        s.serialize_none()
    }
}

/// The relative step of the central differences: h_i = STEP · u(x_i). Small against u so the
/// difference quotient is the derivative (not a secant over ±u, which would mix in the second
/// order terms the first-order GUM leaves out), large enough that round-off stays below 1e-9
/// relative for models evaluated near 1e8 units (JCGM 100 H.1 in nanometres).
const STEP: f64 = 1e-3;

/// Sensitivity coefficients ∂f_j/∂x_i at `x` as an `n_out × n_in` matrix.
pub fn sensitivities<M: Model + ?Sized>(model: &M, x: &[f64], u: &[f64]) -> DMatrix<f64> {
    let n_out = model.n_outputs();
    let mut c = DMatrix::zeros(n_out, x.len());
    let mut xp = x.to_vec();
    let mut yp = vec![0.0; n_out];
    let mut ym = vec![0.0; n_out];
    for i in 0..x.len() {
        let h = if u[i] > 0.0 {
            STEP * u[i]
        } else {
            1e-6 * x[i].abs().max(1.0)
        };
        xp[i] = x[i] + h;
        model.evaluate(&xp, &mut yp);
        xp[i] = x[i] - h;
        model.evaluate(&xp, &mut ym);
        xp[i] = x[i];
        for j in 0..n_out {
            c[(j, i)] = (yp[j] - ym[j]) / (2.0 * h);
        }
    }
    c
}

/// Coverage factor for probability `p` and `dof` degrees of freedom (`None` = infinite).
///
/// The degrees of freedom are truncated to the next lower integer before the t quantile is taken
/// (JCGM 100 G.6.4), which is how H.1 gets k = t₉₉(16) = 2.92 from ν_eff = 16.7.
pub fn coverage_factor(p: f64, dof: Option<f64>) -> f64 {
    let q = 0.5 * (1.0 + p);
    match dof {
        None => std_normal_quantile(q),
        Some(nu) => {
            let nu = nu.floor().max(1.0);
            t_quantile(q, nu).unwrap_or_else(|| std_normal_quantile(q))
        }
    }
}

/// Effective degrees of freedom of one output (JCGM 100 G.4, eq. G.2b), `None` = infinite.
///
/// The Welch–Satterthwaite formula needs independent components. An uncorrelated input is one;
/// inputs that share a `group` (one evaluation, as the intercept and slope of one straight-line
/// fit) are one together, with variance Σ c_i c_k u(x_i, x_k) over the group and the group's
/// ν — for JCGM 100 H.3 this gives ν = n − 2 = 9, where treating intercept and slope as two
/// independent contributions gives a meaningless value. A correlation between different
/// components that carry finite ν has no Welch–Satterthwaite form (G.4 gives none): that is an
/// error naming the inputs and the ways out.
pub fn effective_dof(
    c: &[f64],
    inputs: &[GumInput],
    ux: &DMatrix<f64>,
    output: &str,
) -> Result<Option<f64>, UncertaintyError> {
    let n = inputs.len();
    let same = |i: usize, k: usize| {
        i == k || matches!((&inputs[i].group, &inputs[k].group), (Some(a), Some(b)) if a == b)
    };
    for i in 0..n {
        for k in (i + 1)..n {
            let finite = inputs[i].dof.is_finite() || inputs[k].dof.is_finite();
            if ux[(i, k)] != 0.0 && !same(i, k) && finite {
                return Err(UncertaintyError::Invalid(format!(
                    "output `{output}`: ν_eff is undefined because `{}` and `{}` are correlated \
                     and have finite degrees of freedom (JCGM 100 G.4 covers independent \
                     inputs only). If they come from one evaluation (as the intercept and slope \
                     of one fit, JCGM 100 H.3), give both the same `group` and `dof`; otherwise \
                     give the output's `dof` or a fixed `coverage_factor` in [settings]",
                    inputs[i].name, inputs[k].name
                )));
            }
        }
    }
    let mut denom = 0.0;
    let mut var_total = 0.0;
    let mut done = vec![false; n];
    for i in 0..n {
        if done[i] {
            continue;
        }
        let members: Vec<usize> = (i..n).filter(|k| same(i, *k)).collect();
        let mut v = 0.0;
        for &a in &members {
            done[a] = true;
            for &b in &members {
                v += c[a] * c[b] * ux[(a, b)];
            }
        }
        var_total += v;
        let nu = inputs[i].dof;
        if let Some(m) = members.iter().find(|m| inputs[**m].dof != nu) {
            return Err(UncertaintyError::Invalid(format!(
                "inputs `{}` and `{}` are in one group but have different `dof`: a group is one \
                 evaluation with one number of degrees of freedom",
                inputs[i].name, inputs[*m].name
            )));
        }
        if nu.is_finite() && v > 0.0 {
            denom += v * v / nu;
        }
    }
    Ok((denom > 0.0).then(|| var_total * var_total / denom))
}

/// Propagates `inputs` through `model` by the GUM law of propagation.
///
/// `correlation` is the inputs' correlation matrix (identity when `None`). ν_eff by
/// [`effective_dof`].
pub fn propagate<M: Model + ?Sized>(
    model: &M,
    output_names: &[String],
    inputs: &[GumInput],
    correlation: Option<&DMatrix<f64>>,
    coverage: Coverage,
) -> Result<GumResult, UncertaintyError> {
    propagate_with_dof(
        model,
        output_names,
        inputs,
        correlation,
        coverage,
        &vec![None; output_names.len()],
    )
}

/// [`propagate`] with degrees of freedom given per output (`Some` replaces ν_eff: for a
/// correlation structure the Welch–Satterthwaite formula cannot express).
pub fn propagate_with_dof<M: Model + ?Sized>(
    model: &M,
    output_names: &[String],
    inputs: &[GumInput],
    correlation: Option<&DMatrix<f64>>,
    coverage: Coverage,
    output_dof: &[Option<f64>],
) -> Result<GumResult, UncertaintyError> {
    let n_in = inputs.len();
    let n_out = model.n_outputs();
    if output_names.len() != n_out {
        return Err(UncertaintyError::Invalid(format!(
            "{} output names for a model with {n_out} outputs",
            output_names.len()
        )));
    }
    if let Some(r) = correlation
        && (r.nrows() != n_in || r.ncols() != n_in)
    {
        return Err(UncertaintyError::Invalid(format!(
            "correlation matrix is {}×{} for {n_in} inputs",
            r.nrows(),
            r.ncols()
        )));
    }
    let x: Vec<f64> = inputs.iter().map(|i| i.estimate).collect();
    let u: Vec<f64> = inputs.iter().map(|i| i.standard_uncertainty).collect();
    let mut y = vec![0.0; n_out];
    model.evaluate(&x, &mut y);
    if let Some(j) = y.iter().position(|v| !v.is_finite()) {
        return Err(UncertaintyError::NonFinite {
            output: output_names[j].clone(),
            context: "at the input estimates".into(),
        });
    }
    let c = sensitivities(model, &x, &u);
    // Covariance of the inputs U_x = D R D, of the outputs U_y = C U_x Cᵀ (JCGM 102 eq. 3).
    let mut ux = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
        n_in,
        u.iter().map(|v| v * v),
    ));
    if let Some(r) = correlation {
        for i in 0..n_in {
            for j in 0..n_in {
                if i != j {
                    ux[(i, j)] = r[(i, j)] * u[i] * u[j];
                }
            }
        }
    }
    let uy = &c * &ux * c.transpose();
    let mut outputs = Vec::with_capacity(n_out);
    for j in 0..n_out {
        let uc = uy[(j, j)].max(0.0).sqrt();
        let mut budget = Vec::with_capacity(n_in);
        for (i, inp) in inputs.iter().enumerate() {
            let ci = c[(j, i)];
            budget.push(BudgetLine {
                input: inp.name.clone(),
                estimate: inp.estimate,
                standard_uncertainty: inp.standard_uncertainty,
                dof: inp.dof,
                sensitivity: ci,
                contribution: ci * inp.standard_uncertainty,
            });
        }
        let row: Vec<f64> = c.row(j).iter().copied().collect();
        let dof_eff = match output_dof.get(j).copied().flatten() {
            Some(nu) => nu.is_finite().then_some(nu),
            None => match effective_dof(&row, inputs, &ux, &output_names[j]) {
                Ok(v) => v,
                // A fixed k needs no ν; report it as unknown (infinite) rather than fail.
                Err(_) if coverage.factor.is_some() => None,
                Err(e) => return Err(e),
            },
        };
        let k = coverage
            .factor
            .unwrap_or_else(|| coverage_factor(coverage.probability, dof_eff));
        let big_u = k * uc;
        outputs.push(GumOutput {
            name: output_names[j].clone(),
            estimate: y[j],
            standard_uncertainty: uc,
            dof_eff,
            coverage_factor: k,
            expanded_uncertainty: big_u,
            interval: [y[j] - big_u, y[j] + big_u],
            budget,
        });
    }
    let output_correlation = (0..n_out)
        .map(|a| {
            (0..n_out)
                .map(|b| {
                    let d = (uy[(a, a)] * uy[(b, b)]).sqrt();
                    if d > 0.0 { uy[(a, b)] / d } else { 0.0 }
                })
                .collect()
        })
        .collect();
    Ok(GumResult {
        coverage_probability: coverage.probability,
        outputs,
        output_correlation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_factors_from_tables() {
        // JCGM 100 table G.2.
        assert!((coverage_factor(0.95, None) - 1.960).abs() < 1e-3);
        assert!((coverage_factor(0.99, Some(16.7)) - 2.921).abs() < 1e-3);
        assert!((coverage_factor(0.95, Some(10.0)) - 2.228).abs() < 1e-3);
    }
}
