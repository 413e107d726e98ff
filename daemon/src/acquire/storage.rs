//! The log directory's policy (`[storage]`, README "Disk space"): a retention rule (runs older
//! than `keep_days` deleted; the oldest runs deleted while less than `min_free_gb` is free)
//! applied before a run starts and once a minute while it runs, never to the run being written;
//! and a warning when less than `warn_free_gb` is free.
//!
//! A run is a file `metrolog-*.mcap` directly in `output_dir` (the names the log writer gives);
//! nothing else there is touched. Free space is read through [`FreeSpace`], so the tests can
//! give a directory a capacity without mounting a file system.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// Bytes in a GB as the config counts them (10^9, as disks are sold and `df -H` shows).
pub const GB: f64 = 1e9;

/// Default of `[storage] warn_free_gb`: about 6 h of a run at the highest rates (0.75 GB/h).
pub const DEFAULT_WARN_FREE_GB: f64 = 5.0;

/// How often the policy is applied while a run is written.
pub const CHECK_PERIOD: Duration = Duration::from_secs(60);

/// `[storage]`: what may be deleted, and when to warn.
#[derive(Debug, Clone, PartialEq)]
pub struct StoragePolicy {
    /// Delete runs last written longer ago than this (None: never by age).
    pub keep: Option<Duration>,
    /// Delete the oldest runs while less than this many bytes are free (None: never for space).
    pub min_free_bytes: Option<u64>,
    /// Warn while less than this many bytes are free.
    pub warn_free_bytes: u64,
}

impl Default for StoragePolicy {
    /// Without a `[storage]` section nothing is deleted; the warning stays on.
    fn default() -> Self {
        StoragePolicy {
            keep: None,
            min_free_bytes: None,
            warn_free_bytes: (DEFAULT_WARN_FREE_GB * GB) as u64,
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

/// One run's file.
#[derive(Debug, Clone)]
pub struct RunFile {
    pub path: PathBuf,
    pub modified: SystemTime,
    pub bytes: u64,
}

/// The runs in `dir`, oldest (last written first) first.
pub fn runs(dir: &Path) -> std::io::Result<Vec<RunFile>> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir)? {
        let e = e?;
        let name = e.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with("metrolog-") && name.ends_with(".mcap")) {
            continue;
        }
        let m = e.metadata()?;
        if m.is_file() {
            v.push(RunFile {
                path: e.path(),
                modified: m.modified()?,
                bytes: m.len(),
            });
        }
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
/// less than `min_free_bytes` is free. `current` (the run being written) is never deleted.
pub fn apply(
    policy: &StoragePolicy,
    dir: &Path,
    current: Option<&Path>,
    now: SystemTime,
    free: &dyn FreeSpace,
) -> std::io::Result<Applied> {
    let mut out = Applied::default();
    let candidates: Vec<RunFile> = runs(dir)?
        .into_iter()
        .filter(|r| Some(r.path.as_path()) != current)
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
                "{:.2} GB free, less than min_free_gb {:.2}",
                out.free_bytes as f64 / GB,
                min as f64 / GB
            );
            delete(&r, why, &mut out)?;
            out.free_bytes = free.free_bytes(dir)?;
        }
    }
    Ok(out)
}

fn delete(r: &RunFile, why: String, out: &mut Applied) -> std::io::Result<()> {
    match std::fs::remove_file(&r.path) {
        Ok(()) => {}
        // Gone already (an operator moved it): nothing to do.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e),
    }
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

/// Apply the policy and report what it did (INFO per deleted run, WARN when space is low).
/// Returns whether the space is low. Errors are reported, never fatal: the run goes on.
pub fn apply_and_report(
    policy: &StoragePolicy,
    dir: &Path,
    current: Option<&Path>,
    free: &dyn FreeSpace,
) -> bool {
    match apply(policy, dir, current, SystemTime::now(), free) {
        Ok(a) => {
            for (p, why) in &a.deleted {
                tracing::info!("retention: deleted {} ({why})", p.display());
            }
            match low_space(policy, dir, a.free_bytes) {
                Some(w) => {
                    tracing::warn!("{w}");
                    true
                }
                None => false,
            }
        }
        Err(e) => {
            tracing::warn!("retention in {} failed: {e}", dir.display());
            false
        }
    }
}

/// While `cancel` is not cancelled: apply the policy every [`CHECK_PERIOD`] (never to
/// `current`); warn when the space gets low, and once more when it has recovered.
pub async fn watch(
    policy: StoragePolicy,
    dir: PathBuf,
    current: PathBuf,
    cancel: tokio_util::sync::CancellationToken,
) {
    let mut low = false;
    let mut tick = tokio::time::interval(CHECK_PERIOD);
    tick.tick().await;
    loop {
        tokio::select! {
            _ = cancel.cancelled() => return,
            _ = tick.tick() => {}
        }
        let (p, d, c) = (policy.clone(), dir.clone(), current.clone());
        let was_low = low;
        let now_low = tokio::task::spawn_blocking(move || {
            // Warn on every check while low: each WARN line is a minute apart.
            apply_and_report(&p, &d, Some(&c), &Statvfs)
        })
        .await
        .unwrap_or(was_low);
        if was_low && !now_low {
            tracing::info!(
                "disk space in {} is above warn_free_gb again",
                dir.display()
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
