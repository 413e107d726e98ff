//! metrolog's log format: one MCAP file per run, the single source of truth of a measurement
//! (docs/log-format.md). Protocol and types only: this crate links no serial or CAN I/O and no
//! maths (`protocol` and `types` are its only crates of ours; the pose detection that produces
//! `/pose` is `metrolog-detect`'s, run by the service and by replay).
//!
//! What others use, re-exported here:
//! - writing: [`LogWriter`] with [`LogOptions`], [`RunMetadata`], the attachment and metadata
//!   names ([`TRAJECTORY_ATTACHMENT`], [`RUN_METADATA`], ...), [`channel_specs`] and
//!   [`MessageTap`] for the live view;
//! - reading: [`read_log`] and its variants (record by record, stopping at the first damaged
//!   byte, so a killed writer's file gives its intact prefix), [`LogItem`], [`ReadSummary`],
//!   [`recover()`];
//! - decoding: [`decode_message`] ([`LogMessage`], [`DecodeError`]) over every format; the
//!   messages of each topic in [`topics`]; the raw protobuf batches of formats 2 and 3 in
//!   [`raw`] ([`BatchError`] says what is wrong with one and where);
//! - the trajectory table of a run ([`trajectory`]: [`parse_trajectory`], the one parser).
//!
//! # Use
//!
//! ```no_run
//! use metrolog_log::{LogOptions, LogWriter, RunMetadata};
//! # fn samples() -> Vec<types::Sample> { Vec::new() }
//! # fn main() -> Result<(), metrolog_log::LogError> {
//! let clock = types::HostClock::new();
//! let meta = RunMetadata { machine: "mill-1".into(), started_ns: clock.now_ns(), ..Default::default() };
//! let mut log = LogWriter::create_in_dir("/var/lib/metrolog".as_ref(), &meta, LogOptions::default())?;
//! log.attach_file("/etc/metrolog/metrolog.toml".as_ref(), "application/toml", clock.now_ns())?;
//! for s in samples() {
//!     log.write_sample(&s)?; // raw topic of the sample's instrument, at its host arrival time
//!     log.flush_if_due()?; // closes a chunk at least once a second
//! }
//! let _path = log.finish()?;
//! # Ok(()) }
//! ```
//!
//! # Files
//!
//! Each run writes a new file, created with `O_EXCL` (an existing file is never opened for
//! writing, so an earlier run cannot be damaged), directly under its final name `*.mcap` (no
//! `.part` + rename: a log cut by a power loss keeps its name and opens in Foxglove; whether
//! it was closed cleanly is visible in the file itself — footer and end magic — and
//! `metrolog info` reports it).

#[doc(hidden)]
mod bg_file;
pub mod fuzzcheck;
mod prescan;
pub mod raw;
pub mod reader;
pub mod recover;
mod run;
pub mod split;
pub mod topics;
pub mod trajectory;
pub mod writer;

pub use raw::BatchError;
pub use reader::{
    LogItem, ReadSummary, read_log, read_log_progress, read_log_until, read_run_metadata,
};
pub use recover::recover;
pub use run::{
    CAPBALL_CALIBRATION_KEY, CONFIG_ATTACHMENT, DETECTOR_KEY, INSTRUMENT_METADATA, LOG_FORMAT,
    LOG_FORMAT_KEY, LogError, RUN_METADATA, RunMetadata, TEMPERATURE_SENSORS_KEY,
    TRAJECTORY_ATTACHMENT, rfc3339,
};
pub use topics::{DecodeError, LogMessage, decode_message};
pub use trajectory::{TrajectoryRow, parse_trajectory, write_trajectory};
/// The detector settings a run stores (`metrolog-types`), re-exported for the log's readers.
pub use types::{DetectorSettings, NC_SETTLE_US, TriggerTime};
pub use writer::{ChannelSpec, LogOptions, LogWriter, MessageTap, channel_specs};
