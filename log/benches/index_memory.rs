//! What the log writer keeps in memory as a run grows (issue 15: the one-hour soak's RSS grew
//! by about 29 kB a minute).
//!
//! A counting global allocator measures the bytes the process holds while a synthetic run of
//! one hour (`SyntheticRun`, every instrument and the triggers) is written with a flush once a
//! second of run time, as the daemon does. The same hour is written twice: at the given rates
//! and at four times the samples per second. If what grows is the writer's index of chunks
//! (one `ChunkIndex` per closed chunk, with its per-channel message-index offsets, kept for the
//! summary written at the end), the growth per chunk is the same for both; if it were the data,
//! it would be four times larger.
//!
//! `cargo bench -p metrolog-log --bench index_memory` (MINUTES=60 by default).

#[path = "../tests/support/counting_alloc.rs"]
mod counting_alloc;

use drivers::DriverEvent;
use drivers::synthetic::SyntheticRun;
use metrolog_log::{LogOptions, LogWriter, RunMetadata};

#[global_allocator]
static ALLOC: counting_alloc::Counting = counting_alloc::Counting;

fn held() -> i64 {
    counting_alloc::held() as i64
}

/// Bytes held at each whole minute of run time, and the chunks written.
struct Growth {
    per_minute: Vec<i64>,
    chunks: u64,
    samples: u64,
}

fn write_hour(minutes: usize, scale: f64) -> Growth {
    let run = SyntheticRun {
        li80_hz: 1000.0 * scale,
        cb3_hz: 1000.0 * scale,
        psd_hz: 100.0 * scale,
        targets_mm: (0..minutes * 20).map(|k| (k % 11) as f64 * 10.0).collect(),
        move_s: 0.5,
        dwell_s: 2.5,
        ..SyntheticRun::default()
    };
    let dir = tempfile::tempdir().expect("temporary directory");
    let meta = RunMetadata {
        machine: "index-memory".into(),
        started_ns: run.start_ns,
        ..RunMetadata::default()
    };
    let opts = LogOptions {
        fsync: false,
        // The flush below closes each chunk, as the daemon's 1 s flush does.
        flush_interval: std::time::Duration::from_secs(3600 * 24),
        ..LogOptions::default()
    };
    let mut w = LogWriter::create(&dir.path().join("run.mcap"), &meta, opts).expect("create log");
    let (mut next_flush, mut next_minute) = (run.start_ns + 1_000_000_000, run.start_ns);
    let mut g = Growth {
        per_minute: Vec::new(),
        chunks: 0,
        samples: 0,
    };
    for ev in run.events() {
        let t = match &ev {
            DriverEvent::Sample(s) => {
                w.write_sample(s).expect("write sample");
                g.samples += 1;
                s.host_ns
            }
            DriverEvent::Trigger(tr) => {
                w.write_trigger(tr).expect("write trigger");
                tr.host_ns
            }
            _ => continue,
        };
        while t >= next_flush {
            w.flush().expect("flush");
            g.chunks += 1;
            next_flush += 1_000_000_000;
        }
        if t >= next_minute {
            g.per_minute.push(held());
            next_minute += 60_000_000_000;
        }
    }
    w.finish().expect("finish");
    g
}

fn report(label: &str, g: &Growth) {
    let first = g.per_minute.get(1).copied().unwrap_or(0);
    let last = g.per_minute.last().copied().unwrap_or(0);
    let minutes = g.per_minute.len().saturating_sub(2).max(1) as f64;
    let chunks = g.chunks as f64 * minutes / (g.per_minute.len().max(1) as f64);
    println!(
        "{label}: {} samples, {} chunks; held at minute 1 {:.1} kB, at the end {:.1} kB: \
         +{:.1} kB/min, {:.0} bytes per chunk",
        g.samples,
        g.chunks,
        first as f64 / 1e3,
        last as f64 / 1e3,
        (last - first) as f64 / 1e3 / minutes,
        (last - first) as f64 / chunks
    );
    let marks: Vec<String> = g
        .per_minute
        .iter()
        .enumerate()
        .filter(|(m, _)| m % 10 == 0)
        .map(|(m, b)| format!("{m} min {:.0} kB", *b as f64 / 1e3))
        .collect();
    println!("  {}", marks.join(", "));
}

fn main() {
    let minutes: usize = std::env::var("MINUTES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60);
    let base = held();
    println!("bytes held before writing: {base}");
    report(
        "1x rates (li80 1 kHz, cb3 1 kHz, psd 100 Hz)",
        &write_hour(minutes, 1.0),
    );
    report("4x rates", &write_hour(minutes, 4.0));
    println!(
        "bytes held after both files were finished: {}",
        held() - base
    );
}
