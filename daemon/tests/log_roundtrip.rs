//! Round trip of every topic through the MCAP writer and reader, and exact replay.

mod log_common;

use std::collections::BTreeMap;

use drivers::synthetic::SyntheticRun;
use drivers::{DriverEvent, Instrument};
use metrolog::cmd::replay::{ReplayOptions, replay};
use metrolog_log::topics::{LogMessage, decode_message};
use metrolog_log::{LogItem, RUN_METADATA, RunMetadata, read_log};
use types::PoseStatus;

#[test]
fn every_topic_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun::default();
    let w = log_common::write_run(dir.path(), "run.mcap", &run);

    let mut samples = Vec::new();
    let mut triggers = Vec::new();
    let mut poses = Vec::new();
    let mut statuses = Vec::new();
    let mut events = Vec::new();
    let mut attachments = BTreeMap::new();
    let mut run_meta = None;
    let mut inst_meta = Vec::new();
    let summary = read_log(&w.path, |item| match item {
        LogItem::Message {
            topic,
            encoding,
            log_ns,
            data,
        } => match decode_message(topic, encoding, log_ns, data)
            .unwrap()
            .unwrap()
        {
            LogMessage::Samples(s) => samples.extend(s),
            LogMessage::Trigger(t) => triggers.push(t.to_trigger(log_ns)),
            LogMessage::Pose(p) => poses.push(p),
            LogMessage::Status(s) => statuses.push((log_ns, s)),
            LogMessage::Event(e) => events.push(e),
        },
        LogItem::Channel { .. } => {}
        LogItem::Attachment {
            name,
            data,
            media_type,
            ..
        } => {
            attachments.insert(name.to_string(), (media_type.to_string(), data.to_vec()));
        }
        LogItem::Metadata { name, map } => {
            if name == RUN_METADATA {
                run_meta = Some(RunMetadata::from_map(map).unwrap());
            } else {
                inst_meta.push(map.clone());
            }
        }
    })
    .unwrap();
    assert!(summary.clean_close, "{summary:?}");
    assert_eq!(summary.error, None);

    // Raw samples and triggers: every field back, in the order written.
    let want_samples: Vec<_> = w
        .events
        .iter()
        .filter_map(|e| {
            if let DriverEvent::Sample(s) = e {
                Some(s.clone())
            } else {
                None
            }
        })
        .collect();
    let want_triggers: Vec<_> = w
        .events
        .iter()
        .filter_map(|e| {
            if let DriverEvent::Trigger(t) = e {
                Some(t.clone())
            } else {
                None
            }
        })
        .collect();
    assert_eq!(samples.len(), want_samples.len());
    // Per topic in the order written (format 2 batches each topic: across topics the file
    // order is by batch; docs/log-format.md).
    let by_topic = |v: &[drivers::Sample]| {
        let mut m: BTreeMap<&str, Vec<drivers::Sample>> = BTreeMap::new();
        for s in v {
            m.entry(metrolog_log::raw::topic_of(s))
                .or_default()
                .push(s.clone());
        }
        m
    };
    assert!(
        by_topic(&samples) == by_topic(&want_samples),
        "samples differ"
    );
    assert_eq!(triggers, want_triggers);
    // Expected counts from the run's shape: 17.5 s at 1 kHz / 1 kHz / 100 Hz / 1 Hz.
    let count = |i: Instrument, env: bool| {
        samples
            .iter()
            .filter(|s| {
                s.instrument == i
                    && matches!(s.values, drivers::SampleValues::Environment { .. }) == env
            })
            .count()
    };
    let d = run.duration_s();
    assert_eq!(
        count(Instrument::Interferometer, false),
        (d * 1000.0).ceil() as usize
    );
    assert_eq!(
        count(Instrument::Capball, false),
        (d * 1000.0).ceil() as usize
    );
    assert_eq!(count(Instrument::Psd, false), (d * 100.0).ceil() as usize);
    assert_eq!(count(Instrument::Interferometer, true), d.ceil() as usize);
    // 5 poses × (motion start, exact stop, dwell end) + program start and end.
    assert_eq!(triggers.len(), 17);

    // Poses: what the recorder returned, and close to the synthetic truth.
    assert_eq!(poses, w.poses);
    assert_eq!(poses.len(), 15);
    for p in &poses {
        assert_eq!(p.status, PoseStatus::Ok, "{p:?}");
        assert_eq!(p.n, 150);
        let k = p.pose as usize - 1;
        let tol = 4.0 * run.noise_um / 150f64.sqrt();
        let want: Vec<(&str, f64)> = match p.instrument {
            Instrument::Interferometer => vec![("position_um", run.targets_mm[k] * 1000.0)],
            Instrument::Capball => {
                let e = SyntheticRun::capball_error_um(k);
                vec![("ex_um", e[0]), ("ey_um", e[1]), ("ez_um", e[2])]
            }
            Instrument::Psd => {
                let e = SyntheticRun::psd_error_um(k);
                vec![("x_um", e[0]), ("y_um", e[1])]
            }
            Instrument::Trigger | Instrument::Thermometer => {
                panic!("a pose value of {:?}", p.instrument)
            }
        };
        assert_eq!(p.mean.len(), want.len());
        for (name, v) in want {
            assert!((p.mean[name] - v).abs() < tol, "{p:?}: {name} expected {v}");
        }
    }

    // Status: once a second, and the last one holds the last counters.
    assert!(
        statuses.len() as f64 >= d - 1.0,
        "{} status records",
        statuses.len()
    );
    for w2 in statuses.windows(2) {
        assert!(w2[1].0 >= w2[0].0);
    }
    let last = &statuses.last().unwrap().1;
    let last_counters = w
        .events
        .iter()
        .rev()
        .find_map(|e| match e {
            DriverEvent::Counters {
                instrument: Instrument::Capball,
                counters,
            } => Some(counters),
            _ => None,
        })
        .unwrap();
    let c = &last.instruments["capball"];
    assert_eq!(c.samples, last_counters.samples);
    assert_eq!(
        c.rejections["bad_checksum"],
        last_counters.rejections[&protocol::RejectKind::BadChecksum]
    );
    assert_eq!(c.clock_drift_ppm, Some(1.5));
    assert_eq!(last.poses["ok"], 15);

    // Events, metadata and attachments.
    assert_eq!(events.len(), 4);
    assert_eq!(inst_meta.len(), 4);
    assert_eq!(run_meta.unwrap().machine, "test-mill");
    let rm = RunMetadata::from_map(&w.meta.to_map()).unwrap();
    assert_eq!(rm.detector, w.meta.detector);
    assert_eq!(rm.instruments, w.meta.instruments);
    assert_eq!(
        attachments["config.toml"].1,
        log_common::CONFIG_TOML.as_bytes()
    );
    assert_eq!(attachments["trajectory.csv"].0, "text/csv");
    assert_eq!(
        attachments["trajectory.csv"].1,
        log_common::TRAJECTORY_CSV.as_bytes()
    );
}

#[test]
fn replay_reproduces_logged_poses_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun {
        seed: 7,
        ..SyntheticRun::default()
    };
    let w = log_common::write_run(dir.path(), "run.mcap", &run);
    let out = replay(&w.path, &ReplayOptions::default()).unwrap();
    assert!(out.same_settings);
    assert_eq!(out.logged.len(), 15);
    assert!(
        out.reproduces_log(),
        "{} of {} identical",
        out.identical,
        out.logged.len()
    );
    for ((_, a), (_, b)) in out.logged.iter().zip(&out.replayed) {
        for (k, v) in &a.mean {
            assert_eq!(v.to_bits(), b.mean[k].to_bits());
        }
    }

    // -o: a new log with the raw topics and new poses; it replays exactly too.
    let o = dir.path().join("replayed.mcap");
    let out2 = replay(
        &w.path,
        &ReplayOptions {
            output: Some(o.clone()),
            detector_samples: None,
            trigger_time: None,
        },
    )
    .unwrap();
    assert!(out2.reproduces_log());
    let again = replay(&o, &ReplayOptions::default()).unwrap();
    assert!(again.read.clean_close);
    assert!(again.reproduces_log());
    let logged: Vec<_> = again.logged.iter().map(|x| &x.1).collect();
    let orig: Vec<_> = out.logged.iter().map(|x| &x.1).collect();
    assert_eq!(logged, orig);
    // Refuses to overwrite.
    assert!(
        replay(
            &w.path,
            &ReplayOptions {
                output: Some(o),
                detector_samples: None,
                trigger_time: None,
            }
        )
        .is_err()
    );

    // Other settings: other windows, still the right plateau.
    let out3 = replay(
        &w.path,
        &ReplayOptions {
            output: None,
            detector_samples: Some(100),
            trigger_time: None,
        },
    )
    .unwrap();
    assert!(!out3.same_settings);
    assert_eq!(out3.replayed.len(), 15);
    assert!(
        out3.replayed
            .iter()
            .all(|(_, p)| p.n == 100 && p.status == PoseStatus::Ok)
    );
    assert!(!out3.reproduces_log());
}

#[test]
fn trigger_free_run_finds_the_plateaus() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun {
        triggers: false,
        ..SyntheticRun::default()
    };
    let w = log_common::write_run(dir.path(), "free.mcap", &run);
    // With trigger-driven settings nothing is measured (no triggers came).
    assert!(w.poses.is_empty(), "{:?}", w.poses);
    // Replay in plateau mode through the library: the interferometer finds the 5 stops.
    let mut settings = metrolog_log::DetectorSettings::default();
    settings.interferometer.mode = types::DetectorMode::Plateaus;
    let mut engine = detect::PoseEngine::new(&settings).unwrap();
    let mut found = Vec::new();
    for e in &w.events {
        if let DriverEvent::Sample(s) = e {
            found.extend(engine.on_sample(s));
        }
    }
    let interf: Vec<_> = found
        .iter()
        .filter(|p| p.instrument == Instrument::Interferometer)
        .collect();
    assert_eq!(interf.len(), 5, "{interf:?}");
    for (k, p) in interf.iter().enumerate() {
        assert_eq!(p.pose as usize, k + 1);
        assert!((p.mean["position_um"] - run.targets_mm[k] * 1000.0).abs() < 0.01);
    }
}

#[test]
fn info_and_replay_commands() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun {
        targets_mm: vec![0.0, 10.0],
        temperature_hz: 2.0,
        ..SyntheticRun::default()
    };
    let w = log_common::write_run(dir.path(), "run.mcap", &run);
    let bin = env!("CARGO_BIN_EXE_metrolog");
    let out = std::process::Command::new(bin)
        .arg("info")
        .arg(&w.path)
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("closed     cleanly"), "{text}");
    assert!(text.contains("/interferometer/position"), "{text}");
    assert!(text.contains("interferometer   ok 2"), "{text}");
    assert!(text.contains("config.toml"), "{text}");

    let out = std::process::Command::new(bin)
        .args(["info", "--json"])
        .arg(&w.path)
        .output()
        .unwrap();
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["read"]["clean_close"], true);
    assert_eq!(j["poses"]["capball"]["ok"], 2);
    assert_eq!(
        j["last_status"]["instruments"]["psd"]["clock_drift_ppm"],
        1.5
    );
    let rate = j["topics"]["/interferometer/position"]["rate_hz"]
        .as_f64()
        .unwrap();
    assert!((rate - 1000.0).abs() < 1.0, "{rate}");
    // The temperature module's samples: every one written, at 2 Hz.
    let temps: Vec<&Vec<f64>> = w
        .events
        .iter()
        .filter_map(|e| match e {
            DriverEvent::Sample(s) => match &s.values {
                drivers::SampleValues::Temperature { values_c } => Some(values_c),
                _ => None,
            },
            _ => None,
        })
        .collect();
    assert!(temps.len() >= 10, "{}", temps.len());
    assert_eq!(j["topics"]["/temperature"]["samples"], temps.len() as u64);
    let rate = j["topics"]["/temperature"]["rate_hz"].as_f64().unwrap();
    assert!((rate - 2.0).abs() < 0.01, "{rate}");

    let out = std::process::Command::new(bin)
        .arg("replay")
        .arg(&w.path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("all 6 logged pose values reproduced exactly"),
        "{text}"
    );
    // The temperatures' range per channel, computed here from what was written (the log of
    // the test has no sensor names: channels are numbered).
    let range = |k: usize| {
        let v: Vec<f64> = temps.iter().map(|t| t[k]).collect();
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        format!("ch{k} {lo:.2}..{hi:.2} °C")
    };
    let want = format!(
        "temperatures: {} samples; {}, {}, ch2: no reading",
        temps.len(),
        range(0),
        range(1)
    );
    assert!(text.contains(&want), "{want} not in {text}");
    // `replay -o` copies the temperatures into the new log.
    let copy = dir.path().join("copy.mcap");
    let out = std::process::Command::new(bin)
        .arg("replay")
        .arg(&w.path)
        .arg("-o")
        .arg(&copy)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = std::process::Command::new(bin)
        .args(["info", "--json"])
        .arg(&copy)
        .output()
        .unwrap();
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["topics"]["/temperature"]["samples"], temps.len() as u64);

    let out = std::process::Command::new(bin)
        .arg("info")
        .arg(dir.path().join("nope.mcap"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("nope.mcap") && err.contains("No such file"),
        "{err}"
    );
}

#[test]
fn dark_psd_samples_round_trip_as_nan_and_replay_exactly() {
    let dir = tempfile::tempdir().unwrap();
    // Every 40th PSD sample is dark: the 150-sample windows must avoid them, so with
    // 100 Hz the PSD never has 150 consecutive valid samples: beam_invalid, in replay too.
    let run = SyntheticRun {
        targets_mm: vec![0.0, 10.0],
        psd_dark_every: 40,
        ..SyntheticRun::default()
    };
    let w = log_common::write_run(dir.path(), "dark.mcap", &run);
    let mut dark = 0;
    read_log(&w.path, |item| {
        if let LogItem::Message {
            topic: "/psd/sample",
            encoding,
            data,
            log_ns,
        } = item
            && let Some(LogMessage::Samples(ss)) =
                decode_message("/psd/sample", encoding, log_ns, data).unwrap()
        {
            for s in ss {
                if let drivers::SampleValues::Psd { x_um, y_um, .. } = s.values
                    && !s.valid
                {
                    assert!(x_um.is_nan() && y_um.is_nan(), "{s:?}");
                    dark += 1;
                }
            }
        }
    })
    .unwrap();
    assert!(dark > 10);
    let psd: Vec<_> = w
        .poses
        .iter()
        .filter(|p| p.instrument == Instrument::Psd)
        .collect();
    assert_eq!(psd.len(), 2);
    assert!(
        psd.iter().all(|p| p.status == PoseStatus::BeamInvalid),
        "{psd:?}"
    );
    let out = replay(&w.path, &ReplayOptions::default()).unwrap();
    assert!(out.reproduces_log());
}

#[test]
fn only_the_instruments_of_the_run_get_pose_values() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun {
        targets_mm: vec![0.0, 10.0],
        ..SyntheticRun::default()
    };
    let mut meta = log_common::meta(&run);
    meta.detector.instruments = vec![Instrument::Interferometer];
    let path = dir.path().join("li80.mcap");
    let mut rec = metrolog::acquire::recorder::Recorder::create(
        &path,
        &meta,
        metrolog_log::LogOptions::default(),
    )
    .unwrap();
    let mut poses = Vec::new();
    for ev in run.events() {
        // Only the interferometer and the triggers are part of this run.
        match &ev {
            DriverEvent::Sample(s) if s.instrument != Instrument::Interferometer => continue,
            _ => {}
        }
        poses.extend(rec.record(&ev, run.start_ns).unwrap());
    }
    poses.extend(rec.finish(run.start_ns + 20_000_000_000).unwrap().1);
    assert_eq!(poses.len(), 2, "{poses:?}");
    assert!(
        poses
            .iter()
            .all(|p| p.instrument == Instrument::Interferometer && p.status == PoseStatus::Ok)
    );
    let out = replay(&path, &ReplayOptions::default()).unwrap();
    assert!(out.reproduces_log());
    assert_eq!(out.detector.instruments, vec![Instrument::Interferometer]);
}
