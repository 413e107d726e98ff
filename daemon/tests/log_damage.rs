//! Damaged logs: cut at many offsets, a writer killed with SIGKILL, a write that fails, and
//! directories that cannot take a log.

mod log_common;

use std::path::Path;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use drivers::synthetic::SyntheticRun;
use metrolog::cmd::info::inspect;
use metrolog::cmd::replay::{ReplayOptions, replay};
use metrolog_log::{LogError, LogOptions, LogWriter, RunMetadata};

fn short_run() -> SyntheticRun {
    SyntheticRun {
        targets_mm: vec![0.0, 25.0, 50.0],
        dwell_s: 2.0,
        seed: 3,
        ..SyntheticRun::default()
    }
}

#[test]
fn truncated_logs_give_their_intact_prefix() {
    let dir = tempfile::tempdir().unwrap();
    // Small chunks: many chunk boundaries to cut across.
    let opts = LogOptions {
        chunk_size: 32 << 10,
        ..LogOptions::default()
    };
    let w = log_common::write_run_with(dir.path(), "full.mcap", &short_run(), opts);
    let full = std::fs::read(&w.path).unwrap();
    let (all, s) = log_common::messages(&w.path);
    assert!(s.clean_close);
    let full_replay = replay(&w.path, &ReplayOptions::default()).unwrap();
    assert!(full_replay.reproduces_log());

    let cut_path = dir.path().join("cut.mcap");
    let n_cuts = 40;
    let mut last_count = 0;
    for i in 0..=n_cuts {
        // Evenly spread, plus the very start (inside the magic and header).
        let at = if i < 5 {
            i * 3
        } else {
            full.len() * (i - 4) / (n_cuts - 4) - 1
        };
        std::fs::write(&cut_path, &full[..at]).unwrap();
        if at < 8 {
            // Inside the magic: not an MCAP file at all, refused before any reading.
            let e = inspect(&cut_path).unwrap_err();
            assert!(
                format!("{e:#}").contains("not an MCAP log"),
                "cut at {at}: {e:#}"
            );
            continue;
        }
        let (got, s) = log_common::messages(&cut_path);
        assert!(!s.clean_close, "cut at {at} reported clean");
        assert!(s.error.is_some());
        assert_eq!(got[..], all[..got.len()], "cut at {at}: not a prefix");
        assert!(
            got.len() >= last_count,
            "cut at {at} recovered fewer messages than a shorter cut"
        );
        last_count = got.len();
        let info = inspect(&cut_path).unwrap();
        assert!(!info.read.clean_close);
        assert_eq!(info.read.messages as usize, got.len());
        if i % 10 == 0 {
            let r = replay(&cut_path, &ReplayOptions::default()).unwrap();
            // Everything logged in the prefix is reproduced; only the end can differ.
            assert_eq!(r.logged[..], full_replay.logged[..r.logged.len()]);
            assert_eq!(r.identical, r.logged.len(), "cut at {at}");
            // Nothing invented for the dwell the cut left open.
            assert!(r.replayed.len() <= full_replay.replayed.len());
            assert_eq!(
                r.replayed[..],
                full_replay.replayed[..r.replayed.len()],
                "cut at {at}"
            );
        }
    }
    // Most of the file is recovered from a cut near its end.
    assert!(
        last_count as f64 > 0.9 * all.len() as f64,
        "{last_count} of {}",
        all.len()
    );
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
}

/// Child process body: writes LI-80 samples in real time until killed (or until the write
/// fails, when `METROLOG_FSIZE` limits the file size).
#[test]
fn writer_child() {
    let Ok(path) = std::env::var("METROLOG_WRITER_CHILD") else {
        return;
    };
    if let Ok(limit) = std::env::var("METROLOG_FSIZE") {
        let limit: u64 = limit.parse().unwrap();
        unsafe {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let rl = libc::rlimit {
                rlim_cur: limit,
                rlim_max: limit,
            };
            libc::setrlimit(libc::RLIMIT_FSIZE, &rl);
        }
    }
    let meta = RunMetadata {
        machine: "kill-test".into(),
        started_ns: now_ns(),
        ..RunMetadata::default()
    };
    let mut w = LogWriter::create(Path::new(&path), &meta, LogOptions::default()).unwrap();
    let mut seq = 0u64;
    loop {
        for _ in 0..10 {
            seq += 1;
            let t = now_ns();
            let m = drivers::Sample {
                instrument: drivers::Instrument::Interferometer,
                seq,
                device_t_us: seq * 1000,
                host_ns: t,
                fitted_ns: t,
                valid: true,
                values: drivers::SampleValues::Position {
                    raw_nm: seq as i64,
                    position_um: seq as f64 * 1e-3,
                    sig: 90,
                    flags: 0,
                },
            };
            if let Err(e) = w.write_sample(&m) {
                println!("WRITE ERROR: {e}");
                return;
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn spawn_child(path: &Path, fsize: Option<u64>) -> std::process::Child {
    let mut cmd = std::process::Command::new(std::env::current_exe().unwrap());
    cmd.args(["--exact", "writer_child", "--nocapture", "--test-threads=1"])
        .env("METROLOG_WRITER_CHILD", path)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    if let Some(l) = fsize {
        cmd.env("METROLOG_FSIZE", l.to_string());
    }
    cmd.spawn().unwrap()
}

#[test]
fn killed_writer_loses_at_most_about_a_second() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.mcap");
    let mut child = spawn_child(&path, None);
    let t0 = Instant::now();
    while !path.exists() && t0.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(3300));
    let killed_ns = now_ns();
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();

    let (msgs, s) = log_common::messages(&path);
    assert!(!s.clean_close);
    // Raw samples come in batches of 10 ms: decode them.
    let samples: Vec<drivers::Sample> = msgs
        .iter()
        .flat_map(|(topic, _, d)| {
            metrolog_log::raw::Batch::decode(topic, d)
                .unwrap()
                .unwrap()
                .samples()
                .unwrap()
        })
        .collect();
    assert!(
        samples.len() > 1000,
        "only {} samples recovered",
        samples.len()
    );
    let last = s.last_log_ns.unwrap();
    let lost_s = (killed_ns - last) as f64 * 1e-9;
    assert!(
        lost_s < 1.5,
        "the last {lost_s:.2} s before the kill were lost"
    );
    // Sequence numbers are contiguous: nothing inside the prefix is missing.
    for (i, m) in samples.iter().enumerate() {
        assert_eq!(m.seq, i as u64 + 1);
    }
    let info = inspect(&path).unwrap();
    assert!(!info.read.clean_close);
    assert_eq!(info.run["machine"], "kill-test");
    replay(&path, &ReplayOptions::default()).unwrap();
}

#[test]
fn failed_write_is_reported_and_keeps_the_flushed_part() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    // The file may not grow past 200 kB: the write fails like on a full disk.
    let child = spawn_child(&path, Some(200_000));
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout
        .lines()
        .find(|l| l.contains("WRITE ERROR"))
        .unwrap_or_else(|| {
            panic!(
                "no write error in {stdout:?} (status {:?}, stderr {:?})",
                out.status,
                String::from_utf8_lossy(&out.stderr)
            )
        });
    assert!(line.contains(&path.display().to_string()), "{line}");
    assert!(line.contains("last flush"), "{line}");
    let (msgs, s) = log_common::messages(&path);
    assert!(!s.clean_close);
    assert!(!msgs.is_empty());
    // The half-written chunk was cut off: the file ends at a record boundary.
    assert_eq!(s.error.as_deref(), Some("the file ends without a footer"));
    assert!(s.file_bytes < 200_000);
}

#[test]
fn missing_or_unwritable_directory_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no/such/dir");
    let meta = RunMetadata::default();
    let e = LogWriter::create_in_dir(&missing, &meta, LogOptions::default())
        .err()
        .unwrap();
    assert!(matches!(e, LogError::Create { .. }));
    let text = e.to_string();
    assert!(text.contains(&missing.display().to_string()), "{text}");
    assert!(text.contains("check that the directory exists"), "{text}");

    // Unwritable (root may write anywhere, so only as another user).
    if unsafe { libc::geteuid() } != 0 {
        use std::os::unix::fs::PermissionsExt;
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        let e = LogWriter::create_in_dir(&ro, &meta, LogOptions::default())
            .err()
            .unwrap();
        let text = e.to_string();
        assert!(text.contains("ro") && text.contains("may write"), "{text}");
    }
}

#[test]
fn each_run_gets_a_new_file_and_earlier_ones_stay_intact() {
    let dir = tempfile::tempdir().unwrap();
    let meta = RunMetadata {
        machine: "mill 1/a".into(),
        started_ns: 1_795_305_600_000_000_000,
        ..RunMetadata::default()
    };
    let a = LogWriter::create_in_dir(dir.path(), &meta, LogOptions::default())
        .unwrap()
        .finish()
        .unwrap();
    let before = std::fs::read(&a).unwrap();
    let mut w = LogWriter::create_in_dir(dir.path(), &meta, LogOptions::default()).unwrap();
    let b = w.path().to_path_buf();
    assert_ne!(a, b);
    assert_eq!(
        a.file_name().unwrap(),
        "metrolog-mill_1_a-20261122T000000Z.mcap"
    );
    assert_eq!(
        b.file_name().unwrap(),
        "metrolog-mill_1_a-20261122T000000Z-2.mcap"
    );
    w.flush().unwrap();
    drop(w);
    assert_eq!(std::fs::read(&a).unwrap(), before);
    assert!(log_common::messages(&a).1.clean_close);
    // An explicit path that exists is refused.
    let e = LogWriter::create(&a, &meta, LogOptions::default())
        .err()
        .unwrap();
    assert!(
        e.to_string().contains("File exists") || e.to_string().contains("exists"),
        "{e}"
    );
}
