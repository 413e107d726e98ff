//! The daemon's configuration file (TOML): parsing, validation against the instruments' data
//! sheets (`docs/instruments.md`), and loading of the files it points to (CapBall transform,
//! trajectory).
//!
//! Every error names the file, the line and column, and says in one sentence what is wrong;
//! unknown keys are rejected (a misspelt key must never silently fall back to a default).
//! Relative paths in the file are relative to the directory of the config file.

use std::ops::Range;
use std::path::{Path, PathBuf};

use metrolog_log::trajectory::{TrajectoryRow, parse_trajectory};
use serde::Deserialize;
use toml::Spanned;

pub use super::preflight::PortSpec;
use super::storage::{self, StoragePolicy};

/// Defaults, shared with the example config `deploy/metrolog.toml`. The data-sheet limits the
/// values are checked against (rate ranges, PSD-2 bauds and line size, CAN identifiers) and the
/// data-sheet defaults (α of steel, the CB-3's nominal sensitivity, the PSD-2's baud) are
/// `protocol`'s (docs/instruments.md), defined there only.
pub const DEFAULT_DETECTOR_SAMPLES: usize = 150;
pub const DEFAULT_LI80_RATE_HZ: u32 = 1000;
pub const DEFAULT_CB3_RATE_HZ: u32 = 1000;
pub const DEFAULT_PSD_RATE_HZ: u32 = 100;
pub const DEFAULT_PSD_MIN_SUM_PA: f64 = 100_000.0;

/// Default of `[run] connect_timeout_s`: how long no device may be connected before the
/// service says so loudly (README, "Nothing connected").
pub const DEFAULT_CONNECT_TIMEOUT_S: u64 = 60;
/// Accepted range of `[run] connect_timeout_s` (from 1 s, for tests, to a day).
pub const CONNECT_TIMEOUT_S: (u64, u64) = (1, 86_400);

/// Accepted range of `[run] read_coalesce_ms`: 0 (read as bytes arrive) to 20 ms, which keeps
/// the pose latency (a window's last sample to its `/pose` record) well under 50 ms.
pub const READ_COALESCE_MS: (u64, u64) = (0, 20);

/// The steady test needs a variance of successive differences (metrolog-detect): 3 at least.
pub const DETECTOR_SAMPLES: (usize, usize) = (3, 1_000_000);

/// A configuration error. Each message says which file and line and what to fix.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The configuration file could not be read.
    #[error("cannot read config file {}: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// The configuration file is not what it should be, at a given place.
    #[error("{}:{line}:{column}: {message}", path.display())]
    Invalid {
        path: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
    /// More than one mistake: every one found in one pass, in the order of the file.
    #[error("{} problems in the config:\n{}", .0.len(), list_errors(.0))]
    Several(Vec<ConfigError>),
}

fn list_errors(errors: &[ConfigError]) -> String {
    let lines: Vec<String> = errors.iter().map(|e| format!("  {e}")).collect();
    lines.join("\n")
}

impl ConfigError {
    /// Line (1-based) of an [`ConfigError::Invalid`] (of the first, for several).
    pub fn line(&self) -> Option<usize> {
        match self {
            ConfigError::Invalid { line, .. } => Some(*line),
            ConfigError::Read { .. } => None,
            ConfigError::Several(v) => v.first().and_then(ConfigError::line),
        }
    }

    /// Each single mistake (one for every variant but [`ConfigError::Several`]).
    pub fn each(&self) -> Vec<&ConfigError> {
        match self {
            ConfigError::Several(v) => v.iter().flat_map(ConfigError::each).collect(),
            e => vec![e],
        }
    }
}

/// The mistakes found so far while validating: each key is checked even after another failed,
/// so one `--check` names every mistake of the file.
#[derive(Debug, Default)]
struct Errors(Vec<ConfigError>);

impl Errors {
    /// The value of a key that passed, or `None` with its mistake kept.
    fn keep<T>(&mut self, r: Result<T, ConfigError>) -> Option<T> {
        match r {
            Ok(v) => Some(v),
            Err(ConfigError::Several(v)) => {
                self.0.extend(v);
                None
            }
            Err(e) => {
                self.0.push(e);
                None
            }
        }
    }

    /// All mistakes as one error, in the order of the file (call when one was kept).
    fn into_error(mut self) -> ConfigError {
        self.0.sort_by_key(|e| e.line().unwrap_or(0));
        if self.0.len() == 1
            && let Some(e) = self.0.pop()
        {
            return e;
        }
        ConfigError::Several(self.0)
    }

    /// `Ok(v)` when no mistake was kept.
    fn result<T>(self, v: Option<T>) -> Result<T, ConfigError> {
        match v {
            Some(v) if self.0.is_empty() => Ok(v),
            _ => Err(self.into_error()),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The file as written (spans kept for the error messages).

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    run: Spanned<RawRun>,
    detector: Option<Spanned<RawDetector>>,
    interferometer: Option<Spanned<RawInterferometer>>,
    capball: Option<Spanned<RawCapball>>,
    psd: Option<Spanned<RawPsd>>,
    trigger: Option<Spanned<RawTrigger>>,
    live: Option<Spanned<RawLive>>,
    temperature: Option<Spanned<RawTemperature>>,
    storage: Option<Spanned<RawStorage>>,
}

/// `[storage]`: retention and the low-space warning (acquire::storage).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStorage {
    keep_days: Option<Spanned<f64>>,
    min_free_gb: Option<Spanned<f64>>,
    warn_free_gb: Option<Spanned<f64>>,
    split_minutes: Option<Spanned<f64>>,
    split_mb: Option<Spanned<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRun {
    machine: Spanned<String>,
    output_dir: Spanned<String>,
    trajectory: Option<Spanned<String>>,
    #[serde(default)]
    stop_at_program_end: bool,
    time_scale: Option<Spanned<f64>>,
    connect_timeout_s: Option<Spanned<i64>>,
    reference_pose: Option<Spanned<OneOrMany>>,
    reference_settle_s: Option<Spanned<f64>>,
    read_coalesce_ms: Option<Spanned<i64>>,
}

/// `reference_pose = 7` or `reference_pose = [7, 13, 19]`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum OneOrMany {
    One(i64),
    Many(Vec<i64>),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDetector {
    samples: Option<Spanned<i64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawInterferometer {
    port: Spanned<String>,
    rate_hz: Option<Spanned<i64>>,
    alpha_um_per_m_k: Option<Spanned<f64>>,
    /// The device may be absent at start (plugged in for each test): the service waits.
    #[serde(default)]
    hotplug: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCapball {
    port: Spanned<String>,
    rate_hz: Option<Spanned<i64>>,
    poly: Option<Spanned<Vec<Vec<f64>>>>,
    transform: Option<Spanned<String>>,
    /// The device may be absent at start (plugged in for each test): the service waits.
    #[serde(default)]
    hotplug: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPsd {
    port: Spanned<String>,
    baud: Option<Spanned<i64>>,
    rate_hz: Option<Spanned<i64>>,
    min_sum_pa: Option<Spanned<f64>>,
    /// The device may be absent at start (plugged in for each test): the service waits.
    #[serde(default)]
    hotplug: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTrigger {
    slcan: Option<Spanned<String>>,
    socketcan: Option<Spanned<String>>,
    can_id: Option<Spanned<i64>>,
    /// The device may be absent at start (plugged in for each test): the service waits.
    #[serde(default)]
    hotplug: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLive {
    listen: Spanned<String>,
    raw_hz: Option<Spanned<i64>>,
}

// ---------------------------------------------------------------------------------------------
// The validated configuration.

/// A validated configuration, with the files it points to already read.
#[derive(Debug, Clone)]
pub struct Config {
    /// Where it was read from.
    pub path: PathBuf,
    /// The file as written (stored in the log).
    pub text: String,
    pub run: RunConfig,
    pub detector: DetectorConfig,
    pub interferometer: Option<drivers::Li80Config>,
    pub capball: Option<CapballConfig>,
    pub psd: Option<drivers::PsdConfig>,
    pub trigger: Option<TriggerConfig>,
    /// The live view (`[live]`, off when absent): docs/live-view.md.
    pub live: Option<LiveConfig>,
    /// The Modbus RTU temperature module (`[temperature]`): docs/instruments.md §5.
    pub temperature: Option<drivers::ModbusTempConfig>,
    /// Every device the config names, where it is written (for the port checks).
    pub ports: Vec<PortSpec>,
    /// `[storage]`: retention and the low-space warning (defaults when absent).
    pub storage: StoragePolicy,
}

/// Default of `[live] raw_hz`: raw batches per second and raw topic sent to the live view.
pub const DEFAULT_LIVE_RAW_HZ: u32 = 10;

/// `[live]`: where the live view (Foxglove WebSocket and operator page) listens.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveConfig {
    pub listen: std::net::SocketAddr,
    /// Raw batches per second and raw topic streamed (0: no raw topics); the log keeps all.
    pub raw_hz: u32,
}

#[derive(Debug, Clone)]
pub struct RunConfig {
    /// Machine name; also the prefix of the log file names.
    pub machine: String,
    pub output_dir: PathBuf,
    pub trajectory: Option<Trajectory>,
    /// End the run when the CNC sends program end.
    pub stop_at_program_end: bool,
    /// For simulated runs only: how many times faster than real time the simulator's slow
    /// effects (drift, environment) run; the analyses multiply times by it. 1 on a machine.
    pub time_scale: f64,
    /// Seconds with no device connected after which the service says so loudly (and, when
    /// no device is `hotplug`, ends with [`crate::exit::NOTHING_CONNECTED`]).
    pub connect_timeout_s: u64,
    /// The trajectory's reference poses (1-based), whose target is the interferometer's datum
    /// position: a lost datum epoch is re-referenced at the first one reached (docs/design.md,
    /// "Datum epochs"). Empty: none.
    pub reference_poses: Vec<u32>,
    /// How long the axis stands at the reference pose before `DATUM`, s.
    pub reference_settle_s: f64,
    /// How long a serial reader waits after a read before the next one, so that reads are
    /// coalesced (`drivers::set_read_coalesce`).
    pub read_coalesce: std::time::Duration,
}

/// Default of `[run] reference_settle_s`: the ringing of a stop is gone (below a nanometre
/// after 0.15 s in the demo machine), well inside a dwell.
pub const DEFAULT_REFERENCE_SETTLE_S: f64 = 0.2;

/// The interferometer's datum position on X, mm: where `DATUM` is taken at connect (home),
/// the positioning analysis' default `datum_x_mm`.
pub const DATUM_X_MM: f64 = 0.0;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorConfig {
    /// Samples averaged per steady value.
    pub samples: usize,
}

#[derive(Debug, Clone)]
pub struct CapballConfig {
    pub driver: drivers::Cb3Config,
    /// The transform file (path and text as read), stored in the log; `None` = identity.
    pub transform_file: Option<(PathBuf, String)>,
}

#[derive(Debug, Clone, PartialEq)]
pub enum TriggerConfig {
    Slcan(drivers::SlcanConfig),
    SocketCan(drivers::SocketCanConfig),
}

/// The trajectory (pose table) of a run.
#[derive(Debug, Clone)]
pub struct Trajectory {
    pub path: PathBuf,
    /// The file as read (stored in the log as an attachment).
    pub text: String,
    pub rows: Vec<TrajectoryRow>,
}

impl Config {
    /// Read and validate a config file.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Config::parse(path, &text)
    }

    /// Validate config text; `path` names it in errors and anchors its relative paths. The
    /// devices are not looked at (see [`Config::load_checked`]), except that two keys naming
    /// the same port are refused.
    pub fn parse(path: &Path, text: &str) -> Result<Config, ConfigError> {
        Config::parse_with(path, text, false)
    }

    /// [`Config::load`], and the devices checked as the service will find them: every port
    /// exists (unless `hotplug = true`), is a device, and no two keys name the same one
    /// (also through a udev symlink); `output_dir` is a directory if it exists. All
    /// mistakes, of the file and of the devices, come in one error. What is not a mistake
    /// but worth a line (a `hotplug` device absent now, a port this user cannot open) is in
    /// [`Config::notes`].
    pub fn load_checked(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Config::parse_with(path, &text, true)
    }

    /// [`Config::parse`], with the devices checked when `devices` ([`Config::load_checked`]).
    pub fn parse_with(path: &Path, text: &str, devices: bool) -> Result<Config, ConfigError> {
        let ctx = Ctx {
            path,
            text,
            devices,
            ports: Default::default(),
        };
        let raw: RawConfig = toml::from_str(text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            ctx.err(span, first_sentence(e.message()))
        })?;
        ctx.validate(raw)
    }

    /// Lines worth reading before a run that are not mistakes: a `hotplug` device absent now,
    /// a port this user may not open (the service's user may).
    pub fn notes(&self) -> Vec<String> {
        super::preflight::port_notes(&self.ports)
    }

    /// The instruments configured, in a fixed order.
    pub fn instruments(&self) -> Vec<drivers::Instrument> {
        let mut v = Vec::new();
        if self.interferometer.is_some() {
            v.push(drivers::Instrument::Interferometer);
        }
        if self.capball.is_some() {
            v.push(drivers::Instrument::Capball);
        }
        if self.psd.is_some() {
            v.push(drivers::Instrument::Psd);
        }
        if self.trigger.is_some() {
            v.push(drivers::Instrument::Trigger);
        }
        if self.temperature.is_some() {
            v.push(drivers::Instrument::Thermometer);
        }
        v
    }
}

/// toml's messages are sometimes several lines; the first says what is wrong.
fn first_sentence(m: &str) -> String {
    m.lines().next().unwrap_or(m).trim().to_string()
}

struct Ctx<'a> {
    path: &'a Path,
    text: &'a str,
    /// Check the devices and directories as they are now ([`Config::load_checked`]).
    devices: bool,
    /// The ports named so far, for the checks across sections.
    ports: std::cell::RefCell<Vec<PortSpec>>,
}

impl Ctx<'_> {
    fn err(&self, span: Range<usize>, message: impl Into<String>) -> ConfigError {
        let (line, column) = line_col(self.text, span.start);
        ConfigError::Invalid {
            path: self.path.to_path_buf(),
            line,
            column,
            message: message.into(),
        }
    }

    /// The port mistakes: the same device named twice, and (when checking devices) one that
    /// is missing and not `hotplug`, or not a device.
    fn port_checks(&self, ports: &[PortSpec]) -> Vec<ConfigError> {
        let mut found = super::preflight::shared_ports(ports);
        if self.devices {
            found.extend(super::preflight::missing_ports(ports));
        }
        found
            .into_iter()
            .map(|(p, message)| ConfigError::Invalid {
                path: self.path.to_path_buf(),
                line: p.line,
                column: p.column,
                message,
            })
            .collect()
    }

    fn validate_connect_timeout(&self, t: Option<Spanned<i64>>) -> Result<u64, ConfigError> {
        let Some(t) = t else {
            return Ok(DEFAULT_CONNECT_TIMEOUT_S);
        };
        let v = *t.get_ref();
        let (lo, hi) = CONNECT_TIMEOUT_S;
        if v < lo as i64 || v > hi as i64 {
            return Err(self.err(
                t.span(),
                format!("connect_timeout_s = {v} is outside {lo} to {hi} s (how long the service waits for a first device before saying nothing is connected)"),
            ));
        }
        Ok(v as u64)
    }

    fn validate_read_coalesce(
        &self,
        t: Option<Spanned<i64>>,
    ) -> Result<std::time::Duration, ConfigError> {
        let Some(t) = t else {
            return Ok(drivers::READ_COALESCE_DEFAULT);
        };
        let v = *t.get_ref();
        let (lo, hi) = READ_COALESCE_MS;
        if v < lo as i64 || v > hi as i64 {
            return Err(self.err(
                t.span(),
                format!("read_coalesce_ms = {v} is outside {lo} to {hi} ms (how long a serial reader lets bytes gather between reads)"),
            ));
        }
        Ok(std::time::Duration::from_millis(v as u64))
    }

    /// A path in the config, relative to the config file's directory.
    fn resolve(&self, p: &str) -> PathBuf {
        let p = Path::new(p);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.path.parent().unwrap_or_else(|| Path::new(".")).join(p)
        }
    }

    fn rate(
        &self,
        v: Option<Spanned<i64>>,
        default: u32,
        range: std::ops::RangeInclusive<u32>,
        what: &str,
    ) -> Result<u32, ConfigError> {
        let Some(v) = v else { return Ok(default) };
        let x = *v.get_ref();
        let (lo, hi) = (*range.start(), *range.end());
        if x < lo as i64 || x > hi as i64 {
            return Err(self.err(
                v.span(),
                format!("rate_hz = {x} is outside what the {what} supports ({lo} to {hi} Hz)"),
            ));
        }
        Ok(x as u32)
    }

    /// A device path; kept (with its place and `hotplug`) for the port checks.
    fn port(
        &self,
        v: Spanned<String>,
        key: &str,
        hotplug: bool,
        interface: bool,
    ) -> Result<String, ConfigError> {
        if v.get_ref().trim().is_empty() {
            return Err(self.err(
                v.span(),
                "port is empty; give the device path, e.g. /dev/metrolog-li80",
            ));
        }
        let (line, column) = line_col(self.text, v.span().start);
        self.ports.borrow_mut().push(PortSpec {
            key: key.to_string(),
            path: v.get_ref().clone(),
            interface,
            hotplug,
            line,
            column,
        });
        Ok(v.into_inner())
    }

    fn validate(&self, raw: RawConfig) -> Result<Config, ConfigError> {
        let mut errs = Errors::default();
        if let Some(p) = &raw.run.get_ref().reference_pose
            && raw.interferometer.is_none()
        {
            errs.0.push(self.err(
                p.span(),
                "reference_pose is set but there is no [interferometer] to re-reference",
            ));
        }
        let run = errs.keep(self.validate_run(raw.run.into_inner()));
        let detector = errs.keep(self.validate_detector(raw.detector));
        let interferometer = self.section(&mut errs, raw.interferometer, |r| {
            self.validate_interferometer(r)
        });
        let capball = self.section(&mut errs, raw.capball, |r| self.validate_capball(r));
        let psd = self.section(&mut errs, raw.psd, |r| self.validate_psd(r));
        let trigger = match raw.trigger {
            None => Some(None),
            Some(s) => errs.keep(self.validate_trigger(s)).map(Some),
        };
        let live = self.section(&mut errs, raw.live, |r| self.validate_live(r));
        let storage = self.section(&mut errs, raw.storage, |r| self.validate_storage(r));
        let temperature = match raw.temperature {
            None => Some(None),
            Some(s) => errs.keep(self.validate_temperature(s)).map(Some),
        };
        let ports = self.ports.take();
        errs.0.extend(self.port_checks(&ports));
        let (Some(run), Some(detector), Some(interferometer), Some(capball), Some(psd)) =
            (run, detector, interferometer, capball, psd)
        else {
            return Err(errs.into_error());
        };
        let (Some(trigger), Some(live), Some(storage), Some(temperature)) =
            (trigger, live, storage, temperature)
        else {
            return Err(errs.into_error());
        };
        errs.result(Some(Config {
            path: self.path.to_path_buf(),
            text: self.text.to_string(),
            run,
            detector,
            interferometer,
            capball,
            psd,
            trigger,
            live,
            temperature,
            ports,
            storage: storage.unwrap_or_default(),
        }))
    }

    /// An optional section: `Some(None)` when absent, `None` when it has a mistake (kept).
    fn section<R, T>(
        &self,
        errs: &mut Errors,
        raw: Option<Spanned<R>>,
        validate: impl FnOnce(R) -> Result<T, ConfigError>,
    ) -> Option<Option<T>> {
        match raw {
            None => Some(None),
            Some(s) => errs.keep(validate(s.into_inner())).map(Some),
        }
    }

    fn validate_detector(
        &self,
        raw: Option<Spanned<RawDetector>>,
    ) -> Result<DetectorConfig, ConfigError> {
        let Some(s) = raw.and_then(|d| d.into_inner().samples) else {
            return Ok(DetectorConfig {
                samples: DEFAULT_DETECTOR_SAMPLES,
            });
        };
        let n = *s.get_ref();
        let (lo, hi) = DETECTOR_SAMPLES;
        if n < lo as i64 || n > hi as i64 {
            return Err(self.err(
                s.span(),
                format!(
                    "samples = {n} is impossible; a steady value averages {lo} to {hi} samples"
                ),
            ));
        }
        Ok(DetectorConfig {
            samples: n as usize,
        })
    }

    fn validate_live(&self, r: RawLive) -> Result<LiveConfig, ConfigError> {
        let mut errs = Errors::default();
        let listen = errs.keep(r.listen.get_ref().trim().parse().map_err(|_| {
            self.err(
                r.listen.span(),
                format!(
                    "listen = {:?} is not an address and port; write e.g. \"127.0.0.1:8765\"",
                    r.listen.get_ref()
                ),
            )
        }));
        let raw_hz = errs.keep(match r.raw_hz {
            None => Ok(DEFAULT_LIVE_RAW_HZ),
            Some(v) if (0..=100).contains(v.get_ref()) => Ok(*v.get_ref() as u32),
            Some(v) => Err(self.err(
                v.span(),
                format!(
                    "raw_hz = {} is outside 0 to 100 (raw batches per second and topic; the log holds 100)",
                    v.get_ref()
                ),
            )),
        });
        errs.result(
            listen
                .zip(raw_hz)
                .map(|(listen, raw_hz)| LiveConfig { listen, raw_hz }),
        )
    }

    fn validate_alpha(&self, a: Option<Spanned<f64>>) -> Result<f64, ConfigError> {
        let Some(a) = a else {
            return Ok(protocol::convert::ALPHA_STEEL_UM_PER_M_K);
        };
        let x = *a.get_ref();
        // Machine-tool materials lie within about -1 (invar, Zerodur) to 30 (aluminium,
        // polymer concrete is lower); 100 leaves room and still catches a value typed in the
        // wrong unit (e.g. 1/K: 1.17e-5).
        if !x.is_finite() || x.abs() > 100.0 {
            return Err(self.err(
                a.span(),
                format!("alpha_um_per_m_k = {x} is not a plausible expansion coefficient; give it in µm/(m·K), e.g. 11.7 for steel"),
            ));
        }
        Ok(x)
    }

    fn validate_interferometer(
        &self,
        r: RawInterferometer,
    ) -> Result<drivers::Li80Config, ConfigError> {
        let mut errs = Errors::default();
        let rate_hz = errs.keep(self.rate(
            r.rate_hz,
            DEFAULT_LI80_RATE_HZ,
            protocol::li80::RATE_HZ,
            "LI-80",
        ));
        let alpha = errs.keep(self.validate_alpha(r.alpha_um_per_m_k));
        let port = errs.keep(self.port(r.port, "[interferometer] port", r.hotplug, false));
        let (Some(rate_hz), Some(alpha_um_per_m_k), Some(port)) = (rate_hz, alpha, port) else {
            return Err(errs.into_error());
        };
        Ok(drivers::Li80Config {
            port,
            rate_hz,
            alpha_um_per_m_k,
        })
    }

    fn validate_baud(&self, b: Option<Spanned<i64>>) -> Result<u32, ConfigError> {
        let Some(b) = b else {
            return Ok(protocol::psd::DEFAULT_BAUD);
        };
        let x = *b.get_ref();
        if !protocol::psd::BAUDS.iter().any(|&p| p as i64 == x) {
            return Err(self.err(
                b.span(),
                format!(
                    "baud = {x} is not a baud rate the PSD-2 supports ({:?})",
                    protocol::psd::BAUDS
                ),
            ));
        }
        Ok(x as u32)
    }

    fn validate_min_sum(&self, m: Option<Spanned<f64>>) -> Result<f64, ConfigError> {
        let Some(m) = m else {
            return Ok(DEFAULT_PSD_MIN_SUM_PA);
        };
        let x = *m.get_ref();
        if !x.is_finite() || x < 0.0 {
            return Err(self.err(
                m.span(),
                format!("min_sum_pa = {x} is impossible; a photocurrent threshold is a finite number of pA ≥ 0"),
            ));
        }
        Ok(x)
    }

    fn validate_psd(&self, r: RawPsd) -> Result<drivers::PsdConfig, ConfigError> {
        let mut errs = Errors::default();
        let baud = errs.keep(self.validate_baud(r.baud));
        let rate_span = r.rate_hz.as_ref().map(|v| v.span()).unwrap_or(0..0);
        let rate_hz = errs.keep(self.rate(
            r.rate_hz,
            DEFAULT_PSD_RATE_HZ,
            protocol::psd::RATE_HZ,
            "PSD-2",
        ));
        if let (Some(baud), Some(rate_hz)) = (baud, rate_hz) {
            let max_lines = baud / protocol::psd::LINE_BITS;
            if rate_hz > max_lines {
                errs.keep::<()>(Err(self.err(
                    rate_span,
                    format!("rate_hz = {rate_hz} is more than a {baud} baud link carries (about {max_lines} lines/s); lower rate_hz or raise baud"),
                )));
            }
        }
        let min_sum_pa = errs.keep(self.validate_min_sum(r.min_sum_pa));
        let port = errs.keep(self.port(r.port, "[psd] port", r.hotplug, false));
        let (Some(baud), Some(rate_hz), Some(min_sum_pa), Some(port)) =
            (baud, rate_hz, min_sum_pa, port)
        else {
            return Err(errs.into_error());
        };
        errs.result(Some(drivers::PsdConfig {
            port,
            baud,
            rate_hz,
            min_sum_pa,
            // Not part of the config file (yet): no error map, no head correction.
            error_map: None,
            head: None,
        }))
    }

    fn validate_can_id(&self, c: Option<Spanned<i64>>) -> Result<u32, ConfigError> {
        let Some(c) = c else {
            return Ok(protocol::can::DEFAULT_CAN_ID);
        };
        let x = *c.get_ref();
        if !(0..=i64::from(protocol::can::STANDARD_ID_MAX)).contains(&x) {
            return Err(self.err(
                c.span(),
                format!("can_id = {x:#x} is not a CAN 2.0A (11-bit) identifier; it must be 0x000 to 0x7FF"),
            ));
        }
        Ok(x as u32)
    }

    fn validate_trigger(&self, s: Spanned<RawTrigger>) -> Result<TriggerConfig, ConfigError> {
        let span = s.span();
        let r = s.into_inner();
        let mut errs = Errors::default();
        let can_id = errs.keep(self.validate_can_id(r.can_id));
        let link = errs.keep(self.trigger_link(span, r.slcan, r.socketcan, r.hotplug));
        let (Some(can_id), Some(link)) = (can_id, link) else {
            return Err(errs.into_error());
        };
        Ok(match link {
            Ok(port) => TriggerConfig::Slcan(drivers::SlcanConfig { port, can_id }),
            Err(interface) => {
                TriggerConfig::SocketCan(drivers::SocketCanConfig { interface, can_id })
            }
        })
    }

    /// The trigger's link: `Ok(serial port)` for SLCAN, `Err(interface)` for SocketCAN.
    fn trigger_link(
        &self,
        span: Range<usize>,
        slcan: Option<Spanned<String>>,
        socketcan: Option<Spanned<String>>,
        hotplug: bool,
    ) -> Result<Result<String, String>, ConfigError> {
        match (slcan, socketcan) {
            (Some(p), None) => Ok(Ok(self.port(p, "[trigger] slcan", hotplug, false)?)),
            (None, Some(i)) => {
                let name = i.get_ref();
                // Linux interface names are at most 15 bytes (IFNAMSIZ - 1).
                if name.is_empty() || name.len() > 15 || name.contains(['/', ' ']) {
                    return Err(self.err(
                        i.span(),
                        format!(
                            "socketcan = {name:?} is not a network interface name (e.g. \"can0\")"
                        ),
                    ));
                }
                Ok(Err(self.port(i, "[trigger] socketcan", hotplug, true)?))
            }
            (Some(_), Some(s)) => Err(self.err(
                s.span(),
                "[trigger] has both slcan and socketcan; keep the one the CNC is wired to",
            )),
            (None, None) => Err(self.err(
                span,
                "[trigger] needs slcan = \"/dev/...\" or socketcan = \"can0\"",
            )),
        }
    }

    fn validate_machine(&self, m: Spanned<String>) -> Result<String, ConfigError> {
        let machine = m.get_ref();
        if machine.is_empty()
            || !machine
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        {
            return Err(self.err(
                m.span(),
                format!("machine = {machine:?} must be a non-empty name of letters, digits, '-', '_' or '.' (it names the log files)"),
            ));
        }
        Ok(m.into_inner())
    }

    fn validate_output_dir(&self, d: Spanned<String>) -> Result<PathBuf, ConfigError> {
        if d.get_ref().trim().is_empty() {
            return Err(self.err(
                d.span(),
                "output_dir is empty; give the directory the logs go to",
            ));
        }
        let dir = self.resolve(d.get_ref());
        if self.devices && dir.exists() && !dir.is_dir() {
            return Err(self.err(
                d.span(),
                format!(
                    "output_dir {} is not a directory; give the directory the logs go to",
                    dir.display()
                ),
            ));
        }
        Ok(dir)
    }

    fn validate_trajectory(
        &self,
        t: Option<Spanned<String>>,
    ) -> Result<Option<Trajectory>, ConfigError> {
        let Some(t) = t else { return Ok(None) };
        let path = self.resolve(t.get_ref());
        let text = std::fs::read_to_string(&path).map_err(|e| {
            self.err(
                t.span(),
                format!("trajectory file {} cannot be read: {e}", path.display()),
            )
        })?;
        let rows = parse_trajectory(&text)
            .map_err(|m| self.err(t.span(), format!("trajectory file {}: {m}", path.display())))?;
        Ok(Some(Trajectory { path, text, rows }))
    }

    fn validate_time_scale(&self, t: Option<Spanned<f64>>) -> Result<f64, ConfigError> {
        let Some(t) = t else { return Ok(1.0) };
        let v = *t.get_ref();
        if !(v.is_finite() && v > 0.0) {
            return Err(self.err(
                t.span(),
                format!("time_scale = {v} must be a positive number (1 on a real machine)"),
            ));
        }
        Ok(v)
    }

    fn validate_run(&self, r: RawRun) -> Result<RunConfig, ConfigError> {
        let mut errs = Errors::default();
        let machine = errs.keep(self.validate_machine(r.machine));
        let output_dir = errs.keep(self.validate_output_dir(r.output_dir));
        let trajectory = errs.keep(self.validate_trajectory(r.trajectory));
        let time_scale = errs.keep(self.validate_time_scale(r.time_scale));
        let connect_timeout_s = errs.keep(self.validate_connect_timeout(r.connect_timeout_s));
        let settle = errs.keep(self.validate_reference_settle(r.reference_settle_s));
        let read_coalesce = errs.keep(self.validate_read_coalesce(r.read_coalesce_ms));
        let (Some(machine), Some(output_dir), Some(trajectory), Some(time_scale)) =
            (machine, output_dir, trajectory, time_scale)
        else {
            return Err(errs.into_error());
        };
        let reference_pose =
            errs.keep(self.validate_reference_pose(r.reference_pose, trajectory.as_ref()));
        let (
            Some(reference_poses),
            Some(reference_settle_s),
            Some(connect_timeout_s),
            Some(read_coalesce),
        ) = (reference_pose, settle, connect_timeout_s, read_coalesce)
        else {
            return Err(errs.into_error());
        };
        errs.result(Some(RunConfig {
            machine,
            output_dir,
            trajectory,
            stop_at_program_end: r.stop_at_program_end,
            time_scale,
            connect_timeout_s,
            reference_poses,
            reference_settle_s,
            read_coalesce,
        }))
    }

    /// `reference_pose`: poses of the trajectory whose target X is the datum position.
    fn validate_reference_pose(
        &self,
        p: Option<Spanned<OneOrMany>>,
        trajectory: Option<&Trajectory>,
    ) -> Result<Vec<u32>, ConfigError> {
        let Some(p) = p else { return Ok(Vec::new()) };
        let span = p.span();
        let ks = match p.into_inner() {
            OneOrMany::One(k) => vec![k],
            OneOrMany::Many(v) => v,
        };
        let Some(t) = trajectory else {
            return Err(self.err(
                span,
                "reference_pose needs a trajectory (its target must be the interferometer's datum position)",
            ));
        };
        let n = t.rows.len();
        let mut poses = Vec::new();
        let mut errs = Errors::default();
        for k in ks {
            let row = usize::try_from(k)
                .ok()
                .filter(|i| (1..=n).contains(i))
                .map(|i| &t.rows[i - 1]);
            let found = match row {
                None => Err(format!(
                    "reference_pose {k} is not a pose of the trajectory (1 to {n})"
                )),
                Some(r) if (r.x_mm - DATUM_X_MM).abs() > 0.0005 => Err(format!(
                    "reference_pose {k} has target X {} mm, not the interferometer's datum position X {DATUM_X_MM} mm (where DATUM is taken at connect): a re-reference there would move the zero",
                    r.x_mm
                )),
                Some(r) => Ok(r.pose),
            };
            match found {
                Ok(pose) => poses.push(pose),
                Err(m) => errs.0.push(self.err(span.clone(), m)),
            }
        }
        errs.result(Some(poses))
    }

    fn validate_reference_settle(&self, t: Option<Spanned<f64>>) -> Result<f64, ConfigError> {
        let Some(t) = t else {
            return Ok(DEFAULT_REFERENCE_SETTLE_S);
        };
        let v = *t.get_ref();
        if !(v.is_finite() && v > 0.0 && v <= 10.0) {
            return Err(self.err(
                t.span(),
                format!("reference_settle_s = {v} must be above 0 and at most 10 s (how long the axis stands at the reference pose before DATUM)"),
            ));
        }
        Ok(v)
    }

    fn validate_poly(
        &self,
        p: Option<Spanned<Vec<Vec<f64>>>>,
    ) -> Result<[[f64; 3]; 3], ConfigError> {
        let Some(p) = p else {
            return Ok([protocol::convert::CapBallPoly::NOMINAL.c; 3]);
        };
        let v = p.get_ref();
        let shape_ok = v.len() == 3 && v.iter().all(|row| row.len() == 3);
        if !shape_ok {
            return Err(self.err(
                p.span(),
                "poly must be three rows (one per channel) of three coefficients [c1, c2, c3]",
            ));
        }
        if v.iter().flatten().any(|c| !c.is_finite()) {
            return Err(self.err(
                p.span(),
                "poly has a coefficient that is not a finite number",
            ));
        }
        if v.iter().any(|row| row[0] == 0.0) {
            return Err(self.err(
                p.span(),
                "poly has a channel with c1 = 0, which reads every distance as zero; nominal c1 is 10 µm/V",
            ));
        }
        let mut out = [[0.0; 3]; 3];
        for (o, row) in out.iter_mut().zip(v) {
            o.copy_from_slice(row);
        }
        Ok(out)
    }

    /// The CapBall transform (identity when absent) and the file as read.
    fn validate_transform(&self, t: Option<Spanned<String>>) -> Result<Transform, ConfigError> {
        let Some(t) = t else {
            return Ok((identity4(), None));
        };
        let path = self.resolve(t.get_ref());
        let text = std::fs::read_to_string(&path).map_err(|e| {
            self.err(
                t.span(),
                format!("transform file {} cannot be read: {e}", path.display()),
            )
        })?;
        let m = parse_transform(&text)
            .map_err(|m| self.err(t.span(), format!("transform file {}: {m}", path.display())))?;
        Ok((m, Some((path, text))))
    }

    fn validate_capball(&self, r: RawCapball) -> Result<CapballConfig, ConfigError> {
        let mut errs = Errors::default();
        let rate_hz = errs.keep(self.rate(
            r.rate_hz,
            DEFAULT_CB3_RATE_HZ,
            protocol::cb3::RATE_HZ,
            "CB-3",
        ));
        let poly = errs.keep(self.validate_poly(r.poly));
        let transform = errs.keep(self.validate_transform(r.transform));
        let port = errs.keep(self.port(r.port, "[capball] port", r.hotplug, false));
        let (Some(rate_hz), Some(poly), Some((transform, transform_file)), Some(port)) =
            (rate_hz, poly, transform, port)
        else {
            return Err(errs.into_error());
        };
        Ok(CapballConfig {
            driver: drivers::Cb3Config {
                port,
                rate_hz,
                poly,
                transform,
            },
            transform_file,
        })
    }
}

/// `[storage]`: the retention policy and the low-space warning.
impl Ctx<'_> {
    /// A number of `what` within `lo..=hi`, or the key's mistake.
    fn bounded(
        &self,
        v: &Spanned<f64>,
        key: &str,
        (lo, hi): (f64, f64),
        what: &str,
    ) -> Result<f64, ConfigError> {
        let x = *v.get_ref();
        if !(x.is_finite() && (lo..=hi).contains(&x)) {
            return Err(self.err(
                v.span(),
                format!("{key} = {x} is outside {lo} to {hi} ({what})"),
            ));
        }
        Ok(x)
    }

    fn validate_storage(&self, r: RawStorage) -> Result<StoragePolicy, ConfigError> {
        let mut errs = Errors::default();
        let gb = |v: &Spanned<f64>, key| {
            self.bounded(v, key, (0.0, 1e6), "GB of free space")
                .map(|x| (x * storage::GB) as u64)
        };
        let keep = errs.keep(r.keep_days.as_ref().map_or(Ok(None), |v| {
            self.bounded(v, "keep_days", (0.01, 36_500.0), "days a run is kept")
                .map(|d| Some(std::time::Duration::from_secs_f64(d * 86_400.0)))
        }));
        let min_free = errs.keep(
            r.min_free_gb
                .as_ref()
                .map_or(Ok(None), |v| gb(v, "min_free_gb").map(Some)),
        );
        let default_warn = StoragePolicy::default().warn_free_bytes;
        let warn = errs.keep(
            r.warn_free_gb
                .as_ref()
                .map_or(Ok(default_warn), |v| gb(v, "warn_free_gb")),
        );
        let split_after = errs.keep(r.split_minutes.as_ref().map_or(Ok(None), |v| {
            self.bounded(
                v,
                "split_minutes",
                (1.0, 10_080.0),
                "minutes per part of a run",
            )
            .map(|m| Some(std::time::Duration::from_secs_f64(m * 60.0)))
        }));
        let split_bytes = errs.keep(r.split_mb.as_ref().map_or(Ok(None), |v| {
            self.bounded(v, "split_mb", (0.1, 1e6), "MB per part of a run")
                .map(|mb| Some((mb * 1e6) as u64))
        }));
        let (Some(keep), Some(min_free_bytes), Some(warn_free_bytes)) = (keep, min_free, warn)
        else {
            return Err(errs.into_error());
        };
        let (Some(split_after), Some(split_bytes)) = (split_after, split_bytes) else {
            return Err(errs.into_error());
        };
        Ok(StoragePolicy {
            keep,
            min_free_bytes,
            warn_free_bytes,
            split_after,
            split_bytes,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// `[temperature]`: the Modbus RTU temperature module (docs/instruments.md §5). Kept apart from
// the other sections: its own raw structs, checks and limits.

/// Baud rates of the RS-485 temperature modules metrolog reads (the Modbus serial line's set).
pub const TEMPERATURE_BAUDS: [u32; 8] = [1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200];
/// Longest poll period, s (an hour; thermal tests sample every few seconds to a minute).
pub const TEMPERATURE_MAX_POLL_S: f64 = 3600.0;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTemperature {
    port: Spanned<String>,
    baud: Option<Spanned<i64>>,
    parity: Option<Spanned<drivers::Parity>>,
    unit: Spanned<i64>,
    registers: Option<Spanned<drivers::RegisterKind>>,
    start_register: Option<Spanned<i64>>,
    scale_c: Option<Spanned<f64>>,
    offset_c: Option<Spanned<f64>>,
    fault_values: Option<Spanned<Vec<i64>>>,
    poll_period_s: Option<Spanned<f64>>,
    timeout_s: Option<Spanned<f64>>,
    silence_s: Option<Spanned<f64>>,
    sensors: Option<Spanned<Vec<Spanned<RawSensor>>>>,
    /// The device may be absent at start: the service waits.
    #[serde(default)]
    hotplug: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSensor {
    name: Spanned<String>,
    #[serde(default)]
    location: String,
    scale: Option<Spanned<f64>>,
}

/// Seconds one poll takes on the wire at `baud` for `channels` registers: the request
/// (8 bytes), the answer (5 + 2·channels bytes), 11 bits a character, and the silence that
/// ends each frame.
pub fn temperature_exchange_s(baud: u32, channels: usize) -> f64 {
    let chars = (8 + 5 + 2 * channels) as f64;
    chars * 11.0 / baud as f64 + 2.0 * protocol::modbus::frame_gap_us(baud) as f64 * 1e-6
}

impl Ctx<'_> {
    fn validate_temperature(
        &self,
        s: Spanned<RawTemperature>,
    ) -> Result<drivers::ModbusTempConfig, ConfigError> {
        let span = s.span();
        let r = s.into_inner();
        let d = drivers::ModbusTempConfig {
            port: String::new(),
            baud: 9600,
            parity: drivers::Parity::default(),
            unit: 1,
            registers: drivers::RegisterKind::default(),
            start_register: 0,
            sensors: Vec::new(),
            scale_c: 0.1,
            offset_c: 0.0,
            fault_values: vec![i16::MIN, i16::MAX],
            poll_period_s: 1.0,
            timeout_s: 0.3,
            silence_s: 10.0,
        };
        let sensors = self.temperature_sensors(r.sensors, span.clone())?;
        let baud = self.temperature_baud(r.baud, d.baud)?;
        let unit = self.temperature_unit(r.unit)?;
        let start_register = self.temperature_start(r.start_register, sensors.len())?;
        let cfg = drivers::ModbusTempConfig {
            port: self.port(r.port, "[temperature] port", r.hotplug, false)?,
            baud,
            parity: r.parity.map_or(d.parity, Spanned::into_inner),
            unit,
            registers: r.registers.map_or(d.registers, Spanned::into_inner),
            start_register,
            scale_c: self.temperature_scale(r.scale_c, d.scale_c)?,
            offset_c: self.temperature_offset(r.offset_c, d.offset_c)?,
            fault_values: self.temperature_faults(r.fault_values, d.fault_values)?,
            sensors,
            ..d
        };
        let times = [r.poll_period_s, r.timeout_s, r.silence_s];
        let cfg = self.temperature_timing(cfg, times, span.clone())?;
        // Everything the driver checks was checked above with its key; this only guards
        // against the two drifting apart.
        cfg.validate()
            .map_err(|e| self.err(span, format!("[temperature]: {e}")))?;
        Ok(cfg)
    }

    fn temperature_sensors(
        &self,
        v: Option<Spanned<Vec<Spanned<RawSensor>>>>,
        section: Range<usize>,
    ) -> Result<Vec<drivers::TempSensor>, ConfigError> {
        let max = protocol::modbus::MAX_READ_REGISTERS as usize;
        let Some(v) = v else {
            return Err(self.err(
                section,
                "[temperature] has no sensors; add one [[temperature.sensors]] with name = \"...\" per channel, in register order",
            ));
        };
        let span = v.span();
        let list = v.into_inner();
        if list.is_empty() || list.len() > max {
            return Err(self.err(
                span,
                format!(
                    "sensors lists {} channels; one Modbus read takes 1 to {max} registers",
                    list.len()
                ),
            ));
        }
        let mut out: Vec<drivers::TempSensor> = Vec::with_capacity(list.len());
        for s in list {
            let s = s.into_inner();
            let name = s.name.get_ref();
            let ok = name.starts_with(|c: char| c.is_ascii_alphabetic())
                && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if !ok {
                return Err(self.err(
                    s.name.span(),
                    format!("sensor name = {name:?} must start with a letter and hold only letters, digits and '_' (it names a column, e.g. spindle_head)"),
                ));
            }
            if out.iter().any(|o| o.name == *name) {
                return Err(self.err(
                    s.name.span(),
                    format!(
                        "sensor name = {name:?} is given twice; each channel needs its own name"
                    ),
                ));
            }
            let scale = match s.scale {
                Some(v) if !(v.get_ref().is_finite() && *v.get_ref() != 0.0) => {
                    return Err(self.err(
                        v.span(),
                        format!("scale = {} must be a finite number other than 0 (the channel's unit per count)", v.get_ref()),
                    ));
                }
                v => v.map(Spanned::into_inner),
            };
            out.push(drivers::TempSensor {
                name: s.name.into_inner(),
                location: s.location.trim().to_string(),
                scale,
            });
        }
        Ok(out)
    }

    fn temperature_baud(&self, v: Option<Spanned<i64>>, default: u32) -> Result<u32, ConfigError> {
        let Some(b) = v else { return Ok(default) };
        let x = *b.get_ref();
        match TEMPERATURE_BAUDS.iter().find(|&&p| i64::from(p) == x) {
            Some(&p) => Ok(p),
            None => Err(self.err(
                b.span(),
                format!("baud = {x} is not a Modbus RTU baud rate ({TEMPERATURE_BAUDS:?}); use the module's setting, 9600 on most"),
            )),
        }
    }

    fn temperature_unit(&self, v: Spanned<i64>) -> Result<u8, ConfigError> {
        let x = *v.get_ref();
        if !(1..=247).contains(&x) {
            return Err(self.err(
                v.span(),
                format!("unit = {x} is not a Modbus unit (slave) address; it must be 1 to 247, as set on the module"),
            ));
        }
        Ok(x as u8)
    }

    fn temperature_start(
        &self,
        v: Option<Spanned<i64>>,
        channels: usize,
    ) -> Result<u16, ConfigError> {
        let Some(v) = v else { return Ok(0) };
        let x = *v.get_ref();
        let end = x + channels as i64;
        if !(0..=65535).contains(&x) || end > 65536 {
            return Err(self.err(
                v.span(),
                format!("start_register = {x} with {channels} sensors reads registers {x} to {}; Modbus registers are 0 to 65535 (the protocol address: 30001 in the manual's numbering is 0)", end - 1),
            ));
        }
        Ok(x as u16)
    }

    fn temperature_scale(&self, v: Option<Spanned<f64>>, default: f64) -> Result<f64, ConfigError> {
        let Some(v) = v else { return Ok(default) };
        let x = *v.get_ref();
        if !x.is_finite() || x == 0.0 {
            return Err(self.err(
                v.span(),
                format!("scale_c = {x} must be a finite number other than 0: °C per count of the register, e.g. 0.1"),
            ));
        }
        Ok(x)
    }

    fn temperature_offset(
        &self,
        v: Option<Spanned<f64>>,
        default: f64,
    ) -> Result<f64, ConfigError> {
        let Some(v) = v else { return Ok(default) };
        let x = *v.get_ref();
        if !x.is_finite() {
            return Err(self.err(
                v.span(),
                format!("offset_c = {x} must be a finite number of °C"),
            ));
        }
        Ok(x)
    }

    fn temperature_faults(
        &self,
        v: Option<Spanned<Vec<i64>>>,
        default: Vec<i16>,
    ) -> Result<Vec<i16>, ConfigError> {
        let Some(v) = v else { return Ok(default) };
        let mut out = Vec::with_capacity(v.get_ref().len());
        for &x in v.get_ref() {
            let r = i16::try_from(x).map_err(|_| {
                self.err(
                    v.span(),
                    format!("fault_values holds {x}, which no register can hold; give raw signed 16-bit values (-32768 to 32767)"),
                )
            })?;
            out.push(r);
        }
        Ok(out)
    }

    /// A time in seconds: finite and > 0; `None` keeps `default`.
    fn seconds(
        &self,
        v: &Option<Spanned<f64>>,
        key: &str,
        default: f64,
    ) -> Result<f64, ConfigError> {
        let Some(v) = v else { return Ok(default) };
        let x = *v.get_ref();
        if !(x.is_finite() && x > 0.0) {
            return Err(self.err(
                v.span(),
                format!("{key} = {x} must be a number of seconds > 0"),
            ));
        }
        Ok(x)
    }

    fn temperature_timing(
        &self,
        cfg: drivers::ModbusTempConfig,
        [poll, timeout, silence]: [Option<Spanned<f64>>; 3],
        section: Range<usize>,
    ) -> Result<drivers::ModbusTempConfig, ConfigError> {
        let poll_period_s = self.seconds(&poll, "poll_period_s", cfg.poll_period_s)?;
        let timeout_s = self.seconds(&timeout, "timeout_s", cfg.timeout_s)?;
        let silence_s = self.seconds(&silence, "silence_s", cfg.silence_s)?;
        // A default that does not fit (a slow line, many channels) is reported at the section.
        let span = |v: &Option<Spanned<f64>>| v.as_ref().map_or(section.clone(), |v| v.span());
        let wire = temperature_exchange_s(cfg.baud, cfg.sensors.len());
        let wire_text = format!(
            "one read of {} registers takes about {:.1} ms on the wire at {} baud",
            cfg.sensors.len(),
            wire * 1e3,
            cfg.baud
        );
        if poll_period_s > TEMPERATURE_MAX_POLL_S {
            return Err(self.err(
                span(&poll),
                format!("poll_period_s = {poll_period_s} is more than an hour ({TEMPERATURE_MAX_POLL_S} s); poll at least once an hour"),
            ));
        }
        if poll_period_s < wire {
            return Err(self.err(
                span(&poll),
                format!("poll_period_s = {poll_period_s} is shorter than a poll: {wire_text}; raise poll_period_s or baud"),
            ));
        }
        if timeout_s < wire {
            return Err(self.err(
                span(&timeout),
                format!("timeout_s = {timeout_s} is shorter than the answer can take: {wire_text}; raise timeout_s or baud"),
            ));
        }
        if silence_s < poll_period_s + timeout_s {
            return Err(self.err(
                span(&silence),
                format!("silence_s = {silence_s} would reopen the port after a single missed poll; it must be at least poll_period_s + timeout_s = {} s", poll_period_s + timeout_s),
            ));
        }
        Ok(drivers::ModbusTempConfig {
            poll_period_s,
            timeout_s,
            silence_s,
            ..cfg
        })
    }
}

/// A CapBall transform and the file it was read from (path, text), if any.
type Transform = ([[f64; 4]; 4], Option<(PathBuf, String)>);

fn identity4() -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

/// 1-based line and column of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// A 4×4 homogeneous transform as CSV: four rows of four numbers (comma or whitespace
/// separated; `#` comments and blank lines ignored).
pub fn parse_transform(text: &str) -> Result<[[f64; 4]; 4], String> {
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let cells: Vec<&str> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        if cells.len() != 4 {
            return Err(format!(
                "line {} has {} numbers, a 4×4 transform needs 4 per row",
                i + 1,
                cells.len()
            ));
        }
        let mut row = [0.0; 4];
        for (r, c) in row.iter_mut().zip(&cells) {
            *r = c
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("line {}: {c:?} is not a finite number", i + 1))?;
        }
        rows.push(row);
    }
    if rows.len() != 4 {
        return Err(format!("has {} rows, a 4×4 transform needs 4", rows.len()));
    }
    // A homogeneous transform maps [d; 1] to [v; 1]: its last row is [0 0 0 1]. T = M·S⁺ from
    // the cube calibration has that row exactly up to rounding when M and S carry the row of ones.
    let last = rows[3];
    if (last[0].abs() + last[1].abs() + last[2].abs() + (last[3] - 1.0).abs()) > 1e-6 {
        return Err(format!(
            "last row is {last:?}; a homogeneous transform ends with 0, 0, 0, 1"
        ));
    }
    Ok([rows[0], rows[1], rows[2], rows[3]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_col_counts_from_one() {
        assert_eq!(line_col("a\nbc\n", 0), (1, 1));
        assert_eq!(line_col("a\nbc\n", 3), (2, 2));
    }

    #[test]
    fn transform_rejects_non_homogeneous() {
        let t = "1,0,0,0\n0,1,0,0\n0,0,1,0\n0,0,0,2\n";
        assert!(parse_transform(t).unwrap_err().contains("0, 0, 0, 1"));
    }
}
