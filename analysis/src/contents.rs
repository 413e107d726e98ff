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
        c.distrust_misplaced_dwells();
        Ok(c)
    }

    /// A pose whose interferometer value the daemon marked `off_target` was measured in a dwell
    /// that was not its own (another pose's samples; docs/design.md, "Values off their target"),
    /// or against a zero that was not the datum. The other instruments' values of that pose
    /// came from the same triggers' window, and which of the two happened the log cannot tell:
    /// their `ok` values are taken as `off_target` too, so no analysis uses them (the CapBall
    /// and PSD analyses list them as skipped with that status). Returns how many changed.
    fn distrust_misplaced_dwells(&mut self) -> usize {
        let misplaced: std::collections::BTreeSet<u32> = self
            .poses
            .iter()
            .filter(|p| {
                p.msg.instrument == Instrument::Interferometer
                    && p.msg.status == PoseStatus::OffTarget
            })
            .map(|p| p.msg.pose)
            .collect();
        let mut changed = 0;
        for p in &mut self.poses {
            let m = &mut p.msg;
            if m.instrument != Instrument::Interferometer
                && m.status == PoseStatus::Ok
                && misplaced.contains(&m.pose)
            {
                m.status = PoseStatus::OffTarget;
                changed += 1;
            }
        }
        changed
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

#[cfg(test)]
mod tests {
    use super::*;

    fn value(instrument: Instrument, pose: u32, status: PoseStatus) -> LoggedPose {
        LoggedPose {
            log_ns: u64::from(pose),
            msg: PoseMsg {
                instrument,
                pose,
                status,
                n: 150,
                mean: BTreeMap::new(),
                std: BTreeMap::new(),
                t_first_ns: u64::from(pose) * 1_000_000_000,
                t_last_ns: u64::from(pose) * 1_000_000_000 + 1,
                datum_epoch: 0,
            },
        }
    }

    /// Pose 3's interferometer value was another pose's: the CapBall's `ok` value of pose 3
    /// is not used either; the CapBall's other poses, its own failures and the PSD's poses
    /// whose interferometer value was right stay as logged.
    #[test]
    fn the_other_instruments_values_of_a_misplaced_dwell_are_not_used() {
        use Instrument::{Capball, Interferometer, Psd};
        use PoseStatus::{NeverSteady, OffTarget, Ok};
        let mut c = LogContents::default();
        for pose in 1..=4 {
            let status = if pose == 3 { OffTarget } else { Ok };
            c.poses.push(value(Interferometer, pose, status));
            c.poses.push(value(Capball, pose, Ok));
            c.poses
                .push(value(Psd, pose, if pose == 3 { NeverSteady } else { Ok }));
        }
        assert_eq!(c.distrust_misplaced_dwells(), 1);
        let status = |i, pose| c.pose_values(i)[&pose].status;
        assert_eq!(status(Capball, 3), OffTarget);
        assert_eq!(status(Psd, 3), NeverSteady);
        for pose in [1, 2, 4] {
            assert_eq!((status(Capball, pose), status(Psd, pose)), (Ok, Ok));
        }
        assert_eq!(status(Interferometer, 3), OffTarget);
        // A log without an off-target value is left as it is.
        let mut clean = LogContents::default();
        clean.poses.push(value(Capball, 1, Ok));
        assert_eq!(clean.distrust_misplaced_dwells(), 0);
    }
}
