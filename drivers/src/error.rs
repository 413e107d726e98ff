//! Why a driver lost its port or its device, as the operator reads it in `DriverEvent::Error`
//! and `DriverEvent::Disconnected` (and in the log's `/event` topic, which stores the message).
//!
//! The messages are the ones the drivers have always printed; the variants carry the numbers
//! and paths behind them so a consumer can act on them without parsing text.

use std::sync::Arc;
use std::time::Duration;

use protocol::convert::ConvertError;

/// What went wrong with a port or a device. Cloneable (events are), so I/O causes are shared.
///
/// The I/O cause is part of the message (as the drivers always printed it) and therefore not
/// also returned by `source()`: a chain printer would otherwise print it twice.
#[derive(Debug, Clone, thiserror::Error)]
pub enum DriverError {
    /// The port reported end of file: the device or its adapter vanished.
    #[error("end of file on the port")]
    EndOfFile,
    /// Reading the port (or CAN interface) failed with `cause`.
    #[error("read failed: {cause}")]
    ReadFailed { cause: Arc<std::io::Error> },
    /// Writing `command` to the port failed with `cause`.
    #[error("write of `{command}` failed: {cause}")]
    WriteFailed {
        command: String,
        cause: Arc<std::io::Error>,
    },
    /// Flushing the port after a command failed with `cause`.
    #[error("flush failed: {cause}")]
    FlushFailed { cause: Arc<std::io::Error> },
    /// No byte arrived for `idle` while streaming: the device is taken for lost.
    #[error("no data for {:.1} s while streaming", .idle.as_secs_f64())]
    Silent { idle: Duration },
    /// The device on `port` did not answer `command` within `timeout`.
    #[error("port {port}: no answer to `{command}` within {} s", .timeout.as_secs_f64())]
    NoAnswer {
        port: String,
        command: String,
        timeout: Duration,
    },
    /// The device on `port` answered `command` with `answer`, which is not what it must answer.
    #[error("port {port}: command `{command}` answered `{}`", .answer.escape_debug())]
    UnexpectedAnswer {
        port: String,
        command: String,
        answer: String,
    },
    /// The device on `port` did not send `awaited` within `timeout`.
    #[error("port {port}: no {awaited} within {} s", .timeout.as_secs_f64())]
    NothingWithin {
        port: String,
        awaited: &'static str,
        timeout: Duration,
    },
    /// The PSD-2 on `port` refused `command`: its error queue (`SYST:ERR?`) answered `answer`.
    #[error("port {port}: command `{command}` failed: SYST:ERR? answered `{}`", .answer.escape_debug())]
    CommandFailed {
        port: String,
        command: String,
        answer: String,
    },
    /// An LI-80 `$ENV` record on `port` could not give a compensation (`cause`); the last good
    /// one stays in use.
    #[error("port {port}: `$ENV` record unusable: {cause}")]
    UnusableEnvironment { port: String, cause: ConvertError },
    /// The LI-80 on `port` sent `$ERR` with `code` and `text`.
    #[error("port {port}: device reports error {code}: {text}")]
    DeviceReported {
        port: String,
        code: u32,
        text: String,
    },
    /// The configured PSD error map of the PSD-2 on `port` is malformed (`cause`).
    #[error("port {port}: PSD error map: {cause}")]
    BadErrorMap { port: String, cause: ConvertError },
    /// The SocketCAN `interface` could not be opened (`cause`).
    #[error("cannot open CAN interface {interface}: {cause}")]
    CanInterface {
        interface: String,
        cause: Arc<std::io::Error>,
    },
}

impl DriverError {
    /// The port failed or went silent (reopen it), as opposed to a device that refused or
    /// ignored a command or sent something unusable (retry the session or carry on).
    pub fn is_port_lost(&self) -> bool {
        matches!(
            self,
            DriverError::EndOfFile
                | DriverError::ReadFailed { .. }
                | DriverError::WriteFailed { .. }
                | DriverError::FlushFailed { .. }
                | DriverError::Silent { .. }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_are_the_drivers_historic_texts() {
        let e = DriverError::NoAnswer {
            port: "/dev/x".into(),
            command: "RATE 5".into(),
            timeout: Duration::from_secs(1),
        };
        assert_eq!(
            e.to_string(),
            "port /dev/x: no answer to `RATE 5` within 1 s"
        );
        let e = DriverError::UnexpectedAnswer {
            port: "/dev/x".into(),
            command: "S6".into(),
            answer: "\x07".into(),
        };
        assert_eq!(e.to_string(), "port /dev/x: command `S6` answered `\\u{7}`");
        let e = DriverError::Silent {
            idle: Duration::from_millis(2050),
        };
        assert_eq!(e.to_string(), "no data for 2.0 s while streaming");
        assert!(e.is_port_lost());
        let e = DriverError::DeviceReported {
            port: "/dev/li80".into(),
            code: 3,
            text: "beam lost".into(),
        };
        assert_eq!(
            e.to_string(),
            "port /dev/li80: device reports error 3: beam lost"
        );
        assert!(!e.is_port_lost());
    }
}
