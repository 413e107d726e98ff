//! The `[temperature]` section (Modbus RTU temperature module, docs/instruments.md §5): the
//! values written reach the driver's configuration, the defaults are the documented ones, and
//! every mistake is reported at the line of its key with what to fix.

use std::path::Path;

use metrolog::acquire::config::{Config, ConfigError};

const RUN: &str = "[run]\nmachine = \"m\"\noutput_dir = \"out\"\n";

const SECTION: &str = r#"[temperature]
port = "/dev/ttyUSB3"
baud = 19200
parity = "even"
unit = 12
registers = "holding"
start_register = 100
scale_c = 0.01
offset_c = -0.5
fault_values = [-32768, 32767, 30000]
poll_period_s = 5.0
timeout_s = 0.5
silence_s = 30
[[temperature.sensors]]
name = "spindle_head"
location = "  front bearing  "
[[temperature.sensors]]
name = "bed"
"#;

fn parse(section: &str) -> Result<Config, ConfigError> {
    Config::parse(
        Path::new("/etc/metrolog/metrolog.toml"),
        &format!("{RUN}{section}"),
    )
}

/// The error for `section` with `from` replaced by `to`: (line, message); the line must be
/// the one holding `at`.
fn error_at(from: &str, to: &str, at: &str) -> String {
    let section = SECTION.replace(from, to);
    assert_ne!(section, SECTION, "{from:?} is not in the section");
    let e = match parse(&section) {
        Ok(_) => panic!("accepted {to:?}"),
        Err(e) => e,
    };
    let text = format!("{RUN}{section}");
    let want = text.lines().position(|l| l.contains(at)).expect("at") + 1;
    assert_eq!(e.line(), Some(want), "{e}");
    e.to_string()
}

#[test]
fn the_values_written_reach_the_driver_config() {
    let c = parse(SECTION).unwrap();
    let t = c.temperature.as_ref().unwrap();
    assert_eq!(t.port, "/dev/ttyUSB3");
    assert_eq!((t.baud, t.unit, t.start_register), (19200, 12, 100));
    assert_eq!(t.parity, drivers::Parity::Even);
    assert_eq!(t.registers, drivers::RegisterKind::Holding);
    assert_eq!((t.scale_c, t.offset_c), (0.01, -0.5));
    assert_eq!(t.fault_values, vec![-32768, 32767, 30000]);
    assert_eq!(
        (t.poll_period_s, t.timeout_s, t.silence_s),
        (5.0, 0.5, 30.0)
    );
    let names: Vec<_> = t.sensors.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["spindle_head", "bed"]);
    assert_eq!(t.sensors[0].location, "front bearing");
    assert_eq!(t.sensors[1].location, "");
    assert_eq!(c.instruments(), vec![drivers::Instrument::Thermometer]);
    // The read it polls with: 2 holding registers from 100 of unit 12.
    let r = t.request();
    assert_eq!((r.unit, r.function, r.start, r.count), (12, 3, 100, 2));
}

#[test]
fn defaults_are_the_documented_ones() {
    let c = parse(
        "[temperature]\nport = \"/dev/t\"\nunit = 1\n[[temperature.sensors]]\nname = \"a\"\n",
    )
    .unwrap();
    let t = c.temperature.unwrap();
    assert_eq!((t.baud, t.parity), (9600, drivers::Parity::None));
    assert_eq!(
        (t.registers, t.start_register),
        (drivers::RegisterKind::Input, 0)
    );
    assert_eq!((t.scale_c, t.offset_c), (0.1, 0.0));
    assert_eq!(t.fault_values, vec![i16::MIN, i16::MAX]);
    assert_eq!(
        (t.poll_period_s, t.timeout_s, t.silence_s),
        (1.0, 0.3, 10.0)
    );
    assert!(parse("").unwrap().temperature.is_none());
}

#[test]
fn each_mistake_is_reported_at_its_key() {
    let cases: [(&str, &str, &str, &[&str]); 16] = [
        (
            "port = \"/dev/ttyUSB3\"",
            "port = \" \"",
            "port",
            &["port is empty"],
        ),
        (
            "baud = 19200",
            "baud = 14400",
            "baud",
            &["baud = 14400", "9600"],
        ),
        (
            "parity = \"even\"",
            "parity = \"mark\"",
            "parity",
            &["mark", "even"],
        ),
        ("unit = 12", "unit = 0", "unit", &["unit = 0", "1 to 247"]),
        ("unit = 12", "unit = 248", "unit", &["unit = 248"]),
        (
            "registers = \"holding\"",
            "registers = \"coil\"",
            "registers",
            &["coil"],
        ),
        (
            "start_register = 100",
            "start_register = 65535",
            "start_register",
            &["65535 to 65536", "0 to 65535"],
        ),
        (
            "scale_c = 0.01",
            "scale_c = 0.0",
            "scale_c",
            &["scale_c = 0", "0.1"],
        ),
        (
            "offset_c = -0.5",
            "offset_c = nan",
            "offset_c",
            &["offset_c = NaN"],
        ),
        (
            "30000]",
            "40000]",
            "fault_values",
            &["40000", "-32768 to 32767"],
        ),
        (
            "poll_period_s = 5.0",
            "poll_period_s = -1",
            "poll_period_s",
            &["poll_period_s = -1", "> 0"],
        ),
        (
            "poll_period_s = 5.0",
            "poll_period_s = 7200",
            "poll_period_s",
            &["more than an hour"],
        ),
        (
            "poll_period_s = 5.0",
            "poll_period_s = 0.001",
            "poll_period_s",
            &["shorter than a poll", "ms on the wire at 19200 baud"],
        ),
        (
            "timeout_s = 0.5",
            "timeout_s = 0.002",
            "timeout_s",
            &["timeout_s = 0.002", "raise timeout_s or baud"],
        ),
        (
            "silence_s = 30",
            "silence_s = 5",
            "silence_s",
            &["silence_s = 5", "poll_period_s + timeout_s = 5.5"],
        ),
        (
            "name = \"bed\"",
            "name = \"2nd bed\"",
            "2nd bed",
            &["start with a letter"],
        ),
    ];
    for (from, to, at, want) in cases {
        let msg = error_at(from, to, at);
        for w in want {
            assert!(msg.contains(w), "{to:?}: {msg:?} lacks {w:?}");
        }
    }
}

#[test]
fn a_sensor_name_given_twice_is_reported_at_the_second() {
    let section = SECTION.replace("name = \"bed\"", "name = \"spindle_head\"");
    let e = parse(&section).unwrap_err();
    let text = format!("{RUN}{section}");
    let lines: Vec<usize> = (1..=text.lines().count())
        .filter(|&i| {
            text.lines()
                .nth(i - 1)
                .unwrap()
                .contains("\"spindle_head\"")
        })
        .collect();
    assert_eq!(lines.len(), 2);
    assert_eq!(e.line(), Some(lines[1]), "{e}");
    assert!(e.to_string().contains("given twice"), "{e}");
}

#[test]
fn missing_and_unknown_keys_and_sensor_lists() {
    let e = parse(&SECTION.replace("unit = 12\n", ""))
        .unwrap_err()
        .to_string();
    assert!(e.contains("unit"), "{e}");
    let e = parse(&SECTION.replace("baud = 19200", "baud_rate = 19200"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("unknown field") && e.contains("baud_rate"),
        "{e}"
    );
    let e = parse(&SECTION.replace("location = \"  front bearing  \"", "place = \"x\""))
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown field") && e.contains("place"), "{e}");
    // No sensors: reported at the section, saying what to add.
    let cut = SECTION.split("[[temperature.sensors]]").next().unwrap();
    let e = parse(cut).unwrap_err();
    assert_eq!(e.line(), Some(4), "{e}");
    assert!(e.to_string().contains("[[temperature.sensors]]"), "{e}");
    // 126 sensors: more than one read returns.
    let many: String = (0..126)
        .map(|i| format!("[[temperature.sensors]]\nname = \"t{i}\"\n"))
        .collect();
    let e = parse(&format!("{cut}{many}")).unwrap_err().to_string();
    assert!(e.contains("126 channels") && e.contains("1 to 125"), "{e}");
    // 125 at 1200 baud: a read takes 2.3 s, longer than the default timeout; said at the section.
    let slow = format!(
        "[temperature]\nport = \"/dev/t\"\nunit = 1\nbaud = 1200\npoll_period_s = 10\n{}",
        &many[..many.rfind("[[").unwrap()]
    );
    let e = parse(&slow).unwrap_err();
    assert_eq!(e.line(), Some(4), "{e}");
    assert!(e.to_string().contains("timeout_s = 0.3"), "{e}");
}

#[test]
fn a_channel_may_have_its_own_scale() {
    // The spindle speed on an analogue input of the module: rpm per count.
    let section = SECTION.replace("name = \"bed\"", "name = \"spindle_rpm\"\nscale = 1.0");
    let c = parse(&section).unwrap();
    let t = c.temperature.as_ref().unwrap();
    assert_eq!((t.sensors[0].scale, t.sensors[1].scale), (None, Some(1.0)));
    let e = error_at(
        "name = \"bed\"",
        "name = \"bed\"\nscale = 0.0",
        "scale = 0.0",
    );
    assert!(
        e.contains("scale = 0 must be a finite number other than 0"),
        "{e}"
    );
}
