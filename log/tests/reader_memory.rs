//! A damaged length field must not make the reader allocate what it claims: a 1 GiB record
//! length in a small file once made `read_log` zero a 1 GiB buffer before finding the file
//! too short (the `mcap_reader` fuzz target ran at 190 inputs/s with 1 GB resident). A
//! counting allocator measures the peak the reader holds.

#[path = "support/counting_alloc.rs"]
mod counting_alloc;

use drivers::synthetic::SyntheticRun;
use metrolog_log::{LogOptions, LogWriter, RunMetadata, read_log};

#[global_allocator]
static ALLOC: counting_alloc::Counting = counting_alloc::Counting;

/// A small valid log.
fn small_log(dir: &std::path::Path) -> Vec<u8> {
    let run = SyntheticRun::small();
    let path = dir.join("small.mcap");
    let meta = RunMetadata {
        machine: "reader-memory".into(),
        started_ns: run.start_ns,
        ..RunMetadata::default()
    };
    let opts = LogOptions {
        fsync: false,
        ..LogOptions::default()
    };
    let mut w = LogWriter::create(&path, &meta, opts).unwrap();
    for ev in run.events() {
        if let drivers::DriverEvent::Sample(s) = &ev {
            w.write_sample(s).unwrap();
        }
    }
    w.finish().unwrap();
    std::fs::read(&path).unwrap()
}

#[test]
fn a_huge_length_in_a_small_file_costs_no_huge_buffer() {
    let dir = tempfile::tempdir().unwrap();
    let good = small_log(dir.path());
    // The first record after the 8-byte magic: opcode (1 byte), then its length (u64 LE).
    let mut bad = good.clone();
    bad[9..17].copy_from_slice(&(1u64 << 30).to_le_bytes());
    let path = dir.path().join("bad.mcap");
    std::fs::write(&path, &bad).unwrap();
    let before = counting_alloc::reset_peak();
    let s = read_log(&path, |_| {}).unwrap();
    let peak = counting_alloc::peak() - before;
    assert!(s.error.is_some() && s.messages == 0, "{s:?}");
    assert!(
        peak < 4 << 20,
        "reading a {} byte file held up to {peak} bytes",
        bad.len()
    );
}
