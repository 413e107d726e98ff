//! The log directory's policy (`[storage]`, README "Disk space"): a retention rule (runs older
//! than `keep_days` deleted; the oldest runs deleted while less than `min_free_gb` is free)
//! applied before a run starts and every 10 s while it runs, never to the run being written;
//! and a warning when less than `warn_free_gb` is free.
//!
//! A run is a file `metrolog-*.mcap` directly in `output_dir` (the names the log writer gives),
//! or all the parts `<run>-pNNNN.mcap` of a split run (`metrolog_log::split`), deleted
//! together; nothing else there is touched. Free space is read through [`FreeSpace`], so the tests can
//! give a directory a capacity without mounting a file system.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// Bytes in a GB as the config counts them (10^9, as disks are sold and `df -H` shows).
pub const GB: f64 = 1e9;

/// Default of `[storage] warn_free_gb`: about 6 h of a run at the highest rates (0.75 GB/h).
pub const DEFAULT_WARN_FREE_GB: f64 = 5.0;

/// Below this much free space a run does not start (exit 73) rather than leave an empty log
/// file on a full disk at every start.
pub const START_MIN_FREE_BYTES: u64 = 256 * 1024;

/// Whether a run can start in `dir` after retention: `Err` with what to do when the disk is
/// (nearly) full. A directory whose free space cannot be read is let through (the log's
/// creation then says what is wrong).
pub fn room_to_start(dir: &Path, free: &dyn FreeSpace) -> Result<(), String> {
    match free.free_bytes(dir) {
        Ok(b) if b < START_MIN_FREE_BYTES => Err(format!(
            "only {} KiB free in {}; a run needs at least {} KiB to start: free space (older runs are the metrolog-*.mcap files there) or set [storage] min_free_gb so that they are deleted for the next",
            b / 1024,
            dir.display(),
            START_MIN_FREE_BYTES / 1024
        )),
        _ => Ok(()),
    }
}

/// How often the policy is applied while a run is written (a full-rate run writes about 2 MB
/// in that time; a check reads the directory and `statvfs`).
pub const CHECK_PERIOD: Duration = Duration::from_secs(10);

/// `[storage]`: what may be deleted, and when to warn.
#[derive(Debug, Clone, PartialEq)]
pub struct StoragePolicy {
    /// Delete runs last written longer ago than this (None: never by age).
    pub keep: Option<Duration>,
    /// Delete the oldest runs while less than this many bytes are free (None: never for space).
    pub min_free_bytes: Option<u64>,
    /// Warn while less than this many bytes are free.
    pub warn_free_bytes: u64,
    /// Start a new part of the run after this much time (`split_minutes`; None: never).
    pub split_after: Option<Duration>,
    /// Start a new part of the run when a part reaches this size (`split_mb`; None: never).
    pub split_bytes: Option<u64>,
}

impl Default for StoragePolicy {
    /// Without a `[storage]` section nothing is deleted; the warning stays on.
    fn default() -> Self {
        StoragePolicy {
            keep: None,
            min_free_bytes: None,
            warn_free_bytes: (DEFAULT_WARN_FREE_GB * GB) as u64,
            split_after: None,
            split_bytes: None,
        }
    }
}

/// Where free space is read from (the file system, or a test's stand-in).
pub trait FreeSpace {
    /// Bytes an unprivileged writer may still write in `dir`'s file system.
    fn free_bytes(&self, dir: &Path) -> std::io::Result<u64>;
}

/// The file system's own count (`statvfs`: blocks available to unprivileged users).
pub struct Statvfs;

impl FreeSpace for Statvfs {
    fn free_bytes(&self, dir: &Path) -> std::io::Result<u64> {
        let s = nix::sys::statvfs::statvfs(dir).map_err(std::io::Error::from)?;
        Ok(s.blocks_available() as u64 * s.fragment_size() as u64)
    }
}

/// One run: its file, or the parts of a split run.
#[derive(Debug, Clone)]
pub struct RunFile {
    /// The run's name (the file name without `.mcap`, or without `-pNNNN.mcap`).
    pub run: String,
    /// The first file (in name order: part 1 of a split run).
    pub path: PathBuf,
    /// Every file of the run, in name order.
    pub files: Vec<PathBuf>,
    /// When its last file was last written.
    pub modified: SystemTime,
    pub bytes: u64,
}

/// The run a log file belongs to, by its name.
pub fn run_name(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_str()?;
    Some(metrolog_log::split::run_of_file_name(name).to_string())
}

/// The runs in `dir`, oldest (last written first) first; the parts of a split run are one.
pub fn runs(dir: &Path) -> std::io::Result<Vec<RunFile>> {
    let mut by_run: std::collections::BTreeMap<String, RunFile> = Default::default();
    for e in std::fs::read_dir(dir)? {
        let e = e?;
        let path = e.path();
        let name = e.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with("metrolog-") && name.ends_with(".mcap")) {
            continue;
        }
        let m = e.metadata()?;
        let Some(run) = run_name(&path).filter(|_| m.is_file()) else {
            continue;
        };
        let modified = m.modified()?;
        let r = by_run.entry(run.clone()).or_insert_with(|| RunFile {
            run,
            path: path.clone(),
            files: Vec::new(),
            modified,
            bytes: 0,
        });
        r.files.push(path);
        r.modified = r.modified.max(modified);
        r.bytes += m.len();
    }
    let mut v: Vec<RunFile> = by_run.into_values().collect();
    for r in &mut v {
        r.files.sort();
        r.path = r.files[0].clone();
    }
    v.sort_by(|a, b| (a.modified, &a.path).cmp(&(b.modified, &b.path)));
    Ok(v)
}

/// What one application of the policy did.
#[derive(Debug, Default)]
pub struct Applied {
    /// Deleted runs, with why.
    pub deleted: Vec<(PathBuf, String)>,
    /// Free bytes afterwards.
    pub free_bytes: u64,
}

/// Apply `policy` to `dir` at time `now`: runs older than `keep` go, then the oldest while
/// less than `min_free_bytes` is free. `current` (a file of the run being written: all of
/// that run's parts) is never deleted.
pub fn apply(
    policy: &StoragePolicy,
    dir: &Path,
    current: Option<&Path>,
    now: SystemTime,
    free: &dyn FreeSpace,
) -> std::io::Result<Applied> {
    let mut out = Applied::default();
    let current = current.and_then(run_name);
    let candidates: Vec<RunFile> = runs(dir)?
        .into_iter()
        .filter(|r| Some(&r.run) != current.as_ref())
        .collect();
    let mut left = Vec::new();
    for r in candidates {
        let age = now.duration_since(r.modified).unwrap_or_default();
        match policy.keep {
            Some(keep) if age > keep => {
                let days = age.as_secs_f64() / 86_400.0;
                delete(&r, format!("last written {days:.1} days ago"), &mut out)?;
            }
            _ => left.push(r),
        }
    }
    out.free_bytes = free.free_bytes(dir)?;
    if let Some(min) = policy.min_free_bytes {
        for r in left {
            if out.free_bytes >= min {
                break;
            }
            let why = format!(
                "{} GB free, less than min_free_gb {}",
                gb(out.free_bytes),
                gb(min)
            );
            delete(&r, why, &mut out)?;
            out.free_bytes = free.free_bytes(dir)?;
        }
    }
    Ok(out)
}

/// Deletes every file of run `r` (part 1 last, so a run cut short by an error still shows
/// where it began).
/// Bytes in GB with two decimals, or with four significant digits below 0.1 GB (a small
/// file system would read "0.00 GB free, less than 0.00").
fn gb(bytes: u64) -> String {
    let x = bytes as f64 / GB;
    if x >= 0.1 || x == 0.0 {
        format!("{x:.2}")
    } else {
        let decimals = (3.0 - x.log10().floor()).clamp(2.0, 12.0) as usize;
        format!("{x:.decimals$}")
    }
}

fn delete(r: &RunFile, why: String, out: &mut Applied) -> std::io::Result<()> {
    let mut gone = 0;
    for f in r.files.iter().rev() {
        match std::fs::remove_file(f) {
            Ok(()) => gone += 1,
            // Gone already (an operator moved it): nothing to do.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e),
        }
    }
    if gone == 0 {
        return Ok(());
    }
    let why = match r.files.len() {
        1 => why,
        n => format!("{why}; all {n} parts"),
    };
    out.deleted.push((r.path.clone(), why));
    Ok(())
}

/// The warning for `free_bytes` under `policy`, if any.
/// The threshold is `warn_free_gb`, or `min_free_gb` when higher (retention could not free
/// that much: every other run is gone).
pub fn low_space(policy: &StoragePolicy, dir: &Path, free_bytes: u64) -> Option<String> {
    let threshold = policy
        .warn_free_bytes
        .max(policy.min_free_bytes.unwrap_or(0));
    if free_bytes >= threshold {
        return None;
    }
    let hours = free_bytes as f64 / (0.75 * GB);
    Some(format!(
        "low disk space: {:.2} GB free in {} (warned below {:.2} GB); about {hours:.1} h of a full-rate run; free space, or set [storage] keep_days / min_free_gb",
        free_bytes as f64 / GB,
        dir.display(),
        threshold as f64 / GB
    ))
}

/// Apply the policy and report each deleted run (INFO); returns the low-space warning, if
/// any, and sets `alarm`. Errors are reported, never fatal: the run goes on.
pub fn apply_and_report(
    policy: &StoragePolicy,
    dir: &Path,
    current: Option<&Path>,
    free: &dyn FreeSpace,
    alarm: &DiskAlarm,
) -> Option<String> {
    match apply(policy, dir, current, SystemTime::now(), free) {
        Ok(a) => {
            for (p, why) in &a.deleted {
                tracing::info!("retention: deleted {} ({why})", p.display());
            }
            set_alarm(alarm, policy, dir, a.free_bytes);
            low_space(policy, dir, a.free_bytes)
        }
        Err(e) => {
            tracing::warn!("retention in {} failed: {e}", dir.display());
            None
        }
    }
}

/// Checks between two repeats of the low-space warning during a run (10 min at the period).
const WARN_EVERY: u32 = 60;

/// The low-space state as systemd's `STATUS=` shows it (`LOW DISK 1.23 GB free`), shared
/// with the pipeline; `None` while there is room.
pub type DiskAlarm = std::sync::Arc<std::sync::Mutex<Option<String>>>;

/// Set `alarm` from the free bytes under `policy`.
pub fn set_alarm(alarm: &DiskAlarm, policy: &StoragePolicy, dir: &Path, free_bytes: u64) {
    let text = low_space(policy, dir, free_bytes)
        .map(|_| format!("{:.2} GB free", free_bytes as f64 / GB));
    if let Ok(mut a) = alarm.lock() {
        *a = text;
    }
}

/// Where and how often [`watch`] applies the policy during a run.
pub struct Watch {
    pub policy: StoragePolicy,
    pub dir: PathBuf,
    /// The run being written: never deleted.
    pub current: PathBuf,
    pub free: std::sync::Arc<dyn FreeSpace + Send + Sync>,
    pub period: Duration,
    /// Set while the space is low (for `STATUS=`).
    pub alarm: DiskAlarm,
}

impl Watch {
    /// The service's: the file system's free space, every [`CHECK_PERIOD`].
    pub fn service(
        policy: StoragePolicy,
        dir: PathBuf,
        current: PathBuf,
        alarm: DiskAlarm,
    ) -> Watch {
        Watch {
            policy,
            dir,
            current,
            free: std::sync::Arc::new(Statvfs),
            period: CHECK_PERIOD,
            alarm,
        }
    }
}

/// While `cancel` is not cancelled: apply the policy every period (never to the current run);
/// warn when the space gets low and every [`WARN_EVERY`] checks while it stays low, and say
/// once when it has recovered.
pub async fn watch(w: Watch, cancel: tokio_util::sync::CancellationToken) {
    let w = std::sync::Arc::new(w);
    let mut low = false;
    let mut low_checks = 0u32;
    let mut tick = tokio::time::interval(w.period);
    tick.tick().await;
    loop {
        tokio::select! {
            _ = cancel.cancelled() => return,
            _ = tick.tick() => {}
        }
        let w2 = w.clone();
        let warning = tokio::task::spawn_blocking(move || {
            apply_and_report(
                &w2.policy,
                &w2.dir,
                Some(&w2.current),
                w2.free.as_ref(),
                &w2.alarm,
            )
        })
        .await
        .unwrap_or(None);
        let now_low = warning.is_some();
        if let Some(text) = warning {
            if low_checks.is_multiple_of(WARN_EVERY) {
                tracing::warn!("{text}");
            }
            low_checks += 1;
        } else {
            low_checks = 0;
        }
        if low && !now_low {
            tracing::info!(
                "disk space in {} is above the warning again",
                w.dir.display()
            );
        }
        low = now_low;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A directory with a capacity: free = capacity − the bytes of its files (what a small
    /// file system holding only these files would say).
    struct Capacity(u64);

    impl FreeSpace for Capacity {
        fn free_bytes(&self, dir: &Path) -> std::io::Result<u64> {
            let mut used = 0;
            for e in std::fs::read_dir(dir)? {
                used += e?.metadata()?.len();
            }
            Ok(self.0.saturating_sub(used))
        }
    }

    /// A run file of `bytes` last written `days_ago` days before `now`.
    fn run(dir: &Path, name: &str, bytes: usize, now: SystemTime, days_ago: f64) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, vec![0u8; bytes]).unwrap();
        let t = now - Duration::from_secs_f64(days_ago * 86_400.0);
        std::fs::File::options()
            .write(true)
            .open(&p)
            .unwrap()
            .set_modified(t)
            .unwrap();
        p
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// During a run: as the current run grows, the oldest runs go to keep `min_free`, the
    /// current one never (waited for by condition, not by time).
    #[tokio::test]
    async fn during_a_run_the_oldest_runs_make_room_as_the_current_one_grows() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().to_path_buf();
        let now = SystemTime::now();
        run(&d, "metrolog-a.mcap", 300, now, 3.0);
        run(&d, "metrolog-b.mcap", 300, now, 2.0);
        let current = run(&d, "metrolog-c.mcap", 100, now, 0.0);
        let policy = StoragePolicy {
            keep: None,
            min_free_bytes: Some(400),
            warn_free_bytes: 0,
            ..StoragePolicy::default()
        };
        // 1200 − 700 = 500 free: nothing to delete yet.
        let cancel = tokio_util::sync::CancellationToken::new();
        let task = tokio::spawn(watch(
            Watch {
                policy,
                dir: d.clone(),
                current: current.clone(),
                free: std::sync::Arc::new(Capacity(1200)),
                period: Duration::from_millis(5),
                alarm: DiskAlarm::default(),
            },
            cancel.clone(),
        ));
        // The run grows by 200 bytes: 300 free, so the oldest (a) must go, and only it.
        std::fs::write(&current, vec![0u8; 300]).unwrap();
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        while d.join("metrolog-a.mcap").exists() {
            assert!(std::time::Instant::now() < deadline, "a was never deleted");
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        // Grows again, past what deleting b can make up: b goes, the current run stays.
        std::fs::write(&current, vec![0u8; 1000]).unwrap();
        while d.join("metrolog-b.mcap").exists() {
            assert!(std::time::Instant::now() < deadline, "b was never deleted");
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        cancel.cancel();
        task.await.unwrap();
        assert_eq!(names(&d), ["metrolog-c.mcap"]);
    }

    /// A split run is deleted whole, oldest run first; no part of the current run goes, even
    /// its first part, older than everything else.
    #[test]
    fn split_runs_go_whole_and_the_current_run_keeps_every_part() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let now = SystemTime::now();
        run(d, "metrolog-m-a-p0001.mcap", 100, now, 5.0);
        run(d, "metrolog-m-a-p0002.mcap", 100, now, 4.9);
        run(d, "metrolog-m-b.mcap", 100, now, 4.0);
        run(d, "metrolog-m-c-p0001.mcap", 100, now, 6.0);
        let current = run(d, "metrolog-m-c-p0002.mcap", 100, now, 0.0);
        let policy = StoragePolicy {
            min_free_bytes: Some(350),
            ..StoragePolicy::default()
        };
        // 500 used of 600: 100 free; run a (200 bytes, the oldest by its last part) goes
        // whole (300 free), then b (400); c is the current run and stays although its part 1 is the oldest file.
        let a = apply(&policy, d, Some(&current), now, &Capacity(600)).unwrap();
        let deleted: Vec<String> = a
            .deleted
            .iter()
            .map(|(p, _)| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(deleted, ["metrolog-m-a-p0001.mcap", "metrolog-m-b.mcap"]);
        assert!(a.deleted[0].1.contains("all 2 parts"), "{:?}", a.deleted);
        assert!(
            a.deleted[0]
                .1
                .starts_with("0.0000001000 GB free, less than min_free_gb 0.0000003500"),
            "{:?}",
            a.deleted
        );
        assert_eq!(
            names(d),
            ["metrolog-m-c-p0001.mcap", "metrolog-m-c-p0002.mcap"]
        );
    }

    #[test]
    fn runs_older_than_keep_days_are_deleted_and_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let now = SystemTime::now();
        run(d, "metrolog-m-20260101T000000Z.mcap", 10, now, 40.0);
        run(d, "metrolog-m-20260201T000000Z.mcap", 10, now, 29.0);
        // Not a run: kept whatever its age.
        run(d, "report.html", 10, now, 400.0);
        // The current run, even if its time says old (a clock set back), is kept.
        let current = run(d, "metrolog-m-20250101T000000Z.mcap", 10, now, 365.0);
        let policy = StoragePolicy {
            keep: Some(Duration::from_secs(30 * 86_400)),
            ..StoragePolicy::default()
        };
        let a = apply(&policy, d, Some(&current), now, &Statvfs).unwrap();
        assert_eq!(a.deleted.len(), 1, "{:?}", a.deleted);
        assert!(a.deleted[0].1.contains("40.0 days ago"), "{:?}", a.deleted);
        assert_eq!(
            names(d),
            [
                "metrolog-m-20250101T000000Z.mcap",
                "metrolog-m-20260201T000000Z.mcap",
                "report.html"
            ]
        );
    }

    #[test]
    fn the_oldest_runs_go_until_min_free_and_never_the_current_one() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let now = SystemTime::now();
        // 4 runs of 300 bytes on a "disk" of 1500: 300 free.
        run(d, "metrolog-a.mcap", 300, now, 4.0);
        run(d, "metrolog-b.mcap", 300, now, 3.0);
        run(d, "metrolog-c.mcap", 300, now, 2.0);
        let current = run(d, "metrolog-d.mcap", 300, now, 0.0);
        let policy = StoragePolicy {
            keep: None,
            min_free_bytes: Some(800),
            warn_free_bytes: 1000,
            ..StoragePolicy::default()
        };
        let fs = Capacity(1500);
        let a = apply(&policy, d, Some(&current), now, &fs).unwrap();
        // 300 → 600 → 900 free: a and b deleted, oldest first.
        let deleted: Vec<String> = a
            .deleted
            .iter()
            .map(|(p, _)| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(deleted, ["metrolog-a.mcap", "metrolog-b.mcap"]);
        assert_eq!(a.free_bytes, 900);
        assert_eq!(names(d), ["metrolog-c.mcap", "metrolog-d.mcap"]);
        // Still below warn_free: the warning says how much is free.
        let w = low_space(&policy, d, a.free_bytes).unwrap();
        assert!(w.contains("0.00 GB free"), "{w}");

        // The current run alone, and still short of space: it stays.
        std::fs::remove_file(d.join("metrolog-c.mcap")).unwrap();
        let a = apply(&policy, d, Some(&current), now, &Capacity(500)).unwrap();
        assert!(a.deleted.is_empty());
        assert!(current.exists());
        assert!(low_space(&policy, d, 10_000).is_none());
    }
}
