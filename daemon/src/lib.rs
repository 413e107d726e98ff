//! The `metrolog` binary's library:
//!
//! - [`acquire`]: the acquisition service (`metrolog run`): config, the run's log, the
//!   pipeline from the drivers' queue to the recorder, its status, systemd integration;
//! - [`live`]: the live view, a read-only tap on the run's log served to Foxglove and the
//!   operator page;
//! - [`cmd`]: the subcommands (argument handling and I/O; the maths is in the maths crates,
//!   the reports' text in `metrolog-analysis`), and [`cli`] which dispatches to them;
//! - [`exit`]: the process exit codes systemd acts on.
//!
//! The log format is the crate `metrolog-log`, pose detection `metrolog-detect`, the analyses
//! `metrolog-analysis`; the simulator (`metrolog-sim`) is linked only with the feature `sim`.

pub mod acquire;
pub mod cli;
pub mod cmd;
pub mod exit;
#[doc(hidden)]
pub mod fuzzcheck;
pub mod live;
