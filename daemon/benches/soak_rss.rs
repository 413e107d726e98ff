//! Memory over a two-day run (issue 26: "a simulated two-day run at the thermal-test rates
//! keeps RSS flat, ±1 MB after the first hour").
//!
//! Feeds the service's [`Recorder`] (log writer with zstd chunks, the pose engine, `/status`,
//! the run's counts) a synthetic run of `HOURS` hours (48 by default) as fast as it can, in
//! compressed time: a thermal test's instruments — the CB-3 at `CB3_HZ` (1000 by default;
//! `metrolog demo`'s 480×-compressed thermal run uses 20 000), the temperature module polled at
//! `TEMP_HZ` (20, every 50 ms as in the demo), the LI-80's environment once a second, the CNC's
//! triggers of a visit every 3 min (84 s move, 96 s dwell, as `metrolog plan thermal
//! --every-min 3`). The log is flushed once a second of run time as the daemon does, and split
//! every `SPLIT_MINUTES` (30; 0: one file, to see what splitting bounds); finished parts are
//! deleted as retention would, so the disk holds about one part.
//!
//! The process's resident set (`VmRSS`, /proc/self/status) is read every simulated minute;
//! printed: RSS after the first simulated hour, its largest deviation from that afterwards,
//! RSS at the end, run length simulated and wall time; beside it the bytes the Rust heap holds
//! (a counting allocator), which tells data kept from pages the allocator keeps.
//!
//! `cargo bench -p metrolog --bench soak_rss` (env: HOURS, CB3_HZ, TEMP_HZ, SPLIT_MINUTES).

use std::time::{Duration, Instant};

// What Rust code holds (zstd's own buffers are C allocations and not counted): tells growth of
// data kept (held grows) from the allocator's retained pages (RSS grows, held does not).
#[path = "../../log/tests/support/counting_alloc.rs"]
mod counting_alloc;

#[global_allocator]
static ALLOC: counting_alloc::Counting = counting_alloc::Counting;

use drivers::DriverEvent;
use drivers::synthetic::SyntheticRun;
use metrolog::acquire::recorder::Recorder;
use metrolog_log::{DetectorSettings, LogOptions, LogWriter, RunMetadata};

fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The process's resident set, bytes.
fn rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

/// The thermal test's run: a visit every 3 min for `hours`.
fn thermal_run(hours: f64, cb3_hz: f64, temp_hz: f64) -> SyntheticRun {
    let visits = (hours * 20.0).ceil() as usize;
    SyntheticRun {
        li80_hz: 0.0,
        cb3_hz,
        psd_hz: 0.0,
        temperature_hz: temp_hz,
        // The measuring pose and the park pose, alternately.
        targets_mm: (0..visits)
            .map(|k| if k % 2 == 0 { 120.0 } else { 160.0 })
            .collect(),
        move_s: 84.0,
        dwell_s: 96.0,
        ..SyntheticRun::default()
    }
}

fn event_ns(e: &DriverEvent) -> Option<u64> {
    match e {
        DriverEvent::Sample(s) => Some(s.host_ns),
        DriverEvent::Trigger(t) => Some(t.host_ns),
        _ => None,
    }
}

/// Deletes every finished part in `dir` (all files but `current`).
fn drop_finished_parts(dir: &std::path::Path, current: &std::path::Path) {
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        if e.path() != current {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

fn main() {
    let hours = env_f64("HOURS", 48.0);
    let cb3_hz = env_f64("CB3_HZ", 1000.0);
    let temp_hz = env_f64("TEMP_HZ", 20.0);
    let split_min = env_f64("SPLIT_MINUTES", 30.0);
    let run = thermal_run(hours, cb3_hz, temp_hz);
    let dir = tempfile::tempdir().expect("temporary directory");
    let meta = RunMetadata {
        machine: "soak".into(),
        started_ns: run.start_ns,
        detector: DetectorSettings::default(),
        ..RunMetadata::default()
    };
    let opts = LogOptions {
        fsync: false,
        // Flushed below once a second of run time, as the daemon's timer does.
        flush_interval: Duration::from_secs(86_400 * 365),
        split_after: (split_min > 0.0).then(|| Duration::from_secs_f64(split_min * 60.0)),
        ..LogOptions::default()
    };
    let w =
        LogWriter::create(&dir.path().join("metrolog-soak.mcap"), &meta, opts).expect("create log");
    let mut rec = Recorder::new(w, &meta.detector).expect("recorder");
    println!(
        "soak: {hours} h simulated, CB-3 {cb3_hz} Hz, temperatures {temp_hz} Hz, triggers of a visit every 3 min, split every {split_min} min"
    );
    let t0 = Instant::now();
    let (mut now, mut next_flush, mut next_minute) = (run.start_ns, run.start_ns, run.start_ns);
    let mut rss: Vec<u64> = Vec::new();
    let mut held: Vec<u64> = Vec::new();
    let mut samples = 0u64;
    let mut part = rec.part();
    for ev in run.events() {
        if let Some(t) = event_ns(&ev) {
            now = now.max(t);
        }
        samples += u64::from(matches!(ev, DriverEvent::Sample(_)));
        rec.record(&ev, now).expect("record");
        while now >= next_flush {
            rec.writer().flush().expect("flush");
            next_flush += 1_000_000_000;
        }
        if rec.part() != part {
            part = rec.part();
            drop_finished_parts(dir.path(), rec.log_path());
        }
        if now >= next_minute {
            rss.push(rss_bytes());
            held.push(counting_alloc::held() as u64);
            next_minute += 60_000_000_000;
            if rss.len() % 60 == 1 {
                println!(
                    "  hour {:>3}: RSS {:.2} MB, heap held {:.2} MB, part {part}, {samples} samples, {:.0} s wall",
                    rss.len() / 60,
                    *rss.last().unwrap_or(&0) as f64 / 1e6,
                    *held.last().unwrap_or(&0) as f64 / 1e6,
                    t0.elapsed().as_secs_f64()
                );
            }
        }
    }
    rec.finish(now).expect("finish");
    report("RSS", &rss, samples, hours, t0.elapsed());
    report("heap held", &held, samples, hours, t0.elapsed());
}

fn report(what: &str, rss: &[u64], samples: u64, hours: f64, wall: Duration) {
    let Some(&at_hour) = rss.get(60) else {
        println!("run shorter than an hour: RSS {rss:?}");
        return;
    };
    let after = &rss[60..];
    let dev = after
        .iter()
        .map(|&r| r as i64 - at_hour as i64)
        .max_by_key(|d| d.abs())
        .unwrap_or(0);
    let (lo, hi) = (
        after.iter().min().copied().unwrap_or(0),
        after.iter().max().copied().unwrap_or(0),
    );
    println!(
        "soak result: {hours} h simulated ({samples} samples) in {:.0} s wall; {what} after the first hour {:.2} MB; after it {:.2} .. {:.2} MB, largest deviation {:+.3} MB; at the end {:.2} MB (target ±1 MB: {})",
        wall.as_secs_f64(),
        at_hour as f64 / 1e6,
        lo as f64 / 1e6,
        hi as f64 / 1e6,
        dev as f64 / 1e6,
        *rss.last().unwrap_or(&0) as f64 / 1e6,
        if dev.abs() <= 1_000_000 {
            "met"
        } else {
            "NOT met"
        }
    );
}
