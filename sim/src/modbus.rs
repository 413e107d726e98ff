//! A simulated Modbus RTU temperature module (docs/instruments.md §5) on a pseudo-terminal:
//! the slave side of the data sheet, written here from it (requests parsed, answers encoded by
//! `protocol::modbus`), independent of the driver's client (`tokio-modbus`).
//!
//! The temperatures come from a function of the seconds since the module started, given at
//! construction (`None` for a channel is a sensor fault: the register reads 0x8000). Faults
//! are injected per request ([`ModbusFault`]): no answer (the host times out), an exception
//! response, or the right answer with a wrong CRC. Every request addressed to the module is
//! recorded with what it got ([`Answered`]), so a test can check each sample and each fault.
//!
//! RTU framing: a request is taken once its 8 bytes have a good CRC; bytes that do not make
//! one are dropped one at a time, and a partial frame followed by a 3.5-character silence is
//! discarded. The module answers no sooner than 3.5 characters after the request, answers
//! nothing to another unit or to broadcasts, and answers exception 01 to another function,
//! 02 to registers it does not have, 03 to a count of 0 or more than 125.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use protocol::modbus::{
    MAX_READ_REGISTERS, ReadRequest, RequestParse, encode_exception, encode_read_response,
    exception, frame_gap_us, parse_request,
};
use tokio::sync::mpsc;

use crate::pty::{Pty, ReadOutcome};

/// The module's settings (as set on its front panel or by its vendor's tool).
#[derive(Debug, Clone, PartialEq)]
pub struct ModbusModuleConfig {
    pub unit: u8,
    /// The function the module answers (0x04 or 0x03); the other gets exception 01.
    pub function: u8,
    pub start_register: u16,
    pub channels: u16,
    /// °C per count and offset: `register = round((t − offset_c) / scale_c)`.
    pub scale_c: f64,
    pub offset_c: f64,
    /// The register value of a faulty sensor.
    pub fault_value: u16,
    /// Sets the 3.5-character gap (the pty itself ignores the baud rate).
    pub baud: u32,
    /// Per channel, a scale (its unit per count, no offset) instead of `scale_c`: a channel
    /// that is no temperature, e.g. the spindle speed on an analogue input. Empty: none.
    pub channel_scales: Vec<Option<f64>>,
}

impl Default for ModbusModuleConfig {
    fn default() -> Self {
        ModbusModuleConfig {
            unit: 1,
            function: protocol::modbus::READ_INPUT,
            start_register: 0,
            channels: 4,
            scale_c: 0.1,
            offset_c: 0.0,
            fault_value: 0x8000,
            baud: 9600,
            channel_scales: Vec::new(),
        }
    }
}

/// Temperatures, °C, per channel at `t` seconds since the module started (`None`: sensor
/// fault). A shorter vector leaves the remaining channels faulty.
pub type Temperatures = Arc<dyn Fn(f64) -> Vec<Option<f64>> + Send + Sync>;

/// What to do to the next request addressed to the module.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModbusFault {
    /// No fault: answer as the data sheet says (a placeholder in a fault sequence).
    Answer,
    /// Say nothing.
    NoAnswer,
    /// Answer with this exception code.
    Exception(u8),
    /// Answer the registers with the CRC's last byte flipped.
    BadCrc,
}

/// What the module did with one request addressed to it.
#[derive(Debug, Clone, PartialEq)]
pub struct Answered {
    /// Seconds since the module started, when the request was complete.
    pub t_s: f64,
    pub request: ReadRequest,
    pub reply: Reply,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    Registers(Vec<u16>),
    Exception(u8),
    Silent,
    /// These registers, sent with a wrong CRC.
    BadCrc(Vec<u16>),
}

enum Cmd {
    Shutdown,
}

/// A running simulated module. Dropping it aborts the task (and closes the pty).
pub struct ModbusModule {
    link: PathBuf,
    pts: PathBuf,
    faults: Arc<Mutex<std::collections::VecDeque<ModbusFault>>>,
    log: Arc<Mutex<Vec<Answered>>>,
    ctl: mpsc::Sender<Cmd>,
    task: Option<tokio::task::JoinHandle<()>>,
}

impl ModbusModule {
    /// Start the module behind the symlink `link` (created or replaced). Must be called inside
    /// a tokio runtime.
    pub fn start(
        link: &Path,
        cfg: ModbusModuleConfig,
        temperatures: Temperatures,
    ) -> std::io::Result<ModbusModule> {
        let pty = Pty::open(link)?;
        let pts = pty.pts().to_path_buf();
        let faults = Arc::new(Mutex::new(std::collections::VecDeque::new()));
        let log = Arc::new(Mutex::new(Vec::new()));
        let (ctl, rx) = mpsc::channel(1);
        let slave = Slave {
            cfg,
            temperatures,
            faults: faults.clone(),
            log: log.clone(),
            t0: Instant::now(),
        };
        let task = tokio::spawn(slave.run(pty, rx));
        Ok(ModbusModule {
            link: link.to_path_buf(),
            pts,
            faults,
            log,
            ctl,
            task: Some(task),
        })
    }

    /// The stable link (what the host opens).
    pub fn port(&self) -> &Path {
        &self.link
    }

    /// The `/dev/pts/N` behind it.
    pub fn pts(&self) -> &Path {
        &self.pts
    }

    /// Apply these faults to the next requests addressed to the module, one each, in order.
    pub fn inject(&self, faults: impl IntoIterator<Item = ModbusFault>) {
        lock(&self.faults).extend(faults);
    }

    /// Faults injected and not yet applied.
    pub fn pending_faults(&self) -> usize {
        lock(&self.faults).len()
    }

    /// Every request addressed to the module so far, with its reply.
    pub fn answered(&self) -> Vec<Answered> {
        lock(&self.log).clone()
    }

    /// Stop the module: pty closed, link removed.
    pub async fn shutdown(mut self) {
        let _ = self.ctl.send(Cmd::Shutdown).await;
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
    }
}

impl Drop for ModbusModule {
    fn drop(&mut self) {
        if let Some(t) = &self.task {
            t.abort();
            let _ = std::fs::remove_file(&self.link);
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

struct Slave {
    cfg: ModbusModuleConfig,
    temperatures: Temperatures,
    faults: Arc<Mutex<std::collections::VecDeque<ModbusFault>>>,
    log: Arc<Mutex<Vec<Answered>>>,
    t0: Instant,
}

/// How often the module looks at its port: well under the 3.5-character gap at 9600 baud.
const POLL: Duration = Duration::from_millis(1);

impl Slave {
    async fn run(self, pty: Pty, mut ctl: mpsc::Receiver<Cmd>) {
        let gap = Duration::from_micros(frame_gap_us(self.cfg.baud));
        let mut buf = Vec::<u8>::new();
        let mut last_byte = Instant::now();
        let mut chunk = [0u8; 512];
        loop {
            tokio::select! {
                c = ctl.recv() => match c {
                    Some(Cmd::Shutdown) | None => break,
                },
                _ = tokio::time::sleep(POLL) => {}
            }
            let mut got = false;
            while let ReadOutcome::Data(n) = pty.try_read(&mut chunk) {
                if !got && !buf.is_empty() && last_byte.elapsed() > gap {
                    // A frame that stopped short: the silence ended it.
                    buf.clear();
                }
                got = true;
                buf.extend_from_slice(&chunk[..n]);
                last_byte = Instant::now();
            }
            if !got && !buf.is_empty() && last_byte.elapsed() > gap {
                buf.clear();
            }
            loop {
                match parse_request(&buf) {
                    RequestParse::Incomplete => break,
                    RequestParse::BadCrc => {
                        buf.remove(0);
                    }
                    RequestParse::Request { req, len } => {
                        buf.drain(..len);
                        if let Some(bytes) = self.answer(req) {
                            // Turnaround: the answer starts after a 3.5-character silence.
                            tokio::time::sleep(gap).await;
                            write_all(&pty, &bytes).await;
                        }
                    }
                }
            }
        }
        pty.unplug();
    }

    /// The reply to `req` (None: silence), recorded.
    fn answer(&self, req: ReadRequest) -> Option<Vec<u8>> {
        let c = &self.cfg;
        if req.unit != c.unit {
            return None;
        }
        let t_s = self.t0.elapsed().as_secs_f64();
        let end = c.start_register as u32 + c.channels as u32;
        let code = if req.function != c.function {
            Some(exception::ILLEGAL_FUNCTION)
        } else if req.count == 0 || req.count > MAX_READ_REGISTERS {
            Some(exception::ILLEGAL_DATA_VALUE)
        } else if req.start < c.start_register || req.start as u32 + req.count as u32 > end {
            Some(exception::ILLEGAL_DATA_ADDRESS)
        } else {
            None
        };
        let regs = || {
            let temps = (self.temperatures)(t_s);
            let first = (req.start - c.start_register) as usize;
            (first..first + req.count as usize)
                .map(|i| match temps.get(i).copied().flatten() {
                    Some(t) if t.is_finite() => encode(t, c, i),
                    _ => c.fault_value,
                })
                .collect::<Vec<u16>>()
        };
        let fault = lock(&self.faults).pop_front();
        let (reply, bytes) = match (fault, code) {
            (Some(ModbusFault::NoAnswer), _) => (Reply::Silent, None),
            (Some(ModbusFault::Exception(e)), _) | (_, Some(e)) => (
                Reply::Exception(e),
                Some(encode_exception(c.unit, req.function, e)),
            ),
            (Some(ModbusFault::BadCrc), None) => {
                let r = regs();
                let mut b = encode_read_response(c.unit, req.function, &r);
                *b.last_mut().expect("a frame has a CRC") ^= 0x5A;
                (Reply::BadCrc(r), Some(b))
            }
            (None | Some(ModbusFault::Answer), None) => {
                let r = regs();
                let b = encode_read_response(c.unit, req.function, &r);
                (Reply::Registers(r), Some(b))
            }
        };
        lock(&self.log).push(Answered {
            t_s,
            request: req,
            reply,
        });
        bytes
    }
}

/// A temperature as the module's register: signed 16 bit, clamped short of the fault values.
fn encode(t: f64, c: &ModbusModuleConfig, channel: usize) -> u16 {
    let raw = match c.channel_scales.get(channel).copied().flatten() {
        Some(scale) => (t / scale).round(),
        None => ((t - c.offset_c) / c.scale_c).round(),
    };
    (raw.clamp(-32767.0, 32766.0) as i16) as u16
}

async fn write_all(pty: &Pty, mut bytes: &[u8]) {
    for _ in 0..1000 {
        if bytes.is_empty() {
            return;
        }
        match pty.try_write(bytes) {
            Ok(n) => bytes = &bytes[n..],
            Err(_) => return,
        }
        if !bytes.is_empty() {
            tokio::time::sleep(POLL).await;
        }
    }
}
