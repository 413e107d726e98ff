//! Pseudo-terminals standing in for the USB / serial ports of real instruments.
//!
//! A device owns only the master side. The slave is opened once, at creation, to set it raw
//! and is closed again at once: holding it would hide the host's close/open from the device
//! (a master read fails with `EIO` exactly while no slave is open) and would keep the tty alive
//! after an unplug. Closing the master is the unplug: the kernel removes `/dev/pts/N` and the
//! host's next read returns end-of-file.
//!
//! Each device is published under a stable symlink (`<dir>/li80 -> /dev/pts/N`), as a udev rule
//! does for a real adapter, and the symlink is re-pointed on replug.

use std::io;
use std::os::fd::{AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use tokio::io::unix::AsyncFd;

/// What one non-blocking read of the master returned.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum ReadOutcome {
    /// Bytes from the host.
    Data(usize),
    /// The host has the port open, nothing to read.
    Idle,
    /// No process has the slave open (the host closed the port or never opened it).
    NoHost,
}

/// The master side of one pseudo-terminal, published under a stable symlink.
pub(crate) struct Pty {
    /// `None` only transiently inside [`Pty::rearm`].
    master: Option<AsyncFd<OwnedFd>>,
    pts: PathBuf,
    link: PathBuf,
}

impl Pty {
    /// Create a raw pseudo-terminal and point `link` at its slave (replacing an old link).
    pub(crate) fn open(link: &Path) -> io::Result<Pty> {
        let pair = nix::pty::openpty(None, None).map_err(io::Error::from)?;
        // Both sides raw at once: a fresh pty echoes input and maps CR to NL, which would
        // corrupt binary frames and answer the host's commands with its own bytes.
        for fd in [&pair.master, &pair.slave] {
            let mut t = tcgetattr(fd).map_err(io::Error::from)?;
            cfmakeraw(&mut t);
            tcsetattr(fd, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        }
        let pts = nix::unistd::ttyname(&pair.slave).map_err(io::Error::from)?;
        drop(pair.slave);
        let flags = fcntl(&pair.master, FcntlArg::F_GETFL).map_err(io::Error::from)?;
        let flags = OFlag::from_bits_truncate(flags) | OFlag::O_NONBLOCK;
        fcntl(&pair.master, FcntlArg::F_SETFL(flags)).map_err(io::Error::from)?;
        // SAFETY: the AsyncFd takes ownership of the OwnedFd, so the descriptor stays open and
        // refers to the same pty master until the AsyncFd is dropped.
        let master = unsafe { AsyncFd::register(pair.master) }.map_err(io::Error::from)?;
        publish_link(link, &pts)?;
        Ok(Pty {
            master: Some(master),
            pts,
            link: link.to_path_buf(),
        })
    }

    /// The `/dev/pts/N` path behind the symlink.
    pub(crate) fn pts(&self) -> &Path {
        &self.pts
    }

    /// Read what the host sent, without blocking.
    fn fd(&self) -> Option<&OwnedFd> {
        self.master.as_ref().map(|m| m.get_ref())
    }

    pub(crate) fn try_read(&self, buf: &mut [u8]) -> ReadOutcome {
        let Some(fd) = self.fd() else {
            return ReadOutcome::NoHost;
        };
        let raw = fd.as_raw_fd();
        match nix::unistd::read(fd, buf) {
            Ok(0) => ReadOutcome::NoHost,
            Ok(n) => ReadOutcome::Data(n),
            Err(nix::errno::Errno::EAGAIN) => ReadOutcome::Idle,
            Err(nix::errno::Errno::EINTR) => ReadOutcome::Idle,
            Err(e) => {
                tracing::trace!(fd = raw, error = %e, "pty master read: no host");
                ReadOutcome::NoHost
            }
        }
    }

    /// Write as much of `bytes` as the pty buffer takes now; returns the count written.
    /// `Ok(0)` when the buffer is full (the host is not reading).
    pub(crate) fn try_write(&self, bytes: &[u8]) -> io::Result<usize> {
        if bytes.is_empty() {
            return Ok(0);
        }
        let Some(fd) = self.fd() else { return Ok(0) };
        match nix::unistd::write(fd, bytes) {
            Ok(n) => Ok(n),
            Err(nix::errno::Errno::EAGAIN) | Err(nix::errno::Errno::EINTR) => Ok(0),
            Err(e) => Err(io::Error::from(e)),
        }
    }

    /// Wait until the host may have written something (only meaningful while a host has the
    /// slave open; without one the master is permanently readable with `EIO`).
    pub(crate) async fn readable(&self) -> io::Result<()> {
        let Some(m) = &self.master else {
            return std::future::pending().await;
        };
        let mut guard = m.readable().await?;
        guard.clear_ready();
        Ok(())
    }

    /// Register the master with the reactor afresh. Tokio keeps a hang-up (`EPOLLHUP`, seen
    /// while no host has the slave open) as a readiness that `clear_ready` cannot clear, so
    /// after the host (re)opens the port the old registration would report "readable" forever;
    /// a new registration starts from the pty's present state.
    pub(crate) fn rearm(&mut self) -> io::Result<()> {
        if let Some(m) = self.master.take() {
            let fd = m.into_inner();
            // SAFETY: as in `open`: the AsyncFd owns the descriptor.
            self.master = Some(unsafe { AsyncFd::register(fd) }.map_err(io::Error::from)?);
        }
        Ok(())
    }

    /// Unplug: remove the symlink and close the master (the kernel removes the pts).
    pub(crate) fn unplug(self) {
        remove_link_if_ours(&self.link, &self.pts);
        drop(self.master);
    }
}

/// Point `link` at `target`, atomically replacing whatever was there.
fn publish_link(link: &Path, target: &Path) -> io::Result<()> {
    let tmp = link.with_extension("tmp-link");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link)
}

fn remove_link_if_ours(link: &Path, pts: &Path) {
    if std::fs::read_link(link).map(|t| t == pts).unwrap_or(false) {
        let _ = std::fs::remove_file(link);
    }
}
