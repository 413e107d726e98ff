//! MCAP log benchmarks.
//!
//! - log size at the nominal demo rates (LI-80 1 kHz, CB-3 1 kHz, PSD 100 Hz): one minute of
//!   a synthetic run is written and scaled to an hour; printed as MB/h and bytes per sample;
//! - writer throughput at LI-80 10 kHz + CB-3 20 kHz + PSD 1 kHz, through the `Recorder`
//!   (JSON encoding, zstd chunks, the three steady-value detectors, `/status`), in samples/s,
//!   with the CPU share that the real-time rate would take;
//! - the steady-value detector alone.

use std::hint::black_box;
use std::time::Instant;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use detect::SteadyDetector;
use drivers::DriverEvent;
use drivers::synthetic::SyntheticRun;
use metrolog::acquire::recorder::Recorder;
use metrolog_log::{DetectorSettings, LogOptions, LogWriter, RunMetadata};
use types::{SteadyConfig, TriggerEvent};

fn event_ns(e: &DriverEvent, now: u64) -> u64 {
    match e {
        DriverEvent::Sample(s) => now.max(s.host_ns),
        DriverEvent::Trigger(t) => now.max(t.host_ns),
        _ => now,
    }
}

/// Writes `events` to a new log in `dir`; returns (file bytes, samples).
fn write(dir: &std::path::Path, name: &str, events: &[DriverEvent], start_ns: u64) -> (u64, u64) {
    let meta = RunMetadata {
        machine: "bench".into(),
        started_ns: start_ns,
        ..RunMetadata::default()
    };
    let path = dir.join(name);
    let _ = std::fs::remove_file(&path);
    let w = LogWriter::create(&path, &meta, LogOptions::default()).unwrap();
    let mut rec = Recorder::new(w, &DetectorSettings::default()).unwrap();
    let mut now = start_ns;
    let mut samples = 0;
    for e in events {
        now = event_ns(e, now);
        if matches!(e, DriverEvent::Sample(_)) {
            samples += 1;
        }
        rec.record(e, now).unwrap();
    }
    rec.finish(now).unwrap();
    (std::fs::metadata(&path).unwrap().len(), samples)
}

fn cpu_s() -> f64 {
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

fn log_size(dir: &std::path::Path) {
    // 20 poses of 3 s: one minute at the nominal rates.
    let run = SyntheticRun {
        targets_mm: (0..20).map(|k| k as f64 * 10.0).collect(),
        ..SyntheticRun::default()
    };
    let events: Vec<_> = run.events().collect();
    let (bytes, samples) = write(dir, "size.mcap", &events, run.start_ns);
    let per_hour = bytes as f64 * 3600.0 / run.duration_s();
    println!(
        "log size at LI-80 1 kHz + CB-3 1 kHz + PSD 100 Hz (+ env 1 Hz): {:.1} MB/h, {:.1} bytes/sample ({} samples, {} bytes in {:.1} s)",
        per_hour / 1e6,
        bytes as f64 / samples as f64,
        samples,
        bytes,
        run.duration_s()
    );
}

fn throughput(c: &mut Criterion, dir: &std::path::Path) {
    let run = SyntheticRun {
        li80_hz: 10_000.0,
        cb3_hz: 20_000.0,
        psd_hz: 1_000.0,
        targets_mm: vec![0.0, 10.0],
        dwell_s: 1.5,
        ..SyntheticRun::default()
    };
    let events: Vec<_> = run.events().collect();
    let samples = events
        .iter()
        .filter(|e| matches!(e, DriverEvent::Sample(_)))
        .count() as u64;
    // One timed pass with the CPU time, for the report.
    let (t0, c0) = (Instant::now(), cpu_s());
    let (bytes, _) = write(dir, "rate.mcap", &events, run.start_ns);
    let (wall, cpu) = (t0.elapsed().as_secs_f64(), cpu_s() - c0);
    let rate = samples as f64 / wall;
    let real_rate = 31_000.0;
    println!(
        "writer at LI-80 10 kHz + CB-3 20 kHz + PSD 1 kHz: {:.0} samples/s ({:.1}x real time), CPU {:.2} s for {:.1} s of data = {:.1}% of one core at the real rate; {:.1} bytes/sample",
        rate,
        rate / real_rate,
        cpu,
        run.duration_s(),
        100.0 * cpu / run.duration_s(),
        bytes as f64 / samples as f64
    );
    let mut g = c.benchmark_group("log_writer");
    g.sample_size(10);
    g.throughput(Throughput::Elements(samples));
    g.bench_function("recorder_10k_20k_1k_hz", |b| {
        b.iter(|| write(dir, "bench.mcap", black_box(&events), run.start_ns))
    });
    g.finish();
}

fn detector(c: &mut Criterion) {
    let n = 20_000u64;
    let mut g = c.benchmark_group("steady_detector");
    g.throughput(Throughput::Elements(n));
    g.sample_size(20);
    g.bench_function("3_channels_in_dwell", |b| {
        b.iter(|| {
            let mut d = SteadyDetector::new(SteadyConfig::default(), 3).unwrap();
            d.push_trigger(TriggerEvent::ExactStop, 1, 0);
            let mut k = 0usize;
            for i in 0..n {
                // A slow oscillation that never settles: the worst case, a test per sample.
                let y = (i as f64 * 0.01).sin();
                k += d.push_sample(i * 50_000, &[y, y, y], true).len();
            }
            black_box(k)
        })
    });
    g.finish();
}

fn benches(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    log_size(dir.path());
    throughput(c, dir.path());
    detector(c);
}

criterion_group! {
    name = log;
    // No plots: plotters needs fonts the build machines may not have.
    config = Criterion::default().without_plots();
    targets = benches
}
criterion_main!(log);
