//! What the CLI tests share: running the built binary.

use std::process::Command;

/// `metrolog ARGS`, which must succeed; its standard output.
pub fn metrolog(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "metrolog {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}
