//! The commands on a split run (docs/log-format.md, "Split runs"): the same synthetic run is
//! written once as one file and once in parts; `info`, `replay`, `analyze positioning`,
//! `report` and `recover`, given the first part, another part or the directory of parts, answer
//! what they answer for the one file, and say that they read a split run; a missing middle part
//! is reported as damage, never joined.

mod log_common;

mod cli_common;
use cli_common::outcome as metrolog;
use std::path::{Path, PathBuf};
use std::time::Duration;

use drivers::synthetic::SyntheticRun;
use metrolog_log::LogOptions;

/// The run at low rates (5 poses of 3 s): a few thousand events.
fn run() -> SyntheticRun {
    SyntheticRun {
        li80_hz: 200.0,
        cb3_hz: 100.0,
        psd_hz: 50.0,
        ..SyntheticRun::default()
    }
}

/// Flushed at every new host time (so a part can end anywhere, as the daemon's once-a-second
/// flush does in a long run), not synced; split every 3 s of log time when `split`.
fn opts(split: bool) -> LogOptions {
    LogOptions {
        fsync: false,
        flush_interval: Duration::ZERO,
        split_after: split.then(|| Duration::from_secs(3)),
        ..LogOptions::default()
    }
}

fn parts(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains("-p0"))
        .collect();
    v.sort();
    v
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

struct Runs {
    _dirs: [tempfile::TempDir; 2],
    whole: PathBuf,
    split_dir: PathBuf,
    parts: Vec<PathBuf>,
}

fn write_both() -> Runs {
    let one = tempfile::tempdir().unwrap();
    let many = tempfile::tempdir().unwrap();
    let whole = log_common::write_run_with(one.path(), "metrolog-a.mcap", &run(), opts(false));
    log_common::write_run_with(many.path(), "metrolog-a.mcap", &run(), opts(true));
    let parts = parts(many.path());
    assert!(parts.len() >= 3, "{parts:?}");
    Runs {
        whole: whole.path,
        split_dir: many.path().to_path_buf(),
        parts,
        _dirs: [one, many],
    }
}

/// `--json` output of `args` on `log` with the log's own path taken out.
fn json_of(args: &[&str], log: &Path, drop: &[&str]) -> (serde_json::Value, String) {
    let mut a = args.to_vec();
    a.push(s(log));
    let (ok, out, err) = metrolog(&a);
    assert!(ok, "{a:?}: {err}");
    let mut v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for k in drop {
        v.as_object_mut().unwrap().remove(*k);
    }
    (v, err)
}

#[test]
fn every_command_reads_a_split_run_as_the_one_file() {
    let r = write_both();
    let given = [r.parts[0].clone(), r.parts[1].clone(), r.split_dir.clone()];

    // info: the same messages, topics, poses and attachments; the parts listed.
    let (mut want, _) = json_of(&["info", "--json"], &r.whole, &["path"]);
    let want_read = want["read"].take();
    for g in &given {
        let (mut got, _) = json_of(&["info", "--json"], g, &["path"]);
        let read = got["read"].take();
        assert_eq!(got, want, "info of {g:?}");
        assert_eq!(read["messages"], want_read["messages"], "{g:?}");
        assert_eq!(read["clean_close"], true);
        assert_eq!(read["parts"].as_array().unwrap().len(), r.parts.len());
        let (ok, text, _) = metrolog(&["info", s(g)]);
        assert!(
            ok && text.contains(&format!("parts      {}", r.parts.len())),
            "{text}"
        );
    }

    // replay and analyze positioning: the same answers, and a note that the run was split.
    for cmd in [
        &["replay", "--json"][..],
        &["analyze", "positioning", "--json"][..],
    ] {
        // The answer without what names or sizes the files (paths, `read`'s byte counts).
        let answer = |out: &str, p: &Path| -> serde_json::Value {
            let mut v: serde_json::Value =
                serde_json::from_str(&out.replace(s(p), "LOG")).unwrap_or_default();
            if let Some(o) = v.as_object_mut() {
                let read = o.remove("read");
                o.insert(
                    "messages".into(),
                    read.map(|r| r["messages"].clone()).unwrap_or_default(),
                );
            }
            v
        };
        let mut a = cmd.to_vec();
        a.push(s(&r.whole));
        let (ok1, want, _) = metrolog(&a);
        let want = answer(&want, &r.whole);
        assert!(!want.is_null(), "{a:?}: no JSON");
        for g in &given {
            *a.last_mut().unwrap() = s(g);
            let (ok2, got, err) = metrolog(&a);
            assert_eq!(ok1, ok2, "{a:?}: {err}");
            assert!(
                answer(&got, g) == want,
                "{a:?}: another answer than the one file's"
            );
            assert!(
                err.contains(&format!("split run of {} parts read as one", r.parts.len())),
                "{a:?}: {err}"
            );
        }
    }

    // recover: the whole run into one file, which reads as the unsplit one.
    let out = r.split_dir.join("joined.mcap");
    let (ok, _, err) = metrolog(&["recover", s(&r.parts[1]), "-o", s(&out)]);
    assert!(ok, "{err}");
    assert!(err.contains("split run of"), "{err}");
    let (a, _) = log_common::messages(&r.whole);
    let (b, sb) = log_common::messages(&out);
    assert!(a == b, "recover of a split run: messages differ");
    assert!(sb.parts.is_empty() && sb.error.is_none());
}

#[test]
fn a_missing_middle_part_is_damage_not_joined() {
    let r = write_both();
    std::fs::remove_file(&r.parts[1]).unwrap();
    let (ok, text, _) = metrolog(&["info", s(&r.parts[0])]);
    assert!(ok, "{text}");
    assert!(text.contains("NOT cleanly"), "{text}");
    assert!(
        text.contains("part 2 of split run") && text.contains("missing"),
        "{text}"
    );
    let (_, _, err) = metrolog(&["analyze", "positioning", s(&r.parts[2])]);
    assert!(
        err.contains("is damaged") && err.contains("part 2"),
        "{err}"
    );
    // A directory with two runs' parts names neither.
    std::fs::copy(&r.parts[0], r.split_dir.join("metrolog-b-p0001.mcap")).unwrap();
    let (ok, _, err) = metrolog(&["info", s(&r.split_dir)]);
    assert!(!ok && err.contains("parts of 2 runs"), "{err}");
}
