//! `metrolog replay LOG.mcap [-o OUT.mcap] [--detector-samples N] [--trigger-time T]`: re-runs the steady-value
//! detection on the raw topics and triggers of a log, in file order, through the same
//! [`PoseEngine`] the live pipeline uses. With the logged settings it reproduces the logged
//! `/pose` records exactly; `-o` writes a new log with the raw topics copied and the new
//! `/pose` records.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::Serialize;

use metrolog_log::topics::{LogMessage, PoseMsg, TopicMessage, decode_message};

use detect::PoseEngine;
use metrolog_log::{
    DetectorSettings, LogItem, LogOptions, LogWriter, RUN_METADATA, ReadSummary, RunMetadata,
    TriggerTime, read_log_progress, read_run_metadata,
};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The log file (.mcap).
    pub log: PathBuf,
    /// Write a new log: raw topics, attachments and metadata copied, new `/pose` records.
    #[arg(short = 'o', long = "output")]
    pub output: Option<PathBuf>,
    /// Samples averaged per pose (overrides the logged detector settings).
    #[arg(long)]
    pub detector_samples: Option<usize>,
    /// Which time of a trigger places the dwells (overrides the logged setting):
    /// `nc_clock_settled` (the NC clock fitted to the host clock, each trigger placed once the
    /// fit has settled), `nc_clock` (placed with the fit as it stood when the frame came) or
    /// `arrival` (the frame's arrival time, what logs from before the NC clock fit used);
    /// docs/design.md, timing model.
    #[arg(long, value_parser = parse_trigger_time)]
    pub trigger_time: Option<TriggerTime>,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Settings of a replay.
#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    pub output: Option<PathBuf>,
    pub detector_samples: Option<usize>,
    pub trigger_time: Option<TriggerTime>,
}

fn parse_trigger_time(s: &str) -> Result<TriggerTime, String> {
    serde_json::from_value(serde_json::Value::String(s.replace('-', "_"))).map_err(|_| {
        format!("`{s}` is not a trigger time: use nc_clock_settled, nc_clock or arrival")
    })
}

/// What a replay produced.
#[derive(Debug, Clone, Serialize)]
pub struct ReplayOutcome {
    pub read: ReadSummary,
    pub detector: DetectorSettings,
    /// Whether the detector settings are the logged ones.
    pub same_settings: bool,
    /// `/pose` records in the log, with their log times, in file order.
    pub logged: Vec<(u64, PoseMsg)>,
    /// `/pose` records of the replay, with the log time of the message that completed them.
    pub replayed: Vec<(u64, PoseMsg)>,
    /// Replayed poses whose JSON is byte-identical to the logged one at the same position.
    pub identical: usize,
    pub output: Option<PathBuf>,
    /// The temperature module's samples (`/temperature`), per channel.
    pub temperatures: TemperatureSummary,
}

/// What `/temperature` held: samples, and per channel (named as in the run metadata) the
/// range and last value of its readings (NaN readings, sensor faults, left out).
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct TemperatureSummary {
    pub samples: u64,
    pub channels: Vec<ChannelRange>,
}

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ChannelRange {
    pub name: String,
    /// Readings that were numbers (not a sensor fault).
    pub readings: u64,
    pub min_c: Option<f64>,
    pub max_c: Option<f64>,
    pub last_c: Option<f64>,
}

impl TemperatureSummary {
    /// Channel names from the run metadata (`ch<i>` where it has none).
    fn new(run: &RunMetadata) -> TemperatureSummary {
        let names: Vec<String> = run
            .extra
            .get(metrolog_log::TEMPERATURE_SENSORS_KEY)
            .and_then(|j| serde_json::from_str::<Vec<drivers::TempSensor>>(j).ok())
            .map(|v| v.into_iter().map(|s| s.name).collect())
            .unwrap_or_default();
        TemperatureSummary {
            samples: 0,
            channels: names.into_iter().map(ChannelRange::named).collect(),
        }
    }

    fn add(&mut self, values_c: &[f64]) {
        self.samples += 1;
        for (i, &v) in values_c.iter().enumerate() {
            if self.channels.len() <= i {
                self.channels.push(ChannelRange::named(format!("ch{i}")));
            }
            let c = &mut self.channels[i];
            if v.is_finite() {
                c.readings += 1;
                c.min_c = Some(c.min_c.map_or(v, |m| m.min(v)));
                c.max_c = Some(c.max_c.map_or(v, |m| m.max(v)));
                c.last_c = Some(v);
            }
        }
    }

    /// One line, e.g. `120 samples; spindle 20.1..22.4 °C, air 20.4..20.6 °C, open: no reading`.
    pub fn line(&self) -> String {
        let ch: Vec<String> = self
            .channels
            .iter()
            .map(|c| match (c.min_c, c.max_c) {
                (Some(a), Some(b)) => format!("{} {a:.2}..{b:.2} °C", c.name),
                _ => format!("{}: no reading", c.name),
            })
            .collect();
        format!("{} samples; {}", self.samples, ch.join(", "))
    }
}

impl ChannelRange {
    fn named(name: String) -> ChannelRange {
        ChannelRange {
            name,
            readings: 0,
            min_c: None,
            max_c: None,
            last_c: None,
        }
    }
}

impl ReplayOutcome {
    /// Every logged pose reproduced exactly, and nothing more.
    pub fn reproduces_log(&self) -> bool {
        self.identical == self.logged.len() && self.logged.len() == self.replayed.len()
    }
}

fn json(p: &PoseMsg) -> Vec<u8> {
    serde_json::to_vec(p).unwrap_or_default()
}

/// Replays `path`.
pub fn replay(path: &Path, opts: &ReplayOptions) -> anyhow::Result<ReplayOutcome> {
    // The run metadata (settings) first, so the detectors exist before the first sample.
    let run_map = read_run_metadata(path)?;
    let run = match &run_map {
        Some(m) => RunMetadata::from_map(m)?,
        None => RunMetadata::default(),
    };
    let logged_settings = run.detector.clone();
    let mut detector = match opts.detector_samples {
        Some(n) => logged_settings.clone().with_samples(n),
        None => logged_settings.clone(),
    };
    if let Some(t) = opts.trigger_time {
        detector.trigger_time = t;
    }
    let mut engine = PoseEngine::new(&detector).context("cannot build the detectors")?;

    // The new log is written under a temporary name beside `-o` and renamed when complete: a
    // replay that fails leaves no file.
    let tmp = opts
        .output
        .as_deref()
        .map(super::input::new_output_path)
        .transpose()?;
    let mut writer = match &tmp {
        Some(t) => {
            let mut meta = run.clone();
            meta.detector = detector.clone();
            meta.extra
                .insert("replayed_from".into(), path.display().to_string());
            Some(LogWriter::create(t, &meta, LogOptions::default())?)
        }
        None => None,
    };

    let mut temperatures = TemperatureSummary::new(&run);
    let mut logged = Vec::new();
    let mut replayed = Vec::new();
    let mut last_ns = 0u64;
    let mut first_error: Option<anyhow::Error> = None;
    let bar = super::progress::Progress::new("replay");
    let mut on_item = |item: LogItem<'_>| {
        let r: anyhow::Result<()> = (|| {
            match item {
                LogItem::Message {
                    topic,
                    encoding,
                    log_ns,
                    data,
                } => {
                    last_ns = last_ns.max(log_ns);
                    let msg = match decode_message(topic, encoding, log_ns, data) {
                        Ok(m) => m,
                        Err(e) => bail!("a {topic} message at {log_ns} ns does not decode: {e}"),
                    };
                    match msg {
                        Some(LogMessage::Pose(p)) => logged.push((log_ns, p)),
                        Some(LogMessage::Trigger(t)) => {
                            let trig = t.to_trigger(log_ns);
                            let new_poses = engine.on_trigger(&trig);
                            if let Some(w) = writer.as_mut() {
                                w.write_trigger(&trig)?;
                                for p in &new_poses {
                                    w.write_pose(log_ns, p)?;
                                }
                            }
                            replayed.extend(new_poses.into_iter().map(|p| (log_ns, p)));
                        }
                        // Samples one by one, each at its host arrival time (a batch of a
                        // format-2 log holds many; environment records feed no detector).
                        Some(LogMessage::Samples(samples)) => {
                            for s in &samples {
                                last_ns = last_ns.max(s.host_ns);
                                if let drivers::SampleValues::Temperature { values_c } = &s.values {
                                    temperatures.add(values_c);
                                }
                                let new_poses = engine.on_sample(s);
                                if let Some(w) = writer.as_mut() {
                                    w.write_sample(s)?;
                                    for p in &new_poses {
                                        w.write_pose(s.host_ns, p)?;
                                    }
                                }
                                replayed.extend(new_poses.into_iter().map(|p| (s.host_ns, p)));
                            }
                        }
                        // /status, /event and unknown topics are copied as they are.
                        Some(_) | None => {
                            if let Some(w) = writer.as_mut()
                                && encoding == "json"
                            {
                                w.write_raw(topic, log_ns, data)?;
                            }
                        }
                    }
                }
                LogItem::Channel { .. } => {}
                LogItem::Attachment {
                    name,
                    media_type,
                    log_ns,
                    data,
                } => {
                    if let Some(w) = writer.as_mut() {
                        w.attach(name, media_type, data, log_ns)?;
                    }
                }
                LogItem::Metadata { name, map } => {
                    if let Some(w) = writer.as_mut()
                        && name != RUN_METADATA
                    {
                        w.write_metadata(name, map.clone())?;
                    }
                }
            }
            Ok(())
        })();
        match r {
            Ok(()) => std::ops::ControlFlow::Continue(()),
            Err(e) => {
                first_error = Some(e);
                std::ops::ControlFlow::Break(())
            }
        }
    };
    let read = read_log_progress(path, |d, t| bar.update(d, t), &mut on_item)?;
    drop(bar);
    if let Some(note) = read.split_note() {
        errln!("note: {note}");
    }
    if let Some(e) = first_error {
        return Err(e);
    }
    // A cleanly closed log's last records are the poses of its final dwells and the last
    // /status, all at the finish time. A log whose writer was killed never finished: its open
    // dwell stays open (closing it would invent a status the run never had).
    let tail = if read.clean_close {
        engine.finish(last_ns)
    } else {
        Vec::new()
    };
    if let Some(w) = writer.as_mut() {
        for p in &tail {
            w.write_pose(last_ns, p)?;
        }
    }
    replayed.extend(tail.into_iter().map(|p| (last_ns, p)));
    if let (Some(w), Some(t), Some(out)) = (writer, tmp, &opts.output) {
        w.finish()?;
        super::input::finish_new_output(t, out)?;
    }
    let identical = logged
        .iter()
        .zip(&replayed)
        .filter(|((_, a), (_, b))| json(a) == json(b))
        .count();
    Ok(ReplayOutcome {
        read,
        same_settings: detector == logged_settings,
        detector,
        logged,
        replayed,
        identical,
        output: opts.output.clone(),
        temperatures,
    })
}

fn fmt_pose(p: &PoseMsg) -> String {
    let m: Vec<String> = p.mean.iter().map(|(k, v)| format!("{k} {v:.4}")).collect();
    format!(
        "{:<14} pose {:>4} {:<15} n {:>4} {}",
        p.instrument.name(),
        p.pose,
        p.status.name(),
        p.n,
        m.join(" ")
    )
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let opts = ReplayOptions {
        output: args.output.clone(),
        detector_samples: args.detector_samples,
        trigger_time: args.trigger_time,
    };
    let out = replay(&args.log, &opts)
        .with_context(|| format!("cannot replay {}", args.log.display()))?;

    // Analysis hook: the replayed pose values (`out.replayed`) and the run metadata are what
    // the analyses (ISO 230-2, identification, uncertainty) take; they will run here.

    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    if !out.read.clean_close || out.read.error.is_some() {
        outln!(
            "note: the log is damaged or was not closed cleanly; replayed its intact part ({} messages){}",
            out.read.messages,
            out.read
                .error
                .as_ref()
                .map(|e| format!(": {e}"))
                .unwrap_or_default()
        )?;
    }
    let mut by_status: BTreeMap<(String, String), usize> = BTreeMap::new();
    for (_, p) in &out.replayed {
        *by_status
            .entry((p.instrument.name().into(), p.status.name().into()))
            .or_default() += 1;
    }
    outln!(
        "replayed {} pose values ({} logged) with samples = {}/{}/{} (interferometer/capball/psd){}",
        out.replayed.len(),
        out.logged.len(),
        out.detector.interferometer.samples,
        out.detector.capball.samples,
        out.detector.psd.samples,
        if out.same_settings {
            ", the logged settings"
        } else {
            ", NOT the logged settings"
        }
    )?;
    for ((i, s), n) in &by_status {
        outln!("  {i:<16} {s:<16} {n}")?;
    }
    if out.temperatures.samples > 0 {
        outln!("temperatures: {}", out.temperatures.line())?;
    }
    if out.same_settings {
        if out.reproduces_log() {
            outln!(
                "all {} logged pose values reproduced exactly",
                out.logged.len()
            )?;
        } else {
            outln!(
                "{} of {} logged pose values reproduced exactly; first differences:",
                out.identical,
                out.logged.len()
            )?;
            let mut shown = 0;
            for i in 0..out.logged.len().max(out.replayed.len()) {
                let a = out.logged.get(i).map(|x| &x.1);
                let b = out.replayed.get(i).map(|x| &x.1);
                if a.map(json) != b.map(json) && shown < 10 {
                    shown += 1;
                    outln!(
                        "  logged   {}",
                        a.map(fmt_pose).unwrap_or_else(|| "-".into())
                    )?;
                    outln!(
                        "  replayed {}",
                        b.map(fmt_pose).unwrap_or_else(|| "-".into())
                    )?;
                }
            }
        }
    } else {
        for (_, p) in &out.replayed {
            outln!("  {}", fmt_pose(p))?;
        }
    }
    if let Some(o) = &out.output {
        outln!("wrote {} (new {} records)", o.display(), PoseMsg::TOPIC)?;
    }
    Ok(())
}
