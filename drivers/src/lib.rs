//! Async drivers of metrolog's instruments: each driver task owns its port, identifies and
//! configures the device, decodes the stream with the `protocol` decoders, timestamps, converts
//! and counts every sample, survives unplug/replug, and hands everything on as [`DriverEvent`]s
//! through a bounded queue it never waits on (docs/design.md, "Data flow").
//!
//! What others use, all re-exported here (the modules are private):
//! - [`spawn_li80`], [`spawn_cb3`], [`spawn_psd`], [`spawn_slcan`] and, with the cargo feature
//!   `socketcan` (default), `spawn_socketcan`, and [`spawn_modbus_temperature`] (Modbus RTU temperature modules),
//!   with their configurations;
//! - what they yield: [`DriverEvent`] through an [`EventSender`], [`DriverError`], and the
//!   shared vocabulary of `metrolog-types` ([`Sample`], [`Trigger`], [`Counters`], ...);
//! - [`trigger_from_frame`] (and `from_socketcan`): the one decoding path of CAN triggers.
//!
//! A serial driver's way, one direction: port bytes → `SerialLink` (protocol decoder, arrival
//! time) → the instrument's `FrameConverter` → `SampleStamper` (sequence, device clock fit) →
//! `EventReporter` (count, emit); the instrument's `SerialDriver` only issues its commands
//! (connect, stop a stale stream, identify, configure, stream; reopen with backoff 100 ms to
//! 2 s on loss; a stop delivers every sample sent before the device's answer; while streaming,
//! reads are coalesced on a shared tick, [`set_read_coalesce`], so a device costs about one
//! wake-up per tick whatever its rate). Sessions are
//! generic over the byte stream, so the tests run real drivers over `tokio::io::duplex`.

#[cfg(feature = "socketcan")]
mod can_socket;
mod cb3;
mod error;
mod event;
mod li80;
mod modbus;
mod psd;
mod reporter;
mod sample_path;
mod serial_driver;
mod serial_link;
mod stamper;
#[doc(hidden)]
pub mod synthetic;
#[cfg(test)]
mod test_port;
mod trigger;
mod tty_port;

#[cfg(feature = "socketcan")]
pub use can_socket::{from_socketcan, spawn_socketcan};
pub use cb3::{Cb3Config, spawn_cb3};
pub use error::DriverError;
pub use event::{DatumChange, DriverEvent, EventSender};
pub use li80::{Li80Command, Li80Config, Li80Control, spawn_li80, spawn_li80_with};
pub use modbus::{
    ModbusConfigError, ModbusTempConfig, Parity, RegisterKind, TempSensor, spawn_modbus_temperature,
};
pub use psd::{HeadCorrection, PsdAxis, PsdConfig, spawn_psd};
pub use serial_driver::{
    READ_COALESCE_DEFAULT, TAKE_AFTER_TICK, late_reads, next_read_tick, read_coalesce,
    set_read_coalesce,
};
pub use trigger::{SlcanConfig, SocketCanConfig, spawn_slcan, trigger_from_frame};
/// The shared vocabulary the drivers' events are made of (`metrolog-types`).
pub use types::{Counters, HostClock, Instrument, Sample, SampleValues, Trigger};
