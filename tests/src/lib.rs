//! Helpers for the hardware-in-loop tests in `tests/tests/`: the real drivers against the
//! simulated instruments of `sim/` on pseudo-terminals, and against small scripted devices
//! (a pty whose far end the test plays, writing bytes made with `protocol`'s encoders).

use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use drivers::{Counters, DriverEvent, Instrument, Sample};
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

/// A pseudo-terminal pair, both sides raw.
pub struct Pty {
    pub master: OwnedFd,
    pub slave: OwnedFd,
    /// `/dev/pts/N` of the slave.
    pub path: PathBuf,
}

/// Open a pty pair with both sides in raw mode (no echo, no line editing, 8 bit clean).
pub fn pty() -> anyhow::Result<Pty> {
    let r = nix::pty::openpty(None, None).context("openpty")?;
    for fd in [&r.master, &r.slave] {
        let mut t = tcgetattr(fd.as_fd()).context("tcgetattr")?;
        cfmakeraw(&mut t);
        tcsetattr(fd.as_fd(), SetArg::TCSANOW, &t).context("tcsetattr")?;
    }
    let path = nix::unistd::ttyname(r.slave.as_fd()).context("ttyname")?;
    Ok(Pty {
        master: r.master,
        slave: r.slave,
        path,
    })
}

/// Point the stable `link` at `target` (atomically: a udev rule re-pointing a symlink).
pub fn point_link(link: &Path, target: &Path) -> anyhow::Result<()> {
    let tmp = link.with_extension("tmp");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp).context("symlink")?;
    std::fs::rename(&tmp, link).context("rename symlink")?;
    Ok(())
}

/// What a scripted device does with a command line: the bytes to answer, and whether to
/// start (`Some(true)`) or stop (`Some(false)`) streaming its script.
pub type Respond = Box<dyn FnMut(&str, &mut Vec<u8>) -> Option<bool> + Send>;

/// A device played by the test on the master side of a pty: answers commands with `respond`,
/// and while streaming writes `chunks` one every `period`.
pub struct FakeDevice {
    stop: Arc<AtomicBool>,
    done: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<()>>,
    /// Command lines received, in order.
    pub commands: Arc<Mutex<Vec<String>>>,
    pub link: PathBuf,
}

impl FakeDevice {
    /// Start the device behind the symlink `link` (created or re-pointed). Commands end in
    /// `terminator` (`\n`, or `\r` for SLCAN).
    pub fn start(
        link: &Path,
        terminator: u8,
        mut respond: Respond,
        chunks: Vec<Vec<u8>>,
        period: Duration,
    ) -> anyhow::Result<FakeDevice> {
        let p = pty()?;
        let flags = OFlag::from_bits_truncate(fcntl(p.master.as_fd(), FcntlArg::F_GETFL)?);
        fcntl(
            p.master.as_fd(),
            FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK),
        )?;
        point_link(link, &p.path)?;
        let stop = Arc::new(AtomicBool::new(false));
        let done = Arc::new(AtomicBool::new(false));
        let commands = Arc::new(Mutex::new(Vec::new()));
        let (stop2, done2, commands2) = (stop.clone(), done.clone(), commands.clone());
        let handle = std::thread::spawn(move || {
            let Pty { master, slave, .. } = p;
            let mut line = Vec::new();
            let mut buf = [0u8; 4096];
            let mut streaming = false;
            let mut next = 0usize;
            let mut next_at = Instant::now();
            let mut out = Vec::new();
            while !stop2.load(Ordering::Relaxed) {
                match nix::unistd::read(master.as_fd(), &mut buf) {
                    Ok(n) if n > 0 => {
                        for &b in &buf[..n] {
                            if b == terminator {
                                let cmd = String::from_utf8_lossy(&line).trim().to_string();
                                line.clear();
                                commands2.lock().unwrap().push(cmd.clone());
                                out.clear();
                                match respond(&cmd, &mut out) {
                                    Some(true) => {
                                        streaming = true;
                                        next_at = Instant::now();
                                    }
                                    Some(false) => streaming = false,
                                    None => {}
                                }
                                write_all(&master, &out);
                            } else {
                                line.push(b);
                            }
                        }
                    }
                    _ => {}
                }
                if streaming && next < chunks.len() && Instant::now() >= next_at {
                    write_all(&master, &chunks[next]);
                    next += 1;
                    next_at += period;
                    if next == chunks.len() {
                        done2.store(true, Ordering::Relaxed);
                    }
                }
                std::thread::sleep(Duration::from_micros(500));
            }
            drop(slave);
            drop(master);
        });
        Ok(FakeDevice {
            stop,
            done,
            handle: Some(handle),
            commands,
            link: link.to_path_buf(),
        })
    }

    /// The command lines received, once there are at least `n` of them or `limit` has passed
    /// (the device thread reads them in its own time: a loaded machine delays it).
    pub fn wait_commands(&self, n: usize, limit: Duration) -> Vec<String> {
        let t0 = Instant::now();
        loop {
            let cmds = self.commands.lock().unwrap().clone();
            if cmds.len() >= n || t0.elapsed() > limit {
                return cmds;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Whether every chunk of the script has been written.
    pub fn script_done(&self) -> bool {
        self.done.load(Ordering::Relaxed)
    }

    /// Unplug: the pty closes (the host's reads fail) and the link disappears.
    pub fn unplug(mut self) {
        self.stop_thread();
        let _ = std::fs::remove_file(&self.link);
    }

    fn stop_thread(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for FakeDevice {
    fn drop(&mut self) {
        self.stop_thread();
    }
}

fn write_all(fd: &OwnedFd, mut bytes: &[u8]) {
    let deadline = Instant::now() + Duration::from_secs(5);
    while !bytes.is_empty() && Instant::now() < deadline {
        match nix::unistd::write(fd, bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(nix::errno::Errno::EAGAIN) => std::thread::sleep(Duration::from_micros(200)),
            Err(_) => return,
        }
    }
}

/// Everything a driver reported, sorted by kind.
#[derive(Debug, Default)]
pub struct Collected {
    pub samples: Vec<Sample>,
    pub triggers: Vec<drivers::Trigger>,
    pub connected: Vec<String>,
    pub disconnected: Vec<String>,
    pub errors: Vec<String>,
    /// The interferometer's datum changes (reconnect, beam loss, re-reference).
    pub datum: Vec<drivers::DatumChange>,
    pub counters: Option<Counters>,
}

impl Collected {
    pub fn push(&mut self, ev: DriverEvent) {
        match ev {
            DriverEvent::Sample(s) => self.samples.push(s),
            DriverEvent::Trigger(t) => self.triggers.push(t),
            DriverEvent::Connected { identity, .. } => self.connected.push(identity),
            DriverEvent::Disconnected { reason, .. } => self.disconnected.push(reason.to_string()),
            DriverEvent::Error { error, .. } => self.errors.push(error.to_string()),
            DriverEvent::Datum { change, .. } => self.datum.push(change),
            DriverEvent::Counters { counters, .. } => self.counters = Some(counters),
        }
    }

    /// Samples of the main stream (LI-80 `$POS`, CB-3, PSD), without `$ENV`.
    pub fn stream(&self) -> impl Iterator<Item = &Sample> {
        self.samples
            .iter()
            .filter(|s| !matches!(s.values, drivers::SampleValues::Environment { .. }))
    }
}

/// Receive events into `c` until `until(c)` holds or `timeout` passes; false on timeout.
pub async fn collect_until(
    rx: &mut tokio::sync::mpsc::Receiver<DriverEvent>,
    c: &mut Collected,
    timeout: Duration,
    until: impl Fn(&Collected) -> bool,
) -> bool {
    let deadline = tokio::time::Instant::now() + timeout;
    while !until(c) {
        match tokio::time::timeout_at(deadline, rx.recv()).await {
            Ok(Some(ev)) => c.push(ev),
            Ok(None) | Err(_) => return until(c),
        }
    }
    true
}

/// Stop a driver and gather its last events (the final counters snapshot).
pub async fn finish(
    cancel: tokio_util::sync::CancellationToken,
    task: tokio::task::JoinHandle<()>,
    rx: &mut tokio::sync::mpsc::Receiver<DriverEvent>,
    c: &mut Collected,
) {
    cancel.cancel();
    let _ = tokio::time::timeout(Duration::from_secs(5), task).await;
    while let Ok(ev) = rx.try_recv() {
        c.push(ev);
    }
}

/// Instrument name for messages.
pub fn name(i: Instrument) -> &'static str {
    i.name()
}

/// Log to stderr when `RUST_LOG` is set (`RUST_LOG=drivers=debug cargo test ...`).
pub fn init_tracing() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_test_writer()
        .try_init();
}

/// Command behaviour of the scripted devices, per the data sheets (instruments.md).
pub mod fake {
    use super::Respond;

    fn cb3_text(t: &str, out: &mut Vec<u8>) {
        protocol::cb3::encode(&protocol::cb3::Frame::Text(t.into()), out);
    }

    /// CB-3: `STOP`, `ID?`, `RATE`, `START`, each answered by a text frame.
    pub fn cb3_device() -> Respond {
        Box::new(|cmd, out| match cmd {
            "STOP" => {
                cb3_text("OK", out);
                Some(false)
            }
            "ID?" => {
                cb3_text("CB-3,0042,1.3", out);
                None
            }
            c if c.starts_with("RATE ") => {
                cb3_text("OK", out);
                None
            }
            "START" => {
                cb3_text("OK", out);
                Some(true)
            }
            _ => {
                cb3_text("ERR unknown command", out);
                None
            }
        })
    }

    /// PSD-2: SCPI, no answer to commands without `?`, errors queued for `SYST:ERR?`.
    pub fn psd_device() -> Respond {
        let mut err: Vec<(i32, &'static str)> = Vec::new();
        Box::new(move |cmd, out| {
            match cmd {
                "*IDN?" => out.extend_from_slice(b"PSD-2,777,2.1\n"),
                "*OPC?" => out.extend_from_slice(b"1\n"),
                "SYST:ERR?" => {
                    let (code, text) = if err.is_empty() {
                        (0, "No error")
                    } else {
                        err.remove(0)
                    };
                    out.extend_from_slice(format!("{code},\"{text}\"\n").as_bytes());
                }
                "INIT:CONT ON" => return Some(true),
                "INIT:CONT OFF" => return Some(false),
                c if c.starts_with("CONF:RATE ") => {
                    let hz: u32 = c[10..].trim().parse().unwrap_or(0);
                    if !(1..=1000).contains(&hz) {
                        err.push((-222, "Data out of range"));
                    }
                }
                _ => err.push((-100, "Command error")),
            }
            None
        })
    }

    /// The `$ENV` record the scripted LI-80 reports.
    pub fn li80_env(seq: u32) -> protocol::li80::EnvFrame {
        protocol::li80::EnvFrame {
            seq,
            t_us: 0,
            air_c: 21.5,
            air_pa: 98_500.0,
            rh_pct: 45.0,
            material_c: vec![22.0, 23.0],
        }
    }

    /// LI-80: `*IDN?`, `RATE`, `STREAM ON/OFF`, `DATUM`, `ENV?`, one answer line each.
    pub fn li80_device() -> Respond {
        Box::new(|cmd, out| {
            match cmd {
                "*IDN?" => out.extend_from_slice(b"LI-80,80123,2.4.1\r\n"),
                "STREAM ON" => {
                    out.extend_from_slice(b"OK\r\n");
                    return Some(true);
                }
                "STREAM OFF" => {
                    out.extend_from_slice(b"OK\r\n");
                    return Some(false);
                }
                "DATUM" => out.extend_from_slice(b"OK\r\n"),
                "ENV?" => protocol::li80::encode_env(&li80_env(0), out),
                c if c.starts_with("RATE ") => match c[5..].trim().parse::<u32>() {
                    Ok(1..=10_000) => out.extend_from_slice(b"OK\r\n"),
                    _ => out.extend_from_slice(b"ERR 2 rate out of range\r\n"),
                },
                _ => out.extend_from_slice(b"ERR 1 unknown command\r\n"),
            }
            None
        })
    }

    /// `n` clean samples per device from a fresh power-up, in chunks of `per_chunk`.
    pub fn li80_script(n: u64, rate_hz: u64, per_chunk: u64) -> Vec<Vec<u8>> {
        chunked(n, per_chunk, |i, out| {
            if i > 0 && i % rate_hz == 0 {
                protocol::li80::encode_env(&li80_env((i / rate_hz) as u32), out);
            }
            let f = protocol::li80::PosFrame {
                seq: i as u32,
                t_us: i * 1_000_000 / rate_hz,
                raw_nm: (i as i64 * 7919) % 1_000_000_000 - 250_000_000,
                sig: 80,
                flags: protocol::li80::PosFlags(0),
            };
            protocol::li80::encode_pos(&f, out);
        })
    }

    pub fn cb3_script(n: u64, rate_hz: u64, per_chunk: u64) -> Vec<Vec<u8>> {
        chunked(n, per_chunk, |i, out| {
            let f = protocol::cb3::SampleFrame {
                seq: i as u16,
                t_us: (i * 1_000_000 / rate_hz) as u32,
                ch: [(i % 1000) as i32 * 3000, -((i % 777) as i32) * 9000, 12345],
                flags: 0,
            };
            protocol::cb3::encode(&protocol::cb3::Frame::Sample(f), out);
        })
    }

    pub fn psd_script(n: u64, rate_hz: u64, per_chunk: u64) -> Vec<Vec<u8>> {
        chunked(n, per_chunk, |i, out| {
            let d = protocol::psd::DataLine {
                seq: i as u32,
                t_us: i * 1_000_000 / rate_hz,
                x1_pa: 1_000_000 + i % 5000,
                x2_pa: 1_200_000,
                y1_pa: 900_000,
                y2_pa: 1_100_000 + i % 3000,
                head_mc: 21_000 + (i % 100) as i32,
            };
            protocol::psd::encode_data(&d, out);
        })
    }

    fn chunked(n: u64, per_chunk: u64, mut one: impl FnMut(u64, &mut Vec<u8>)) -> Vec<Vec<u8>> {
        let mut chunks = Vec::new();
        let mut chunk = Vec::new();
        for i in 0..n {
            one(i, &mut chunk);
            if (i + 1) % per_chunk.max(1) == 0 {
                chunks.push(std::mem::take(&mut chunk));
            }
        }
        if !chunk.is_empty() {
            chunks.push(chunk);
        }
        chunks
    }
}

/// Puts a descriptor (a pty side a test relays through) in non-blocking mode.
pub fn nonblocking(fd: &OwnedFd) {
    let flags = nix::fcntl::OFlag::from_bits_truncate(
        nix::fcntl::fcntl(fd.as_fd(), nix::fcntl::FcntlArg::F_GETFL).expect("F_GETFL"),
    );
    nix::fcntl::fcntl(
        fd.as_fd(),
        nix::fcntl::FcntlArg::F_SETFL(flags | nix::fcntl::OFlag::O_NONBLOCK),
    )
    .expect("F_SETFL");
}

/// Writes all of `b` to a non-blocking descriptor, waiting out a full buffer (EAGAIN); any
/// other error fails the test (a relay between two ptys must not lose bytes silently, unlike
/// a fake device's port, which may vanish: [`FakeDevice`]'s writes stop quietly).
pub fn relay_write(fd: &OwnedFd, mut b: &[u8]) {
    while !b.is_empty() {
        match nix::unistd::write(fd, b) {
            Ok(n) => b = &b[n..],
            Err(nix::errno::Errno::EAGAIN) => {
                std::thread::sleep(std::time::Duration::from_micros(200))
            }
            Err(e) => panic!("relay write: {e}"),
        }
    }
}

/// What a [`ModbusRelay`] does to the answer with this index (0-based).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Relay {
    Pass,
    Drop,
    CorruptCrc,
}

/// A Modbus RTU line between our side (a stable `link` to a pty our driver opens) and a peer
/// on another pty ([`ModbusRelay::peer_path`]): requests pass as they come, answers frame by
/// frame (their length from the function code and byte count, instruments.md §5) with what
/// `plan` says for each.
pub struct ModbusRelay {
    /// The pty the peer (the Modbus slave) opens.
    pub peer_path: PathBuf,
    stop: Arc<AtomicBool>,
    relayed: Arc<Mutex<Vec<Relay>>>,
    request_bytes: Arc<std::sync::atomic::AtomicUsize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ModbusRelay {
    pub fn start(
        link: &Path,
        plan: impl Fn(usize) -> Relay + Send + 'static,
    ) -> anyhow::Result<ModbusRelay> {
        let peer = pty()?;
        let ours = pty()?;
        point_link(link, &ours.path)?;
        nonblocking(&peer.master);
        nonblocking(&ours.master);
        let stop = Arc::new(AtomicBool::new(false));
        let relayed = Arc::new(Mutex::new(Vec::new()));
        let request_bytes = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let (stop2, relayed2, req2) = (stop.clone(), relayed.clone(), request_bytes.clone());
        let peer_path = peer.path.clone();
        let thread = std::thread::spawn(move || {
            let mut answer: Vec<u8> = Vec::new();
            let mut buf = [0u8; 1024];
            while !stop2.load(Ordering::Relaxed) {
                if let Ok(n) = nix::unistd::read(ours.master.as_fd(), &mut buf) {
                    req2.fetch_add(n, Ordering::Relaxed);
                    relay_write(&peer.master, &buf[..n]);
                }
                if let Ok(n) = nix::unistd::read(peer.master.as_fd(), &mut buf) {
                    answer.extend_from_slice(&buf[..n]);
                }
                while let Some(len) = answer_len(&answer) {
                    let mut frame: Vec<u8> = answer.drain(..len).collect();
                    let mut r = relayed2.lock().unwrap_or_else(|e| e.into_inner());
                    let what = plan(r.len());
                    r.push(what);
                    match what {
                        Relay::Pass => relay_write(&ours.master, &frame),
                        Relay::Drop => {}
                        Relay::CorruptCrc => {
                            frame[len - 1] ^= 0xFF;
                            relay_write(&ours.master, &frame);
                        }
                    }
                }
                std::thread::sleep(Duration::from_micros(300));
            }
        });
        Ok(ModbusRelay {
            peer_path,
            stop,
            relayed,
            request_bytes,
            thread: Some(thread),
        })
    }

    /// What was done to each answer so far, in order.
    pub fn relayed(&self) -> Vec<Relay> {
        self.relayed
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Read requests our side has sent (8 bytes each).
    pub fn requests(&self) -> usize {
        self.request_bytes.load(Ordering::Relaxed) / 8
    }

    pub fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().expect("the relay thread panicked");
        }
    }
}

/// Length of the complete answer frame at the start of `b`, if there is one: an exception
/// is 5 bytes, a read answer 5 + its byte count.
fn answer_len(b: &[u8]) -> Option<usize> {
    let len = match b.get(1)? {
        f if f & 0x80 != 0 => 5,
        _ => 5 + *b.get(2)? as usize,
    };
    (b.len() >= len).then_some(len)
}

/// Whether python3 with pymodbus and pyserial is there; without it, skip locally (with a
/// message) and fail in CI.
pub fn pymodbus_available(test: &str) -> bool {
    let ok = std::process::Command::new("python3")
        .args(["-c", "import pymodbus, serial"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "{test}: python3 with pymodbus and pyserial is required in CI (pip install pymodbus pyserial)"
        );
        eprintln!(
            "skipped: {test}: python3 with pymodbus is missing (pip install pymodbus pyserial)"
        );
    }
    ok
}
