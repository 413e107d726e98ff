//! A serial port that is in no epoll set unless a task waits on it.
//!
//! Read coalescing (docs/design.md, "Where the daemon's CPU goes") reads a streaming port on a
//! timer tick. A port registered with the runtime's epoll set (as `tokio-serial` keeps it)
//! still wakes a worker thread for every device write, although no task waits for it until the
//! tick. [`TtyPort`] is the open tty in non-blocking mode with no registration: a read on the
//! tick is a plain `read(2)` ([`crate::serial_link::Port::read_now`]); only a read or a write
//! that has to wait (a command's answer, a probe read, the SLCAN triggers) registers it, and
//! [`crate::serial_link::Port::unwatch`] takes it out again.

use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::pin::Pin;
use std::task::{Context, Poll, ready};

use serialport::SerialPort;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, Interest, ReadBuf};

/// An open tty, non-blocking, registered with the runtime only while a task waits on it.
pub(crate) struct TtyPort {
    // Declared first, so dropped (deregistered) before `tty` closes the fd.
    watch: Option<AsyncFd<RawFd>>,
    tty: serialport::TTYPort,
}

impl TtyPort {
    /// Open `path` at `baud`, 8N1, no flow control, exclusively, and forget whatever the
    /// device sent before.
    pub(crate) fn open(path: &str, baud: u32) -> io::Result<Self> {
        let builder = serialport::new(path, baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None);
        let tty = serialport::TTYPort::open(&builder).map_err(io::Error::from)?;
        set_nonblocking(tty.as_raw_fd())?;
        // Whatever the device sent before we looked is stale.
        tty.clear(serialport::ClearBuffer::All)
            .map_err(io::Error::from)?;
        Ok(TtyPort { watch: None, tty })
    }

    /// The registration with the runtime (made now if there is none).
    fn watch(&mut self) -> io::Result<&AsyncFd<RawFd>> {
        if self.watch.is_none() {
            let fd = self.tty.as_raw_fd();
            // SAFETY: the fd stays open while the registration lives: `watch` is dropped
            // before `tty` (field order, `unwatch`), and nothing else closes it.
            let w = unsafe {
                AsyncFd::register_with_interest(fd, Interest::READABLE | Interest::WRITABLE)
            };
            self.watch = Some(w?);
        }
        match &self.watch {
            Some(w) => Ok(w),
            None => Err(io::Error::other("no registration")),
        }
    }

    /// Read what is there now; `None` when nothing is.
    pub(crate) fn try_read(&self, buf: &mut [u8]) -> io::Result<Option<usize>> {
        let fd = self.tty.as_raw_fd();
        // SAFETY: the fd is open for as long as `self.tty` lives; `buf` is valid for its length.
        retry(|| unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) })
    }

    fn try_write(&self, data: &[u8]) -> io::Result<Option<usize>> {
        let fd = self.tty.as_raw_fd();
        // SAFETY: as in `try_read`.
        retry(|| unsafe { libc::write(fd, data.as_ptr().cast(), data.len()) })
    }

    /// Take the port out of the runtime's epoll set (a later wait puts it back).
    pub(crate) fn unwatch(&mut self) {
        self.watch = None;
    }
}

/// Run a read(2) or write(2) until it is not interrupted: the count, `None` for EAGAIN, or
/// the error.
fn retry(mut call: impl FnMut() -> isize) -> io::Result<Option<usize>> {
    loop {
        let n = call();
        if n >= 0 {
            return Ok(Some(n as usize));
        }
        let e = io::Error::last_os_error();
        match e.kind() {
            io::ErrorKind::Interrupted => continue,
            io::ErrorKind::WouldBlock => return Ok(None),
            _ => return Err(e),
        }
    }
}

fn set_nonblocking(fd: RawFd) -> io::Result<()> {
    // SAFETY: fcntl on an fd we own, with integer arguments.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

impl AsyncRead for TtyPort {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        loop {
            if let Some(n) = this.try_read(buf.initialize_unfilled())? {
                buf.advance(n);
                return Poll::Ready(Ok(()));
            }
            let mut guard = ready!(this.watch()?.poll_read_ready(cx))?;
            guard.clear_ready();
        }
    }
}

impl AsyncWrite for TtyPort {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        loop {
            if let Some(n) = this.try_write(data)? {
                return Poll::Ready(Ok(n));
            }
            let mut guard = ready!(this.watch()?.poll_write_ready(cx))?;
            guard.clear_ready();
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        // A write is in the tty's buffer when it returns; the answer is what is waited for.
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}
