//! `recover`: rewrites the intact prefix of a torn or killed log into a valid, indexed,
//! cleanly closed file — what `mcap recover` does for the MCAP ecosystem, with metrolog's
//! reader, which stops at the first damaged byte ([`crate::read_log`]).
//!
//! Records are copied as they are (schemas, channels, messages, attachments, metadata), so a
//! log of either format keeps its format; only the chunking, the index and the footer are new.

use std::collections::BTreeMap;
use std::fs::OpenOptions;
use std::io::BufWriter;
use std::ops::ControlFlow;
use std::path::Path;

use mcap::records::{MessageHeader, Metadata};
use mcap::{Attachment, Compression, McapError, WriteOptions};

use crate::reader::{LogItem, ReadSummary, read_log_progress};
use crate::{LogError, LogOptions};

/// Copies what is readable of `src` into the new file `dst` (which must not exist);
/// `progress(bytes read, file bytes)` as it goes. Returns what reading `src` found.
pub fn recover(
    src: &Path,
    dst: &Path,
    progress: impl FnMut(u64, u64),
) -> Result<ReadSummary, LogError> {
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(dst)
        .map_err(|source| LogError::Create {
            path: dst.to_path_buf(),
            source,
        })?;
    let opts = LogOptions::default();
    let werr = |e: McapError| LogError::Write {
        path: dst.to_path_buf(),
        reason: e.to_string(),
        hint: "check the disk and the output directory",
    };
    let mut w = WriteOptions::new()
        .compression(Some(Compression::Zstd))
        .compression_level(opts.zstd_level)
        .chunk_size(Some(opts.chunk_size))
        .profile("")
        .library(concat!("metrolog ", env!("CARGO_PKG_VERSION"), " recover"))
        .create(BufWriter::with_capacity(1 << 20, file))
        .map_err(werr)?;
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    let mut sequence = 0u32;
    let mut failed: Option<McapError> = None;
    let summary = read_log_progress(src, progress, |item| {
        let r: Result<(), McapError> = (|| {
            match item {
                LogItem::Channel {
                    topic,
                    encoding,
                    schema_name,
                    schema_encoding,
                    schema_data,
                    ..
                } => {
                    let sid = if schema_name.is_empty() {
                        0
                    } else {
                        w.add_schema(schema_name, schema_encoding, schema_data)?
                    };
                    let cid = w.add_channel(sid, topic, encoding, &BTreeMap::new())?;
                    channels.insert(topic.to_string(), cid);
                }
                LogItem::Message {
                    topic,
                    log_ns,
                    data,
                    ..
                } => {
                    // The reader announces a channel before its first message.
                    if let Some(&channel_id) = channels.get(topic) {
                        let header = MessageHeader {
                            channel_id,
                            sequence,
                            log_time: log_ns,
                            publish_time: log_ns,
                        };
                        w.write_to_known_channel(&header, data)?;
                        sequence = sequence.wrapping_add(1);
                    }
                }
                LogItem::Attachment {
                    name,
                    media_type,
                    log_ns,
                    data,
                } => w.attach(&Attachment {
                    log_time: log_ns,
                    create_time: log_ns,
                    name: name.into(),
                    media_type: media_type.into(),
                    data: std::borrow::Cow::Borrowed(data),
                })?,
                LogItem::Metadata { name, map } => w.write_metadata(&Metadata {
                    name: name.into(),
                    metadata: map.clone(),
                })?,
            }
            Ok(())
        })();
        match r {
            Ok(()) => ControlFlow::Continue(()),
            Err(e) => {
                failed = Some(e);
                ControlFlow::Break(())
            }
        }
    })?;
    if let Some(e) = failed {
        return Err(werr(e));
    }
    w.finish().map_err(werr)?;
    let sink = w.into_inner();
    let file = sink.into_inner().map_err(|e| LogError::Write {
        path: dst.to_path_buf(),
        reason: e.error().to_string(),
        hint: "check the disk",
    })?;
    file.sync_all().map_err(|e| LogError::Write {
        path: dst.to_path_buf(),
        reason: e.to_string(),
        hint: "check the disk",
    })?;
    Ok(summary)
}
