#![allow(dead_code)]
//! Helpers of the device tests: a runtime, a port opened as a driver would, reads with
//! deadlines.

use std::path::Path;
use std::time::{Duration, Instant};

use serialport::SerialPort;
use sim::scenario::{PoseRow, Scenario};

pub struct Env {
    pub rt: tokio::runtime::Runtime,
    pub dir: tempfile::TempDir,
    pub sim: Option<sim::SimHandle>,
}

impl Env {
    pub fn start(scenario: Scenario) -> Env {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let sim = {
            let _g = rt.enter();
            sim::Sim::start(scenario, dir.path()).unwrap()
        };
        Env {
            rt,
            dir,
            sim: Some(sim),
        }
    }
    pub fn sim(&self) -> &sim::SimHandle {
        self.sim.as_ref().unwrap()
    }
    pub fn open(&self, d: sim::Device) -> Box<dyn SerialPort> {
        open(&self.sim().port(d))
    }
}

impl Drop for Env {
    fn drop(&mut self) {
        if let Some(s) = self.sim.take() {
            self.rt.block_on(s.shutdown());
        }
    }
}

pub fn open(path: &Path) -> Box<dyn SerialPort> {
    serialport::new(path.to_string_lossy(), 921_600)
        .timeout(Duration::from_millis(20))
        .open()
        .unwrap()
}

/// Read everything arriving within `dur`.
pub fn read_for(p: &mut dyn SerialPort, dur: Duration) -> Vec<u8> {
    let end = Instant::now() + dur;
    let mut out = Vec::new();
    let mut buf = [0u8; 8192];
    while Instant::now() < end {
        match p.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => out.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("read failed: {e}"),
        }
    }
    out
}

/// Read until `done(bytes)` or the timeout.
pub fn read_until(
    p: &mut dyn SerialPort,
    timeout: Duration,
    done: impl Fn(&[u8]) -> bool,
) -> Vec<u8> {
    let end = Instant::now() + timeout;
    let mut out = Vec::new();
    let mut buf = [0u8; 8192];
    while Instant::now() < end && !done(&out) {
        match p.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => out.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("read failed: {e}"),
        }
    }
    out
}

/// Read until nothing arrives for `quiet`.
pub fn drain(p: &mut dyn SerialPort, quiet: Duration) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; 8192];
    let mut last = Instant::now();
    while last.elapsed() < quiet {
        match p.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                out.extend_from_slice(&buf[..n]);
                last = Instant::now();
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("read failed: {e}"),
        }
    }
    out
}

pub fn send(p: &mut dyn SerialPort, s: &str) {
    p.write_all(s.as_bytes()).unwrap();
    p.flush().unwrap();
}

/// Send a command and return the bytes that came back within `wait`.
pub fn ask(p: &mut dyn SerialPort, s: &str, done: impl Fn(&[u8]) -> bool) -> Vec<u8> {
    send(p, s);
    read_until(p, Duration::from_secs(2), done)
}

pub fn ends_with(suffix: &'static [u8]) -> impl Fn(&[u8]) -> bool {
    move |b: &[u8]| b.ends_with(suffix)
}

/// A short scenario: home, then two poses along X, quick moves, no faults.
pub fn quick() -> Scenario {
    let mut s = Scenario::demo();
    s.faults = Default::default();
    s.program.lead_in_s = 0.1;
    s.program.lead_out_s = 0.1;
    s.program.move_s = 0.1;
    s.program.dwell_s = 0.3;
    let row = |x: f64| PoseRow {
        pose: None,
        x_mm: x,
        y_mm: 0.0,
        z_mm: 0.0,
        a_deg: 0.0,
        c_deg: 0.0,
        move_s: None,
        dwell_s: None,
    };
    s.program.poses = vec![row(101.871), row(198.544)];
    s
}
