//! MCAP writer of a run.
//!
//! Durability: the open chunk is closed, written and `fsync`ed at least every
//! `LogOptions::flush_interval` (1 s) — checked on every write and by
//! [`LogWriter::flush_if_due`], which the pipeline calls on a timer — so a power loss or
//! SIGKILL costs at most about one second of data; a closed chunk is never rewritten.
//!
//! Raw samples are gathered per topic into protobuf batches ([`crate::raw`]) of at most
//! `LogOptions::batch_interval` of host time. Before any other message is written the open
//! batches are written, so the file keeps the order in which the pipeline saw samples,
//! triggers and pose values per instrument (replay depends on it; docs/log-format.md).

use std::collections::BTreeMap;
use std::fs::OpenOptions;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};
use mcap::{Attachment, Compression, McapError, WriteOptions};
use types::{Sample, Trigger};

use super::bg_file::BgFile;
use super::raw::{self, Builder};
use super::split::{PART_METADATA, PART_NEXT_METADATA, parse_part_name, part_name};
use super::topics::{self, PoseMsg, StatusMsg, TopicMessage, TriggerMsg};
use super::{LogError, RUN_METADATA, RunMetadata};

/// Writer settings.
#[derive(Debug, Clone)]
pub struct LogOptions {
    /// Longest time a message stays in an open chunk.
    pub flush_interval: Duration,
    /// Chunk size that closes a chunk early (uncompressed bytes).
    pub chunk_size: u64,
    /// zstd level.
    pub zstd_level: u32,
    /// `fsync` the file on every flush (off only in benchmarks of the encoder).
    pub fsync: bool,
    /// Longest span of host arrival times in one raw batch.
    pub batch_interval: Duration,
    /// Most samples in one raw batch.
    pub batch_max: usize,
    /// Split the run into a new part when a part spans this much log time
    /// (`[storage] split_minutes`; `crate::split`). None: never by time.
    pub split_after: Option<Duration>,
    /// Split the run into a new part when a part holds this many bytes (`[storage] split_mb`).
    /// None: never by size.
    pub split_bytes: Option<u64>,
}

impl LogOptions {
    /// Whether a run is written as parts (`crate::split`).
    pub fn splits(&self) -> bool {
        self.split_after.is_some() || self.split_bytes.is_some()
    }
}

impl Default for LogOptions {
    fn default() -> Self {
        LogOptions {
            flush_interval: Duration::from_secs(1),
            chunk_size: 4 << 20,
            zstd_level: 3,
            fsync: true,
            batch_interval: Duration::from_millis(10),
            batch_max: 1000,
            split_after: None,
            split_bytes: None,
        }
    }
}

/// The file under the MCAP writer: written by its own thread ([`BgFile`]), its `flush`
/// reaches the disk when `fsync` (and the page cache otherwise), and it knows how much of the
/// file is durable (everything up to the end of the last flushed chunk).
struct SyncFile {
    inner: BgFile,
    fsync: bool,
    pos: u64,
    /// The file's size as written (read by the writer to split by size).
    size: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl Write for SyncFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.pos += n as u64;
        self.size
            .fetch_max(self.pos, std::sync::atomic::Ordering::Relaxed);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush_to_disk(self.fsync)
    }
}

impl Seek for SyncFile {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.pos = self.inner.seek(pos)?;
        Ok(self.pos)
    }
}

/// One channel of the log: its topic, encodings and schema, as the MCAP file declares it.
/// The live view (`metrolog::live`) advertises the same, so a client decodes both alike.
#[derive(Debug, Clone)]
pub struct ChannelSpec {
    pub topic: &'static str,
    /// `protobuf` (raw batches) or `json`.
    pub message_encoding: &'static str,
    pub schema_name: &'static str,
    /// `protobuf` (a `FileDescriptorSet`) or `jsonschema`.
    pub schema_encoding: &'static str,
    pub schema: Vec<u8>,
}

/// Every channel a log has, in the order the writer declares them: the raw topics (protobuf
/// batches), then the JSON topics (docs/log-format.md).
pub fn channel_specs() -> Vec<ChannelSpec> {
    let descriptors = raw::descriptor_set();
    let mut v: Vec<ChannelSpec> = raw::RAW_TOPICS
        .iter()
        .map(|&(topic, schema_name)| ChannelSpec {
            topic,
            message_encoding: "protobuf",
            schema_name,
            schema_encoding: "protobuf",
            schema: descriptors.clone(),
        })
        .collect();
    for (topic, schema_name, schema) in topics::json_topics() {
        v.push(ChannelSpec {
            topic,
            message_encoding: "json",
            schema_name,
            schema_encoding: "jsonschema",
            schema: serde_json::to_vec(&schema).unwrap_or_default(),
        });
    }
    v
}

/// A copy of every message the writer has written: topic, log time (ns) and the encoded
/// bytes as they are in the file. Called on the writer's thread, so it must not block
/// (the live view hands the message to a lossy queue).
pub type MessageTap = Box<dyn FnMut(&'static str, u64, &[u8]) + Send>;

/// A record every part of a split run repeats at its start.
enum Carried {
    Attachment {
        name: String,
        media_type: String,
        log_ns: u64,
        data: Vec<u8>,
    },
    Metadata {
        name: String,
        map: BTreeMap<String, String>,
    },
}

/// Where a split run stands.
struct Split {
    dir: PathBuf,
    run: String,
    part: u32,
    /// Log times of the current part's first and last message.
    first_ns: Option<u64>,
    last_ns: u64,
    /// Records repeated in every part: the attachments, and the last metadata record of
    /// each name and instrument (so what is kept stays bounded over days).
    carried: Vec<Carried>,
}

impl Split {
    fn carry(&mut self, c: Carried) {
        let key = |c: &Carried| match c {
            Carried::Attachment { name, .. } => (0, name.clone(), None),
            Carried::Metadata { name, map } => (1, name.clone(), map.get("instrument").cloned()),
        };
        let k = key(&c);
        match self.carried.iter_mut().find(|o| key(o) == k) {
            Some(old) => *old = c,
            None => self.carried.push(c),
        }
    }
}

/// Writes one run to one MCAP file, or to several when split (`LogOptions::split_after`,
/// `LogOptions::split_bytes`; `crate::split`).
pub struct LogWriter {
    mcap: Option<mcap::Writer<SyncFile>>,
    path: PathBuf,
    /// The run metadata record (repeated in every part).
    run_meta: BTreeMap<String, String>,
    split: Option<Split>,
    /// Bytes in the current file.
    size: std::sync::Arc<std::sync::atomic::AtomicU64>,
    channels: BTreeMap<&'static str, u16>,
    sequence: u32,
    messages: u64,
    last_flush: Instant,
    opts: LogOptions,
    /// The first write error: after it, every write returns it again.
    failed: Option<(String, &'static str)>,
    /// Open raw batches, by `raw::RAW_TOPICS` index.
    pending: [Builder; raw::RAW_TOPICS.len()],
    /// Encoding buffer, reused.
    buf: Vec<u8>,
    samples: u64,
    tap: Option<MessageTap>,
}

/// The error with its causes (the mcap crate's message alone hides the OS error).
fn describe(e: &McapError) -> String {
    let mut s = e.to_string();
    let mut src = std::error::Error::source(e);
    while let Some(c) = src {
        s.push_str(&format!(": {c}"));
        src = c.source();
    }
    s
}

fn hint_for(e: &McapError) -> &'static str {
    let io = match e {
        McapError::Io(io) => Some(io),
        _ => None,
    };
    match io.map(|e| e.kind()) {
        Some(std::io::ErrorKind::StorageFull) => {
            "the disk is full: free space or choose another log directory; the file holds everything up to the last flush (at most about 1 s earlier)"
        }
        Some(std::io::ErrorKind::PermissionDenied)
        | Some(std::io::ErrorKind::ReadOnlyFilesystem) => {
            "the file system refused the write: check that it is mounted read-write and writable by the metrolog user"
        }
        _ => {
            "the file holds everything up to the last flush (at most about 1 s earlier); check the disk"
        }
    }
}

/// Where part 1 of a split run named by `path` goes (see [`LogWriter::create`]).
fn first_part(path: &Path) -> Split {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let run = match parse_part_name(&name) {
        Some((run, _)) => run.to_string(),
        None => name.strip_suffix(".mcap").unwrap_or(&name).to_string(),
    };
    Split {
        dir,
        run,
        part: 1,
        first_ns: None,
        last_ns: 0,
        carried: Vec::new(),
    }
}

/// Creates `path` (which must not exist) as an MCAP file with the header, schemas and
/// channels; returns the writer and the channel ids by topic.
fn open_mcap(
    path: &Path,
    opts: &LogOptions,
    size: &std::sync::Arc<std::sync::atomic::AtomicU64>,
) -> Result<(mcap::Writer<SyncFile>, BTreeMap<&'static str, u16>), LogError> {
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .map_err(|source| LogError::Create {
            path: path.to_path_buf(),
            source,
        })?;
    let inner = BgFile::new(file).map_err(|source| LogError::Create {
        path: path.to_path_buf(),
        source,
    })?;
    let sink = SyncFile {
        inner,
        fsync: opts.fsync,
        pos: 0,
        size: size.clone(),
    };
    let wopts = WriteOptions::new()
        .compression(Some(Compression::Zstd))
        .compression_level(opts.zstd_level)
        .chunk_size(Some(opts.chunk_size))
        .profile("")
        .library(concat!("metrolog ", env!("CARGO_PKG_VERSION")));
    let werr = |e: McapError| LogError::Write {
        path: path.to_path_buf(),
        hint: hint_for(&e),
        reason: describe(&e),
    };
    let mut mcap = wopts.create(sink).map_err(werr)?;
    let mut channels = BTreeMap::new();
    for c in channel_specs() {
        let sid = mcap
            .add_schema(c.schema_name, c.schema_encoding, &c.schema)
            .map_err(werr)?;
        let cid = mcap
            .add_channel(sid, c.topic, c.message_encoding, &BTreeMap::new())
            .map_err(werr)?;
        channels.insert(c.topic, cid);
    }
    Ok((mcap, channels))
}

impl LogWriter {
    /// Creates `path` (which must not exist) and writes the header, schemas, channels and the
    /// run metadata. A split run (`opts.splits()`) starts at part 1 of the run `path` names:
    /// `path` itself when it is a part's name (`<run>-p0001.mcap`), else `<stem>-p0001.mcap`
    /// beside it ([`LogWriter::path`] says which).
    pub fn create(
        path: &Path,
        meta: &RunMetadata,
        opts: LogOptions,
    ) -> Result<LogWriter, LogError> {
        let split = opts.splits().then(|| first_part(path));
        let path = split
            .as_ref()
            .map_or(path.to_path_buf(), |s| s.dir.join(part_name(&s.run, 1)));
        let size = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        let (mcap, channels) = open_mcap(&path, &opts, &size)?;
        let mut w = LogWriter {
            mcap: Some(mcap),
            path,
            run_meta: meta.to_map(),
            split,
            size,
            channels,
            sequence: 0,
            messages: 0,
            last_flush: Instant::now(),
            opts,
            failed: None,
            pending: std::array::from_fn(|_| Builder::new(meta.capball)),
            buf: Vec::with_capacity(64 << 10),
            samples: 0,
            tap: None,
        };
        w.write_part_header(false)?;
        w.flush()?;
        Ok(w)
    }

    /// The run metadata, then (parts 2.. of a split run) the carried records, then the part
    /// record (`crate::split`).
    fn write_part_header(&mut self, carry: bool) -> Result<(), LogError> {
        let run_meta = self.run_meta.clone();
        self.put_metadata(RUN_METADATA, run_meta)?;
        let Some(sp) = self.split.as_mut() else {
            return Ok(());
        };
        let carried = if carry {
            std::mem::take(&mut sp.carried)
        } else {
            Vec::new()
        };
        let part = BTreeMap::from([
            ("run".to_string(), sp.run.clone()),
            ("part".to_string(), sp.part.to_string()),
        ]);
        let mut r = Ok(());
        for c in &carried {
            r = r.and_then(|()| match c {
                Carried::Attachment {
                    name,
                    media_type,
                    log_ns,
                    data,
                } => self.put_attachment(name, media_type, data, *log_ns),
                Carried::Metadata { name, map } => self.put_metadata(name, map.clone()),
            });
        }
        if let Some(sp) = self.split.as_mut() {
            sp.carried = carried;
        }
        r?;
        self.put_metadata(PART_METADATA, part)
    }

    /// The current part of a split run (1-based; 1 for a run that is not split).
    pub fn part(&self) -> u32 {
        self.split.as_ref().map_or(1, |s| s.part)
    }

    /// Whether the current part is due to end (its time span or size reached).
    fn split_due(&self) -> bool {
        let Some(sp) = &self.split else { return false };
        let by_time = match (self.opts.split_after, sp.first_ns) {
            (Some(d), Some(first)) => sp.last_ns.saturating_sub(first) >= d.as_nanos() as u64,
            _ => false,
        };
        let by_size = self
            .opts
            .split_bytes
            .is_some_and(|b| self.size.load(std::sync::atomic::Ordering::Relaxed) >= b);
        by_time || by_size
    }

    /// Ends the current part (naming its successor in it) and starts the next one.
    fn roll(&mut self) -> Result<(), LogError> {
        let Some(sp) = self.split.as_ref() else {
            return Ok(());
        };
        let (next, dir) = (part_name(&sp.run, sp.part + 1), sp.dir.clone());
        let map = BTreeMap::from([("next".to_string(), next.clone())]);
        self.put_metadata(PART_NEXT_METADATA, map)?;
        self.close(self.opts.fsync)?;
        let path = dir.join(next);
        self.path = path.clone();
        let size = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
        match open_mcap(&path, &self.opts, &size) {
            Ok((mcap, channels)) => {
                self.mcap = Some(mcap);
                self.channels = channels;
                self.size = size;
            }
            Err(e) => {
                self.failed = Some((e.to_string(), ""));
                return Err(e);
            }
        }
        if let Some(sp) = self.split.as_mut() {
            sp.part += 1;
            sp.first_ns = None;
        }
        self.write_part_header(true)?;
        self.flush_file()
    }

    /// Creates a new file in `dir`, named `metrolog-<machine>-<UTC start>.mcap` (with `-2`,
    /// `-3`, … when that name exists); a split run's parts are `<that name>-pNNNN.mcap`.
    pub fn create_in_dir(
        dir: &Path,
        meta: &RunMetadata,
        opts: LogOptions,
    ) -> Result<LogWriter, LogError> {
        let machine: String = meta
            .machine
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let stamp: String = super::rfc3339(meta.started_ns)
            .chars()
            .filter(|c| c.is_ascii_digit() || *c == 'T')
            .take(15)
            .collect();
        let base = if machine.is_empty() {
            format!("metrolog-{stamp}Z")
        } else {
            format!("metrolog-{machine}-{stamp}Z")
        };
        let mut k = 1;
        loop {
            let (path, other) = LogWriter::free_name(dir, &base, opts.splits(), k);
            // A run name is taken by a file of either form (one file, or a split run's part
            // 1): two runs of one name would be one run to retention.
            if other.exists() && k < 1000 {
                k += 1;
                continue;
            }
            match LogWriter::create(&path, meta, opts.clone()) {
                Err(LogError::Create { source, .. })
                    if source.kind() == std::io::ErrorKind::AlreadyExists && k < 1000 =>
                {
                    k += 1
                }
                r => return r,
            }
        }
    }

    /// For [`LogWriter::create_in_dir`]: the first file of candidate `k` of run name `base`,
    /// and the first file of that name in the other form (split or not).
    fn free_name(dir: &Path, base: &str, splits: bool, k: u32) -> (PathBuf, PathBuf) {
        let run = if k == 1 {
            base.to_string()
        } else {
            format!("{base}-{k}")
        };
        let (part, whole) = (
            dir.join(part_name(&run, 1)),
            dir.join(format!("{run}.mcap")),
        );
        match splits {
            true => (part, whole),
            false => (whole, part),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Messages written so far (a raw batch is one message).
    pub fn messages(&self) -> u64 {
        self.messages
    }

    /// Raw samples written so far (including those in open batches).
    pub fn samples(&self) -> u64 {
        self.samples
    }

    fn fail(&mut self, e: McapError) -> LogError {
        let hint = hint_for(&e);
        if self.failed.is_none() {
            self.failed = Some((describe(&e), hint));
            // Close the file as well as possible: drop what was not flushed and cut a
            // half-written chunk off, so the file ends at a record boundary after the last
            // complete chunk (readers then stop cleanly; nothing flushed is lost).
            if let Some(w) = self.mcap.take() {
                let (file, durable) = w.into_inner().inner.into_file();
                if let Some(file) = file
                    && file.set_len(durable).is_ok()
                {
                    let _ = file.sync_all();
                }
            }
        }
        self.failed_error()
    }

    fn failed_error(&self) -> LogError {
        let (reason, hint) = self.failed.clone().unwrap_or_default();
        LogError::Write {
            path: self.path.clone(),
            reason,
            hint,
        }
    }

    fn writer(&mut self) -> Result<&mut mcap::Writer<SyncFile>, LogError> {
        if self.failed.is_some() {
            return Err(self.failed_error());
        }
        match self.mcap.as_mut() {
            Some(w) => Ok(w),
            None => Err(LogError::Write {
                path: self.path.clone(),
                reason: "the log is already closed".into(),
                hint: "",
            }),
        }
    }

    /// Writes a message of topic `T` with log time `log_ns` (host arrival time).
    pub fn write<T: TopicMessage>(&mut self, log_ns: u64, msg: &T) -> Result<(), LogError> {
        let data = serde_json::to_vec(msg).map_err(|e| LogError::Write {
            path: self.path.clone(),
            reason: format!("cannot encode a {} message: {e}", T::TOPIC),
            hint: "",
        })?;
        self.write_raw(T::TOPIC, log_ns, &data)
    }

    /// Writes an already encoded JSON message of one of metrolog's JSON topics (after the
    /// open raw batches, which keeps the file in the order the messages came).
    pub fn write_raw(&mut self, topic: &str, log_ns: u64, data: &[u8]) -> Result<(), LogError> {
        if raw::RAW_TOPICS.iter().any(|(t, _)| *t == topic) {
            return Err(LogError::Write {
                path: self.path.clone(),
                reason: format!("{topic} holds protobuf batches, not JSON"),
                hint: "write raw samples with write_sample",
            });
        }
        self.write_batches()?;
        self.write_message(topic, log_ns, data)?;
        self.flush_if_due()?;
        Ok(())
    }

    /// Every message written from now on is also handed to `tap` (after it is in the file).
    pub fn set_tap(&mut self, tap: MessageTap) {
        self.tap = Some(tap);
    }

    fn write_message(&mut self, topic: &str, log_ns: u64, data: &[u8]) -> Result<(), LogError> {
        let Some((&topic, &channel_id)) = self.channels.get_key_value(topic) else {
            return Err(LogError::Write {
                path: self.path.clone(),
                reason: format!("unknown topic {topic}"),
                hint: "",
            });
        };
        let header = MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: log_ns,
            publish_time: log_ns,
        };
        let r = self.writer()?.write_to_known_channel(&header, data);
        if let Err(e) = r {
            return Err(self.fail(e));
        }
        self.sequence = self.sequence.wrapping_add(1);
        self.messages += 1;
        if let Some(sp) = self.split.as_mut() {
            sp.first_ns.get_or_insert(log_ns);
            sp.last_ns = sp.last_ns.max(log_ns);
        }
        if let Some(tap) = self.tap.as_mut() {
            tap(topic, log_ns, data);
        }
        Ok(())
    }

    /// A raw sample into the batch of its topic; the batch is written when it spans
    /// `batch_interval` of host time or holds `batch_max` samples, before any other message,
    /// and on every flush. Its log time is the host arrival time of its first sample.
    pub fn write_sample(&mut self, s: &Sample) -> Result<(), LogError> {
        let topic = raw::topic_of(s);
        let Some(i) = raw::RAW_TOPICS.iter().position(|(t, _)| *t == topic) else {
            // Every sample kind has a raw topic (`raw::topic_of`); kept for a future one.
            return Ok(());
        };
        let batch = &mut self.pending[i];
        batch.push(s);
        self.samples += 1;
        let first_ns = batch.first_host_ns().unwrap_or(s.host_ns);
        let full = batch.len() >= self.opts.batch_max
            || s.host_ns.saturating_sub(first_ns) >= self.opts.batch_interval.as_nanos() as u64;
        if full {
            self.write_batch(i)?;
            self.flush_if_due()?;
        }
        Ok(())
    }

    fn write_batch(&mut self, i: usize) -> Result<(), LogError> {
        let batch = &mut self.pending[i];
        let (Some(topic), Some(log_ns)) = (batch.topic(), batch.first_host_ns()) else {
            return Ok(());
        };
        let mut buf = std::mem::take(&mut self.buf);
        buf.clear();
        batch.encode(&mut buf);
        let r = self.write_message(topic, log_ns, &buf);
        self.buf = buf;
        r
    }

    /// Writes every open raw batch, oldest first.
    fn write_batches(&mut self) -> Result<(), LogError> {
        let mut open: Vec<(u64, usize)> = (0..self.pending.len())
            .filter_map(|i| self.pending[i].first_host_ns().map(|t| (t, i)))
            .collect();
        open.sort_unstable();
        for (_, i) in open {
            self.write_batch(i)?;
        }
        Ok(())
    }

    /// CapBall batches written as ADC codes and as doubles (when the run's calibration did
    /// not reproduce their samples; docs/log-format.md).
    pub fn capball_batches(&self) -> [u64; 2] {
        let mut n = [0; 2];
        for b in &self.pending {
            n[0] += b.capball_batches[0];
            n[1] += b.capball_batches[1];
        }
        n
    }

    pub fn write_trigger(&mut self, t: &Trigger) -> Result<(), LogError> {
        self.write(t.host_ns, &TriggerMsg::from_trigger(t))
    }

    pub fn write_pose(&mut self, log_ns: u64, p: &PoseMsg) -> Result<(), LogError> {
        self.write(log_ns, p)
    }

    pub fn write_status(&mut self, log_ns: u64, s: &StatusMsg) -> Result<(), LogError> {
        self.write(log_ns, s)
    }

    /// A metadata record (written at once, outside chunks). A split run repeats the last
    /// record of each name (and `instrument` key) in every later part.
    pub fn write_metadata(
        &mut self,
        name: &str,
        map: BTreeMap<String, String>,
    ) -> Result<(), LogError> {
        if let Some(sp) = self.split.as_mut() {
            sp.carry(Carried::Metadata {
                name: name.into(),
                map: map.clone(),
            });
        }
        self.put_metadata(name, map)
    }

    fn put_metadata(&mut self, name: &str, map: BTreeMap<String, String>) -> Result<(), LogError> {
        let r = self.writer()?.write_metadata(&Metadata {
            name: name.into(),
            metadata: map,
        });
        r.map_err(|e| self.fail(e))
    }

    /// An attachment (config, trajectory, calibration file ...); a split run repeats it in
    /// every later part.
    pub fn attach(
        &mut self,
        name: &str,
        media_type: &str,
        data: &[u8],
        log_ns: u64,
    ) -> Result<(), LogError> {
        if let Some(sp) = self.split.as_mut() {
            sp.carry(Carried::Attachment {
                name: name.into(),
                media_type: media_type.into(),
                log_ns,
                data: data.to_vec(),
            });
        }
        self.put_attachment(name, media_type, data, log_ns)
    }

    fn put_attachment(
        &mut self,
        name: &str,
        media_type: &str,
        data: &[u8],
        log_ns: u64,
    ) -> Result<(), LogError> {
        let att = Attachment {
            log_time: log_ns,
            create_time: log_ns,
            name: name.into(),
            media_type: media_type.into(),
            data: std::borrow::Cow::Borrowed(data),
        };
        let r = self.writer()?.attach(&att);
        r.map_err(|e| self.fail(e))
    }

    /// Attaches a file under its file name.
    pub fn attach_file(
        &mut self,
        path: &Path,
        media_type: &str,
        log_ns: u64,
    ) -> Result<(), LogError> {
        let data = std::fs::read(path).map_err(|source| LogError::Attachment {
            path: path.to_path_buf(),
            source,
        })?;
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        self.attach(&name, media_type, &data, log_ns)
    }

    /// Closes the open chunk and writes it through to the disk; then, in a split run whose
    /// part is due to end, goes on in the next part.
    pub fn flush(&mut self) -> Result<(), LogError> {
        self.flush_file()?;
        if self.split_due() {
            self.roll()?;
        }
        Ok(())
    }

    fn flush_file(&mut self) -> Result<(), LogError> {
        self.write_batches()?;
        let r = self.writer()?.flush();
        self.last_flush = Instant::now();
        r.map_err(|e| self.fail(e))
    }

    /// Flushes when the flush interval has passed since the last flush; true if it did.
    pub fn flush_if_due(&mut self) -> Result<bool, LogError> {
        if self.last_flush.elapsed() >= self.opts.flush_interval {
            self.flush()?;
            return Ok(true);
        }
        Ok(false)
    }

    /// Writes the summary, footer and end magic and syncs: a cleanly closed log.
    /// Returns the path of the last file (the last part of a split run).
    pub fn finish(mut self) -> Result<PathBuf, LogError> {
        self.close(true)?;
        Ok(self.path.clone())
    }

    /// Closes the current file (summary, footer, magic); `sync`: through to the disk.
    fn close(&mut self, sync: bool) -> Result<(), LogError> {
        if self.failed.is_some() {
            return Err(self.failed_error());
        }
        if self.mcap.is_some() {
            self.write_batches()?;
        }
        let Some(mut w) = self.mcap.take() else {
            return Ok(());
        };
        if let Err(e) = w.finish() {
            return Err(self.fail(e));
        }
        let mut sink = w.into_inner();
        sink.fsync = sync;
        sink.flush().map_err(|e| self.fail(McapError::Io(e)))
    }
}

impl Drop for LogWriter {
    /// Closes the file as well as possible (a failed writer leaves what was flushed).
    fn drop(&mut self) {
        if self.failed.is_none() && self.mcap.is_some() {
            let _ = self.close(true);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_says_so() {
        let e = McapError::Io(std::io::Error::from(std::io::ErrorKind::StorageFull));
        assert!(hint_for(&e).starts_with("the disk is full"));
        let e = McapError::Io(std::io::Error::from(std::io::ErrorKind::PermissionDenied));
        assert!(hint_for(&e).contains("writable"));
    }
}
