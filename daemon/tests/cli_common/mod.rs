//! What the CLI tests share: running the built binary. Each test binary uses some of it.
#![allow(dead_code)]

use std::process::Command;

/// `metrolog ARGS`, which must succeed; its standard output.
pub fn metrolog(args: &[&str]) -> String {
    let (ok, stdout, stderr) = outcome(args);
    assert!(ok, "metrolog {args:?}: {stderr}");
    stdout
}

/// `metrolog ARGS`: (success, stdout, stderr).
pub fn outcome(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
