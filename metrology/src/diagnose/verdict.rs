//! What the report concludes once the effects are fitted: whether the noise is correlated or
//! heavy-tailed (then the evidence and the outliers are read accordingly), whether structure
//! is left that no effect explains (`unexplained`), and which combination explains the run
//! (`docs/datasets.md`, "Diagnosis report"; `docs/methods.md`, "Diagnosis").

#![allow(clippy::needless_range_loop)]

use std::collections::BTreeMap;

use statrs::distribution::{Continuous, ContinuousCDF, DiscreteCDF, Normal, Poisson, StudentsT};

use super::Finding;
use super::correlation::design_lag1;
use super::fit::{FinalFit, Obs, heldout_rms};
use super::outliers::robust_scale;

/// Residual RMS above this many times the short-term noise is structure, not noise.
const UNEXPLAINED_RATIO: f64 = 3.0;
/// More flagged readings than this share are not isolated outliers.
pub(super) const MAX_OUTLIER_SHARE: f64 = 0.10;
/// Readings this many robust scales off their trend are far: isolated events, not the tail.
const FAR: f64 = 6.5;
/// Level of the test for more readings between 3 and [`FAR`] robust scales than normal noise
/// gives.
const HEAVY_TAIL_ALPHA: f64 = 0.01;
/// A mean effect that gains less than this share of the held-out error is not reported next
/// to an `unexplained` finding (it only stretches over structure it does not explain).
const MIN_GAIN_WHEN_UNEXPLAINED: f64 = 0.10;
/// A machine effect next to `unexplained` must explain this many times the RMS left.
const MACHINE_DOMINANCE: f64 = 3.0;

/// What is left after the fit, read against the short-term noise.
pub(super) struct Residue {
    /// Lag-1 correlation of the final residuals in time order.
    pub(super) rho: f64,
    /// Short-term noise: robust scale of successive differences of the residuals / √2, µm.
    pub(super) sigma_short_um: f64,
    /// RMS of the final residuals (outliers left out), µm.
    pub(super) rms_left_um: f64,
    /// The flagged readings look like the tail of a heavy-tailed noise, not isolated events.
    pub(super) heavy_tails: bool,
    pub(super) outlier_share: f64,
}

pub(super) fn residue(obs: &Obs, fin: &FinalFit) -> Residue {
    let rho = design_lag1(obs, &fin.w, &fin.cols, &fin.resid);
    let kept: Vec<f64> = obs
        .time_order
        .iter()
        .filter(|&&j| fin.eval[j])
        .map(|&j| fin.resid[j])
        .collect();
    let mut diffs: Vec<f64> = kept.windows(2).map(|w| w[1] - w[0]).collect();
    let sigma_short_um = robust_scale(&mut diffs) / std::f64::consts::SQRT_2;
    let rms_left_um = (kept.iter().map(|r| r * r).sum::<f64>() / kept.len().max(1) as f64).sqrt();
    let n = obs.len();
    let n_out = fin.out.iter().filter(|o| **o).count();
    // Tails: readings between 3 and 6.5 robust scales from their trend (flagged or not),
    // compared with what normal noise gives; a continuum there means the flagged ones are its
    // tail. Isolated events (8–15 σ is typical of a beam interruption) fall beyond it.
    let scale = robust_scale(&mut fin.resid.clone());
    let n_mid = fin
        .resid
        .iter()
        .filter(|r| (3.0 * scale..FAR * scale).contains(&r.abs()))
        .count() as f64;
    let p_mid = Normal::new(0.0, 1.0)
        .map(|d| 2.0 * (d.cdf(-3.0) - d.cdf(-FAR)))
        .unwrap_or(0.0027);
    let expected = n as f64 * p_mid;
    // And the kurtosis of the readings inside the bound: 3 for normal noise, with a sampling
    // standard deviation of √(24/n).
    let inside: Vec<f64> = (0..n)
        .filter(|&j| fin.eval[j])
        .map(|j| fin.resid[j])
        .collect();
    let m2 = inside.iter().map(|r| r * r).sum::<f64>() / inside.len().max(1) as f64;
    let m4 = inside.iter().map(|r| r.powi(4)).sum::<f64>() / inside.len().max(1) as f64;
    let kurtosis = if m2 > 0.0 { m4 / (m2 * m2) } else { 3.0 };
    // Flagged readings that all stay below 6.5 robust scales are the tail of the noise.
    let n_far = (0..n)
        .filter(|&j| fin.out[j] && fin.resid[j].abs() >= FAR * scale)
        .count();
    // How likely is at least this many readings in the zone under normal noise (Poisson with
    // the normal expectation)? A tail that continues into the bulk is heavy.
    let p_mid_excess = if n_mid >= 1.0 {
        Poisson::new(expected.max(1e-9)).map_or(1.0, |d| 1.0 - d.cdf(n_mid as u64 - 1))
    } else {
        1.0
    };
    let heavy_tails = n_out > 0
        && (n_far == 0
            || p_mid_excess < HEAVY_TAIL_ALPHA
            || kurtosis > 3.0 + 3.0 * (24.0 / inside.len().max(1) as f64).sqrt()
            || tails_as_likely(&fin.resid, &fin.out));
    Residue {
        rho,
        sigma_short_um,
        rms_left_um,
        heavy_tails,
        outlier_share: n_out as f64 / n.max(1) as f64,
    }
}

/// Do the residuals fit a Student-t noise better than normal noise with the flagged readings
/// as isolated events? The two models by their BIC, the lower one taken:
/// - the t: its scale and degrees of freedom (the best of a grid from 2.2 to 50);
/// - the events: normal noise for the kept readings, and each reading an event with a
///   probability q, its value then uniform within ±R (scale, q and R fitted: q = k/N, R the
///   largest residual).
///
/// The whole shape of the residuals is weighed, not only a zone: on a short run one reading
/// 6 σ out with a few at 3–4 σ is the tail of a t with 3–5 degrees of freedom rather than a
/// beam cut.
fn tails_as_likely(resid: &[f64], out: &[bool]) -> bool {
    let n = resid.len() as f64;
    let k = out.iter().filter(|o| **o).count() as f64;
    let kept: Vec<f64> = (0..resid.len())
        .filter(|&j| !out[j])
        .map(|j| resid[j])
        .collect();
    let var = kept.iter().map(|r| r * r).sum::<f64>() / kept.len().max(1) as f64;
    let span = resid.iter().fold(0.0_f64, |m, r| m.max(r.abs()));
    if var <= 0.0 || k == 0.0 || k >= n || span <= 0.0 {
        return false;
    }
    let q = k / n;
    let ll_events = -0.5 * kept.len() as f64 * ((std::f64::consts::TAU * var).ln() + 1.0)
        + k * (q / (2.0 * span)).ln()
        + (n - k) * (1.0 - q).ln();
    let ll_t = [
        2.2, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 15.0, 25.0, 50.0,
    ]
    .iter()
    .map(|&nu| student_t_loglik(resid, nu, var.sqrt()))
    .fold(f64::NEG_INFINITY, f64::max);
    let bic_events = -2.0 * ll_events + 3.0 * n.ln();
    let bic_t = -2.0 * ll_t + 2.0 * n.ln();
    bic_t < bic_events
}

/// Maximum log-likelihood of `r` under a Student t with `nu` degrees of freedom over its
/// scale (EM iteration for the scale, started at `s0`).
fn student_t_loglik(r: &[f64], nu: f64, s0: f64) -> f64 {
    let mut s2 = s0 * s0;
    for _ in 0..100 {
        let next = r
            .iter()
            .map(|x| (nu + 1.0) / (nu + x * x / s2) * x * x)
            .sum::<f64>()
            / r.len() as f64;
        let done = (next - s2).abs() <= 1e-10 * s2;
        s2 = next.max(f64::MIN_POSITIVE);
        if done {
            break;
        }
    }
    StudentsT::new(0.0, s2.sqrt(), nu)
        .map(|d| r.iter().map(|x| d.ln_pdf(*x)).sum())
        .unwrap_or(f64::NEG_INFINITY)
}

impl Residue {
    pub(super) fn unexplained(&self) -> bool {
        (self.sigma_short_um > 0.0 && self.rms_left_um > UNEXPLAINED_RATIO * self.sigma_short_um)
            || self.outlier_share > MAX_OUTLIER_SHARE
    }

    /// Factor on the uncertainties of fitted parameters for correlated noise.
    pub(super) fn u_factor(&self) -> f64 {
        let r = self.rho.clamp(0.0, 0.95);
        ((1.0 + r) / (1.0 - r)).sqrt()
    }
}

/// The `unexplained` finding.
pub(super) fn unexplained_finding(obs: &Obs, fin: &FinalFit, res: &Residue) -> Finding {
    let ho = heldout_rms(obs, &fin.w, &fin.cols, &fin.eval);
    let ratio = res.rms_left_um / res.sigma_short_um.max(f64::MIN_POSITIVE);
    let share = if res.outlier_share > MAX_OUTLIER_SHARE {
        format!(
            "; {:.0} % of the readings are far off their target's trend — too many to be \
             isolated outliers",
            100.0 * res.outlier_share
        )
    } else {
        String::new()
    };
    Finding {
        effect: "unexplained".into(),
        params: BTreeMap::from([("rms_um".into(), res.rms_left_um)]),
        params_u: BTreeMap::new(),
        significance: obs.len() as f64 * (ratio * ratio).max(1.0).ln(),
        heldout_rms_before_um: ho,
        heldout_rms_after_um: ho,
        cause: format!(
            "after the best model {:.2} µm RMS is left, {ratio:.1}× the short-term noise of \
             {:.2} µm that successive readings show{share}: the data hold structure no effect \
             of the vocabulary explains. Suspect the measuring system first — a reference \
             sensor that jumps or is out of range, a loose sensor or target mount, a beam cut \
             or misaligned — then the axis; check the reference against a second one and \
             repeat the run",
            res.rms_left_um, res.sigma_short_um
        ),
        alternatives: Vec::new(),
    }
}

/// Findings not to report next to `unexplained` (indices into `findings`), with why:
/// - a mean effect that gains less than [`MIN_GAIN_WHEN_UNEXPLAINED`] of the held-out error
///   only stretches over structure it does not explain;
/// - a machine effect (a drift, warm-up, cycle, scale change, reversal change or one noisy
///   target) must explain more than [`MACHINE_DOMINANCE`] × the RMS left unexplained: a
///   reference that jumps and stays at each level also shifts the mean path, and a fitted
///   cycle or drift through its jumps would name a machine cause for a measuring-system
///   fault. A step or offsets per cycle already name the measuring system and stay.
pub(super) fn demoted_next_to_unexplained(
    findings: &[Finding],
    rms_left_um: f64,
) -> Vec<(usize, &'static str)> {
    (0..findings.len())
        .filter_map(|i| {
            let f = &findings[i];
            let (b, a) = (f.heldout_rms_before_um, f.heldout_rms_after_um);
            let gain = 1.0 - a / b.max(1e-300);
            let explained = (b * b - a * a).max(0.0).sqrt();
            let machine = !matches!(f.effect.as_str(), "step" | "cycle_offsets" | "outliers");
            if f.effect != "local_anomaly" && gain < MIN_GAIN_WHEN_UNEXPLAINED {
                Some((i, "it would stretch over structure it does not explain"))
            } else if machine && explained <= MACHINE_DOMINANCE * rms_left_um {
                Some((
                    i,
                    "it cannot be told from the unexplained structure (a reference that jumps \
                     also moves the mean path): check the measuring system, then repeat the run",
                ))
            } else {
                None
            }
        })
        .collect()
}

/// The sentence that says which combination explains the run.
pub(super) fn conclusion(findings: &[Finding], baseline_heldout: f64, noise_um: f64) -> String {
    if let Some(u) = findings.iter().find(|f| f.effect == "unexplained") {
        let others: Vec<&str> = findings
            .iter()
            .filter(|f| f.effect != "unexplained")
            .map(|f| f.effect.as_str())
            .collect();
        let with = if others.is_empty() {
            String::new()
        } else {
            format!(" besides {}", others.join(" + "))
        };
        return format!(
            "unexplained: {:.2} µm RMS of structure is left{with} that no effect of the \
             vocabulary explains; the measuring system is the first suspect",
            u.params.get("rms_um").copied().unwrap_or(0.0)
        );
    }
    if findings.is_empty() {
        return format!(
            "the baseline (a constant deviation per target and direction plus {noise_um:.2} µm \
             of noise) explains the run: no effect beyond the noise"
        );
    }
    let names: Vec<String> = findings
        .iter()
        .map(|f| {
            if f.alternatives.is_empty() {
                f.effect.clone()
            } else {
                let alts: Vec<&str> = f.alternatives.iter().map(|a| a.effect.as_str()).collect();
                format!(
                    "{} (or {}: the data cannot tell)",
                    f.effect,
                    alts.join(" or ")
                )
            }
        })
        .collect();
    format!(
        "the run is explained by {} on top of the baseline (held-out error of the baseline \
         {baseline_heldout:.2} µm; each finding gives its own gain)",
        names.join(" + ")
    )
}
