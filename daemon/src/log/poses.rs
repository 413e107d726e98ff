//! From samples and triggers to `/pose` records — the same code live and in replay.
//!
//! [`PoseEngine`] holds one [`SteadyDetector`] per instrument. It is fed every sample and
//! trigger in the order they are written to the log; replay reads the log in file order and
//! feeds the very same calls, so it reproduces the logged pose values bit for bit (JSON
//! numbers are written in shortest round-trip form, so every `f64` reads back exactly).
//!
//! Time axis: samples enter the detector at their clock-fitted time (`Sample::fitted_ns`, the
//! device clock mapped onto the host axis), triggers at their host arrival time — the one
//! axis all instruments and triggers share.

use std::collections::BTreeMap;

use drivers::{Counters, DriverEvent, Instrument, Sample, SampleValues, Trigger};
use metrology::steady::{SteadyDetector, TriggerKind};

use super::topics::{EventKind, EventMsg, PoseInstrument, PoseMsg, StatusMsg, TriggerEventName};
use super::writer::LogWriter;
use super::{DetectorSettings, INSTRUMENT_METADATA, LogError};

/// The steady-value detectors of the interferometer, the CapBall and the PSD.
#[derive(Debug, Clone)]
pub struct PoseEngine {
    detectors: Vec<(PoseInstrument, SteadyDetector)>,
}

impl PoseEngine {
    pub fn new(settings: &DetectorSettings) -> Result<PoseEngine, LogError> {
        let mk = |i: PoseInstrument, cfg: &metrology::steady::SteadyConfig| {
            SteadyDetector::new(cfg.clone(), i.channels().len()).map(|d| (i, d))
        };
        let mut detectors = Vec::new();
        for (inst, cfg) in [
            (PoseInstrument::Interferometer, &settings.interferometer),
            (PoseInstrument::Capball, &settings.capball),
            (PoseInstrument::Psd, &settings.psd),
        ] {
            if settings.instruments.contains(&inst) {
                detectors.push(mk(inst, cfg)?);
            }
        }
        Ok(PoseEngine { detectors })
    }

    /// Feeds a sample to its instrument's detector (environment records are not).
    pub fn on_sample(&mut self, s: &Sample) -> Vec<PoseMsg> {
        let (inst, values, n): (PoseInstrument, [f64; 3], usize) = match &s.values {
            SampleValues::Position { position_um, .. } => {
                (PoseInstrument::Interferometer, [*position_um, 0.0, 0.0], 1)
            }
            SampleValues::Capball { e_um, .. } => (PoseInstrument::Capball, *e_um, 3),
            SampleValues::Psd { x_um, y_um, .. } => (PoseInstrument::Psd, [*x_um, *y_um, 0.0], 2),
            SampleValues::Environment { .. } => return Vec::new(),
        };
        let Some((_, det)) = self.detectors.iter_mut().find(|(i, _)| *i == inst) else {
            return Vec::new();
        };
        det.push_sample(s.fitted_ns, &values[..n], s.valid)
            .iter()
            .map(|v| PoseMsg::from_value(inst, v))
            .collect()
    }

    /// Feeds a trigger to every detector.
    pub fn on_trigger(&mut self, t: &Trigger) -> Vec<PoseMsg> {
        let kind: TriggerKind = TriggerEventName::from(t.event).into();
        let mut out = Vec::new();
        for (inst, det) in &mut self.detectors {
            for v in det.push_trigger(kind, u32::from(t.pose), t.host_ns) {
                out.push(PoseMsg::from_value(*inst, &v));
            }
        }
        out
    }

    /// End of the run: closes open dwells.
    pub fn finish(&mut self, t_ns: u64) -> Vec<PoseMsg> {
        let mut out = Vec::new();
        for (inst, det) in &mut self.detectors {
            for v in det.finish(t_ns) {
                out.push(PoseMsg::from_value(*inst, &v));
            }
        }
        out
    }
}

/// The log of a run fed with driver events: raw topics, `/pose` from the [`PoseEngine`],
/// `/event`, and `/status` once a second.
pub struct Recorder {
    writer: LogWriter,
    engine: PoseEngine,
    counters: BTreeMap<Instrument, Counters>,
    poses: BTreeMap<String, u64>,
    last_status_ns: Option<u64>,
    last_ns: u64,
}

/// Interval of `/status` records, ns.
pub const STATUS_INTERVAL_NS: u64 = 1_000_000_000;

impl Recorder {
    /// A new log file in `dir` (see [`LogWriter::create_in_dir`]) whose detectors use
    /// `meta.detector` — the settings stored in the log, so replay uses the same.
    pub fn create_in_dir(
        dir: &std::path::Path,
        meta: &super::RunMetadata,
        opts: super::LogOptions,
    ) -> Result<Recorder, LogError> {
        let settings = meta.detector.clone();
        Recorder::new(LogWriter::create_in_dir(dir, meta, opts)?, &settings)
    }

    /// Like [`Recorder::create_in_dir`], at an explicit path (which must not exist).
    pub fn create(
        path: &std::path::Path,
        meta: &super::RunMetadata,
        opts: super::LogOptions,
    ) -> Result<Recorder, LogError> {
        let settings = meta.detector.clone();
        Recorder::new(LogWriter::create(path, meta, opts)?, &settings)
    }

    /// Around an open writer; `settings` must be the `detector` of the writer's
    /// [`RunMetadata`](super::RunMetadata), or replay will not reproduce the pose values.
    pub fn new(writer: LogWriter, settings: &DetectorSettings) -> Result<Recorder, LogError> {
        Ok(Recorder {
            writer,
            engine: PoseEngine::new(settings)?,
            counters: BTreeMap::new(),
            poses: BTreeMap::new(),
            last_status_ns: None,
            last_ns: 0,
        })
    }

    pub fn writer(&mut self) -> &mut LogWriter {
        &mut self.writer
    }

    /// Writes one driver event (and the pose values it completes); returns those pose values.
    /// `now_ns` is the host clock (`HostClock::now_ns`), used for the log time of events that
    /// carry none and for the `/status` cadence.
    pub fn record(&mut self, ev: &DriverEvent, now_ns: u64) -> Result<Vec<PoseMsg>, LogError> {
        self.last_ns = self.last_ns.max(now_ns);
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
            DriverEvent::Counters {
                instrument,
                counters,
            } => {
                self.counters.insert(*instrument, counters.clone());
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
                    text: reason.clone(),
                };
                self.writer.write(now_ns, &msg)?;
                Vec::new()
            }
            DriverEvent::Error {
                instrument,
                port,
                message,
            } => {
                let msg = EventMsg {
                    instrument: instrument.name().into(),
                    kind: EventKind::Error,
                    port: port.clone(),
                    text: message.clone(),
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
            *self.poses.entry(p.status.name().to_string()).or_default() += 1;
            self.writer.write_pose(log_ns, p)?;
        }
        Ok(())
    }

    /// The `/status` message as it stands.
    pub fn status(&self) -> StatusMsg {
        StatusMsg {
            instruments: self
                .counters
                .iter()
                .map(|(i, c)| (i.name().to_string(), c.into()))
                .collect(),
            log_messages: self.writer.messages(),
            poses: self.poses.clone(),
        }
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
        self.writer.flush_if_due()?;
        Ok(())
    }

    /// Ends the run: closes open dwells (their pose values are returned), writes a last
    /// `/status`, closes the file cleanly and returns its path.
    pub fn finish(mut self, now_ns: u64) -> Result<(std::path::PathBuf, Vec<PoseMsg>), LogError> {
        let p = self.engine.finish(now_ns);
        self.write_poses(now_ns, &p)?;
        let st = self.status();
        self.writer.write_status(now_ns, &st)?;
        Ok((self.writer.finish()?, p))
    }
}
