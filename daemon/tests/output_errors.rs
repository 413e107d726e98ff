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
