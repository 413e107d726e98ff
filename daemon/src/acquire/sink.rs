//! Where the pipeline puts the driver events ([`EventSink`]): the run's log ([`LiveLog`]: the
//! [`Recorder`] and the thread that makes the file durable once a second), or the pose engine
//! alone ([`DetectOnly`], benchmarks and tests). A sink keeps the run's one [`RunCounts`].

use std::time::Duration;

use drivers::DriverEvent;
use metrolog_log::topics::PoseMsg;

use detect::PoseEngine;

use super::counts::RunCounts;
use super::recorder::Recorder;

/// Where the pipeline puts the driver events: the MCAP log with its pose engine in a run
/// ([`LiveLog`]), the pose engine alone in benchmarks and tests ([`DetectOnly`]).
pub trait EventSink: Send {
    /// Record one event; returns the pose values it completes.
    fn record(&mut self, ev: &DriverEvent, now_ns: u64) -> anyhow::Result<Vec<PoseMsg>>;
    /// Called at least once a second (status record, flushing).
    fn tick(&mut self, now_ns: u64) -> anyhow::Result<()>;
    /// Close open dwells and the log; returns the last pose values and the final counts.
    fn finish(self: Box<Self>, now_ns: u64) -> anyhow::Result<Closed>;
    /// The run's counts so far: the drivers' counters and the pose values this sink recorded.
    fn counts(&self) -> &RunCounts;
    /// Whether triggers are placed as they come ([`PoseEngine::placing_at_once`]): poses of
    /// triggers that waited for the NC clock fit to settle are left out of the pose latency.
    fn placing_at_once(&self) -> bool {
        true
    }
}

/// What a sink hands back when it closes.
#[derive(Debug, Clone, Default)]
pub struct Closed {
    /// The pose values of the dwells still open at the end.
    pub poses: Vec<PoseMsg>,
    /// The run's final counts (those poses included).
    pub counts: RunCounts,
}

/// The run's log: the [`Recorder`] (raw topics, pose engine, `/status`), writing through the
/// page cache, and a thread that makes the file durable once a second. `fdatasync` of a busy
/// log can take hundreds of milliseconds; on the pipeline thread it would hold up every event
/// behind it (measured: pose records up to 0.5 s late at full rates), on its own thread it
/// holds up nothing. A power cut loses at most about two seconds instead of one. When a split
/// run goes on in a new part, the thread syncs the finished part once more and then follows
/// the new one.
pub struct LiveLog {
    recorder: Recorder,
    /// The run's first file (part 1 of a split run): what names the run.
    path: std::path::PathBuf,
    /// The part the sync thread follows.
    part: u32,
    /// A new file to follow (`Some`), or the end (`None`).
    sync_tx: std::sync::mpsc::Sender<Option<std::fs::File>>,
    sync_thread: Option<std::thread::JoinHandle<()>>,
}

/// The log-sync thread: `fdatasync` the file once a second; a new file replaces it after a
/// last sync of the old one; the end syncs it a last time.
fn sync_loop(
    mut file: std::fs::File,
    rx: std::sync::mpsc::Receiver<Option<std::fs::File>>,
    shown: std::path::PathBuf,
) {
    let mut reported = false;
    loop {
        let msg = rx.recv_timeout(Duration::from_secs(1));
        if let Err(e) = file.sync_data()
            && !reported
        {
            reported = true;
            tracing::error!("cannot sync {} to disk: {e}", shown.display());
        }
        match msg {
            Ok(Some(next)) => file = next,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
            Ok(None) | Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
        }
    }
}

impl LiveLog {
    /// Around an open recorder; starts the log-sync thread.
    pub fn new(mut recorder: Recorder) -> anyhow::Result<LiveLog> {
        use anyhow::Context;
        let path = recorder.writer().path().to_path_buf();
        // fsync(2) works on a descriptor opened for reading: it flushes the file, not the fd.
        let file = std::fs::File::open(&path)
            .with_context(|| format!("cannot open {} for syncing", path.display()))?;
        let (sync_tx, rx) = std::sync::mpsc::channel();
        let shown = path.clone();
        let sync_thread = std::thread::Builder::new()
            .name("log-sync".into())
            .spawn(move || sync_loop(file, rx, shown))
            .context("cannot start the log-sync thread")?;
        Ok(LiveLog {
            part: recorder.part(),
            recorder,
            path,
            sync_tx,
            sync_thread: Some(sync_thread),
        })
    }

    /// After a write: when a split run went on in a new part, the sync thread follows it.
    fn follow_part(&mut self) -> anyhow::Result<()> {
        let part = self.recorder.part();
        if part == self.part {
            return Ok(());
        }
        use anyhow::Context;
        self.part = part;
        let path = self.recorder.log_path().to_path_buf();
        let file = std::fs::File::open(&path)
            .with_context(|| format!("cannot open {} for syncing", path.display()))?;
        tracing::info!("log continues in part {part}: {}", path.display());
        let _ = self.sync_tx.send(Some(file));
        Ok(())
    }

    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Hands every message written from now on to `tap` too (the live view).
    pub fn set_tap(&mut self, tap: metrolog_log::MessageTap) {
        self.recorder.writer().set_tap(tap);
    }
}

impl EventSink for LiveLog {
    fn record(&mut self, ev: &DriverEvent, now_ns: u64) -> anyhow::Result<Vec<PoseMsg>> {
        let poses = self.recorder.record(ev, now_ns)?;
        self.follow_part()?;
        Ok(poses)
    }
    fn tick(&mut self, now_ns: u64) -> anyhow::Result<()> {
        self.recorder.tick(now_ns)?;
        self.follow_part()
    }
    fn counts(&self) -> &RunCounts {
        self.recorder.counts()
    }
    fn placing_at_once(&self) -> bool {
        self.recorder.placing_at_once()
    }
    fn finish(self: Box<Self>, now_ns: u64) -> anyhow::Result<Closed> {
        let LiveLog {
            recorder,
            path: first,
            sync_tx,
            sync_thread,
            part,
        } = *self;
        let r = recorder.finish_counted(now_ns);
        // The last sync, after the footer.
        let _ = sync_tx.send(None);
        if let Some(h) = sync_thread {
            let _ = h.join();
        }
        let (path, poses, counts) = r?;
        match part {
            1 => tracing::info!("log closed: {}", path.display()),
            n => tracing::info!(
                "log closed: {} parts, {} .. {}",
                n,
                first.display(),
                path.display()
            ),
        }
        Ok(Closed { poses, counts })
    }
}

/// The pose engine without a log (benchmarks, tests).
pub struct DetectOnly {
    engine: PoseEngine,
    counts: RunCounts,
}

impl DetectOnly {
    pub fn new(engine: PoseEngine) -> DetectOnly {
        DetectOnly {
            engine,
            counts: RunCounts::default(),
        }
    }

    fn counted(&mut self, poses: Vec<PoseMsg>) -> Vec<PoseMsg> {
        for p in &poses {
            self.counts.on_pose(p);
        }
        poses
    }
}

impl EventSink for DetectOnly {
    fn record(&mut self, ev: &DriverEvent, _now_ns: u64) -> anyhow::Result<Vec<PoseMsg>> {
        self.counts.on_event(ev);
        let poses = match ev {
            DriverEvent::Sample(s) => self.engine.on_sample(s),
            DriverEvent::Trigger(t) => self.engine.on_trigger(t),
            _ => Vec::new(),
        };
        Ok(self.counted(poses))
    }
    fn tick(&mut self, _now_ns: u64) -> anyhow::Result<()> {
        Ok(())
    }
    fn counts(&self) -> &RunCounts {
        &self.counts
    }
    fn finish(mut self: Box<Self>, now_ns: u64) -> anyhow::Result<Closed> {
        let last = self.engine.finish(now_ns);
        let poses = self.counted(last);
        Ok(Closed {
            poses,
            counts: self.counts,
        })
    }
    fn placing_at_once(&self) -> bool {
        self.engine.placing_at_once()
    }
}
