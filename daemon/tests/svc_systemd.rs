//! The systemd unit passes `systemd-analyze verify` and has the settings the service relies on.

use std::path::Path;
use std::process::Command;

fn unit_text() -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/metrolog.service"),
    )
    .unwrap()
}

#[test]
fn unit_passes_systemd_analyze_verify() {
    if Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_err()
    {
        println!(
            "SKIPPED: systemd-analyze is not installed (apt-get install systemd; .ci/run does)"
        );
        return;
    }
    // verify checks that ExecStart is executable: point it at the binary under test.
    let dir = tempfile::tempdir().unwrap();
    let unit = dir.path().join("metrolog.service");
    std::fs::write(
        &unit,
        unit_text().replace("/usr/local/bin/metrolog", env!("CARGO_BIN_EXE_metrolog")),
    )
    .unwrap();
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&unit)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    // Unknown keys are only warnings (exit code 0): any line about our file is a failure.
    let about_unit: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("metrolog.service"))
        .collect();
    assert!(
        out.status.success() && about_unit.is_empty(),
        "systemd-analyze verify:\n{stderr}"
    );
}

#[test]
fn unit_has_the_settings_the_service_relies_on() {
    let text = unit_text();
    let has = |k: &str| text.lines().any(|l| l.trim() == k);
    for k in [
        "Type=notify",
        "NotifyAccess=main",
        "SupplementaryGroups=dialout",
        "StateDirectory=metrolog",
        "ProtectSystem=strict",
        "ProtectHome=yes",
        "PrivateTmp=yes",
        "NoNewPrivileges=yes",
        "DevicePolicy=closed",
        "DeviceAllow=char-ttyUSB rw",
        "DeviceAllow=char-ttyACM rw",
        "RestrictAddressFamilies=AF_UNIX AF_CAN",
    ] {
        assert!(has(k), "missing `{k}`");
    }
    // PrivateDevices would hide the serial ports.
    assert!(
        !text
            .lines()
            .any(|l| l.trim_start().starts_with("PrivateDevices="))
    );
    assert!(text.lines().any(|l| l.starts_with("WatchdogSec=")));
}
