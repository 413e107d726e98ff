//! What the positioning reader notes and refuses reaches the user of `analyze positioning`
//! (issue: cycles numbered 10…50 were read as 50 cycles; a deviation of 1e155 panicked).

use std::process::Command;

/// Two cycles numbered `c1`, `c2` of three targets, with times, the first deviation `dev`.
fn run_csv(c1: u32, c2: u32, dev: &str) -> String {
    let mut t = String::from("cycle,direction,index,target_mm,deviation_um,time_s\n");
    let mut time = 0;
    for c in [c1, c2] {
        for (dir, order) in [("+", [0, 1, 2]), ("-", [2, 1, 0])] {
            for k in order {
                time += 1;
                let d = if time == 1 { dev } else { "1.5" };
                t += &format!("{c},{dir},{},{},{d},{time}\n", k + 1, 100 * k);
            }
        }
    }
    t
}

fn analyze(csv: &str) -> std::process::Output {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let path = dir.path().join("run.csv");
    std::fs::write(&path, csv).expect("the CSV is written");
    Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["analyze", "positioning"])
        .arg(&path)
        .output()
        .expect("metrolog runs")
}

#[test]
fn renumbered_cycles_are_noted_on_stderr() {
    let out = analyze(&run_csv(10, 50, "1.0"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "stderr: {err}");
    assert!(
        err.contains("note:") && err.contains("cycle numbers 10, 50"),
        "stderr: {err}"
    );
}

#[test]
fn a_deviation_out_of_range_is_an_error_with_its_line_not_a_panic() {
    let out = analyze(&run_csv(1, 2, "1e155"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stderr: {err}");
    assert!(
        err.contains("line 2") && err.contains("deviation_um"),
        "stderr: {err}"
    );
    assert!(!err.contains("panicked"), "stderr: {err}");
}
