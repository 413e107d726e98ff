//! The acquisition pipeline: driver events in, steady values out, everything recorded.
//!
//! ```text
//! drivers ──(one bounded queue)──▶ Pipeline ──▶ EventSink (acquire::sink): the Recorder's raw
//!                                     │          topics, PoseEngine (a SteadyDetector per
//!                                     │          instrument) ─▶ /pose, /status
//!                                     └──── Status for systemd (STATUS, WATCHDOG) and progress
//! ```
//!
//! The pipeline runs on its own thread (see [`spawn`]) so that writing the log never delays the
//! drivers' tasks; the drivers never wait on the queue (a full queue is counted by them as
//! `dropped`). The pose values come from `detect::PoseEngine`, the very code `metrolog replay`
//! runs, so a replay reproduces them.
//!
//! The [`Status`] is the one model of the run's state: what the pipeline sees itself
//! (connections, events received, the program's state, the queue, pose latency, log failures)
//! beside the counts the sink keeps ([`RunCounts`]: driver counters, pose values by status),
//! which are read from the sink, never counted twice.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use drivers::{DriverEvent, HostClock, Instrument};
use metrolog_log::topics::PoseMsg;
use protocol::can::TriggerEvent;
use serde::Serialize;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

use super::counts::RunCounts;
use super::service::{Notifier, Watchdog};
use super::sink::EventSink;

/// Capacity of the queue from the drivers to the pipeline: one second of every instrument at
/// its highest rate (10 kHz + 20 kHz + 1 kHz) plus margin, so a log flush of up to a second
/// costs nothing.
pub const QUEUE_CAPACITY: usize = 1 << 16;

/// While the drivers coalesce their reads (`drivers::read_coalesce`), the pipeline takes the
/// queue this long after their tick: their reads of the tick are then queued (a read that
/// ends later says so, `drivers::late_reads`, and is taken then).
const BATCH_AFTER_TICK: Duration = drivers::TAKE_AFTER_TICK;
/// Longest wait, after the program end that stops a run, for the streaming readers' samples
/// up to that instant ([`Pipeline::catch_up_readers`]).
const CATCH_UP_LIMIT: Duration = Duration::from_secs(1);

/// How often `/status` is written and systemd hears from us.
pub const STATUS_PERIOD: Duration = Duration::from_secs(1);

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
    /// Pose values written, by status (from the sink's [`RunCounts`]).
    pub poses: BTreeMap<&'static str, u64>,
    /// The driver's own counters (latest snapshot, from the sink's [`RunCounts`]).
    pub driver: drivers::Counters,
    pub last_error: Option<String>,
    /// Connected at least once this run (a device that is not connected now was unplugged).
    #[serde(skip)]
    pub was_connected: bool,
    /// The status of this instrument's last pose value.
    #[serde(skip)]
    pub last_pose_status: Option<types::PoseStatus>,
    /// The datum alarm while the interferometer's epoch is not the run's (from its driver's
    /// datum change until the re-reference).
    #[serde(skip)]
    pub datum_alarm: Option<String>,
}

impl InstrumentStatus {
    /// Device faults, as the operator page's "Faults" counts them: device errors and
    /// disconnects.
    pub fn device_faults(&self) -> u64 {
        self.driver.device_errors + self.driver.disconnects
    }

    /// The alarm that holds on this instrument now, if any: unplugged, or what its last pose
    /// value says (beam lost, datum lost).
    pub fn alarm(&self) -> Option<String> {
        if self.was_connected && !self.connected {
            return Some("unplugged".to_string());
        }
        if let Some(a) = &self.datum_alarm {
            return Some(a.clone());
        }
        self.last_pose_status
            .and_then(super::progress::alarm_of)
            .map(str::to_string)
    }

    /// Stream defects: every counted defect of the stream (gaps, rejected frames, resyncs,
    /// disconnects, dropped samples, device errors).
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

/// The status of a run: every counter, as systemd's STATUS, the progress display and the
/// outcome see it.
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
    /// The "nothing connected" alarm while it holds: what was waited for and how long.
    pub nothing_connected: Option<String>,
    /// The low-disk alarm while it holds (`[storage] warn_free_gb`): the free space.
    pub low_disk: Option<String>,
    /// Poses in the run's trajectory (0: none given).
    #[serde(skip)]
    pub trajectory_len: usize,
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
    /// Device errors and disconnects, all instruments (the operator page's "Faults").
    pub fn device_faults(&self) -> u64 {
        self.instruments.values().map(|s| s.device_faults()).sum()
    }
    /// The alarms that hold now, per instrument.
    pub fn alarms(&self) -> Vec<(Instrument, String)> {
        self.instruments
            .iter()
            .filter_map(|(i, s)| s.alarm().map(|a| (*i, a)))
            .collect()
    }
    /// "pose k/N" (or "pose k", or "no pose yet").
    fn pose_progress(&self) -> String {
        match (self.last_pose, self.trajectory_len) {
            (0, _) => "no pose yet".to_string(),
            (k, 0) => format!("pose {k}"),
            (k, n) => format!("pose {k}/{n}"),
        }
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
        let mut failed = match &self.log_failed {
            Some(e) => format!("LOG WRITE FAILED, run stopped ({e}); "),
            None => String::new(),
        };
        if let Some(n) = &self.nothing_connected {
            failed.push_str(&format!("NOTHING CONNECTED {n}; "));
        }
        if let Some(d) = &self.low_disk {
            failed.push_str(&format!("LOW DISK {d}; "));
        }
        format!(
            "{failed}{}, {}, faults {}; poses {} ({} ok), samples {}, stream defects {}, lost {}, connected: {}",
            self.pose_progress(),
            super::progress::alarms_text(&self.alarms()),
            self.device_faults(),
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
    /// No device was connected for the [`ConnectPolicy`]'s time, and none is `hotplug`.
    NothingConnected,
}

/// What to do when no device is connected (README, "Nothing connected").
#[derive(Debug, Clone)]
pub struct ConnectPolicy {
    /// How long no device may be connected (from the start, or since the last one went).
    pub timeout: Duration,
    /// Some device is `hotplug`: raise the alarm and wait; otherwise end the run.
    pub wait: bool,
    /// Each device's port, named in the alarm.
    pub ports: Vec<(Instrument, String)>,
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
    /// The "nothing connected" alarm (None: never raised).
    pub connect: Option<ConnectPolicy>,
    /// The low-disk alarm the storage check keeps (None: none shown).
    pub disk_alarm: Option<super::storage::DiskAlarm>,
    /// The run's pose table: "pose k of N" and the targets in the terminal lines.
    pub trajectory: Vec<metrolog_log::trajectory::TrajectoryRow>,
    /// The LI-80 driver's datum commands (None: no interferometer).
    pub datum: Option<DatumControl>,
}

/// How the pipeline steers the interferometer's datum from the triggers (docs/design.md,
/// "Datum epochs"): a first trigger that is not the program start loses the datum (the
/// service started mid-program); the exact stop of the reference pose re-references a lost
/// epoch; a motion start cancels a `DATUM` still waiting.
#[derive(Debug, Clone)]
pub struct DatumControl {
    pub commands: tokio::sync::mpsc::UnboundedSender<drivers::Li80Command>,
    /// `[run] reference_pose` (empty: the run cannot re-reference).
    pub reference_poses: Vec<u32>,
    /// How long the axis stands at the reference pose before `DATUM`.
    pub settle: Duration,
}

impl DatumControl {
    fn on_trigger(&self, t: &types::Trigger, first: bool) {
        let pose = u32::from(t.pose);
        let cmd = match t.event {
            _ if first && t.event != TriggerEvent::ProgramStart => {
                drivers::Li80Command::LoseDatum {
                    reason: format!(
                        "the service started mid-program (its first trigger was {:?} of pose \
                         {pose}, not the program start)",
                        t.event
                    ),
                }
            }
            TriggerEvent::ExactStop if self.reference_poses.contains(&pose) => {
                drivers::Li80Command::Reference {
                    pose,
                    settle: self.settle,
                }
            }
            TriggerEvent::MotionStart => drivers::Li80Command::Moving,
            _ => return,
        };
        // The driver may be gone at the end of the run: nothing to steer then.
        let _ = self.commands.send(cmd);
    }
}

/// The pipeline: the sink and the run's state beside it (one per run).
pub struct Pipeline {
    sink: Box<dyn EventSink>,
    state: RunState,
}

/// What the pipeline itself keeps of a run: the [`Status`] without the sink's counts.
struct RunState {
    cfg: PipelineConfig,
    clock: HostClock,
    /// The status as the pipeline keeps it; `instruments[..].driver` and `.poses`, `poses` and
    /// `poses_ok` are filled from the sink's counts in every snapshot.
    status: Status,
    started: Instant,
    /// Host time (ns) of the batch of events that brought the last sample.
    last_sample_ns: Option<u64>,
    /// Since when no device is connected (None while one is).
    nothing_since: Option<Instant>,
    poses: Vec<PoseMsg>,
    stop: Option<StopReason>,
    /// Host time (ns) of the program-end trigger that stops the run.
    program_end_ns: Option<u64>,
}

impl RunState {
    fn slot(&mut self, i: Instrument) -> &mut InstrumentStatus {
        self.status.instruments.entry(i).or_default()
    }

    /// A failed write stops the run (disk full: going on would only retry a failing write for
    /// every sample, and acquire what cannot be kept); the journal and the status say why.
    fn sink_result<T: Default>(&mut self, r: anyhow::Result<T>) -> T {
        match r {
            Ok(v) => v,
            Err(e) => {
                self.status.log_errors += 1;
                if self.status.log_failed.is_none() {
                    tracing::error!("the log writer failed; stopping the run: {e:#}");
                    self.status.log_failed = Some(format!("{e:#}"));
                    self.stop = Some(StopReason::LogFailed);
                }
                T::default()
            }
        }
    }

    /// What the pipeline sees of one event (the sink has recorded it).
    fn on_event(&mut self, ev: DriverEvent, now_ns: u64) {
        match ev {
            DriverEvent::Sample(s) => {
                self.last_sample_ns = Some(now_ns);
                self.slot(s.instrument).received += 1;
            }
            DriverEvent::Trigger(t) => {
                let first = self.slot(Instrument::Trigger).received == 0;
                if let Some(d) = &self.cfg.datum {
                    d.on_trigger(&t, first);
                }
                self.slot(Instrument::Trigger).received += 1;
                self.status.last_pose = self.status.last_pose.max(t.pose as u32);
                match t.event {
                    TriggerEvent::ProgramStart => self.status.program = ProgramState::Running,
                    TriggerEvent::ProgramEnd => {
                        self.status.program = ProgramState::Ended;
                        tracing::info!("program end");
                        if self.cfg.stop_at_program_end {
                            self.stop = Some(StopReason::ProgramEnd);
                            self.program_end_ns = Some(t.host_ns);
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
                st.was_connected = true;
                st.port = port;
                st.identity = identity;
                self.connected_again(instrument);
            }
            DriverEvent::Disconnected {
                instrument, port, ..
            } => {
                let st = self.slot(instrument);
                st.connected = false;
                st.port = port;
                if self.status.instruments.values().all(|s| !s.connected) {
                    self.nothing_since = Some(Instant::now());
                }
            }
            DriverEvent::Error {
                instrument, error, ..
            } => {
                self.slot(instrument).last_error = Some(error.to_string());
            }
            // The sink keeps the counters ([`RunCounts`]); an instrument that sends them has
            // a place in the status.
            DriverEvent::Counters { instrument, .. } => {
                self.slot(instrument);
            }
            DriverEvent::Datum {
                instrument, change, ..
            } => {
                self.slot(instrument).datum_alarm = (!change.referenced)
                    .then(|| format!("datum lost (epoch {}): re-reference", change.epoch));
            }
        }
    }

    /// A device connected: the "nothing connected" alarm ends.
    fn connected_again(&mut self, instrument: Instrument) {
        self.nothing_since = None;
        if self.status.nothing_connected.take().is_some() {
            tracing::info!(
                "{} connected: the \"nothing connected\" alarm is over",
                instrument.name()
            );
        }
    }

    /// The "nothing connected" alarm, checked once a second with the time `now`: raised (an
    /// ERROR line, the STATUS prefix) once no device has been connected for the policy's
    /// time; the run stops there unless the policy waits.
    fn check_connected(&mut self, now: Instant) {
        let (Some(policy), Some(since)) = (&self.cfg.connect, self.nothing_since) else {
            return;
        };
        let waited = now.saturating_duration_since(since);
        if waited < policy.timeout {
            return;
        }
        let secs = waited.as_secs();
        let first = self.status.nothing_connected.is_none();
        let ports: Vec<String> = policy
            .ports
            .iter()
            .map(|(i, p)| {
                match &self
                    .status
                    .instruments
                    .get(i)
                    .and_then(|s| s.last_error.clone())
                {
                    Some(e) => format!("{} on {p} ({e})", i.name()),
                    None => format!("{} on {p}", i.name()),
                }
            })
            .collect();
        let what = ports.join(", ");
        self.status.nothing_connected = Some(format!("for {secs} s: {what}"));
        if !first {
            return;
        }
        let advice = "check that the devices are plugged in and powered, and that the ports in the config are theirs";
        if policy.wait {
            tracing::error!(
                "nothing connected for {secs} s: no device answered ({what}); {advice}; waiting for them (hotplug)"
            );
        } else {
            tracing::error!(
                "nothing connected for {secs} s: no device answered ({what}); {advice}; ending the run (exit {})",
                crate::exit::NOTHING_CONNECTED
            );
            self.stop = Some(StopReason::NothingConnected);
        }
    }

    /// What the pipeline takes from pose values (the sink counts them): the highest pose, the
    /// latency when `timed` (not when their triggers waited for the NC clock fit to settle,
    /// docs/design.md), and the values themselves when kept.
    fn on_poses(&mut self, poses: Vec<PoseMsg>, timed: bool) {
        if poses.is_empty() {
            return;
        }
        self.tell_poses(&poses);
        let now = self.clock.now_ns();
        for v in poses {
            if v.n > 0 && timed {
                let latency_ms = now.saturating_sub(v.t_last_ns) as f64 / 1e6;
                if latency_ms > self.status.pose_latency_max_ms {
                    self.status.pose_latency_max_ms = latency_ms;
                }
            }
            self.status.last_pose = self.status.last_pose.max(v.pose);
            let before = self.slot(v.instrument).last_pose_status.replace(v.status);
            tell_alarm(v.instrument, v.pose, before, v.status);
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

    /// One INFO line per pose finished in this batch (README, "Reading the run on the
    /// terminal").
    fn tell_poses(&self, poses: &[PoseMsg]) {
        let mut done: Vec<u32> = poses.iter().map(|v| v.pose).collect();
        done.sort_unstable();
        done.dedup();
        for k in done {
            let line = super::progress::pose_line(k, &self.cfg.trajectory, poses);
            tracing::info!("{line}");
        }
    }

    /// The status now, with the sink's counts.
    fn snapshot(&mut self, queue_len: usize, counts: &RunCounts) -> Status {
        self.status.t_ns = self.clock.now_ns();
        self.status.uptime_s = self.started.elapsed().as_secs_f64();
        self.status.queue_len = queue_len;
        self.status.queue_max = self.status.queue_max.max(queue_len);
        if let Some(a) = &self.cfg.disk_alarm {
            self.status.low_disk = a.lock().ok().and_then(|a| a.clone());
        }
        let mut st = self.status.clone();
        st.poses = counts.poses_total();
        st.poses_ok = counts.poses_ok();
        for (i, c) in &counts.drivers {
            st.instruments.entry(*i).or_default().driver = c.clone();
        }
        for (i, p) in &counts.poses {
            st.instruments.entry(*i).or_default().poses = p.clone();
        }
        st
    }

    /// The watchdog facts now (see [`crate::acquire::service`]).
    fn watchdog(&self, interval: Duration) -> Watchdog {
        Watchdog {
            since_loop_s: 0.0,
            since_sample_s: self
                .last_sample_ns
                .map(|t| self.clock.now_ns().saturating_sub(t) as f64 / 1e9),
            uptime_s: self.started.elapsed().as_secs_f64(),
            connected: self
                .status
                .instruments
                .values()
                .filter(|s| s.connected)
                .count(),
            program_idle: self.status.program == ProgramState::Ended,
            interval_s: interval.as_secs_f64(),
        }
    }
}

impl Pipeline {
    pub fn new(cfg: PipelineConfig, clock: HostClock, sink: Box<dyn EventSink>) -> Pipeline {
        let trajectory_len = cfg.trajectory.len();
        let instruments = cfg
            .instruments
            .iter()
            .map(|&i| (i, InstrumentStatus::default()))
            .collect();
        Pipeline {
            sink,
            state: RunState {
                cfg,
                clock,
                status: Status {
                    instruments,
                    trajectory_len,
                    queue_capacity: QUEUE_CAPACITY,
                    ..Status::default()
                },
                started: Instant::now(),
                last_sample_ns: None,
                program_end_ns: None,
                nothing_since: Some(Instant::now()),
                poses: Vec::new(),
                stop: None,
            },
        }
    }

    /// Handle one driver event.
    pub fn handle(&mut self, ev: DriverEvent) {
        let now = self.state.clock.now_ns();
        self.handle_at(ev, now);
    }

    /// Handle one driver event of a batch taken from the queue at `now` (ns): the clock is
    /// read once per batch, not per sample (docs/design.md, "Where the daemon's CPU goes").
    fn handle_at(&mut self, ev: DriverEvent, now: u64) {
        let timed = self.sink.placing_at_once();
        let r = self.sink.record(&ev, now);
        let poses = self.state.sink_result(r);
        self.state.on_event(ev, now);
        self.state.on_poses(poses, timed);
    }

    /// Snapshot the status.
    pub fn status(&mut self, queue_len: usize) -> Status {
        self.state.snapshot(queue_len, self.sink.counts())
    }

    /// Pose values the sink has counted so far.
    fn poses_counted(&self) -> u64 {
        self.sink.counts().poses_total()
    }

    /// The once-a-second work: the sink's status record and flush.
    fn tick(&mut self, queue_len: usize) -> Status {
        self.state.check_connected(Instant::now());
        let now = self.state.clock.now_ns();
        let r = self.sink.tick(now);
        self.state.sink_result(r);
        self.status(queue_len)
    }

    /// Close every open dwell, write the final status and close the log.
    pub fn finish(self, reason: StopReason, queue_len: usize) -> anyhow::Result<Outcome> {
        let Pipeline { sink, mut state } = self;
        let now = state.clock.now_ns();
        let mut reason = reason;
        let timed = sink.placing_at_once();
        // The counts as they stand, should the sink fail to close.
        let before = sink.counts().clone();
        let counts = match sink.finish(now) {
            Ok(closed) => {
                state.on_poses(closed.poses, timed);
                closed.counts
            }
            // The file could not be closed (its footer not written): what was written before
            // stays readable, as after a kill (the reader reads the intact prefix).
            Err(e) => {
                tracing::error!("the log could not be closed cleanly: {e:#}");
                state.status.log_errors += 1;
                if state.status.log_failed.is_none() {
                    state.status.log_failed = Some(format!("{e:#}"));
                }
                reason = StopReason::LogFailed;
                before
            }
        };
        let status = state.snapshot(queue_len, &counts);
        Ok(Outcome {
            reason,
            status,
            poses: state.poses,
        })
    }

    /// Handles `first` (if any) and what is queued now, up to 4096 events, all with one clock
    /// read; notes the queue's high-water mark.
    fn take_batch(&mut self, rx: &mut mpsc::Receiver<DriverEvent>, first: Option<DriverEvent>) {
        let now = self.state.clock.now_ns();
        if let Some(ev) = first {
            self.handle_at(ev, now);
        }
        let mut budget = rx.len().min(4096);
        while budget > 0 && self.state.stop.is_none() {
            match rx.try_recv() {
                Ok(ev) => self.handle_at(ev, now),
                Err(_) => break,
            }
            budget -= 1;
        }
        self.state.status.queue_max = self.state.status.queue_max.max(rx.len());
    }

    /// Publishes the status on `progress` when pose values were written since the last time.
    fn publish_poses(
        &mut self,
        published: &mut u64,
        progress: &watch::Sender<Status>,
        queue: usize,
    ) {
        if self.poses_counted() != *published {
            *published = self.poses_counted();
            progress.send_replace(self.status(queue));
        }
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
            // While the readers coalesce their reads, the queue is taken just after their
            // tick, so one wake-up takes what all of them sent; otherwise at every event.
            let coalesced = !drivers::read_coalesce().is_zero();
            let batch_at = drivers::next_read_tick() + BATCH_AFTER_TICK;
            tokio::select! {
                biased;
                _ = cancel.cancelled() => break StopReason::Cancelled,
                _ = tick.tick() => {
                    let st = self.tick(rx.len());
                    notifier.status(&st.summary());
                    if let Some(iv) = watchdog_interval {
                        if self.state.watchdog(iv).healthy() {
                            notifier.watchdog();
                        } else {
                            tracing::warn!(
                                "no samples for {:.0} s from connected instruments while a program runs; not petting the watchdog",
                                crate::acquire::service::STALL_TIMEOUT_S
                            );
                        }
                    }
                    progress.send_replace(st);
                    if let Some(r) = self.state.stop.clone() {
                        break r;
                    }
                }
                ev = rx.recv(), if !coalesced => {
                    let Some(ev) = ev else { break StopReason::DriversGone };
                    self.take_batch(&mut rx, Some(ev));
                    self.publish_poses(&mut poses_published, &progress, rx.len());
                    if let Some(r) = self.state.stop.clone() {
                        break r;
                    }
                }
                _ = batch_due(batch_at), if coalesced => {
                    if rx.is_closed() && rx.is_empty() {
                        break StopReason::DriversGone;
                    }
                    self.take_batch(&mut rx, None);
                    self.publish_poses(&mut poses_published, &progress, rx.len());
                    if let Some(r) = self.state.stop.clone() {
                        break r;
                    }
                }
            }
        };
        if reason == StopReason::ProgramEnd {
            self.catch_up_readers(&mut rx).await;
        }
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

/// When the pipeline takes the queue while the readers coalesce: just after their tick, or
/// when a read of the tick ended after that take (its samples would otherwise wait a period).
async fn batch_due(at: tokio::time::Instant) {
    tokio::select! {
        _ = tokio::time::sleep_until(at) => {}
        _ = drivers::late_reads().notified() => {}
    }
}

impl Pipeline {
    /// The program-end trigger is not coalesced, the streaming readers deliver on their tick:
    /// the last dwell's samples may still be on their way when it stops the run. Takes events
    /// until every connected streaming instrument has delivered a sample from after the program
    /// end, for at most [`CATCH_UP_LIMIT`] (an instrument that went silent).
    async fn catch_up_readers(&mut self, rx: &mut mpsc::Receiver<DriverEvent>) {
        let Some(end_ns) = self.state.program_end_ns else {
            return;
        };
        let mut behind: Vec<Instrument> = [
            Instrument::Interferometer,
            Instrument::Capball,
            Instrument::Psd,
        ]
        .into_iter()
        .filter(|i| {
            self.state
                .status
                .instruments
                .get(i)
                .is_some_and(|s| s.connected)
        })
        .collect();
        let deadline = tokio::time::Instant::now() + CATCH_UP_LIMIT;
        while !behind.is_empty() {
            let Ok(Some(ev)) = tokio::time::timeout_at(deadline, rx.recv()).await else {
                break;
            };
            if let DriverEvent::Sample(s) = &ev
                && s.host_ns >= end_ns
            {
                behind.retain(|i| *i != s.instrument);
            }
            self.handle(ev);
        }
    }
}

/// A WARN line when a pose value starts an alarm on its instrument (beam lost, datum lost),
/// an INFO line when the alarm is over.
fn tell_alarm(
    instrument: Instrument,
    pose: u32,
    before: Option<types::PoseStatus>,
    now: types::PoseStatus,
) {
    use super::progress::alarm_of;
    let (was, is) = (before.and_then(alarm_of), alarm_of(now));
    if was == is {
        return;
    }
    let name = instrument.name();
    match (was, is) {
        (_, Some(a)) => tracing::warn!("{name}: {a} at pose {pose}"),
        (Some(a), None) => tracing::info!("{name}: {a} is over at pose {pose}"),
        (None, None) => {}
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

#[cfg(test)]
mod tests {
    //! The Status bookkeeping on plain driver events, through a scripted sink (no pose engine,
    //! no log, no clock waits): what each event changes, where the counts come from, how a
    //! failing log stops the run.

    use std::collections::VecDeque;

    use drivers::{Counters, DriverError, Sample, SampleValues, Trigger};
    use types::PoseStatus;

    use super::*;
    use crate::acquire::sink::Closed;

    /// Returns the pose values it was given, one batch per recorded event, and counts them and
    /// the counters as every sink does; fails writes when told to.
    #[derive(Default)]
    struct Scripted {
        batches: VecDeque<Vec<PoseMsg>>,
        at_finish: Vec<PoseMsg>,
        counts: RunCounts,
        fail_writes: bool,
        fail_finish: bool,
        placing_at_once: bool,
    }

    impl EventSink for Scripted {
        fn record(&mut self, ev: &DriverEvent, _now_ns: u64) -> anyhow::Result<Vec<PoseMsg>> {
            if self.fail_writes {
                anyhow::bail!("no space left on device");
            }
            self.counts.on_event(ev);
            let poses = self.batches.pop_front().unwrap_or_default();
            poses.iter().for_each(|p| self.counts.on_pose(p));
            Ok(poses)
        }
        fn tick(&mut self, _now_ns: u64) -> anyhow::Result<()> {
            Ok(())
        }
        fn finish(mut self: Box<Self>, _now_ns: u64) -> anyhow::Result<Closed> {
            if self.fail_finish {
                anyhow::bail!("cannot write the footer");
            }
            let poses = std::mem::take(&mut self.at_finish);
            poses.iter().for_each(|p| self.counts.on_pose(p));
            Ok(Closed {
                poses,
                counts: self.counts,
            })
        }
        fn counts(&self) -> &RunCounts {
            &self.counts
        }
        fn placing_at_once(&self) -> bool {
            self.placing_at_once
        }
    }

    fn pipeline(sink: Scripted, stop_at_program_end: bool) -> Pipeline {
        Pipeline::new(
            PipelineConfig {
                instruments: vec![Instrument::Interferometer, Instrument::Trigger],
                stop_at_program_end,
                keep_poses: true,
                connect: None,
                disk_alarm: None,
                trajectory: Vec::new(),
                datum: None,
            },
            HostClock::new(),
            Box::new(sink),
        )
    }

    fn sample(instrument: Instrument, seq: u64) -> DriverEvent {
        DriverEvent::Sample(Sample {
            instrument,
            seq,
            device_t_us: seq,
            host_ns: seq * 1000,
            fitted_ns: seq * 1000,
            valid: true,
            values: SampleValues::Position {
                raw_nm: 0,
                position_um: 0.0,
                sig: 90,
                flags: 0,
            },
        })
    }

    fn trigger(event: TriggerEvent, pose: u16) -> DriverEvent {
        DriverEvent::Trigger(Trigger {
            event,
            pose,
            nc_ms: 0,
            host_ns: 0,
        })
    }

    fn pose(instrument: Instrument, pose: u32, status: PoseStatus, n: u64) -> PoseMsg {
        PoseMsg {
            instrument,
            pose,
            status,
            n,
            mean: BTreeMap::new(),
            std: BTreeMap::new(),
            t_first_ns: 0,
            t_last_ns: 0,
            datum_epoch: 0,
        }
    }

    fn silent() -> DriverError {
        DriverError::Silent {
            idle: Duration::from_secs(2),
        }
    }

    #[test]
    fn configured_instruments_start_disconnected_and_unknown() {
        let mut p = pipeline(Scripted::default(), false);
        let st = p.status(7);
        assert_eq!(
            st.instruments.keys().copied().collect::<Vec<_>>(),
            vec![Instrument::Interferometer, Instrument::Trigger]
        );
        assert!(st.instruments.values().all(|s| !s.connected));
        assert_eq!(st.program, ProgramState::Unknown);
        assert_eq!((st.queue_len, st.queue_max), (7, 7));
        assert_eq!(st.queue_capacity, QUEUE_CAPACITY);
        assert_eq!(p.status(2).queue_max, 7);
        assert_eq!(
            st.summary(),
            "no pose yet, ok, faults 0; poses 0 (0 ok), samples 0, stream defects 0, lost 0, connected: none"
        );
    }

    #[test]
    fn connections_and_errors_are_kept_per_instrument() {
        let mut p = pipeline(Scripted::default(), false);
        p.handle(DriverEvent::Connected {
            instrument: Instrument::Interferometer,
            port: "/dev/li80".into(),
            identity: "LI-80,SN1".into(),
        });
        p.handle(DriverEvent::Connected {
            instrument: Instrument::Psd,
            port: "/dev/psd".into(),
            identity: "PSD-2".into(),
        });
        let st = p.status(0);
        let li = &st.instruments[&Instrument::Interferometer];
        assert!(li.connected);
        assert_eq!(
            (li.port.as_str(), li.identity.as_str()),
            ("/dev/li80", "LI-80,SN1")
        );
        // An instrument that was not configured but speaks gets a place.
        assert!(st.instruments[&Instrument::Psd].connected);
        assert!(st.summary().ends_with("connected: interferometer psd"));

        p.handle(DriverEvent::Disconnected {
            instrument: Instrument::Interferometer,
            port: "/dev/li80-b".into(),
            reason: DriverError::EndOfFile,
        });
        p.handle(DriverEvent::Error {
            instrument: Instrument::Interferometer,
            port: "/dev/li80-b".into(),
            error: silent(),
        });
        let st = p.status(0);
        let li = &st.instruments[&Instrument::Interferometer];
        assert!(!li.connected);
        assert_eq!(li.port, "/dev/li80-b");
        // The identity of the last connection stays.
        assert_eq!(li.identity, "LI-80,SN1");
        assert_eq!(
            li.last_error.as_deref(),
            Some("no data for 2.0 s while streaming")
        );
        assert!(st.summary().ends_with("connected: psd"));
    }

    #[test]
    fn the_status_line_leads_with_pose_k_of_n_and_the_alarms() {
        let sink = Scripted {
            // One batch per event: the connect and disconnect finish no pose.
            batches: VecDeque::from([
                vec![],
                vec![],
                vec![pose(
                    Instrument::Interferometer,
                    2,
                    PoseStatus::DatumLost,
                    150,
                )],
                vec![pose(Instrument::Interferometer, 3, PoseStatus::Ok, 150)],
            ]),
            ..Scripted::default()
        };
        let mut p = pipeline(sink, false);
        p.state.status.trajectory_len = 129;
        p.handle(DriverEvent::Connected {
            instrument: Instrument::Psd,
            port: "/dev/psd".into(),
            identity: "PSD-2".into(),
        });
        assert!(
            p.status(0)
                .summary()
                .starts_with("no pose yet, ok, faults 0; ")
        );
        p.handle(DriverEvent::Disconnected {
            instrument: Instrument::Psd,
            port: "/dev/psd".into(),
            reason: DriverError::EndOfFile,
        });
        p.handle(sample(Instrument::Interferometer, 0));
        let line = p.status(0).summary();
        assert!(
            line.starts_with("pose 2/129, interferometer datum lost, psd unplugged, faults 0; "),
            "{line}"
        );
        // A good value ends the interferometer's alarm; the PSD stays unplugged.
        p.handle(sample(Instrument::Interferometer, 1));
        let line = p.status(0).summary();
        assert!(
            line.starts_with("pose 3/129, psd unplugged, faults 0; "),
            "{line}"
        );
    }

    fn with_policy(wait: bool) -> Pipeline {
        let mut p = pipeline(Scripted::default(), false);
        p.state.cfg.connect = Some(ConnectPolicy {
            timeout: Duration::from_secs(60),
            wait,
            ports: vec![(Instrument::Interferometer, "/dev/li80".into())],
        });
        p
    }

    #[test]
    fn nothing_connected_raises_the_alarm_after_the_timeout_and_stops_unless_waiting() {
        let t0 = Instant::now();
        let mut p = with_policy(false);
        // Not yet: the time is the pipeline's start plus 59 s at most.
        p.state.check_connected(t0);
        assert!(p.state.status.nothing_connected.is_none() && p.state.stop.is_none());
        p.state.check_connected(t0 + Duration::from_secs(61));
        let alarm = p.status(0).nothing_connected.clone().unwrap();
        assert!(alarm.contains("interferometer on /dev/li80"), "{alarm}");
        assert!(p.status(0).summary().starts_with("NOTHING CONNECTED for 6"));
        assert_eq!(p.state.stop, Some(StopReason::NothingConnected));

        // hotplug: the same alarm, and the run goes on; a connection ends it.
        let mut p = with_policy(true);
        p.state.check_connected(t0 + Duration::from_secs(61));
        assert!(p.state.status.nothing_connected.is_some());
        assert_eq!(p.state.stop, None);
        p.handle(DriverEvent::Connected {
            instrument: Instrument::Interferometer,
            port: "/dev/li80".into(),
            identity: "LI-80".into(),
        });
        assert!(p.status(0).nothing_connected.is_none());
        p.state.check_connected(t0 + Duration::from_secs(600));
        assert!(p.state.status.nothing_connected.is_none());
    }

    #[test]
    fn the_low_disk_alarm_shows_in_the_status_line_while_it_holds() {
        let mut p = pipeline(Scripted::default(), false);
        let alarm = super::super::storage::DiskAlarm::default();
        p.state.cfg.disk_alarm = Some(alarm.clone());
        assert!(p.status(0).summary().starts_with("no pose yet, ok"));
        *alarm.lock().unwrap() = Some("1.23 GB free".into());
        assert!(
            p.status(0)
                .summary()
                .starts_with("LOW DISK 1.23 GB free; no pose yet"),
            "{}",
            p.status(0).summary()
        );
        *alarm.lock().unwrap() = None;
        assert!(p.status(0).low_disk.is_none());
    }

    #[test]
    fn the_timeout_counts_from_the_last_device_gone() {
        let mut p = with_policy(false);
        p.handle(DriverEvent::Connected {
            instrument: Instrument::Interferometer,
            port: "/dev/li80".into(),
            identity: "LI-80".into(),
        });
        p.handle(DriverEvent::Disconnected {
            instrument: Instrument::Interferometer,
            port: "/dev/li80".into(),
            reason: DriverError::EndOfFile,
        });
        let gone = p.state.nothing_since.unwrap();
        p.state.check_connected(gone + Duration::from_secs(59));
        assert_eq!(p.state.stop, None);
        p.state.check_connected(gone + Duration::from_secs(60));
        assert_eq!(p.state.stop, Some(StopReason::NothingConnected));
    }

    #[test]
    fn samples_and_triggers_are_counted_as_received() {
        let mut p = pipeline(Scripted::default(), false);
        for k in 0..5 {
            p.handle(sample(Instrument::Interferometer, k));
        }
        p.handle(sample(Instrument::Capball, 0));
        p.handle(trigger(TriggerEvent::ExactStop, 3));
        let st = p.status(0);
        assert_eq!(st.instruments[&Instrument::Interferometer].received, 5);
        assert_eq!(st.instruments[&Instrument::Capball].received, 1);
        assert_eq!(st.instruments[&Instrument::Trigger].received, 1);
        // Triggers are not samples.
        assert_eq!(st.samples(), 6);
        assert_eq!(st.last_pose, 3);
    }

    #[test]
    fn the_program_state_follows_the_triggers() {
        let mut p = pipeline(Scripted::default(), false);
        let mut seen = Vec::new();
        for ev in [
            TriggerEvent::ProgramStart,
            TriggerEvent::FeedHold,
            TriggerEvent::MotionStart,
            TriggerEvent::ProgramEnd,
            TriggerEvent::ExactStop,
        ] {
            p.handle(trigger(ev, 1));
            seen.push(p.status(0).program);
        }
        assert_eq!(
            seen,
            vec![
                ProgramState::Running,
                ProgramState::Held,
                ProgramState::Running,
                ProgramState::Ended,
                ProgramState::Running,
            ]
        );
        // Not configured to stop at program end: the run goes on.
        let out = p.finish(StopReason::Cancelled, 0).unwrap();
        assert_eq!(out.reason, StopReason::Cancelled);
    }

    #[test]
    fn program_end_stops_the_run_only_when_configured() {
        for stop in [false, true] {
            let mut p = pipeline(Scripted::default(), stop);
            p.handle(trigger(TriggerEvent::ProgramStart, 0));
            assert_eq!(p.state.stop, None);
            p.handle(trigger(TriggerEvent::ProgramEnd, 0));
            let want = stop.then_some(StopReason::ProgramEnd);
            assert_eq!(p.state.stop, want, "stop_at_program_end = {stop}");
        }
    }

    #[test]
    fn driver_counters_come_from_the_sink_latest_snapshot_wins() {
        let mut p = pipeline(Scripted::default(), false);
        let mut c = Counters {
            gaps: 2,
            gap_samples: 5,
            resyncs: 1,
            disconnects: 1,
            dropped: 3,
            device_errors: 1,
            ..Counters::default()
        };
        c.rejections.insert(protocol::RejectKind::BadChecksum, 4);
        p.handle(DriverEvent::Counters {
            instrument: Instrument::Psd,
            counters: Counters {
                gaps: 100,
                ..Counters::default()
            },
        });
        p.handle(DriverEvent::Counters {
            instrument: Instrument::Psd,
            counters: c.clone(),
        });
        let st = p.status(0);
        assert_eq!(st.instruments[&Instrument::Psd].driver.gaps, 2);
        // gaps + rejections + resyncs + disconnects + dropped + device errors
        assert_eq!(
            st.instruments[&Instrument::Psd].faults(),
            2 + 4 + 1 + 1 + 3 + 1
        );
        assert_eq!(st.faults(), 12);
        // The page's "Faults": device errors and disconnects only.
        assert_eq!(st.device_faults(), 2);
        assert!(st.summary().contains("faults 2; "), "{}", st.summary());
        assert!(
            st.summary().contains("stream defects 12, "),
            "{}",
            st.summary()
        );
        // dropped + samples missing in gaps
        assert_eq!(st.lost(), 8);
        // The status holds what the sink counted, no count of its own.
        assert_eq!(p.sink.counts().drivers[&Instrument::Psd].gaps, 2);
    }

    #[test]
    fn pose_values_are_counted_once_by_the_sink() {
        let sink = Scripted {
            batches: VecDeque::from([
                vec![
                    pose(Instrument::Interferometer, 1, PoseStatus::Ok, 150),
                    pose(Instrument::Capball, 1, PoseStatus::DeviceAway, 0),
                ],
                vec![],
                vec![pose(Instrument::Interferometer, 4, PoseStatus::Ok, 150)],
            ]),
            at_finish: vec![pose(
                Instrument::Interferometer,
                5,
                PoseStatus::NeverSteady,
                150,
            )],
            ..Scripted::default()
        };
        let mut p = pipeline(sink, false);
        for k in 0..3 {
            p.handle(sample(Instrument::Interferometer, k));
        }
        let st = p.status(0);
        assert_eq!((st.poses, st.poses_ok), (3, 2));
        assert_eq!(st.last_pose, 4);
        assert_eq!(
            st.instruments[&Instrument::Interferometer].poses.get("ok"),
            Some(&2)
        );
        // Not configured, but it has pose values: it has a place in the status.
        assert_eq!(
            st.instruments[&Instrument::Capball]
                .poses
                .get("device_away"),
            Some(&1)
        );
        assert_eq!(
            st.summary(),
            "pose 4, ok, faults 0; poses 3 (2 ok), samples 3, stream defects 0, lost 0, connected: none"
        );

        // The dwells closed at the end count too, and every value is kept.
        let out = p.finish(StopReason::Cancelled, 0).unwrap();
        assert_eq!((out.status.poses, out.status.poses_ok), (4, 2));
        assert_eq!(out.status.last_pose, 5);
        assert_eq!(
            out.status.instruments[&Instrument::Interferometer]
                .poses
                .get(PoseStatus::NeverSteady.name()),
            Some(&1)
        );
        assert_eq!(
            out.poses.iter().map(|v| v.pose).collect::<Vec<_>>(),
            vec![1, 1, 4, 5]
        );
    }

    #[test]
    fn pose_latency_leaves_out_empty_values_and_triggers_that_waited() {
        // A pose value whose last sample is at the epoch: its latency is the whole clock.
        for (placing_at_once, n, counted) in
            [(true, 150, true), (true, 0, false), (false, 150, false)]
        {
            let sink = Scripted {
                batches: VecDeque::from([vec![pose(Instrument::Psd, 1, PoseStatus::Ok, n)]]),
                placing_at_once,
                ..Scripted::default()
            };
            let mut p = pipeline(sink, false);
            p.handle(sample(Instrument::Psd, 0));
            let latency = p.status(0).pose_latency_max_ms;
            assert_eq!(
                latency > 0.0,
                counted,
                "placing at once {placing_at_once}, n {n}: {latency} ms"
            );
        }
    }

    #[test]
    fn a_failed_write_stops_the_run_and_says_why() {
        let sink = Scripted {
            fail_writes: true,
            ..Scripted::default()
        };
        let mut p = pipeline(sink, false);
        p.handle(sample(Instrument::Interferometer, 0));
        p.handle(sample(Instrument::Interferometer, 1));
        assert_eq!(p.state.stop, Some(StopReason::LogFailed));
        let st = p.status(0);
        assert_eq!(st.log_errors, 2);
        assert_eq!(st.log_failed.as_deref(), Some("no space left on device"));
        // What arrived is still counted as received.
        assert_eq!(st.instruments[&Instrument::Interferometer].received, 2);
        assert!(
            st.summary().starts_with(
                "LOG WRITE FAILED, run stopped (no space left on device); no pose yet"
            ),
            "{}",
            st.summary()
        );
    }

    #[test]
    fn a_log_that_cannot_be_closed_ends_the_run_as_failed_with_its_counts() {
        let sink = Scripted {
            batches: VecDeque::from([vec![pose(
                Instrument::Interferometer,
                1,
                PoseStatus::Ok,
                150,
            )]]),
            fail_finish: true,
            ..Scripted::default()
        };
        let mut p = pipeline(sink, false);
        p.handle(sample(Instrument::Interferometer, 0));
        let out = p.finish(StopReason::Cancelled, 0).unwrap();
        assert_eq!(out.reason, StopReason::LogFailed);
        assert_eq!(out.status.log_errors, 1);
        assert_eq!(
            out.status.log_failed.as_deref(),
            Some("cannot write the footer")
        );
        assert_eq!((out.status.poses, out.status.poses_ok), (1, 1));
    }

    /// The datum commands the triggers give the LI-80 driver: a first trigger that is not the
    /// program start loses the datum; the exact stop of a reference pose asks for `DATUM`
    /// after the settle time, every motion start cancels one waiting; nothing else.
    #[test]
    fn triggers_steer_the_interferometer_datum() {
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let d = DatumControl {
            commands: tx,
            reference_poses: vec![7],
            settle: Duration::from_millis(200),
        };
        let trig = |event, pose| Trigger {
            event,
            pose,
            nc_ms: 0,
            host_ns: 0,
        };
        let mut got = |t: Trigger, first: bool| {
            d.on_trigger(&t, first);
            rx.try_recv().ok()
        };
        assert_eq!(got(trig(TriggerEvent::ProgramStart, 0), true), None);
        assert_eq!(got(trig(TriggerEvent::ExactStop, 6), false), None);
        assert_eq!(got(trig(TriggerEvent::DwellEnd, 7), false), None);
        assert_eq!(
            got(trig(TriggerEvent::ExactStop, 7), false),
            Some(drivers::Li80Command::Reference {
                pose: 7,
                settle: Duration::from_millis(200)
            })
        );
        assert_eq!(
            got(trig(TriggerEvent::MotionStart, 8), false),
            Some(drivers::Li80Command::Moving)
        );
        match got(trig(TriggerEvent::DwellEnd, 5), true) {
            Some(drivers::Li80Command::LoseDatum { reason }) => {
                assert!(reason.contains("started mid-program"), "{reason}")
            }
            other => panic!("{other:?}"),
        }
    }
}
