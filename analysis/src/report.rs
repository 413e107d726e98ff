//! The text the `demo` command prints at its end: every analysis of the run's log.

use std::fmt::Write as _;
use std::path::Path;

use diagnose::axis::{self, Options};
use geometry::capball::CapballSetup;
use geometry::kinematics::Pose;
use positioning::positioning_data::PositioningData;

use super::capball::identify_subset;
use crate::contents::{AnalysisError, LogContents};
use crate::positioning::PositioningOptions;

fn opt(v: Option<f64>) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{v:.2}"))
}

/// The analyses of the log at `path` as compact text. A part that cannot be computed says why
/// in its place; `Err` only when the log cannot be read at all.
pub fn demo_report(path: &Path) -> Result<String, AnalysisError> {
    let log = LogContents::read(path)?;
    let mut s = String::new();
    let _ = writeln!(s, "Analysis of {}", path.display());
    if let Some(d) = log.damage() {
        let _ = writeln!(
            s,
            "BUILT ON PART OF THE RUN: the log is damaged: {d}; the ISO 230-2, CapBall and PSD \
             results below use the readings before the damage only"
        );
    }
    positioning_section(&log, &mut s);
    capball_section(&log, &mut s);
    psd_section(&log, &mut s);
    Ok(s)
}

/// ISO 230-2 of the run's positioning poses, and the diagnosis of that run.
fn positioning_section(log: &LogContents, s: &mut String) {
    match super::positioning::positioning_from_contents(log, &PositioningOptions::default()) {
        Err(e) => {
            let _ = writeln!(s, "\nISO 230-2: not available: {e}");
        }
        Ok(data) => {
            let an = crate::positioning_report::analyze_positioning(&data, None);
            let a = &an.iso230_2;
            let _ = writeln!(
                s,
                "\nISO 230-2, axis X (poses {}, {} targets × {} cycles, {} missing), µm:",
                data.metadata.get("poses").map_or("?", String::as_str),
                an.n_targets,
                an.n_cycles,
                an.missing.len()
            );
            let _ = writeln!(
                s,
                "  A {}  A↑ {}  A↓ {}  E {}  E↑ {}  E↓ {}",
                opt(a.a),
                opt(a.a_up),
                opt(a.a_down),
                opt(a.e),
                opt(a.e_up),
                opt(a.e_down)
            );
            let _ = writeln!(
                s,
                "  R {}  R↑ {}  R↓ {}  B {}  B̄ {}  M {}",
                opt(a.r),
                opt(a.r_up),
                opt(a.r_down),
                opt(a.b),
                opt(a.b_mean),
                opt(a.m)
            );
            for n in &an.notes {
                let _ = writeln!(s, "  note: {n}");
            }
            diagnosis_section(&data, s);
        }
    }
}

fn diagnosis_section(data: &PositioningData, s: &mut String) {
    match axis::diagnose(data, &Options::default()) {
        Err(e) => {
            let _ = writeln!(s, "\nDiagnosis: not available: {e}");
        }
        Ok(d) => {
            let r = &d.report;
            let _ = writeln!(
                s,
                "\nDiagnosis (baseline RMS {:.3} µm, held-out {:.3} µm):",
                r.baseline.rms_um, r.baseline.heldout_rms_um
            );
            if r.findings.is_empty() {
                let _ = writeln!(s, "  no finding: the baseline explains the data");
            }
            for (k, f) in r.findings.iter().enumerate() {
                let params: Vec<String> = f
                    .params()
                    .into_iter()
                    .map(|(n, v)| match f.params_u.get(n) {
                        Some(u) => format!("{n} = {v:.3} ± {u:.3}"),
                        None => format!("{n} = {v:.3}"),
                    })
                    .collect();
                let _ = writeln!(
                    s,
                    "  {}. {}: {}\n     held-out {:.3} → {:.3} µm; cause: {}",
                    k + 1,
                    f.effect,
                    params.join(", "),
                    f.heldout_rms_before_um,
                    f.heldout_rms_after_um,
                    f.cause
                );
            }
            if !r.conclusion.is_empty() {
                let _ = writeln!(s, "  conclusion: {}", r.conclusion);
            }
        }
    }
}

/// The CapBall link-error identification of the run's CapBall poses.
fn capball_section(log: &LogContents, s: &mut String) {
    match super::capball::capball_from_contents_auto(log) {
        Err(e) => {
            let _ = writeln!(s, "\nCapBall: not available: {e}");
        }
        Ok(cb) => {
            // Run 1 identifies; a second run (A reversed) validates, in the diagnosis below.
            let ident = cb.records.iter().filter(|r| r.run == 1);
            let poses: Vec<Pose> = ident.clone().map(|r| r.pose).collect();
            let meas: Vec<[f64; 3]> = ident.map(|r| r.e_um).collect();
            let res = CapballSetup::with_ball_from_poses(cb.machine.clone(), &poses)
                .map_err(AnalysisError::from)
                .and_then(|st| identify_subset(&st, &poses, &meas));
            match res {
                Err(e) => {
                    let _ = writeln!(
                        s,
                        "\nCapBall ({} poses): identification failed: {e}",
                        poses.len()
                    );
                }
                Ok(id) => {
                    let _ = writeln!(
                        s,
                        "\nCapBall identification ({} poses{}, ball at {:.1}, {:.1}, {:.1} mm, \
                         machine {}): condition number {:.1}",
                        id.n_poses,
                        if cb.skipped.is_empty() {
                            String::new()
                        } else {
                            format!(", {} skipped", cb.skipped.len())
                        },
                        cb.ball_mm.x,
                        cb.ball_mm.y,
                        cb.ball_mm.z,
                        cb.machine_name,
                        id.condition_number
                    );
                    for chunk in id.params.chunks(4) {
                        let cells: Vec<String> = chunk
                            .iter()
                            .map(|(n, p, u)| format!("{n} {p:.2} ± {u:.2}"))
                            .collect();
                        let _ = writeln!(s, "  {}", cells.join("   "));
                    }
                    if !id.fixed.is_empty() {
                        let _ = writeln!(
                            s,
                            "  not separable with these poses (held at 0): {}",
                            id.fixed.join(", ")
                        );
                    }
                    let _ = writeln!(
                        s,
                        "  residual RMS {} µm",
                        crate::export::xyz_or(id.residual_rms_um, 3, "residuals not finite")
                    );
                }
            }
            capball_diagnosis_section(&cb, s);
        }
    }
}

/// The CapBall diagnosis (`metrolog diagnose --capball`) when the log holds an identification
/// run and a validation run (A reversed).
fn capball_diagnosis_section(cb: &super::capball::CapballFromLog, s: &mut String) {
    use diagnose::capball::{self, runs_from_records};
    let Ok((ident, validation)) = runs_from_records(&cb.records) else {
        let _ = writeln!(
            s,
            "\nCapBall diagnosis: not available: the log holds one run (a second run with A \
             reversed validates)"
        );
        return;
    };
    let d = CapballSetup::with_ball_from_poses(cb.machine.clone(), &ident.poses)
        .map_err(AnalysisError::from)
        .and_then(|setup| {
            capball::diagnose(
                &setup,
                &ident,
                &validation,
                None,
                &capball::Options::default(),
            )
            .map_err(AnalysisError::from)
        });
    match d {
        Err(e) => {
            let _ = writeln!(s, "\nCapBall diagnosis: not available: {e}");
        }
        Ok(d) => {
            let _ = writeln!(
                s,
                "\nCapBall diagnosis (run 1 identifies, {} validation pose(s); `metrolog diagnose \
                 --capball LOG`):",
                validation.iter().map(|v| v.poses.len()).sum::<usize>()
            );
            for line in super::diagnosis_text::capball_text(&d).lines() {
                let _ = writeln!(s, "  {line}");
            }
        }
    }
}

/// The straightness of the run's PSD segment.
fn psd_section(log: &LogContents, s: &mut String) {
    match super::psd::psd_from_contents(log, None) {
        Err(e) => {
            let _ = writeln!(s, "\nPSD: not available: {e}");
        }
        Ok(seg) => {
            let (nx, ny) = seg.error_names();
            let _ = writeln!(
                s,
                "\nPSD straightness along {} (poses {}-{}, {} points, offset and slope removed):\n  \
                 {nx} {:.2} µm, {ny} {:.2} µm (slopes {:.4}, {:.4} µm/mm); the 13-error frame \
                 identification needs the 51-point frame and a reference run",
                seg.axis,
                seg.first_pose,
                seg.last_pose,
                seg.points.len(),
                seg.straightness_x_um,
                seg.straightness_y_um,
                seg.slope_x_um_per_mm,
                seg.slope_y_um_per_mm
            );
        }
    }
}
