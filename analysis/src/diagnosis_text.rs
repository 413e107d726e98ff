//! A diagnosis as text: `metrolog diagnose` prints it, and the demo report includes it.

use std::fmt::Write as _;

use crate::export::{result_or, xyz_or};

use diagnose::axis::Diagnosis;
use diagnose::capball::CapballDiagnosis;

/// The human-readable diagnosis.
pub fn positioning_text(d: &Diagnosis) -> String {
    let r = &d.report;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Baseline (static deviation per target and direction + stationary noise): RMS residual \
         {:.3} µm, held-out cycles {:.3} µm",
        r.baseline.rms_um, r.baseline.heldout_rms_um
    );
    if r.findings.is_empty() {
        let _ = writeln!(
            s,
            "No finding: the baseline explains the data (noise {} µm).",
            result_or(
                d.model.noise_um,
                3,
                "the residuals do not give a finite scatter"
            )
        );
    }
    for (k, f) in r.findings.iter().enumerate() {
        let params: Vec<String> = f
            .params()
            .into_iter()
            .map(|(name, v)| match f.params_u.get(name) {
                Some(u) => format!("{name} = {v:.4} ± {u:.2}"),
                None => format!("{name} = {v:.4}"),
            })
            .collect();
        write_finding(
            &mut s,
            (k + 1, f.effect.name(), f.significance),
            &params,
            ("held-out", f.heldout_rms_before_um, f.heldout_rms_after_um),
            &f.cause,
        );
    }
    if !r.conclusion.is_empty() {
        let _ = writeln!(s, "\nConclusion: {}", r.conclusion);
    }
    if let Some(rep) = &r.reproduction {
        let _ = writeln!(
            s,
            "\nSimulating the same run ({} seeds) — RMS of simulated − measured per-target statistics:\n   \
             extended model: x̄ {:.3} µm, s {:.3} µm\n   baseline model: x̄ {:.3} µm, s {:.3} µm",
            rep.seeds,
            rep.mean_rms_um,
            rep.s_rms_um,
            rep.baseline_mean_rms_um,
            rep.baseline_s_rms_um
        );
    }
    if let Some(p) = &r.extended_model {
        let _ = writeln!(s, "\nExtended model written to {p}");
    }
    for n in &r.notes {
        let _ = writeln!(s, "Note: {n}");
    }
    s
}

/// One finding of a diagnosis report as text: number, effect and significance, parameters,
/// the error before → after on the run the effect was checked against, and the cause.
fn write_finding(
    s: &mut String,
    (number, effect, significance): (usize, &str, f64),
    params: &[String],
    (checked_on, before_um, after_um): (&str, f64, f64),
    cause: &str,
) {
    let _ = writeln!(s, "\n{number}. {effect} (significance {significance:.1})");
    let _ = writeln!(s, "   {}", params.join(", "));
    let _ = writeln!(s, "   {checked_on} error {before_um:.3} → {after_um:.3} µm");
    let _ = writeln!(s, "   cause: {cause}");
}

/// The human-readable CapBall diagnosis.
pub fn capball_text(d: &CapballDiagnosis) -> String {
    let r = &d.report;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Baseline (14-parameter link/setup model + white noise): RMS residual {:.3} µm, \
         validation run {:.3} µm",
        r.baseline.rms_um, r.baseline.heldout_rms_um
    );
    if r.findings.is_empty() {
        let _ = writeln!(s, "No finding: the baseline explains the data.");
    }
    for (k, f) in r.findings.iter().enumerate() {
        let params: Vec<String> = f
            .summary_params()
            .into_iter()
            .map(|(n, v)| match f.params_u.get(n) {
                Some(u) => format!("{n} = {} ± {}", compact(&v), compact(u)),
                None => format!("{n} = {}", compact(&v)),
            })
            .collect();
        write_finding(
            &mut s,
            (k + 1, f.effect.name(), f.significance),
            &params,
            (
                "validation",
                f.heldout_rms_before_um,
                f.heldout_rms_after_um,
            ),
            &f.cause,
        );
    }
    let moved: Vec<String> = r
        .parameters
        .iter()
        .filter(|p| p.shift_sigma.abs() >= 2.0)
        .map(|p| {
            format!(
                "{} {:.2} → {:.2} ({:+.1} σ)",
                p.name, p.baseline, p.extended, p.shift_sigma
            )
        })
        .collect();
    if !moved.is_empty() {
        let _ = writeln!(
            s,
            "\nIdentified parameters once the effects are modelled: {}",
            moved.join("; ")
        );
    }
    for res in &r.residuals {
        let _ = writeln!(
            s,
            "Residual RMS ({}) {} µm; white noise {} µm",
            res.run,
            xyz_or(res.rms_um, 3, "the run's residuals are not finite"),
            xyz_or(
                res.noise_um,
                3,
                "the pose-to-pose differences give no finite value"
            ),
        );
    }
    if let Some(p) = &r.extended_model {
        let _ = writeln!(s, "\nExtended model written to {p}");
    }
    for n in &r.notes {
        let _ = writeln!(s, "Note: {n}");
    }
    s
}

/// A JSON value in a short form (numbers to 4 significant places).
fn compact(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => n.as_f64().map(|x| format!("{x:.4}")).unwrap_or_default(),
        serde_json::Value::Object(m) => {
            let parts: Vec<String> = m
                .iter()
                .map(|(k, v)| format!("{k} {}", compact(v)))
                .collect();
            format!("{{{}}}", parts.join(", "))
        }
        serde_json::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}
