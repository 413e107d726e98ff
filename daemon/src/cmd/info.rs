//! `metrolog info LOG.mcap`: what a log holds — run metadata, topics with counts and rates,
//! pose values by status, the counters of the last `/status`, attachments, and whether the
//! file was closed cleanly (or how much of a damaged one could be read).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

use metrolog_log::topics::{self, LogMessage, PoseMsg, StatusMsg, TopicMessage};
use metrolog_log::{self as log, LogItem, RUN_METADATA, ReadSummary};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The log file (.mcap).
    pub log: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Messages of one topic.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct TopicInfo {
    /// MCAP messages (a raw batch of a format-2 log is one).
    pub messages: u64,
    /// Raw samples (raw topics only).
    pub samples: u64,
    pub first_ns: Option<u64>,
    pub last_ns: Option<u64>,
    /// Mean rate between the first and the last message, Hz: samples per second on the raw
    /// topics, messages per second on the others.
    pub rate_hz: Option<f64>,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct AttachmentInfo {
    pub name: String,
    pub media_type: String,
    pub bytes: u64,
}

/// Everything `info` reports.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct InfoReport {
    pub path: PathBuf,
    pub read: ReadSummary,
    /// The run metadata record (key → value).
    pub run: BTreeMap<String, String>,
    /// Identities of instruments that connected during the run.
    pub instruments: Vec<BTreeMap<String, String>>,
    pub topics: BTreeMap<String, TopicInfo>,
    /// Pose values by instrument, then status.
    pub poses: BTreeMap<String, BTreeMap<String, u64>>,
    /// Distinct poses (any instrument).
    pub distinct_poses: u64,
    /// The last `/status` message.
    pub last_status: Option<StatusMsg>,
    pub attachments: Vec<AttachmentInfo>,
    /// Raw batches, `/pose` and `/status` messages that did not decode as their topic's type.
    pub undecodable: u64,
}

/// Reads a log and builds the report (damage in the file is reported, not an error).
pub fn inspect(path: &Path) -> anyhow::Result<InfoReport> {
    let mut run = BTreeMap::new();
    let mut instruments = Vec::new();
    let mut tops: BTreeMap<String, TopicInfo> = BTreeMap::new();
    let mut poses: BTreeMap<String, BTreeMap<String, u64>> = BTreeMap::new();
    let mut pose_ids = std::collections::BTreeSet::new();
    let mut last_status = None;
    let mut attachments = Vec::new();
    let mut undecodable = 0;
    let mut on_item = |item: LogItem<'_>| match item {
        LogItem::Channel { .. } => {}
        LogItem::Message {
            topic,
            encoding,
            log_ns,
            data,
        } => {
            let t = tops.entry(topic.to_string()).or_default();
            t.messages += 1;
            t.first_ns.get_or_insert(log_ns);
            t.last_ns = Some(log_ns);
            if encoding == "protobuf" {
                // A raw batch: count its samples (the length of one column).
                match metrolog_log::raw::Batch::decode(topic, data) {
                    Ok(Some(b)) => {
                        t.samples += b.len() as u64;
                        // The span ends at the last sample, not at the batch's log time.
                        if let Some(last) = b.samples().ok().and_then(|s| s.last().cloned()) {
                            t.last_ns = t.last_ns.max(Some(last.host_ns));
                        }
                    }
                    _ => undecodable += 1,
                }
                return;
            }
            if metrolog_log::raw::RAW_TOPICS
                .iter()
                .any(|(r, _)| *r == topic)
            {
                t.samples += 1; // format 1: one JSON message per sample
            }
            // Only the topics the report reads are decoded: an hour of raw samples is millions.
            if topic != PoseMsg::TOPIC && topic != StatusMsg::TOPIC {
                return;
            }
            match topics::decode_message(topic, encoding, log_ns, data) {
                Ok(Some(LogMessage::Pose(p))) => {
                    *poses
                        .entry(p.instrument.name().to_string())
                        .or_default()
                        .entry(p.status.name().to_string())
                        .or_default() += 1;
                    pose_ids.insert(p.pose);
                }
                Ok(Some(LogMessage::Status(s))) => last_status = Some(s),
                Ok(_) => {}
                Err(_) => undecodable += 1,
            }
        }
        LogItem::Attachment {
            name,
            media_type,
            data,
            ..
        } => attachments.push(AttachmentInfo {
            name: name.into(),
            media_type: media_type.into(),
            bytes: data.len() as u64,
        }),
        LogItem::Metadata { name, map } => {
            if name == RUN_METADATA {
                run = map.clone();
            } else if name == log::INSTRUMENT_METADATA {
                instruments.push(map.clone());
            }
        }
    };
    let bar = super::progress::Progress::new("info");
    let read = log::read_log_progress(
        path,
        |d, t| bar.update(d, t),
        |item| {
            on_item(item);
            std::ops::ControlFlow::Continue(())
        },
    )
    .with_context(|| format!("cannot inspect {}", path.display()))?;
    drop(bar);
    for t in tops.values_mut() {
        if let (Some(a), Some(b)) = (t.first_ns, t.last_ns)
            && b > a
            && t.messages > 1
        {
            // Raw topics: samples per second (a format-2 message is a batch of samples).
            let n = if t.samples > 0 { t.samples } else { t.messages };
            t.rate_hz = Some((n - 1) as f64 / ((b - a) as f64 * 1e-9));
        }
    }
    Ok(InfoReport {
        path: path.to_path_buf(),
        read,
        run,
        instruments,
        topics: tops,
        poses,
        distinct_poses: pose_ids.len() as u64,
        last_status,
        attachments,
        undecodable,
    })
}

/// A run metadata value as the text report shows it: the detector settings' per-pose targets
/// as their count (a long run has thousands; `--json` keeps them).
fn shown_run_value(key: &str, value: &str) -> String {
    if key != metrolog_log::DETECTOR_KEY {
        return value.to_string();
    }
    let Ok(mut v) = serde_json::from_str::<serde_json::Value>(value) else {
        return value.to_string();
    };
    let Some(t) = v.pointer_mut("/position_targets/targets_um") else {
        return value.to_string();
    };
    let n = t.as_array().map_or(0, Vec::len);
    *t = serde_json::Value::String(format!("{n} poses"));
    v.to_string()
}

/// The text report, written with [`super::input::print_out`]: a log's strings (machine name,
/// identities, topic and attachment names) are another program's, and reach the terminal
/// without control characters.
fn print_text(r: &InfoReport) -> anyhow::Result<()> {
    use std::fmt::Write as _;
    let mut out = String::new();
    let _ = writeln!(out, "log        {}", r.path.display());
    let rd = &r.read;
    if !rd.parts.is_empty() {
        let _ = writeln!(
            out,
            "parts      {} (a split run, read as one; sizes and counts are over all parts)",
            rd.parts.len()
        );
        for p in &rd.parts {
            let _ = writeln!(out, "           {}", p.display());
        }
    }
    if rd.clean_close && rd.missing_messages > 0 {
        let _ = writeln!(
            out,
            "closed     cleanly but DAMAGED — {} messages its summary counts are missing ({} read)",
            rd.missing_messages, rd.messages
        );
    } else if rd.clean_close {
        let _ = writeln!(out, "closed     cleanly ({} bytes)", rd.file_bytes);
    } else {
        let _ = writeln!(
            out,
            "closed     NOT cleanly — recovered {} messages from {} bytes{}",
            rd.messages,
            rd.file_bytes,
            rd.last_log_ns
                .map(|t| format!(", up to {}", log::rfc3339(t)))
                .unwrap_or_default()
        );
    }
    if let Some(e) = &rd.error {
        let _ = writeln!(out, "           damage: {e}");
    }
    if let (Some(a), Some(b)) = (rd.first_log_ns, rd.last_log_ns) {
        let _ = writeln!(
            out,
            "span       {} .. {} ({:.1} s)",
            log::rfc3339(a),
            log::rfc3339(b),
            (b.saturating_sub(a)) as f64 * 1e-9
        );
    }
    let _ = writeln!(out, "\nrun");
    for (k, v) in &r.run {
        let _ = writeln!(out, "  {k:<22} {}", shown_run_value(k, v));
    }
    for i in &r.instruments {
        let _ = writeln!(
            out,
            "  connected: {} on {}: {}",
            i.get("instrument").map_or("?", |s| s),
            i.get("port").map_or("?", |s| s),
            i.get("identity").map_or("?", |s| s)
        );
    }
    let _ = writeln!(out, "\ntopics{:>34} {:>12}", "messages", "rate");
    for (name, t) in &r.topics {
        let rate = t
            .rate_hz
            .map(|h| format!("{h:.1} Hz"))
            .unwrap_or_else(|| "-".into());
        let _ = writeln!(out, "  {name:<30} {:>10} {rate:>12}", t.messages);
    }
    let _ = writeln!(out, "\nposes ({} distinct)", r.distinct_poses);
    if r.poses.is_empty() {
        let _ = writeln!(out, "  none");
    }
    for (inst, by) in &r.poses {
        let s: Vec<String> = by.iter().map(|(k, v)| format!("{k} {v}")).collect();
        let _ = writeln!(out, "  {inst:<16} {}", s.join(", "));
    }
    let _ = writeln!(out, "\ncounters (last /status)");
    match &r.last_status {
        None => {
            let _ = writeln!(out, "  no /status record");
        }
        Some(st) => {
            let _ = writeln!(out, "  log messages {}", st.log_messages);
            for (inst, c) in &st.instruments {
                let rej: u64 = c.rejections.values().sum();
                let _ = writeln!(
                    out,
                    "  {inst:<16} samples {} gaps {} ({} samples) rejections {rej} resyncs {} reconnects {} disconnects {} dropped {} invalid {} device errors {} clock drift {}",
                    c.samples,
                    c.gaps,
                    c.gap_samples,
                    c.resyncs,
                    c.reconnects,
                    c.disconnects,
                    c.dropped,
                    c.invalid,
                    c.device_errors,
                    c.clock_drift_ppm
                        .map(|d| format!("{d:.3} ppm"))
                        .unwrap_or_else(|| "-".into())
                );
                for (k, v) in &c.rejections {
                    let _ = writeln!(out, "  {:<16}   rejected {k}: {v}", "");
                }
            }
        }
    }
    if !r.attachments.is_empty() {
        let _ = writeln!(out, "\nattachments");
        for a in &r.attachments {
            let _ = writeln!(out, "  {} ({}, {} bytes)", a.name, a.media_type, a.bytes);
        }
    }
    if r.undecodable > 0 {
        let _ = writeln!(
            out,
            "\n{} messages did not decode as their topic's type",
            r.undecodable
        );
    }
    super::input::print_out(&out)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let r = inspect(&args.log)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        print_text(&r)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_detector_s_targets_are_shown_as_their_count() {
        let s = types::DetectorSettings {
            position_targets: Some(types::PositionTargets {
                targets_um: vec![0.0, 100_000.0, 200_000.0],
                tol_um: types::OFF_TARGET_TOL_UM,
                floor_um: None,
            }),
            ..types::DetectorSettings::default()
        };
        let json = serde_json::to_string(&s).unwrap();
        let shown = shown_run_value(metrolog_log::DETECTOR_KEY, &json);
        assert!(shown.contains(r#""targets_um":"3 poses""#), "{shown}");
        assert!(shown.contains(r#""tol_um":2000.0"#), "{shown}");
        // Other keys, and settings without targets, as they are.
        assert_eq!(shown_run_value("machine", "x"), "x");
        let plain = serde_json::to_string(&types::DetectorSettings::default()).unwrap();
        assert_eq!(shown_run_value(metrolog_log::DETECTOR_KEY, &plain), plain);
    }
}
