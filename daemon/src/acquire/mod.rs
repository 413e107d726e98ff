//! The acquisition service (`metrolog run`), in the order a sample travels (`docs/design.md`):
//!
//! - [`config`]: the service's TOML config, validated with the file, line and what to fix;
//! - drivers (crate `metrolog-drivers`) send every sample, trigger and connection change into
//!   one bounded queue;
//! - [`pipeline`]: takes the events off the queue on its own thread and hands each to the
//!   [`recorder::Recorder`], keeps the [`pipeline::Status`] for systemd and the log;
//! - the pose engine (crate `metrolog-detect`): the steady-value detectors of the three
//!   instruments (the same code replay runs);
//! - [`recorder`]: writes raw topics, the detectors' pose values, `/event` and `/status` through
//!   the log writer (crate `metrolog-log`);
//! - [`service`]: systemd integration (READY/STATUS/STOPPING, watchdog), signals, tracing.

pub mod config;
pub mod pipeline;
pub mod recorder;
pub mod service;
