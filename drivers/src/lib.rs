//! Async drivers of metrolog's instruments. Each driver owns its port, identifies and configures
//! the device, decodes the stream with the `protocol` decoders, timestamps and converts every
//! sample, counts every fault, and survives unplug/replug. Drivers never block on the consumer:
//! they send into a bounded channel and count what could not be delivered.
//!
//! Public surface (the modules are private; this is everything the daemon needs):
//! - [`Sample`], [`SampleValues`], [`Trigger`], [`DriverEvent`] — what the drivers yield,
//!   through an [`EventSender`];
//! - [`DriverError`] — why a port or device failed (in `DriverEvent::{Error, Disconnected}`);
//! - [`Counters`] — per-instrument counters;
//! - [`Instrument`], with the pose-valued instruments and their detector channels;
//! - [`spawn_li80`], [`spawn_cb3`], [`spawn_psd`], [`spawn_slcan`], [`spawn_socketcan`],
//!   [`spawn_modbus_temperature`] with
//!   their configurations — start a driver task;
//! - [`trigger_from_frame`] and [`from_socketcan`] — the one decoding path of SLCAN and
//!   SocketCAN frames (the CAN trigger event is the one enum `protocol::can::TriggerEvent`,
//!   which the pose detector takes as it is);
//! - [`HostClock`] — the host monotonic clock as ns since the Unix epoch (`metrolog-types`);
//!   the clock fits the stamper uses are `metrolog-detect`'s.
//!
//! A sample's way through a serial driver is one direction (docs/design.md):
//!
//! ```text
//! port bytes ─ SerialLink (protocol decoder) ─ FrameConverter (the instrument's: frame → Reading)
//!   ─ SampleStamper (unwrap sequence and device clock, ClockFit) ─ EventReporter (count, emit
//!   DriverEvent into the bounded queue)
//! ```
//!
//! The instrument's `SerialDriver` (e.g. `Li80Driver`) only issues its command sequence through
//! a `SerialSession`, which reads and routes data arriving meanwhile down the same way.
//!
//! Every serial driver runs the same loop: open the port (8N1, no flow control), stop a stream
//! the device may still be sending, identify, configure, start streaming; then read in large
//! batches (about every 10 ms, every second read waiting for fresh bytes so the clock fit gets
//! precise arrival times), decode, convert with `protocol::convert`, stamp and count. A read
//! error, end of file or silence while streaming reports `Disconnected` and reopens the port
//! with backoff (100 ms doubling to 2 s); a device that answers `ERR` or nothing reports
//! `Error` naming the port, the command and the answer, and is retried. Cancelling stops the
//! stream and still delivers every sample sent before the device's answer.

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
mod trigger;

pub use cb3::{Cb3Config, spawn_cb3};
pub use error::DriverError;
pub use event::{DriverEvent, EventSender};
pub use li80::{Li80Config, spawn_li80};
pub use modbus::{
    ModbusConfigError, ModbusTempConfig, Parity, RegisterKind, TempSensor, spawn_modbus_temperature,
};
pub use psd::{HeadCorrection, PsdAxis, PsdConfig, spawn_psd};
pub use trigger::{
    SlcanConfig, SocketCanConfig, from_socketcan, spawn_slcan, spawn_socketcan, trigger_from_frame,
};
/// The shared vocabulary the drivers' events are made of (`metrolog-types`).
pub use types::{Counters, HostClock, Instrument, Sample, SampleValues, Trigger};
