//! A file written by a thread of its own ([`BgFile`]): the writer hands it buffers and seeks in
//! order and goes on; the thread does the `write(2)`s. A `write` into the page cache can block
//! for a second or more when the kernel throttles dirty pages (another process writing much,
//! a slow SD card): on the daemon's pipeline thread that held up every pose value behind it
//! (measured: pose latency 1.6 s at moderate rates while `dd` wrote 9 GB). With this file the
//! writer only waits when [`MAX_QUEUED`] buffers are still on their way, or when it asks for a
//! flush that syncs.
//!
//! Errors are seen one call late: the thread keeps its first error, skips everything after it,
//! and every later call of the writer returns it (with its kind, so a full disk is still told
//! as one). [`BgFile::durable`] is the end of the last flush the thread completed: what a failed
//! writer truncates the file to.

use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::sync::{Arc, Mutex};

/// Bytes gathered before they go to the thread (as `BufWriter` gathered them before).
const BUF_BYTES: usize = 1 << 20;
/// Buffers on their way at most: the writer waits beyond (16 MiB, about 80 s of a full-rate
/// log; a stall longer than that holds the writer up as a plain file would).
pub(crate) const MAX_QUEUED: usize = 16;

/// One step for the thread, in the writer's order.
enum Op {
    Write(Vec<u8>),
    Seek(u64),
    /// Everything before is written; `pos` is then durable (after `sync_data` when `sync`).
    Flush {
        pos: u64,
        sync: bool,
        done: Option<SyncSender<std::io::Result<()>>>,
    },
}

/// What the thread tells the writer.
#[derive(Default)]
struct Shared {
    error: Mutex<Option<(std::io::ErrorKind, String)>>,
    durable: AtomicU64,
}

impl Shared {
    fn error(&self) -> Option<std::io::Error> {
        let slot = self.error.lock().unwrap_or_else(|p| p.into_inner());
        slot.as_ref()
            .map(|(kind, text)| std::io::Error::new(*kind, text.clone()))
    }
    fn set_error(&self, e: &std::io::Error) {
        let mut slot = self.error.lock().unwrap_or_else(|p| p.into_inner());
        if slot.is_none() {
            *slot = Some((e.kind(), e.to_string()));
        }
    }
}

/// A file written by its own thread (see the module docs). Seeks from the start, the current
/// position and the end are known here without asking the thread.
pub(crate) struct BgFile {
    buf: Vec<u8>,
    /// Where the next byte goes.
    pos: u64,
    /// The file's length as written.
    end: u64,
    tx: Option<SyncSender<Op>>,
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<File>>,
}

impl BgFile {
    /// Takes `file` (empty, at its start) to a new writing thread.
    pub(crate) fn new(file: File) -> std::io::Result<BgFile> {
        let (tx, rx) = sync_channel(MAX_QUEUED);
        let shared = Arc::new(Shared::default());
        let theirs = shared.clone();
        let thread = std::thread::Builder::new()
            .name("log-write".into())
            .spawn(move || write_loop(file, rx, &theirs))?;
        Ok(BgFile {
            buf: Vec::with_capacity(BUF_BYTES),
            pos: 0,
            end: 0,
            tx: Some(tx),
            shared,
            thread: Some(thread),
        })
    }

    /// End of the last flush the thread completed.
    pub(crate) fn durable(&self) -> u64 {
        self.shared.durable.load(Ordering::Acquire)
    }

    /// Everything written before is on its way; with `sync`, waits until it is written and
    /// synced (`sync_data`) and returns how that went. Without, returns at once.
    pub(crate) fn flush_to_disk(&mut self, sync: bool) -> std::io::Result<()> {
        self.send_buf()?;
        let (done, answer) = match sync {
            true => {
                let (tx, rx) = sync_channel(1);
                (Some(tx), Some(rx))
            }
            false => (None, None),
        };
        self.send(Op::Flush {
            pos: self.end,
            sync,
            done,
        })?;
        match answer.map(|rx| rx.recv()) {
            None => Ok(()),
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(self.gone()),
        }
    }

    /// Stops the thread after what is queued and gives the file back, with the end of the
    /// last flush that completed.
    pub(crate) fn into_file(mut self) -> (Option<File>, u64) {
        self.tx = None;
        let file = self.thread.take().and_then(|h| h.join().ok());
        (file, self.durable())
    }

    fn send_buf(&mut self) -> std::io::Result<()> {
        if self.buf.is_empty() {
            return Ok(());
        }
        let full = std::mem::replace(&mut self.buf, Vec::with_capacity(BUF_BYTES));
        self.send(Op::Write(full))
    }

    fn send(&mut self, op: Op) -> std::io::Result<()> {
        if let Some(e) = self.shared.error() {
            return Err(e);
        }
        match self.tx.as_ref().map(|tx| tx.send(op)) {
            Some(Ok(())) => Ok(()),
            _ => Err(self.gone()),
        }
    }

    /// The thread's error, or that it is gone.
    fn gone(&self) -> std::io::Error {
        self.shared
            .error()
            .unwrap_or_else(|| std::io::Error::other("the log's writing thread ended"))
    }
}

impl Write for BgFile {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        if let Some(e) = self.shared.error() {
            return Err(e);
        }
        self.buf.extend_from_slice(data);
        self.pos += data.len() as u64;
        self.end = self.end.max(self.pos);
        if self.buf.len() >= BUF_BYTES {
            self.send_buf()?;
        }
        Ok(data.len())
    }

    /// Hands everything on to the thread without waiting (see [`BgFile::flush_to_disk`]).
    fn flush(&mut self) -> std::io::Result<()> {
        self.send_buf()
    }
}

impl Seek for BgFile {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => self.end.checked_add_signed(d),
            SeekFrom::Current(d) => self.pos.checked_add_signed(d),
        }
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "seek before 0"))?;
        if target != self.pos {
            self.send_buf()?;
            self.send(Op::Seek(target))?;
            self.pos = target;
        }
        Ok(target)
    }
}

impl Drop for BgFile {
    /// Lets the thread write what is queued and end.
    fn drop(&mut self) {
        self.tx = None;
        if let Some(h) = self.thread.take() {
            let _ = h.join();
        }
    }
}

/// The thread: does each step in order; after the first error it only answers flushes (with
/// that error). Returns the file when the writer is gone.
fn write_loop(mut file: File, rx: Receiver<Op>, shared: &Shared) -> File {
    let mut failed = false;
    while let Ok(op) = rx.recv() {
        let r = match op {
            _ if failed => Err(shared
                .error()
                .unwrap_or_else(|| std::io::Error::other("failed"))),
            Op::Write(data) => file.write_all(&data),
            Op::Seek(p) => file.seek(SeekFrom::Start(p)).map(|_| ()),
            Op::Flush { pos, sync, done } => {
                let r = if sync { file.sync_data() } else { Ok(()) };
                if r.is_ok() {
                    shared.durable.store(pos, Ordering::Release);
                }
                let answer = r.as_ref().map(|_| ()).map_err(clone_error);
                if let Some(done) = done {
                    let _ = done.send(answer);
                }
                r
            }
        };
        if let Err(e) = r
            && !failed
        {
            failed = true;
            shared.set_error(&e);
        }
    }
    file
}

fn clone_error(e: &std::io::Error) -> std::io::Error {
    std::io::Error::new(e.kind(), e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    fn read_all(path: &std::path::Path) -> Vec<u8> {
        let mut v = Vec::new();
        File::open(path).unwrap().read_to_end(&mut v).unwrap();
        v
    }

    /// Writes, a seek back to patch a header, a seek to the end and a syncing flush give the
    /// bytes a plain file given the same calls holds.
    #[test]
    fn the_same_bytes_as_a_plain_file() {
        let dir = tempfile::tempdir().unwrap();
        let calls = |w: &mut dyn WriteSeek| {
            w.write_all(b"HEADER??").unwrap();
            let big = vec![7u8; BUF_BYTES + 123];
            w.write_all(&big).unwrap();
            assert_eq!(w.stream_position().unwrap(), 8 + big.len() as u64);
            w.seek(SeekFrom::Start(6)).unwrap();
            w.write_all(b"OK").unwrap();
            w.seek(SeekFrom::End(0)).unwrap();
            w.write_all(b"tail").unwrap();
            w.flush().unwrap();
        };
        let plain = dir.path().join("plain");
        calls(&mut File::create(&plain).unwrap());
        let bg = dir.path().join("bg");
        let mut f = BgFile::new(File::create(&bg).unwrap()).unwrap();
        calls(&mut f);
        f.flush_to_disk(true).unwrap();
        assert_eq!(f.durable(), 8 + BUF_BYTES as u64 + 123 + 4);
        drop(f);
        assert_eq!(read_all(&bg), read_all(&plain));
    }

    /// A write that fails on the thread (a full disk) is returned, with its kind, by a later
    /// call; the durable end stays at the last flush that worked.
    #[test]
    #[cfg(target_os = "linux")]
    fn a_full_disk_comes_back_with_its_kind() {
        let full = std::fs::OpenOptions::new().write(true).open("/dev/full");
        let Ok(full) = full else { return };
        let mut f = BgFile::new(full).unwrap();
        f.write_all(b"abc").unwrap();
        let e = f.flush_to_disk(true).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::StorageFull, "{e}");
        assert_eq!(f.durable(), 0);
        let e = f.write(b"more").unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::StorageFull);
        let (file, durable) = f.into_file();
        assert!(file.is_some());
        assert_eq!(durable, 0);
    }

    trait WriteSeek: Write + Seek {}
    impl<T: Write + Seek> WriteSeek for T {}
}
