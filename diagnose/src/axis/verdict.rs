//! What the report concludes once the effects are fitted: whether the noise is correlated or
//! heavy-tailed (then the evidence and the outliers are read accordingly), whether structure
//! is left that no effect explains (`unexplained`), and which combination explains the run
//! (`docs/datasets.md`, "Diagnosis report"; `docs/methods.md`, "Diagnosis").

#![allow(clippy::needless_range_loop)]

use std::collections::BTreeMap;

use super::correlation::design_lag1;
use super::fit::{FinalFit, heldout_rms};
use super::obs::Obs;
use super::outliers::robust_scale;
use super::tails::{EVENTS_BAYES_FACTOR, ln_bayes_factor_events};
use super::types::{Finding, Found, Stated};
use positioning::axis_model::EffectKind;

/// Residual RMS above this many times the short-term noise is structure, not noise.
const UNEXPLAINED_RATIO: f64 = 3.0;
/// Short-term noise below this is no noise (rounding of equal readings), µm.
const NOISE_FLOOR_UM: f64 = 1e-9;
/// More flagged readings than this share are not isolated outliers.
pub(super) const MAX_OUTLIER_SHARE: f64 = 0.10;
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
    // The flagged readings are the tail of the noise unless isolated events explain all the
    // residuals clearly better than a heavy-tailed noise does (tails.rs).
    let heavy_tails = n_out > 0
        && ln_bayes_factor_events(&fin.resid, MAX_OUTLIER_SHARE) < EVENTS_BAYES_FACTOR.ln();
    Residue {
        rho,
        sigma_short_um,
        rms_left_um,
        heavy_tails,
        outlier_share: n_out as f64 / n.max(1) as f64,
    }
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
    // Successive readings that differ by less than any instrument resolves show no noise to
    // compare with (a fuzzed file of equal readings gave a ratio of 10²⁹⁰ and significance ∞).
    let ratio = (res.sigma_short_um > NOISE_FLOOR_UM).then(|| res.rms_left_um / res.sigma_short_um);
    let against_noise = match ratio {
        Some(r) => format!(
            "{r:.1}× the short-term noise of {:.2} µm that successive readings show",
            res.sigma_short_um
        ),
        None => "and successive readings show no short-term noise to compare it with".into(),
    };
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
        effect: Found::Unexplained {
            rms_um: res.rms_left_um,
        },
        stated: Stated::default(),
        params_u: BTreeMap::new(),
        significance: obs.len() as f64 * ratio.map_or(1.0, |r| (r * r).max(1.0)).ln(),
        heldout_rms_before_um: ho,
        heldout_rms_after_um: ho,
        cause: format!(
            "after the best model {:.2} µm RMS is left, {against_noise}{share}: the data hold \
             structure no effect of the vocabulary explains. Suspect the measuring system \
             first — a reference sensor that jumps or is out of range, a loose sensor or target \
             mount, a beam cut or misaligned — then the axis; check the reference against a \
             second one and repeat the run",
            res.rms_left_um
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
            let machine = !matches!(
                f.effect.kind(),
                Some(EffectKind::Step | EffectKind::CycleOffsets | EffectKind::Outliers)
            );
            if f.effect.kind() != Some(EffectKind::LocalAnomaly) && gain < MIN_GAIN_WHEN_UNEXPLAINED
            {
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
    let unexplained = findings.iter().find_map(|f| match f.effect {
        Found::Unexplained { rms_um } => Some(rms_um),
        Found::Effect(_) => None,
    });
    if let Some(rms_um) = unexplained {
        let others: Vec<&str> = findings
            .iter()
            .filter(|f| f.effect.kind().is_some())
            .map(|f| f.effect.name())
            .collect();
        let with = if others.is_empty() {
            String::new()
        } else {
            format!(" besides {}", others.join(" + "))
        };
        return format!(
            "unexplained: {:.2} µm RMS of structure is left{with} that no effect of the \
             vocabulary explains; the measuring system is the first suspect",
            rms_um
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
                f.effect.name().to_string()
            } else {
                let alts: Vec<&str> = f.alternatives.iter().map(|a| a.effect.name()).collect();
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
