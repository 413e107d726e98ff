//! `metrolog diagnose` on CapBall data (`docs/datasets.md`, CapBall dataset and effects): what
//! the 14-parameter link/setup model gets wrong, with the validation run's gain.

use std::path::Path;

use anyhow::Context as _;
use diagnose::capball::{
    self as capball_diagnosis, CapballDiagnosis, DriftRecord, Options, parse_drift_record,
    runs_from_records,
};
use geometry::capball::{self, CapballRecord, CapballSetup};
use geometry::kinematics::Machine;

/// Whether `path` holds CapBall data: a CSV whose header names `ex_um` (an MCAP log is
/// CapBall data only when asked for with `--capball`).
pub fn is_capball_csv(path: &Path) -> bool {
    if metrolog_analysis::is_mcap(path) {
        return false;
    }
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
                .map(|h| h.split(',').any(|c| c.trim() == "ex_um"))
        })
        .unwrap_or(false)
}

/// The CapBall records of a CSV dataset or an MCAP log, and the machine they were read with.
pub fn load(path: &Path) -> anyhow::Result<(Vec<CapballRecord>, Machine, Vec<String>)> {
    let mut notes = Vec::new();
    if metrolog_analysis::is_mcap(path) {
        let cb = super::progress::read_contents(path, "reading")
            .and_then(|log| metrolog_analysis::capball::capball_from_contents_auto(&log))
            .with_context(|| format!("reading the CapBall poses of {}", path.display()))?;
        for (pose, status) in &cb.skipped {
            notes.push(format!("CapBall pose {pose} skipped ({status})"));
        }
        notes.push(format!("machine: {}", cb.machine_name));
        return Ok((cb.records, cb.machine, notes));
    }
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let recs = capball::parse_dataset(&text).with_context(|| format!("{}", path.display()))?;
    let machine = Machine::from_config(&CapballSetup::paper_machine_config())?;
    Ok((recs, machine, notes))
}

/// Diagnose a CapBall dataset (run 1 identifies, the others validate), with an optional drift
/// record at one fixed pose.
pub fn diagnose_path(path: &Path, drift: Option<&Path>) -> anyhow::Result<CapballDiagnosis> {
    let (recs, machine, mut notes) = load(path)?;
    if recs.iter().any(|r| r.time_s.is_none()) {
        notes.push(
            "no `time_s` for some poses: their pose number stands in for seconds, so drift rates and periods are per pose".into(),
        );
    }
    let (ident, validation) = runs_from_records(&recs).with_context(|| {
        format!(
            "{}: a CapBall diagnosis needs run 1 (identification) and run 2 (validation, A reversed)",
            path.display()
        )
    })?;
    let setup = CapballSetup::with_ball_from_poses(machine, &ident.poses)
        .with_context(|| format!("{}: run 1", path.display()))?;
    let record: Option<DriftRecord> = match drift {
        Some(p) => {
            let t =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            Some(parse_drift_record(&t).with_context(|| format!("{}", p.display()))?)
        }
        None => None,
    };
    let mut d = capball_diagnosis::diagnose(
        &setup,
        &ident,
        &validation,
        record.as_ref(),
        &Options::default(),
    )
    .with_context(|| format!("diagnosing {}", path.display()))?;
    d.report.notes.extend(notes);
    Ok(d)
}

/// The `[capball.truth]` section of a simulator scenario with the found effects (TOML).
pub fn scenario_section(d: &CapballDiagnosis, source: &Path) -> anyhow::Result<String> {
    #[derive(serde::Serialize)]
    struct Section {
        capball: Truth,
    }
    #[derive(serde::Serialize)]
    struct Truth {
        truth: ::sim::scenario::CapballModel,
    }
    let toml = toml::to_string_pretty(&Section {
        capball: Truth {
            truth: ::sim::scenario::CapballModel::from_diagnosis(d),
        },
    })
    .context("serialising the CapBall model")?;
    let found = d.report.effects();
    Ok(format!(
        "# CapBall model extended by `metrolog diagnose {}`: the 14 parameters identified with\n\
         # the effects modelled, plus the effects found ({}). Times are the dataset's clock.\n\
         # Replace the scenario's [capball.truth] table with this one.\n{toml}",
        source.display(),
        if found.is_empty() {
            "none".to_string()
        } else {
            found.join(", ")
        }
    ))
}

/// `metrolog diagnose` for CapBall input.
pub fn run(args: &crate::cmd::diagnose::Args) -> anyhow::Result<()> {
    let mut d = diagnose_path(&args.input, args.drift_record.as_deref())?;
    if let Some(p) = &args.write_model {
        let text = scenario_section(&d, &args.input)?;
        std::fs::write(p, text).with_context(|| format!("writing {}", p.display()))?;
        d.report.extended_model = Some(p.display().to_string());
    }
    let text = if args.json {
        serde_json::to_string_pretty(&d.report)? + "\n"
    } else {
        metrolog_analysis::diagnosis_text::capball_text(&d)
    };
    crate::cmd::input::print_out(&text)
}
