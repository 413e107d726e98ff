//! A command whose standard output cannot be written ends as a Unix tool does — killed by
//! SIGPIPE for a closed pipe, a clear error and the I/O error code (README, exit codes) for a
//! full device — never a panic (issue: `info LOG > /dev/full` exited 101).

use std::process::{Command, Stdio};

fn budget() -> String {
    concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/budgets/jcgm100_h1_end_gauge.toml"
    )
    .into()
}

#[test]
fn a_full_stdout_is_an_io_error_not_a_panic() {
    let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") else {
        eprintln!("no /dev/full here: skipped");
        return;
    };
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["uncertainty", &budget(), "--method", "gum"])
        .stdout(Stdio::from(full))
        .stderr(Stdio::piped())
        .output()
        .expect("metrolog runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(74), "stderr: {err}");
    assert!(err.contains("cannot write the output"), "stderr: {err}");
    assert!(!err.contains("panicked"), "stderr: {err}");
}

#[test]
fn a_closed_pipe_is_an_io_error_not_a_panic() {
    // The reading end is closed before the command starts: every write fails (EPIPE).
    let (reader, writer) = std::io::pipe().expect("a pipe");
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["uncertainty", &budget(), "--method", "gum"])
        .stdout(Stdio::from(writer))
        .stderr(Stdio::piped())
        .output()
        .expect("metrolog runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "stderr: {err}");
    // As Unix tools do (cli.rs restores SIGPIPE for the analysis commands).
    use std::os::unix::process::ExitStatusExt as _;
    assert_eq!(
        out.status.signal(),
        Some(13),
        "status {:?}, stderr: {err}",
        out.status
    );
}

/// A trial count past what memory can hold is a usage error naming the limit, not an abort on
/// allocation (issue: `--trials 18446744073709551615` aborted with an exabyte allocation).
#[test]
fn a_trial_count_past_the_limit_is_a_usage_error() {
    for args in [
        vec![
            "uncertainty".to_string(),
            budget(),
            "--trials".into(),
            u64::MAX.to_string(),
        ],
        vec![
            "uncertainty".to_string(),
            budget(),
            "--trials".into(),
            "0".into(),
        ],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
            .args(&args)
            .output()
            .expect("metrolog runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains("20000000"), "{args:?}: {err}");
    }
}

/// A seed count for the diagnosis's reproduction check is bounded (issue 27's held-out sweep,
/// seed 67: `diagnose … --check-seeds 4294967296` ran for as many simulated runs, without end).
#[test]
fn a_check_seed_count_past_the_limit_is_a_usage_error() {
    for v in ["18446744073709551615", "4294967296", "101", "0"] {
        let (code, err) = exit_and_stderr(&["diagnose", "run.csv", "--check-seeds", v]);
        assert_eq!(code, Some(2), "{v}: {err}");
        assert!(
            err.contains("--check-seeds") && err.contains("100"),
            "{v}: {err}"
        );
    }
}

/// The pose count of a CapBall trajectory is bounded (`identify trajectory --poses
/// 18446744073709551615` panicked on the allocation; 10⁸ ran without end).
#[test]
fn a_trajectory_pose_count_past_the_limit_is_a_usage_error() {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let out_csv = dir.path().join("t.csv");
    for v in ["18446744073709551615", "100000000", "4"] {
        let out_arg = out_csv.to_string_lossy();
        let (code, err) =
            exit_and_stderr(&["identify", "trajectory", "--poses", v, "--out", &out_arg]);
        assert_eq!(code, Some(2), "{v}: {err}");
        assert!(
            err.contains("--poses") && err.contains("100000"),
            "{v}: {err}"
        );
        assert!(!out_csv.exists(), "{v}: a file was written");
    }
}

/// The trajectory's angles are bounded and a trajectory that cannot identify the errors is not
/// written (`--c-turns 1e308` or `nan` ran without end; `0` wrote a file and printed a
/// condition number of inf with exit 0).
#[test]
fn a_trajectory_that_cannot_identify_is_refused() {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let out_csv = dir.path().join("t.csv");
    let cases: [(&[&str], i32, &str); 5] = [
        (&["--c-turns", "1e308"], 2, "turns of C"),
        (&["--c-turns", "nan"], 2, "turns of C"),
        (&["--c-turns", "0"], 2, "turns of C"),
        (&["--a-end-deg", "1e300"], 2, "A angle"),
        (&["--a-start-deg", "0", "--a-end-deg", "0"], 1, "singular"),
    ];
    for (args, code, words) in cases {
        let out_arg = out_csv.to_string_lossy();
        let mut all = vec!["identify", "trajectory"];
        all.extend_from_slice(args);
        all.extend_from_slice(&["--out", &out_arg]);
        let (got, err) = exit_and_stderr(&all);
        assert_eq!(got, Some(code), "{args:?}: {err}");
        assert!(err.contains(words), "{args:?}: {err}");
        assert!(!out_csv.exists(), "{args:?}: a file was written");
    }
}

/// Runs metrolog with `args`: its exit code and its stderr.
fn exit_and_stderr(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(args)
        .output()
        .expect("metrolog runs");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
