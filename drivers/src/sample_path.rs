//! A decoded frame's way to the consumer, one direction: the instrument's [`FrameConverter`]
//! says what the frame means ([`Reading`]), the [`SampleStamper`] dates data frames, the
//! [`EventReporter`] counts and emits. Answers to commands are handed back to the session
//! waiting for them.

use protocol::can::TriggerError;
use protocol::{Decoded, RejectKind, StreamDecoder};

use crate::reporter::EventReporter;
use crate::stamper::SampleStamper;
use crate::{DriverError, HostClock, Instrument, Sample, SampleValues, Trigger};

/// What one decoded frame of an instrument means.
pub(crate) enum Reading {
    /// An answer line, for the command waiting for it.
    Answer(String),
    /// A data frame to stamp with its device sequence and clock, converted.
    Data {
        raw_seq: u64,
        raw_t_us: u64,
        valid: bool,
        values: SampleValues,
    },
    /// A sample with its own timing (LI-80 `$ENV`), emitted as it is.
    Timed(Sample),
    /// A CNC trigger.
    Trigger(Trigger),
    /// A frame with our trigger identifier whose payload is not a trigger.
    BadTrigger {
        can_id: u32,
        error: TriggerError,
        bytes: usize,
    },
    /// The device reports a fault of its own (counted as a device error).
    DeviceError(DriverError),
    /// Something the operator must read, not a device fault.
    Problem(DriverError),
    /// The interferometer's datum epoch changed (docs/design.md, "Datum epochs").
    Datum(crate::DatumChange),
}

/// The instrument-specific step: decoded frames to readings. Owns the conversion state (e.g.
/// the LI-80's air compensation), which survives reconnects.
pub(crate) trait FrameConverter: Send {
    type Decoder: StreamDecoder + Send;
    fn new_decoder(&self) -> Self::Decoder;
    /// What `frame` means; a frame may mean several things (or nothing).
    fn convert(&mut self, frame: Frame<Self>, host_ns: u64, out: &mut impl FnMut(Reading));
}

/// The frame type of a converter's decoder.
pub(crate) type Frame<C> = <<C as FrameConverter>::Decoder as StreamDecoder>::Frame;

/// The rejection kind a bad trigger payload is counted under.
pub(crate) fn reject_kind(e: &TriggerError) -> RejectKind {
    match e {
        TriggerError::BadDlc(_) => RejectKind::BadLength,
        TriggerError::UnknownEvent(_) => RejectKind::UnknownRecord,
        TriggerError::Reserved(_) => RejectKind::Malformed,
    }
}

/// Converter, stamper and reporter of one instrument, for the driver's whole life.
pub(crate) struct SamplePath<C> {
    pub(crate) converter: C,
    pub(crate) stamper: SampleStamper,
    pub(crate) reporter: EventReporter,
}

impl<C: FrameConverter> SamplePath<C> {
    pub(crate) fn new(
        converter: C,
        stamper: SampleStamper,
        instrument: Instrument,
        port: &str,
        clock: HostClock,
        tx: crate::EventSender,
    ) -> Self {
        SamplePath {
            converter,
            stamper,
            reporter: EventReporter::new(instrument, port, clock, tx),
        }
    }

    /// Take one decoded item that arrived at `host_ns`; returns the answer line it carries.
    pub(crate) fn take(&mut self, item: Decoded<Frame<C>>, host_ns: u64) -> Option<String> {
        match item {
            Decoded::Reject(r) => {
                self.reporter.reject(r.kind, r.bytes);
                None
            }
            Decoded::Frame(f) => {
                let SamplePath {
                    converter,
                    stamper,
                    reporter,
                } = self;
                let mut answer = None;
                converter.convert(f, host_ns, &mut |r| {
                    if let Some(a) = route(reporter, stamper, r, host_ns) {
                        answer = Some(a);
                    }
                });
                answer
            }
        }
    }

    /// Take one reading (of a transport without a decoder: SocketCAN).
    #[cfg(feature = "socketcan")]
    pub(crate) fn take_reading(&mut self, r: Reading, host_ns: u64) {
        route(&mut self.reporter, &mut self.stamper, r, host_ns);
    }

    /// Send a counters snapshot when `force` or about a second after the last one.
    pub(crate) fn tick(&mut self, force: bool) {
        self.reporter.tick(force, &self.stamper);
    }
}

/// Where each reading goes; returns an answer line.
fn route(
    reporter: &mut EventReporter,
    stamper: &mut SampleStamper,
    r: Reading,
    host_ns: u64,
) -> Option<String> {
    match r {
        Reading::Answer(a) => {
            reporter.counters.answers += 1;
            return Some(a);
        }
        Reading::Data {
            raw_seq,
            raw_t_us,
            valid,
            values,
        } => {
            if !reporter.accepting {
                return None;
            }
            let st = stamper.stamp(raw_seq, raw_t_us, host_ns);
            if st.restarted {
                reporter.counters.resyncs += 1;
                tracing::warn!(instrument = reporter.instrument.name(), port = %reporter.port, "sequence or device clock stepped back; restarting the count and the clock fit");
            }
            if st.missed > 0 {
                reporter.counters.gaps += 1;
                reporter.counters.gap_samples += st.missed;
            }
            let s = Sample {
                instrument: reporter.instrument,
                seq: st.seq,
                device_t_us: st.device_t_us,
                host_ns,
                fitted_ns: st.fitted_ns,
                valid,
                values,
            };
            reporter.emit_sample(s, stamper);
        }
        Reading::Timed(s) => reporter.emit_sample(s, stamper),
        Reading::Trigger(t) => {
            if reporter.accepting {
                reporter.emit_trigger(t, stamper);
            }
        }
        Reading::BadTrigger {
            can_id,
            error,
            bytes,
        } => {
            if reporter.accepting {
                tracing::warn!(port = %reporter.port, id = can_id, "bad trigger frame: {error}");
                reporter.reject(reject_kind(&error), bytes);
            }
        }
        Reading::DeviceError(e) => {
            reporter.counters.device_errors += 1;
            reporter.error(e);
        }
        Reading::Problem(e) => reporter.error(e),
        Reading::Datum(d) => reporter.datum(d),
    }
    None
}
