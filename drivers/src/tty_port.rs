//! A serial port that can leave the reactor while its reader coalesces (docs/design.md, "Where
//! the daemon's CPU goes").
//!
//! A port registered in tokio's epoll set wakes a worker thread for every write of the device
//! (every 1–2 ms per instrument), even while no task waits on it: the reader sleeps until the
//! next coalescing tick and then drains everything at once. [`TtyPort`] leaves the epoll set
//! for that sleep ([`TtyPort::detach`]); the read on the tick is then one plain non-blocking
//! `read(2)`, and only a read that finds nothing (a sparse device, the clock-fit probe) joins
//! the reactor again to wait. `tokio_serial::SerialStream` cannot leave it (its `AsyncFd` is
//! private), hence this thin wrapper around the same `mio_serial::SerialStream`.

use std::io::{self, Read, Write};
use std::pin::Pin;
use std::task::{Context, Poll, ready};

use mio_serial::SerialStream;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// Where the port is: in the reactor (waits are woken by epoll) or out of it (plain
/// non-blocking reads and writes, no wake-ups).
enum State {
    Attached(AsyncFd<SerialStream>),
    Detached(SerialStream),
    /// Only while moving between the two.
    Moving,
}

/// An open serial port (non-blocking, as `mio_serial` opens it).
pub(crate) struct TtyPort {
    state: State,
}

impl TtyPort {
    /// A port opened by `mio_serial`; it starts out of the reactor.
    pub(crate) fn new(port: SerialStream) -> Self {
        TtyPort {
            state: State::Detached(port),
        }
    }

    /// Leave the reactor: bytes that arrive from now on wake nobody until the next wait.
    pub(crate) fn detach(&mut self) {
        self.state = match std::mem::replace(&mut self.state, State::Moving) {
            State::Attached(fd) => State::Detached(fd.into_inner()),
            other => other,
        };
    }

    /// One non-blocking read while out of the reactor (`WouldBlock` when nothing is there);
    /// `None` while in it (wait through `AsyncRead` instead).
    pub(crate) fn read_detached(&mut self, buf: &mut [u8]) -> Option<io::Result<usize>> {
        match &mut self.state {
            State::Detached(p) => Some(p.read(buf)),
            State::Attached(_) => None,
            State::Moving => Some(Err(moving())),
        }
    }

    /// The registered port, joining the reactor first if it is out of it.
    fn attached(&mut self) -> io::Result<&AsyncFd<SerialStream>> {
        self.state = match std::mem::replace(&mut self.state, State::Moving) {
            // SAFETY: the `mio_serial::SerialStream` owns its file descriptor, keeps it open for
            // its whole life and returns the same one from every `as_raw_fd`; it moves into the
            // `AsyncFd` and leaves it only through `into_inner` (`detach`).
            State::Detached(p) => match unsafe { AsyncFd::register(p) } {
                Ok(fd) => State::Attached(fd),
                Err(e) => {
                    let (p, cause) = e.into_parts();
                    self.state = State::Detached(p);
                    return Err(cause);
                }
            },
            other => other,
        };
        match &self.state {
            State::Attached(fd) => Ok(fd),
            _ => Err(moving()),
        }
    }
}

/// Never returned in practice: the state is `Moving` only inside `detach` and `attached`.
fn moving() -> io::Error {
    io::Error::other("the serial port is between the reactor and plain reads")
}

impl AsyncRead for TtyPort {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let fd = self.get_mut().attached()?;
        loop {
            let mut guard = ready!(fd.poll_read_ready(cx))?;
            match guard.try_io(|p| p.get_ref().read(buf.initialize_unfilled())) {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for TtyPort {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let fd = self.get_mut().attached()?;
        loop {
            let mut guard = ready!(fd.poll_write_ready(cx))?;
            if let Ok(r) = guard.try_io(|p| p.get_ref().write(buf)) {
                return Poll::Ready(r);
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let fd = self.get_mut().attached()?;
        loop {
            let mut guard = ready!(fd.poll_write_ready(cx))?;
            if let Ok(r) = guard.try_io(|p| p.get_ref().flush()) {
                return Poll::Ready(r);
            }
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.poll_flush(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    /// A pty pair: (the device's end, the driver's port). Raw at once, as the simulator does.
    fn pair() -> (SerialStream, TtyPort) {
        let (master, slave) = SerialStream::pair().expect("a pty pair");
        (master, TtyPort::new(slave))
    }

    #[tokio::test]
    async fn a_detached_port_reads_without_the_reactor_and_waits_with_it() {
        let (mut device, mut port) = pair();
        let mut buf = [0u8; 64];
        // Out of the reactor: nothing there is WouldBlock, not a wait.
        let nothing = port.read_detached(&mut buf).expect("detached");
        assert_eq!(
            nothing.map_err(|e| e.kind()),
            Err(io::ErrorKind::WouldBlock)
        );
        // Bytes written meanwhile are all there on the next plain read.
        device.write_all(b"one\ntwo\n").expect("device writes");
        let mut got = Vec::new();
        while got.len() < 8 {
            match port.read_detached(&mut buf).expect("detached") {
                Ok(n) => got.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => tokio::task::yield_now().await,
                Err(e) => panic!("read failed: {e}"),
            }
        }
        assert_eq!(got, b"one\ntwo\n");
        // A wait joins the reactor; bytes written after it wake it.
        let writer = std::thread::spawn(move || {
            device.write_all(b"three\n").expect("device writes");
            device
        });
        let n = port.read(&mut buf).await.expect("an attached read");
        assert!(n > 0 && b"three\n".starts_with(&buf[..n]));
        assert!(port.read_detached(&mut buf).is_none(), "attached now");
        // The driver writes through it too, in or out of the reactor.
        port.write_all(b"DATUM\n").await.expect("write attached");
        port.detach();
        port.write_all(b"STREAM ON\n")
            .await
            .expect("write detached");
        let mut device = writer.join().expect("writer");
        let mut cmd = Vec::new();
        while !cmd.ends_with(b"STREAM ON\n") {
            match device.read(&mut buf) {
                Ok(n) => cmd.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => tokio::task::yield_now().await,
                Err(e) => panic!("device read failed: {e}"),
            }
        }
        assert_eq!(cmd, b"DATUM\nSTREAM ON\n");
    }

    #[tokio::test]
    async fn a_closed_device_is_an_error_out_of_the_reactor_too() {
        let (device, mut port) = pair();
        drop(device);
        let mut buf = [0u8; 16];
        let r = port.read_detached(&mut buf).expect("detached");
        let ended = match r {
            Ok(n) => n == 0,
            Err(e) => e.kind() != io::ErrorKind::WouldBlock,
        };
        assert!(ended, "a read of a closed pty ends the session");
    }
}
