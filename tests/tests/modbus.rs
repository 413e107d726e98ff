//! The Modbus RTU temperature module (instruments.md §5) from both sides, each against a peer
//! this project did not write where one exists:
//! - our driver (`tokio-modbus` client) reads our simulated module (`sim::modbus`), with a
//!   timeout, an exception and a bad CRC injected;
//! - our driver reads pymodbus's RTU server (`tests/python/modbus_slave.py`) through a relay
//!   between two ptys that drops one answer and corrupts another's CRC, pymodbus itself
//!   answering one request with an exception;
//! - pymodbus's RTU client (`tests/python/modbus_master.py`) reads our simulated module.
//!
//! Every fault must be counted once, by kind, and every other answer must be a sample, in
//! order, with the values the peer sent. The Python tests skip with a message when python3 or
//! pymodbus is missing, and fail instead when `CI=true`.

use std::sync::Arc;
use std::time::Duration;

use drivers::{HostClock, ModbusTempConfig, SampleValues, TempSensor};
use hil::{Collected, ModbusRelay, Relay, collect_until, finish, pymodbus_available};
use protocol::RejectKind;
use sim::modbus::{Answered, ModbusFault, ModbusModule, ModbusModuleConfig, Reply};
use tokio_util::sync::CancellationToken;

fn driver_config(port: &str, unit: u8, channels: usize) -> ModbusTempConfig {
    ModbusTempConfig {
        port: port.to_string(),
        baud: 9600,
        parity: drivers::Parity::None,
        unit,
        registers: drivers::RegisterKind::Input,
        start_register: 0,
        sensors: (0..channels)
            .map(|i| TempSensor {
                name: format!("t{i}"),
                location: String::new(),
                scale: None,
            })
            .collect(),
        scale_c: 0.1,
        offset_c: 0.0,
        fault_values: vec![i16::MIN, i16::MAX],
        poll_period_s: 0.05,
        // Long enough that only the injected no-answer times out on a loaded machine (an
        // answer later than this is counted as a timeout too).
        timeout_s: 2.0,
        silence_s: 10.0,
    }
}

fn temperatures(c: &Collected) -> Vec<Vec<f64>> {
    c.samples
        .iter()
        .map(|s| match &s.values {
            SampleValues::Temperature { values_c } => values_c.clone(),
            other => panic!("not a temperature: {other:?}"),
        })
        .collect()
}

fn rejections(c: &Collected, k: RejectKind) -> u64 {
    c.counters
        .as_ref()
        .and_then(|c| c.rejections.get(&k).copied())
        .unwrap_or(0)
}

/// The registers as the data sheet says the host reads them (written here, not the driver's).
fn expect_c(regs: &[u16]) -> Vec<Option<f64>> {
    regs.iter()
        .map(|&r| match r {
            0x8000 | 0x7FFF => None,
            r => Some(r as i16 as f64 / 10.0),
        })
        .collect()
}

fn assert_values(got: &[f64], want: &[Option<f64>]) {
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(want) {
        match w {
            None => assert!(g.is_nan(), "{got:?} vs {want:?}"),
            Some(w) => assert!((g - w).abs() < 1e-9, "{got:?} vs {want:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn our_driver_reads_the_simulated_module_and_counts_each_fault() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("temp");
    let cfg = ModbusModuleConfig {
        unit: 5,
        channels: 3,
        ..ModbusModuleConfig::default()
    };
    // Channel 0 rises 1 °C/s from 20 °C, channel 1 is -3.5 °C, channel 2 an open sensor.
    let module = ModbusModule::start(
        &link,
        cfg,
        Arc::new(|t| vec![Some(20.0 + t), Some(-3.5), None]),
    )
    .unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(1000);
    let cancel = CancellationToken::new();
    let dcfg = driver_config(&link.display().to_string(), 5, 3);
    let task = drivers::spawn_modbus_temperature(dcfg, HostClock::new(), tx, cancel.clone());
    let mut c = Collected::default();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(20), |c| c
            .samples
            .len()
            >= 3)
        .await,
        "no samples: {:?}",
        c.errors
    );
    module.inject([
        ModbusFault::NoAnswer,
        ModbusFault::Answer,
        ModbusFault::Exception(protocol::modbus::exception::DEVICE_BUSY),
        ModbusFault::Answer,
        ModbusFault::BadCrc,
    ]);
    let n0 = c.samples.len();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(20), |c| {
            c.samples.len() >= n0 + 5
                && rejections(c, RejectKind::BadCrc) == 1
                && rejections(c, RejectKind::Exception) == 1
                && rejections(c, RejectKind::Timeout) == 1
        })
        .await,
        "{:?} {:?}",
        c.counters,
        c.errors
    );
    finish(cancel, task, &mut rx, &mut c).await;
    let log = module.answered();
    module.shutdown().await;

    let k = c.counters.clone().unwrap();
    assert_eq!(k.rejections.values().sum::<u64>(), 3, "{k:?}");
    assert_eq!(k.samples, c.samples.len() as u64);
    assert_eq!(k.invalid, k.samples, "channel 2 is an open sensor");
    assert_eq!(c.connected.len(), 1);
    assert!(c.disconnected.is_empty(), "{:?}", c.disconnected);
    assert!(
        c.errors.iter().any(|e| e.contains("exception 06")),
        "{:?}",
        c.errors
    );
    // Every answer with registers is a sample, in order; each fault is a request without one.
    let answered: Vec<&Answered> = log
        .iter()
        .filter(|a| matches!(a.reply, Reply::Registers(_)))
        .collect();
    let faults = log.len() - answered.len();
    assert_eq!(faults, 3, "{log:?}");
    let temps = temperatures(&c);
    // The last request may have been answered while the driver was cancelled.
    assert!(
        temps.len() == answered.len() || temps.len() + 1 == answered.len(),
        "{} samples, {} answers",
        temps.len(),
        answered.len()
    );
    for (t, a) in temps.iter().zip(&answered) {
        let Reply::Registers(r) = &a.reply else {
            unreachable!()
        };
        assert_values(t, &expect_c(r));
        assert!(
            (t[0] - (20.0 + a.t_s)).abs() < 0.051,
            "{t:?} at {} s",
            a.t_s
        );
    }
    for (i, s) in c.samples.iter().enumerate() {
        assert_eq!(s.seq, i as u64);
        assert!(!s.valid);
        assert_eq!(s.instrument, drivers::Instrument::Thermometer);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn our_driver_reads_the_pymodbus_slave() {
    hil::init_tracing();
    if !pymodbus_available("our_driver_reads_the_pymodbus_slave") {
        return;
    }
    const CHANNELS: usize = 4;
    const REQUESTS: usize = 12;
    // Answer 3 is dropped (a timeout), 5 is pymodbus's exception, 7 gets a wrong CRC.
    let plan = |k: usize| match k {
        3 => Relay::Drop,
        7 => Relay::CorruptCrc,
        _ => Relay::Pass,
    };
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("temp");
    let relay = ModbusRelay::start(&link, plan).unwrap();

    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/python/modbus_slave.py");
    let py_path = relay.peer_path.clone();
    let slave = tokio::task::spawn_blocking(move || {
        std::process::Command::new("python3")
            .arg(script)
            .arg(&py_path)
            .args(["9", &CHANNELS.to_string(), &REQUESTS.to_string(), "5"])
            .output()
    });
    let (tx, mut rx) = tokio::sync::mpsc::channel(1000);
    let cancel = CancellationToken::new();
    let dcfg = driver_config(&link.display().to_string(), 9, CHANNELS);
    let task = drivers::spawn_modbus_temperature(dcfg, HostClock::new(), tx, cancel.clone());
    let mut c = Collected::default();
    // Until the driver has handled pymodbus's requests: a sample or a counted fault each
    // (pymodbus answers later ones with exception 06 until it stops; they are left out).
    let done = collect_until(&mut rx, &mut c, Duration::from_secs(60), |c| {
        let faults: u64 = c
            .counters
            .as_ref()
            .map_or(0, |k| k.rejections.values().sum());
        c.samples.len() + faults as usize >= REQUESTS
    })
    .await;
    let at_done = c.counters.clone();
    cancel.cancel();
    let out = slave.await.unwrap().expect("python3 runs");
    finish(cancel, task, &mut rx, &mut c).await;
    let relayed = relay.relayed();
    relay.stop();
    assert!(
        out.status.success(),
        "pymodbus slave failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(done, "{:?} {:?} {:?}", c.counters, c.errors, relayed);
    let samples_at_done = c.samples.len();
    let log: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(log.len(), REQUESTS, "{log:?}");
    let relayed = relayed[..REQUESTS].to_vec();

    // What must have become samples: pymodbus's register answers the relay passed intact.
    let want: Vec<Vec<u16>> = log
        .iter()
        .zip(&relayed)
        .filter(|(e, r)| e.get("registers").is_some() && **r == Relay::Pass)
        .map(|(e, _)| {
            e["registers"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap() as u16)
                .collect()
        })
        .collect();
    assert_eq!(want.len(), REQUESTS - 3);
    let temps = temperatures(&c);
    assert_eq!(temps.len(), want.len(), "{temps:?}");
    assert_eq!(
        samples_at_done,
        want.len(),
        "no sample after pymodbus's last answer"
    );
    for (t, w) in temps.iter().zip(&want) {
        assert_values(t, &expect_c(w));
    }
    let k = at_done.unwrap();
    assert_eq!(k.rejections.get(&RejectKind::Exception), Some(&1), "{k:?}");
    assert_eq!(k.rejections.get(&RejectKind::BadCrc), Some(&1), "{k:?}");
    assert_eq!(k.rejections.get(&RejectKind::Timeout), Some(&1), "{k:?}");
    assert_eq!(k.rejections.values().sum::<u64>(), 3, "{k:?}");
    let k = c.counters.unwrap();
    assert_eq!(k.invalid, k.samples, "the last channel is an open sensor");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymodbus_master_reads_the_simulated_module() {
    hil::init_tracing();
    if !pymodbus_available("pymodbus_master_reads_the_simulated_module") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("temp");
    let cfg = ModbusModuleConfig {
        unit: 17,
        channels: 4,
        ..ModbusModuleConfig::default()
    };
    let module = ModbusModule::start(
        &link,
        cfg,
        Arc::new(|t| vec![Some(21.0 + 0.5 * t), Some(-12.3), None, Some(850.0)]),
    )
    .unwrap();
    use ModbusFault::*;
    module.inject([
        Answer,
        Answer,
        NoAnswer,
        Answer,
        Exception(protocol::modbus::exception::DEVICE_FAILURE),
        Answer,
        BadCrc,
        Answer,
    ]);
    let port = link.clone();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/python/modbus_master.py");
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new("python3")
            .arg(script)
            .arg(&port)
            .args(["17", "4", "9"])
            .output()
    })
    .await
    .unwrap()
    .expect("python3 runs");
    let log = module.answered();
    module.shutdown().await;
    assert!(
        out.status.success(),
        "pymodbus master failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let reads: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(reads.len(), 9);
    assert_eq!(log.len(), 9, "one request per read: {log:?}");
    for (i, (r, a)) in reads.iter().zip(&log).enumerate() {
        match &a.reply {
            Reply::Registers(regs) => {
                let got: Vec<u16> = r["registers"]
                    .as_array()
                    .unwrap_or_else(|| panic!("read {i}: {r}"))
                    .iter()
                    .map(|v| v.as_u64().unwrap() as u16)
                    .collect();
                assert_eq!(&got, regs, "read {i}");
                // The data sheet's encoding, checked by hand: 0.1 °C, two's complement, 0x8000.
                assert_eq!(got[1], (-123i16) as u16);
                assert_eq!(got[2], 0x8000);
                assert_eq!(got[3], 8500);
                assert!((got[0] as f64 / 10.0 - (21.0 + 0.5 * a.t_s)).abs() <= 0.05);
            }
            Reply::Exception(code) => {
                assert_eq!(r["exception"].as_u64(), Some(*code as u64), "read {i}: {r}");
            }
            Reply::Silent | Reply::BadCrc(_) => {
                assert!(r.get("error").is_some(), "read {i}: {r}");
            }
        }
    }
    let kinds: Vec<_> = log
        .iter()
        .map(|a| match a.reply {
            Reply::Registers(_) => 'r',
            Reply::Exception(_) => 'e',
            Reply::Silent => 's',
            Reply::BadCrc(_) => 'c',
        })
        .collect();
    assert_eq!(kinds.iter().collect::<String>(), "rrsrercrr");
}
