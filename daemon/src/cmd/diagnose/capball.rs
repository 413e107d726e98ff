//! `metrolog diagnose` on CapBall data (`docs/datasets.md`, CapBall dataset and effects): what
//! the 14-parameter link/setup model gets wrong, with the validation run's gain.

use std::path::Path;

use anyhow::Context as _;
use diagnose::capball::{
    self as capball_diagnosis, CapballDiagnosis, DriftRecord, Options, parse_drift_record,
    runs_from_records,
};
use geometry::capball::CapballSetup;

/// Diagnose a CapBall dataset (run 1 identifies, the others validate), with an optional drift
/// record at one fixed pose.
pub fn diagnose_path(path: &Path, drift: Option<&Path>) -> anyhow::Result<CapballDiagnosis> {
    let input = crate::cmd::input::load_capball(path, None)?;
    let mut notes: Vec<String> = input.damage_note().into_iter().collect();
    notes.extend(
        input
            .skipped
            .iter()
            .map(|(pose, status)| format!("CapBall pose {pose} skipped ({status})")),
    );
    let (recs, machine) = (input.records, input.machine);
    if let Some(name) = &input.machine_name {
        notes.push(format!("machine: {name}"));
    }
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
            let t = crate::cmd::input::read_text(p)?;
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
    notes.append(&mut d.report.notes);
    d.report.notes = notes;
    Ok(d)
}

/// The `[capball.truth]` section of a simulator scenario with the found effects (TOML).
#[cfg(feature = "sim")]
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

/// A build without the simulator (`--no-default-features`) cannot write its scenario.
#[cfg(not(feature = "sim"))]
pub fn scenario_section(_: &CapballDiagnosis, _: &Path) -> anyhow::Result<String> {
    Err(no_simulator())
}

fn no_simulator() -> anyhow::Error {
    anyhow::anyhow!(
        "--write-model on CapBall data writes the simulator's [capball.truth] table: this \
         metrolog was built without the simulator (the service build); build it with the \
         default features to write the model"
    )
}

/// `metrolog diagnose` for CapBall input: the report (JSON or text) on stdout, the extended
/// model to `write_model`.
pub fn run(
    input: &Path,
    drift_record: Option<&Path>,
    write_model: Option<&Path>,
    json: bool,
) -> anyhow::Result<()> {
    if write_model.is_some() && !cfg!(feature = "sim") {
        // Before the diagnosis, which takes a while.
        return Err(no_simulator());
    }
    let mut d = diagnose_path(input, drift_record)?;
    if let Some(p) = write_model {
        let text = scenario_section(&d, input)?;
        std::fs::write(p, text).with_context(|| format!("writing {}", p.display()))?;
        d.report.extended_model = Some(p.display().to_string());
    }
    let text = if json {
        serde_json::to_string_pretty(&d.report)? + "\n"
    } else {
        metrolog_analysis::diagnosis_text::capball_text(&d)
    };
    crate::cmd::input::print_out(&text)
}
