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
    /// A snapshot of the counters (sent about once a second and on change of connection).
    Counters {
        instrument: Instrument,
        counters: Counters,
    },
}

/// How a driver hands its events on: a bounded queue; a full queue is counted, never waited on.
pub type EventSender = tokio::sync::mpsc::Sender<DriverEvent>;
