//! Replays the cargo-fuzz corpora of the log's parsers (`protocol/fuzz/corpus/trajectory/`,
//! `protocol/fuzz/corpus/mcap_reader/`) and any crash kept there through the same checks as
//! the fuzz targets (`metrolog_log::fuzzcheck`), so CI re-runs them on stable. Files named
//! `valid_*` must parse (trajectory) or read to the end (MCAP).
//!
//! The committed MCAP seeds were written by the Python `mcap` package (an independent writer:
//! a small file, cut at 10/50/90/99.9 % and bit-flipped); `cargo test -p metrolog-log --test
//! fuzz_corpus -- --ignored write_mcap_seeds` adds the same from our writer.

use std::path::PathBuf;

use drivers::synthetic::SyntheticRun;
use metrolog_log::{LogOptions, LogWriter, RunMetadata, fuzzcheck};

fn corpus(target: &str) -> Vec<(String, PathBuf)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../protocol/fuzz/corpus")
        .join(target);
    let mut files: Vec<(String, PathBuf)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            let p = e.unwrap().path();
            (p.file_name().unwrap().to_string_lossy().into_owned(), p)
        })
        .collect();
    files.sort();
    files
}

#[test]
fn replay_trajectory_corpus() {
    let files = corpus("trajectory");
    assert!(files.len() >= 4, "{files:?}");
    for (name, path) in files {
        let data = std::fs::read(&path).unwrap();
        fuzzcheck::trajectory(&data);
        if name.starts_with("valid_") {
            let text = String::from_utf8(data).unwrap();
            metrolog_log::trajectory::parse_trajectory(&text)
                .unwrap_or_else(|e| panic!("{name}: {e}"));
        }
    }
}

#[test]
fn replay_mcap_reader_corpus() {
    let files = corpus("mcap_reader");
    assert!(files.len() >= 4, "{files:?}");
    for (name, path) in files {
        fuzzcheck::mcap_file(&path);
        if name.starts_with("valid_") {
            let s = metrolog_log::read_log(&path, |_| {}).unwrap();
            assert!(
                s.clean_close && s.error.is_none() && s.messages > 0,
                "{name}: {s:?}"
            );
        }
    }
}

/// Small logs written by the real writer (a synthetic run of two poses, small chunks so a
/// file has several), whole and cut at a few places: the seeds of the `mcap_reader` target.
#[test]
#[ignore = "writes the seed corpus into protocol/fuzz/corpus/mcap_reader"]
fn write_mcap_seeds() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../protocol/fuzz/corpus/mcap_reader");
    std::fs::create_dir_all(&dir).unwrap();
    let run = SyntheticRun::small();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("seed.mcap");
    let meta = RunMetadata {
        machine: "fuzz-seed".into(),
        started_ns: run.start_ns,
        ..RunMetadata::default()
    };
    let mut w = LogWriter::create(
        &path,
        &meta,
        LogOptions {
            chunk_size: 2048,
            fsync: false,
            ..LogOptions::default()
        },
    )
    .unwrap();
    w.attach(
        "trajectory.csv",
        "text/csv",
        b"pose,x_mm,y_mm,z_mm\n1,0,0,0\n2,25,0,0\n",
        run.start_ns,
    )
    .unwrap();
    for ev in run.events() {
        if let drivers::DriverEvent::Sample(s) = &ev {
            w.write_sample(s).unwrap();
        }
        if let drivers::DriverEvent::Trigger(t) = &ev {
            w.write_trigger(t).unwrap();
        }
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(dir.join("valid_small_run"), &bytes).unwrap();
    for (i, frac) in [0.1, 0.5, 0.9, 0.999].iter().enumerate() {
        let n = (bytes.len() as f64 * frac) as usize;
        std::fs::write(dir.join(format!("cut_{i}")), &bytes[..n]).unwrap();
    }
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x40;
    std::fs::write(dir.join("bit_flipped"), &flipped).unwrap();
}
