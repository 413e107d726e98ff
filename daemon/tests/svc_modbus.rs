//! `metrolog run` with a `[temperature]` section logs the temperatures of pymodbus's RTU
//! server (`tests/python/modbus_slave.py`, a peer this project did not write) playing the
//! module, through a relay between two ptys that drops one answer (a timeout) and corrupts
//! another's CRC, pymodbus answering one request with an exception. The log is read back: every
//! register answer that reached the daemon intact is a `/temperature` sample, in order, with
//! the values pymodbus sent, and each fault is counted in `/status` (it costs that poll only).
//! Skips with a message without python3 and pymodbus, fails instead when `CI=true`.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use drivers::SampleValues;
use hil::{ModbusRelay, Relay, pymodbus_available};
use metrolog_log::topics::{LogMessage, StatusMsg, decode_message};
use metrolog_log::{LogItem, RUN_METADATA, TEMPERATURE_SENSORS_KEY, read_log};

const CHANNELS: usize = 4;
const REQUESTS: usize = 12;
const UNIT: u8 = 9;
/// The driver's answer timeout. An answer later than this is discarded and counted as a timeout
/// (as it should be), so it must be far longer than pymodbus can take on a loaded CI machine:
/// with 0.3 s, two answers of a full CI run came late and the log rightly lacked them.
const TIMEOUT_S: f64 = 2.0;

/// Wait until `cond` holds, at most `limit`.
fn wait_for(limit: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        if cond() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    cond()
}

fn config(dir: &Path, link: &Path) -> PathBuf {
    let mut text = format!(
        "[run]\nmachine = \"modbus-test\"\noutput_dir = \"{}\"\n\n[temperature]\nport = \"{}\"\nunit = {UNIT}\npoll_period_s = 0.05\ntimeout_s = {TIMEOUT_S}\nsilence_s = 60\n",
        dir.join("logs").display(),
        link.display()
    );
    for (name, location) in [
        ("spindle", "spindle head"),
        ("bed", "machine bed"),
        ("air", "ambient"),
        ("open", "unplugged"),
    ] {
        text += &format!("[[temperature.sensors]]\nname = \"{name}\"\nlocation = \"{location}\"\n");
    }
    let p = dir.join("metrolog.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// What the log holds: the temperatures of `/temperature` with their seq, the last `/status`
/// and the run metadata.
struct Logged {
    samples: Vec<(u64, Vec<f64>)>,
    status: Option<StatusMsg>,
    run: std::collections::BTreeMap<String, String>,
}

fn read_back(path: &Path) -> Logged {
    let mut l = Logged {
        samples: Vec::new(),
        status: None,
        run: Default::default(),
    };
    let summary = read_log(path, |item| match item {
        LogItem::Message {
            topic,
            encoding,
            log_ns,
            data,
        } => match decode_message(topic, encoding, log_ns, data).unwrap() {
            Some(LogMessage::Samples(ss)) => {
                for s in ss {
                    match s.values {
                        SampleValues::Temperature { values_c } => l.samples.push((s.seq, values_c)),
                        other => panic!("a sample of {topic}: {other:?}"),
                    }
                }
            }
            Some(LogMessage::Status(st)) => l.status = Some(st),
            _ => {}
        },
        LogItem::Metadata { name, map } if name == RUN_METADATA => l.run = map.clone(),
        _ => {}
    })
    .unwrap();
    assert!(summary.clean_close, "{summary:?}");
    l
}

fn the_log(dir: &Path) -> PathBuf {
    let logs: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    assert_eq!(logs.len(), 1, "one log per run: {logs:?}");
    logs[0].clone()
}

fn stderr_of(mut c: Child) -> String {
    use std::io::Read;
    let _ = c.kill();
    let _ = c.wait();
    let mut s = String::new();
    if let Some(mut e) = c.stderr.take() {
        let _ = e.read_to_string(&mut s);
    }
    s
}

#[test]
fn run_logs_the_temperatures_of_a_pymodbus_slave_and_counts_its_faults() {
    if !pymodbus_available("run_logs_the_temperatures_of_a_pymodbus_slave") {
        return;
    }
    // Answer 3 is dropped (a timeout), 5 is pymodbus's exception, 7 gets a wrong CRC.
    let plan = |k: usize| match k {
        3 => Relay::Drop,
        7 => Relay::CorruptCrc,
        _ => Relay::Pass,
    };
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("temp");
    let relay = ModbusRelay::start(&link, plan).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/python/modbus_slave.py");
    let mut slave = Command::new("python3")
        .arg(script)
        .arg(&relay.peer_path)
        .args([
            &UNIT.to_string(),
            &CHANNELS.to_string(),
            &REQUESTS.to_string(),
            "5",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let cfg = config(dir.path(), &link);
    let daemon = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["run", "--config"])
        .arg(&cfg)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();

    // pymodbus stops by itself after its requests (and 0.5 s of busy answers).
    let slave_done = wait_for(Duration::from_secs(60), || {
        slave.try_wait().unwrap().is_some()
    });
    assert!(slave_done, "pymodbus did not finish: {}", stderr_of(daemon));
    let out = slave.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "pymodbus slave failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The driver polls one request at a time: two more requests after pymodbus ended mean
    // every answer before them has been handled (a sample queued or a fault counted).
    let n = relay.requests();
    assert!(
        wait_for(Duration::from_secs(30), || relay.requests() >= n + 2),
        "the daemon stopped polling"
    );
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(daemon.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    let out_d = daemon.wait_with_output().unwrap();
    let relayed = relay.relayed();
    relay.stop();
    assert!(
        out_d.status.success(),
        "metrolog run: {}",
        String::from_utf8_lossy(&out_d.stderr)
    );

    let answered: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(answered.len(), REQUESTS, "{answered:?}");
    // pymodbus's register answers the relay passed intact, decoded as the data sheet says
    // (0.1 °C, two's complement, 0x8000 an open sensor), computed here.
    let want: Vec<Vec<Option<f64>>> = answered
        .iter()
        .zip(&relayed)
        .filter(|(e, r)| e.get("registers").is_some() && **r == Relay::Pass)
        .map(|(e, _)| {
            e["registers"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| match v.as_u64().unwrap() as u16 {
                    0x8000 | 0x7FFF => None,
                    r => Some(r as i16 as f64 / 10.0),
                })
                .collect()
        })
        .collect();
    assert_eq!(want.len(), REQUESTS - 3);

    let log = read_back(&the_log(&dir.path().join("logs")));
    let got: Vec<&Vec<f64>> = log.samples.iter().map(|(_, v)| v).collect();
    let timeouts = log.status.as_ref().map(|st| {
        st.instruments["temperature"]
            .rejections
            .get("timeout")
            .copied()
    });
    assert_eq!(
        got.len(),
        want.len(),
        "{got:?}; timeouts counted: {timeouts:?} (an answer later than {TIMEOUT_S} s is one)"
    );
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g.len(), CHANNELS);
        for (g, w) in g.iter().zip(w) {
            match w {
                None => assert!(g.is_nan(), "{g} for an open sensor"),
                Some(w) => assert!((g - w).abs() < 1e-9, "{g} vs {w}"),
            }
        }
    }
    // Nothing lost between them: the driver numbered them 0, 1, 2, ...
    let seqs: Vec<u64> = log.samples.iter().map(|(s, _)| *s).collect();
    assert_eq!(seqs, (0..want.len() as u64).collect::<Vec<_>>());

    let st = log.status.expect("a /status record");
    let c = &st.instruments["temperature"];
    assert_eq!(c.samples, want.len() as u64, "{c:?}");
    assert_eq!(c.invalid, c.samples, "the last channel is an open sensor");
    assert_eq!(c.rejections.get("bad_crc"), Some(&1), "{c:?}");
    // pymodbus's exception for request 5, then its busy answers while it stopped.
    assert!(
        c.rejections.get("exception").is_some_and(|&n| n >= 1),
        "{c:?}"
    );
    // The dropped answer, then the polls after pymodbus ended.
    assert!(
        c.rejections.get("timeout").is_some_and(|&n| n >= 3),
        "{c:?}"
    );
    let sensors: serde_json::Value =
        serde_json::from_str(&log.run[TEMPERATURE_SENSORS_KEY]).unwrap();
    assert_eq!(sensors[0]["name"], "spindle");
    assert_eq!(sensors[3]["location"], "unplugged");
    assert_eq!(log.run["instruments_configured"], "temperature");
}
