//! The compensate-and-verify loop of `metrolog demo` (`docs/methods.md`, "Verification run"),
//! on the demo's axis: its ISO 230-2 segment runs on the simulated instruments through the real
//! drivers, pipeline and log; the LinuxCNC table built from that log is written to disk; the
//! simulated axis loads the written file as LinuxCNC does (`sim::ScrewComp`, not the writer's
//! own numbers) and the segment runs again. The error at the targets, both directions (ISO
//! 230-2 E, measured), must drop to at most 15 % of what the calibration run measured.
//!
//! Negative control: the same file with every trim's sign turned (what the writer produced
//! before issue 28's sign fix) runs too and must roughly double E, so the 15 % criterion fails
//! for it: the loop can tell a right table from a wrong one.

use std::path::Path;

use metrolog::cmd::demo::sim_run;
use metrolog::cmd::demo::verify::{
    positioning_segment, verification_scenario, write_linuxcnc_table,
};
use metrolog::cmd::input::load_positioning;
use positioning::axis_model::Direction;
use positioning::compensation::{Remeasured, remeasured};
use positioning::positioning_data::PositioningData;
use sim::{Scenario, ScrewComp};

async fn measure(sc: Scenario, dir: &Path) -> PositioningData {
    let (report, _) = sim_run(sc, dir, "compensation loop test")
        .await
        .expect("the run completes");
    load_positioning(&report.log_path).expect("the log holds the positioning run")
}

fn e(r: &Remeasured) -> (f64, f64) {
    (r.before.e.expect("E before"), r.after.e.expect("E after"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_written_table_applied_by_the_axis_leaves_at_most_15_percent_of_e() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let base = Scenario::demo();
    let before = measure(positioning_segment(&base), &tmp.path().join("calibration")).await;
    let (table, files) = write_linuxcnc_table(&before, &tmp.path().join("comp")).expect("table");
    let text = std::fs::read_to_string(&files[0]).expect("comp file");
    let comp = ScrewComp::from_linuxcnc(&text).expect("LinuxCNC reads the whole file");
    assert_eq!(comp.ignored_lines, 0);
    // The file as the simulated LinuxCNC reads it holds the corrections the writer meant (its
    // prediction uses those), to the file's 1 nm.
    for (k, &p) in table.points_mm.iter().enumerate() {
        for (dir, want) in [
            (Direction::Up, table.correction_up_um[k]),
            (Direction::Down, table.correction_down_um[k]),
        ] {
            let got = comp.trim_um(p, dir);
            assert!(
                (got - want).abs() < 2e-3,
                "{p} mm {dir:?}: {got} vs {want} µm"
            );
        }
    }

    let after = measure(
        verification_scenario(&base, comp.clone()),
        &tmp.path().join("verify"),
    )
    .await;
    let right = remeasured(&before, &after);
    assert!(right.unmatched_mm.is_empty(), "{:?}", right.unmatched_mm);
    assert_eq!(right.targets.len(), 5);
    let (b, a) = e(&right);
    println!(
        "E measured before {b:.3} µm, after {a:.3} µm ({:.1} %)",
        100.0 * a / b
    );
    assert!(b > 5.0, "the demo's axis error is there to remove: E = {b}");
    assert!(a <= 0.15 * b, "E {b:.3} -> {a:.3} µm");

    let wrong = measure(
        verification_scenario(&base, comp.negated()),
        &tmp.path().join("wrong-sign"),
    )
    .await;
    let (_, w) = e(&remeasured(&before, &wrong));
    println!("wrong sign: E {b:.3} -> {w:.3} µm");
    assert!(w > 0.15 * b, "the criterion must fail for the wrong sign");
    assert!(
        (1.6..2.4).contains(&(w / b)),
        "the wrong sign doubles the error: E {b:.3} -> {w:.3} µm"
    );
}
