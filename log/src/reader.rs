//! Streaming MCAP reader that survives a damaged end.
//!
//! It walks the file front to back with the `mcap` crate's sans-IO linear reader (reading the
//! file in pieces, never all at once) and hands out every message, attachment and metadata
//! record in file order. At the first error — a file cut mid-chunk by SIGKILL or a power loss,
//! a bad CRC — it stops and reports the error with what it read until then: the intact prefix.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Read;
use std::ops::ControlFlow;
use std::path::Path;

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::LogError;

/// One record of a log, in file order.
#[derive(Debug)]
pub enum LogItem<'a> {
    Message {
        topic: &'a str,
        /// The channel's message encoding: `json` or `protobuf` (raw batches, format 2).
        encoding: &'a str,
        log_ns: u64,
        data: &'a [u8],
    },
    /// A channel, when it is first declared (before its first message).
    Channel {
        id: u16,
        topic: &'a str,
        encoding: &'a str,
        schema_name: &'a str,
        schema_encoding: &'a str,
        schema_data: &'a [u8],
    },
    Attachment {
        name: &'a str,
        media_type: &'a str,
        log_ns: u64,
        data: &'a [u8],
    },
    Metadata {
        name: &'a str,
        map: &'a BTreeMap<String, String>,
    },
}

/// What reading a log found.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ReadSummary {
    /// Size of the file, bytes.
    pub file_bytes: u64,
    /// Bytes handed to the decoder before it stopped.
    pub bytes_read: u64,
    /// Footer and end magic read: the writer closed the file.
    pub clean_close: bool,
    /// Why reading stopped early (None when the whole file was read).
    pub error: Option<String>,
    pub messages: u64,
    /// Messages the file's summary section counts (its statistics record) that were not read:
    /// a chunk removed or overwritten in a file that otherwise closes cleanly.
    pub missing_messages: u64,
    pub first_log_ns: Option<u64>,
    pub last_log_ns: Option<u64>,
    /// The files read as one split run (`crate::split`), in part order; empty for a single
    /// file. The byte counts above are then over all of them.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub parts: Vec<std::path::PathBuf>,
}

impl ReadSummary {
    /// For a split run read as one: `split run of N parts read as one: FIRST .. LAST`; None
    /// for a single file. Every command that reads a log tells it.
    pub fn split_note(&self) -> Option<String> {
        let (first, last) = (self.parts.first()?, self.parts.last()?);
        Some(format!(
            "split run of {} parts read as one: {} .. {}",
            self.parts.len(),
            first.display(),
            last.display()
        ))
    }
}

/// Whether the file's last bytes are the MCAP magic (the writer's very last write).
fn ends_with_magic(file: &mut File) -> bool {
    use std::io::{Seek, SeekFrom};
    let mut tail = [0u8; 8];
    file.seek(SeekFrom::End(-8)).is_ok()
        && file.read_exact(&mut tail).is_ok()
        && tail == mcap::MAGIC
}

/// Refuses what is not an MCAP file before any reading: a FIFO or device (opening one for
/// reading would wait for a writer forever), a directory, an empty file, and a file that does
/// not start with the MCAP magic (a CSV, random bytes). Leaves `file` at its start.
fn check_is_mcap(path: &Path, file: &mut File, file_bytes: u64) -> Result<(), LogError> {
    use std::io::{Seek, SeekFrom};
    let not = |reason: &str| LogError::NotMcap {
        path: path.to_path_buf(),
        reason: reason.into(),
    };
    if file_bytes == 0 {
        return Err(not("the file is empty"));
    }
    let mut head = [0u8; 8];
    if file.read_exact(&mut head).is_err() || head != mcap::MAGIC {
        return Err(not("it does not start with the MCAP magic bytes"));
    }
    file.seek(SeekFrom::Start(0))
        .map_err(|source| LogError::Open {
            path: path.to_path_buf(),
            source,
        })?;
    Ok(())
}

/// Opens a log for reading: only a regular file (checked before opening, since opening a FIFO
/// blocks until a writer comes) that starts like an MCAP file.
fn open_log(path: &Path) -> Result<(File, u64), LogError> {
    let open_err = |source| LogError::Open {
        path: path.to_path_buf(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(open_err)?;
    if !meta.is_file() {
        return Err(LogError::NotMcap {
            path: path.to_path_buf(),
            reason: "it is not a regular file (a directory, pipe or device)".into(),
        });
    }
    let mut file = File::open(path).map_err(open_err)?;
    let file_bytes = file.metadata().map_err(open_err)?.len();
    check_is_mcap(path, &mut file, file_bytes)?;
    Ok((file, file_bytes))
}

/// Reads `path`, calling `on` for every record, until the end or the first damage.
///
/// `Err` only when the file cannot be opened or read at all; damage inside the file is
/// reported in [`ReadSummary::error`].
pub fn read_log(path: &Path, mut on: impl FnMut(LogItem<'_>)) -> Result<ReadSummary, LogError> {
    read_log_until(path, |item| {
        on(item);
        ControlFlow::Continue(())
    })
}

/// The run metadata record (written at the start of a log), without reading the rest.
pub fn read_run_metadata(path: &Path) -> Result<Option<BTreeMap<String, String>>, LogError> {
    let mut found = None;
    read_log_until(path, |item| match item {
        LogItem::Metadata { name, map } if name == super::RUN_METADATA => {
            found = Some(map.clone());
            ControlFlow::Break(())
        }
        // The writer puts it before the first message.
        LogItem::Message { .. } => ControlFlow::Break(()),
        _ => ControlFlow::Continue(()),
    })?;
    Ok(found)
}

/// Like [`read_log`], stopping early when `on` says [`ControlFlow::Break`] (the summary then
/// covers what was read).
pub fn read_log_until(
    path: &Path,
    on: impl FnMut(LogItem<'_>) -> ControlFlow<()>,
) -> Result<ReadSummary, LogError> {
    read_log_progress(path, |_, _| {}, on)
}

/// Whether an attachment record's body ends before its CRC: `mcap::parse_record` (0.26.0)
/// slices `body[header..len - 4]` without checking and panics on such a body (found by the
/// `mcap_reader` fuzz target; the input is kept in its corpus). Fields: log time, create time
/// (u64 each), name and media type (u32 length + bytes each), data length (u64), data, CRC
/// (u32).
fn attachment_too_short(body: &[u8]) -> bool {
    let string_end = |at: usize| -> Option<usize> {
        let len = body.get(at..at.checked_add(4)?)?;
        let len = u32::from_le_bytes(len.try_into().ok()?) as usize;
        at.checked_add(4)?.checked_add(len)
    };
    let header_end = string_end(16).and_then(string_end);
    match header_end.and_then(|h| h.checked_add(8 + 4)) {
        Some(min) => body.len() < min,
        // Too short for the header itself: `parse_record` reports that as an error.
        None => false,
    }
}

/// The longest record the reader accepts: 100 × the file (a record inside a compressed chunk
/// can be longer than the file, by the compression ratio), at least 16 MiB and at most 1 GiB.
/// A damaged length field then costs at most that much memory, not a gigabyte for any file.
fn record_length_limit(file_bytes: u64) -> usize {
    let limit = file_bytes.saturating_mul(100).clamp(16 << 20, 1 << 30);
    usize::try_from(limit).unwrap_or(1 << 30)
}

/// Like [`read_log_until`], telling `progress(bytes read, file bytes)` as it goes (for a
/// progress bar: an 8-hour log is gigabytes).
///
/// A part of a split run, or a directory holding one run's parts, is read as the whole run
/// (`crate::split`): every part from the first, in order, the records each part repeats from
/// the ones before skipped; [`ReadSummary::parts`] lists the files. A missing part ends the
/// reading there, reported in [`ReadSummary::error`] like damage inside a file.
pub fn read_log_progress(
    path: &Path,
    progress: impl FnMut(u64, u64),
    on: impl FnMut(LogItem<'_>) -> ControlFlow<()>,
) -> Result<ReadSummary, LogError> {
    match crate::split::resolve(path)? {
        crate::split::Resolved::Single(p) => read_one(&p, progress, on),
        crate::split::Resolved::Split { run, parts } => read_split(&run, &parts, progress, on),
    }
}

/// Adds one part's summary to the run's.
fn merge(run: &mut ReadSummary, part: ReadSummary, path: &Path) {
    run.file_bytes += part.file_bytes;
    run.bytes_read += part.bytes_read;
    run.messages += part.messages;
    run.missing_messages += part.missing_messages;
    run.clean_close &= part.clean_close;
    run.first_log_ns = run.first_log_ns.or(part.first_log_ns);
    run.last_log_ns = part.last_log_ns.or(run.last_log_ns);
    if let Some(e) = part.error {
        run.error = Some(format!("in part {}: {e}", path.display()));
    }
    run.parts.push(path.to_path_buf());
}

/// Reads the parts of split run `run` as one (see [`read_log_progress`]).
fn read_split(
    run: &str,
    parts: &[(u32, std::path::PathBuf)],
    mut progress: impl FnMut(u64, u64),
    mut on: impl FnMut(LogItem<'_>) -> ControlFlow<()>,
) -> Result<ReadSummary, LogError> {
    use crate::split::{PART_METADATA, PART_NEXT_METADATA, first_gap, part_name};
    let total: u64 = parts
        .iter()
        .map(|(_, p)| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0))
        .sum();
    let gap = first_gap(parts);
    let mut sum = ReadSummary {
        clean_close: true,
        ..ReadSummary::default()
    };
    let mut announced: std::collections::BTreeSet<String> = Default::default();
    let mut next: Option<String> = None;
    let mut stopped = false;
    for (n, path) in parts.iter().take_while(|(n, _)| gap.is_none_or(|g| *n < g)) {
        // Part 1's records are all its own; later parts repeat the earlier ones' metadata and
        // attachments up to their `metrolog.part` record.
        let mut own = *n == 1;
        let base = sum.bytes_read;
        next = None;
        let s = read_one(
            path,
            |d, _| progress(base + d, total),
            |item| match item {
                LogItem::Metadata { name, .. } if name == PART_METADATA => {
                    own = true;
                    ControlFlow::Continue(())
                }
                LogItem::Metadata { name, map } if name == PART_NEXT_METADATA => {
                    next = map.get("next").cloned();
                    ControlFlow::Continue(())
                }
                LogItem::Channel { topic, .. } if announced.contains(topic) => {
                    ControlFlow::Continue(())
                }
                LogItem::Metadata { .. } | LogItem::Attachment { .. } if !own => {
                    ControlFlow::Continue(())
                }
                item => {
                    if let LogItem::Channel { topic, .. } = &item {
                        announced.insert(topic.to_string());
                    }
                    let flow = on(item);
                    stopped |= flow.is_break();
                    flow
                }
            },
        )?;
        merge(&mut sum, s, path);
        if stopped || sum.error.is_some() {
            return Ok(sum);
        }
    }
    let missing = match gap {
        Some(g) => Some(g),
        // The last part read names a successor that is not there.
        None => next.map(|_| parts.last().map_or(1, |(n, _)| n + 1)),
    };
    if let Some(g) = missing {
        sum.clean_close = false;
        sum.error = Some(format!(
            "part {g} of split run {run} ({}) is missing: the run is damaged, read up to part {}",
            part_name(run, g),
            g - 1
        ));
    }
    Ok(sum)
}

/// One MCAP file (see [`read_log_progress`]).
fn read_one(
    path: &Path,
    mut progress: impl FnMut(u64, u64),
    mut on: impl FnMut(LogItem<'_>) -> ControlFlow<()>,
) -> Result<ReadSummary, LogError> {
    let open_err = |source| LogError::Open {
        path: path.to_path_buf(),
        source,
    };
    let (mut file, file_bytes) = open_log(path)?;
    let mut summary = ReadSummary {
        file_bytes,
        ..ReadSummary::default()
    };
    // Fed only up to a chunk the `mcap` reader would not survive (`prescan`).
    let bad_chunk = crate::prescan::first_bad_chunk(&mut file, file_bytes).map_err(open_err)?;
    let feed_bytes = bad_chunk.unwrap_or(file_bytes);
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            // Check a chunk's CRC before handing out any of its records: a torn chunk must
            // not yield garbled messages before its CRC fails (log/tests/formats.rs).
            .with_prevalidate_chunk_crcs(true)
            // A file cut at a record boundary ends cleanly (no footer); cut inside a record it
            // is an unexpected end. The footer is checked for separately.
            .with_skip_end_magic(true)
            // A damaged record must not make the reader allocate without bound.
            .with_record_length_limit(record_length_limit(file_bytes)),
    );
    let mut schemas: BTreeMap<u16, (String, String, Vec<u8>)> = BTreeMap::new();
    let mut topics: BTreeMap<u16, (String, String)> = BTreeMap::new();
    let mut saw_footer = false;
    // The message count of the summary section's statistics record, when it has one.
    let mut counted: Option<u64> = None;
    loop {
        let ev = match reader.next_event() {
            None => {
                if !saw_footer {
                    summary.error = Some("the file ends without a footer".into());
                } else if !ends_with_magic(&mut file) {
                    summary.error = Some("the file ends inside the closing magic".into());
                } else {
                    summary.clean_close = true;
                    check_count(&mut summary, counted);
                }
                break;
            }
            Some(Err(e)) => {
                summary.error = Some(match e {
                    mcap::McapError::UnexpectedEof if bad_chunk.is_some() => format!(
                        "damaged chunk at byte {feed_bytes}: a record inside it runs past the \
                         chunk's end"
                    ),
                    mcap::McapError::UnexpectedEof => format!(
                        "the file ends inside a record after {} of {} bytes (the writer did not close it)",
                        summary.bytes_read, file_bytes
                    ),
                    e => e.to_string(),
                });
                break;
            }
            Some(Ok(ev)) => ev,
        };
        match ev {
            LinearReadEvent::ReadRequest(n) => {
                // Never more than the file still holds: a damaged length asks for up to the
                // record limit, and the buffer is allocated (and zeroed) before the read.
                let left = feed_bytes.saturating_sub(summary.bytes_read);
                let want = n
                    .max(64 * 1024)
                    .min(usize::try_from(left).unwrap_or(usize::MAX));
                let buf = reader.insert(want);
                // Nothing left to feed (the file's end, or a chunk `prescan` stops at): an
                // empty read tells the reader it is the end.
                let got = loop {
                    if buf.is_empty() {
                        break 0;
                    }
                    match file.read(buf) {
                        Ok(k) => break k,
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                        Err(e) => return Err(open_err(e)),
                    }
                };
                reader.notify_read(got);
                summary.bytes_read += got as u64;
                progress(summary.bytes_read, file_bytes);
            }
            LinearReadEvent::Record { data, opcode } => {
                if opcode == mcap::records::op::ATTACHMENT && attachment_too_short(data) {
                    summary.error = Some(format!(
                        "damaged record (opcode {opcode:#04x}): an attachment of {} bytes, too \
                         short for its own fields",
                        data.len()
                    ));
                    break;
                }
                let rec = match mcap::parse_record(opcode, data) {
                    Ok(r) => r,
                    Err(e) => {
                        summary.error = Some(format!("damaged record (opcode {opcode:#04x}): {e}"));
                        break;
                    }
                };
                let flow = match rec {
                    Record::Schema { header, data } => {
                        schemas
                            .insert(header.id, (header.name, header.encoding, data.into_owned()));
                        ControlFlow::Continue(())
                    }
                    Record::Channel(c) => {
                        // The summary section repeats channels: announce each once.
                        if topics.contains_key(&c.id) {
                            continue;
                        }
                        topics.insert(c.id, (c.topic.clone(), c.message_encoding.clone()));
                        let (name, enc, sdata) = schemas
                            .get(&c.schema_id)
                            .map(|(n, e, d)| (n.as_str(), e.as_str(), d.as_slice()))
                            .unwrap_or(("", "", &[]));
                        on(LogItem::Channel {
                            id: c.id,
                            topic: &c.topic,
                            encoding: &c.message_encoding,
                            schema_name: name,
                            schema_encoding: enc,
                            schema_data: sdata,
                        })
                    }
                    Record::Message { header, data } => {
                        let Some((topic, encoding)) = topics.get(&header.channel_id) else {
                            summary.error =
                                Some(format!("message on unknown channel {}", header.channel_id));
                            break;
                        };
                        summary.messages += 1;
                        summary.first_log_ns.get_or_insert(header.log_time);
                        summary.last_log_ns = Some(header.log_time);
                        on(LogItem::Message {
                            topic,
                            encoding,
                            log_ns: header.log_time,
                            data: &data,
                        })
                    }
                    Record::Attachment { header, data, .. } => on(LogItem::Attachment {
                        name: &header.name,
                        media_type: &header.media_type,
                        log_ns: header.log_time,
                        data: &data,
                    }),
                    Record::Metadata(m) => on(LogItem::Metadata {
                        name: &m.name,
                        map: &m.metadata,
                    }),
                    Record::Footer(_) => {
                        saw_footer = true;
                        ControlFlow::Continue(())
                    }
                    Record::Statistics(st) => {
                        counted = Some(st.message_count);
                        ControlFlow::Continue(())
                    }
                    _ => ControlFlow::Continue(()),
                };
                if flow.is_break() {
                    break;
                }
            }
        }
    }
    Ok(summary)
}

/// A cleanly closed file whose summary counts more messages than were read lost records in
/// its middle (a chunk removed or overwritten): it is damaged, not intact.
fn check_count(summary: &mut ReadSummary, counted: Option<u64>) {
    let Some(n) = counted else { return };
    if n > summary.messages {
        summary.missing_messages = n - summary.messages;
        summary.error = Some(format!(
            "the file closes cleanly but {} of the {n} messages its summary counts are missing \
             (a chunk removed or overwritten); the log is damaged",
            summary.missing_messages
        ));
    }
}
