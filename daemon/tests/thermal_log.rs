//! `metrolog thermal fit | diagnose` read a run's log: the `/temperature` samples and the pose
//! values of the measuring pose become a thermal test, one row per visit. The log is written
//! here with known temperatures and pose values; the rows are checked against values computed
//! here from the same formulas (the mean of the readings in a visit's window, or the linear
//! interpolation when the window holds none).

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use drivers::{Instrument, Sample, SampleValues};
use metrolog::cmd::thermal::from_log::dataset_from_log;
use metrolog_log::topics::PoseMsg;
use metrolog_log::{LogOptions, LogWriter, RunMetadata, TEMPERATURE_SENSORS_KEY};
use types::PoseStatus;

const T0: u64 = 1_795_305_600_000_000_000;
const VISITS: usize = 90;

fn spindle(t: f64) -> f64 {
    20.0 + 4.0 * (1.0 - (-t / 2400.0).exp())
}
fn air(t: f64) -> f64 {
    20.0 + 0.2 * (2.0 * std::f64::consts::PI * t / 3600.0).sin()
}
fn ns(t: f64) -> u64 {
    T0 + (t * 1e9).round() as u64
}

/// Visit `j`: centre, and the window (visit 5's holds no reading: 81..83 s past its centre).
fn window(j: usize) -> (f64, f64) {
    let c = 80.0 + 120.0 * j as f64;
    if j == 5 {
        (c + 1.0, c + 3.0)
    } else {
        (c - 5.0, c + 5.0)
    }
}

fn pose(instrument: Instrument, pose: u32, from: f64, to: f64, mean: &[(&str, f64)]) -> PoseMsg {
    PoseMsg {
        instrument,
        pose,
        status: PoseStatus::Ok,
        n: 150,
        mean: mean.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
        std: BTreeMap::new(),
        t_first_ns: ns(from),
        t_last_ns: ns(to),
        datum_epoch: 0,
    }
}

/// ex = 3 µm/K of the spindle 10 min earlier, ey = −1 µm/K of the air, PSD x = 0.5 µm/K.
fn displacements(t: f64) -> [f64; 3] {
    [
        3.0 * (spindle(t - 600.0) - 20.0),
        -(air(t) - 20.0),
        0.5 * (spindle(t) - 20.0),
    ]
}

fn write_log(path: &Path, with_temperatures: bool) {
    let mut meta = RunMetadata {
        machine: "thermal-test".into(),
        started_ns: T0,
        ..RunMetadata::default()
    };
    meta.extra.insert(
        TEMPERATURE_SENSORS_KEY.into(),
        r#"[{"name":"spindle","location":"head"},{"name":"air","location":""},{"name":"open","location":""}]"#.into(),
    );
    let mut w = LogWriter::create(path, &meta, LogOptions::default()).unwrap();
    let mut j = 0;
    for k in 0..=1080u64 {
        let t = 10.0 * k as f64;
        if with_temperatures {
            let s = Sample {
                instrument: Instrument::Thermometer,
                seq: k,
                device_t_us: (t * 1e6) as u64,
                host_ns: ns(t) + 1_000_000,
                fitted_ns: ns(t),
                valid: false,
                values: SampleValues::Temperature {
                    values_c: vec![spindle(t), air(t), f64::NAN],
                },
            };
            w.write_sample(&s).unwrap();
        }
        while j < VISITS && window(j).1 <= t {
            let (a, b) = window(j);
            let d = displacements((a + b) / 2.0);
            w.write_pose(
                ns(b),
                &pose(
                    Instrument::Capball,
                    1,
                    a,
                    b,
                    &[("ex_um", d[0]), ("ey_um", d[1])],
                ),
            )
            .unwrap();
            w.write_pose(
                ns(b),
                &pose(
                    Instrument::Psd,
                    1,
                    a,
                    b,
                    &[("x_um", d[2]), ("y_um_std", 9.0)],
                ),
            )
            .unwrap();
            if j == 3 {
                // Another pose, visited once: left out.
                w.write_pose(
                    ns(b),
                    &pose(Instrument::Capball, 2, a, b, &[("ex_um", 100.0)]),
                )
                .unwrap();
            }
            j += 1;
        }
    }
    w.finish().unwrap();
}

#[test]
fn a_logs_temperatures_and_pose_values_make_a_thermal_test_row_per_visit() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    write_log(&path, true);
    let ds = dataset_from_log(&path).unwrap();
    // The open sensor has no reading: left out.
    assert_eq!(ds.sensor_names, ["spindle", "air"]);
    assert_eq!(ds.channel_names, ["capball_ex", "capball_ey", "psd_x"]);
    assert_eq!(ds.len(), VISITS);
    let c0 = 80.0;
    for j in 0..VISITS {
        let (a, b) = window(j);
        let mid = (a + b) / 2.0;
        assert!(
            (ds.time_s[j] - (mid - c0)).abs() < 1e-6,
            "visit {j}: {}",
            ds.time_s[j]
        );
        // Readings every 10 s: the window of a usual visit holds the one at its centre;
        // visit 5's holds none, so the values at c and c + 10 s are interpolated at c + 2 s.
        let want = |f: fn(f64) -> f64| {
            if j == 5 {
                let c = 80.0 + 120.0 * 5.0;
                f(c) + 0.2 * (f(c + 10.0) - f(c))
            } else {
                f(mid)
            }
        };
        assert!(
            (ds.temperatures_c[0][j] - want(spindle)).abs() < 1e-12,
            "visit {j}"
        );
        assert!(
            (ds.temperatures_c[1][j] - want(air)).abs() < 1e-12,
            "visit {j}"
        );
        let d = displacements(mid);
        for (k, dk) in d.iter().enumerate() {
            assert_eq!(ds.displacements_um[k][j], *dk, "visit {j} channel {k}");
        }
    }
}

#[test]
fn thermal_fit_and_diagnose_take_a_log() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    write_log(&path, true);
    let model = dir.path().join("model.json");
    let bin = env!("CARGO_BIN_EXE_metrolog");
    let out = Command::new(bin)
        .args(["thermal", "fit"])
        .arg(&path)
        .arg("-o")
        .arg(&model)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains(&format!("{VISITS} samples")), "{text}");
    // The sensitivities the log was written with: PSD x 0.5 µm/K of the spindle, CapBall ey
    // -1 µm/K of the air (ex follows the spindle 10 min late: for an exponential rise that is
    // the spindle itself times e^(600/2400), 3.852 µm/K, without a lag).
    for (channel, want) in [
        (
            "psd_x:",
            "sensor spindle (rise above 20.50 °C), no lag: +0.500 µm/K",
        ),
        (
            "capball_ey:",
            "sensor air (rise above 20.11 °C), no lag: -1.000 µm/K",
        ),
        (
            "capball_ex:",
            "sensor spindle (rise above 20.50 °C), no lag: +3.852 µm/K",
        ),
    ] {
        // The channel's lines: its header and the indented terms under it.
        let block: String = text
            .lines()
            .skip_while(|l| !l.starts_with(channel))
            .skip(1)
            .take_while(|l| l.starts_with("  "))
            .collect::<Vec<_>>()
            .join("\n");
        assert!(block.contains(want), "{channel} {want:?} in {text}");
    }
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("\"open\"") && err.contains("pose 1"), "{err}");
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(&model).unwrap()).unwrap();
    assert!(m.to_string().contains("capball_ex"), "{m}");
    let out = Command::new(bin)
        .args(["thermal", "diagnose"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // A log without temperatures says what it lacks.
    let bare = dir.path().join("bare.mcap");
    write_log(&bare, false);
    let out = Command::new(bin)
        .args(["thermal", "fit"])
        .arg(&bare)
        .arg("-o")
        .arg(dir.path().join("m2.json"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no /temperature samples"), "{err}");
}
