//! Whole-pipeline benchmark: the release `metrolog run` binary against the simulated
//! instruments for about 60 s of CNC program, in three runs, each against a fresh simulator
//! with the same program:
//!
//! 1. **full rate**: LI-80 10 kHz, CB-3 20 kHz, PSD-2 1 kHz, CNC triggers;
//! 2. **moderate rate**: LI-80 and CB-3 1 kHz, PSD-2 500 Hz (issue 26's peer program);
//! 3. **Python peer** at the moderate rates: `benches/py/plain_daemon.py`, a plain pyserial
//!    daemon that reads the same ports, parses minimally and appends to files.
//!
//! For each: the process's CPU per sample received (user + system, from `wait4`), its
//! wake-ups per second (voluntary context switches, all threads), samples lost, peak RSS and,
//! for metrolog, the largest delay from the last sample of a pose window to its `/pose`
//! record (peak RSS is the first run's: later children are forked from this process, whose
//! memory their `ru_maxrss` counts). Targets (issue 26): ≥ 30× less CPU per sample than the Python peer at moderate
//! rates, ≤ 1 µs per sample at full rate, pose latency < 50 ms, nothing lost, < 30 MB.
//!
//! Run: `cargo bench -p metrolog --bench pipeline` (the simulator runs in this process, so
//! its CPU is not counted against the daemon). `BENCH_PROGRAM_S` shortens the program;
//! `BENCH_RUNS` picks runs (`full,moderate,python`); `METROLOG_BIN` measures another
//! `metrolog` binary (an older build, for a before/after comparison); `BENCH_PYTHON` names the
//! Python interpreter (needs pyserial; the run is skipped without it).

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Instant;

use sim::{ProgramStart, Scenario};

const FULL_HZ: [u32; 3] = [10_000, 20_000, 1000];
const MODERATE_HZ: [u32; 3] = [1000, 1000, 500];

/// What one run of a daemon cost and delivered.
#[derive(Debug, Default, Clone, Copy)]
struct Measured {
    wall_s: f64,
    cpu_s: f64,
    /// Voluntary and involuntary context switches, all threads.
    nvcsw: i64,
    nivcsw: i64,
    peak_rss_mb: f64,
    sent: f64,
    received: f64,
    lost: f64,
    latency_ms: f64,
}

impl Measured {
    fn us_per_sample(&self) -> f64 {
        1e6 * self.cpu_s / self.received
    }
    fn wakeups_per_s(&self) -> f64 {
        self.nvcsw as f64 / self.wall_s
    }
    fn print(&self, name: &str) {
        println!(
            "  {name:<28} {:>8.3} µs CPU/sample  {:>5.1} % of a core  {:>7.0} wake-ups/s ({:.0} involuntary/s)  received {:.0} of {:.0} sent, lost {:.0}  RSS {:.1} MB  pose latency ≤ {:.1} ms",
            self.us_per_sample(),
            100.0 * self.cpu_s / self.wall_s,
            self.wakeups_per_s(),
            self.nivcsw as f64 / self.wall_s,
            self.received,
            self.sent,
            self.lost,
            self.peak_rss_mb,
            self.latency_ms,
        );
    }
}

fn main() {
    // `cargo bench` passes `--bench`; a plain `cargo test --benches` run passes nothing and
    // should not spend minutes here.
    if !std::env::args().any(|a| a == "--bench") {
        println!("pipeline bench: run with `cargo bench -p metrolog --bench pipeline`");
        return;
    }
    let program_s: f64 = std::env::var("BENCH_PROGRAM_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
    let runs = std::env::var("BENCH_RUNS").unwrap_or_else(|_| "full,moderate,python".into());
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let bin =
        std::env::var("METROLOG_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_metrolog").into());
    println!("pipeline bench: {program_s:.0} s program per run, metrolog binary {bin}");
    let mut results = Vec::new();
    for run in runs.split(',') {
        let m = match run {
            "full" => rt.block_on(run_metrolog(&bin, program_s, FULL_HZ, true)),
            "moderate" => rt.block_on(run_metrolog(&bin, program_s, MODERATE_HZ, false)),
            "python" => rt.block_on(run_python(program_s, MODERATE_HZ)),
            other => panic!("unknown run {other:?} in BENCH_RUNS (full, moderate, python)"),
        };
        if let Some(m) = m {
            results.push((run, m));
        }
    }
    println!("summary:");
    for (run, m) in &results {
        m.print(match *run {
            "full" => "metrolog, full rate",
            "moderate" => "metrolog, moderate rate",
            _ => "Python peer, moderate rate",
        });
    }
    let get = |r: &str| results.iter().find(|(n, _)| *n == r).map(|(_, m)| *m);
    if let (Some(m), Some(p)) = (get("moderate"), get("python")) {
        println!(
            "  moderate rate: metrolog uses {:.1}× less CPU per sample than the Python peer (target ≥ 30×)",
            p.us_per_sample() / m.us_per_sample()
        );
    }
    if let Some(f) = get("full") {
        println!(
            "  full rate: {:.3} µs per sample (target ≤ 1 µs), pose latency ≤ {:.1} ms (target < 50 ms)",
            f.us_per_sample(),
            f.latency_ms
        );
    }
}

/// A simulator with the demo program repeated to about `program_s`, no faults, the program
/// starting when the CAN channel opens.
fn start_sim(program_s: f64, ports: &Path) -> sim::SimHandle {
    let mut sc = Scenario::demo();
    sc.faults = Default::default();
    sc.program.start = ProgramStart::OnCanOpen;
    sc.program.start_delay_s = 1.5;
    let one = sc.program.poses.clone();
    while sc.program_duration_s() < program_s {
        sc.program.poses.extend(one.iter().copied());
    }
    sim::Sim::start(sc, ports).unwrap()
}

/// Waits for `child` (on a blocking thread: wait4 gives its exact CPU time, context switches
/// and peak RSS) and returns its exit status, usage, wall time since `t0` and stdout, stderr.
async fn wait(child: Child, t0: Instant) -> (i32, libc::rusage, f64, String, String) {
    let pid = child.id() as i32;
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
    let mut child = child;
    let read = |r: Option<&mut dyn std::io::Read>| {
        let mut s = String::new();
        if let Some(r) = r {
            let _ = r.read_to_string(&mut s);
        }
        s
    };
    let out = read(child.stdout.as_mut().map(|o| o as &mut dyn std::io::Read));
    let err = read(child.stderr.as_mut().map(|e| e as &mut dyn std::io::Read));
    (status, ru, wall_s, out, err)
}

fn usage(ru: &libc::rusage, wall_s: f64) -> Measured {
    Measured {
        wall_s,
        cpu_s: tv(ru.ru_utime) + tv(ru.ru_stime),
        nvcsw: ru.ru_nvcsw,
        nivcsw: ru.ru_nivcsw,
        peak_rss_mb: ru.ru_maxrss as f64 / 1024.0,
        latency_ms: f64::NAN,
        ..Measured::default()
    }
}

/// Samples the simulated instruments wrote to their ports (those beyond the record's cap
/// counted as written: the bench's scenario has no faults).
fn sent(record: &sim::Record) -> f64 {
    [&record.interferometer, &record.capball, &record.psd]
        .iter()
        .map(|d| {
            let written = d.samples.iter().filter(|s| s.fate == sim::Fate::Sent);
            written.count() as u64 + d.unrecorded
        })
        .sum::<u64>() as f64
}

/// The release daemon against the simulator at `rates`; with `details`, the log's size per
/// topic too.
async fn run_metrolog(
    bin: &str,
    program_s: f64,
    rates: [u32; 3],
    details: bool,
) -> Option<Measured> {
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    let sim = start_sim(program_s, &ports);
    let toml = metrolog::cmd::sim::write_daemon_config_with_rates(&sim, &ports, &logs, true, rates)
        .unwrap();
    // `BENCH_RUN_EXTRA`: lines added to the config's `[run]` table (e.g. `read_coalesce_ms = 20`).
    let toml = match std::env::var("BENCH_RUN_EXTRA") {
        Ok(extra) => toml.replacen("[run]\n", &format!("[run]\n{extra}\n"), 1),
        Err(_) => toml,
    };
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();
    let child = Command::new(bin)
        .args(["run", "--config"])
        .arg(&cfg)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (status, ru, wall_s, _, stderr) = wait(child, Instant::now()).await;
    let record = sim.record();
    sim.shutdown().await;
    assert!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "metrolog run failed:\n{stderr}"
    );
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
    let m = Measured {
        sent: sent(&record),
        received: grab("samples").unwrap_or(f64::NAN),
        lost: grab("lost").unwrap_or(f64::NAN),
        latency_ms: grab("pose latency at most").unwrap_or(f64::NAN),
        ..usage(&ru, wall_s)
    };
    println!(
        "metrolog at {rates:?} Hz: {:.1} s wall (daemon from start to exit)",
        wall_s
    );
    m.print("metrolog");
    if details {
        println!("  log: {}", logs_size(&logs));
        if let Some(log) = std::fs::read_dir(&logs)
            .ok()
            .and_then(|mut rd| rd.next())
            .and_then(|e| e.ok())
        {
            topic_sizes(&log.path(), m.received);
        }
    }
    println!("  daemon's last line: {}", last.trim());
    Some(m)
}

/// The plain Python daemon (`benches/py/plain_daemon.py`) against the simulator at `rates`.
async fn run_python(program_s: f64, rates: [u32; 3]) -> Option<Measured> {
    let python = std::env::var("BENCH_PYTHON").unwrap_or_else(|_| "python3".into());
    let has_pyserial = Command::new(&python)
        .args(["-c", "import serial"])
        .status()
        .is_ok_and(|s| s.success());
    if !has_pyserial {
        println!("Python peer: SKIPPED ({python} with pyserial is needed: pip install pyserial)");
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    std::fs::create_dir_all(&ports).unwrap();
    let sim = start_sim(program_s, &ports);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/py/plain_daemon.py");
    let port = |d| sim.port(d).display().to_string();
    let child = Command::new(&python)
        .arg(script)
        .arg(dir.path())
        .args([
            port(sim::Device::Interferometer),
            port(sim::Device::Capball),
            port(sim::Device::Psd),
            port(sim::Device::Trigger),
        ])
        .args(rates.map(|r| r.to_string()))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (status, ru, wall_s, stdout, stderr) = wait(child, Instant::now()).await;
    let record = sim.record();
    sim.shutdown().await;
    assert!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "the Python peer failed:\n{stderr}"
    );
    let received: f64 = stdout
        .lines()
        .find_map(|l| l.strip_prefix("samples "))
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or(f64::NAN);
    let sent = sent(&record);
    let m = Measured {
        sent,
        received,
        lost: sent - received,
        ..usage(&ru, wall_s)
    };
    println!("Python peer at {rates:?} Hz: {wall_s:.1} s wall");
    m.print("Python peer");
    Some(m)
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
