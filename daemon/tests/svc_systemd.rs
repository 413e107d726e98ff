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
        "RestrictAddressFamilies=AF_UNIX",
        "PrivateNetwork=yes",
        "PrivateMounts=yes",
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

/// The codes of `RestartPreventExitStatus=` in the unit.
fn restart_prevent_codes(text: &str) -> Vec<u8> {
    let mut codes: Vec<u8> = text
        .lines()
        .filter_map(|l| l.trim().strip_prefix("RestartPreventExitStatus="))
        .flat_map(|v| v.split_whitespace())
        .map(|c| {
            c.parse()
                .expect("RestartPreventExitStatus takes numbers here")
        })
        .collect();
    codes.sort_unstable();
    codes
}

/// `systemd-run --user` cannot run here (no systemd as PID 1 in the test container, and CI
/// runs in the same kind of container), so the unit is checked against the binary's
/// documented codes instead: every code after which a restart cannot help is in
/// `RestartPreventExitStatus=`, and no other.
#[test]
fn unit_prevents_restart_exactly_on_the_documented_codes() {
    let mut want = metrolog::exit::NO_RESTART.to_vec();
    want.sort_unstable();
    assert_eq!(restart_prevent_codes(&unit_text()), want);
    assert!(
        unit_text()
            .lines()
            .any(|l| l.trim() == "Restart=on-failure")
    );
}

/// The README's deploy section has a row for every exit code the binary uses.
#[test]
fn readme_lists_every_exit_code() {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .unwrap();
    for (code, what) in metrolog::exit::ALL {
        assert!(
            readme
                .lines()
                .any(|l| l.starts_with(&format!("| {code} |"))),
            "README has no row for exit code {code} ({what})"
        );
    }
}

fn run_binary(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

/// The real binary exits with the documented code for each startup failure.
#[test]
fn binary_exits_with_the_documented_codes() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.toml");
    let (code, err) = run_binary(&["run", "--config", missing.to_str().unwrap()]);
    assert_eq!(code, Some(metrolog::exit::CONFIG as i32), "{err}");
    assert!(err.contains("cannot read config file"), "{err}");

    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[run]\nmachine = 3\n").unwrap();
    let (code, err) = run_binary(&["run", "--check", "--config", bad.to_str().unwrap()]);
    assert_eq!(code, Some(metrolog::exit::CONFIG as i32), "{err}");

    let (code, err) = run_binary(&["run", "--no-such-flag"]);
    assert_eq!(code, Some(metrolog::exit::USAGE as i32), "{err}");

    // A valid config whose output_dir cannot be created (a file is in the way): 73.
    let blocker = dir.path().join("not-a-dir");
    std::fs::write(&blocker, "").unwrap();
    let cfg = dir.path().join("ok.toml");
    std::fs::write(
        &cfg,
        format!(
            "[run]\nmachine = \"m\"\noutput_dir = {:?}\n\n[interferometer]\nport = \"/dev/null\"\n",
            blocker.join("logs").display().to_string()
        ),
    )
    .unwrap();
    let (code, err) = run_binary(&["run", "--config", cfg.to_str().unwrap()]);
    assert_eq!(code, Some(metrolog::exit::CANT_CREATE as i32), "{err}");
    assert!(err.contains("cannot create the output directory"), "{err}");
}

/// The exposure `systemd-analyze security` gives a unit file (with its drop-ins beside it).
fn exposure(unit: &Path) -> Option<f64> {
    let out = Command::new("systemd-analyze")
        .args(["security", "--offline=true", "--no-pager"])
        .arg(unit)
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find(|l| l.contains("Overall exposure level"))?;
    let after = line.split(':').nth(1)?.trim();
    after.split_whitespace().next()?.parse().ok()
}

/// `systemd-analyze security` rates the default unit at most 1.1, and the SocketCAN drop-in
/// opens only the network namespace and AF_CAN (at most 1.2).
#[test]
fn unit_exposure_is_at_most_1_1() {
    let dir = tempfile::tempdir().unwrap();
    let unit = dir.path().join("metrolog.service");
    std::fs::write(
        &unit,
        unit_text().replace("/usr/local/bin/metrolog", env!("CARGO_BIN_EXE_metrolog")),
    )
    .unwrap();
    let Some(default) = exposure(&unit) else {
        println!("SKIPPED: systemd-analyze security --offline is not available (systemd >= 250)");
        return;
    };
    assert!(default <= 1.1, "exposure of the default unit {default}");
    let dropins = dir.path().join("metrolog.service.d");
    std::fs::create_dir_all(&dropins).unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/metrolog-socketcan.conf"),
        dropins.join("socketcan.conf"),
    )
    .unwrap();
    let socketcan = exposure(&unit).unwrap();
    assert!(
        socketcan > default && socketcan <= 1.2,
        "exposure with the SocketCAN drop-in {socketcan}"
    );
    // The live view's drop-in (TCP, loopback peers only): measured 1.3, 1.5 with both.
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/metrolog-live.conf"),
        dropins.join("live.conf"),
    )
    .unwrap();
    let both = exposure(&unit).unwrap();
    assert!(both > socketcan && both <= 1.5, "SocketCAN and live {both}");
    std::fs::remove_file(dropins.join("socketcan.conf")).unwrap();
    let live = exposure(&unit).unwrap();
    assert!(
        live > default && live <= 1.3,
        "exposure with the live drop-in {live}"
    );
}
