//! One open byte stream with the protocol decoder of its instrument: bytes in, decoded frames
//! and rejections out, each dated by its read's arrival time on the host clock.
//!
//! The stream is anything that reads and writes asynchronously ([`Port`]): a serial port
//! opened by [`open_port`] in service (a [`TtyPort`], in no epoll set between waits), an in-memory `tokio::io::duplex` in the tests. Opening
//! is a separate step: the driver loop asks its opener for a new stream after every loss.

use std::pin::Pin;
use std::task::{Context, Poll, Waker};

use protocol::{Decoded, StreamDecoder};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};

pub(crate) use crate::tty::TtyPort;
use crate::{DriverError, HostClock};

/// Read buffer: large, so that one read takes everything the kernel holds.
const READ_BUF: usize = 64 * 1024;

/// A byte stream a serial driver talks over.
pub(crate) trait Port: AsyncRead + AsyncWrite + Unpin + Send {
    /// Read what is there now, without waiting and without asking to be woken when more
    /// comes: `None` when nothing is, `Some(0)` at end of file. (A serial port read on the
    /// coalescing tick is then in no epoll set between ticks, see [`TtyPort`].)
    fn read_now(&mut self, buf: &mut [u8]) -> std::io::Result<Option<usize>> {
        let mut cx = Context::from_waker(Waker::noop());
        let mut rb = ReadBuf::new(buf);
        match Pin::new(&mut *self).poll_read(&mut cx, &mut rb) {
            Poll::Ready(Ok(())) => Ok(Some(rb.filled().len())),
            Poll::Ready(Err(e)) => Err(e),
            Poll::Pending => Ok(None),
        }
    }
    /// Stop asking to be woken when bytes arrive, until the next read that waits.
    fn unwatch(&mut self) {}
}

impl Port for TtyPort {
    fn read_now(&mut self, buf: &mut [u8]) -> std::io::Result<Option<usize>> {
        self.try_read(buf)
    }
    fn unwatch(&mut self) {
        TtyPort::unwatch(self)
    }
}

/// The tests' in-memory ports.
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
    TtyPort::open(path, baud)
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
        let n = match self.port.read(&mut self.buf).await {
            Ok(0) => return Err(DriverError::EndOfFile),
            Ok(n) => n,
            Err(e) => return Err(DriverError::ReadFailed { cause: e.into() }),
        };
        self.feed(n, &mut sink);
        Ok(n)
    }

    /// Read what is there now without waiting (see [`Port::read_now`]) and hand it to `sink`
    /// as [`Self::read`] does; `None` when nothing was there.
    pub(crate) fn read_now(
        &mut self,
        mut sink: impl FnMut(Decoded<D::Frame>, u64),
    ) -> Result<Option<usize>, DriverError> {
        let n = match self.port.read_now(&mut self.buf) {
            Ok(None) => return Ok(None),
            Ok(Some(0)) => return Err(DriverError::EndOfFile),
            Ok(Some(n)) => n,
            Err(e) => return Err(DriverError::ReadFailed { cause: e.into() }),
        };
        self.feed(n, &mut sink);
        Ok(Some(n))
    }

    /// Decode the first `n` bytes of the buffer, all dated now.
    fn feed(&mut self, n: usize, sink: &mut impl FnMut(Decoded<D::Frame>, u64)) {
        let host_ns = self.clock.now_ns();
        self.decoder
            .feed(&self.buf[..n], |item| sink(item, host_ns));
    }

    /// Take the port out of the runtime's epoll set until the next read that waits.
    pub(crate) fn unwatch(&mut self) {
        self.port.unwatch();
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

    /// Forget a partial frame.
    pub(crate) fn reset_decoder(&mut self) {
        self.decoder.reset();
    }
}
