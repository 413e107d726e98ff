//! What the drivers hand on: samples, triggers and counters.

use serde::Serialize;

use crate::Instrument;

/// One converted, timestamped sample of an instrument.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sample {
    pub instrument: Instrument,
    /// Device sequence number, unwrapped (monotonic across wraps within one connection).
    pub seq: u64,
    /// Device clock, µs, unwrapped.
    pub device_t_us: u64,
    /// Host arrival time, ns since the Unix epoch (see [`HostClock`]).
    pub host_ns: u64,
    /// Device time mapped onto the host axis by the clock fit, ns since the Unix epoch
    /// (offset by the least delay seen, without drift, until the fit has enough points).
    pub fitted_ns: u64,
    pub valid: bool,
    pub values: SampleValues,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SampleValues {
    /// LI-80 `$POS`, with the compensated length.
    Position {
        raw_nm: i64,
        position_um: f64,
        sig: u8,
        flags: u32,
    },
    /// LI-80 `$ENV`, with the refractive index computed from it.
    Environment {
        air_c: f64,
        air_pa: f64,
        rh_pct: f64,
        material_c: Vec<f64>,
        n_air: f64,
    },
    /// CB-3 sample: volts, distance changes (polynomial) and machine-frame error (transform).
    Capball {
        volts: [f64; 3],
        d_um: [f64; 3],
        e_um: [f64; 3],
        flags: u8,
    },
    /// PSD-2 sample: position, summed photocurrent, head temperature.
    Psd {
        x_um: f64,
        y_um: f64,
        sum_pa: f64,
        head_c: f64,
    },
    /// Temperature module (Modbus RTU, instruments.md §5): one value per configured channel,
    /// °C, in the configured channel order; NaN for a channel reporting a sensor fault (the
    /// sample is then invalid).
    Temperature { values_c: Vec<f64> },
}

/// A flag of [`SampleValues::Position`] set by the host, not the device (whose flags use the
/// low bits, instruments.md §1): the reading's zero is not the run's datum. The LI-80 driver
/// takes the datum once per run; after a reconnect the device may have been power-cycled or
/// re-zeroed, so every later reading carries this flag and is invalid until the epoch is
/// re-referenced.
pub const DATUM_NOT_RUNS: u32 = 1 << 31;

/// The host bits of [`SampleValues::Position`]'s flags that hold the reading's datum epoch
/// (docs/log-format.md): 0 is the run's datum; a reconnect, a beam loss or a service start
/// mid-program starts the next. With [`DATUM_NOT_RUNS`] clear in an epoch > 0, the epoch was
/// re-referenced (`DATUM` at the run's reference pose).
pub const DATUM_EPOCH_SHIFT: u32 = 16;
/// Mask of the epoch bits (15 bits, below [`DATUM_NOT_RUNS`]).
pub const DATUM_EPOCH_MASK: u32 = 0x7FFF << DATUM_EPOCH_SHIFT;

/// The datum epoch a [`SampleValues::Position`]'s flags carry.
pub fn datum_epoch(flags: u32) -> u32 {
    (flags & DATUM_EPOCH_MASK) >> DATUM_EPOCH_SHIFT
}

/// The host bits for epoch `epoch` (saturating at the mask: 32767 epochs).
pub fn datum_epoch_bits(epoch: u32) -> u32 {
    epoch.min(DATUM_EPOCH_MASK >> DATUM_EPOCH_SHIFT) << DATUM_EPOCH_SHIFT
}

/// The flags of [`SampleValues::Position`] that say the reading's zero is not the run's: the
/// device's own "datum lost" (the beam was interrupted) and the host's [`DATUM_NOT_RUNS`].
pub const DATUM_FLAGS: u32 = protocol::li80::PosFlags::DATUM_LOST | DATUM_NOT_RUNS;

/// A CNC trigger, from SocketCAN or SLCAN alike.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Trigger {
    pub event: protocol::can::TriggerEvent,
    pub pose: u16,
    pub nc_ms: u32,
    pub host_ns: u64,
}

/// Per-instrument counters. Every field only grows during a run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Counters {
    /// Samples handed on (LI-80: `$POS` and `$ENV`; triggers: trigger frames).
    pub samples: u64,
    /// Samples missing according to the sequence numbers.
    pub gap_samples: u64,
    /// Number of gaps (events), each of one or more samples.
    pub gaps: u64,
    /// Lines or frames discarded by the decoder (and trigger frames with a bad payload), by
    /// kind, once streaming. What a device sends before we start its stream is discarded
    /// uncounted. A polled device (the Modbus temperature module) counts its failed
    /// transactions here too: `timeout`, `exception`, `bad_crc`.
    pub rejections: std::collections::BTreeMap<protocol::RejectKind, u64>,
    /// Sequence number or device clock stepped back within one connection (the device
    /// restarted under us): counting and the clock fit start afresh; not a gap.
    pub resyncs: u64,
    /// Connections identified again after a disconnect.
    pub reconnects: u64,
    pub disconnects: u64,
    /// Samples that could not be delivered because the consumer's queue was full.
    pub dropped: u64,
    /// Samples marked invalid (beam low or datum lost, over-range, photocurrent below minimum).
    pub invalid: u64,
    /// Asynchronous device errors (`$ERR`; CAN error frames on SocketCAN).
    pub device_errors: u64,
    /// Answer lines or frames routed to commands.
    pub answers: u64,
    /// Fitted drift of the device clock against the host clock, ppm (None until fitted).
    pub clock_drift_ppm: Option<f64>,
}
