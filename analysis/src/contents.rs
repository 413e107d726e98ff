//! What the analyses read from a run's log: its pose values, environment, trajectory, config
//! and metadata, with the reasons a log cannot serve as an analysis input.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use metrolog_log::topics::{Decoded, EnvironmentMsg, LogMessage, PoseMsg, decode_message};
use metrolog_log::trajectory::{TrajectoryRow, parse_trajectory};
use metrolog_log::{
    CONFIG_ATTACHMENT, LogError, RUN_METADATA, ReadSummary, TRAJECTORY_ATTACHMENT,
    read_log_progress,
};
use types::Instrument;
use types::PoseStatus;

/// Why a log could not be turned into an analysis input. Each says what to fix.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// {0}
    #[error(transparent)]
    Log(#[from] LogError),
    /// {path}: the log has no `trajectory.csv` attachment; give the run's trajectory with `--trajectory FILE`
    #[error(
        "{}: the log has no `trajectory.csv` attachment; give the run's trajectory with `--trajectory FILE`",
        path.display()
    )]
    NoTrajectory { path: PathBuf },
    /// trajectory {source_name}: {message}
    #[error("trajectory {source_name}: {message}")]
    BadTrajectory {
        source_name: String,
        message: String,
    },
    /// {path}: {what} — {hint}
    #[error("{}: {what} — {hint}", path.display())]
    NoData {
        path: PathBuf,
        what: String,
        hint: String,
    },
    /// bad option: {0}
    #[error("bad option: {0}")]
    BadOption(String),
    /// {0}
    #[error("{0}")]
    Dataset(#[from] ::positioning::positioning_data::DatasetError),
    /// {0}
    #[error("{0}")]
    Capball(#[from] geometry::capball::CapballError),
}

/// One `/pose` value with the log time it was written at.
#[derive(Debug, Clone)]
pub struct LoggedPose {
    pub log_ns: u64,
    pub msg: PoseMsg,
}

/// What the analyses need from a log, read once.
#[derive(Debug, Clone, Default)]
pub struct LogContents {
    pub path: PathBuf,
    /// `/pose` values in file order.
    pub poses: Vec<LoggedPose>,
    /// `/interferometer/environment` records in file order.
    pub environment: Vec<EnvironmentMsg>,
    /// Attachments by name (the last one of a name wins).
    pub attachments: BTreeMap<String, Vec<u8>>,
    /// The `metrolog.run` metadata record.
    pub run_metadata: BTreeMap<String, String>,
    /// The `metrolog.instrument` records (`instrument`, `port`, `identity` = the `*IDN?`
    /// answer, `time_ns`), one per connection, in file order.
    pub instrument_records: Vec<BTreeMap<String, String>>,
    pub summary: ReadSummary,
    /// The interferometer's re-references (`/event` records of kind `datum`), in log order.
    pub rereferences: Vec<Rereference>,
    /// Messages that did not decode (counted, skipped).
    pub undecodable: u64,
}

/// A re-reference of the interferometer's datum, from its `/event` record
/// (`epoch <k> referenced at pose <p>: …`, docs/log-format.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rereference {
    pub epoch: u32,
    pub pose: u32,
}

impl Rereference {
    fn of(e: &metrolog_log::topics::EventMsg) -> Option<Rereference> {
        if e.kind != metrolog_log::topics::EventKind::Datum {
            return None;
        }
        let rest = e.text.strip_prefix("epoch ")?;
        let (epoch, rest) = rest.split_once(' ')?;
        let rest = rest.strip_prefix("referenced at pose ")?;
        let pose = rest.split(':').next()?;
        Some(Rereference {
            epoch: epoch.parse().ok()?,
            pose: pose.trim().parse().ok()?,
        })
    }
}

impl LogContents {
    /// Reads `path` (the intact prefix of a damaged file; see [`metrolog_log::read_log`]).
    pub fn read(path: &Path) -> Result<LogContents, AnalysisError> {
        LogContents::read_progress(path, |_, _| {})
    }

    /// [`LogContents::read`], calling `progress(bytes_read, file_bytes)` as it goes (a progress
    /// bar for an 8-hour log of gigabytes).
    pub fn read_progress(
        path: &Path,
        progress: impl FnMut(u64, u64),
    ) -> Result<LogContents, AnalysisError> {
        let mut c = LogContents {
            path: path.to_path_buf(),
            ..LogContents::default()
        };
        let summary = read_log_progress(path, progress, |item| {
            c.take(item);
            std::ops::ControlFlow::Continue(())
        })?;
        c.summary = summary;
        Ok(c)
    }

    /// Where the log is damaged and how much of it was read, when it is (a torn or corrupt
    /// file, records missing from a cleanly closed one); `None` for an intact log.
    pub fn damage(&self) -> Option<String> {
        let s = &self.summary;
        s.error.as_ref().map(|e| {
            format!(
                "{e} ({} messages read, {} of {} bytes)",
                s.messages, s.bytes_read, s.file_bytes
            )
        })
    }

    /// One record of the log into the contents.
    fn take(&mut self, item: metrolog_log::LogItem<'_>) {
        let c = self;
        match item {
            metrolog_log::LogItem::Message {
                topic,
                encoding,
                log_ns,
                data,
            } => {
                if topic != "/pose" && topic != "/interferometer/environment" && topic != "/event" {
                    return;
                }
                match decode_message(topic, encoding, log_ns, data) {
                    Ok(Some(LogMessage::Pose(msg))) => c.poses.push(LoggedPose { log_ns, msg }),
                    Ok(Some(LogMessage::Event(e))) => {
                        if let Some(r) = Rereference::of(&e) {
                            c.rereferences.push(r);
                        }
                    }
                    Ok(Some(LogMessage::Samples(samples))) => {
                        c.environment.extend(samples.iter().filter_map(|s| {
                            match Decoded::from_sample(s) {
                                Decoded::Environment(e) => Some(e),
                                _ => None,
                            }
                        }))
                    }
                    Ok(_) => {}
                    Err(_) => c.undecodable += 1,
                }
            }
            metrolog_log::LogItem::Attachment { name, data, .. } => {
                c.attachments.insert(name.to_string(), data.to_vec());
            }
            metrolog_log::LogItem::Channel { .. } => {}
            metrolog_log::LogItem::Metadata { name, map } => {
                if name == RUN_METADATA {
                    c.run_metadata = map.clone();
                } else if name == metrolog_log::INSTRUMENT_METADATA {
                    c.instrument_records.push(map.clone());
                }
            }
        }
    }

    /// The trajectory: `override_path` if given, else the log's attachment.
    pub fn trajectory(
        &self,
        override_path: Option<&Path>,
    ) -> Result<Vec<TrajectoryRow>, AnalysisError> {
        let (name, text) = match override_path {
            Some(p) => (
                p.display().to_string(),
                std::fs::read_to_string(p).map_err(|e| AnalysisError::BadTrajectory {
                    source_name: p.display().to_string(),
                    message: format!("cannot be read: {e}"),
                })?,
            ),
            None => {
                let data = self.attachments.get(TRAJECTORY_ATTACHMENT).ok_or_else(|| {
                    AnalysisError::NoTrajectory {
                        path: self.path.clone(),
                    }
                })?;
                (
                    format!("attachment {TRAJECTORY_ATTACHMENT}"),
                    String::from_utf8_lossy(data).into_owned(),
                )
            }
        };
        parse_trajectory(&text).map_err(|message| AnalysisError::BadTrajectory {
            source_name: name,
            message,
        })
    }

    /// The config attachment parsed as TOML (None when absent or unreadable).
    pub fn config(&self) -> Option<toml::Table> {
        let data = self.attachments.get(CONFIG_ATTACHMENT)?;
        std::str::from_utf8(data).ok()?.parse::<toml::Table>().ok()
    }

    /// The first `/pose` value of `instrument` for every pose number.
    pub fn pose_values(&self, instrument: Instrument) -> BTreeMap<u32, &PoseMsg> {
        let mut m = BTreeMap::new();
        for p in &self.poses {
            if p.msg.instrument == instrument {
                m.entry(p.msg.pose).or_insert(&p.msg);
            }
        }
        m
    }

    /// The environment record nearest in time to `t_ns` (by its clock-fitted time).
    pub fn environment_at(&self, t_ns: u64) -> Option<&EnvironmentMsg> {
        self.environment
            .iter()
            .filter(|e| e.valid)
            .min_by_key(|e| e.fitted_ns.abs_diff(t_ns))
    }
}

/// Whether a pose value can be used.
pub(crate) fn is_ok(p: &PoseMsg) -> bool {
    p.status == PoseStatus::Ok
}

/// Whether a log path is an MCAP log (by extension).
pub fn is_mcap(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
        || (path.is_dir() && metrolog_log::split::resolve(path).is_ok())
}
