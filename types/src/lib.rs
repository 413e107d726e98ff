//! The vocabulary every metrolog crate shares, and nothing else: which instruments there are,
//! what a driver hands on (a [`Sample`], a [`Trigger`], [`Counters`]), what the steady-value
//! detector gives ([`PoseValue`], [`PoseMsg`]) and its settings ([`SteadyConfig`],
//! [`DetectorSettings`]), and the host clock every time is stamped with. Plain data with serde
//! (JSON schemas behind the `schemars` feature); the CNC trigger events and the decoders'
//! rejection kinds are the wire contract's own enums (`protocol`), re-exported here.
#![warn(unreachable_pub)]

mod detector;
mod host_clock;
mod instrument;
mod pose;
mod sample;

pub use detector::{
    DetectorMode, DetectorSettings, NC_SETTLE_US, OFF_TARGET_FLOOR_UM, OFF_TARGET_TOL_UM,
    PositionTargets, SteadyConfig, SteadyError, TriggerTime,
};
pub use host_clock::HostClock;
pub use instrument::Instrument;
pub use pose::{PoseMsg, PoseStatus, PoseValue, Stamp};
pub use protocol::RejectKind;
pub use protocol::can::TriggerEvent;
pub use sample::{
    Counters, DATUM_EPOCH_MASK, DATUM_EPOCH_SHIFT, DATUM_FLAGS, DATUM_NOT_RUNS, Sample,
    SampleValues, Trigger, datum_epoch, datum_epoch_bits,
};
