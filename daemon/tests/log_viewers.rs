//! Every channel of a log opens in Foxglove and Lichtblick: the viewers' own MCAP reader
//! (npm `@mcap/core`, zstd from `@mcap/support`) reads a demo-like log, its JSON schemas are
//! checked against the rules the viewers' JSON-schema parser applies, and the raw protobuf
//! batches are decoded with `protobufjs` from the FileDescriptorSet in the log
//! (`tests/js/check_viewers.cjs`; docs/log-format.md). The decoded values are compared with
//! the samples that were written.
//!
//! Needs node and the npm packages that `.ci/run` installs into `.ci/npm`
//! (`METROLOG_NPM_DIR` overrides); without node the test says so and passes, without the
//! packages it does the same outside CI and fails in CI.

mod log_common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use drivers::synthetic::SyntheticRun;
use drivers::{DriverEvent, SampleValues};
use serde_json::Value;

fn npm_dir() -> PathBuf {
    match std::env::var_os("METROLOG_NPM_DIR") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../.ci/npm"),
    }
}

/// The node check's summary of `log`, or None (with the reason printed) when it cannot run.
fn check(log: &Path) -> Option<Value> {
    if Command::new("node").arg("--version").output().is_err() {
        println!("SKIPPED the viewer check: node is not installed (apt-get install nodejs npm)");
        return None;
    }
    let modules = npm_dir().join("node_modules");
    if !modules.join("@mcap/core").exists() {
        let msg = format!(
            "the viewer check needs npm packages in {} (npm install --prefix {} @mcap/core@2 @mcap/support@1 protobufjs@7; .ci/run does)",
            modules.display(),
            npm_dir().display()
        );
        assert!(std::env::var_os("CI").is_none(), "{msg}");
        println!("SKIPPED: {msg}");
        return None;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/js/check_viewers.cjs");
    let out = Command::new("node")
        .arg(&script)
        .arg(log)
        .env("NODE_PATH", &modules)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "check_viewers.cjs failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(serde_json::from_slice(&out.stdout).unwrap())
}

#[test]
fn every_channel_opens_in_the_viewers_and_decodes_to_what_was_written() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun {
        targets_mm: vec![0.0, 10.0, 20.0],
        temperature_hz: 2.0,
        ..SyntheticRun::default()
    };
    let w = log_common::write_run(dir.path(), "demo.mcap", &run);
    let Some(r) = check(&w.path) else { return };
    assert_eq!(r["footer"], true);
    let topics = r["topics"].as_object().unwrap();
    let want = [
        "/interferometer/position",
        "/interferometer/environment",
        "/capball/sample",
        "/psd/sample",
        "/temperature",
        "/cnc/trigger",
        "/pose",
        "/status",
        "/event",
    ];
    for t in want {
        let info = &topics[t];
        assert_eq!(info["problems"], serde_json::json!([]), "{t}: {info}");
        assert!(info["messages"].as_u64().unwrap() > 0, "{t}: no message");
        assert!(!info["first"].is_null(), "{t}: nothing decoded");
    }
    assert_eq!(topics.len(), want.len(), "{:?}", topics.keys());

    // Raw topics: the samples node decoded, per topic, and the first one's values.
    let mut samples: BTreeMap<&str, Vec<&drivers::Sample>> = BTreeMap::new();
    for e in &w.events {
        if let DriverEvent::Sample(s) = e {
            samples
                .entry(metrolog_log::raw::topic_of(s))
                .or_default()
                .push(s);
        }
    }
    for (topic, ss) in &samples {
        let info = &topics[*topic];
        assert_eq!(info["samples"], ss.len() as u64, "{topic}");
        assert_eq!(info["message_encoding"], "protobuf");
        let first = &info["first"];
        let s = ss[0];
        let h = &first["header"];
        // Format 3: differences from the previous sample (the first from 0) as 64-bit
        // integers, which come as strings (longs: String); times relative to `time`
        // {seconds, nanos}.
        assert_eq!(h["seq_delta"][0], s.seq.to_string(), "{topic}");
        assert_eq!(
            h["device_t_us_delta"][0],
            s.device_t_us.to_string(),
            "{topic}"
        );
        assert_eq!(h["time_delta_ns"][0], "0", "{topic}");
        let ft = &h["time"];
        let ns = ft["seconds"].as_str().unwrap().parse::<u64>().unwrap() * 1_000_000_000
            + ft["nanos"].as_u64().unwrap();
        assert_eq!(ns, s.fitted_ns, "{topic}");
        assert_eq!(h["valid"][0], s.valid, "{topic}");
        let count = h["count"].as_u64().unwrap() as usize;
        let f = |k: &str| first[k][0].as_f64().unwrap();
        match &s.values {
            SampleValues::Position { position_um, .. } => {
                assert_eq!(f("position_um"), *position_um)
            }
            SampleValues::Environment { air_c, .. } => assert_eq!(f("air_c"), *air_c),
            SampleValues::Capball { volts, .. } => {
                // The ADC codes: volts = code · 10 / 2^23 (instruments.md §2), computed here.
                for (k, v) in volts.iter().enumerate() {
                    let code = first[format!("code_{}_delta", k + 1)][0].as_i64().unwrap();
                    assert_eq!(code as f64 * 10.0 / 8_388_608.0, *v, "{topic} channel {k}");
                }
                assert!(first["calibration"]["poly"].as_array().unwrap().len() == 9);
                // The batch's mean error, what a viewer plots against log time.
                let valid: Vec<[f64; 3]> = ss[..count]
                    .iter()
                    .filter(|s| s.valid)
                    .map(|s| match &s.values {
                        SampleValues::Capball { e_um, .. } => *e_um,
                        _ => unreachable!(),
                    })
                    .collect();
                for (k, name) in ["mean_ex_um", "mean_ey_um", "mean_ez_um"]
                    .iter()
                    .enumerate()
                {
                    let want = valid.iter().map(|e| e[k]).sum::<f64>() / valid.len() as f64;
                    let got = first[*name].as_f64().unwrap();
                    assert!((got - want).abs() < 1e-9, "{name}: {got} vs {want}");
                }
            }
            SampleValues::Psd { y_um, .. } => assert_eq!(f("y_um"), *y_um),
            SampleValues::Temperature { values_c } => {
                // The first sample's channels lead `values_c`; NaN (an open sensor) comes out of
                // JSON.stringify as null.
                assert_eq!(first["channels"][0], values_c.len() as u64, "{topic}");
                for (k, v) in values_c.iter().enumerate() {
                    let got = &first["values_c"][k];
                    if v.is_nan() {
                        assert!(got.is_null(), "{topic} channel {k}: {got}");
                    } else {
                        assert_eq!(got.as_f64(), Some(*v), "{topic} channel {k}");
                    }
                }
            }
        }
    }
    // JSON topics: the first /pose with its times as {sec, nsec}.
    let p = &topics["/pose"]["first"];
    let p0 = &w.poses[0];
    assert_eq!(p["pose"], p0.pose);
    let t = &p["t_first"];
    assert_eq!(
        t["sec"].as_u64().unwrap() * 1_000_000_000 + t["nsec"].as_u64().unwrap(),
        p0.t_first_ns
    );
}

/// `check_part.cjs` on `part`: the viewers' indexed reader's view of one file.
fn check_part(part: &Path) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/js/check_part.cjs");
    let out = Command::new("node")
        .arg(&script)
        .arg(part)
        .env("NODE_PATH", npm_dir().join("node_modules"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "check_part.cjs failed on {}: {}",
        part.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Each part of a split run opens alone in the viewers: the stream check finds every channel
/// loadable and the footer, the viewers' indexed reader (what Foxglove uses for a local file)
/// reads every message through the part's own index, and finds the run metadata and the
/// trajectory attachment in the part's summary. The parts' samples add up to what was written.
#[test]
fn each_part_of_a_split_run_opens_alone_in_the_viewers() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun {
        li80_hz: 200.0,
        cb3_hz: 100.0,
        psd_hz: 50.0,
        temperature_hz: 2.0,
        ..SyntheticRun::default()
    };
    let opts = metrolog_log::LogOptions {
        fsync: false,
        flush_interval: std::time::Duration::ZERO,
        split_after: Some(std::time::Duration::from_secs(4)),
        ..metrolog_log::LogOptions::default()
    };
    let w = log_common::write_run_with(dir.path(), "metrolog-v.mcap", &run, opts);
    let mut parts: Vec<PathBuf> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    parts.sort();
    assert!(parts.len() >= 3, "{parts:?}");
    let mut samples: BTreeMap<String, u64> = BTreeMap::new();
    for p in &parts {
        let Some(r) = check(p) else { return };
        assert_eq!(r["footer"], true, "{p:?}");
        for (t, info) in r["topics"].as_object().unwrap() {
            assert_eq!(info["problems"], serde_json::json!([]), "{p:?} {t}: {info}");
            *samples.entry(t.clone()).or_default() += info["samples"].as_u64().unwrap_or(0);
        }
        let ix = check_part(p);
        assert!(ix["chunks"].as_u64().unwrap() > 0, "{p:?}: {ix}");
        let by_topic: u64 = ix["topics"]
            .as_object()
            .unwrap()
            .values()
            .map(|n| n.as_u64().unwrap())
            .sum();
        assert_eq!(Some(by_topic), ix["statistics_messages"].as_u64(), "{p:?}");
        let att = ix["attachments"].to_string();
        assert!(att.contains("trajectory.csv"), "{p:?}: {att}");
        assert_eq!(ix["run"][0]["machine"], "test-mill", "{p:?}: {ix}");
        assert!(
            ix["metadata"].to_string().contains("metrolog.part"),
            "{p:?}"
        );
    }
    // Every raw sample is in exactly one part.
    for e in &w.events {
        if let DriverEvent::Sample(s) = e {
            let t = metrolog_log::raw::topic_of(s);
            *samples.get_mut(t).unwrap() -= 1;
        }
    }
    assert!(samples.values().all(|&n| n == 0), "{samples:?}");
}

/// The check itself can fail: a log of format 1 (JSON samples with `null` numbers and `$ref`
/// enums) is rejected on the channels the viewers could not open.
#[test]
fn the_check_rejects_a_format_1_log() {
    let log = Path::new(env!("CARGO_MANIFEST_DIR")).join("../log/tests/data/format1.mcap");
    let Some(r) = check(&log) else { return };
    let problems = |t: &str| r["topics"][t]["problems"].as_array().unwrap().len();
    assert!(
        problems("/psd/sample") > 0,
        "{}",
        r["topics"]["/psd/sample"]
    );
    assert!(problems("/pose") > 0, "{}", r["topics"]["/pose"]);
}
