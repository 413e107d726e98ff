//! Replays the cargo-fuzz corpora of the dataset readers (`protocol/fuzz/corpus/
//! positioning_csv/`, `.../capball_csv/`: real runs and the example datasets, plus any crash
//! kept there), so CI re-runs every finding on stable. A reader must answer each with a
//! dataset or an error, never a panic; the real files and the examples must read.

use std::path::PathBuf;

fn corpus(target: &str) -> Vec<(String, String)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../protocol/fuzz/corpus")
        .join(target);
    let mut files: Vec<(String, String)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            let p = e.unwrap().path();
            let bytes = std::fs::read(&p).unwrap();
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                String::from_utf8_lossy(&bytes).into_owned(),
            )
        })
        .collect();
    files.sort();
    files
}

/// Seeds that are real or example datasets (must read); anything else is a fuzz finding.
fn is_seed(name: &str) -> bool {
    name.ends_with(".csv")
}

#[test]
fn replay_positioning_csv_corpus() {
    let files = corpus("positioning_csv");
    assert!(files.len() >= 4, "{files:?}");
    for (name, text) in files {
        let r = positioning::positioning_data::PositioningData::from_csv_str(&text);
        if is_seed(&name) {
            let d = r.unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(!d.readings.is_empty(), "{name}");
        }
    }
}

#[test]
fn replay_capball_csv_corpus() {
    let files = corpus("capball_csv");
    assert!(files.len() >= 3, "{files:?}");
    for (name, text) in files {
        let r = geometry::capball::parse_dataset(&text);
        if is_seed(&name) {
            let d = r.unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(!d.is_empty(), "{name}");
        }
    }
}
