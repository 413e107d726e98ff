//! A damaged length field must not make the reader allocate what it claims: a 1 GiB record
//! length in a small file once made `read_log` zero a 1 GiB buffer before finding the file
//! too short (the `mcap_reader` fuzz target ran at 190 inputs/s with 1 GB resident). A
//! counting allocator measures the peak the reader holds.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use metrolog_log::synthetic::SyntheticRun;
use metrolog_log::{LogOptions, LogWriter, RunMetadata, read_log};

struct Peak;

static HELD: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Peak {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let now = HELD.fetch_add(l.size(), Ordering::Relaxed) + l.size();
        PEAK.fetch_max(now, Ordering::Relaxed);
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        HELD.fetch_sub(l.size(), Ordering::Relaxed);
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static ALLOC: Peak = Peak;

/// A small valid log.
fn small_log(dir: &std::path::Path) -> Vec<u8> {
    let run = SyntheticRun {
        targets_mm: vec![0.0, 25.0],
        dwell_s: 0.05,
        move_s: 0.02,
        li80_hz: 200.0,
        cb3_hz: 100.0,
        psd_hz: 50.0,
        ..SyntheticRun::default()
    };
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
    let before = HELD.load(Ordering::Relaxed);
    PEAK.store(before, Ordering::Relaxed);
    let s = read_log(&path, |_| {}).unwrap();
    let peak = PEAK.load(Ordering::Relaxed) - before;
    assert!(s.error.is_some() && s.messages == 0, "{s:?}");
    assert!(
        peak < 4 << 20,
        "reading a {} byte file held up to {peak} bytes",
        bad.len()
    );
}
