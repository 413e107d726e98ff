//! Old logs keep working: `info`, `replay` and the analyses' reader take the golden logs of
//! every format (`log/tests/data/`), replay reproduces their pose values exactly, and replay
//! of a format-1 log writes a log of the current format.

use std::path::{Path, PathBuf};

use metrolog::cmd::info::inspect;
use metrolog::cmd::replay::{ReplayOptions, replay};
use metrolog_analysis::LogContents;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../log/tests/data")
        .join(name)
}

#[test]
fn info_replay_and_analysis_read_every_format() {
    let mut replayed = Vec::new();
    for name in ["format1.mcap", "format2.mcap", "format3.mcap"] {
        let info = inspect(&data(name)).unwrap();
        assert!(info.read.clean_close, "{name}");
        assert_eq!(info.undecodable, 0, "{name}");
        assert_eq!(info.topics["/capball/sample"].samples, 1829, "{name}");
        assert_eq!(info.topics["/psd/sample"].samples, 1804, "{name}");
        assert_eq!(info.poses["capball"]["ok"], 3, "{name}");
        let r = replay(&data(name), &ReplayOptions::default()).unwrap();
        assert!(
            r.reproduces_log(),
            "{name}: {} of {}",
            r.identical,
            r.logged.len()
        );
        assert_eq!(r.logged.len(), 6);
        replayed.push(r.replayed);
        let c = LogContents::read(&data(name)).unwrap();
        assert_eq!(c.poses.len(), 6, "{name}");
        assert_eq!(c.environment.len(), 2, "{name}");
        assert_eq!(c.undecodable, 0, "{name}");
    }
    let poses = |v: &[(u64, metrolog_log::topics::PoseMsg)]| -> Vec<_> {
        v.iter().map(|(_, p)| p.clone()).collect()
    };
    assert_eq!(poses(&replayed[0]), poses(&replayed[1]));
    assert_eq!(poses(&replayed[0]), poses(&replayed[2]));
}

#[test]
fn replay_converts_a_format_1_log_to_the_current_format() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("converted.mcap");
    let opts = ReplayOptions {
        output: Some(out.clone()),
        ..ReplayOptions::default()
    };
    let r = replay(&data("format1.mcap"), &opts).unwrap();
    assert!(r.reproduces_log());
    let meta = metrolog_log::read_run_metadata(&out).unwrap().unwrap();
    assert_eq!(meta[metrolog_log::LOG_FORMAT_KEY], "3");
    let again = replay(&out, &ReplayOptions::default()).unwrap();
    assert!(again.reproduces_log());
    assert_eq!(again.logged.len(), 6);
}

#[test]
fn recover_command_repairs_a_truncated_log() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fixed.mcap");
    let st = std::process::Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .arg("recover")
        .arg(data("truncated.mcap"))
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let text = String::from_utf8_lossy(&st.stdout);
    assert!(text.contains("recovered"), "{text}");
    let info = inspect(&out).unwrap();
    assert!(info.read.clean_close && info.read.error.is_none());
    assert!(info.topics["/capball/sample"].samples > 0);
}

/// `metrolog info LOG | head -1`: the reader goes before the report is written. The command
/// must end as Unix tools do (killed by SIGPIPE, nothing on stderr), not panic in `println!`.
#[test]
fn info_into_a_closed_pipe_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .arg("info")
        .arg(data("format3.mcap"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(
        out.status.signal(),
        Some(libc::SIGPIPE),
        "{:?} {err}",
        out.status
    );
}
