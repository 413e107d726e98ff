//! What a run is in its log: the run metadata record, the names of its metadata records and
//! attachments (one constant each, used by writer and reader), and the errors of the log.

use std::collections::BTreeMap;
use std::path::PathBuf;

use types::DetectorSettings;

/// Name of the metadata record describing the run.
pub const RUN_METADATA: &str = "metrolog.run";
/// Name of the metadata records of connected instruments.
pub const INSTRUMENT_METADATA: &str = "metrolog.instrument";
/// Name of the attachment holding the run's trajectory CSV ([`trajectory`]).
pub const TRAJECTORY_ATTACHMENT: &str = "trajectory.csv";
/// Name of the attachment holding the run's config file.
pub const CONFIG_ATTACHMENT: &str = "metrolog.toml";
/// Key of the log format version in the run metadata: absent in format 1 (one JSON message
/// per raw sample), `2` for protobuf batches, `3` for compact batches (CB-3 as ADC codes,
/// per-sample times as differences; docs/log-format.md).
pub const LOG_FORMAT_KEY: &str = "log_format";
/// The format this crate writes.
pub const LOG_FORMAT: u32 = 3;
/// Key of the CapBall calibration (JSON of `protocol::convert::CapBallCalibration`) in the run
/// metadata; every CapBall batch of format 3 carries it too.
pub const CAPBALL_CALIBRATION_KEY: &str = "capball_calibration";
/// Key of the temperature module's sensors in the run metadata: JSON array of
/// `{"name", "location"}` in channel order, the order of `values_c` in `/temperature`.
pub const TEMPERATURE_SENSORS_KEY: &str = "temperature_sensors";
/// Key of the detector settings (JSON of [`DetectorSettings`]) in the run metadata.
pub const DETECTOR_KEY: &str = "detector";

/// What a run is: stored as the `metrolog.run` metadata record.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RunMetadata {
    /// Machine under test (from the config).
    pub machine: String,
    /// Start of the run, ns since the Unix epoch.
    pub started_ns: u64,
    /// Detector settings the run used (replay uses them by default).
    pub detector: DetectorSettings,
    /// Instrument identities known at start (`*IDN?` answers), by instrument name.
    pub instruments: BTreeMap<String, String>,
    /// The CapBall calibration the CB-3 driver converts with: the writer stores CB-3 samples
    /// as ADC codes when it reproduces them (docs/log-format.md); `None` stores doubles.
    pub capball: Option<protocol::convert::CapBallCalibration>,
    /// Anything else worth keeping (operator, config path, ...).
    pub extra: BTreeMap<String, String>,
}

impl RunMetadata {
    pub fn to_map(&self) -> BTreeMap<String, String> {
        let mut m = self.extra.clone();
        m.insert("machine".into(), self.machine.clone());
        m.insert("start_time_ns".into(), self.started_ns.to_string());
        m.insert("start_time".into(), rfc3339(self.started_ns));
        m.insert("metrolog_version".into(), env!("CARGO_PKG_VERSION").into());
        m.insert(LOG_FORMAT_KEY.into(), LOG_FORMAT.to_string());
        m.insert(
            DETECTOR_KEY.into(),
            serde_json::to_string(&self.detector).unwrap_or_default(),
        );
        if let Some(c) = &self.capball {
            m.insert(
                CAPBALL_CALIBRATION_KEY.into(),
                serde_json::to_string(c).unwrap_or_default(),
            );
        }
        for (k, v) in &self.instruments {
            m.insert(format!("instrument.{k}"), v.clone());
        }
        m
    }

    /// Back from a metadata map; unknown keys go to `extra`.
    pub fn from_map(map: &BTreeMap<String, String>) -> Result<RunMetadata, LogError> {
        let mut r = RunMetadata::default();
        for (k, v) in map {
            match k.as_str() {
                "machine" => r.machine = v.clone(),
                "start_time_ns" => r.started_ns = v.parse().unwrap_or(0),
                "start_time" | "metrolog_version" | LOG_FORMAT_KEY => {
                    r.extra.insert(k.clone(), v.clone());
                }
                CAPBALL_CALIBRATION_KEY => {
                    r.capball =
                        Some(serde_json::from_str(v).map_err(|e| LogError::BadMetadata {
                            key: CAPBALL_CALIBRATION_KEY.into(),
                            reason: e.to_string(),
                        })?)
                }
                DETECTOR_KEY => {
                    r.detector = serde_json::from_str(v).map_err(|e| LogError::BadMetadata {
                        key: DETECTOR_KEY.into(),
                        reason: e.to_string(),
                    })?
                }
                _ => {
                    if let Some(name) = k.strip_prefix("instrument.") {
                        r.instruments.insert(name.into(), v.clone());
                    } else {
                        r.extra.insert(k.clone(), v.clone());
                    }
                }
            }
        }
        Ok(r)
    }
}

/// `YYYY-MM-DDTHH:MM:SS.mmmZ` of ns since the Unix epoch (proleptic Gregorian, UTC).
pub fn rfc3339(unix_ns: u64) -> String {
    let secs = unix_ns / 1_000_000_000;
    let ms = (unix_ns / 1_000_000) % 1000;
    let days = (secs / 86_400) as i64;
    let sod = secs % 86_400;
    // Civil-from-days (H. Hinnant, "chrono-Compatible Low-Level Date Algorithms").
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{ms:03}Z",
        sod / 3600,
        (sod / 60) % 60,
        sod % 60
    )
}

/// Errors of the log. Each says which file and what to do.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// cannot create log file {path}: {source} — check that the directory exists and that the
    /// metrolog user may write to it (or choose another log directory in the config)
    #[error(
        "cannot create log file {}: {source} — check that the directory exists and that the metrolog user may write to it (or choose another log directory in the config)",
        path.display()
    )]
    Create {
        path: PathBuf,
        source: std::io::Error,
    },
    /// writing log file {path} failed: {reason}; {hint}
    #[error("writing log file {} failed: {reason}; {hint}", path.display())]
    Write {
        path: PathBuf,
        reason: String,
        hint: &'static str,
    },
    /// cannot read log file {path}: {source}
    #[error("cannot read log file {}: {source}", path.display())]
    Open {
        path: PathBuf,
        source: std::io::Error,
    },
    /// {path} is not an MCAP log: {reason}
    #[error(
        "{} is not an MCAP log: {reason}; metrolog reads the .mcap files a run writes",
        path.display()
    )]
    NotMcap { path: PathBuf, reason: String },
    /// cannot read attachment {path}: {source}
    #[error("cannot read attachment {}: {source}", path.display())]
    Attachment {
        path: PathBuf,
        source: std::io::Error,
    },
    /// metadata `{key}` of the log is unreadable: {reason}
    #[error("metadata `{key}` of the log is unreadable: {reason}")]
    BadMetadata { key: String, reason: String },
    /// invalid detector settings: {0}
    #[error("invalid detector settings: {0}")]
    Detector(#[from] types::SteadyError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc3339_known_dates() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00.000Z");
        // 2000-02-29T12:34:56.789Z = 951827696.789 s (leap day of a century leap year).
        assert_eq!(rfc3339(951_827_696_789_000_000), "2000-02-29T12:34:56.789Z");
        // 2026-11-22T00:00:00Z = 1795305600 s.
        assert_eq!(
            rfc3339(1_795_305_600_000_000_000),
            "2026-11-22T00:00:00.000Z"
        );
    }
}
