//! Golden logs of each format (`tests/data/`, see its README) decode with `decode_message`,
//! and damaged ones give their intact prefix and recover into a valid file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use metrolog_log::topics::{LogMessage, PoseMsg, decode_message};
use metrolog_log::{LOG_FORMAT_KEY, LogItem, ReadSummary, read_log, read_run_metadata};
use types::Sample;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

#[derive(Default)]
struct Contents {
    samples: Vec<Sample>,
    poses: Vec<PoseMsg>,
    /// (topic, encoding) → messages.
    channels: BTreeMap<(String, String), u64>,
    summary: ReadSummary,
}

fn read(path: &Path) -> Contents {
    let mut c = Contents::default();
    c.summary = read_log(path, |item| {
        if let LogItem::Message {
            topic,
            encoding,
            log_ns,
            data,
        } = item
        {
            *c.channels
                .entry((topic.to_string(), encoding.to_string()))
                .or_default() += 1;
            match decode_message(topic, encoding, log_ns, data).unwrap() {
                Some(LogMessage::Samples(s)) => c.samples.extend(s),
                Some(LogMessage::Pose(p)) => c.poses.push(p),
                Some(_) => {}
                None => panic!("unknown topic {topic}"),
            }
        }
    })
    .unwrap();
    c
}

#[test]
fn both_formats_hold_the_same_run() {
    let f1 = read(&data("format1.mcap"));
    let f2 = read(&data("format2.mcap"));
    assert!(f1.summary.clean_close && f2.summary.clean_close);
    // Format 1: one JSON message per sample; format 2: protobuf batches.
    assert_eq!(
        f1.channels[&("/capball/sample".into(), "json".into())],
        1829
    );
    let batches = f2.channels[&("/capball/sample".into(), "protobuf".into())];
    assert!(batches < 1829 / 5, "{batches} capball batches");
    assert_eq!(f1.samples.len(), f2.samples.len());
    // Per topic, sample for sample, bit for bit (the debug text shows NaN and -0.0 exactly);
    // across topics format 2 groups samples into batches.
    assert!(
        by_topic(&f1.samples) == by_topic(&f2.samples),
        "samples differ"
    );
    assert_eq!(f1.poses.len(), 6);
    assert_eq!(f1.poses, f2.poses);
    let m1 = read_run_metadata(&data("format1.mcap")).unwrap().unwrap();
    let m2 = read_run_metadata(&data("format2.mcap")).unwrap().unwrap();
    assert_eq!(m1.get(LOG_FORMAT_KEY), None);
    assert_eq!(m2.get(LOG_FORMAT_KEY).map(String::as_str), Some("2"));
}

/// (topic, log time, data) of every message.
fn messages(path: &Path) -> (Vec<(String, u64, Vec<u8>)>, ReadSummary) {
    let mut v = Vec::new();
    let s = read_log(path, |item| {
        if let LogItem::Message {
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

#[test]
fn damaged_logs_give_their_prefix_and_recover_into_valid_files() {
    let (all, _) = messages(&data("format2.mcap"));
    let dir = tempfile::tempdir().unwrap();
    for (name, why) in [
        ("truncated.mcap", ["ends inside a record"].as_slice()),
        // Zeroed bytes inside a compressed chunk: a bad CRC or a garbled record inside it.
        ("torn-chunk.mcap", ["crc", "record"].as_slice()),
    ] {
        let (got, s) = messages(&data(name));
        assert!(!s.clean_close, "{name}");
        let err = s.error.clone().unwrap();
        assert!(
            why.iter().any(|w| err.to_lowercase().contains(w)),
            "{name}: {err}"
        );
        assert!(!got.is_empty() && got.len() < all.len(), "{name}");
        assert_eq!(got[..], all[..got.len()], "{name}: not a prefix");

        let out = dir.path().join(name);
        let r = metrolog_log::recover::recover(&data(name), &out, |_, _| {}).unwrap();
        assert_eq!(r.messages as usize, got.len());
        let (again, s2) = messages(&out);
        assert!(s2.clean_close && s2.error.is_none(), "{name}: {s2:?}");
        assert_eq!(again, got, "{name}: recovered messages");
        // An existing output is never overwritten.
        assert!(metrolog_log::recover::recover(&data(name), &out, |_, _| {}).is_err());
    }
}

/// The CapBall calibration of the run in `format1.mcap`: `poly` as in its config attachment
/// (`[capball] poly = [[10.0, 0.02, -0.001], [10.0, -0.015, 0.0], [10.0, 0.01, 0.0005]]`),
/// the transform from its `capball-transform.csv` attachment.
fn format1_calibration() -> protocol::convert::CapBallCalibration {
    use protocol::convert::{CapBallCalibration, CapBallPoly, CapBallTransform};
    let mut csv = String::new();
    read_log(&data("format1.mcap"), |item| {
        if let LogItem::Attachment { name, data, .. } = item
            && name == "capball-transform.csv"
        {
            csv = String::from_utf8(data.to_vec()).unwrap();
        }
    })
    .unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split(',').map(|x| x.trim().parse().unwrap()).collect())
        .collect();
    CapBallCalibration {
        poly: [
            [10.0, 0.02, -0.001],
            [10.0, -0.015, 0.0],
            [10.0, 0.01, 0.0005],
        ]
        .map(|c| CapBallPoly { c }),
        transform: CapBallTransform {
            t: std::array::from_fn(|r| std::array::from_fn(|k| rows[r][k])),
        },
    }
}

#[test]
fn format_3_holds_the_same_run_with_capball_codes() {
    let f1 = read(&data("format1.mcap"));
    let f3 = read(&data("format3.mcap"));
    assert!(f3.summary.clean_close);
    assert_eq!(f1.samples.len(), f3.samples.len());
    assert!(
        by_topic(&f1.samples) == by_topic(&f3.samples),
        "samples differ"
    );
    assert_eq!(f1.poses, f3.poses);
    let m3 = read_run_metadata(&data("format3.mcap")).unwrap().unwrap();
    assert_eq!(m3.get(LOG_FORMAT_KEY).map(String::as_str), Some("3"));
    let meta = metrolog_log::RunMetadata::from_map(&m3).unwrap();
    assert_eq!(meta.capball, Some(format1_calibration()));
    // Every CapBall batch holds ADC codes and the calibration, none the nine doubles.
    let mut capball = 0;
    read_log(&data("format3.mcap"), |item| {
        if let LogItem::Message { topic, data, .. } = item
            && topic == "/capball/sample"
        {
            let b = metrolog_log::raw::Batch::decode(topic, data)
                .unwrap()
                .unwrap();
            let metrolog_log::raw::Batch::Format3(metrolog_log::raw::v3::Batch::Capball(b)) = b
            else {
                panic!("not a format-3 CapBall batch")
            };
            assert!(b.calibration.is_some() && b.volts_1.is_empty());
            capball += 1;
        }
    })
    .unwrap();
    assert_eq!(capball, 57);
    // Pinned: the size of the fixture (format 2 of the same run is larger).
    let size = |n: &str| std::fs::metadata(data(n)).unwrap().len();
    assert!(size("format3.mcap") < size("format2.mcap"));
}

/// Regenerates `format3.mcap` from `format1.mcap` with this version's writer (what
/// `metrolog replay format1.mcap -o format3.mcap` writes, without re-running the detectors:
/// the logged pose values are copied), with the run's CapBall calibration from its attachments.
/// `format2.mcap` and the damaged logs made from it were written the same way by the writer of
/// format 2 and are kept as they are.
/// Run: `cargo test -p metrolog-log --test formats -- --ignored regenerate`.
#[test]
#[ignore = "rewrites the fixtures"]
fn regenerate_fixtures() {
    use metrolog_log::{LogOptions, LogWriter, RUN_METADATA, RunMetadata};
    let src = data("format1.mcap");
    let dst = data("format3.mcap");
    let _ = std::fs::remove_file(&dst);
    let mut meta = RunMetadata::from_map(&read_run_metadata(&src).unwrap().unwrap()).unwrap();
    meta.capball = Some(format1_calibration());
    meta.extra.insert(
        "fixture".into(),
        "format-3 golden log: format1.mcap rewritten by the format-3 writer".into(),
    );
    let opts = LogOptions {
        chunk_size: 64 << 10,
        ..LogOptions::default()
    };
    let mut w = LogWriter::create(&dst, &meta, opts).unwrap();
    read_log(&src, |item| match item {
        LogItem::Message {
            topic,
            encoding,
            log_ns,
            data,
        } => match decode_message(topic, encoding, log_ns, data).unwrap() {
            Some(LogMessage::Samples(s)) => s.iter().for_each(|s| w.write_sample(s).unwrap()),
            Some(LogMessage::Pose(p)) => w.write_pose(log_ns, &p).unwrap(),
            Some(LogMessage::Trigger(t)) => w.write_trigger(&t.to_trigger(log_ns)).unwrap(),
            Some(LogMessage::Status(s)) => w.write_status(log_ns, &s).unwrap(),
            Some(LogMessage::Event(e)) => w.write(log_ns, &e).unwrap(),
            None => panic!("{topic}"),
        },
        LogItem::Attachment {
            name,
            media_type,
            log_ns,
            data,
        } => w.attach(name, media_type, data, log_ns).unwrap(),
        LogItem::Metadata { name, map } if name != RUN_METADATA => {
            w.write_metadata(name, map.clone()).unwrap()
        }
        _ => {}
    })
    .unwrap();
    assert_eq!(
        w.capball_batches()[1],
        0,
        "CapBall batches written as doubles"
    );
    w.finish().unwrap();
}

/// Samples per topic as their debug text (which shows NaN and -0.0 exactly), in order.
fn by_topic(v: &[Sample]) -> BTreeMap<&'static str, Vec<String>> {
    let mut m: BTreeMap<&'static str, Vec<String>> = BTreeMap::new();
    for s in v {
        m.entry(metrolog_log::raw::topic_of(s))
            .or_default()
            .push(format!("{s:?}"));
    }
    m
}
