//! Uncertainty budgets written as TOML files.
//!
//! ```toml
//! title = "JCGM 101 9.2.2: additive model"
//! [settings]              # all optional
//! coverage_probability = 0.95
//! coverage_factor = 2.0   # a fixed k for the GUM result instead of t(p, ν_eff)
//! ndig = 2                # significant digits for the adaptive Monte Carlo tolerance
//! seed = 1
//! trials = 1000000        # a fixed number of trials instead of the adaptive procedure
//! max_trials = 10000000
//! interval = "symmetric"  # or "shortest": the interval the adaptive procedure watches
//!
//! [[input]]
//! name = "X1"
//! unit = "mm"             # optional, for display
//! dof = 8                 # optional degrees of freedom (default infinite)
//! group = "fit"           # optional: inputs of one evaluation (one fit) share a group and a
//!                         # dof; they are one Welch–Satterthwaite component (JCGM 100 H.3)
//! distribution = "normal" # + the distribution's fields: see `Distribution`
//! mean = 0.0
//! u = 1.0
//!
//! [[correlation]]
//! inputs = ["X1", "X2"]
//! r = 0.5
//!
//! [[intermediate]]        # optional named sub-expressions, evaluated in order
//! name = "s"
//! expr = "X1 + X2"
//!
//! [[output]]
//! name = "Y"
//! expr = "s + X3"
//! dof = 9                 # optional: ν instead of ν_eff (correlated inputs of several evaluations)
//! ```

use nalgebra::DMatrix;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, StandardNormal};
use serde::{Deserialize, Serialize};

use super::dist::{Distribution, std_normal_cdf};
use super::expr::Expr;
use super::gum::{self, Coverage, GumInput, GumResult};
use super::mc::{self, IntervalKind, McOptions, McProgress, McResult, TrialSource, Validation};
use super::{Model, UncertaintyError};

/// Optional settings of a budget.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    pub coverage_probability: Option<f64>,
    pub coverage_factor: Option<f64>,
    pub ndig: Option<u32>,
    pub seed: Option<u64>,
    pub trials: Option<usize>,
    pub max_trials: Option<usize>,
    pub interval: Option<IntervalKind>,
    /// Absolute numerical tolerance per output (overrides `ndig`).
    pub tolerance: Option<Vec<f64>>,
}

/// One input quantity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Input {
    pub name: String,
    #[serde(default)]
    pub unit: Option<String>,
    #[serde(default)]
    pub description: Option<String>,
    /// Degrees of freedom of the standard uncertainty (JCGM 100 G.3); infinite when absent.
    #[serde(default)]
    pub dof: Option<f64>,
    /// Inputs from one evaluation (e.g. intercept and slope of one fit) share a group name and
    /// one `dof`; the group is one Welch–Satterthwaite component (JCGM 100 H.3).
    #[serde(default)]
    pub group: Option<String>,
    #[serde(flatten)]
    pub distribution: Distribution,
}

/// A correlation coefficient between two inputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Correlation {
    pub inputs: [String; 2],
    pub r: f64,
}

/// A named expression (an intermediate or an output quantity).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Quantity {
    pub name: String,
    pub expr: String,
    #[serde(default)]
    pub unit: Option<String>,
    #[serde(default)]
    pub description: Option<String>,
    /// Outputs only: degrees of freedom to use instead of ν_eff (for a correlation structure
    /// the Welch–Satterthwaite formula cannot express).
    #[serde(default)]
    pub dof: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct BudgetFile {
    title: String,
    #[serde(default)]
    description: Option<String>,
    #[serde(default)]
    settings: Settings,
    #[serde(default, rename = "input")]
    inputs: Vec<Input>,
    #[serde(default, rename = "correlation")]
    correlations: Vec<Correlation>,
    #[serde(default, rename = "intermediate")]
    intermediates: Vec<Quantity>,
    #[serde(default, rename = "output")]
    outputs: Vec<Quantity>,
}

/// A parsed and compiled budget.
#[derive(Debug, Clone)]
pub struct Budget {
    pub title: String,
    pub description: Option<String>,
    pub settings: Settings,
    pub inputs: Vec<Input>,
    pub correlations: Vec<Correlation>,
    pub intermediates: Vec<Quantity>,
    pub outputs: Vec<Quantity>,
    intermediate_exprs: Vec<Expr>,
    output_exprs: Vec<Expr>,
    correlation_matrix: Option<DMatrix<f64>>,
    cholesky_l: Option<DMatrix<f64>>,
}

/// Which method(s) to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    Gum,
    Mc,
    Both,
}

/// Everything a budget evaluation produced.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    pub title: String,
    pub units: Vec<Option<String>>,
    pub gum: Option<GumResult>,
    pub monte_carlo: Option<McResult>,
    /// JCGM 101 §8 validation of each GUM output (when both methods ran).
    pub validation: Vec<Validation>,
}

impl Budget {
    /// Parses and checks a budget file's text.
    pub fn from_toml(text: &str) -> Result<Budget, UncertaintyError> {
        let f: BudgetFile =
            toml::from_str(text).map_err(|e| UncertaintyError::Format(e.to_string()))?;
        if f.outputs.is_empty() {
            return Err(UncertaintyError::Format(
                "the budget has no [[output]] (give at least one output with an `expr`)".into(),
            ));
        }
        // One namespace: inputs, then intermediates, then outputs.
        let mut names: Vec<&str> = Vec::new();
        for n in f
            .inputs
            .iter()
            .map(|i| i.name.as_str())
            .chain(f.intermediates.iter().map(|q| q.name.as_str()))
            .chain(f.outputs.iter().map(|q| q.name.as_str()))
        {
            if names.contains(&n) {
                return Err(UncertaintyError::DuplicateName(n.to_string()));
            }
            if n.is_empty() || !n.chars().all(|c| c.is_alphanumeric() || c == '_') {
                return Err(UncertaintyError::Format(format!(
                    "the name `{n}` must be letters, digits and `_` only (it is used in expressions)"
                )));
            }
            names.push(n);
        }
        for i in &f.inputs {
            i.distribution.validate(&i.name)?;
            if let Some(d) = i.dof
                && (d.is_nan() || d <= 0.0)
            {
                return Err(UncertaintyError::BadDistribution {
                    input: i.name.clone(),
                    reason: "`dof` must be positive".into(),
                });
            }
        }
        for q in &f.intermediates {
            if q.dof.is_some() {
                return Err(UncertaintyError::Format(format!(
                    "intermediate `{}`: `dof` belongs to outputs only",
                    q.name
                )));
            }
        }
        if let Some(q) = f
            .outputs
            .iter()
            .find(|q| q.dof.is_some_and(|d| d.is_nan() || d <= 0.0))
        {
            return Err(UncertaintyError::Format(format!(
                "output `{}`: `dof` must be positive",
                q.name
            )));
        }
        let n_in = f.inputs.len();
        let mut intermediate_exprs = Vec::new();
        for (k, q) in f.intermediates.iter().enumerate() {
            let visible = n_in + k;
            let e = Expr::compile(&q.expr, &|n| names[..visible].iter().position(|m| *m == n))
                .map_err(|source| UncertaintyError::Expr {
                    quantity: q.name.clone(),
                    source,
                })?;
            intermediate_exprs.push(e);
        }
        let visible = n_in + f.intermediates.len();
        let mut output_exprs = Vec::new();
        for q in &f.outputs {
            let e = Expr::compile(&q.expr, &|n| names[..visible].iter().position(|m| *m == n))
                .map_err(|source| UncertaintyError::Expr {
                    quantity: q.name.clone(),
                    source,
                })?;
            output_exprs.push(e);
        }
        let (correlation_matrix, cholesky_l) = if f.correlations.is_empty() {
            (None, None)
        } else {
            let mut r = DMatrix::<f64>::identity(n_in, n_in);
            for c in &f.correlations {
                let idx = |n: &str| {
                    f.inputs
                        .iter()
                        .position(|i| i.name == n)
                        .ok_or_else(|| UncertaintyError::UnknownInput(n.to_string()))
                };
                let (a, b) = (idx(&c.inputs[0])?, idx(&c.inputs[1])?);
                if a == b || !(-1.0..=1.0).contains(&c.r) {
                    return Err(UncertaintyError::Format(format!(
                        "correlation between `{}` and `{}`: needs two different inputs and −1 ≤ r ≤ 1",
                        c.inputs[0], c.inputs[1]
                    )));
                }
                r[(a, b)] = c.r;
                r[(b, a)] = c.r;
            }
            let l = r
                .clone()
                .cholesky()
                .ok_or(UncertaintyError::NotPositiveDefinite)?
                .l();
            (Some(r), Some(l))
        };
        Ok(Budget {
            title: f.title,
            description: f.description,
            settings: f.settings,
            inputs: f.inputs,
            correlations: f.correlations,
            intermediates: f.intermediates,
            outputs: f.outputs,
            intermediate_exprs,
            output_exprs,
            correlation_matrix,
            cholesky_l,
        })
    }

    /// The GUM view of the inputs.
    pub fn gum_inputs(&self) -> Vec<GumInput> {
        self.inputs
            .iter()
            .map(|i| GumInput {
                name: i.name.clone(),
                estimate: i.distribution.mean(),
                standard_uncertainty: i.distribution.standard_uncertainty(),
                dof: i
                    .dof
                    .or_else(|| i.distribution.implied_dof())
                    .unwrap_or(f64::INFINITY),
                group: i.group.clone(),
            })
            .collect()
    }

    pub fn output_names(&self) -> Vec<String> {
        self.outputs.iter().map(|q| q.name.clone()).collect()
    }

    pub fn coverage(&self) -> Coverage {
        Coverage {
            probability: self.settings.coverage_probability.unwrap_or(0.95),
            factor: self.settings.coverage_factor,
        }
    }

    /// Monte Carlo options from the settings.
    pub fn mc_options(&self) -> McOptions {
        let d = McOptions::default();
        McOptions {
            coverage_probability: self.coverage().probability,
            ndig: self.settings.ndig.unwrap_or(d.ndig),
            tolerance: self.settings.tolerance.clone(),
            seed: self.settings.seed.unwrap_or(d.seed),
            fixed_trials: self.settings.trials,
            max_trials: self.settings.max_trials.unwrap_or(d.max_trials),
            interval: self.settings.interval.unwrap_or_default(),
        }
    }

    /// `vars[..n_inputs]` hold the inputs; fills the intermediates after them, then `y`.
    fn eval_into(&self, vars: &mut [f64], y: &mut [f64]) {
        let n_in = self.inputs.len();
        for (k, e) in self.intermediate_exprs.iter().enumerate() {
            vars[n_in + k] = e.eval(vars);
        }
        for (o, e) in y.iter_mut().zip(&self.output_exprs) {
            *o = e.eval(vars);
        }
    }

    /// The GUM evaluation.
    pub fn gum(&self) -> Result<GumResult, UncertaintyError> {
        gum::propagate_with_dof(
            self,
            &self.output_names(),
            &self.gum_inputs(),
            self.correlation_matrix.as_ref(),
            self.coverage(),
            &self.outputs.iter().map(|q| q.dof).collect::<Vec<_>>(),
        )
    }

    /// The Monte Carlo evaluation.
    pub fn monte_carlo(
        &self,
        opts: &McOptions,
        progress: Option<&(dyn Fn(&McProgress) + Sync)>,
    ) -> Result<McResult, UncertaintyError> {
        mc::run(self, opts, progress)
    }

    /// Runs the chosen method(s) and, for both, the JCGM 101 §8 validation: the Monte Carlo run
    /// is then the adaptive one of [`mc::run_for_validation`] (continued until each verdict is
    /// decided) unless `opts` fixes the number of trials.
    pub fn evaluate(
        &self,
        method: Method,
        opts: &McOptions,
        progress: Option<&(dyn Fn(&McProgress) + Sync)>,
    ) -> Result<Report, UncertaintyError> {
        let (gum, monte_carlo, validation) = match method {
            Method::Gum => (Some(self.gum()?), None, Vec::new()),
            Method::Mc => (None, Some(self.monte_carlo(opts, progress)?), Vec::new()),
            Method::Both => {
                let g = self.gum()?;
                let (m, v) = mc::run_for_validation(self, &g.outputs, opts, progress)?;
                (Some(g), Some(m), v)
            }
        };
        Ok(Report {
            title: self.title.clone(),
            units: self.outputs.iter().map(|q| q.unit.clone()).collect(),
            gum,
            monte_carlo,
            validation,
        })
    }

    fn sample_inputs(&self, rng: &mut ChaCha8Rng, z: &mut [f64], x: &mut [f64]) {
        match &self.cholesky_l {
            None => {
                for (xi, inp) in x.iter_mut().zip(&self.inputs) {
                    *xi = inp.distribution.sample(rng);
                }
            }
            Some(l) => {
                // Gaussian copula: correlated standard normals z = L·n; a normal input takes z
                // directly (exact), any other its quantile at Φ(z), which keeps its marginal
                // distribution and imposes the rank correlation of the normal pair (the
                // NIST Uncertainty Machine's default copula does the same).
                let n = z.len();
                for zi in z.iter_mut() {
                    *zi = StandardNormal.sample(rng);
                }
                for i in (0..n).rev() {
                    let mut s = 0.0;
                    for k in 0..=i {
                        s += l[(i, k)] * z[k];
                    }
                    z[i] = s;
                }
                for (i, (xi, inp)) in x.iter_mut().zip(&self.inputs).enumerate() {
                    *xi = match inp.distribution {
                        Distribution::Normal { mean, u } => mean + u * z[i],
                        Distribution::Constant { value } => value,
                        ref d => d.quantile(std_normal_cdf(z[i]).clamp(1e-300, 1.0 - 1e-16)),
                    };
                }
            }
        }
    }
}

impl Model for Budget {
    fn n_outputs(&self) -> usize {
        self.outputs.len()
    }
    fn evaluate(&self, x: &[f64], y: &mut [f64]) {
        let mut vars = x.to_vec();
        vars.resize(self.inputs.len() + self.intermediates.len(), 0.0);
        self.eval_into(&mut vars, y);
    }
}

/// Scratch of a budget's Monte Carlo worker.
pub struct BudgetScratch {
    vars: Vec<f64>,
    z: Vec<f64>,
}

impl TrialSource for Budget {
    type Scratch = BudgetScratch;
    fn n_outputs(&self) -> usize {
        self.outputs.len()
    }
    fn output_names(&self) -> Vec<String> {
        Budget::output_names(self)
    }
    fn scratch(&self) -> BudgetScratch {
        BudgetScratch {
            vars: vec![0.0; self.inputs.len() + self.intermediates.len()],
            z: vec![0.0; self.inputs.len()],
        }
    }
    fn fill(&self, rng: &mut ChaCha8Rng, s: &mut BudgetScratch, out: &mut [f64]) {
        let n_in = self.inputs.len();
        let n_out = self.outputs.len();
        for y in out.chunks_exact_mut(n_out) {
            self.sample_inputs(rng, &mut s.z, &mut s.vars[..n_in]);
            self.eval_into(&mut s.vars, y);
        }
    }
}
