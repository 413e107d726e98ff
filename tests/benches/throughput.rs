//! End-to-end throughput of the drivers through pseudo-terminals: LI-80 at 10 kHz, CB-3 at
//! 20 kHz and PSD-2 at 1 kHz together, for `METROLOG_BENCH_SECS` (default 15) seconds.
//!
//! The devices run in a child process (this binary started again with
//! `METROLOG_BENCH_DEVICE_DIR` set), so the CPU time measured with `getrusage(RUSAGE_SELF)` in
//! this process is the drivers' (plus a consumer that only counts). Checks that nothing is
//! lost (every sequence number arrives once, no gap, nothing dropped or rejected) and reports
//! the CPU time per second of data as a percentage of one core.
//!
//! `cargo bench -p metrolog-hil --bench throughput`

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use drivers::{DriverEvent, HostClock, Instrument, SampleValues};
use hil::FakeDevice;
use hil::fake::*;
use tokio_util::sync::CancellationToken;

const LI80_HZ: u64 = 10_000;
const CB3_HZ: u64 = 20_000;
const PSD_HZ: u64 = 1_000;
/// Devices write every 2 ms, like a USB virtual serial port delivering its buffers.
const CHUNK_MS: u64 = 2;

fn secs() -> u64 {
    std::env::var("METROLOG_BENCH_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(15)
}

fn device_main(dir: &str) {
    let n = secs();
    let dir = std::path::Path::new(dir);
    let p = Duration::from_millis(CHUNK_MS);
    let per = |hz: u64| hz * CHUNK_MS / 1000;
    let li = FakeDevice::start(
        &dir.join("li80"),
        b'\n',
        li80_device(),
        li80_script(n * LI80_HZ, LI80_HZ, per(LI80_HZ)),
        p,
    )
    .expect("li80 pty");
    let cb = FakeDevice::start(
        &dir.join("cb3"),
        b'\n',
        cb3_device(),
        cb3_script(n * CB3_HZ, CB3_HZ, per(CB3_HZ)),
        p,
    )
    .expect("cb3 pty");
    let ps = FakeDevice::start(
        &dir.join("psd2"),
        b'\n',
        psd_device(),
        psd_script(n * PSD_HZ, PSD_HZ, per(PSD_HZ)),
        p,
    )
    .expect("psd pty");
    let deadline = Instant::now() + Duration::from_secs(n * 3 + 30);
    while !(li.script_done() && cb.script_done() && ps.script_done()) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    // Let the host read the rest before the ptys close.
    std::thread::sleep(Duration::from_secs(3));
}

fn cpu_s() -> f64 {
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage writes into the struct we own.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

#[derive(Default, Debug)]
struct Seen {
    samples: u64,
    next_seq: Option<u64>,
    out_of_order: u64,
}

fn main() {
    if let Ok(dir) = std::env::var("METROLOG_BENCH_DEVICE_DIR") {
        device_main(&dir);
        return;
    }
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let n = secs();
    let dir = tempfile::tempdir().expect("tempdir");
    let mut child = std::process::Command::new(std::env::current_exe().expect("exe"))
        .env("METROLOG_BENCH_DEVICE_DIR", dir.path())
        .env("METROLOG_BENCH_SECS", n.to_string())
        .spawn()
        .expect("device process");
    for l in ["li80", "cb3", "psd2"] {
        let deadline = Instant::now() + Duration::from_secs(10);
        while !dir.path().join(l).exists() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    // The daemon's runtime: multi-threaded with 2 workers (METROLOG_BENCH_RT=current for a
    // current-thread runtime).
    let current = std::env::var("METROLOG_BENCH_RT").is_ok_and(|v| v == "current");
    let rt = if current {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
    }
    .expect("runtime");
    rt.block_on(async {
        let (tx, mut rx) = tokio::sync::mpsc::channel(65_536);
        let cancel = CancellationToken::new();
        let clock = HostClock::new();
        let port = |l: &str| dir.path().join(l).display().to_string();
        let tasks = vec![
            drivers::spawn_li80(
                drivers::Li80Config { port: port("li80"), rate_hz: LI80_HZ as u32, alpha_um_per_m_k: 11.7 },
                clock,
                tx.clone(),
                cancel.clone(),
            ),
            drivers::spawn_cb3(
                drivers::Cb3Config {
                    port: port("cb3"),
                    rate_hz: CB3_HZ as u32,
                    poly: [[10.0, 0.0, 0.0]; 3],
                    transform: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
                },
                clock,
                tx.clone(),
                cancel.clone(),
            ),
            drivers::spawn_psd(
                drivers::PsdConfig {
                    port: port("psd2"),
                    baud: 921_600,
                    rate_hz: PSD_HZ as u32,
                    min_sum_pa: 1000.0,
                    error_map: None,
                    head: None,
                },
                clock,
                tx.clone(),
                cancel.clone(),
            ),
        ];
        drop(tx);
        let expected: BTreeMap<Instrument, u64> =
            [(Instrument::Interferometer, n * LI80_HZ), (Instrument::Capball, n * CB3_HZ), (Instrument::Psd, n * PSD_HZ)].into();
        let mut seen: BTreeMap<Instrument, Seen> = BTreeMap::new();
        let mut counters = BTreeMap::new();
        let mut connected = 0;
        let (mut t0, mut c0) = (Instant::now(), cpu_s());
        let deadline = Instant::now() + Duration::from_secs(n * 3 + 30);
        let mut batch = Vec::with_capacity(1024);
        'outer: while Instant::now() < deadline {
            batch.clear();
            let Ok(k) = tokio::time::timeout(Duration::from_secs(5), rx.recv_many(&mut batch, 1024)).await else { break };
            if k == 0 {
                break;
            }
            for ev in batch.drain(..) {
            match ev {
                DriverEvent::Sample(s) => {
                    if matches!(s.values, SampleValues::Environment { .. }) {
                        continue;
                    }
                    let e = seen.entry(s.instrument).or_default();
                    if e.next_seq.is_some_and(|q| q != s.seq) {
                        e.out_of_order += 1;
                    }
                    e.next_seq = Some(s.seq + 1);
                    e.samples += 1;
                    if expected.iter().all(|(i, &n)| seen.get(i).is_some_and(|s| s.samples >= n)) {
                        break 'outer;
                    }
                }
                DriverEvent::Connected { .. } => {
                    connected += 1;
                    if connected == 3 {
                        // Measure from the moment all three stream.
                        t0 = Instant::now();
                        c0 = cpu_s();
                    }
                }
                DriverEvent::Counters { instrument, counters: c } => {
                    counters.insert(instrument, c);
                }
                DriverEvent::Error { error, .. } => eprintln!("driver error: {error}"),
                DriverEvent::Disconnected { reason, .. } => eprintln!("disconnected: {reason}"),
                DriverEvent::Trigger(_) | DriverEvent::Datum { .. } => {}
            }
            }
        }
        let (wall, cpu) = (t0.elapsed().as_secs_f64(), cpu_s() - c0);
        cancel.cancel();
        for t in tasks {
            let _ = t.await;
        }
        while let Some(ev) = rx.recv().await {
            if let DriverEvent::Counters { instrument, counters: c } = ev {
                counters.insert(instrument, c);
            }
        }
        let total: u64 = seen.values().map(|s| s.samples).sum();
        println!(
            "drivers end to end through ptys, {n} s of data: LI-80 {LI80_HZ} Hz + CB-3 {CB3_HZ} Hz + PSD-2 {PSD_HZ} Hz ({} runtime)",
            if current { "current-thread" } else { "2-worker" }
        );
        let mut lost_any = false;
        for (i, &exp) in &expected {
            let s = seen.get(i).map_or(0, |s| s.samples);
            let k = counters.get(i).cloned().unwrap_or_default();
            let rej: u64 = k.rejections.values().sum();
            let ooo = seen.get(i).map_or(0, |s| s.out_of_order);
            println!(
                "  {:<15} received {s:>8} of {exp:>8}  gaps {} (samples {})  dropped {}  rejected {rej}  out of order {ooo}",
                i.name(),
                k.gaps,
                k.gap_samples,
                k.dropped
            );
            lost_any |= s != exp || k.gaps != 0 || k.dropped != 0 || rej != 0 || ooo != 0;
        }
        println!(
            "  {total} samples in {wall:.2} s wall; driver process CPU {cpu:.3} s = {:.2} % of one core ({:.0} ns per sample)",
            100.0 * cpu / wall,
            cpu / total.max(1) as f64 * 1e9
        );
        println!("  lost samples: {}", if lost_any { "YES" } else { "none" });
    });
    let _ = child.wait();
}
