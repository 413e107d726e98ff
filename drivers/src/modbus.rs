//! Temperature module driver: Modbus RTU over RS-485 (instruments.md §5), read with
//! `tokio-modbus`'s RTU client over `tokio-serial`.
//!
//! Every `poll_period_s` the driver reads one register per sensor (function 0x04, or 0x03 if
//! configured) and emits one [`SampleValues::Temperature`] sample: `raw · scale_c + offset_c`
//! per channel, NaN for a channel that reports a sensor fault (the sample is then invalid).
//! The module has no clock and no sequence number: `seq` numbers the samples this driver
//! delivered, `device_t_us` is the host's monotonic time of the request since the driver
//! started, `fitted_ns` the host time of the request (the module's value is at most one of its
//! conversion periods older), `host_ns` the response's arrival.
//!
//! Faults are counted in [`crate::Counters::rejections`] (one per failed transaction, none
//! lost besides it): `timeout` (no answer within `timeout_s`), `exception` (an exception
//! response; also reported once as an `Error` event, since a lasting one is a configuration
//! the operator must fix), `bad_crc` (a frame of the right length whose CRC is wrong),
//! `bad_length` (an answer that stopped short), `malformed` (bytes that are no answer to the
//! request). `tokio-modbus` itself would drop a bad-CRC frame byte by byte and then wait, and
//! stop its frame stream after too many undecodable bytes; so the port is wrapped in a
//! [`Tap`] that sees the request written and releases only a complete, CRC-checked answer to
//! it (`protocol::modbus::parse_response`), and tells the driver at once about anything else.
//! Bytes that arrive outside a transaction (a late answer after a timeout) are discarded
//! before the next request is written.
//!
//! The port lost (read error or end of file) or no answer at all for `silence_s` reports
//! `Disconnected` and reopens the port with backoff (100 ms doubling to 2 s). The device
//! counts as connected from its first answer (data or exception) on each opened port.

use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use protocol::RejectKind;
use protocol::modbus::{ReadRequest, Response, parse_request, parse_response};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::Notify;
use tokio_modbus::client::Reader;
use tokio_util::sync::CancellationToken;

use crate::reporter::EventReporter;
use crate::stamper::SampleStamper;
use crate::{DriverError, HostClock, Instrument, Sample, SampleValues};

const BACKOFF_MIN: Duration = Duration::from_millis(100);
const BACKOFF_MAX: Duration = Duration::from_secs(2);

/// Which register table the module's temperatures are in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RegisterKind {
    /// Function 0x04, Read Input Registers (the usual place for measured values).
    #[default]
    Input,
    /// Function 0x03, Read Holding Registers.
    Holding,
}

impl RegisterKind {
    pub fn function_code(self) -> u8 {
        match self {
            RegisterKind::Input => protocol::modbus::READ_INPUT,
            RegisterKind::Holding => protocol::modbus::READ_HOLDING,
        }
    }
}

/// Serial parity of the RS-485 line (the Modbus default is even; most temperature modules
/// ship set to none).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Parity {
    #[default]
    None,
    Even,
    Odd,
}

/// One sensor: channel `i` of the module is register `start_register + i`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct TempSensor {
    /// Short name, e.g. `spindle_head`, `table`, `air_x`.
    pub name: String,
    /// Where it sits on the machine, in words (kept in the run's metadata).
    #[serde(default)]
    pub location: String,
    /// A channel that is no temperature (e.g. `spindle_rpm`, the spindle drive's speed on an
    /// analogue input of the module): its unit per count, used instead of `scale_c` and
    /// `offset_c`. Its value is logged with the temperatures, in that unit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
}

/// What the daemon configures for a Modbus RTU temperature module: meant to be its
/// `[temperature]` TOML section, with `[[temperature.sensors]]` per channel.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusTempConfig {
    pub port: String,
    #[serde(default = "defaults::baud")]
    pub baud: u32,
    #[serde(default)]
    pub parity: Parity,
    /// Modbus unit (slave) address, 1–247.
    pub unit: u8,
    #[serde(default)]
    pub registers: RegisterKind,
    /// Register of channel 0 (protocol address, counted from 0).
    #[serde(default)]
    pub start_register: u16,
    /// One per channel, in register order; their count is the channel count.
    pub sensors: Vec<TempSensor>,
    /// °C per count of the signed 16-bit register (0.1 for most modules).
    #[serde(default = "defaults::scale_c")]
    pub scale_c: f64,
    /// °C added after scaling.
    #[serde(default)]
    pub offset_c: f64,
    /// Raw register values that mean a sensor fault (open or shorted sensor, out of range).
    #[serde(default = "defaults::fault_values")]
    pub fault_values: Vec<i16>,
    #[serde(default = "defaults::poll_period_s")]
    pub poll_period_s: f64,
    /// Longest wait for the answer to one request.
    #[serde(default = "defaults::timeout_s")]
    pub timeout_s: f64,
    /// No answer at all for this long: the port is reopened.
    #[serde(default = "defaults::silence_s")]
    pub silence_s: f64,
}

mod defaults {
    pub(super) fn baud() -> u32 {
        9600
    }
    pub(super) fn scale_c() -> f64 {
        0.1
    }
    pub(super) fn fault_values() -> Vec<i16> {
        vec![i16::MIN, i16::MAX]
    }
    pub(super) fn poll_period_s() -> f64 {
        1.0
    }
    pub(super) fn timeout_s() -> f64 {
        0.3
    }
    pub(super) fn silence_s() -> f64 {
        10.0
    }
}

/// A temperature module setting that cannot work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModbusConfigError {
    #[error("temperature `unit` is {0}; a Modbus unit address is 1 to 247")]
    Unit(u8),
    #[error(
        "temperature module has {0} sensors; one read takes 1 to {max}",
        max = protocol::modbus::MAX_READ_REGISTERS
    )]
    Channels(usize),
    #[error("temperature registers {start}..{end} run past register 65535")]
    Registers { start: u16, end: u32 },
    #[error("temperature `{0}` is {1}; it must be a finite number > 0")]
    NotPositive(&'static str, f64),
    #[error("temperature `{0}` is {1}; it must be finite")]
    NotFinite(&'static str, f64),
}

impl ModbusTempConfig {
    pub fn validate(&self) -> Result<(), ModbusConfigError> {
        if !(1..=247).contains(&self.unit) {
            return Err(ModbusConfigError::Unit(self.unit));
        }
        let n = self.sensors.len();
        if n == 0 || n > protocol::modbus::MAX_READ_REGISTERS as usize {
            return Err(ModbusConfigError::Channels(n));
        }
        let end = self.start_register as u32 + n as u32;
        if end > 65536 {
            return Err(ModbusConfigError::Registers {
                start: self.start_register,
                end,
            });
        }
        for (name, v) in [
            ("poll_period_s", self.poll_period_s),
            ("timeout_s", self.timeout_s),
            ("silence_s", self.silence_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ModbusConfigError::NotPositive(name, v));
            }
        }
        if !(self.scale_c.is_finite() && self.scale_c != 0.0) {
            return Err(ModbusConfigError::NotPositive("scale_c", self.scale_c));
        }
        if !self.offset_c.is_finite() {
            return Err(ModbusConfigError::NotFinite("offset_c", self.offset_c));
        }
        Ok(())
    }

    /// The read request this configuration polls with.
    pub fn request(&self) -> ReadRequest {
        ReadRequest {
            unit: self.unit,
            function: self.registers.function_code(),
            start: self.start_register,
            count: self.sensors.len() as u16,
        }
    }

    /// Registers to °C (NaN for a sensor fault) and whether every channel is valid.
    pub fn convert(&self, registers: &[u16]) -> (Vec<f64>, bool) {
        let mut valid = registers.len() == self.sensors.len();
        let values = registers
            .iter()
            .enumerate()
            .map(|(i, &r)| {
                let raw = r as i16;
                let own = self.sensors.get(i).and_then(|s| s.scale);
                if self.fault_values.contains(&raw) {
                    valid = false;
                    f64::NAN
                } else if let Some(scale) = own {
                    raw as f64 * scale
                } else {
                    raw as f64 * self.scale_c + self.offset_c
                }
            })
            .collect();
        (values, valid)
    }

    fn describe_request(&self) -> String {
        let req = self.request();
        format!(
            "read {} registers {}..{} of unit {}",
            match self.registers {
                RegisterKind::Input => "input",
                RegisterKind::Holding => "holding",
            },
            req.start,
            req.start as u32 + req.count as u32,
            req.unit
        )
    }
}

/// What the tap made of the bytes of the current transaction.
#[derive(Debug, Default)]
struct TapState {
    /// The request being written or answered (complete once 8 bytes were written).
    tx: Vec<u8>,
    req: Option<ReadRequest>,
    rx: Vec<u8>,
    /// A complete answer, CRC good, not yet handed to the reader.
    release: Vec<u8>,
    /// Final classification of this transaction's bytes, once there is one.
    verdict: Option<Response>,
    /// Bytes discarded because no transaction was waiting for them.
    stale: u64,
}

/// The port, seen through the current transaction: see the module documentation.
struct Tap<T> {
    inner: T,
    state: Arc<Mutex<TapState>>,
    bad: Arc<Notify>,
}

fn lock(s: &Mutex<TapState>) -> std::sync::MutexGuard<'_, TapState> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

impl<T: AsyncRead + Unpin> Tap<T> {
    /// Read and discard whatever the port holds now (never waits).
    fn drain(&mut self, cx: &mut Context<'_>) -> u64 {
        let mut n = 0u64;
        let mut buf = [0u8; 256];
        for _ in 0..64 {
            let mut rb = ReadBuf::new(&mut buf);
            match Pin::new(&mut self.inner).poll_read(cx, &mut rb) {
                Poll::Ready(Ok(())) if !rb.filled().is_empty() => n += rb.filled().len() as u64,
                _ => break,
            }
        }
        n
    }
}

impl<T: AsyncRead + AsyncWrite + Unpin> AsyncWrite for Tap<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let me = &mut *self;
        let new_request = {
            let s = lock(&me.state);
            s.tx.is_empty() || s.req.is_some() || s.tx.len() >= 8
        };
        if new_request {
            let stale = me.drain(cx);
            let mut s = lock(&me.state);
            *s = TapState {
                stale: s.stale + stale,
                ..TapState::default()
            };
        }
        let r = Pin::new(&mut me.inner).poll_write(cx, buf);
        if let Poll::Ready(Ok(n)) = r {
            let mut s = lock(&me.state);
            s.tx.extend_from_slice(&buf[..n]);
            if let protocol::modbus::RequestParse::Request { req, .. } = parse_request(&s.tx) {
                s.req = Some(req);
            }
        }
        r
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for Tap<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        out: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let me = &mut *self;
        let mut buf = [0u8; 256];
        loop {
            {
                let mut s = lock(&me.state);
                if !s.release.is_empty() {
                    let n = s.release.len().min(out.remaining());
                    out.put_slice(&s.release[..n]);
                    s.release.drain(..n);
                    return Poll::Ready(Ok(()));
                }
            }
            let mut rb = ReadBuf::new(&mut buf);
            match Pin::new(&mut me.inner).poll_read(cx, &mut rb) {
                Poll::Pending => return Poll::Pending,
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                // End of file: hand it on.
                Poll::Ready(Ok(())) if rb.filled().is_empty() => return Poll::Ready(Ok(())),
                Poll::Ready(Ok(())) => {}
            }
            let mut s = lock(&me.state);
            let Some(req) = s.req else {
                s.stale += rb.filled().len() as u64;
                continue;
            };
            if s.verdict.is_some() {
                continue;
            }
            s.rx.extend_from_slice(rb.filled());
            match parse_response(&req, &s.rx) {
                Response::Nothing | Response::Truncated => {}
                ok @ (Response::Registers(_) | Response::Exception(_)) => {
                    s.release = std::mem::take(&mut s.rx);
                    s.verdict = Some(ok);
                }
                bad => {
                    s.verdict = Some(bad);
                    me.bad.notify_waiters();
                }
            }
        }
    }
}

/// How one transaction ended.
enum Outcome {
    Registers(Vec<u16>),
    Exception(u8),
    /// Counted, no sample; the device did answer (with bytes).
    Garbled(RejectKind),
    Timeout,
    /// The port failed.
    Lost(DriverError),
}

async fn transact(
    ctx: &mut tokio_modbus::client::Context,
    cfg: &ModbusTempConfig,
    tap: &(Arc<Mutex<TapState>>, Arc<Notify>),
) -> Outcome {
    let (state, bad) = tap;
    let req = cfg.request();
    let timeout = Duration::from_secs_f64(cfg.timeout_s);
    // Created before the request is written, so a verdict during the call is not missed.
    let notified = bad.notified();
    let call = async {
        match cfg.registers {
            RegisterKind::Input => ctx.read_input_registers(req.start, req.count).await,
            RegisterKind::Holding => ctx.read_holding_registers(req.start, req.count).await,
        }
    };
    let r = tokio::select! {
        r = call => Some(r),
        _ = notified => None,
        _ = tokio::time::sleep(timeout) => None,
    };
    match r {
        Some(Ok(Ok(regs))) => Outcome::Registers(regs),
        Some(Ok(Err(code))) => Outcome::Exception(code.into()),
        Some(Err(tokio_modbus::Error::Transport(e))) => {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                Outcome::Lost(DriverError::EndOfFile)
            } else {
                Outcome::Lost(DriverError::ReadFailed { cause: Arc::new(e) })
            }
        }
        // The tap releases only answers with our unit and function; kept for completeness.
        Some(Err(tokio_modbus::Error::Protocol(_))) => Outcome::Garbled(RejectKind::Malformed),
        None => {
            let s = lock(state);
            match s.verdict {
                Some(Response::BadCrc) => Outcome::Garbled(RejectKind::BadCrc),
                Some(Response::Malformed) => Outcome::Garbled(RejectKind::Malformed),
                _ if !s.rx.is_empty() => Outcome::Garbled(RejectKind::BadLength),
                _ => Outcome::Timeout,
            }
        }
    }
}

fn open(cfg: &ModbusTempConfig) -> std::io::Result<tokio_serial::SerialStream> {
    let parity = match cfg.parity {
        Parity::None => tokio_serial::Parity::None,
        Parity::Even => tokio_serial::Parity::Even,
        Parity::Odd => tokio_serial::Parity::Odd,
    };
    let builder = tokio_serial::new(&cfg.port, cfg.baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(parity)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None);
    let port = tokio_serial::SerialStream::open(&builder).map_err(std::io::Error::from)?;
    tokio_serial::SerialPort::clear(&port, tokio_serial::ClearBuffer::All)
        .map_err(std::io::Error::from)?;
    Ok(port)
}

/// Start the temperature module's driver task. The configuration must be valid
/// ([`ModbusTempConfig::validate`]); an invalid one is reported as an `Error` event and the
/// task ends.
pub fn spawn_modbus_temperature(
    cfg: ModbusTempConfig,
    clock: HostClock,
    tx: crate::EventSender,
    cancel: CancellationToken,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(run(cfg, clock, tx, cancel))
}

async fn run(
    cfg: ModbusTempConfig,
    clock: HostClock,
    tx: crate::EventSender,
    cancel: CancellationToken,
) {
    let mut rep = EventReporter::new(Instrument::Thermometer, &cfg.port, clock, tx);
    // No device clock to fit: the stamper only answers `drift_ppm` (None) for the counters.
    let stamper = SampleStamper::new(64, 64);
    if let Err(e) = cfg.validate() {
        rep.error(DriverError::UnexpectedAnswer {
            port: cfg.port.clone(),
            command: "configuration".into(),
            answer: e.to_string(),
        });
        return;
    }
    let start = tokio::time::Instant::now();
    let period = Duration::from_secs_f64(cfg.poll_period_s);
    let silence = Duration::from_secs_f64(cfg.silence_s);
    let mut seq = 0u64;
    let mut backoff = BACKOFF_MIN;
    let mut open_failures = 0u32;
    'connection: loop {
        if cancel.is_cancelled() {
            break;
        }
        let port = match open(&cfg) {
            Ok(p) => p,
            Err(e) => {
                if open_failures == 0 {
                    tracing::warn!(port = %cfg.port, "cannot open the port ({e}); retrying with backoff");
                }
                open_failures += 1;
                tokio::select! {
                    _ = cancel.cancelled() => break,
                    _ = tokio::time::sleep(backoff) => {}
                }
                backoff = (backoff * 2).min(BACKOFF_MAX);
                continue;
            }
        };
        open_failures = 0;
        let tap_state = (
            Arc::new(Mutex::new(TapState::default())),
            Arc::new(Notify::new()),
        );
        let tap = Tap {
            inner: port,
            state: tap_state.0.clone(),
            bad: tap_state.1.clone(),
        };
        let mut ctx = tokio_modbus::client::rtu::attach_slave(tap, tokio_modbus::Slave(cfg.unit));
        rep.accepting = false;
        let mut last_answer = tokio::time::Instant::now();
        let mut last_counters = tokio::time::Instant::now();
        let mut ticker = tokio::time::interval(period);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                _ = cancel.cancelled() => break 'connection,
                _ = ticker.tick() => {}
            }
            let req_ns = rep.clock.now_ns();
            let req_t = tokio::time::Instant::now();
            let outcome = transact(&mut ctx, &cfg, &tap_state).await;
            let answered = !matches!(outcome, Outcome::Timeout | Outcome::Lost(_));
            if answered {
                last_answer = tokio::time::Instant::now();
                if !rep.accepting {
                    rep.accepting = true;
                    backoff = BACKOFF_MIN;
                    let identity = format!(
                        "Modbus RTU temperature module, unit {}, {} channels ({})",
                        cfg.unit,
                        cfg.sensors.len(),
                        cfg.describe_request()
                    );
                    rep.connected(identity, &stamper);
                }
            }
            let mut force = false;
            match outcome {
                Outcome::Registers(regs) => {
                    let (values_c, valid) = cfg.convert(&regs);
                    let sample = Sample {
                        instrument: Instrument::Thermometer,
                        seq,
                        device_t_us: req_t.duration_since(start).as_micros() as u64,
                        host_ns: rep.clock.now_ns(),
                        fitted_ns: req_ns,
                        valid,
                        values: SampleValues::Temperature { values_c },
                    };
                    seq += 1;
                    rep.emit_sample(sample, &stamper);
                }
                Outcome::Exception(code) => {
                    rep.reject(RejectKind::Exception, 5);
                    rep.error(DriverError::UnexpectedAnswer {
                        port: cfg.port.clone(),
                        command: cfg.describe_request(),
                        answer: format!("exception {code:02X} ({})", exception_text(code)),
                    });
                    force = true;
                }
                Outcome::Garbled(kind) => {
                    tracing::debug!(port = %cfg.port, ?kind, "answer rejected");
                    rep.reject(kind, lock(&tap_state.0).rx.len());
                    force = true;
                }
                Outcome::Timeout => {
                    tracing::debug!(port = %cfg.port, "no answer within {} s", cfg.timeout_s);
                    rep.reject(RejectKind::Timeout, 0);
                    force = true;
                    if !rep.accepting {
                        rep.error(DriverError::NoAnswer {
                            port: cfg.port.clone(),
                            command: cfg.describe_request(),
                            timeout: Duration::from_secs_f64(cfg.timeout_s),
                        });
                    }
                    if last_answer.elapsed() >= silence {
                        let idle = last_answer.elapsed();
                        if rep.accepting {
                            rep.disconnected(DriverError::Silent { idle }, &stamper);
                        }
                        break;
                    }
                }
                Outcome::Lost(e) => {
                    if rep.accepting {
                        rep.disconnected(e, &stamper);
                    } else {
                        tracing::warn!(port = %cfg.port, "port failed before the module answered: {e}");
                    }
                    break;
                }
            }
            if force || last_counters.elapsed() >= Duration::from_secs(1) {
                last_counters = tokio::time::Instant::now();
                rep.tick(true, &stamper);
            }
        }
        drop(ctx);
        tokio::select! {
            _ = cancel.cancelled() => break,
            _ = tokio::time::sleep(backoff) => {}
        }
        backoff = (backoff * 2).min(BACKOFF_MAX);
    }
    rep.tick(true, &stamper);
}

/// The exception codes' meanings (Modbus application protocol, 7).
fn exception_text(code: u8) -> &'static str {
    use protocol::modbus::exception::*;
    match code {
        ILLEGAL_FUNCTION => "illegal function",
        ILLEGAL_DATA_ADDRESS => "illegal data address",
        ILLEGAL_DATA_VALUE => "illegal data value",
        DEVICE_FAILURE => "device failure",
        DEVICE_BUSY => "device busy",
        _ => "other",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> ModbusTempConfig {
        toml_like(
            r#"{"port": "/dev/ttyUSB0", "unit": 3,
                "sensors": [{"name": "a", "location": "table"}, {"name": "b"}, {"name": "c"}]}"#,
        )
    }

    fn toml_like(json: &str) -> ModbusTempConfig {
        serde_json::from_str(json).unwrap()
    }

    #[test]
    fn config_defaults_and_conversion() {
        let c = cfg();
        c.validate().unwrap();
        assert_eq!(c.baud, 9600);
        assert_eq!(c.registers, RegisterKind::Input);
        assert_eq!(
            c.request(),
            ReadRequest {
                unit: 3,
                function: 4,
                start: 0,
                count: 3
            }
        );
        let (v, ok) = c.convert(&[215, (-52i16) as u16, 0x8000]);
        assert!(!ok);
        assert!((v[0] - 21.5).abs() < 1e-12 && (v[1] + 5.2).abs() < 1e-12 && v[2].is_nan());
        let (v, ok) = c.convert(&[0x7FFE, 0, 1]);
        assert!(ok && (v[0] - 3276.6).abs() < 1e-9);
    }

    #[test]
    fn a_channel_with_its_own_scale_ignores_the_modules() {
        // The spindle speed on an analogue input, 1 rpm per count, beside 0.01 °C channels.
        let c = toml_like(
            r#"{"port": "x", "unit": 1, "scale_c": 0.01, "offset_c": 5.0,
                "sensors": [{"name": "head"}, {"name": "spindle_rpm", "scale": 1.0}]}"#,
        );
        let (v, ok) = c.convert(&[1500, 4000]);
        assert!(ok && (v[0] - 20.0).abs() < 1e-12, "{v:?}");
        assert_eq!(v[1], 4000.0);
        // A fault value is a fault on that channel too.
        let (v, ok) = c.convert(&[1500, 0x8000]);
        assert!(!ok && v[1].is_nan());
    }

    #[test]
    fn config_rejects_unknown_fields_and_bad_values() {
        assert!(
            serde_json::from_str::<ModbusTempConfig>(
                r#"{"port": "x", "unit": 1, "sensors": [], "rate_hz": 5}"#
            )
            .is_err()
        );
        let mut c = cfg();
        c.unit = 0;
        assert_eq!(c.validate(), Err(ModbusConfigError::Unit(0)));
        let mut c = cfg();
        c.sensors.clear();
        assert_eq!(c.validate(), Err(ModbusConfigError::Channels(0)));
        let mut c = cfg();
        c.start_register = 65534;
        assert!(matches!(
            c.validate(),
            Err(ModbusConfigError::Registers { .. })
        ));
        let mut c = cfg();
        c.poll_period_s = 0.0;
        assert!(matches!(
            c.validate(),
            Err(ModbusConfigError::NotPositive(..))
        ));
    }
}
