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

#[cfg(test)]
mod tests {
    use std::os::fd::{FromRawFd, OwnedFd};
    use std::time::Duration;

    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    use super::*;

    /// A pty pair: the master (the device's end) and the slave's path.
    fn pty() -> (std::fs::File, String) {
        let (mut master, mut slave) = (-1, -1);
        // SAFETY: openpty writes two fds; the name, termios and winsize pointers may be null.
        let r = unsafe {
            libc::openpty(
                &mut master,
                &mut slave,
                std::ptr::null_mut(),
                std::ptr::null(),
                std::ptr::null(),
            )
        };
        assert_eq!(r, 0, "openpty: {}", io::Error::last_os_error());
        // SAFETY: both fds were just opened and are owned here alone.
        let (master, slave) =
            unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        let path = std::fs::read_link(format!("/proc/self/fd/{}", slave.as_raw_fd())).unwrap();
        drop(slave);
        (std::fs::File::from(master), path.display().to_string())
    }

    /// The fds in the process's epoll sets, read from the kernel (`/proc/self/fdinfo` of every
    /// eventpoll fd lists its targets as `tfd:`), not from tokio.
    fn in_epoll_sets() -> Vec<RawFd> {
        let mut fds = Vec::new();
        for e in std::fs::read_dir("/proc/self/fd").unwrap().flatten() {
            let is_epoll = std::fs::read_link(e.path())
                .is_ok_and(|l| l.to_string_lossy().contains("eventpoll"));
            let info = std::fs::read_to_string(format!(
                "/proc/self/fdinfo/{}",
                e.file_name().to_string_lossy()
            ));
            if let (true, Ok(info)) = (is_epoll, info) {
                fds.extend(info.lines().filter_map(|l| {
                    l.strip_prefix("tfd:")?
                        .split_whitespace()
                        .next()?
                        .parse::<RawFd>()
                        .ok()
                }));
            }
        }
        fds
    }

    /// A tty is in the runtime's epoll set only while a read waits on it; read without waiting
    /// it gives nothing, then the bytes written; a closed master is an error, as a pulled USB
    /// adapter is.
    #[tokio::test]
    async fn a_tty_is_watched_only_while_a_read_waits_and_sees_its_master_close() {
        use std::io::Write;
        let (mut master, path) = pty();
        let mut port = TtyPort::open(&path, 115_200).unwrap();
        let fd = port.tty.as_raw_fd();
        let mut buf = [0u8; 64];
        assert!(port.try_read(&mut buf).unwrap().is_none());
        assert!(!in_epoll_sets().contains(&fd), "watched before any wait");

        // A waiting read registers the tty, then gets the bytes.
        {
            let mut read = std::pin::pin!(port.read(&mut buf));
            let first = tokio::time::timeout(Duration::ZERO, &mut read).await;
            assert!(first.is_err(), "read something before it was written");
            assert!(in_epoll_sets().contains(&fd), "not watched while waiting");
            master.write_all(b"hello").unwrap();
            let n = tokio::time::timeout(Duration::from_secs(10), read)
                .await
                .unwrap()
                .unwrap();
            assert_eq!(n, 5);
        }
        assert_eq!(&buf[..5], b"hello");
        port.unwatch();
        assert!(
            !in_epoll_sets().contains(&fd),
            "still watched after unwatch"
        );

        // Commands go out through the same fd.
        port.write_all(b"STREAM ON\n").await.unwrap();
        let mut line = [0u8; 10];
        std::io::Read::read_exact(&mut master, &mut line).unwrap();
        assert_eq!(&line, b"STREAM ON\n");

        // Bytes written meanwhile are there for a read that does not wait.
        master.write_all(b"12345").unwrap();
        let mut got = Vec::new();
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        while got.len() < 5 && tokio::time::Instant::now() < deadline {
            match port.try_read(&mut buf).unwrap() {
                Some(n) => got.extend_from_slice(&buf[..n]),
                None => tokio::time::sleep(Duration::from_millis(1)).await,
            }
        }
        assert_eq!(got, b"12345");
        assert!(
            !in_epoll_sets().contains(&fd),
            "a read that does not wait registered"
        );

        // The device's end closes: a read without waiting says so (EIO or end of file, both
        // a lost port for the driver loop), not "nothing yet".
        drop(master);
        let gone = loop {
            match port.try_read(&mut buf) {
                Err(e) => break format!("error {e}"),
                Ok(Some(0)) => break "end of file".to_string(),
                Ok(got) if tokio::time::Instant::now() > deadline => panic!("still {got:?}"),
                Ok(_) => tokio::time::sleep(Duration::from_millis(1)).await,
            }
        };
        eprintln!("closed master: {gone}");
    }
}
