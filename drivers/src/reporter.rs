//! The end of a sample's way through a driver: counting and handing events to the consumer.
//! Never waits: a full queue is counted as dropped.

use protocol::RejectKind;
use tokio::sync::mpsc::error::TrySendError;

use crate::stamper::SampleStamper;
use crate::{Counters, DriverError, DriverEvent, EventSender, HostClock, Instrument, Sample};

/// Counts and reports what one instrument's driver sees.
pub(crate) struct EventReporter {
    pub(crate) instrument: Instrument,
    pub(crate) port: String,
    tx: EventSender,
    pub(crate) clock: HostClock,
    pub(crate) counters: Counters,
    last_counters_ns: u64,
    /// The message of the last error sent, so a repeated one is sent once.
    last_error: Option<String>,
    /// Data frames become samples only once streaming was started by us; what a device sends
    /// before that (it may have been streaming when the port opened) is discarded uncounted.
    pub(crate) accepting: bool,
    was_connected: bool,
}

impl EventReporter {
    pub(crate) fn new(
        instrument: Instrument,
        port: &str,
        clock: HostClock,
        tx: EventSender,
    ) -> Self {
        EventReporter {
            instrument,
            port: port.to_string(),
            tx,
            clock,
            counters: Counters::default(),
            last_counters_ns: 0,
            last_error: None,
            accepting: false,
            was_connected: false,
        }
    }

    fn send(&mut self, ev: DriverEvent) -> bool {
        match self.tx.try_send(ev) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) | Err(TrySendError::Closed(_)) => false,
        }
    }

    pub(crate) fn emit_sample(&mut self, s: Sample, stamper: &SampleStamper) {
        self.counters.samples += 1;
        if !s.valid {
            self.counters.invalid += 1;
        }
        if !self.send(DriverEvent::Sample(s)) {
            self.counters.dropped += 1;
        }
        self.tick(false, stamper);
    }

    pub(crate) fn emit_trigger(&mut self, t: crate::Trigger, stamper: &SampleStamper) {
        self.counters.samples += 1;
        if !self.send(DriverEvent::Trigger(t)) {
            self.counters.dropped += 1;
        }
        self.tick(false, stamper);
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
    pub(crate) fn error(&mut self, error: DriverError) {
        let message = error.to_string();
        tracing::error!(instrument = self.instrument.name(), port = %self.port, "{message}");
        if self.last_error.as_deref() == Some(message.as_str()) {
            return;
        }
        self.last_error = Some(message);
        let ev = DriverEvent::Error {
            instrument: self.instrument,
            port: self.port.clone(),
            error,
        };
        self.send(ev);
    }

    pub(crate) fn connected(&mut self, identity: String, stamper: &SampleStamper) {
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
        self.tick(true, stamper);
    }

    pub(crate) fn disconnected(&mut self, reason: DriverError, stamper: &SampleStamper) {
        self.counters.disconnects += 1;
        self.accepting = false;
        tracing::warn!(instrument = self.instrument.name(), port = %self.port, %reason, "disconnected");
        let ev = DriverEvent::Disconnected {
            instrument: self.instrument,
            port: self.port.clone(),
            reason,
        };
        self.send(ev);
        self.tick(true, stamper);
    }

    /// Send a counters snapshot when `force` or about a second after the last one.
    pub(crate) fn tick(&mut self, force: bool, stamper: &SampleStamper) {
        // Reading the clock costs ~20 ns; only do it every 256 samples unless forced.
        if !force && self.counters.samples & 0xFF != 0 {
            return;
        }
        let now = self.clock.now_ns();
        if force || now.saturating_sub(self.last_counters_ns) >= 1_000_000_000 {
            self.last_counters_ns = now;
            self.counters.clock_drift_ppm = stamper.drift_ppm();
            let ev = DriverEvent::Counters {
                instrument: self.instrument,
                counters: self.counters.clone(),
            };
            self.send(ev);
        }
    }
}
