//! Config file validation: the example config loads, and every kind of mistake is reported with
//! the file, the line of the mistake and a sentence naming it.

use std::path::{Path, PathBuf};

use metrolog::acquire::config::{Config, ConfigError, TriggerConfig};

const GOOD: &str = r#"[run]
machine = "mill-01"
output_dir = "/var/lib/metrolog"
stop_at_program_end = false
[detector]
samples = 150
[interferometer]
port = "/dev/metrolog-li80"
rate_hz = 1000
alpha_um_per_m_k = 11.7
[capball]
port = "/dev/metrolog-cb3"
rate_hz = 1000
poly = [[10.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 0.0, 0.0]]
[psd]
port = "/dev/metrolog-psd2"
baud = 921600
rate_hz = 100
min_sum_pa = 100000
[trigger]
slcan = "/dev/metrolog-slcan"
can_id = 0x181
"#;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(Path::new("/etc/metrolog/metrolog.toml"), text)
}

/// Parse `text` expecting an error; return (line, message).
fn error(text: &str) -> (usize, String) {
    match parse(text) {
        Ok(_) => panic!("accepted a bad config:\n{text}"),
        Err(e) => {
            let msg = e.to_string();
            assert!(
                msg.starts_with("/etc/metrolog/metrolog.toml:"),
                "no file name in {msg:?}"
            );
            (e.line().expect("a line"), msg)
        }
    }
}

fn line_of(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|l| l.contains(needle))
        .expect("needle in text")
        + 1
}

#[test]
fn good_config_loads_with_the_values_written() {
    let c = parse(GOOD).unwrap();
    assert_eq!(c.run.machine, "mill-01");
    assert_eq!(c.run.output_dir, PathBuf::from("/var/lib/metrolog"));
    assert_eq!(c.detector.samples, 150);
    let li = c.interferometer.as_ref().unwrap();
    assert_eq!((li.rate_hz, li.alpha_um_per_m_k), (1000, 11.7));
    let cb = c.capball.as_ref().unwrap();
    assert_eq!(cb.driver.poly[2], [10.0, 0.0, 0.0]);
    // No transform file: identity.
    assert_eq!(cb.driver.transform[3], [0.0, 0.0, 0.0, 1.0]);
    assert_eq!(cb.driver.transform[1], [0.0, 1.0, 0.0, 0.0]);
    assert_eq!(c.psd.as_ref().unwrap().baud, 921_600);
    match c.trigger.as_ref().unwrap() {
        TriggerConfig::Slcan(s) => {
            assert_eq!((s.port.as_str(), s.can_id), ("/dev/metrolog-slcan", 0x181))
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn example_config_in_deploy_is_valid() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/metrolog.toml");
    let text = std::fs::read_to_string(&p).unwrap();
    // Installed alone (install.sh copies only this file to /etc/metrolog), devices checked.
    let dir = tempfile::tempdir().unwrap();
    let installed = dir.path().join("metrolog.toml");
    std::fs::write(&installed, &text).unwrap();
    let c = Config::load_checked(&installed).unwrap();
    assert_eq!(c.instruments().len(), 5);
    assert_eq!(c.run.connect_timeout_s, 60);
    // Its files, once uncommented, are read relative to it.
    std::fs::write(
        dir.path().join("poses.csv"),
        "pose,x_mm,y_mm,z_mm\n1,0,0,0\n2,100,0,0\n",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("capball-T.csv"),
        "1,0,0,0\n0,1,0,0\n0,0,1,0\n0,0,0,1\n",
    )
    .unwrap();
    let text = text
        .replace("# trajectory = ", "trajectory = ")
        .replace("# transform = ", "transform = ");
    let c = Config::parse(&installed, &text).unwrap();
    assert_eq!(c.run.trajectory.as_ref().unwrap().rows.len(), 2);
    assert_eq!(c.instruments().len(), 5);
    let t = c.temperature.as_ref().unwrap();
    assert_eq!((t.unit, t.sensors.len()), (1, 3));
    assert_eq!(t.sensors[0].location, "spindle housing, front bearing");
    assert!(c.capball.unwrap().transform_file.is_some());
}

#[test]
fn every_section_but_run_is_optional() {
    let c = parse("[run]\nmachine = \"m\"\noutput_dir = \"out\"\n").unwrap();
    assert!(c.instruments().is_empty());
    assert_eq!(c.detector.samples, 150);
    // Relative to the config file's directory.
    assert_eq!(c.run.output_dir, PathBuf::from("/etc/metrolog/out"));
}

#[test]
fn unknown_key_is_rejected_with_its_line() {
    let text = GOOD.replace("rate_hz = 100\n", "rate_hz = 100\nrate_Hz = 10\n");
    let (line, msg) = error(&text);
    assert_eq!(line, line_of(&text, "rate_Hz"), "{msg}");
    assert!(
        msg.contains("unknown field") && msg.contains("rate_Hz"),
        "{msg}"
    );
}

#[test]
fn unknown_section_is_rejected() {
    let text = format!("{GOOD}[laser]\nport = \"x\"\n");
    let (line, msg) = error(&text);
    assert_eq!(line, line_of(&text, "[laser]"), "{msg}");
    assert!(msg.contains("laser"), "{msg}");
}

#[test]
fn rates_outside_the_data_sheet_are_rejected() {
    // LI-80: 1..10000 Hz.
    let text = GOOD.replace("rate_hz = 1000\nalpha", "rate_hz = 20000\nalpha");
    let (line, msg) = error(&text);
    assert_eq!(line, line_of(&text, "rate_hz = 20000"));
    assert!(
        msg.contains("20000") && msg.contains("1 to 10000 Hz"),
        "{msg}"
    );
    // CB-3: 100..20000 Hz, so 50 is too slow.
    let text = GOOD.replace("rate_hz = 1000\npoly", "rate_hz = 50\npoly");
    let (line, msg) = error(&text);
    assert_eq!(line, line_of(&text, "rate_hz = 50"));
    assert!(msg.contains("100 to 20000 Hz"), "{msg}");
    // PSD-2 at 115200 baud carries about 200 lines/s of 55 bytes: 500 Hz does not fit.
    let text = GOOD.replace(
        "baud = 921600\nrate_hz = 100",
        "baud = 115200\nrate_hz = 500",
    );
    let (line, msg) = error(&text);
    assert_eq!(line, line_of(&text, "rate_hz = 500"));
    assert!(msg.contains("lines/s"), "{msg}");
    // Negative: not even a u32.
    let text = GOOD.replace("rate_hz = 100\n", "rate_hz = -3\n");
    let (line, _) = error(&text);
    assert_eq!(line, line_of(&text, "rate_hz = -3"));
}

#[test]
fn impossible_values_are_rejected() {
    for (from, to, needle) in [
        ("samples = 150", "samples = 2", "samples = 2"),
        ("can_id = 0x181", "can_id = 0x800", "can_id = 0x800"),
        (
            "alpha_um_per_m_k = 11.7",
            "alpha_um_per_m_k = nan",
            "alpha_um_per_m_k",
        ),
        ("min_sum_pa = 100000", "min_sum_pa = -1", "min_sum_pa"),
        ("baud = 921600", "baud = 1000", "baud = 1000"),
        (
            "[[10.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 0.0, 0.0]]",
            "[[10.0, 0.0, 0.0], [10.0, 0.0, inf], [10.0, 0.0, 0.0]]",
            "poly",
        ),
        (
            "[[10.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 0.0, 0.0]]",
            "[[10.0, 0.0], [10.0, 0.0, 0.0], [10.0, 0.0, 0.0]]",
            "poly",
        ),
        (
            "machine = \"mill-01\"",
            "machine = \"mill 01/a\"",
            "machine",
        ),
        (
            "stop_at_program_end = false",
            "stop_at_program_end = false\nconnect_timeout_s = 0",
            "connect_timeout_s",
        ),
        (
            "slcan = \"/dev/metrolog-slcan\"",
            "slcan = \"/dev/metrolog-slcan\"\nsocketcan = \"can0\"",
            "socketcan",
        ),
    ] {
        let text = GOOD.replace(from, to);
        assert_ne!(text, GOOD, "{from}");
        let (line, msg) = error(&text);
        assert_eq!(line, line_of(&text, needle), "{to}: {msg}");
    }
}

#[test]
fn missing_or_bad_referenced_files_are_reported_at_their_key() {
    let text = GOOD.replace("[psd]", "transform = \"no-such-T.csv\"\n[psd]");
    let (line, msg) = error(&text);
    assert_eq!(line, line_of(&text, "no-such-T.csv"));
    assert!(msg.contains("cannot be read"), "{msg}");

    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("T.csv"),
        "1,0,0\n0,1,0,0\n0,0,1,0\n0,0,0,1\n",
    )
    .unwrap();
    let text = GOOD.replace("[psd]", "transform = \"T.csv\"\n[psd]");
    let e = Config::parse(&dir.path().join("m.toml"), &text)
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 1 has 3 numbers"), "{e}");

    std::fs::write(
        dir.path().join("p.csv"),
        "pose,x_mm,y_mm,z_mm\n1,0,0,0\n3,1,0,0\n",
    )
    .unwrap();
    let text = GOOD.replace("stop_at", "trajectory = \"p.csv\"\nstop_at");
    let e = Config::parse(&dir.path().join("m.toml"), &text)
        .unwrap_err()
        .to_string();
    assert!(e.contains("pose 3 should be 2"), "{e}");
}

#[test]
fn transform_file_is_loaded_row_major() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("T.csv"),
        "# cube calibration\n1,0,0,5\n0,2,0,6\n0,0,3,7\n0,0,0,1\n",
    )
    .unwrap();
    let text = GOOD.replace("[psd]", "transform = \"T.csv\"\n[psd]");
    let c = Config::parse(&dir.path().join("m.toml"), &text).unwrap();
    let t = c.capball.unwrap().driver.transform;
    assert_eq!(t[0], [1.0, 0.0, 0.0, 5.0]);
    assert_eq!(t[2], [0.0, 0.0, 3.0, 7.0]);
}

#[test]
fn unreadable_file_names_the_path() {
    let e = Config::load(Path::new("/nonexistent/metrolog.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/metrolog.toml"), "{e}");
}

#[test]
fn the_live_view_is_off_by_default_and_its_mistakes_are_reported() {
    assert_eq!(parse(GOOD).unwrap().live, None);
    let on = parse(&format!("{GOOD}[live]\nlisten = \"127.0.0.1:8765\"\n")).unwrap();
    let live = on.live.unwrap();
    assert_eq!(live.listen.to_string(), "127.0.0.1:8765");
    assert_eq!(live.raw_hz, 10);
    let v6 = parse(&format!(
        "{GOOD}[live]\nlisten = \"[::1]:9000\"\nraw_hz = 0\n"
    ))
    .unwrap();
    assert_eq!(v6.live.unwrap().raw_hz, 0);
    for (bad, needle, what) in [
        (
            "listen = \"localhost\"",
            "listen =",
            "is not an address and port",
        ),
        (
            "listen = \"127.0.0.1:8765\"\nraw_hz = 101",
            "raw_hz",
            "outside 0 to 100",
        ),
        (
            "listen = \"127.0.0.1:8765\"\npublish = true",
            "publish",
            "unknown field",
        ),
    ] {
        let text = format!("{GOOD}[live]\n{bad}\n");
        let (line, msg) = error(&text);
        assert_eq!(line, line_of(&text, needle), "{msg}");
        assert!(msg.contains(what), "{msg}");
    }
    let (_, msg) = error(&format!("{GOOD}[live]\nraw_hz = 5\n"));
    assert!(msg.contains("listen"), "{msg}");
}

/// Every mistake of a file comes in one error, each with its own line, in the file's order:
/// one `--check` is enough to fix them all.
#[test]
fn every_mistake_is_reported_in_one_pass() {
    let text = GOOD
        .replace("machine = \"mill-01\"", "machine = \"mill 01\"")
        .replace("stop_at", "trajectory = \"no-such.csv\"\nstop_at")
        .replace("rate_hz = 1000\nalpha", "rate_hz = 20000\nalpha")
        .replace("alpha_um_per_m_k = 11.7", "alpha_um_per_m_k = 1.17e-5x")
        .replace("baud = 921600", "baud = 1234")
        .replace("can_id = 0x181", "can_id = 0x800");
    // 1.17e-5x is no TOML: that one stops the reader, so keep the value valid here.
    let text = text.replace("1.17e-5x", "1000.0");
    let e = parse(&text).unwrap_err();
    let each: Vec<String> = e.each().iter().map(|e| e.to_string()).collect();
    let want = [
        ("mill 01", "must be a non-empty name"),
        ("no-such.csv", "cannot be read"),
        ("rate_hz = 20000", "outside what the LI-80 supports"),
        ("alpha_um_per_m_k", "not a plausible expansion coefficient"),
        ("baud = 1234", "not a baud rate the PSD-2 supports"),
        ("can_id = 0x800", "not a CAN 2.0A"),
    ];
    assert_eq!(each.len(), want.len(), "{e}");
    for ((needle, what), msg) in want.iter().zip(&each) {
        let line = line_of(&text, needle);
        assert!(
            msg.starts_with(&format!("/etc/metrolog/metrolog.toml:{line}:")),
            "{needle}: {msg}"
        );
        assert!(msg.contains(what), "{msg}");
    }
    assert!(
        e.to_string().starts_with("6 problems in the config:"),
        "{e}"
    );
    assert_eq!(e.line(), Some(line_of(&text, "mill 01")));
}

#[test]
fn one_port_given_to_two_instruments_is_refused() {
    let text = GOOD.replace("/dev/metrolog-cb3", "/dev/metrolog-li80");
    let (line, msg) = error(&text);
    assert_eq!(line, line_of(&text, "[capball]") + 1);
    assert!(
        msg.contains("[capball] port = \"/dev/metrolog-li80\" is already [interferometer] port"),
        "{msg}"
    );
}

/// A config whose ports are this temporary directory's paths.
fn with_ports(dir: &Path, extra: &str) -> PathBuf {
    let text = GOOD
        .replace("/dev/metrolog-li80\"", &format!("/dev/null\"\n{extra}"))
        .replace("/dev/metrolog-", &format!("{}/", dir.display()))
        .replace("/var/lib/metrolog", &dir.join("logs").display().to_string());
    let p = dir.join("metrolog.toml");
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn a_port_that_does_not_exist_is_an_error_unless_hotplug() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = with_ports(dir.path(), "");
    // Parsing alone does not look at the devices.
    assert!(Config::load(&cfg).is_ok());
    let e = Config::load_checked(&cfg).unwrap_err();
    let each: Vec<String> = e.each().iter().map(|e| e.to_string()).collect();
    // cb3, psd2, slcan are missing; /dev/null is a device.
    assert_eq!(each.len(), 3, "{e}");
    let cb3 = dir.path().join("cb3");
    assert!(
        each[0].contains(&format!(
            "[capball] port = {:?} does not exist",
            cb3.display().to_string()
        )),
        "{}",
        each[0]
    );
    assert!(each.iter().all(|m| m.contains("hotplug = true")), "{e}");

    // hotplug on each: no error; the absence is a note.
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace(
            "rate_hz = 1000\npoly",
            "hotplug = true\nrate_hz = 1000\npoly",
        )
        .replace("baud = ", "hotplug = true\nbaud = ")
        .replace("can_id = ", "hotplug = true\ncan_id = ");
    std::fs::write(&cfg, text).unwrap();
    let c = Config::load_checked(&cfg).unwrap();
    let notes = c.notes();
    assert_eq!(notes.len(), 3, "{notes:?}");
    assert!(
        notes[0].contains("does not exist now (hotplug = true"),
        "{notes:?}"
    );
}

#[test]
fn port_and_value_mistakes_come_together() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = with_ports(dir.path(), "");
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("samples = 150", "samples = 2");
    std::fs::write(&cfg, text).unwrap();
    let e = Config::load_checked(&cfg).unwrap_err();
    assert_eq!(e.each().len(), 4, "{e}");
    assert!(e.to_string().contains("samples = 2 is impossible"), "{e}");
}

#[test]
fn output_dir_that_is_a_file_is_refused_when_checked() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("logs"), "").unwrap();
    let cfg = dir.path().join("m.toml");
    std::fs::write(
        &cfg,
        "[run]\nmachine = \"m\"\noutput_dir = \"logs\"\n[interferometer]\nport = \"/dev/null\"\n",
    )
    .unwrap();
    let e = Config::load_checked(&cfg).unwrap_err().to_string();
    assert!(e.contains(":3:") && e.contains("is not a directory"), "{e}");
}

#[test]
fn storage_policy_is_read_and_its_mistakes_reported_together() {
    let c = parse(GOOD).unwrap();
    // Absent: nothing is deleted, the warning stays on (5 GB).
    assert_eq!(c.storage.keep, None);
    assert_eq!(c.storage.min_free_bytes, None);
    assert_eq!(c.storage.warn_free_bytes, 5_000_000_000);
    let c = parse(&format!(
        "{GOOD}[storage]\nkeep_days = 30\nmin_free_gb = 2.5\nwarn_free_gb = 10\n"
    ))
    .unwrap();
    assert_eq!(
        c.storage.keep,
        Some(std::time::Duration::from_secs(30 * 86_400))
    );
    assert_eq!(c.storage.min_free_bytes, Some(2_500_000_000));
    assert_eq!(c.storage.warn_free_bytes, 10_000_000_000);
    assert_eq!((c.storage.split_after, c.storage.split_bytes), (None, None));
    let c = parse(&format!(
        "{GOOD}[storage]\nsplit_minutes = 30\nsplit_mb = 500\n"
    ))
    .unwrap();
    assert_eq!(
        c.storage.split_after,
        Some(std::time::Duration::from_secs(30 * 60))
    );
    assert_eq!(c.storage.split_bytes, Some(500_000_000));
    let text = format!(
        "{GOOD}[storage]\nkeep_days = 0\nmin_free_gb = -1\nwarn_free_gb = nan\nsplit_minutes = 0.5\nsplit_mb = 0\n"
    );
    let e = parse(&text).unwrap_err();
    let each: Vec<String> = e.each().iter().map(|e| e.to_string()).collect();
    assert_eq!(each.len(), 5, "{e}");
    for (msg, key) in each.iter().zip([
        "keep_days",
        "min_free_gb",
        "warn_free_gb",
        "split_minutes",
        "split_mb",
    ]) {
        let line = line_of(&text, key);
        assert!(
            msg.starts_with(&format!("/etc/metrolog/metrolog.toml:{line}:"))
                && msg.contains(&format!("{key} = ")),
            "{msg}"
        );
    }
}

/// `reference_pose`: poses of the trajectory at the interferometer's datum position (X 0),
/// one or a list; every other case named at its line.
#[test]
fn reference_poses_must_be_trajectory_poses_at_the_datum_position() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("p.csv"),
        "pose,x_mm,y_mm,z_mm\n1,0,0,0\n2,100,0,0\n3,0,0,0\n",
    )
    .unwrap();
    let with = |keys: &str, traj: bool| {
        let t = if traj { "trajectory = \"p.csv\"\n" } else { "" };
        GOOD.replace("stop_at", &format!("{t}{keys}\nstop_at"))
    };
    let parse_in = |text: &str| Config::parse(&dir.path().join("m.toml"), text);
    let c = parse_in(&with("reference_pose = 3", true)).unwrap();
    assert_eq!(c.run.reference_poses, vec![3]);
    assert_eq!(c.run.reference_settle_s, 0.2);
    let c = parse_in(&with(
        "reference_pose = [1, 3]\nreference_settle_s = 0.5",
        true,
    ))
    .unwrap();
    assert_eq!(
        (c.run.reference_poses, c.run.reference_settle_s),
        (vec![1, 3], 0.5)
    );
    assert!(parse(GOOD).unwrap().run.reference_poses.is_empty());
    for (keys, traj, want) in [
        (
            "reference_pose = [1, 2]",
            true,
            "reference_pose 2 has target X 100 mm, not the interferometer's datum position",
        ),
        (
            "reference_pose = 4",
            true,
            "reference_pose 4 is not a pose of the trajectory (1 to 3)",
        ),
        (
            "reference_pose = 1",
            false,
            "reference_pose needs a trajectory",
        ),
        (
            "reference_pose = 1\nreference_settle_s = 0",
            true,
            "reference_settle_s = 0 must be above 0",
        ),
    ] {
        let text = with(keys, traj);
        let e = parse_in(&text).unwrap_err();
        assert!(e.to_string().contains(want), "{keys}: {e}");
        let last = keys.lines().last().unwrap();
        assert_eq!(e.line(), Some(line_of(&text, last)), "{keys}: {e}");
    }
    let text = with("reference_pose = 1", true).replace(
        "[interferometer]\nport = \"/dev/metrolog-li80\"\nrate_hz = 1000\nalpha_um_per_m_k = 11.7\n",
        "",
    );
    let e = parse_in(&text).unwrap_err().to_string();
    assert!(e.contains("there is no [interferometer]"), "{e}");
}
