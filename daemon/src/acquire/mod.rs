//! The acquisition service (`metrolog run`), in the order a sample travels (`docs/design.md`):
//!
//! - [`config`]: the service's TOML config, validated with the file, line and what to fix;
//! - [`run_log`]: opens the run's log from the config (which instruments get pose values,
//!   triggers or plateaus, the run metadata and attachments that make the log replay alone);
//! - drivers (crate `metrolog-drivers`) send every sample, trigger and connection change into
//!   one bounded queue;
//! - [`pipeline`]: takes the events off the queue on its own thread and hands each to the
//!   event sink; keeps the one [`pipeline::Status`] for systemd, progress and the outcome;
//! - [`sink`]: where the events go — the run's log ([`sink::LiveLog`]: the recorder plus the
//!   thread that makes the file durable) or the pose engine alone ([`sink::DetectOnly`]);
//! - [`recorder`]: writes raw topics, the pose engine's values (crate `metrolog-detect`, the
//!   same code replay runs), `/event` and `/status` through the log writer (crate
//!   `metrolog-log`);
//! - [`counts`]: the run's counts (driver counters, pose values by status), kept once by the
//!   sink and read by `/status` and the [`pipeline::Status`];
//! - [`service`]: systemd integration (READY/STATUS/STOPPING, watchdog), signals, tracing.

pub mod config;
pub mod counts;
pub mod pipeline;
pub mod preflight;
pub mod progress;
pub mod recorder;
pub mod run_log;
pub mod service;
pub mod sink;
pub mod storage;
