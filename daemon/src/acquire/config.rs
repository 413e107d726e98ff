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

/// Defaults, shared with the example config `deploy/metrolog.toml`. The data-sheet limits the
/// values are checked against (rate ranges, PSD-2 bauds and line size, CAN identifiers) and the
/// data-sheet defaults (α of steel, the CB-3's nominal sensitivity, the PSD-2's baud) are
/// `protocol`'s (docs/instruments.md), defined there only.
pub const DEFAULT_DETECTOR_SAMPLES: usize = 150;
pub const DEFAULT_LI80_RATE_HZ: u32 = 1000;
pub const DEFAULT_CB3_RATE_HZ: u32 = 1000;
pub const DEFAULT_PSD_RATE_HZ: u32 = 100;
pub const DEFAULT_PSD_MIN_SUM_PA: f64 = 100_000.0;

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
}

impl ConfigError {
    /// Line (1-based) of an [`ConfigError::Invalid`].
    pub fn line(&self) -> Option<usize> {
        match self {
            ConfigError::Invalid { line, .. } => Some(*line),
            ConfigError::Read { .. } => None,
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
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCapball {
    port: Spanned<String>,
    rate_hz: Option<Spanned<i64>>,
    poly: Option<Spanned<Vec<Vec<f64>>>>,
    transform: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPsd {
    port: Spanned<String>,
    baud: Option<Spanned<i64>>,
    rate_hz: Option<Spanned<i64>>,
    min_sum_pa: Option<Spanned<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTrigger {
    slcan: Option<Spanned<String>>,
    socketcan: Option<Spanned<String>>,
    can_id: Option<Spanned<i64>>,
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
}

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

    /// Validate config text; `path` names it in errors and anchors its relative paths.
    pub fn parse(path: &Path, text: &str) -> Result<Config, ConfigError> {
        let ctx = Ctx { path, text };
        let raw: RawConfig = toml::from_str(text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            ctx.err(span, first_sentence(e.message()))
        })?;
        ctx.validate(raw)
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

    fn port(&self, v: Spanned<String>) -> Result<String, ConfigError> {
        if v.get_ref().trim().is_empty() {
            return Err(self.err(
                v.span(),
                "port is empty; give the device path, e.g. /dev/metrolog-li80",
            ));
        }
        Ok(v.into_inner())
    }

    fn validate(&self, raw: RawConfig) -> Result<Config, ConfigError> {
        let run = self.validate_run(raw.run.into_inner())?;

        let detector = match raw.detector.and_then(|d| d.into_inner().samples) {
            None => DetectorConfig {
                samples: DEFAULT_DETECTOR_SAMPLES,
            },
            Some(s) => {
                let n = *s.get_ref();
                let (lo, hi) = DETECTOR_SAMPLES;
                if n < lo as i64 || n > hi as i64 {
                    return Err(self.err(
                        s.span(),
                        format!("samples = {n} is impossible; a steady value averages {lo} to {hi} samples"),
                    ));
                }
                DetectorConfig {
                    samples: n as usize,
                }
            }
        };

        let interferometer = match raw.interferometer {
            None => None,
            Some(s) => Some(self.validate_interferometer(s.into_inner())?),
        };

        let capball = match raw.capball {
            None => None,
            Some(s) => Some(self.validate_capball(s.into_inner())?),
        };

        let psd = match raw.psd {
            None => None,
            Some(s) => Some(self.validate_psd(s.into_inner())?),
        };

        let trigger = match raw.trigger {
            None => None,
            Some(s) => Some(self.validate_trigger(s)?),
        };

        let live = match raw.live {
            None => None,
            Some(s) => Some(self.validate_live(s.into_inner())?),
        };

        let temperature = match raw.temperature {
            None => None,
            Some(s) => Some(self.validate_temperature(s)?),
        };

        Ok(Config {
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
        })
    }

    fn validate_live(&self, r: RawLive) -> Result<LiveConfig, ConfigError> {
        let listen = r.listen.get_ref().trim().parse().map_err(|_| {
            self.err(
                r.listen.span(),
                format!(
                    "listen = {:?} is not an address and port; write e.g. \"127.0.0.1:8765\"",
                    r.listen.get_ref()
                ),
            )
        })?;
        let raw_hz = match r.raw_hz {
            None => DEFAULT_LIVE_RAW_HZ,
            Some(v) if (0..=100).contains(v.get_ref()) => *v.get_ref() as u32,
            Some(v) => {
                return Err(self.err(
                    v.span(),
                    format!(
                        "raw_hz = {} is outside 0 to 100 (raw batches per second and topic; the log holds 100)",
                        v.get_ref()
                    ),
                ));
            }
        };
        Ok(LiveConfig { listen, raw_hz })
    }

    fn validate_interferometer(
        &self,
        r: RawInterferometer,
    ) -> Result<drivers::Li80Config, ConfigError> {
        let rate_hz = self.rate(
            r.rate_hz,
            DEFAULT_LI80_RATE_HZ,
            protocol::li80::RATE_HZ,
            "LI-80",
        )?;
        let alpha = match r.alpha_um_per_m_k {
            None => protocol::convert::ALPHA_STEEL_UM_PER_M_K,
            Some(a) => {
                let x = *a.get_ref();
                // Machine-tool materials lie within about -1 (invar, Zerodur) to 30
                // (aluminium, polymer concrete is lower); 100 leaves room and still
                // catches a value typed in the wrong unit (e.g. 1/K: 1.17e-5).
                if !x.is_finite() || x.abs() > 100.0 {
                    return Err(self.err(
                        a.span(),
                        format!("alpha_um_per_m_k = {x} is not a plausible expansion coefficient; give it in µm/(m·K), e.g. 11.7 for steel"),
                    ));
                }
                x
            }
        };
        Ok(drivers::Li80Config {
            port: self.port(r.port)?,
            rate_hz,
            alpha_um_per_m_k: alpha,
        })
    }

    fn validate_psd(&self, r: RawPsd) -> Result<drivers::PsdConfig, ConfigError> {
        let baud = match r.baud {
            None => protocol::psd::DEFAULT_BAUD,
            Some(b) => {
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
                x as u32
            }
        };
        let rate_span = r.rate_hz.as_ref().map(|v| v.span()).unwrap_or(0..0);
        let rate_hz = self.rate(
            r.rate_hz,
            DEFAULT_PSD_RATE_HZ,
            protocol::psd::RATE_HZ,
            "PSD-2",
        )?;
        let max_lines = baud / protocol::psd::LINE_BITS;
        if rate_hz > max_lines {
            return Err(self.err(
                rate_span,
                format!("rate_hz = {rate_hz} is more than a {baud} baud link carries (about {max_lines} lines/s); lower rate_hz or raise baud"),
            ));
        }
        let min_sum_pa = match r.min_sum_pa {
            None => DEFAULT_PSD_MIN_SUM_PA,
            Some(m) => {
                let x = *m.get_ref();
                if !x.is_finite() || x < 0.0 {
                    return Err(self.err(
                        m.span(),
                        format!("min_sum_pa = {x} is impossible; a photocurrent threshold is a finite number of pA ≥ 0"),
                    ));
                }
                x
            }
        };
        Ok(drivers::PsdConfig {
            port: self.port(r.port)?,
            baud,
            rate_hz,
            min_sum_pa,
            // Not part of the config file (yet): no error map, no head correction.
            error_map: None,
            head: None,
        })
    }

    fn validate_trigger(&self, s: Spanned<RawTrigger>) -> Result<TriggerConfig, ConfigError> {
        let span = s.span();
        let r = s.into_inner();
        let can_id = match r.can_id {
            None => protocol::can::DEFAULT_CAN_ID,
            Some(c) => {
                let x = *c.get_ref();
                if !(0..=i64::from(protocol::can::STANDARD_ID_MAX)).contains(&x) {
                    return Err(self.err(
                        c.span(),
                        format!("can_id = {x:#x} is not a CAN 2.0A (11-bit) identifier; it must be 0x000 to 0x7FF"),
                    ));
                }
                x as u32
            }
        };
        match (r.slcan, r.socketcan) {
            (Some(p), None) => Ok(TriggerConfig::Slcan(drivers::SlcanConfig {
                port: self.port(p)?,
                can_id,
            })),
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
                Ok(TriggerConfig::SocketCan(drivers::SocketCanConfig {
                    interface: i.into_inner(),
                    can_id,
                }))
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

    fn validate_run(&self, r: RawRun) -> Result<RunConfig, ConfigError> {
        let machine = r.machine.get_ref();
        if machine.is_empty()
            || !machine
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        {
            return Err(self.err(
                r.machine.span(),
                format!("machine = {machine:?} must be a non-empty name of letters, digits, '-', '_' or '.' (it names the log files)"),
            ));
        }
        if r.output_dir.get_ref().trim().is_empty() {
            return Err(self.err(
                r.output_dir.span(),
                "output_dir is empty; give the directory the logs go to",
            ));
        }
        let output_dir = self.resolve(r.output_dir.get_ref());
        let trajectory = match r.trajectory {
            None => None,
            Some(t) => {
                let path = self.resolve(t.get_ref());
                let text = std::fs::read_to_string(&path).map_err(|e| {
                    self.err(
                        t.span(),
                        format!("trajectory file {} cannot be read: {e}", path.display()),
                    )
                })?;
                let rows = parse_trajectory(&text).map_err(|m| {
                    self.err(t.span(), format!("trajectory file {}: {m}", path.display()))
                })?;
                Some(Trajectory { path, text, rows })
            }
        };
        let time_scale = match r.time_scale {
            None => 1.0,
            Some(t) => {
                let v = *t.get_ref();
                if !(v.is_finite() && v > 0.0) {
                    return Err(self.err(
                        t.span(),
                        format!("time_scale = {v} must be a positive number (1 on a real machine)"),
                    ));
                }
                v
            }
        };
        Ok(RunConfig {
            machine: r.machine.into_inner(),
            output_dir,
            trajectory,
            stop_at_program_end: r.stop_at_program_end,
            time_scale,
        })
    }

    fn validate_capball(&self, r: RawCapball) -> Result<CapballConfig, ConfigError> {
        let rate_hz = self.rate(
            r.rate_hz,
            DEFAULT_CB3_RATE_HZ,
            protocol::cb3::RATE_HZ,
            "CB-3",
        )?;
        let poly = match r.poly {
            None => [protocol::convert::CapBallPoly::NOMINAL.c; 3],
            Some(p) => {
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
                out
            }
        };
        let (transform, transform_file) = match r.transform {
            None => (identity4(), None),
            Some(t) => {
                let path = self.resolve(t.get_ref());
                let text = std::fs::read_to_string(&path).map_err(|e| {
                    self.err(
                        t.span(),
                        format!("transform file {} cannot be read: {e}", path.display()),
                    )
                })?;
                let m = parse_transform(&text).map_err(|m| {
                    self.err(t.span(), format!("transform file {}: {m}", path.display()))
                })?;
                (m, Some((path, text)))
            }
        };
        Ok(CapballConfig {
            driver: drivers::Cb3Config {
                port: self.port(r.port)?,
                rate_hz,
                poly,
                transform,
            },
            transform_file,
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
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSensor {
    name: Spanned<String>,
    #[serde(default)]
    location: String,
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
            port: self.port(r.port)?,
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
            out.push(drivers::TempSensor {
                name: s.name.into_inner(),
                location: s.location.trim().to_string(),
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
