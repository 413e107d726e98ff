//! Whole-pipeline benchmark: the release `metrolog run` binary against the simulated
//! instruments at full rate — LI-80 10 kHz, CB-3 20 kHz, PSD-2 1 kHz, CNC triggers — for about
//! 60 s of CNC program. Reports samples lost, the daemon's CPU (share of one core), its peak
//! RSS, and the largest delay from the last sample of a pose window to its `/pose` record.
//! Targets: nothing lost, < 10 % of a core, < 30 MB, < 50 ms.
//!
//! Run: `cargo bench -p metrolog --bench pipeline` (the simulator runs in this process, so
//! its CPU is not counted against the daemon; `BENCH_PROGRAM_S` shortens the program).

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use sim::{ProgramStart, Scenario};

fn main() {
    // `cargo bench` passes `--bench`; a plain `cargo test --benches` run passes nothing and
    // should not spend a minute here.
    if !std::env::args().any(|a| a == "--bench") {
        println!("pipeline bench: run with `cargo bench -p metrolog --bench pipeline`");
        return;
    }
    let program_s: f64 = std::env::var("BENCH_PROGRAM_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(run(program_s));
}

async fn run(program_s: f64) {
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    let mut sc = Scenario::demo();
    sc.faults = Default::default();
    sc.program.start = ProgramStart::OnCanOpen;
    sc.program.start_delay_s = 1.5;
    let one = sc.program.poses.clone();
    while sc.program_duration_s() < program_s {
        sc.program.poses.extend(one.iter().copied());
    }
    let sim = sim::Sim::start(sc, &ports).unwrap();
    let toml = metrolog::cmd::sim::write_daemon_config_with_rates(
        &sim,
        &ports,
        &logs,
        true,
        [10_000, 20_000, 1000],
    )
    .unwrap();
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();

    let child = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["run", "--config"])
        .arg(&cfg)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as i32;
    let t0 = Instant::now();
    // wait4 gives the child's exact CPU time and peak RSS.
    let (status, ru) = tokio::task::spawn_blocking(move || {
        let mut status = 0;
        // SAFETY: rusage is plain data, fully written by wait4 on success.
        let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut ru) };
        assert_eq!(r, pid, "wait4 failed");
        (status, ru)
    })
    .await
    .unwrap();
    let wall_s = t0.elapsed().as_secs_f64();
    let mut stderr = String::new();
    if let Some(mut e) = { child }.stderr.take() {
        use std::io::Read;
        let _ = e.read_to_string(&mut stderr);
    }
    let record = sim.record();
    sim.shutdown().await;
    assert!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "metrolog run failed:\n{stderr}"
    );

    let cpu_s = tv(ru.ru_utime) + tv(ru.ru_stime);
    let peak_rss_mb = ru.ru_maxrss as f64 / 1024.0;
    let last = stderr
        .lines()
        .rev()
        .find(|l| l.contains("run ended"))
        .unwrap_or("")
        .to_string();
    let grab = |key: &str| -> Option<f64> {
        let i = last.find(key)? + key.len();
        last[i..]
            .trim_start()
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .next()?
            .parse()
            .ok()
    };
    let lost = grab("lost").unwrap_or(f64::NAN);
    let samples = grab("samples").unwrap_or(f64::NAN);
    let latency_ms = grab("pose latency at most").unwrap_or(f64::NAN);
    let sent = record.interferometer.samples.len()
        + record.capball.samples.len()
        + record.psd.samples.len();
    println!(
        "pipeline bench: {:.0} s program, {:.1} s wall (daemon from start to exit)",
        program_s, wall_s
    );
    println!(
        "  samples sent by the simulator {sent}, received by the daemon {samples}, lost (gaps + dropped) {lost}"
    );
    println!(
        "  daemon CPU {cpu_s:.2} s = {:.1} % of one core (target < 10 %)",
        100.0 * cpu_s / wall_s
    );
    println!("  daemon peak RSS {peak_rss_mb:.1} MB (target < 30 MB)");
    println!(
        "  last sample of a pose window to its /pose record: at most {latency_ms:.1} ms (target < 50 ms)"
    );
    println!("  log: {}", logs_size(&logs));
    if let Some(log) = std::fs::read_dir(&logs)
        .ok()
        .and_then(|mut rd| rd.next())
        .and_then(|e| e.ok())
    {
        topic_sizes(&log.path(), samples);
    }
    println!("  daemon's last line: {}", last.trim());
}

/// Bytes per sample on disk, and per raw topic: each topic's messages compressed alone with
/// the writer's zstd level in pieces of the writer's chunk size (the file mixes topics in its
/// chunks, so the topics' sum differs a little from the file; the rest is the index, the
/// summary and the JSON topics).
fn topic_sizes(path: &Path, samples: f64) {
    use std::collections::BTreeMap;
    let opts = metrolog_log::LogOptions::default();
    // topic → (messages, samples, pieces of at most a chunk, compressed bytes, raw bytes)
    let mut topics: BTreeMap<String, (u64, u64, Vec<u8>, u64, u64)> = BTreeMap::new();
    // Every message in file order, for the zstd level and chunk size comparison.
    let mut all = Vec::new();
    let compress = |piece: &[u8]| {
        zstd::bulk::compress(piece, opts.zstd_level as i32).map_or(0, |c| c.len() as u64)
    };
    metrolog_log::read_log(path, |item| {
        if let metrolog_log::LogItem::Message { topic, data, .. } = item {
            all.extend_from_slice(data);
            let t = topics.entry(topic.to_string()).or_default();
            t.0 += 1;
            t.1 += metrolog_log::raw::Batch::decode(topic, data)
                .ok()
                .flatten()
                .map_or(0, |b| b.len() as u64);
            t.2.extend_from_slice(data);
            t.4 += data.len() as u64;
            if t.2.len() as u64 >= opts.chunk_size {
                t.3 += compress(&t.2);
                t.2.clear();
            }
        }
    })
    .unwrap();
    let file = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    println!(
        "  bytes per sample: {:.2} on disk ({} B / {samples} samples)",
        file as f64 / samples,
        file
    );
    let mut sum = 0;
    for (topic, (msgs, n, rest, mut z, raw)) in topics {
        z += compress(&rest);
        sum += z;
        let per = |b: u64| if n > 0 { b as f64 / n as f64 } else { f64::NAN };
        println!(
            "    {topic:<30} {msgs:>7} msgs {n:>9} samples  raw {:>6.2} B/sample  zstd {:>6.2} B/sample of the topic, {:>5.2} B per sample of the run",
            per(raw),
            per(z),
            z as f64 / samples
        );
    }
    println!(
        "    rest (index, summary, attachments, chunk headers): {:.2} B per sample of the run",
        (file as f64 - sum as f64) / samples
    );
    // The writer's zstd level and chunk size: every message compressed in pieces of a chunk.
    for (level, chunk) in [
        (1, 4 << 20),
        (3, 1 << 20),
        (3, 4 << 20),
        (3, 16 << 20),
        (6, 4 << 20),
    ] {
        let t0 = Instant::now();
        let z: u64 = all
            .chunks(chunk)
            .map(|p| zstd::bulk::compress(p, level).map_or(0, |c| c.len() as u64))
            .sum();
        let s = t0.elapsed().as_secs_f64();
        println!(
            "    zstd level {level}, chunks of {} MB: {:.2} B per sample of the run, {:.3} µs per sample to compress (wall time of this process)",
            chunk >> 20,
            z as f64 / samples,
            1e6 * s / samples
        );
    }
}

fn tv(t: libc::timeval) -> f64 {
    t.tv_sec as f64 + t.tv_usec as f64 / 1e6
}

fn logs_size(dir: &Path) -> String {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .map(|e| {
                    format!(
                        "{} ({:.1} MB)",
                        e.file_name().to_string_lossy(),
                        e.metadata().map(|m| m.len()).unwrap_or(0) as f64 / 1e6
                    )
                })
                .collect::<Vec<_>>()
                .join(", ")
        })
        .unwrap_or_default()
}
