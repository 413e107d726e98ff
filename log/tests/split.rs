//! Split runs (`metrolog_log::split`): one run written as parts, each a complete MCAP file
//! that the `mcap` crate's own indexed reader opens alone, and read back by metrolog's reader
//! as the same run an unsplit writer gives; a missing part is a gap, never joined silently.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use drivers::DriverEvent;
use drivers::synthetic::SyntheticRun;
use metrolog_log::{
    LogItem, LogOptions, LogWriter, RUN_METADATA, RunMetadata, TRAJECTORY_ATTACHMENT, read_log,
};

/// Writes the synthetic run to `path` with `opts`, flushing once a second of run time as the
/// daemon does; returns the last file written.
fn write_run(path: &Path, opts: LogOptions) -> PathBuf {
    // 12 poses of 3 s: 36 s of run time.
    let run = SyntheticRun {
        targets_mm: (0..12).map(|k| k as f64 * 10.0).collect(),
        ..SyntheticRun::small()
    };
    let run = SyntheticRun {
        dwell_s: 2.5,
        move_s: 0.5,
        ..run
    };
    let meta = RunMetadata {
        machine: "split".into(),
        started_ns: run.start_ns,
        ..RunMetadata::default()
    };
    let opts = LogOptions {
        fsync: false,
        flush_interval: Duration::from_secs(86_400),
        ..opts
    };
    let mut w = LogWriter::create(path, &meta, opts).expect("create");
    w.attach(
        TRAJECTORY_ATTACHMENT,
        "text/csv",
        b"pose,x_mm\n1,0\n",
        run.start_ns,
    )
    .expect("attach");
    let mut next_flush = run.start_ns + 1_000_000_000;
    for ev in run.events() {
        let t = match &ev {
            DriverEvent::Sample(s) => {
                w.write_sample(s).expect("sample");
                s.host_ns
            }
            DriverEvent::Trigger(tr) => {
                w.write_trigger(tr).expect("trigger");
                tr.host_ns
            }
            _ => continue,
        };
        while t >= next_flush {
            w.flush().expect("flush");
            next_flush += 1_000_000_000;
        }
    }
    w.finish().expect("finish")
}

/// What a reader of the whole run sees: every message (topic, time, bytes), the attachments'
/// names and the run metadata records.
#[derive(Debug, PartialEq, Default)]
struct Seen {
    messages: Vec<(String, u64, Vec<u8>)>,
    attachments: Vec<String>,
    run_metadata: Vec<BTreeMap<String, String>>,
    other_metadata: Vec<String>,
}

fn read_all(path: &Path) -> (Seen, metrolog_log::ReadSummary) {
    let mut seen = Seen::default();
    let summary = read_log(path, |item| match item {
        LogItem::Message {
            topic,
            log_ns,
            data,
            ..
        } => seen.messages.push((topic.into(), log_ns, data.to_vec())),
        LogItem::Attachment { name, .. } => seen.attachments.push(name.into()),
        LogItem::Metadata { name, map } if name == RUN_METADATA => {
            seen.run_metadata.push(map.clone())
        }
        LogItem::Metadata { name, .. } => seen.other_metadata.push(name.into()),
        LogItem::Channel { .. } => {}
    })
    .expect("read");
    (seen, summary)
}

fn parts(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("dir")
        .map(|e| e.expect("entry").path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().contains("-p0"))
        })
        .collect();
    v.sort();
    v
}

fn split_opts() -> LogOptions {
    LogOptions {
        split_after: Some(Duration::from_secs(5)),
        ..LogOptions::default()
    }
}

/// Messages of one part read with the `mcap` crate's indexed reader (summary and chunk
/// indexes, not metrolog's linear reader): each part stands alone.
fn mcap_messages(path: &Path) -> usize {
    let data = std::fs::read(path).expect("read part");
    let summary = mcap::Summary::read(&data)
        .expect("summary")
        .expect("the part has a summary section");
    assert!(!summary.chunk_indexes.is_empty(), "{}", path.display());
    assert_eq!(summary.channels.len(), metrolog_log::channel_specs().len());
    let mut n = 0;
    for m in mcap::MessageStream::new(&data).expect("stream") {
        m.expect("message");
        n += 1;
    }
    assert_eq!(summary.stats.map(|s| s.message_count as usize), Some(n));
    n
}

#[test]
fn a_split_run_reads_as_the_unsplit_one_from_any_part_or_its_directory() {
    let one = tempfile::tempdir().unwrap();
    let whole = write_run(&one.path().join("run.mcap"), LogOptions::default());
    let (want, _) = read_all(&whole);

    let dir = tempfile::tempdir().unwrap();
    let last = write_run(&dir.path().join("metrolog-split-x.mcap"), split_opts());
    let files = parts(dir.path());
    assert!(files.len() >= 3, "{files:?}");
    assert_eq!(
        files[0].file_name().unwrap(),
        "metrolog-split-x-p0001.mcap",
        "{files:?}"
    );
    assert_eq!(files.last(), Some(&last));
    // Each part alone: a complete file with the run metadata and the attachment.
    let mut alone = 0;
    for f in &files {
        alone += mcap_messages(f);
        let data = std::fs::read(f).unwrap();
        let s = mcap::Summary::read(&data).unwrap().unwrap();
        assert!(
            s.attachment_indexes
                .iter()
                .any(|a| a.name == TRAJECTORY_ATTACHMENT)
        );
        assert!(s.metadata_indexes.iter().any(|m| m.name == RUN_METADATA));
    }
    assert_eq!(alone, want.messages.len());

    for given in [files[0].clone(), files[1].clone(), dir.path().to_path_buf()] {
        let (got, summary) = read_all(&given);
        assert_eq!(got.messages.len(), want.messages.len(), "{given:?}");
        assert!(got.messages == want.messages, "{given:?}: messages differ");
        assert_eq!(got.attachments, want.attachments);
        assert_eq!(got.run_metadata, want.run_metadata);
        assert!(got.other_metadata.is_empty(), "{:?}", got.other_metadata);
        assert_eq!(summary.parts, files);
        assert!(
            summary.clean_close && summary.error.is_none(),
            "{summary:?}"
        );
    }
}

/// Runs started in the same second get distinct run names whether split or not (a split run
/// and a one-file run of one name would be one run to retention).
#[test]
fn a_run_name_is_never_shared_by_a_split_and_an_unsplit_run() {
    let dir = tempfile::tempdir().unwrap();
    let meta = RunMetadata {
        machine: "m".into(),
        started_ns: 1_795_305_600_000_000_000,
        ..RunMetadata::default()
    };
    let names: Vec<String> = [LogOptions::default(), split_opts(), LogOptions::default()]
        .into_iter()
        .map(|o| {
            let w = LogWriter::create_in_dir(dir.path(), &meta, o).unwrap();
            let p = w.finish().unwrap();
            p.file_name().unwrap().to_string_lossy().into_owned()
        })
        .collect();
    assert_eq!(
        names,
        [
            "metrolog-m-20261122T000000Z.mcap",
            "metrolog-m-20261122T000000Z-2-p0001.mcap",
            "metrolog-m-20261122T000000Z-3.mcap"
        ]
    );
}

#[test]
fn a_split_run_by_size_keeps_parts_near_the_size() {
    let dir = tempfile::tempdir().unwrap();
    let opts = LogOptions {
        split_bytes: Some(40_000),
        ..LogOptions::default()
    };
    write_run(&dir.path().join("metrolog-size.mcap"), opts);
    let files = parts(dir.path());
    assert!(files.len() >= 2, "{files:?}");
    for f in &files[..files.len() - 1] {
        let len = std::fs::metadata(f).unwrap().len();
        // Split at the first flush past the size: at most about a second of data more.
        assert!((40_000..120_000).contains(&len), "{f:?}: {len}");
    }
}

#[test]
fn a_missing_part_is_a_gap_not_joined() {
    let dir = tempfile::tempdir().unwrap();
    write_run(&dir.path().join("metrolog-gap.mcap"), split_opts());
    let files = parts(dir.path());
    assert!(files.len() >= 3, "{files:?}");
    let (full, _) = read_all(&files[0]);

    // The middle part gone: the run is read up to the gap and said to be damaged.
    std::fs::remove_file(&files[1]).unwrap();
    let (got, summary) = read_all(&files[2]);
    let e = summary.error.clone().expect("a gap is an error");
    assert!(e.contains("part 2") && e.contains("missing"), "{e}");
    assert!(!summary.clean_close);
    assert_eq!(summary.parts, files[..1]);
    assert!(got.messages.len() < full.messages.len());

    // The last part gone: part n−1 names it, so that is a gap too.
    let dir = tempfile::tempdir().unwrap();
    write_run(&dir.path().join("metrolog-tail.mcap"), split_opts());
    let files = parts(dir.path());
    std::fs::remove_file(files.last().unwrap()).unwrap();
    let (_, summary) = read_all(&files[0]);
    let e = summary.error.expect("a missing last part is an error");
    assert!(e.contains(&format!("part {}", files.len())), "{e}");
}
