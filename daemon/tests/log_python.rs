//! An independent reader: the Python `mcap` package reads a log, `jsonschema` validates every
//! JSON message against its topic's schema, and Google's `protobuf` package decodes the raw
//! batches with the FileDescriptorSet stored as their schema (pip packages; CI installs them).

mod log_common;

use std::collections::BTreeMap;
use std::process::Command;

use drivers::synthetic::SyntheticRun;

const SCRIPT: &str = r#"
import json, sys
from mcap.reader import make_reader
from jsonschema import validators
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

counts = {}
batches = {}
errors = []
temperatures = []
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f, validate_crcs=True)
    summary = reader.get_summary()
    validators_by_schema = {}
    classes = {}
    for schema, channel, message in reader.iter_messages():
        if schema.encoding == "protobuf":
            assert channel.message_encoding == "protobuf", channel.message_encoding
            cls = classes.get(schema.id)
            if cls is None:
                pool = descriptor_pool.DescriptorPool()
                fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                for fd in fds.file:
                    pool.Add(fd)
                desc = pool.FindMessageTypeByName(schema.name)
                cls = classes[schema.id] = message_factory.GetMessageClass(desc)
            batch = cls.FromString(message.data)
            # Format 3: the header says how many samples; every repeated column has one entry
            # per sample (a CapBall batch holds either the code columns or the nine doubles).
            n = batch.header.count
            # (repeated fields are the containers with a length)
            columns = [(f.name, getattr(m, f.name)) for m in (batch, batch.header)
                       for f in m.DESCRIPTOR.fields
                       if hasattr(getattr(m, f.name), "__len__") and f.name not in ("material_c", "values_c")]
            for name, col in columns:
                empty_ok = channel.topic == "/capball/sample" and len(col) == 0
                if len(col) != n and not empty_ok:
                    errors.append(f"{channel.topic}: column {name} is not {n} long")
            if channel.topic == "/capball/sample" and len(batch.code_1_delta) != n and len(batch.ex_um) != n:
                errors.append(f"{channel.topic}: neither codes nor values")
            if channel.topic == "/temperature":
                if sum(batch.channels) != len(batch.values_c):
                    errors.append(f"{channel.topic}: channels do not add up to values_c")
                temperatures.extend(None if v != v else v for v in batch.values_c)
            counts[channel.topic] = counts.get(channel.topic, 0) + n
            batches[channel.topic] = batches.get(channel.topic, 0) + 1
            continue
        assert schema.encoding == "jsonschema", schema.encoding
        assert channel.message_encoding == "json", channel.message_encoding
        batches[channel.topic] = batches.get(channel.topic, 0) + 1
        v = validators_by_schema.get(schema.id)
        if v is None:
            doc = json.loads(schema.data)
            cls = validators.validator_for(doc)
            cls.check_schema(doc)
            v = validators_by_schema[schema.id] = cls(doc)
        msg = json.loads(message.data)
        for e in v.iter_errors(msg):
            errors.append(f"{channel.topic} @ {message.log_time}: {e.message}")
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    attachments = {a.name: len(a.data) for a in reader.iter_attachments()}
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
print(json.dumps({
    "counts": counts,
    "errors": errors[:20],
    "n_errors": len(errors),
    "batches": batches,
    "temperatures": temperatures,
    "attachments": attachments,
    "run": metadata.get("metrolog.run", {}),
    "summary_counts": {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()},
}))
"#;

#[test]
fn python_reads_the_log_and_every_message_matches_its_schema() {
    let dir = tempfile::tempdir().unwrap();
    let run = SyntheticRun {
        targets_mm: vec![0.0, 10.0, 20.0],
        temperature_hz: 2.0,
        ..SyntheticRun::default()
    };
    let w = log_common::write_run(dir.path(), "run.mcap", &run);
    let script = dir.path().join("check.py");
    std::fs::write(&script, SCRIPT).unwrap();
    let out = Command::new("python3")
        .arg(&script)
        .arg(&w.path)
        .output()
        .expect("python3 is needed for this test (with pip packages mcap and jsonschema)");
    assert!(
        out.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(r["n_errors"], 0, "schema violations: {}", r["errors"]);

    // Counts by topic, from the events written (independently of the Rust reader).
    let mut want: BTreeMap<&str, u64> = BTreeMap::new();
    for e in &w.events {
        let topic = match e {
            drivers::DriverEvent::Sample(s) => match s.values {
                drivers::SampleValues::Position { .. } => "/interferometer/position",
                drivers::SampleValues::Environment { .. } => "/interferometer/environment",
                drivers::SampleValues::Capball { .. } => "/capball/sample",
                drivers::SampleValues::Psd { .. } => "/psd/sample",
                drivers::SampleValues::Temperature { .. } => "/temperature",
            },
            drivers::DriverEvent::Trigger(_) => "/cnc/trigger",
            drivers::DriverEvent::Connected { .. } => "/event",
            _ => continue,
        };
        *want.entry(topic).or_default() += 1;
    }
    want.insert("/pose", w.poses.len() as u64);
    for (topic, n) in &want {
        assert_eq!(r["counts"][topic], *n, "{topic}");
        assert_eq!(
            r["summary_counts"][topic], r["batches"][topic],
            "{topic} in the summary statistics"
        );
    }
    assert!(r["counts"]["/status"].as_u64().unwrap() >= 9);
    // The temperatures protobuf decoded, channel after channel (NaN: an open sensor, null).
    let temps: Vec<f64> = w
        .events
        .iter()
        .filter_map(|e| match e {
            drivers::DriverEvent::Sample(s) => match &s.values {
                drivers::SampleValues::Temperature { values_c } => Some(values_c.clone()),
                _ => None,
            },
            _ => None,
        })
        .flatten()
        .collect();
    let got = r["temperatures"].as_array().unwrap();
    assert!(want["/temperature"] >= 10, "{want:?}");
    assert_eq!(got.len(), temps.len());
    for (g, t) in got.iter().zip(&temps) {
        match g.as_f64() {
            Some(g) => assert_eq!(g, *t),
            None => assert!(t.is_nan() && g.is_null(), "{g} vs {t}"),
        }
    }
    assert_eq!(w.poses.len(), 9);
    assert_eq!(
        r["attachments"]["config.toml"],
        log_common::CONFIG_TOML.len()
    );
    assert_eq!(r["run"]["machine"], "test-mill");
}
