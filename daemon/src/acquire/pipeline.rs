//! The acquisition pipeline: driver events in, steady values out, everything recorded.
//!
//! ```text
//! drivers ──(one bounded queue)──▶ Pipeline ──▶ log::Recorder: raw topics, PoseEngine (a
//!                                     │          SteadyDetector per instrument) ─▶ /pose, /status
//!                                     └──── status for systemd (STATUS, WATCHDOG) and progress
//! ```
//!
//! The pipeline runs on its own thread (see [`spawn`]) so that writing the log never delays the
//! drivers' tasks; the drivers never wait on the queue (a full queue is counted by them as
//! `dropped`). The pose values come from the log's `PoseEngine`, the very code `metrolog replay`
//! runs, so a replay reproduces them.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use drivers::{DriverEvent, HostClock, Instrument};
use protocol::can::TriggerEvent;
use serde::Serialize;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

use metrolog_log::DetectorSettings;
use metrolog_log::topics::PoseMsg;
use types::PoseStatus;

use crate::acquire::service::{Notifier, Watchdog};
use detect::PoseEngine;

/// Capacity of the queue from the drivers to the pipeline: one second of every instrument at
/// its highest rate (10 kHz + 20 kHz + 1 kHz) plus margin, so a log flush of up to a second
/// costs nothing.
pub const QUEUE_CAPACITY: usize = 1 << 16;

/// How often `/status` is written and systemd hears from us.
pub const STATUS_PERIOD: Duration = Duration::from_secs(1);

/// Where the pipeline puts the driver events: the MCAP log with its pose engine in a run
/// ([`super::recorder::Recorder`]), the pose engine alone in benchmarks and tests ([`DetectOnly`]).
pub trait EventSink: Send {
    /// Record one event; returns the pose values it completes.
    fn record(&mut self, ev: &DriverEvent, now_ns: u64) -> anyhow::Result<Vec<PoseMsg>>;
    /// Called at least once a second (status record, flushing).
    fn tick(&mut self, now_ns: u64) -> anyhow::Result<()>;
    /// Close open dwells and the log; returns the last pose values.
    fn finish(self: Box<Self>, now_ns: u64) -> anyhow::Result<Vec<PoseMsg>>;
    /// Whether triggers are placed as they come ([`PoseEngine::placing_at_once`]): poses of
    /// triggers that waited for the NC clock fit to settle are left out of the pose latency.
    fn placing_at_once(&self) -> bool {
        true
    }
}

/// The run's log: the log's `Recorder` (raw topics, pose engine, `/status`), writing through
/// the page cache, and a thread that makes the file durable once a second. `fdatasync` of a
/// busy log can take hundreds of milliseconds; on the pipeline thread it would hold up every
/// event behind it (measured: pose records up to 0.5 s late at full rates), on its own thread
/// it holds up nothing. A power cut loses at most about two seconds instead of one.
pub struct LiveLog {
    recorder: super::recorder::Recorder,
    path: std::path::PathBuf,
    sync_stop: std::sync::mpsc::Sender<()>,
    sync_thread: Option<std::thread::JoinHandle<()>>,
}

impl LiveLog {
    fn new(mut recorder: super::recorder::Recorder) -> anyhow::Result<LiveLog> {
        use anyhow::Context;
        let path = recorder.writer().path().to_path_buf();
        // fsync(2) works on a descriptor opened for reading: it flushes the file, not the fd.
        let file = std::fs::File::open(&path)
            .with_context(|| format!("cannot open {} for syncing", path.display()))?;
        let (sync_stop, stop_rx) = std::sync::mpsc::channel::<()>();
        let shown = path.clone();
        let sync_thread = std::thread::Builder::new()
            .name("log-sync".into())
            .spawn(move || {
                let mut reported = false;
                loop {
                    let last = !matches!(
                        stop_rx.recv_timeout(Duration::from_secs(1)),
                        Err(std::sync::mpsc::RecvTimeoutError::Timeout)
                    );
                    if let Err(e) = file.sync_data()
                        && !reported
                    {
                        reported = true;
                        tracing::error!("cannot sync {} to disk: {e}", shown.display());
                    }
                    if last {
                        break;
                    }
                }
            })
            .context("cannot start the log-sync thread")?;
        Ok(LiveLog {
            recorder,
            path,
            sync_stop,
            sync_thread: Some(sync_thread),
        })
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
        Ok(self.recorder.record(ev, now_ns)?)
    }
    fn tick(&mut self, now_ns: u64) -> anyhow::Result<()> {
        Ok(self.recorder.tick(now_ns)?)
    }
    fn placing_at_once(&self) -> bool {
        self.recorder.placing_at_once()
    }
    fn finish(self: Box<Self>, now_ns: u64) -> anyhow::Result<Vec<PoseMsg>> {
        let LiveLog {
            recorder,
            sync_stop,
            sync_thread,
            ..
        } = *self;
        let r = recorder.finish(now_ns);
        // The last sync, after the footer.
        let _ = sync_stop.send(());
        if let Some(h) = sync_thread {
            let _ = h.join();
        }
        let (path, poses) = r?;
        tracing::info!("log closed: {}", path.display());
        Ok(poses)
    }
}

/// The pose engine without a log (benchmarks, tests).
pub struct DetectOnly(pub PoseEngine);

impl EventSink for DetectOnly {
    fn record(&mut self, ev: &DriverEvent, _now_ns: u64) -> anyhow::Result<Vec<PoseMsg>> {
        Ok(match ev {
            DriverEvent::Sample(s) => self.0.on_sample(s),
            DriverEvent::Trigger(t) => self.0.on_trigger(t),
            _ => Vec::new(),
        })
    }
    fn tick(&mut self, _now_ns: u64) -> anyhow::Result<()> {
        Ok(())
    }
    fn finish(mut self: Box<Self>, now_ns: u64) -> anyhow::Result<Vec<PoseMsg>> {
        Ok(self.0.finish(now_ns))
    }
    fn placing_at_once(&self) -> bool {
        self.0.placing_at_once()
    }
}

/// Whether the NC program runs, as told by the triggers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ProgramState {
    /// No program start or end seen yet (or no trigger configured).
    #[default]
    Unknown,
    Running,
    /// Program end seen, no start since.
    Ended,
    /// Feed hold / abort.
    Held,
}

/// Per-instrument part of the status.
#[derive(Debug, Clone, Default, Serialize)]
pub struct InstrumentStatus {
    pub connected: bool,
    pub port: String,
    pub identity: String,
    /// Events the pipeline received from this instrument's driver (samples or triggers).
    pub received: u64,
    /// Pose values written, by status.
    pub poses: BTreeMap<&'static str, u64>,
    /// The driver's own counters (latest snapshot).
    pub driver: drivers::Counters,
    pub last_error: Option<String>,
}

impl InstrumentStatus {
    /// Faults: every counted defect of the stream.
    pub fn faults(&self) -> u64 {
        let d = &self.driver;
        d.gaps
            + d.rejections.values().sum::<u64>()
            + d.resyncs
            + d.disconnects
            + d.dropped
            + d.device_errors
    }
}

/// The `/status` record: every counter of the run.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Status {
    /// Host time of this status, ns since the Unix epoch.
    pub t_ns: u64,
    pub uptime_s: f64,
    pub instruments: BTreeMap<Instrument, InstrumentStatus>,
    pub program: ProgramState,
    /// Pose values written (all instruments, all statuses).
    pub poses: u64,
    pub poses_ok: u64,
    /// Highest pose index seen in a trigger or a pose value.
    pub last_pose: u32,
    /// Events waiting in the queue now, and the most ever.
    pub queue_len: usize,
    pub queue_max: usize,
    pub queue_capacity: usize,
    /// Largest delay from the last sample of a pose window to its pose record, ms.
    pub pose_latency_max_ms: f64,
    /// Records the log writer refused (disk full, ...).
    pub log_errors: u64,
    /// Why the log could not be written, once it failed (the run then stops: see
    /// [`StopReason::LogFailed`]).
    pub log_failed: Option<String>,
}

impl Status {
    pub fn samples(&self) -> u64 {
        self.instruments
            .iter()
            .filter(|(i, _)| **i != Instrument::Trigger)
            .map(|(_, s)| s.received)
            .sum()
    }
    pub fn faults(&self) -> u64 {
        self.instruments.values().map(|s| s.faults()).sum()
    }
    /// Samples the drivers could not deliver or the devices never sent.
    pub fn lost(&self) -> u64 {
        self.instruments
            .values()
            .map(|s| s.driver.dropped + s.driver.gap_samples)
            .sum()
    }
    /// The one-line summary for systemd's STATUS and the terminal.
    pub fn summary(&self) -> String {
        let connected: Vec<&str> = self
            .instruments
            .iter()
            .filter(|(_, s)| s.connected)
            .map(|(i, _)| i.name())
            .collect();
        let failed = match &self.log_failed {
            Some(e) => format!("LOG WRITE FAILED, run stopped ({e}); "),
            None => String::new(),
        };
        format!(
            "{failed}poses {} ({} ok), samples {}, faults {}, lost {}, connected: {}",
            self.poses,
            self.poses_ok,
            self.samples(),
            self.faults(),
            self.lost(),
            if connected.is_empty() {
                "none".to_string()
            } else {
                connected.join(" ")
            }
        )
    }
}

/// Why the pipeline ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StopReason {
    /// The run was cancelled from outside (signal, demo end).
    Cancelled,
    /// The CNC sent program end and the config asks to stop there.
    ProgramEnd,
    /// Every driver ended (their senders are gone).
    DriversGone,
    /// The log could not be written (disk full, I/O error): the run stops rather than go on
    /// acquiring what it cannot keep. The file's prefix stays readable.
    LogFailed,
}

/// What the pipeline hands back at the end.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub reason: StopReason,
    pub status: Status,
    /// Every pose value (when `keep_poses`).
    pub poses: Vec<PoseMsg>,
}

/// Settings of a pipeline.
#[derive(Debug, Clone)]
pub struct PipelineConfig {
    pub instruments: Vec<Instrument>,
    pub stop_at_program_end: bool,
    /// Keep every pose value in the outcome (demo, tests).
    pub keep_poses: bool,
}

/// The pipeline's state (one per run).
pub struct Pipeline {
    cfg: PipelineConfig,
    clock: HostClock,
    instruments: BTreeMap<Instrument, InstrumentStatus>,
    status: Status,
    sink: Box<dyn EventSink>,
    started: Instant,
    last_sample: Option<Instant>,
    poses: Vec<PoseMsg>,
    stop: Option<StopReason>,
    log_error_reported: bool,
}

impl Pipeline {
    pub fn new(cfg: PipelineConfig, clock: HostClock, sink: Box<dyn EventSink>) -> Pipeline {
        let instruments = cfg
            .instruments
            .iter()
            .map(|&i| (i, InstrumentStatus::default()))
            .collect();
        Pipeline {
            cfg,
            clock,
            instruments,
            status: Status {
                queue_capacity: QUEUE_CAPACITY,
                ..Status::default()
            },
            sink,
            started: Instant::now(),
            last_sample: None,
            poses: Vec::new(),
            stop: None,
            log_error_reported: false,
        }
    }

    /// A failed write stops the run (disk full: going on would only retry a failing write for
    /// every sample, and acquire what cannot be kept); the journal and the status say why.
    fn sink_result<T: Default>(&mut self, r: anyhow::Result<T>) -> T {
        match r {
            Ok(v) => v,
            Err(e) => {
                self.status.log_errors += 1;
                if !self.log_error_reported {
                    self.log_error_reported = true;
                    tracing::error!("the log writer failed; stopping the run: {e:#}");
                    self.status.log_failed = Some(format!("{e:#}"));
                    self.stop = Some(StopReason::LogFailed);
                }
                T::default()
            }
        }
    }

    fn slot(&mut self, i: Instrument) -> &mut InstrumentStatus {
        self.instruments.entry(i).or_default()
    }

    /// Counts pose values; `timed`: their latency counts (not when their triggers waited for
    /// the NC clock fit to settle, docs/design.md).
    fn count_poses(&mut self, poses: Vec<PoseMsg>, timed: bool) {
        if poses.is_empty() {
            return;
        }
        let now = self.clock.now_ns();
        for v in poses {
            if v.n > 0 && timed {
                let latency_ms = now.saturating_sub(v.t_last_ns) as f64 / 1e6;
                if latency_ms > self.status.pose_latency_max_ms {
                    self.status.pose_latency_max_ms = latency_ms;
                }
            }
            self.status.poses += 1;
            if v.status == PoseStatus::Ok {
                self.status.poses_ok += 1;
            }
            self.status.last_pose = self.status.last_pose.max(v.pose);
            *self
                .slot(v.instrument)
                .poses
                .entry(v.status.name())
                .or_default() += 1;
            tracing::debug!(
                instrument = v.instrument.name(),
                pose = v.pose,
                status = v.status.name(),
                "pose value"
            );
            if self.cfg.keep_poses {
                self.poses.push(v);
            }
        }
    }

    /// Handle one driver event.
    pub fn handle(&mut self, ev: DriverEvent) {
        let now = self.clock.now_ns();
        let timed = self.sink.placing_at_once();
        let r = self.sink.record(&ev, now);
        let poses = self.sink_result(r);
        match ev {
            DriverEvent::Sample(s) => {
                self.last_sample = Some(Instant::now());
                self.slot(s.instrument).received += 1;
            }
            DriverEvent::Trigger(t) => {
                self.slot(Instrument::Trigger).received += 1;
                self.status.last_pose = self.status.last_pose.max(t.pose as u32);
                match t.event {
                    TriggerEvent::ProgramStart => self.status.program = ProgramState::Running,
                    TriggerEvent::ProgramEnd => {
                        self.status.program = ProgramState::Ended;
                        tracing::info!("program end");
                        if self.cfg.stop_at_program_end {
                            self.stop = Some(StopReason::ProgramEnd);
                        }
                    }
                    TriggerEvent::FeedHold => self.status.program = ProgramState::Held,
                    _ => self.status.program = ProgramState::Running,
                }
            }
            DriverEvent::Connected {
                instrument,
                port,
                identity,
            } => {
                let st = self.slot(instrument);
                st.connected = true;
                st.port = port;
                st.identity = identity;
            }
            DriverEvent::Disconnected {
                instrument, port, ..
            } => {
                let st = self.slot(instrument);
                st.connected = false;
                st.port = port;
            }
            DriverEvent::Error {
                instrument, error, ..
            } => {
                self.slot(instrument).last_error = Some(error.to_string());
            }
            DriverEvent::Counters {
                instrument,
                counters,
            } => {
                self.slot(instrument).driver = counters;
            }
        }
        self.count_poses(poses, timed);
    }

    /// Snapshot the status.
    pub fn status(&mut self, queue_len: usize) -> Status {
        self.status.t_ns = self.clock.now_ns();
        self.status.uptime_s = self.started.elapsed().as_secs_f64();
        self.status.queue_len = queue_len;
        self.status.queue_max = self.status.queue_max.max(queue_len);
        self.status.instruments = self.instruments.clone();
        self.status.clone()
    }

    /// The once-a-second work: the sink's status record and flush.
    fn tick(&mut self, queue_len: usize) -> Status {
        let now = self.clock.now_ns();
        let r = self.sink.tick(now);
        self.sink_result(r);
        self.status(queue_len)
    }

    /// The watchdog facts now (see [`crate::acquire::service`]).
    fn watchdog(&self, interval: Duration) -> Watchdog {
        Watchdog {
            since_loop_s: 0.0,
            since_sample_s: self.last_sample.map(|t| t.elapsed().as_secs_f64()),
            uptime_s: self.started.elapsed().as_secs_f64(),
            connected: self.instruments.values().filter(|s| s.connected).count(),
            program_idle: self.status.program == ProgramState::Ended,
            interval_s: interval.as_secs_f64(),
        }
    }

    /// Close every open dwell, write the final status and close the log.
    pub fn finish(mut self, reason: StopReason, queue_len: usize) -> anyhow::Result<Outcome> {
        let now = self.clock.now_ns();
        let sink = std::mem::replace(
            &mut self.sink,
            Box::new(DetectOnly(PoseEngine::new(&DetectorSettings::default())?)),
        );
        let mut reason = reason;
        let timed = sink.placing_at_once();
        match sink.finish(now) {
            Ok(last) => self.count_poses(last, timed),
            // The file could not be closed (its footer not written): what was written before
            // stays readable, as after a kill (the reader reads the intact prefix).
            Err(e) => {
                tracing::error!("the log could not be closed cleanly: {e:#}");
                self.status.log_errors += 1;
                if self.status.log_failed.is_none() {
                    self.status.log_failed = Some(format!("{e:#}"));
                }
                reason = StopReason::LogFailed;
            }
        }
        let status = self.status(queue_len);
        Ok(Outcome {
            reason,
            status,
            poses: self.poses,
        })
    }

    /// The main loop: until cancelled, program end (if configured) or every driver gone.
    /// Publishes the status on `progress` after every pose and every second.
    pub async fn run(
        mut self,
        mut rx: mpsc::Receiver<DriverEvent>,
        cancel: CancellationToken,
        notifier: Notifier,
        progress: watch::Sender<Status>,
    ) -> anyhow::Result<Outcome> {
        let mut tick = tokio::time::interval(STATUS_PERIOD);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let watchdog_interval = notifier.watchdog_interval();
        let mut poses_published = 0u64;
        let reason = loop {
            tokio::select! {
                biased;
                _ = cancel.cancelled() => break StopReason::Cancelled,
                _ = tick.tick() => {
                    let st = self.tick(rx.len());
                    notifier.status(&st.summary());
                    if let Some(iv) = watchdog_interval {
                        if self.watchdog(iv).healthy() {
                            notifier.watchdog();
                        } else {
                            tracing::warn!(
                                "no samples for {:.0} s from connected instruments while a program runs; not petting the watchdog",
                                crate::acquire::service::STALL_TIMEOUT_S
                            );
                        }
                    }
                    progress.send_replace(st);
                    if let Some(r) = self.stop.clone() {
                        break r;
                    }
                }
                ev = rx.recv() => {
                    let Some(ev) = ev else { break StopReason::DriversGone };
                    self.handle(ev);
                    // Drain what is queued without going through select! for every event.
                    let mut budget = 4096;
                    while budget > 0 && self.stop.is_none() {
                        match rx.try_recv() {
                            Ok(ev) => self.handle(ev),
                            Err(_) => break,
                        }
                        budget -= 1;
                    }
                    self.status.queue_max = self.status.queue_max.max(rx.len());
                    if self.status.poses != poses_published {
                        poses_published = self.status.poses;
                        progress.send_replace(self.status(rx.len()));
                    }
                    if let Some(r) = self.stop.clone() {
                        break r;
                    }
                }
            }
        };
        // Whatever is already queued belongs to the run (not so after program end: the next
        // program's samples belong to the next run).
        if !matches!(reason, StopReason::ProgramEnd | StopReason::LogFailed) {
            while let Ok(ev) = rx.try_recv() {
                self.handle(ev);
            }
        }
        let out = self.finish(reason, rx.len())?;
        progress.send_replace(out.status.clone());
        Ok(out)
    }
}

/// Start the pipeline on its own thread (with its own single-threaded runtime), so writing the
/// log never competes with the drivers' tasks.
pub fn spawn(
    pipeline: Pipeline,
    rx: mpsc::Receiver<DriverEvent>,
    cancel: CancellationToken,
    notifier: Notifier,
    progress: watch::Sender<Status>,
) -> std::io::Result<std::thread::JoinHandle<anyhow::Result<Outcome>>> {
    std::thread::Builder::new()
        .name("pipeline".into())
        .spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_time()
                .build()?;
            rt.block_on(pipeline.run(rx, cancel, notifier, progress))
        })
}

/// The detector settings of a config: the same window length for every instrument; poses
/// delimited by the CNC's triggers when a `[trigger]` is configured, found as standstill
/// plateaus in the signal otherwise.
pub fn detector_settings(cfg: &crate::acquire::config::Config) -> DetectorSettings {
    let mut s = DetectorSettings::default().with_samples(cfg.detector.samples);
    // Only the configured instruments get pose values: one left out of the run is not "away".
    s.instruments.retain(|i| match i {
        drivers::Instrument::Interferometer => cfg.interferometer.is_some(),
        drivers::Instrument::Capball => cfg.capball.is_some(),
        drivers::Instrument::Psd => cfg.psd.is_some(),
        drivers::Instrument::Trigger | drivers::Instrument::Thermometer => false,
    });
    if cfg.trigger.is_none() {
        for c in [&mut s.interferometer, &mut s.capball, &mut s.psd] {
            c.mode = types::DetectorMode::Plateaus;
        }
    }
    s
}

/// Open the run's MCAP log in `[run] output_dir` (created if missing) with the run metadata and
/// the config, trajectory and CapBall transform attached, so the log replays on its own.
pub fn open_log(
    cfg: &crate::acquire::config::Config,
    clock: &HostClock,
) -> anyhow::Result<LiveLog> {
    use anyhow::Context;
    let dir = &cfg.run.output_dir;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create the output directory {}", dir.display()))?;
    let settings = detector_settings(cfg);
    let now = clock.now_ns();
    let mut extra = BTreeMap::new();
    extra.insert("config_path".to_string(), cfg.path.display().to_string());
    extra.insert(
        "stop_at_program_end".to_string(),
        cfg.run.stop_at_program_end.to_string(),
    );
    if cfg.run.time_scale != 1.0 {
        extra.insert("time_scale".to_string(), cfg.run.time_scale.to_string());
    }
    extra.insert(
        "instruments_configured".to_string(),
        cfg.instruments()
            .iter()
            .map(|i| i.name())
            .collect::<Vec<_>>()
            .join(","),
    );
    let meta = metrolog_log::RunMetadata {
        machine: cfg.run.machine.clone(),
        started_ns: now,
        detector: settings.clone(),
        instruments: BTreeMap::new(),
        // The log stores CB-3 samples as ADC codes with this calibration (docs/log-format.md).
        capball: cfg.capball.as_ref().map(|c| c.driver.calibration()),
        extra,
    };
    let mut writer = metrolog_log::LogWriter::create_in_dir(
        dir,
        &meta,
        metrolog_log::LogOptions {
            // Durability comes from the log-sync thread of [`LiveLog`].
            fsync: false,
            ..metrolog_log::LogOptions::default()
        },
    )?;
    writer.attach(
        metrolog_log::CONFIG_ATTACHMENT,
        "application/toml",
        cfg.text.as_bytes(),
        now,
    )?;
    if let Some(t) = &cfg.run.trajectory {
        writer.attach(
            metrolog_log::TRAJECTORY_ATTACHMENT,
            "text/csv",
            t.text.as_bytes(),
            now,
        )?;
    }
    if let Some((_, text)) = cfg.capball.as_ref().and_then(|c| c.transform_file.as_ref()) {
        writer.attach("capball-transform.csv", "text/csv", text.as_bytes(), now)?;
    }
    LiveLog::new(super::recorder::Recorder::new(writer, &settings)?)
}
