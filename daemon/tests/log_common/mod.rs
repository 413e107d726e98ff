//! Shared by the log tests: write a synthetic run through the recorder.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use drivers::DriverEvent;
use drivers::synthetic::SyntheticRun;
use metrolog::acquire::recorder::Recorder;
use metrolog_log::topics::PoseMsg;
use metrolog_log::{DetectorSettings, LogOptions, LogWriter, RunMetadata};

pub const CONFIG_TOML: &str = "machine = \"test-mill\"\n[log]\ndir = \"/var/lib/metrolog\"\n";
pub const TRAJECTORY_CSV: &str =
    "pose,x_mm,y_mm,z_mm\n1,0,0,0\n2,50,0,0\n3,100,0,0\n4,150,0,0\n5,200,0,0\n";

pub struct Written {
    pub path: PathBuf,
    pub events: Vec<DriverEvent>,
    pub poses: Vec<PoseMsg>,
    pub meta: RunMetadata,
}

pub fn meta(run: &SyntheticRun) -> RunMetadata {
    let mut m = RunMetadata {
        machine: "test-mill".into(),
        started_ns: run.start_ns,
        detector: DetectorSettings::default(),
        capball: Some(SyntheticRun::capball_calibration()),
        ..RunMetadata::default()
    };
    m.instruments
        .insert("interferometer".into(), "LI-80,SN1234,FW2.1".into());
    m.extra.insert("operator".into(), "tester".into());
    m
}

/// Writes `run` to `dir/name` through a [`Recorder`], closing it cleanly.
pub fn write_run(dir: &Path, name: &str, run: &SyntheticRun) -> Written {
    write_run_with(dir, name, run, LogOptions::default())
}

pub fn write_run_with(dir: &Path, name: &str, run: &SyntheticRun, opts: LogOptions) -> Written {
    let path = dir.join(name);
    let meta = meta(run);
    let mut w = LogWriter::create(&path, &meta, opts).unwrap();
    w.attach(
        "config.toml",
        "application/toml",
        CONFIG_TOML.as_bytes(),
        run.start_ns,
    )
    .unwrap();
    w.attach(
        "trajectory.csv",
        "text/csv",
        TRAJECTORY_CSV.as_bytes(),
        run.start_ns,
    )
    .unwrap();
    let mut rec = Recorder::new(w, &meta.detector).unwrap();
    let events: Vec<DriverEvent> = run.events().collect();
    let mut poses = Vec::new();
    let mut now = run.start_ns;
    for ev in &events {
        now = match ev {
            DriverEvent::Sample(s) => now.max(s.host_ns),
            DriverEvent::Trigger(t) => now.max(t.host_ns),
            _ => now,
        };
        poses.extend(rec.record(ev, now).unwrap());
    }
    let end = now + 1_000_000;
    poses.extend(rec.finish(end).unwrap().1);
    // To look at a test's log: METROLOG_TEST_KEEP=/some/dir.
    if let Ok(keep) = std::env::var("METROLOG_TEST_KEEP") {
        std::fs::copy(&path, Path::new(&keep).join(name)).unwrap();
    }
    Written {
        path,
        events,
        poses,
        meta,
    }
}

/// (topic, log time, data) of every message, in file order, and what the reader saw.
pub fn messages(path: &Path) -> (Vec<(String, u64, Vec<u8>)>, metrolog_log::ReadSummary) {
    let mut v = Vec::new();
    let s = metrolog_log::read_log(path, |item| {
        if let metrolog_log::LogItem::Message {
            topic,
            log_ns,
            data,
            ..
        } = item
        {
            v.push((topic.to_string(), log_ns, data.to_vec()));
        }
    })
    .unwrap();
    (v, s)
}
