//! Replays the corpora of the analysis-path fuzz targets (`protocol/fuzz/corpus/capball_path`,
//! `psd_path`, `thermal_path`, `budget_path`, `parts_path`, `volumetric_path`, `diagnose_path`: example inputs, the hostile corpus' files of
//! each kind, and any finding kept there) through `metrolog::fuzzcheck`, so CI re-runs every
//! finding on stable. Each path must end without a panic and without a NaN or an infinity in
//! an output; the example inputs must go all the way through.

use std::path::PathBuf;

use metrolog::fuzzcheck::{
    budget_path, capball_path, diagnose_path, parts_path, psd_path, thermal_fit_path, thermal_path,
    volumetric_path,
};

fn corpus(target: &str) -> Vec<(String, String)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../protocol/fuzz/corpus")
        .join(target);
    let mut files: Vec<(String, String)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            let p = e.expect("a directory entry").path();
            let bytes = std::fs::read(&p).expect("a corpus file");
            (
                p.file_name()
                    .expect("a file name")
                    .to_string_lossy()
                    .into_owned(),
                String::from_utf8_lossy(&bytes).into_owned(),
            )
        })
        .collect();
    files.sort();
    assert!(files.len() >= 2, "{}: {files:?}", dir.display());
    files
}

#[test]
fn capball_path_corpus() {
    for (name, text) in corpus("capball_path") {
        let out = capball_path(&text);
        if name == "capball_identification_40.csv" {
            let reports = out.unwrap_or_else(|| panic!("{name} refused"));
            assert_eq!(reports.len(), 1, "{name}");
            assert!(reports[0].contains("run 1: 40 poses"), "{}", reports[0]);
        }
    }
}

#[test]
fn psd_path_corpus() {
    for (name, text) in corpus("psd_path") {
        let out = psd_path(&text);
        if name == "psd_readings.csv" {
            let report = out.unwrap_or_else(|| panic!("{name} refused"));
            assert!(report.contains("squareness EC0Y"), "{report}");
        }
    }
}

/// The thermal corpus through `path`: no panic on any file, and `outputs` outputs for the real
/// excerpt.
fn replay_thermal(path: fn(&str) -> Option<Vec<String>>, outputs: usize) {
    for (name, text) in corpus("thermal_path") {
        let out = path(&text);
        if name == "real_spindle_excerpt.csv" {
            let got = out.unwrap_or_else(|| panic!("{name} refused"));
            assert_eq!(got.len(), outputs, "{got:#?}");
        }
    }
}

#[test]
fn thermal_path_corpus() {
    // ETVE, the model's description, the prediction CSV, the model JSON, the diagnosis.
    replay_thermal(thermal_path, 5);
}

/// The fast target's path (`thermal_fit_path`) shares the thermal corpus: its findings are kept
/// there and replayed by both.
#[test]
fn thermal_fit_path_corpus() {
    // ETVE, the model's description, the prediction CSV, the model JSON.
    replay_thermal(thermal_fit_path, 4);
}

#[test]
fn budget_path_corpus() {
    for (name, text) in corpus("budget_path") {
        let out = budget_path(&text);
        if name.starts_with("jcgm") || name.starts_with("li80") {
            let report = out.unwrap_or_else(|| panic!("{name} refused"));
            assert!(report.contains("Monte Carlo"), "{name}: {report}");
        }
    }
}

#[test]
fn parts_path_corpus() {
    for (name, text) in corpus("parts_path") {
        let out = parts_path(&text);
        if name.starts_with("parts") {
            let json = out.unwrap_or_else(|| panic!("{name} refused"));
            assert!(json.contains("\"variance_ratio\":"), "{json}");
        }
    }
}

#[test]
fn volumetric_path_corpus() {
    for (name, text) in corpus("volumetric_path") {
        let out = volumetric_path(&text);
        if name == "component_errors.csv" {
            let outputs = out.unwrap_or_else(|| panic!("{name} refused"));
            // The compensation CSV (a header and 27 points) and the CEC tables.
            assert_eq!(outputs.len(), 2, "{outputs:#?}");
            assert_eq!(outputs[0].lines().count(), 28, "{}", outputs[0]);
        }
    }
}

#[test]
fn diagnose_path_corpus() {
    for (name, text) in corpus("diagnose_path") {
        let out = diagnose_path(&text);
        if !name.starts_with("positioning-") && !name.starts_with("crash-") {
            let report = out.unwrap_or_else(|| panic!("{name} refused"));
            assert!(!report.is_empty(), "{name}");
        }
    }
}
