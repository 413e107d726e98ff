//! One open byte stream with the protocol decoder of its instrument: bytes in, decoded frames
//! and rejections out, each dated by its read's arrival time on the host clock.
//!
//! The stream is anything that reads and writes asynchronously ([`Port`]): a serial port
//! opened by [`open_port`] in service, an in-memory `tokio::io::duplex` in the tests. Opening
//! is a separate step: the driver loop asks its opener for a new stream after every loss.

use protocol::{Decoded, StreamDecoder};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio_serial::SerialPort;

use crate::tty_port::TtyPort;
use crate::{DriverError, HostClock};

/// Read buffer: large, so that one read takes everything the kernel holds.
const READ_BUF: usize = 64 * 1024;

/// A byte stream a serial driver talks over.
pub(crate) trait Port: AsyncRead + AsyncWrite + Unpin + Send {
    /// Stop waking the process for arriving bytes until the next wait (a coalescing reader's
    /// pause; see [`TtyPort`]). Nothing for a stream without a reactor registration.
    fn detach(&mut self) {}
    /// One non-blocking read while detached; `None` when the stream can only be awaited.
    fn read_detached(&mut self, _buf: &mut [u8]) -> Option<std::io::Result<usize>> {
        None
    }
}

impl Port for TtyPort {
    fn detach(&mut self) {
        TtyPort::detach(self);
    }
    fn read_detached(&mut self, buf: &mut [u8]) -> Option<std::io::Result<usize>> {
        TtyPort::read_detached(self, buf)
    }
}

#[cfg(test)]
impl Port for tokio::io::DuplexStream {}

/// An open stream, its decoder and its read buffer.
pub(crate) struct SerialLink<D, P> {
    port: P,
    decoder: D,
    buf: Box<[u8]>,
    clock: HostClock,
    pub(crate) path: String,
}

/// Open `path` at `baud`, 8N1, no flow control, and forget whatever the device sent before.
pub(crate) fn open_port(path: &str, baud: u32) -> std::io::Result<TtyPort> {
    let builder = tokio_serial::new(path, baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None);
    let port = mio_serial::SerialStream::open(&builder).map_err(std::io::Error::from)?;
    // Whatever the device sent before we looked is stale.
    port.clear(tokio_serial::ClearBuffer::All)
        .map_err(std::io::Error::from)?;
    Ok(TtyPort::new(port))
}

impl<D: StreamDecoder + Send, P: Port> SerialLink<D, P> {
    /// `port` (already open) with `decoder`; `path` names it in errors.
    pub(crate) fn new(port: P, decoder: D, clock: HostClock, path: &str) -> Self {
        SerialLink {
            port,
            decoder,
            buf: vec![0u8; READ_BUF].into_boxed_slice(),
            clock,
            path: path.to_string(),
        }
    }

    /// Read once (whatever is there) and hand every decoded item, with the read's arrival time
    /// (ns since the Unix epoch), to `sink`. Returns the byte count. Cancel-safe: the only await
    /// is the read itself.
    pub(crate) async fn read(
        &mut self,
        mut sink: impl FnMut(Decoded<D::Frame>, u64),
    ) -> Result<usize, DriverError> {
        // Out of the reactor (a coalesced read on its tick): one plain read, and a wait only
        // if nothing is there.
        let read = match self.port.read_detached(&mut self.buf) {
            Some(Err(e)) if e.kind() == std::io::ErrorKind::WouldBlock => None,
            other => other,
        };
        let read = match read {
            Some(r) => r,
            None => self.port.read(&mut self.buf).await,
        };
        let n = match read {
            Ok(0) => return Err(DriverError::EndOfFile),
            Ok(n) => n,
            Err(e) => return Err(DriverError::ReadFailed { cause: e.into() }),
        };
        let host_ns = self.clock.now_ns();
        self.decoder
            .feed(&self.buf[..n], |item| sink(item, host_ns));
        Ok(n)
    }

    /// Write a command line (with its terminator).
    pub(crate) async fn write_line(&mut self, line: &str) -> Result<(), DriverError> {
        self.port
            .write_all(line.as_bytes())
            .await
            .map_err(|e| DriverError::WriteFailed {
                command: line.trim().to_string(),
                cause: e.into(),
            })?;
        self.port
            .flush()
            .await
            .map_err(|e| DriverError::FlushFailed { cause: e.into() })
    }

    /// Leave the reactor until the next wait (see [`Port::detach`]).
    pub(crate) fn detach(&mut self) {
        self.port.detach();
    }

    /// Forget a partial frame.
    pub(crate) fn reset_decoder(&mut self) {
        self.decoder.reset();
    }
}
