//! What the drivers hand on: samples, triggers, connection changes, errors and counters.

use crate::{Counters, DriverError, Instrument, Sample, Trigger};

/// Everything a driver reports.
#[derive(Debug, Clone)]
pub enum DriverEvent {
    Sample(Sample),
    Trigger(Trigger),
    /// The device was identified (after every (re)connect).
    Connected {
        instrument: Instrument,
        port: String,
        identity: String,
    },
    /// The port vanished or failed; the driver retries with backoff.
    Disconnected {
        instrument: Instrument,
        port: String,
        reason: DriverError,
    },
    /// An error the operator must read (device answered ERR or nothing).
    Error {
        instrument: Instrument,
        port: String,
        error: DriverError,
    },
    /// The interferometer's datum epoch changed: lost (reconnect, beam loss, a start
    /// mid-program) or re-referenced (`DATUM` at the reference pose).
    Datum {
        instrument: Instrument,
        port: String,
        change: DatumChange,
    },
    /// A snapshot of the counters (sent about once a second and on change of connection).
    Counters {
        instrument: Instrument,
        counters: Counters,
    },
}

/// A change of the interferometer's datum epoch (docs/design.md, "Datum epochs").
#[derive(Debug, Clone, PartialEq)]
pub struct DatumChange {
    /// The epoch from now on (0: the run's datum).
    pub epoch: u32,
    /// `true`: the epoch was re-referenced (its readings are against the run's zero again);
    /// `false`: the datum was lost and this epoch begins.
    pub referenced: bool,
    /// The reference pose, for a re-reference.
    pub pose: Option<u32>,
    /// What the operator reads.
    pub text: String,
}

/// How a driver hands its events on: a bounded queue; a full queue is counted, never waited on.
pub type EventSender = tokio::sync::mpsc::Sender<DriverEvent>;
