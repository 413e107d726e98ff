//! The analysis paths of the CapBall, PSD, thermal and uncertainty-budget inputs, as their
//! commands take them (issue 27): shared by the cargo-fuzz targets `capball_path`, `psd_path`,
//! `thermal_path`, `thermal_fit_path` and `budget_path` (`protocol/fuzz`) and the corpus
//! replay test (`daemon/tests/fuzz_paths.rs`). Each panics when the path breaks a promise on
//! its input: no panic anywhere, and no NaN or infinity in a text, JSON or CSV output of an
//! input the reader accepts. Not part of the API.

use std::path::Path;

use geometry::capball::CapballSetup;
use geometry::kinematics::Machine;
use geometry::psd_frame::{self, PsdLayout};
use metrolog_analysis::fuzzcheck::non_finite_word;

use crate::cmd::identify::{capball as cb, psd};
use crate::cmd::thermal::{fit, iso230_3, predict};

/// The input's name in messages.
const INPUT: &str = "fuzz.csv";

fn assert_finite_text(what: &str, out: &str, input: &str) {
    if let Some(w) = non_finite_word(out) {
        panic!("`{w}` in {what} of an accepted input:\n{out}\n--- input:\n{input}");
    }
}

/// JSON of a result: serde_json writes a NaN or an infinity as `null`, so the check is on the
/// Debug form of the same value.
fn assert_finite_value(what: &str, v: &impl std::fmt::Debug, input: &str) {
    assert_finite_text(what, &format!("{v:?}"), input);
}

/// CapBall CSV → the dataset reader → every run identified on the paper's machine (the
/// command's default) → the text report. Returns the reports (`None`: the reader refused).
pub fn capball_path(text: &str) -> Option<Vec<String>> {
    let records = geometry::capball::parse_dataset(text).ok()?;
    let machine = Machine::from_config(&CapballSetup::paper_machine_config()).ok()?;
    let mut out = vec![];
    for (run, poses, meas) in cb::runs_of(&records) {
        let Ok(setup) = CapballSetup::with_ball_from_poses(machine.clone(), &poses) else {
            continue;
        };
        let Ok(id) = setup.identify(&poses, &meas) else {
            continue;
        };
        let report = cb::identification_text(run, &setup.ball_mm, &id, None);
        assert_finite_text("the identification report", &report, text);
        out.push(report);
    }
    Some(out)
}

/// PSD readings CSV → the reader on paper 003's layout → every run's 13 errors against the
/// first run → the text report with the uncertainty of a 0.2 µm reading.
pub fn psd_path(text: &str) -> Option<String> {
    let layout = PsdLayout::paper();
    let runs = psd_frame::parse_readings_csv(&layout, text).ok()?;
    let reference = runs.first()?.0;
    let out = psd::errors_against(&layout, &runs, reference).ok()?;
    let u = psd_frame::derive_uncertainty(&layout, 0.2 * 2f64.sqrt()).ok()?;
    let report = psd::errors_text(reference, &out, &u);
    assert_finite_text("the PSD report", &report, text);
    for (_, e) in &out {
        assert_finite_value("the PSD errors", e, text);
    }
    Some(report)
}

/// Thermal CSV → the dataset reader → ISO 230-3 (ETVE) → the thermal model: fitted, written as
/// JSON, read back, described, predicting the same data → the diagnosis.
pub fn thermal_path(text: &str) -> Option<Vec<String>> {
    thermal_outputs(text, true)
}

/// `thermal_path` without the diagnosis (the cargo-fuzz target `thermal_fit_path`): the same
/// reader, ISO 230-3, fit, JSON and prediction at the speed a fuzzer needs (the diagnosis'
/// model search runs at 5–30 inputs a second).
pub fn thermal_fit_path(text: &str) -> Option<Vec<String>> {
    thermal_outputs(text, false)
}

fn thermal_outputs(text: &str, diagnose: bool) -> Option<Vec<String>> {
    let ds = thermal::ThermalDataset::from_csv(text).ok()?;
    let mut out = vec![];
    if let Ok(r) = iso230_3::evaluate(&ds, None, Path::new(INPUT)) {
        out.push(iso230_3::render(&r, INPUT));
    }
    if !ds.channel_names.is_empty() {
        if let Ok(model) = thermal::fit(&ds, &thermal::FitOptions::default()) {
            out.extend(thermal_model_outputs(&model, &ds, text));
        }
        if diagnose && let Ok(d) = thermal::diagnose(&ds, &thermal::DiagnoseOptions::default()) {
            out.push(d.render());
        }
    }
    for o in &out {
        assert_finite_text("a thermal output", o, text);
    }
    Some(out)
}

fn thermal_model_outputs(
    model: &thermal::ThermalModel,
    ds: &thermal::ThermalDataset,
    text: &str,
) -> Vec<String> {
    let mut out = vec![model.describe()];
    let Ok(json) = fit::model_json(model) else {
        return out;
    };
    let back: thermal::ThermalModel = match serde_json::from_str(&json) {
        Ok(m) => m,
        Err(e) => panic!("a written model does not read back ({e}):\n{json}\n--- input:\n{text}"),
    };
    if let Ok(p) = back.predict(ds) {
        let level = back.channels.first().map_or(0.95, |c| c.interval.level);
        if let Ok(csv) = predict::prediction_csv(&p, level) {
            out.push(csv);
        }
    }
    out.push(json);
    out
}

/// Budget TOML → the budget reader → GUM and a Monte Carlo of 1 000 trials with the §8
/// validation → the text report.
pub fn budget_path(text: &str) -> Option<String> {
    let budget = uncertainty::Budget::from_toml(text).ok()?;
    let opts = uncertainty::McOptions {
        fixed_trials: Some(1000),
        ..budget.mc_options()
    };
    let report = budget
        .evaluate(uncertainty::Method::Both, &opts, None)
        .ok()?;
    let t = metrolog_analysis::uncertainty_text::budget_text(&report, &budget);
    // The budget's own texts are printed as they are (a title "infinity model").
    let echoed = metrolog_analysis::fuzzcheck::echoed_words(budget.free_texts());
    if let Some(w) = metrolog_analysis::fuzzcheck::non_finite_word_except(&t, &echoed) {
        panic!("`{w}` in the budget report of an accepted input:\n{t}\n--- input:\n{text}");
    }
    Some(t)
}

/// Before and after samples of `metrolog parts`, one text with the after sample following a
/// line `---` → the readers → the comparison with tolerance [−10, 10] → the text and JSON.
pub fn parts_path(text: &str) -> Option<String> {
    let (before, after) = text.split_once("\n---\n")?;
    let b = positioning::parts::parse_sample("before", before).ok()?;
    let a = positioning::parts::parse_sample("after", after).ok()?;
    let r = positioning::parts::compare(&b, &a, -10.0, 10.0).ok()?;
    assert_finite_value("the parts comparison", &r, text);
    serde_json::to_string(&r).ok()
}

/// The example machine of `examples/models` (three linear axes).
const MACHINE_3AXIS: &str = include_str!("../../examples/models/machine_3axis.toml");

/// Component errors CSV → the reader → the volumetric errors on a 3 × 3 × 3 grid of the example
/// machine → the summary, the compensation CSV and the SINUMERIK CEC tables.
pub fn volumetric_path(text: &str) -> Option<Vec<String>> {
    use geometry::volumetric::{self, CecOptions, ComponentErrors, GridSpec};
    let errors = ComponentErrors::from_csv(text).ok()?;
    let machine = Machine::from_toml(MACHINE_3AXIS).ok()?;
    let grid = GridSpec::parse("0:400:3,0:300:3,0:200:3").ok()?;
    let points = volumetric::volumetric_grid(&machine, &errors, &grid).ok()?;
    let summary = volumetric::summarize(&points);
    assert_finite_value("the volumetric summary", &summary, text);
    let mut out = vec![volumetric::compensation_csv(&points)];
    let t = machine.tool_offset_mm;
    let cec = volumetric::siemens_cec_for(
        &points,
        &grid,
        &CecOptions {
            axis_names: ["AX1", "AX2", "AX3"],
            max_tables: volumetric::CEC_TABLES_840D,
            tool_offset_mm: Some([t.x, t.y, t.z]),
        },
    );
    if let Ok(c) = cec {
        out.push(c.ini);
    }
    for o in &out {
        assert_finite_text("a volumetric output", o, text);
    }
    Some(out)
}

/// Positioning CSV → the reader → the diagnosis of the axis (what ISO 230-2 and the baseline
/// model miss, the extended model) with a 2-seed reproduction check → the text report.
pub fn diagnose_path(text: &str) -> Option<String> {
    use diagnose::axis;
    let (data, _notes) =
        positioning::positioning_data::PositioningData::from_csv_str_noted(text).ok()?;
    let mut d = axis::diagnose(&data, &axis::Options::default()).ok()?;
    d.report.reproduction = Some(axis::reproduction_check(&data, &d.model, 2));
    let report = metrolog_analysis::diagnosis_text::positioning_text(&d);
    assert_finite_text("the diagnosis", &report, text);
    Some(report)
}
