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
        // The host clock is read at the start: after it is synchronised (not pulling the
        // target in, as systemd.special(7) says of its users).
        "After=network.target time-sync.target",
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

/// Every udev rule that names an instrument's port keeps ModemManager off it.
#[test]
fn udev_rules_keep_modemmanager_off_every_port() {
    let rules = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/99-metrolog.rules"),
    )
    .unwrap();
    let named: Vec<&str> = rules
        .lines()
        .filter(|l| !l.trim_start().starts_with('#') && l.contains("SYMLINK+="))
        .collect();
    assert_eq!(named.len(), 5, "{rules}");
    for l in named {
        assert!(l.contains(r#"ENV{ID_MM_DEVICE_IGNORE}="1""#), "{l}");
    }
    assert!(
        !unit_text()
            .lines()
            .any(|l| l.trim() == "Wants=time-sync.target")
    );
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

/// The example config, installed alone as install.sh does, passes `--check` (exit 0), its
/// absent `hotplug` devices as notes.
#[test]
fn installed_example_config_passes_check() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("metrolog.toml");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/metrolog.toml"),
        &cfg,
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["run", "--check", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains(": valid; machine mill-01"), "{stdout}");
    assert!(
        stdout.contains("note: [interferometer] port = \"/dev/metrolog-li80\" does not exist now")
            || Path::new("/dev/metrolog-li80").exists(),
        "{stdout}"
    );
}

/// A port that does not exist (not `hotplug`) and one port given twice: `--check` and a start
/// both exit 78, every mistake in one message naming its key and path.
#[test]
fn check_and_start_refuse_missing_and_shared_ports_all_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("m.toml");
    let missing = dir.path().join("ttyUSB9");
    std::fs::write(
        &cfg,
        format!(
            "[run]\nmachine = \"m\"\noutput_dir = \"logs\"\n[interferometer]\nport = {missing:?}\n[capball]\nport = \"/dev/null\"\n[psd]\nport = \"/dev/null\"\n"
        ),
    )
    .unwrap();
    for args in [
        &["run", "--check", "--config"][..],
        &["run", "--config"][..],
    ] {
        let mut a = args.to_vec();
        a.push(cfg.to_str().unwrap());
        let (code, err) = run_binary(&a);
        assert_eq!(code, Some(metrolog::exit::CONFIG as i32), "{err}");
        assert!(err.contains("2 problems in the config"), "{err}");
        assert!(
            err.contains(&format!(
                "m.toml:5:8: [interferometer] port = {:?} does not exist",
                missing.display().to_string()
            )),
            "{err}"
        );
        assert!(
            err.contains(
                "m.toml:9:8: [psd] port = \"/dev/null\" is already [capball] port (line 7)"
            ),
            "{err}"
        );
    }
    // Nothing was started: no log.
    assert!(!dir.path().join("logs").exists());
}

/// Starts `metrolog run` with a NOTIFY_SOCKET the test binds; returns the child and a thread
/// collecting the notifications until `listening` is cleared.
struct Notified {
    child: std::process::Child,
    listening: std::sync::Arc<std::sync::atomic::AtomicBool>,
    listener: std::thread::JoinHandle<Vec<String>>,
}

fn start_notified(cfg: &Path, dir: &Path) -> Notified {
    use std::sync::atomic::{AtomicBool, Ordering};
    let notify_path = dir.join("notify.sock");
    let notify = std::os::unix::net::UnixDatagram::bind(&notify_path).unwrap();
    notify
        .set_read_timeout(Some(std::time::Duration::from_millis(100)))
        .unwrap();
    let listening = std::sync::Arc::new(AtomicBool::new(true));
    let flag = listening.clone();
    let listener = std::thread::spawn(move || {
        let mut states = Vec::new();
        let mut buf = vec![0u8; 65536];
        while flag.load(Ordering::Relaxed) {
            if let Ok(n) = notify.recv(&mut buf) {
                states.push(String::from_utf8_lossy(&buf[..n]).to_string());
            }
        }
        states
    });
    let child = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["run", "--config"])
        .arg(cfg)
        .env("RUST_LOG", "info")
        .env("NOTIFY_SOCKET", &notify_path)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    Notified {
        child,
        listening,
        listener,
    }
}

impl Notified {
    /// Stop listening; the notifications received.
    fn states(self) -> Vec<String> {
        self.listening
            .store(false, std::sync::atomic::Ordering::Relaxed);
        self.listener.join().unwrap()
    }
}

/// A config whose only device is /dev/null (a device that exists but never answers: the
/// serial driver cannot even configure it) with a 1 s connect timeout.
fn nothing_answers(dir: &Path, hotplug: bool) -> std::path::PathBuf {
    let cfg = dir.join("m.toml");
    std::fs::write(
        &cfg,
        format!(
            "[run]\nmachine = \"m\"\noutput_dir = \"logs\"\nconnect_timeout_s = 1\n[interferometer]\nport = \"/dev/null\"\nhotplug = {hotplug}\n"
        ),
    )
    .unwrap();
    cfg
}

/// Nothing connected and no `hotplug` device: an ERROR line naming the port, systemd's STATUS
/// says so, exit 69 (which the unit does not restart); plain text on a pipe (no colour codes).
#[test]
fn nothing_connected_ends_the_run_with_69_and_says_so() {
    use std::io::Read as _;
    let dir = tempfile::tempdir().unwrap();
    let cfg = nothing_answers(dir.path(), false);
    let mut n = start_notified(&cfg, dir.path());
    // The run ends by itself; reading stderr to its end waits for that.
    let mut stderr = String::new();
    n.child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    let status = n.child.wait().unwrap();
    let states = n.states();
    assert_eq!(
        status.code(),
        Some(metrolog::exit::NOTHING_CONNECTED as i32),
        "{stderr}"
    );
    assert!(
        stderr.contains("ERROR")
            && stderr.contains("nothing connected for")
            && stderr.contains("interferometer on /dev/null"),
        "{stderr}"
    );
    assert!(
        !stderr.contains('\u{1b}'),
        "colour codes on a pipe: {stderr:?}"
    );
    assert!(
        states
            .iter()
            .any(|s| s.contains("STATUS=NOTHING CONNECTED for")),
        "{states:?}"
    );
    assert!(metrolog::exit::NO_RESTART.contains(&metrolog::exit::NOTHING_CONNECTED));
}

/// With a `hotplug` device the same alarm is raised, and the service waits (ended here by
/// SIGTERM: exit 0).
#[test]
fn nothing_connected_with_hotplug_raises_the_alarm_and_waits() {
    use std::io::BufRead as _;
    let dir = tempfile::tempdir().unwrap();
    let cfg = nothing_answers(dir.path(), true);
    let mut n = start_notified(&cfg, dir.path());
    let mut lines = std::io::BufReader::new(n.child.stderr.take().unwrap()).lines();
    let mut seen = Vec::new();
    for line in lines.by_ref() {
        let line = line.unwrap();
        let alarm = line.contains("nothing connected for") && line.contains("waiting for them");
        seen.push(line);
        if alarm {
            break;
        }
    }
    assert!(
        seen.last()
            .is_some_and(|l| l.contains("ERROR") && l.contains("(hotplug)")),
        "{seen:#?}"
    );
    // Still running: the alarm did not end it.
    assert!(n.child.try_wait().unwrap().is_none(), "{seen:#?}");
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(n.child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = n.child.wait().unwrap();
    let states = n.states();
    assert_eq!(status.code(), Some(0), "{seen:#?}{rest:#?}");
    assert!(
        states
            .iter()
            .any(|s| s.contains("STATUS=NOTHING CONNECTED for")),
        "{states:?}"
    );
}

/// Before a run starts, `[storage]` retention deletes runs older than `keep_days` (not other
/// files, not newer runs) and the low-space warning is given, in the journal and `STATUS=`.
#[test]
fn retention_and_the_low_space_warning_come_before_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&logs).unwrap();
    let old = logs.join("metrolog-m-20200101T000000Z.mcap");
    let recent = logs.join("metrolog-m-20260101T000000Z.mcap");
    let other = logs.join("notes.txt");
    for p in [&old, &recent, &other] {
        std::fs::write(p, b"x").unwrap();
    }
    let ten_days = std::time::Duration::from_secs(10 * 86_400);
    for p in [&old, &other] {
        std::fs::File::options()
            .write(true)
            .open(p)
            .unwrap()
            .set_modified(std::time::SystemTime::now() - ten_days)
            .unwrap();
    }
    let cfg = nothing_answers(dir.path(), false);
    let text = std::fs::read_to_string(&cfg).unwrap();
    // A warning threshold no disk reaches: the warning must come.
    std::fs::write(
        &cfg,
        format!("{text}[storage]\nkeep_days = 7\nwarn_free_gb = 1000000\n"),
    )
    .unwrap();
    let mut n = start_notified(&cfg, dir.path());
    let mut err = String::new();
    std::io::Read::read_to_string(&mut n.child.stderr.take().unwrap(), &mut err).unwrap();
    let code = n.child.wait().unwrap().code();
    let states = n.states();
    assert_eq!(
        code,
        Some(metrolog::exit::NOTHING_CONNECTED as i32),
        "{err}"
    );
    assert!(
        err.contains(&format!("retention: deleted {}", old.display())),
        "{err}"
    );
    assert!(err.contains("low disk space:"), "{err}");
    // systemd's STATUS= says it too, from the first status line on.
    assert!(
        states
            .iter()
            .any(|s| s.contains("STATUS=") && s.contains("LOW DISK ")),
        "{states:?}"
    );
    assert!(!old.exists() && recent.exists() && other.exists());
    // The new run's log is there beside the recent one.
    let runs = std::fs::read_dir(&logs)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".mcap")
        })
        .count();
    assert_eq!(runs, 2);
}
