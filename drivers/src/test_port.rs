//! In-memory ports for the driver tests: the driver talks to its end of a `tokio::io::duplex`,
//! the test plays the device on the other end, byte for byte as the instrument contract
//! (docs/instruments.md) says. Nothing here waits on time: each step waits for the bytes or
//! the event it needs.

use std::io;
use std::sync::mpsc;

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader, DuplexStream};

use crate::DriverEvent;

/// Where the test plugs devices in: the driver's opener gets them in turn.
pub(crate) struct Socket(mpsc::Sender<DuplexStream>);

/// A socket and the opener to give the driver loop: the next plugged port, or "not found"
/// while none is (the loop retries with backoff, as with a vanished serial port).
pub(crate) fn socket() -> (Socket, impl FnMut() -> io::Result<DuplexStream> + Send) {
    let (tx, rx) = mpsc::channel();
    let open = move || {
        rx.try_recv()
            .map_err(|_| io::Error::new(io::ErrorKind::NotFound, "no device plugged in"))
    };
    (Socket(tx), open)
}

impl Socket {
    /// Plug in a device: the driver opens the other end at its next attempt.
    pub(crate) fn plug(&self) -> Device {
        let (driver_end, device_end) = tokio::io::duplex(64 * 1024);
        self.0.send(driver_end).expect("the opener is alive");
        Device {
            io: BufReader::new(device_end),
        }
    }
}

/// The device's end of a port. Dropping it unplugs the device (the driver reads end of file).
pub(crate) struct Device {
    io: BufReader<DuplexStream>,
}

impl Device {
    /// Reads the next command, through its `\n`, and checks that it is `line` byte for byte.
    pub(crate) async fn expect(&mut self, line: &str) {
        let mut got = Vec::new();
        self.io.read_until(b'\n', &mut got).await.unwrap();
        assert_eq!(
            String::from_utf8_lossy(&got),
            line,
            "command from the driver"
        );
    }

    /// Writes `bytes` as the device would.
    pub(crate) async fn send(&mut self, bytes: &str) {
        let w = self.io.get_mut();
        w.write_all(bytes.as_bytes()).await.unwrap();
        w.flush().await.unwrap();
    }
}

/// `$<body>*HH\r\n`, `HH` the XOR of the bytes of `body` in upper-case hex (instruments.md §1).
pub(crate) fn nmea(body: &str) -> String {
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{sum:02X}\r\n")
}

/// The next event that is not a counters snapshot (those come on every connection change and
/// about once a second; the tests read them from the last one).
pub(crate) async fn next_event(rx: &mut tokio::sync::mpsc::Receiver<DriverEvent>) -> DriverEvent {
    loop {
        match rx.recv().await.expect("the driver is running") {
            DriverEvent::Counters { .. } => continue,
            ev => return ev,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nmea_checksum_is_the_contract_s() {
        // A line whose checksum was worked out by hand: XOR of "POS,1,2,3,50,0" is 0x65.
        assert_eq!(nmea("POS,1,2,3,50,0"), "$POS,1,2,3,50,0*65\r\n");
    }
}
