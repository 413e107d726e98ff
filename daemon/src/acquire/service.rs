//! Service plumbing: logging setup, systemd notification (READY, STATUS, WATCHDOG, STOPPING)
//! and the shutdown signals.
//!
//! Watchdog policy. systemd restarts the service when `WATCHDOG=1` stops arriving within
//! `WatchdogSec`. We pet it only while the pipeline makes progress, which means, at the time of
//! the pet (see [`Watchdog::healthy`]):
//! - the pipeline task has run its loop within the last watchdog interval (it is not stuck), and
//! - either samples arrived from at least one instrument within the last
//!   [`STALL_TIMEOUT_S`] seconds, or the run is *legitimately idle*: no instrument is connected
//!   at all while a driver retries (the operator unplugged the kit; restarting the service would
//!   not help and would only churn), or the CNC is between programs (program end received and
//!   no program start since).
//!
//! A connected instrument that stops delivering samples while a program runs is what a hung
//! driver or a wedged USB stack looks like; there a restart is the right cure, so the pet stops.
//!
//! Idle is not silent: when no device has been connected for `[run] connect_timeout_s`, the
//! pipeline raises the "nothing connected" alarm (an ERROR line, `STATUS=NOTHING CONNECTED …`)
//! and, unless a device is `hotplug`, ends the run with exit 69 (README, "Nothing connected").

use std::sync::Once;
use std::time::Duration;

use tracing_subscriber::EnvFilter;
use tracing_subscriber::prelude::*;

/// Samples must have arrived within this many seconds for the pipeline to count as progressing.
pub const STALL_TIMEOUT_S: f64 = 10.0;

static INIT: Once = Once::new();

/// Set up `tracing`: human-readable on a terminal, journald fields under systemd (when
/// `JOURNAL_STREAM` is set, i.e. stderr is connected to the journal). `RUST_LOG` filters
/// (default `info`). Safe to call more than once.
pub fn init_tracing() {
    init_tracing_with_default("info");
}

/// [`init_tracing`] with another default level when `RUST_LOG` is unset (the demo keeps the
/// terminal for its progress bar and report).
pub fn init_tracing_with_default(default: &str) {
    INIT.call_once(|| {
        let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default));
        if std::env::var_os("JOURNAL_STREAM").is_some()
            && let Ok(journald) = tracing_journald::layer()
        {
            let _ = tracing_subscriber::registry()
                .with(filter)
                .with(journald.with_syslog_identifier("metrolog".into()))
                .try_init();
            return;
        }
        // Colour codes only for a person at a terminal, never in a file or a pipe.
        use std::io::IsTerminal as _;
        let _ = tracing_subscriber::fmt()
            .with_env_filter(filter)
            .with_ansi(std::io::stderr().is_terminal())
            .with_writer(std::io::stderr)
            .with_target(false)
            .try_init();
    });
}

/// systemd notification. Every call is a no-op when not started by systemd (`NOTIFY_SOCKET`
/// unset), so the same code runs on a terminal and in tests.
#[derive(Debug, Clone)]
pub struct Notifier {
    enabled: bool,
    watchdog: Option<Duration>,
}

impl Notifier {
    pub fn from_env() -> Self {
        let enabled = std::env::var_os("NOTIFY_SOCKET").is_some();
        let mut usec = 0u64;
        let watchdog = if enabled && sd_notify::watchdog_enabled(false, &mut usec) {
            Some(Duration::from_micros(usec))
        } else {
            None
        };
        Notifier { enabled, watchdog }
    }

    /// The watchdog interval systemd asked for, if any.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog
    }

    fn send(&self, state: &[sd_notify::NotifyState]) {
        if self.enabled
            && let Err(e) = sd_notify::notify(false, state)
        {
            tracing::warn!("sd_notify failed: {e}");
        }
    }

    pub fn ready(&self, status: &str) {
        self.send(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status(status),
        ]);
    }

    pub fn status(&self, status: &str) {
        self.send(&[sd_notify::NotifyState::Status(status)]);
    }

    pub fn watchdog(&self) {
        if self.watchdog.is_some() {
            self.send(&[sd_notify::NotifyState::Watchdog]);
        }
    }

    pub fn stopping(&self) {
        self.send(&[sd_notify::NotifyState::Stopping]);
    }
}

/// The facts the watchdog decision is made from (see the module documentation).
#[derive(Debug, Clone, Copy)]
pub struct Watchdog {
    /// Seconds since the pipeline loop last ran.
    pub since_loop_s: f64,
    /// Seconds since the last sample of any instrument (None: none yet).
    pub since_sample_s: Option<f64>,
    /// Seconds since the pipeline started.
    pub uptime_s: f64,
    /// Instruments currently connected (identified by their drivers).
    pub connected: usize,
    /// The CNC is between programs (program end seen, no program start since).
    pub program_idle: bool,
    /// The watchdog interval.
    pub interval_s: f64,
}

impl Watchdog {
    /// Whether to pet the watchdog now.
    pub fn healthy(&self) -> bool {
        if self.since_loop_s > self.interval_s {
            return false;
        }
        let flowing = match self.since_sample_s {
            Some(s) => s <= STALL_TIMEOUT_S,
            // Connecting and configuring the devices takes a few seconds.
            None => self.uptime_s <= STALL_TIMEOUT_S,
        };
        flowing || self.connected == 0 || self.program_idle
    }
}

/// Resolves on SIGTERM or SIGINT (Ctrl-C), returning the signal's name.
pub async fn shutdown_signal() -> &'static str {
    use tokio::signal::unix::{SignalKind, signal};
    let term = signal(SignalKind::terminate());
    let int = signal(SignalKind::interrupt());
    match (term, int) {
        (Ok(mut t), Ok(mut i)) => tokio::select! {
            _ = t.recv() => "SIGTERM",
            _ = i.recv() => "SIGINT",
        },
        _ => {
            // Without signal handlers we can still stop on Ctrl-C via tokio's portable path.
            let _ = tokio::signal::ctrl_c().await;
            "SIGINT"
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn w() -> Watchdog {
        Watchdog {
            since_loop_s: 0.1,
            since_sample_s: Some(0.01),
            uptime_s: 100.0,
            connected: 3,
            program_idle: false,
            interval_s: 5.0,
        }
    }

    #[test]
    fn watchdog_policy() {
        assert!(w().healthy());
        assert!(
            !Watchdog {
                since_loop_s: 6.0,
                ..w()
            }
            .healthy(),
            "stuck loop"
        );
        assert!(
            !Watchdog {
                since_sample_s: Some(11.0),
                ..w()
            }
            .healthy(),
            "stalled samples"
        );
        assert!(
            Watchdog {
                since_sample_s: Some(11.0),
                program_idle: true,
                ..w()
            }
            .healthy()
        );
        assert!(
            Watchdog {
                since_sample_s: Some(11.0),
                connected: 0,
                ..w()
            }
            .healthy()
        );
        assert!(
            Watchdog {
                since_sample_s: None,
                uptime_s: 2.0,
                ..w()
            }
            .healthy()
        );
        assert!(
            !Watchdog {
                since_sample_s: None,
                uptime_s: 20.0,
                ..w()
            }
            .healthy()
        );
    }
}
