//! The run's log fed with driver events, in one direction: each event is written to its raw
//! topic, then handed to the [`PoseEngine`] (the detectors), and the pose values it completes
//! are written to `/pose`; connections go to `/event`, counters to `/status` once a second.
//! The recorder keeps the run's one [`RunCounts`] (driver counters, pose values by status).

use std::collections::BTreeMap;

use drivers::DriverEvent;
use metrolog_log::topics::{EventKind, EventMsg, PoseMsg, StatusMsg};
use metrolog_log::{
    DetectorSettings, INSTRUMENT_METADATA, LogError, LogOptions, LogWriter, RunMetadata,
};

use detect::PoseEngine;

use super::counts::RunCounts;

/// The log of a run fed with driver events: raw topics, `/pose` from the [`PoseEngine`],
/// `/event`, and `/status` once a second.
pub struct Recorder {
    writer: LogWriter,
    engine: PoseEngine,
    counts: RunCounts,
    last_status_ns: Option<u64>,
    last_ns: u64,
    /// The `now_ns` of the last flush check: the pipeline hands a batch of events one `now`,
    /// and the writer's flush check reads the clock, so it is made once per batch.
    flush_checked_ns: u64,
}

/// The `/event` text of a datum change (docs/log-format.md): `epoch <k> lost: …` or
/// `epoch <k> referenced at pose <p>: …`.
pub fn datum_text(c: &drivers::DatumChange) -> String {
    match (c.referenced, c.pose) {
        (true, Some(p)) => format!("epoch {} referenced at pose {p}: {}", c.epoch, c.text),
        (true, None) => format!("epoch {} referenced: {}", c.epoch, c.text),
        (false, _) => format!("epoch {} lost: {}", c.epoch, c.text),
    }
}

/// Interval of `/status` records, ns.
pub const STATUS_INTERVAL_NS: u64 = 1_000_000_000;

impl Recorder {
    /// A new log file in `dir` (see [`LogWriter::create_in_dir`]) whose detectors use
    /// `meta.detector` — the settings stored in the log, so replay uses the same.
    pub fn create_in_dir(
        dir: &std::path::Path,
        meta: &RunMetadata,
        opts: LogOptions,
    ) -> Result<Recorder, LogError> {
        let settings = meta.detector.clone();
        Recorder::new(LogWriter::create_in_dir(dir, meta, opts)?, &settings)
    }

    /// Like [`Recorder::create_in_dir`], at an explicit path (which must not exist).
    pub fn create(
        path: &std::path::Path,
        meta: &RunMetadata,
        opts: LogOptions,
    ) -> Result<Recorder, LogError> {
        let settings = meta.detector.clone();
        Recorder::new(LogWriter::create(path, meta, opts)?, &settings)
    }

    /// Around an open writer; `settings` must be the `detector` of the writer's
    /// [`RunMetadata`](RunMetadata), or replay will not reproduce the pose values.
    pub fn new(writer: LogWriter, settings: &DetectorSettings) -> Result<Recorder, LogError> {
        Ok(Recorder {
            writer,
            engine: PoseEngine::new(settings)?,
            counts: RunCounts::default(),
            last_status_ns: None,
            last_ns: 0,
            flush_checked_ns: 0,
        })
    }

    pub fn writer(&mut self) -> &mut LogWriter {
        &mut self.writer
    }

    /// The part of a split run being written (1 for a run that is not split).
    pub fn part(&self) -> u32 {
        self.writer.part()
    }

    /// The file being written (the current part of a split run).
    pub fn log_path(&self) -> &std::path::Path {
        self.writer.path()
    }

    /// The run's counts so far (what `/status` holds).
    pub fn counts(&self) -> &RunCounts {
        &self.counts
    }

    /// Whether its pose engine places triggers as they come ([`PoseEngine::placing_at_once`]).
    pub fn placing_at_once(&self) -> bool {
        self.engine.placing_at_once()
    }

    /// Writes one driver event (and the pose values it completes); returns those pose values.
    /// `now_ns` is the host clock (`HostClock::now_ns`), used for the log time of events that
    /// carry none and for the `/status` cadence.
    pub fn record(&mut self, ev: &DriverEvent, now_ns: u64) -> Result<Vec<PoseMsg>, LogError> {
        self.last_ns = self.last_ns.max(now_ns);
        self.counts.on_event(ev);
        let poses = match ev {
            DriverEvent::Sample(s) => {
                self.writer.write_sample(s)?;
                let p = self.engine.on_sample(s);
                self.write_poses(s.host_ns, &p)?;
                p
            }
            DriverEvent::Trigger(t) => {
                self.writer.write_trigger(t)?;
                let p = self.engine.on_trigger(t);
                self.write_poses(t.host_ns, &p)?;
                p
            }
            DriverEvent::Counters { .. } => Vec::new(),
            DriverEvent::Datum {
                instrument,
                port,
                change,
            } => {
                let msg = EventMsg {
                    instrument: instrument.name().into(),
                    kind: EventKind::Datum,
                    port: port.clone(),
                    text: datum_text(change),
                };
                self.writer.write(now_ns, &msg)?;
                Vec::new()
            }
            DriverEvent::Connected {
                instrument,
                port,
                identity,
            } => {
                let msg = EventMsg {
                    instrument: instrument.name().into(),
                    kind: EventKind::Connected,
                    port: port.clone(),
                    text: identity.clone(),
                };
                self.writer.write(now_ns, &msg)?;
                let map = BTreeMap::from([
                    ("instrument".to_string(), instrument.name().to_string()),
                    ("port".to_string(), port.clone()),
                    ("identity".to_string(), identity.clone()),
                    ("time_ns".to_string(), now_ns.to_string()),
                ]);
                self.writer.write_metadata(INSTRUMENT_METADATA, map)?;
                Vec::new()
            }
            DriverEvent::Disconnected {
                instrument,
                port,
                reason,
            } => {
                let msg = EventMsg {
                    instrument: instrument.name().into(),
                    kind: EventKind::Disconnected,
                    port: port.clone(),
                    text: reason.to_string(),
                };
                self.writer.write(now_ns, &msg)?;
                Vec::new()
            }
            DriverEvent::Error {
                instrument,
                port,
                error,
            } => {
                let msg = EventMsg {
                    instrument: instrument.name().into(),
                    kind: EventKind::Error,
                    port: port.clone(),
                    text: error.to_string(),
                };
                self.writer.write(now_ns, &msg)?;
                Vec::new()
            }
        };
        self.tick(now_ns)?;
        Ok(poses)
    }

    fn write_poses(&mut self, log_ns: u64, poses: &[PoseMsg]) -> Result<(), LogError> {
        for p in poses {
            self.counts.on_pose(p);
            self.writer.write_pose(log_ns, p)?;
        }
        Ok(())
    }

    /// The `/status` message as it stands.
    pub fn status(&self) -> StatusMsg {
        self.counts.status_msg(self.writer.messages())
    }

    /// Writes `/status` when a second has passed and flushes when due. Call at least once a
    /// second (a timer), so a quiet period still reaches the disk.
    pub fn tick(&mut self, now_ns: u64) -> Result<(), LogError> {
        let due = self
            .last_status_ns
            .is_none_or(|t| now_ns >= t + STATUS_INTERVAL_NS);
        if due {
            self.last_status_ns = Some(now_ns);
            let st = self.status();
            self.writer.write_status(now_ns, &st)?;
        }
        if now_ns != self.flush_checked_ns {
            self.flush_checked_ns = now_ns;
            self.writer.flush_if_due()?;
        }
        Ok(())
    }

    /// Ends the run: closes open dwells (their pose values are returned), writes a last
    /// `/status`, closes the file cleanly and returns its path.
    pub fn finish(self, now_ns: u64) -> Result<(std::path::PathBuf, Vec<PoseMsg>), LogError> {
        let (path, poses, _) = self.finish_counted(now_ns)?;
        Ok((path, poses))
    }

    /// [`Recorder::finish`], with the run's final counts.
    pub fn finish_counted(
        mut self,
        now_ns: u64,
    ) -> Result<(std::path::PathBuf, Vec<PoseMsg>, RunCounts), LogError> {
        let p = self.engine.finish(now_ns);
        self.write_poses(now_ns, &p)?;
        let st = self.status();
        self.writer.write_status(now_ns, &st)?;
        Ok((self.writer.finish()?, p, self.counts))
    }
}
