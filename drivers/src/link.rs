//! What every serial driver shares: the port with its decoder and answer routing, the
//! per-instrument bookkeeping (counters, sequence and clock unwrapping, clock fit, event
//! delivery), and the connect / configure / stream / reconnect loop.

use std::collections::VecDeque;
use std::time::Duration;

use protocol::{Decoded, RejectKind, StreamDecoder};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc::error::TrySendError;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use crate::clock::{ClockFit, Unwrap};
use crate::{Counters, DriverEvent, EventSender, HostClock, Instrument, Sample};

/// How long a command waits for its answer.
/// The LI-80 and CB-3 acknowledge a command with a plain `OK` (instruments.md §1, §2).
pub(crate) fn is_ok(answer: &str) -> bool {
    answer.trim() == "OK"
}

pub(crate) const ANSWER_TIMEOUT: Duration = Duration::from_secs(1);
/// First and longest wait between attempts to open a vanished port.
const BACKOFF_MIN: Duration = Duration::from_millis(100);
const BACKOFF_MAX: Duration = Duration::from_secs(2);
/// Read buffer: large, so that one read takes everything the kernel holds.
const READ_BUF: usize = 64 * 1024;
/// While streaming, a read that returned less than this lets the next read wait a little so
/// that bytes accumulate: at 20 kHz the CB-3 otherwise wakes the driver for every frame.
const BATCH_BYTES: usize = 2048;
const BATCH_WAIT: Duration = Duration::from_millis(10);
/// Every this many batched reads, one read waits for the next bytes without the batching
/// pause: its arrival time is then the write time plus the wake-up latency only, which gives
/// the clock fit ([`crate::clock`]) the least-delayed points it needs (a batched read dates
/// everything in it by the read, up to `BATCH_WAIT` late).
const PROBE_EVERY: u32 = 2;

/// Why a session ended.
#[derive(Debug)]
pub(crate) enum SessionError {
    /// The port failed or went silent: report `Disconnected`, reopen with backoff.
    Lost(String),
    /// The device refused or ignored a command: report `Error`, retry after a backoff.
    Device(String),
    Cancelled,
}

/// Consumes what a decoder yields. Returns the text of an answer line so it can be routed to
/// the command waiting for it.
pub(crate) trait Handler {
    type Dec: StreamDecoder + Send;
    fn on_item(
        &mut self,
        item: Decoded<<Self::Dec as StreamDecoder>::Frame>,
        host_ns: u64,
    ) -> Option<String>;
}

/// One open port with its decoder.
pub(crate) struct Link<D> {
    port: tokio_serial::SerialStream,
    dec: D,
    buf: Box<[u8]>,
    answers: VecDeque<String>,
    clock: HostClock,
    pub(crate) path: String,
}

pub(crate) fn open_port(path: &str, baud: u32) -> std::io::Result<tokio_serial::SerialStream> {
    let builder = tokio_serial::new(path, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None);
    let port = tokio_serial::SerialStream::open(&builder).map_err(std::io::Error::from)?;
    // Whatever the device sent before we looked is stale.
    port.clear(tokio_serial::ClearBuffer::All)
        .map_err(std::io::Error::from)?;
    Ok(port)
}

impl<D: StreamDecoder + Send> Link<D> {
    pub(crate) fn new(
        port: tokio_serial::SerialStream,
        dec: D,
        clock: HostClock,
        path: &str,
    ) -> Self {
        Link {
            port,
            dec,
            buf: vec![0u8; READ_BUF].into_boxed_slice(),
            answers: VecDeque::new(),
            clock,
            path: path.to_string(),
        }
    }

    /// Read once (whatever is there), feed the decoder, route answers. Returns the byte count.
    /// Cancel-safe: the only await is the read itself.
    pub(crate) async fn read_once<H: Handler<Dec = D>>(
        &mut self,
        h: &mut H,
    ) -> Result<usize, SessionError> {
        let n = match self.port.read(&mut self.buf).await {
            Ok(0) => return Err(SessionError::Lost("end of file on the port".into())),
            Ok(n) => n,
            Err(e) => return Err(SessionError::Lost(format!("read failed: {e}"))),
        };
        let host_ns = self.clock.now_ns();
        let Link {
            dec, buf, answers, ..
        } = self;
        dec.feed(&buf[..n], |item| {
            if let Some(a) = h.on_item(item, host_ns) {
                answers.push_back(a);
            }
        });
        Ok(n)
    }

    /// Write a command line (with its terminator) that has no answer.
    pub(crate) async fn send(&mut self, line: &str) -> Result<(), SessionError> {
        self.port
            .write_all(line.as_bytes())
            .await
            .map_err(|e| SessionError::Lost(format!("write of `{}` failed: {e}", line.trim())))?;
        self.port
            .flush()
            .await
            .map_err(|e| SessionError::Lost(format!("flush failed: {e}")))
    }

    /// Send a command and wait for its answer line, data lines being handled meanwhile.
    pub(crate) async fn command<H: Handler<Dec = D>>(
        &mut self,
        h: &mut H,
        line: &str,
    ) -> Result<String, SessionError> {
        self.answers.clear();
        self.send(line).await?;
        let deadline = tokio::time::Instant::now() + ANSWER_TIMEOUT;
        loop {
            if let Some(a) = self.answers.pop_front() {
                return Ok(a);
            }
            match tokio::time::timeout_at(deadline, self.read_once(h)).await {
                Ok(r) => {
                    r?;
                }
                Err(_) => {
                    return Err(SessionError::Device(format!(
                        "port {}: no answer to `{}` within {} s",
                        self.path,
                        line.trim(),
                        ANSWER_TIMEOUT.as_secs_f64()
                    )));
                }
            }
        }
    }

    /// Send a command whose answer must satisfy `ok`; otherwise a clear device error.
    pub(crate) async fn expect<H: Handler<Dec = D>>(
        &mut self,
        h: &mut H,
        line: &str,
        ok: impl Fn(&str) -> bool,
    ) -> Result<String, SessionError> {
        let a = self.command(h, line).await?;
        if ok(&a) {
            Ok(a)
        } else {
            Err(SessionError::Device(format!(
                "port {}: command `{}` answered `{}`",
                self.path,
                line.trim(),
                a.escape_debug()
            )))
        }
    }

    /// Keep reading until `done` holds for the handler (e.g. an `$ENV` line came), or time out.
    pub(crate) async fn wait_for<H: Handler<Dec = D>>(
        &mut self,
        h: &mut H,
        what: &str,
        done: impl Fn(&H) -> bool,
    ) -> Result<(), SessionError> {
        let deadline = tokio::time::Instant::now() + ANSWER_TIMEOUT;
        while !done(h) {
            match tokio::time::timeout_at(deadline, self.read_once(h)).await {
                Ok(r) => {
                    r?;
                }
                Err(_) => {
                    return Err(SessionError::Device(format!(
                        "port {}: no {what} within {} s",
                        self.path,
                        ANSWER_TIMEOUT.as_secs_f64()
                    )));
                }
            }
        }
        Ok(())
    }

    /// Forget partial input (after stopping a stream that was running when we opened).
    pub(crate) fn reset_decoder(&mut self) {
        self.dec.reset();
        self.answers.clear();
    }
}

/// Per-instrument bookkeeping shared by the drivers.
pub(crate) struct Acq {
    pub(crate) instrument: Instrument,
    pub(crate) port: String,
    tx: EventSender,
    pub(crate) clock: HostClock,
    pub(crate) counters: Counters,
    fit: ClockFit,
    seq: Unwrap,
    dev_t: Unwrap,
    /// Samples per device µs, to resolve sequence wraps across long gaps.
    rate_per_us: Option<f64>,
    last_counters_ns: u64,
    last_error: Option<String>,
    /// Data frames become samples only once streaming was started by us; what a device sends
    /// before that (it may have been streaming when the port opened) is discarded uncounted.
    pub(crate) accepting: bool,
    was_connected: bool,
}

impl Acq {
    pub(crate) fn new(
        instrument: Instrument,
        port: &str,
        seq_bits: u32,
        t_bits: u32,
        clock: HostClock,
        tx: EventSender,
    ) -> Self {
        Acq {
            instrument,
            port: port.to_string(),
            tx,
            clock,
            counters: Counters::default(),
            fit: ClockFit::default(),
            seq: Unwrap::new(seq_bits),
            dev_t: Unwrap::new(t_bits),
            rate_per_us: None,
            last_counters_ns: 0,
            last_error: None,
            accepting: false,
            was_connected: false,
        }
    }

    pub(crate) fn set_rate(&mut self, rate_hz: u32) {
        self.rate_per_us = (rate_hz > 0).then_some(rate_hz as f64 * 1e-6);
    }

    /// A new connection: the device may have restarted its sequence and clock.
    pub(crate) fn on_open(&mut self) {
        self.seq.reset();
        self.dev_t.reset();
        self.fit.reset();
        self.accepting = false;
    }

    fn send(&mut self, ev: DriverEvent) -> bool {
        match self.tx.try_send(ev) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) | Err(TrySendError::Closed(_)) => false,
        }
    }

    /// Unwrap sequence and device clock, count gaps, fit the clock. Returns
    /// `(seq, device_t_us, fitted_ns)`.
    pub(crate) fn stamp(&mut self, raw_seq: u64, raw_t_us: u64, host_ns: u64) -> (u64, u64, u64) {
        let prev_t = self.dev_t.last();
        let prev_seq = self.seq.last();
        let mut restarted = false;
        let (seq, t) = match self.dev_t.push(raw_t_us) {
            Some(t) => {
                let hint = match (prev_t, self.rate_per_us) {
                    (Some(pt), Some(r)) => Some(((t.saturating_sub(pt)) as f64 * r).round() as u64),
                    _ => None,
                };
                match self.seq.push_hint(raw_seq, hint) {
                    Some(s) if prev_seq.is_none_or(|p| s > p) => (s, t),
                    _ => {
                        restarted = true;
                        self.restart(raw_seq, raw_t_us)
                    }
                }
            }
            None => {
                restarted = true;
                self.restart(raw_seq, raw_t_us)
            }
        };
        if !restarted
            && let Some(p) = prev_seq
            && seq > p + 1
        {
            self.counters.gaps += 1;
            self.counters.gap_samples += seq - p - 1;
        }
        self.fit.push(t, host_ns);
        let fitted = self.fit.map(t).unwrap_or(host_ns);
        (seq, t, fitted)
    }

    /// The device restarted its sequence or clock under us: not a gap; start afresh.
    fn restart(&mut self, raw_seq: u64, raw_t_us: u64) -> (u64, u64) {
        self.counters.resyncs += 1;
        tracing::warn!(instrument = self.instrument.name(), port = %self.port, "sequence or device clock stepped back; restarting the count and the clock fit");
        self.fit.reset();
        let s = self.seq.rebase(raw_seq);
        let t = self.dev_t.rebase(raw_t_us);
        (s, t)
    }

    pub(crate) fn emit_sample(&mut self, s: Sample) {
        self.counters.samples += 1;
        if !s.valid {
            self.counters.invalid += 1;
        }
        if !self.send(DriverEvent::Sample(s)) {
            self.counters.dropped += 1;
        }
        self.tick(false);
    }

    pub(crate) fn emit_trigger(&mut self, t: crate::Trigger) {
        self.counters.samples += 1;
        if !self.send(DriverEvent::Trigger(t)) {
            self.counters.dropped += 1;
        }
        self.tick(false);
    }

    pub(crate) fn reject(&mut self, kind: RejectKind, bytes: usize) {
        if !self.accepting {
            tracing::debug!(
                instrument = self.instrument.name(),
                ?kind,
                bytes,
                "discarded before streaming"
            );
            return;
        }
        tracing::debug!(
            instrument = self.instrument.name(),
            ?kind,
            bytes,
            "rejected"
        );
        *self.counters.rejections.entry(kind).or_insert(0) += 1;
    }

    /// An error the operator must read; repeated identical messages are sent once.
    pub(crate) fn error(&mut self, message: String) {
        tracing::error!(instrument = self.instrument.name(), port = %self.port, "{message}");
        if self.last_error.as_deref() == Some(message.as_str()) {
            return;
        }
        self.last_error = Some(message.clone());
        let ev = DriverEvent::Error {
            instrument: self.instrument,
            port: self.port.clone(),
            message,
        };
        self.send(ev);
    }

    pub(crate) fn connected(&mut self, identity: String) {
        if self.was_connected {
            self.counters.reconnects += 1;
        }
        self.was_connected = true;
        self.last_error = None;
        tracing::info!(instrument = self.instrument.name(), port = %self.port, %identity, "connected");
        let ev = DriverEvent::Connected {
            instrument: self.instrument,
            port: self.port.clone(),
            identity,
        };
        self.send(ev);
        self.tick(true);
    }

    pub(crate) fn disconnected(&mut self, reason: String) {
        self.counters.disconnects += 1;
        self.accepting = false;
        tracing::warn!(instrument = self.instrument.name(), port = %self.port, %reason, "disconnected");
        let ev = DriverEvent::Disconnected {
            instrument: self.instrument,
            port: self.port.clone(),
            reason,
        };
        self.send(ev);
        self.tick(true);
    }

    /// Send a counters snapshot when `force` or about a second after the last one.
    pub(crate) fn tick(&mut self, force: bool) {
        // Reading the clock costs ~20 ns; only do it every 256 samples unless forced.
        if !force && self.counters.samples & 0xFF != 0 {
            return;
        }
        let now = self.clock.now_ns();
        if force || now.saturating_sub(self.last_counters_ns) >= 1_000_000_000 {
            self.last_counters_ns = now;
            self.counters.clock_drift_ppm = self.fit.drift_ppm();
            let ev = DriverEvent::Counters {
                instrument: self.instrument,
                counters: self.counters.clone(),
            };
            self.send(ev);
        }
    }
}

/// A serial instrument: its handler plus how to configure it.
pub(crate) trait Device: Handler + Send {
    fn acq(&mut self) -> &mut Acq;
    fn baud(&self) -> u32;
    fn new_decoder(&self) -> Self::Dec;
    /// Longest silence while streaming before the port is taken for lost.
    fn idle_timeout(&self) -> Duration;
    /// Stop streaming and wait for the device's answer, handling every data line before it,
    /// so a run that ends on purpose loses nothing the device sent.
    fn stop(
        &mut self,
        link: &mut Link<Self::Dec>,
    ) -> impl Future<Output = Result<(), SessionError>> + Send;
    /// Stop, identify, configure and start streaming; returns the identity string.
    fn setup(
        &mut self,
        link: &mut Link<Self::Dec>,
    ) -> impl Future<Output = Result<String, SessionError>> + Send;
}

async fn stream<D: Device>(dev: &mut D, link: &mut Link<D::Dec>) -> Result<(), SessionError> {
    let idle = dev.idle_timeout();
    let mut cycle = 0u32;
    loop {
        match tokio::time::timeout(idle, link.read_once(dev)).await {
            Ok(Ok(n)) => {
                cycle = cycle.wrapping_add(1);
                if n < BATCH_BYTES && !cycle.is_multiple_of(PROBE_EVERY) {
                    tokio::time::sleep(BATCH_WAIT).await;
                }
                dev.acq().tick(false);
            }
            Ok(Err(e)) => return Err(e),
            Err(_) => {
                return Err(SessionError::Lost(format!(
                    "no data for {:.1} s while streaming",
                    idle.as_secs_f64()
                )));
            }
        }
    }
}

/// The driver task: connect, configure, stream; on loss report, back off and start again.
pub(crate) async fn run<D: Device>(mut dev: D, cancel: CancellationToken) {
    let mut backoff = BACKOFF_MIN;
    let mut open_failures = 0u32;
    loop {
        if cancel.is_cancelled() {
            break;
        }
        let path = dev.acq().port.clone();
        let port = match open_port(&path, dev.baud()) {
            Ok(p) => p,
            Err(e) => {
                if open_failures == 0 {
                    tracing::warn!(port = %path, "cannot open the port ({e}); retrying with backoff");
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
        let clock = dev.acq().clock;
        let mut link = Link::new(port, dev.new_decoder(), clock, &path);
        dev.acq().on_open();
        let result = tokio::select! {
            _ = cancel.cancelled() => Err(SessionError::Cancelled),
            r = async {
                let identity = dev.setup(&mut link).await?;
                dev.acq().connected(identity);
                stream(&mut dev, &mut link).await
            } => r,
        };
        match result {
            Ok(()) | Err(SessionError::Cancelled) => {
                if let Err(SessionError::Device(m) | SessionError::Lost(m)) =
                    dev.stop(&mut link).await
                {
                    tracing::warn!(port = %path, "stopping the stream: {m}");
                }
                break;
            }
            Err(SessionError::Lost(reason)) => {
                let was_streaming = dev.acq().accepting;
                dev.acq().disconnected(reason);
                if was_streaming {
                    backoff = BACKOFF_MIN;
                }
            }
            Err(SessionError::Device(message)) => {
                dev.acq().error(message);
            }
        }
        drop(link);
        tokio::select! {
            _ = cancel.cancelled() => break,
            _ = tokio::time::sleep(backoff) => {}
        }
        backoff = (backoff * 2).min(BACKOFF_MAX);
    }
    dev.acq().tick(true);
}
