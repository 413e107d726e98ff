//! The end of a sample's way through a driver: counting and handing events to the consumer.
//! Never waits: a full queue is counted as dropped.

use protocol::RejectKind;
use tokio::sync::mpsc::error::TrySendError;

use crate::stamper::SampleStamper;
use crate::{Counters, DriverError, DriverEvent, EventSender, HostClock, Instrument, Sample};

/// Most samples between two clock reads of [`EventReporter::tick`] (a read costs ~20 ns).
const MAX_CLOCK_STRIDE: u64 = 256;
/// [`EventReporter::tick`] reads the clock about this often at high rates: 100 to 200 times a
/// second, whatever the rate; at every sample when samples are further apart.
const CLOCK_CHECK_NS: u64 = 5_000_000;

/// Counts and reports what one instrument's driver sees.
pub(crate) struct EventReporter {
    pub(crate) instrument: Instrument,
    pub(crate) port: String,
    tx: EventSender,
    pub(crate) clock: HostClock,
    pub(crate) counters: Counters,
    last_counters_ns: u64,
    /// When the clock was last read for [`Self::tick`], and how many samples pass between two
    /// reads (1 at low rates, up to [`MAX_CLOCK_STRIDE`] at high ones).
    last_check_ns: u64,
    clock_stride: u64,
    next_check: u64,
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
            last_check_ns: 0,
            clock_stride: 1,
            next_check: 0,
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

    /// A change of datum epoch: the operator's line (ERROR when the datum is lost, WARN when
    /// it was re-referenced) and a `DriverEvent::Datum` for the log.
    pub(crate) fn datum(&mut self, change: crate::DatumChange) {
        if change.referenced {
            tracing::warn!(instrument = self.instrument.name(), port = %self.port, "{}", change.text);
        } else {
            tracing::error!(instrument = self.instrument.name(), port = %self.port, "{}", change.text);
        }
        let ev = DriverEvent::Datum {
            instrument: self.instrument,
            port: self.port.clone(),
            change,
        };
        self.send(ev);
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
    ///
    /// The clock is read every `clock_stride` samples: the stride doubles while reads come
    /// less than [`CLOCK_CHECK_NS`] apart and halves when they are more than twice that, so a
    /// 20 kHz stream reads it every 128 to 256 samples and a slow one (triggers, a Modbus
    /// module) at every sample. A fixed stride of 256 left the trigger's counters at 0 until
    /// the 256th trigger.
    pub(crate) fn tick(&mut self, force: bool, stamper: &SampleStamper) {
        if !force && self.counters.samples < self.next_check {
            return;
        }
        let now = self.clock.now_ns();
        let since = now.saturating_sub(self.last_check_ns);
        self.clock_stride = if since < CLOCK_CHECK_NS {
            (self.clock_stride * 2).min(MAX_CLOCK_STRIDE)
        } else if since > 2 * CLOCK_CHECK_NS {
            (self.clock_stride / 2).max(1)
        } else {
            self.clock_stride
        };
        self.last_check_ns = now;
        self.next_check = self.counters.samples + self.clock_stride;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn trigger(pose: u16) -> crate::Trigger {
        crate::Trigger {
            event: protocol::can::TriggerEvent::ExactStop,
            pose,
            nc_ms: 0,
            host_ns: 0,
        }
    }

    /// The snapshots' trigger counts.
    fn counted(rx: &mut tokio::sync::mpsc::Receiver<DriverEvent>) -> Vec<u64> {
        let mut v = Vec::new();
        while let Ok(ev) = rx.try_recv() {
            if let DriverEvent::Counters { counters, .. } = ev {
                v.push(counters.samples);
            }
        }
        v
    }

    /// Triggers come one every few seconds: once a second has passed, the next trigger's
    /// counters are reported, not at the 256th trigger (the `/status` that read 0 for 245
    /// triggers, then 256).
    #[test]
    fn a_slow_stream_reports_its_counters_about_once_a_second() {
        let (tx, mut rx) = tokio::sync::mpsc::channel(1024);
        let clock = HostClock::new();
        let mut rep = EventReporter::new(Instrument::Trigger, "can0", clock, tx);
        let stamper = SampleStamper::new(32, 32);
        for pose in 1..=3 {
            // Wait (for the clock, not a fixed time) until a second after the last snapshot.
            let t0 = clock.now_ns();
            while clock.now_ns() < t0 + 1_000_000_000 {
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            rep.emit_trigger(trigger(pose), &stamper);
            assert_eq!(counted(&mut rx), [u64::from(pose)]);
        }
    }

    /// However fast the stream, the clock is read at least every 256 samples, so a snapshot
    /// is never more than 256 samples late.
    #[test]
    fn the_clock_is_read_at_least_every_256_samples() {
        let (tx, _rx) = tokio::sync::mpsc::channel(1 << 20);
        let mut rep = EventReporter::new(Instrument::Psd, "p", HostClock::new(), tx);
        let stamper = SampleStamper::new(32, 32);
        let mut strides = std::collections::BTreeSet::new();
        for _ in 0..20_000 {
            rep.emit_trigger(trigger(0), &stamper);
            strides.insert(rep.clock_stride);
        }
        assert!(
            strides.iter().all(|s| (1..=MAX_CLOCK_STRIDE).contains(s)),
            "{strides:?}"
        );
    }
}
