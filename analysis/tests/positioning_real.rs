//! `analyze positioning` on real runs (fixtures of positioning/tests/data/real/): a single-pass
//! sweep is evaluated and says why the repeatability values are missing.

use metrolog_analysis::positioning_report::{analyze_positioning, render_text};
use positioning::positioning_data::PositioningData;

fn load(name: &str) -> PositioningData {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../positioning/tests/data/real")
        .join(name);
    PositioningData::from_csv_path(&p).expect("real fixture reads")
}

#[test]
fn a_sweep_is_evaluated_and_says_why_repeatability_is_missing() {
    let data = load("bifrost_slit11358_ax1_sweep.csv");
    let an = analyze_positioning(&data, None);
    assert_eq!(an.n_cycles, 1);
    assert!(an.iso230_2.b.is_some() && an.iso230_2.e.is_some());
    assert!(an.iso230_2.r.is_none());
    assert!(
        an.notes
            .iter()
            .any(|n| n.contains("single pass") && n.contains("repeated approaches")),
        "{:?}",
        an.notes
    );
    let text = render_text(&an);
    assert!(text.contains("single pass"), "{text}");
}

#[test]
fn a_repeated_run_has_no_sweep_note() {
    let data = load("ess_target_b02_x.csv");
    let an = analyze_positioning(&data, None);
    assert!(an.iso230_2.r.is_some());
    assert!(an.notes.iter().all(|n| !n.contains("single pass")));
}
