//! The binary's exit codes (README, "Exit codes and failure modes"). systemd decides from them
//! whether a restart can help: `RestartPreventExitStatus=` in deploy/metrolog.service lists
//! exactly the codes of [`NO_RESTART`] (checked by daemon/tests/svc_exit.rs).
//!
//! The numbers follow BSD's sysexits.h where one fits, so they read the same to an operator
//! who knows them from other daemons.

use crate::acquire::config::ConfigError;

/// Finished: program end (`stop_at_program_end = true`), SIGTERM/SIGINT, or a command done.
pub const OK: u8 = 0;
/// A runtime failure a restart may cure (an internal error, a device stack that went away).
pub const FAILURE: u8 = 1;
/// The command line is wrong (clap's own code for usage errors).
pub const USAGE: u8 = 2;
/// EX_UNAVAILABLE: no device was connected for `[run] connect_timeout_s` and none is
/// `hotplug` (README, "Nothing connected"): the kit is unplugged, off, or on other ports.
pub const NOTHING_CONNECTED: u8 = 69;
/// EX_SOFTWARE: the pipeline thread panicked (a bug; the log's prefix stays readable).
pub const SOFTWARE: u8 = 70;
/// EX_CANTCREAT: the run's log could not be created (output directory missing and not
/// creatable, no permission, disk already full).
pub const CANT_CREATE: u8 = 73;
/// EX_IOERR: the log could not be written during the run (disk full, I/O error): the run
/// stopped that file (its prefix readable) and ended.
pub const IO_ERROR: u8 = 74;
/// EX_CONFIG: the configuration file is missing, unreadable or invalid.
pub const CONFIG: u8 = 78;

/// Every code the binary exits with, with its meaning (for the README and the unit test).
pub const ALL: [(u8, &str); 8] = [
    (OK, "finished"),
    (FAILURE, "runtime failure"),
    (USAGE, "command-line usage error"),
    (
        NOTHING_CONNECTED,
        "no device connected within connect_timeout_s",
    ),
    (SOFTWARE, "internal error (pipeline thread panicked)"),
    (CANT_CREATE, "the log file could not be created"),
    (
        IO_ERROR,
        "the log could not be written (disk full, I/O error)",
    ),
    (CONFIG, "invalid configuration"),
];

/// Codes after which restarting the same unit cannot help until an operator acts (fix the
/// config or the unit's command line, free disk space, fix permissions, plug the kit in):
/// systemd must not restart on them, or a bad config would be retried `StartLimitBurst` times
/// for nothing (and an unplugged kit would leave a new empty log every minute).
pub const NO_RESTART: [u8; 5] = [USAGE, NOTHING_CONNECTED, CANT_CREATE, IO_ERROR, CONFIG];

/// The run's log could not be created: exits [`CANT_CREATE`].
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct LogCreateFailed(pub String);

/// The run's log could not be written: exits [`IO_ERROR`].
#[derive(Debug, thiserror::Error)]
#[error("the log could not be written, the run stopped: {0}")]
pub struct LogWriteFailed(pub String);

/// A command's output file could not be written (no such directory, no permission, disk
/// full): exits [`IO_ERROR`].
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct OutputWriteFailed(pub String);

/// No device connected within the configured time: exits [`NOTHING_CONNECTED`].
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct NothingConnected(pub String);

/// The pipeline thread panicked: exits [`SOFTWARE`].
#[derive(Debug, thiserror::Error)]
#[error("the pipeline thread panicked; the log may be incomplete")]
pub struct PipelinePanicked;

/// The exit code for an error that ended the binary.
pub fn code_for(e: &anyhow::Error) -> u8 {
    for cause in e.chain() {
        if cause.is::<ConfigError>() {
            return CONFIG;
        }
        if cause.is::<LogWriteFailed>() || cause.is::<OutputWriteFailed>() {
            return IO_ERROR;
        }
        if cause.is::<LogCreateFailed>() {
            return CANT_CREATE;
        }
        if cause.is::<PipelinePanicked>() {
            return SOFTWARE;
        }
        if cause.is::<NothingConnected>() {
            return NOTHING_CONNECTED;
        }
    }
    FAILURE
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_map_to_their_codes() {
        let cfg = ConfigError::Invalid {
            path: "x.toml".into(),
            line: 1,
            column: 1,
            message: "bad".into(),
        };
        assert_eq!(code_for(&anyhow::Error::new(cfg)), CONFIG);
        let wrapped = anyhow::Error::new(LogWriteFailed("No space left on device".into()))
            .context("run ended");
        assert_eq!(code_for(&wrapped), IO_ERROR);
        assert_eq!(
            code_for(&anyhow::Error::new(LogCreateFailed("x".into()))),
            CANT_CREATE
        );
        assert_eq!(code_for(&anyhow::Error::new(PipelinePanicked)), SOFTWARE);
        assert_eq!(
            code_for(&anyhow::Error::new(NothingConnected("x".into()))),
            NOTHING_CONNECTED
        );
        assert_eq!(
            code_for(&anyhow::Error::new(OutputWriteFailed("x".into()))),
            IO_ERROR
        );
        assert_eq!(code_for(&anyhow::anyhow!("something else")), FAILURE);
    }

    #[test]
    fn codes_are_distinct_and_no_restart_codes_are_documented() {
        let mut codes: Vec<u8> = ALL.iter().map(|(c, _)| *c).collect();
        codes.sort_unstable();
        codes.dedup();
        assert_eq!(codes.len(), ALL.len());
        for c in NO_RESTART {
            assert!(codes.contains(&c), "{c}");
        }
        assert!(!NO_RESTART.contains(&OK) && !NO_RESTART.contains(&FAILURE));
    }
}
