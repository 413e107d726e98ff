//! Uncertainty budgets written as TOML files.
//!
//! ```toml
//! title = "JCGM 101 9.2.2: additive model"
//! [settings]              # all optional
//! coverage_probability = 0.95
//! coverage_factor = 2.0   # a fixed k for the GUM result instead of t(p, ν_eff)
//! ndig = 2                # significant digits for the adaptive Monte Carlo tolerance (1 to 4)
//! seed = 1
//! trials = 1000000        # a fixed number of trials instead of the adaptive procedure
//! max_trials = 10000000   # trials and max_trials: 1 to 20 000 000 (mc::MAX_TRIALS)
//! interval = "symmetric"  # or "shortest": the interval the adaptive procedure watches
//!
//! [[input]]
//! name = "X1"
//! unit = "mm"             # optional, for display
//! dof = 8                 # optional degrees of freedom (default infinite); Monte Carlo
//!                         # draws a normal input with ν as the scaled and shifted t_ν
//!                         # (JCGM 101 §6.4.9: Type A, u = s/√n, ν = n − 1) and a rectangular
//!                         # one as a curvilinear trapezoid with d = a/√(2ν) (§6.4.3)
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
use rand_distr::{ChiSquared, Distribution as _, StandardNormal};
use serde::{Deserialize, Serialize};

use super::dist::{Distribution, open_unit, std_normal_cdf};
use super::expr::Expr;
use super::gum::{self, Coverage, GumInput, GumResult};
use super::mc::{
    self, IntervalKind, MAX_NDIG, MAX_TRIALS, McOptions, McProgress, McResult, TrialSource,
    Validation,
};
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

impl Settings {
    /// Every setting within what a run can do: trial counts within [`MAX_TRIALS`], `ndig`
    /// 1 to [`MAX_NDIG`], a probability in (0, 1), positive finite factors and tolerances.
    fn check(&self) -> Result<(), UncertaintyError> {
        let bad = |m: String| Err(UncertaintyError::Format(format!("[settings] {m}")));
        for (name, n) in [("trials", self.trials), ("max_trials", self.max_trials)] {
            if n.is_some_and(|n| !(1..=MAX_TRIALS).contains(&n)) {
                return bad(format!("`{name}` must be 1 to {MAX_TRIALS}"));
            }
        }
        if self.ndig.is_some_and(|n| !(1..=MAX_NDIG).contains(&n)) {
            return bad(format!("`ndig` must be 1 to {MAX_NDIG}"));
        }
        if self
            .coverage_probability
            .is_some_and(|p| !(p > 0.0 && p < 1.0))
        {
            return bad("`coverage_probability` must be between 0 and 1".into());
        }
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if self.coverage_factor.is_some_and(|k| !positive(k))
            || self
                .tolerance
                .as_ref()
                .is_some_and(|t| !t.iter().copied().all(positive))
        {
            return bad("`coverage_factor` and `tolerance` must be positive finite numbers".into());
        }
        Ok(())
    }
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
    /// The Monte Carlo honours it too: a normal input is drawn as t_ν (JCGM 101 §6.4.9), a
    /// rectangular one as a curvilinear trapezoid (§6.4.3), see `Draw`; other shapes with a
    /// `dof` are drawn as given (only the GUM uses their ν).
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
    /// How the Monte Carlo draws each input (from its distribution and `dof`).
    draws: Vec<Draw>,
    /// ν and the χ²_ν distribution of each shared scale of the t-distributed inputs.
    t_scales: Vec<TScale>,
}

/// How the Monte Carlo draws an input whose standard uncertainty has finite degrees of freedom
/// ν (JCGM 101 §6.4; without `dof` an input is drawn as its distribution says).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Draw {
    /// As its distribution says.
    Plain,
    /// A normal input with ν: the scaled and shifted t_ν of JCGM 101 §6.4.9 (mean + u·t_ν,
    /// u = s/√n, ν = n − 1). `scale` indexes the χ²_ν draw that divides the normal deviate:
    /// inputs of one `group` (the parameters of one fit) share it, which makes them the
    /// multivariate t of JCGM 102 §6.5.3 (and their combination a t_ν with the GUM's u, so
    /// the GUM's t-based interval is reproduced exactly).
    T { scale: usize },
    /// A rectangular input with ν: its half-width a is itself uncertain, the curvilinear
    /// trapezoid of JCGM 101 §6.4.3 with the limits inexact by ±d, d = a/√(2ν) (JCGM 100
    /// G.4.2: ν ≈ ½·(Δu/u)⁻², so Δu/u = 1/√(2ν); H.1's "10 % reliable", ν = 50, is d = 0.1·a).
    CurvilinearTrapezoid { d: f64 },
}

/// Each input's [`Draw`] and the degrees of freedom of the shared χ² scales.
/// ν and the χ²_ν distribution of one shared t scale.
type TScale = (f64, ChiSquared<f64>);
type Draws = (Vec<Draw>, Vec<TScale>);

fn draws_of(inputs: &[Input]) -> Result<Draws, UncertaintyError> {
    let mut draws = Vec::with_capacity(inputs.len());
    let mut scales: Vec<(Option<&str>, TScale)> = Vec::new();
    for i in inputs {
        let nu = i.dof.filter(|v| v.is_finite());
        let d = match (&i.distribution, nu) {
            (Distribution::Normal { .. }, Some(nu)) => {
                let g = i.group.as_deref();
                let at = scales.iter().position(|(n, _)| g.is_some() && *n == g);
                let scale = match at {
                    Some(k) => k,
                    None => {
                        let chi =
                            ChiSquared::new(nu).map_err(|e| UncertaintyError::BadDistribution {
                                input: i.name.clone(),
                                reason: format!("`dof` {nu}: {e}"),
                            })?;
                        scales.push((g, (nu, chi)));
                        scales.len() - 1
                    }
                };
                Draw::T { scale }
            }
            (Distribution::Rectangular { half_width, .. }, Some(nu)) => {
                let d = half_width / (2.0 * nu).sqrt();
                if d > *half_width {
                    return Err(UncertaintyError::BadDistribution {
                        input: i.name.clone(),
                        reason: format!(
                            "rectangular with `dof` {nu}: the half-width would be uncertain by more \
                             than itself (Monte Carlo needs ν ≥ 0.5, JCGM 101 §6.4.3)"
                        ),
                    });
                }
                Draw::CurvilinearTrapezoid { d }
            }
            _ => Draw::Plain,
        };
        draws.push(d);
    }
    Ok((draws, scales.into_iter().map(|s| s.1).collect()))
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

/// A budget's free texts as (field, text): the title, descriptions, units and groups, which
/// the report prints as they are.
fn free_texts<'a>(
    title: &'a str,
    description: Option<&'a String>,
    inputs: &'a [Input],
    quantities: impl Iterator<Item = &'a Quantity> + 'a,
) -> impl Iterator<Item = (&'static str, &'a str)> + 'a {
    [
        ("title", Some(title)),
        ("description", description.map(String::as_str)),
    ]
    .into_iter()
    .chain(inputs.iter().flat_map(|i| {
        [
            ("description", i.description.as_deref()),
            ("unit", i.unit.as_deref()),
            ("group", i.group.as_deref()),
        ]
    }))
    .chain(quantities.flat_map(|q| {
        [
            ("description", q.description.as_deref()),
            ("unit", q.unit.as_deref()),
        ]
    }))
    .filter_map(|(field, text)| text.map(|t| (field, t)))
}

/// The budget's free texts ([`free_texts`]) are printed in the report: a control character
/// there (an escape sequence) would reach the terminal. Line breaks and tabs are text.
fn check_printable(f: &BudgetFile) -> Result<(), UncertaintyError> {
    let quantities = f.intermediates.iter().chain(&f.outputs);
    for (field, t) in free_texts(&f.title, f.description.as_ref(), &f.inputs, quantities) {
        if t.chars()
            .any(|c| c.is_control() && !matches!(c, '\n' | '\r' | '\t'))
        {
            return Err(UncertaintyError::Format(format!(
                "{field} {t:?} holds a control character (other than a line break or a tab); it is printed in the report"
            )));
        }
    }
    Ok(())
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
        check_printable(&f)?;
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
        f.settings.check()?;
        let n_in = f.inputs.len();
        let mut intermediate_exprs = Vec::new();
        for (k, q) in f.intermediates.iter().enumerate() {
            let visible = n_in + k;
            let e = Expr::compile(&q.expr, &|n| names[..visible].iter().position(|m| *m == n))
                .map_err(|error| UncertaintyError::Expr {
                    quantity: q.name.clone(),
                    error,
                })?;
            intermediate_exprs.push(e);
        }
        let visible = n_in + f.intermediates.len();
        let mut output_exprs = Vec::new();
        for q in &f.outputs {
            let e = Expr::compile(&q.expr, &|n| names[..visible].iter().position(|m| *m == n))
                .map_err(|error| UncertaintyError::Expr {
                    quantity: q.name.clone(),
                    error,
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
        let (draws, t_scales) = draws_of(&f.inputs)?;
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
            draws,
            t_scales,
        })
    }

    /// The budget's free texts: title, descriptions, units and groups, as the report prints
    /// them.
    pub fn free_texts(&self) -> impl Iterator<Item = &str> + '_ {
        let quantities = self.intermediates.iter().chain(&self.outputs);
        free_texts(
            &self.title,
            self.description.as_ref(),
            &self.inputs,
            quantities,
        )
        .map(|(_, t)| t)
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
        self.check_monte_carlo()?;
        mc::run(self, opts, progress)
    }

    /// A normal input with ν ≤ 2 is drawn as a t whose variance is infinite (JCGM 101
    /// §6.4.9.4): the Monte Carlo's u(y) would not settle. The GUM evaluation is unaffected.
    fn check_monte_carlo(&self) -> Result<(), UncertaintyError> {
        for (i, d) in self.inputs.iter().zip(&self.draws) {
            if let Draw::T { scale } = d
                && self.t_scales[*scale].0 <= 2.0
            {
                return Err(UncertaintyError::BadDistribution {
                    input: i.name.clone(),
                    reason: format!(
                        "a normal input with `dof` = {} is drawn by Monte Carlo as a Student t \
                         (JCGM 101 §6.4.9), whose variance is infinite for ν ≤ 2; give the \
                         distribution as rectangular (its ν then makes the half-width uncertain) \
                         or state ν > 2",
                        self.t_scales[*scale].0
                    ),
                });
            }
        }
        Ok(())
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
                self.check_monte_carlo()?;
                let g = self.gum()?;
                let (m, v) = mc::run_for_validation(self, &g.outputs, opts, progress)?;
                (Some(g), Some(m), v)
            }
        };
        check_summaries(gum.as_ref(), monte_carlo.as_ref())?;
        Ok(Report {
            title: self.title.clone(),
            units: self.outputs.iter().map(|q| q.unit.clone()).collect(),
            gum,
            monte_carlo,
            validation,
        })
    }

    /// Draws one trial's inputs into `x`. `z` and `w` are scratch: the (correlated) normal
    /// deviates and the t scales 1/√(χ²_ν/ν).
    fn sample_inputs(&self, rng: &mut ChaCha8Rng, s: &mut BudgetScratch, x: &mut [f64]) {
        for (w, (nu, chi)) in s.w.iter_mut().zip(&self.t_scales) {
            *w = (nu / chi.sample(rng)).sqrt();
        }
        match &self.cholesky_l {
            None => {
                for ((xi, inp), d) in x.iter_mut().zip(&self.inputs).zip(&self.draws) {
                    *xi = match *d {
                        Draw::Plain => inp.distribution.sample(rng),
                        _ => {
                            let z: f64 = StandardNormal.sample(rng);
                            let q = open_unit(rng);
                            self.draw(inp, *d, z, q, &s.w)
                        }
                    };
                }
            }
            Some(l) => {
                // Gaussian copula: correlated standard normals z = L·n; a normal input takes z
                // directly (exact), any other its quantile at Φ(z), which keeps its marginal
                // distribution and imposes the rank correlation of the normal pair (the
                // NIST Uncertainty Machine's default copula does the same).
                let z = &mut s.z;
                let n = z.len();
                for zi in z.iter_mut() {
                    *zi = StandardNormal.sample(rng);
                }
                for i in (0..n).rev() {
                    let mut acc = 0.0;
                    for k in 0..=i {
                        acc += l[(i, k)] * z[k];
                    }
                    z[i] = acc;
                }
                for (i, (xi, inp)) in x.iter_mut().zip(&self.inputs).enumerate() {
                    *xi = match (self.draws[i], &inp.distribution) {
                        (Draw::Plain, Distribution::Normal { mean, u }) => mean + u * z[i],
                        (Draw::Plain, Distribution::Constant { value }) => *value,
                        (Draw::Plain, d) => {
                            d.quantile(std_normal_cdf(z[i]).clamp(1e-300, 1.0 - 1e-16))
                        }
                        (d, _) => {
                            let q = open_unit(rng);
                            self.draw(inp, d, z[i], q, &s.w)
                        }
                    };
                }
            }
        }
    }

    /// An input with finite ν from its standard normal deviate `z` (correlated or not) and a
    /// uniform `q` in (0, 1) (see [`Draw`]). For the curvilinear trapezoid the deviate places
    /// the value within the drawn half-width (Φ(z) uniform) and `q` draws the half-width, so a
    /// correlation acts on the position, not on the width.
    fn draw(&self, inp: &Input, d: Draw, z: f64, q: f64, w: &[f64]) -> f64 {
        match (d, &inp.distribution) {
            (Draw::T { scale }, Distribution::Normal { mean, u }) => mean + u * z * w[scale],
            (Draw::CurvilinearTrapezoid { d }, Distribution::Rectangular { mean, half_width }) => {
                let a_s = half_width - d + 2.0 * d * q;
                mean + a_s * (2.0 * std_normal_cdf(z) - 1.0)
            }
            _ => inp.distribution.mean(),
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
    w: Vec<f64>,
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
            w: vec![1.0; self.t_scales.len()],
        }
    }
    fn fill(&self, rng: &mut ChaCha8Rng, s: &mut BudgetScratch, out: &mut [f64]) {
        let n_in = self.inputs.len();
        let n_out = self.outputs.len();
        for y in out.chunks_exact_mut(n_out) {
            let mut vars = std::mem::take(&mut s.vars);
            self.sample_inputs(rng, s, &mut vars[..n_in]);
            self.eval_into(&mut vars, y);
            s.vars = vars;
        }
    }
}

/// Every number a result states is finite: model values that are each finite can still be too
/// large to sum or square (an input of 1e308 gave `b = -inf °C  u = inf °C`).
fn check_summaries(gum: Option<&GumResult>, mc: Option<&McResult>) -> Result<(), UncertaintyError> {
    let bad = |name: &str, how: &str| UncertaintyError::NonFinite {
        output: name.to_string(),
        context: format!(
            "in the {how}: its values are too large to average or square (inputs near 1e308?)"
        ),
    };
    for o in gum.map(|g| g.outputs.as_slice()).unwrap_or_default() {
        let v = [o.estimate, o.standard_uncertainty, o.expanded_uncertainty];
        if !v.iter().chain(&o.interval).all(|x| x.is_finite()) {
            return Err(bad(&o.name, "GUM result"));
        }
    }
    for o in mc.map(|m| m.outputs.as_slice()).unwrap_or_default() {
        let v = [o.estimate, o.standard_uncertainty];
        let all = v
            .iter()
            .chain(&o.symmetric_interval)
            .chain(&o.shortest_interval);
        if !all.clone().all(|x| x.is_finite()) {
            return Err(bad(&o.name, "Monte Carlo result"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_input(dist: &str, dof: &str) -> Budget {
        Budget::from_toml(&format!(
            "title = \"t\"\n[[input]]\nname = \"x\"\n{dof}\n{dist}\n\
             [[output]]\nname = \"y\"\nexpr = \"x\"\n"
        ))
        .unwrap()
    }

    /// An escape sequence in a text the report prints is refused; line breaks are text.
    #[test]
    fn control_characters_in_printed_texts_are_refused() {
        let budget = |title: &str, unit: &str| {
            Budget::from_toml(&format!(
                "title = \"{title}\"\ndescription = \"\"\"\nline 1\r\n\tline 2\n\"\"\"\n\
                 [[input]]\nname = \"x\"\nunit = \"{unit}\"\ndistribution = \"normal\"\n\
                 mean = 0\nu = 1\n[[output]]\nname = \"y\"\nexpr = \"x\"\n"
            ))
        };
        assert!(budget("plain", "mm").is_ok());
        for (title, unit) in [("a \\u001b[2J b", "mm"), ("plain", "m\\u0007m")] {
            let e = budget(title, unit).unwrap_err().to_string();
            assert!(e.contains("control character"), "{e}");
        }
    }

    fn draws(b: &Budget, n: usize) -> Vec<f64> {
        let mc = b
            .monte_carlo(
                &McOptions {
                    fixed_trials: Some(n),
                    seed: 4,
                    ..McOptions::default()
                },
                None,
            )
            .unwrap();
        let mut v = mc.values[0].clone();
        v.sort_unstable_by(f64::total_cmp);
        v
    }

    /// JCGM 101 §6.4.9: a normal input with ν = 5 is drawn as t₅: its 97.5 % point is
    /// t₀.₉₇₅(5) = 2.5706 (tables), not 1.96, and its variance ν/(ν − 2) = 5/3.
    #[test]
    fn normal_with_dof_is_drawn_as_student_t() {
        let b = one_input("distribution = \"normal\"\nmean = 0\nu = 1", "dof = 5");
        let v = draws(&b, 400_000);
        let q = v[(0.975 * v.len() as f64) as usize];
        assert!((q - 2.5706).abs() < 0.03, "{q}");
        let var = v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64;
        assert!((var - 5.0 / 3.0).abs() < 0.05, "{var}");
        // The GUM keeps u = 1 with ν = 5.
        assert_eq!(b.gum_inputs()[0].standard_uncertainty, 1.0);
    }

    /// JCGM 101 §6.4.3: a rectangular input of half-width a = 1 with ν = 2 (50 % reliable) is
    /// a curvilinear trapezoid with d = 0.5: variance a²/3 + d²/9 = 0.36111, support ±1.5.
    #[test]
    fn rectangular_with_dof_is_a_curvilinear_trapezoid() {
        let b = one_input(
            "distribution = \"rectangular\"\nmean = 0\nhalf_width = 1",
            "dof = 2",
        );
        let v = draws(&b, 400_000);
        let var = v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64;
        assert!((var - (1.0 / 3.0 + 0.25 / 9.0)).abs() < 0.004, "{var}");
        assert!(v[0] >= -1.5 && v[v.len() - 1] <= 1.5);
        assert!(
            v[v.len() - 1] > 1.4,
            "the support reaches past the nominal half-width"
        );
    }

    #[test]
    fn normal_with_two_or_fewer_dof_is_refused_by_monte_carlo_only() {
        let b = one_input("distribution = \"normal\"\nmean = 0\nu = 1", "dof = 2");
        assert!(b.gum().is_ok());
        let e = b
            .monte_carlo(&McOptions::default(), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("infinite for ν ≤ 2"), "{e}");
    }
}
