//! The scenario: what the simulated machine does and how the simulated instruments behave.
//! Read from TOML (`deny_unknown_fields` everywhere, so a misspelt key is an error, not a
//! silently ignored setting); `sim/scenarios/demo.toml` documents every key and is the built-in
//! [`Scenario::demo`].

use std::path::Path;

use geometry::capball::{CapballErrors, LinkErrors, SetupErrors};
use geometry::capball_effects::{AxisHarmonic, CapballEffect, CyclicDrift};
use positioning::axis_model::AxisModel;
use protocol::can::TriggerEvent;
use serde::{Deserialize, Serialize};

pub use crate::slow::Slow;

use crate::axis_comp::ScrewComp;
use crate::instrument::Device;

/// A complete simulation scenario.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Seed of every random draw (noise, per-visit scatter, fault placement).
    #[serde(default)]
    pub seed: u64,
    /// Slow effects (environment, drift, axis-model effects, CapBall setup drift, PSD head
    /// temperature) run this many times faster than real time, so a short demo can show hours
    /// of thermal behaviour. Their time argument is `time_scale ×` real seconds since the
    /// program started (since the simulation started, before that).
    #[serde(default = "one")]
    pub time_scale: f64,
    /// Period of sample generation, ms: every device generates, in one write, all samples its
    /// clock says are due.
    #[serde(default = "two")]
    pub batch_ms: f64,
    /// At most this many samples per device are kept in the record (a long `metrolog sim`
    /// session at 20 kHz would otherwise grow it without bound); the rest are only counted.
    #[serde(default = "record_cap")]
    pub record_max_samples: usize,
    pub program: Program,
    #[serde(default)]
    pub ringing: Ringing,
    #[serde(default)]
    pub environment: Environment,
    /// The interferometer's axis: static deviations per target and direction, noise, effects.
    pub axis: AxisModel,
    /// A compensation table loaded into the control of the X axis ([`ScrewComp`], LinuxCNC
    /// semantics): the joint moves to the commanded position plus the table's trim. Not part
    /// of the scenario file; set by `metrolog sim --apply-comp` and the demo's verification run.
    #[serde(skip)]
    pub axis_comp: Option<ScrewComp>,
    #[serde(default)]
    pub interferometer: Interferometer,
    #[serde(default)]
    pub capball: Capball,
    #[serde(default)]
    pub psd: Psd,
    #[serde(default)]
    pub trigger: TriggerAdapter,
    #[serde(default)]
    pub faults: Faults,
    /// The machine's thermal behaviour ([`crate::thermal`]): heat sources, a heat network, the
    /// displacement they cause at the measuring pose (added to what the CapBall and the PSD
    /// read) and the temperature module's channels. None: the machine stays at its start.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thermal: Option<crate::thermal::ThermalMachine>,
}

fn record_cap() -> usize {
    1_000_000
}
fn one() -> f64 {
    1.0
}
fn two() -> f64 {
    2.0
}

/// How the CNC program is started.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ProgramStart {
    /// Only by [`crate::SimHandle::start_program`] (what `metrolog demo` and tests use).
    #[default]
    Manual,
    /// When the host opens the CAN channel of the SLCAN adapter (`O`), after `start_delay_s`.
    OnCanOpen,
    /// `start_delay_s` after the simulation started.
    AfterDelay,
}

/// The CNC program: the pose table, moves and dwells, and its trigger frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Program {
    #[serde(default)]
    pub start: ProgramStart,
    /// Delay for [`ProgramStart::OnCanOpen`] and [`ProgramStart::AfterDelay`], s.
    #[serde(default)]
    pub start_delay_s: f64,
    /// Time from the program-start frame to the first motion start, s.
    #[serde(default = "lead_in")]
    pub lead_in_s: f64,
    /// Time from the last dwell end to the program-end frame, s.
    #[serde(default = "lead_in")]
    pub lead_out_s: f64,
    /// The NC clock (ms, u32, wraps) at simulation start.
    #[serde(default)]
    pub nc_clock_start_ms: u32,
    /// Where the machine stands before the program (the interferometer datum is taken here).
    #[serde(default)]
    pub home: Coords,
    /// Default move time to a pose, s.
    pub move_s: f64,
    /// Default dwell at a pose (from exact stop to dwell end), s.
    pub dwell_s: f64,
    /// The pose table; row `i` (0-based) is pose `i + 1`.
    pub poses: Vec<PoseRow>,
}

fn lead_in() -> f64 {
    0.2
}

/// Axis positions of the machine.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Coords {
    #[serde(default)]
    pub x_mm: f64,
    #[serde(default)]
    pub y_mm: f64,
    #[serde(default)]
    pub z_mm: f64,
    #[serde(default)]
    pub a_deg: f64,
    #[serde(default)]
    pub c_deg: f64,
}

/// One row of the pose table.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseRow {
    /// The pose number the trigger frames carry (default: the row's, `i + 1`). Rows may share
    /// one (a thermal run returns to its measuring pose); they must then share coordinates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose: Option<u16>,
    #[serde(default)]
    pub x_mm: f64,
    #[serde(default)]
    pub y_mm: f64,
    #[serde(default)]
    pub z_mm: f64,
    #[serde(default)]
    pub a_deg: f64,
    #[serde(default)]
    pub c_deg: f64,
    /// Move time to this pose, s (default: the program's `move_s`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub move_s: Option<f64>,
    /// Dwell at this pose, s (default: the program's `dwell_s`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dwell_s: Option<f64>,
}

impl PoseRow {
    /// The pose number of row `i` (0-based).
    pub fn number(&self, i: usize) -> u16 {
        self.pose.unwrap_or((i + 1) as u16)
    }

    pub fn coords(&self) -> Coords {
        Coords {
            x_mm: self.x_mm,
            y_mm: self.y_mm,
            z_mm: self.z_mm,
            a_deg: self.a_deg,
            c_deg: self.c_deg,
        }
    }
}

/// The vibration after an exact stop: `A·e^(−t/τ)·sin(2πft)`, added to every instrument's
/// reading (scaled per instrument) from the exact stop on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ringing {
    pub amplitude_um: f64,
    pub frequency_hz: f64,
    pub decay_s: f64,
}

impl Default for Ringing {
    fn default() -> Self {
        Ringing {
            amplitude_um: 2.0,
            frequency_hz: 35.0,
            decay_s: 0.02,
        }
    }
}

impl Ringing {
    /// Time after the exact stop after which the ringing is below 1 nm (or 5 τ), s.
    pub fn settle_s(&self) -> f64 {
        let by_amp = if self.amplitude_um > 1e-3 {
            self.decay_s * (self.amplitude_um / 1e-3).ln()
        } else {
            0.0
        };
        by_amp.max(5.0 * self.decay_s)
    }
}

/// Air and material conditions around the machine.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Environment {
    pub air_c: Slow,
    pub air_pa: Slow,
    pub rh_pct: Slow,
    /// One to three material sensors, °C.
    pub material_c: Vec<Slow>,
}

impl Default for Environment {
    fn default() -> Self {
        Environment {
            air_c: Slow::constant(20.0),
            air_pa: Slow::constant(101_325.0),
            rh_pct: Slow::constant(50.0),
            material_c: vec![Slow::constant(20.0)],
        }
    }
}

/// Identity and clock of a device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Identity {
    pub serial: String,
    pub firmware: String,
    /// The device clock runs fast by this much against true time, ppm (negative: slow).
    #[serde(default)]
    pub clock_ppm: f64,
    /// Device clock at power-up, µs (to exercise wraps of `t_us`).
    #[serde(default)]
    pub clock_start_us: u64,
    /// First sequence number after power-up (to exercise wraps of `seq`).
    #[serde(default)]
    pub seq_start: u64,
}

impl Identity {
    fn new(serial: &str, firmware: &str, clock_ppm: f64) -> Identity {
        Identity {
            serial: serial.into(),
            firmware: firmware.into(),
            clock_ppm,
            clock_start_us: 0,
            seq_start: 0,
        }
    }
}

/// The LI-80 laser interferometer on the X axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Interferometer {
    pub identity: Identity,
    /// Expansion coefficient of the measured axis, µm/(m·K).
    pub alpha_um_per_m_k: f64,
    /// White noise of every reading, nm (on top of the axis model's per-visit scatter).
    pub sample_noise_nm: f64,
    /// Signal strength while the beam is fine, %.
    pub sig_pct: u8,
    /// Scale of the ringing seen on this axis (1 = the scenario's amplitude).
    pub ringing_gain: f64,
}

impl Default for Interferometer {
    fn default() -> Self {
        Interferometer {
            identity: Identity::new("LI80-SIM-0001", "2.4.1", 35.0),
            alpha_um_per_m_k: 11.7,
            sample_noise_nm: 15.0,
            sig_pct: 86,
            ringing_gain: 1.0,
        }
    }
}

/// The CB-3 CapBall: sensors, polynomials, and the machine's true volumetric error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Capball {
    pub identity: Identity,
    /// Measuring direction of each sensor in the machine frame (rows, normalised on use):
    /// sensor `i` sees `d_i = n_i · e + zero_offset_um[i]`.
    pub sensor_directions: [[f64; 3]; 3],
    /// Sensor reading at zero error (setup offset), µm.
    pub zero_offset_um: [f64; 3],
    /// Per channel `d = c1·V + c2·V² + c3·V³` (µm), the sensor's pre-calibration polynomial.
    pub poly: [[f64; 3]; 3],
    /// White noise per channel, µm.
    pub noise_um: f64,
    /// Scale of the ringing seen by the CapBall (1 = the scenario's amplitude).
    pub ringing_gain: f64,
    /// The default volumetric-error model (used unless a [`crate::CapballTruth`] is given).
    pub truth: CapballModel,
}

impl Default for Capball {
    fn default() -> Self {
        // Three sensors at 120° around the ball, tilted 35.26° from the horizontal: the
        // layout of a CapBall nest, so every sensor sees all three error components.
        let s = 1.0 / 3f64.sqrt();
        let h = (2.0f64 / 3.0).sqrt();
        let dirs = [
            [h, 0.0, s],
            [-0.5 * h, 0.75f64.sqrt() * h, s],
            [-0.5 * h, -(0.75f64.sqrt()) * h, s],
        ];
        Capball {
            identity: Identity::new("CB3-SIM-0042", "1.7.0", -42.0),
            sensor_directions: dirs,
            zero_offset_um: [3.0, -2.0, 1.5],
            poly: [
                [10.0, 0.02, -0.001],
                [10.0, -0.015, 0.0],
                [10.0, 0.01, 0.0005],
            ],
            noise_um: 0.02,
            ringing_gain: 0.5,
            truth: CapballModel::default(),
        }
    }
}

/// The machine's true CapBall errors, in the parameters of [`geometry::capball`] (paper 001):
/// the eight link errors and six setup errors of its `WCAYFXZT` machine
/// ([`geometry::capball::CapballSetup::paper_default`]: A about X and C about Z through the
/// origin, ball at (120, 80, 100) mm on the table), by their names there, plus an optional
/// drift of the measuring loop. The simulator evaluates the analysis's own forward model
/// ([`geometry::capball::forward_um`] geometry), so simulation and identification share one
/// geometry: `metrolog identify capball` on the per-pose truth of poses that hold the tool on
/// the ball recovers these 14 values (without drift).
///
/// Sign conventions are those of [`geometry::kinematics`]: errors of the relative motion of
/// the tool against the workpiece; the volumetric error is `p_tool − p_ball` in the machine
/// frame, µm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapballModel {
    /// The eight link errors, by their names in [`geometry::capball::LinkErrors`] (µrad; `ey0c_um` µm).
    #[serde(flatten)]
    pub link: LinkErrors,
    /// The six setup errors: ball centre (actual − nominal, table frame) and tool point
    /// (actual − nominal, spindle frame), µm ([`geometry::capball::SetupErrors`]).
    #[serde(flatten)]
    pub setup: SetupErrors,
    /// Linear drift of the measuring loop (e.g. spindle growth), µm per (scaled) hour, machine
    /// frame. Not one of the 14 parameters: a non-zero drift biases the identification as it
    /// would on a real machine. Default 0.
    #[serde(default)]
    pub drift_um_per_h: [f64; 3],
    /// Periodic drift of the measuring loop (paper 001: the spindle's cooling cycle), machine
    /// frame, a function of (scaled) time. Not one of the 14 parameters. Default none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cyclic_drift: Option<CyclicDrift>,
    /// Gain error of the reading along machine x, y, z, percent (`docs/datasets.md`,
    /// `sensor_gain`): the error the CapBall reports is `(1 + g/100)` times the true one.
    #[serde(default)]
    pub gain_pct: [f64; 3],
    /// Motion errors of the A and C axes the link-error model lacks (harmonics of the angle).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub axis_errors: Vec<AxisHarmonic>,
    /// Scatter of the measuring loop from one pose visit to the next (what a dwell's steady
    /// value does not average out: real CapBalls show 0.1–0.4 µm), µm, per machine direction.
    /// Default 0.
    #[serde(default)]
    pub pose_noise_um: f64,
}

impl CapballModel {
    /// The 14 parameters as metrology's types.
    pub fn errors(&self) -> CapballErrors {
        CapballErrors {
            link: self.link,
            setup: self.setup,
        }
    }

    /// A model from metrology's parameters, without drift.
    pub fn from_errors(e: &CapballErrors) -> Self {
        CapballModel {
            link: e.link,
            setup: e.setup,
            ..Self::zero_effects()
        }
    }

    /// The model a CapBall diagnosis found (`metrolog diagnose --write-model`): the 14
    /// parameters identified with the effects modelled, plus the effects as this scenario
    /// section takes them; times are those of the diagnosed dataset's clock.
    pub fn from_diagnosis(d: &diagnose::capball::CapballDiagnosis) -> Self {
        let mut m = Self::from_errors(&CapballErrors::from_slice(&d.params_extended));
        for e in d.report.findings.iter().filter_map(|f| f.effect.effect()) {
            m.add_effect(e);
        }
        // The white noise the diagnosis measured on the identification run becomes the
        // per-visit scatter.
        if let Some(r) = d.report.residuals.first() {
            m.pose_noise_um = (r.noise_um.iter().map(|v| v * v).sum::<f64>() / 3.0).sqrt();
        }
        m
    }

    /// Adds an effect to the model (an effect of a kind it holds once replaces it).
    pub fn add_effect(&mut self, e: &CapballEffect) {
        match *e {
            CapballEffect::LinearDrift { rate_um_per_h } => self.drift_um_per_h = rate_um_per_h,
            CapballEffect::CyclicDrift(c) => self.cyclic_drift = Some(c),
            CapballEffect::SensorGain { channel, gain_pct } => {
                self.gain_pct[channel.index()] = gain_pct
            }
            CapballEffect::AxisError(h) => self.axis_errors.push(h),
        }
    }

    /// All 14 parameters zero and no effects (a base for struct updates).
    pub fn zero_effects() -> Self {
        CapballModel {
            link: LinkErrors::default(),
            setup: SetupErrors::default(),
            drift_um_per_h: [0.0; 3],
            cyclic_drift: None,
            gain_pct: [0.0; 3],
            axis_errors: Vec::new(),
            pose_noise_um: 0.0,
        }
    }
}

impl Default for CapballModel {
    fn default() -> Self {
        CapballModel {
            link: LinkErrors {
                ec0y_urad: 12.0,
                eb0z_urad: -18.0,
                ea0z_urad: 9.0,
                eb0a_urad: 25.0,
                ec0a_urad: -15.0,
                ea0c_urad: 20.0,
                eb0c_urad: -15.0,
                ey0c_um: 4.0,
            },
            setup: SetupErrors {
                ball_x_um: 3.0,
                ball_y_um: -2.0,
                ball_z_um: 1.5,
                tool_x_um: -1.5,
                tool_y_um: 2.5,
                tool_z_um: 4.0,
            },
            ..Self::zero_effects()
        }
    }
}

/// The PSD-2 board: a beam along one axis, straightness of the machine seen as spot motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Psd {
    pub identity: Identity,
    /// The axis the beam is parallel to: the coordinate `u` of the straightness polynomials.
    pub along: Axis,
    /// Spot x = Σ `straightness_x_um[k]`·(u/100 mm)^k, µm.
    pub straightness_x_um: Vec<f64>,
    /// Spot y = Σ `straightness_y_um[k]`·(u/100 mm)^k, µm.
    pub straightness_y_um: Vec<f64>,
    /// White noise of the spot position, µm.
    pub noise_um: f64,
    /// Summed photocurrent `x1 + x2` (and `y1 + y2`), pA.
    pub sum_pa: f64,
    /// Measuring-head temperature, °C.
    pub head_c: Slow,
    /// Scale of the ringing seen by the PSD (1 = the scenario's amplitude).
    pub ringing_gain: f64,
}

impl Default for Psd {
    fn default() -> Self {
        Psd {
            identity: Identity::new("PSD2-SIM-0007", "3.1.2", 20.0),
            along: Axis::Z,
            straightness_x_um: vec![12.0, 1.5, -0.8],
            straightness_y_um: vec![-5.0, -0.6, 0.4],
            noise_um: 0.05,
            sum_pa: 1.2e6,
            head_c: Slow {
                mean: 21.5,
                amplitude: 0.2,
                period_s: 1800.0,
                phase_rad: 0.0,
                drift_per_h: 0.1,
            },
            ringing_gain: 0.7,
        }
    }
}

/// A linear machine axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Axis {
    X,
    Y,
    Z,
}

/// The SLCAN adapter delivering the CNC's trigger frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriggerAdapter {
    /// CAN identifier of the trigger frames.
    pub can_id: u32,
    /// Answer to `V` (without the `V` and `\r`).
    pub version: String,
    /// Answer to `N` (without the `N` and `\r`).
    pub serial: String,
    /// Drift of the adapter's millisecond timestamp clock, ppm.
    pub clock_ppm: f64,
}

impl Default for TriggerAdapter {
    fn default() -> Self {
        TriggerAdapter {
            can_id: protocol::can::DEFAULT_CAN_ID,
            version: "1013".into(),
            serial: "SIM1".into(),
            clock_ppm: 10.0,
        }
    }
}

/// Injected faults. Rates are probabilities per sample (each sample gets at most one fault);
/// timed faults are at `at_s` real seconds after the program start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Faults {
    #[serde(default)]
    pub interferometer: StreamFaults,
    #[serde(default)]
    pub capball: StreamFaults,
    #[serde(default)]
    pub psd: StreamFaults,
    /// Beam interruptions of the interferometer: `sig` < 25 and `$ERR,3,beam lost`; the datum
    /// is lost (flag bit 1) until the host sends `DATUM`.
    #[serde(default)]
    pub beam_interruptions: Vec<Timed>,
    /// Unplug a device at `at_s` and plug it in again `duration_s` later.
    #[serde(default)]
    pub unplugs: Vec<Unplug>,
    /// Trigger frames the CNC does not send.
    #[serde(default)]
    pub missing_triggers: Vec<MissingTrigger>,
}

/// Per-sample faults of a streaming device.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct StreamFaults {
    /// A burst of garbage (one rejected line or frame) before the sample.
    #[serde(default)]
    pub garbage_rate: f64,
    /// The sample sent with a wrong checksum (LI-80) or CRC (CB-3); ignored for the PSD-2,
    /// whose lines carry no checksum.
    #[serde(default)]
    pub bad_checksum_rate: f64,
    /// The sample's line or frame cut short (and terminated).
    #[serde(default)]
    pub truncated_rate: f64,
    /// The sample not sent at all: a sequence gap.
    #[serde(default)]
    pub drop_rate: f64,
    /// At most this many of each fault kind (0 = unlimited).
    #[serde(default)]
    pub max_each: u64,
    /// When a host opens the port while the device streams, its first bytes are the tail of
    /// a sample it missed ("a device may start mid-frame when the port opens").
    #[serde(default)]
    pub mid_frame_on_open: bool,
}

/// A timed interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Timed {
    pub at_s: f64,
    pub duration_s: f64,
}

/// An unplug of one device.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Unplug {
    pub device: Device,
    pub at_s: f64,
    pub duration_s: f64,
}

/// A trigger frame left out of the CNC program.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissingTrigger {
    /// Pose index (1-based; 0 for program start and end).
    pub pose: u16,
    pub event: TriggerEvent,
}

/// Why a scenario cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// cannot read scenario file {path}: {source}
    #[error("cannot read scenario file {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    /// scenario is not valid TOML for metrolog-sim: {0}
    #[error("scenario is not valid TOML for metrolog-sim: {0}")]
    Parse(#[from] toml::de::Error),
    /// scenario value out of range: {0}
    #[error("scenario value out of range: {0}")]
    Invalid(String),
}

const DEMO_TOML: &str = include_str!("../scenarios/demo.toml");

impl Scenario {
    /// The built-in demo: `sim/scenarios/demo.toml`.
    pub fn demo() -> Scenario {
        // The file is part of the crate and checked by a unit test, so it always parses.
        match Scenario::from_toml(DEMO_TOML) {
            Ok(s) => s,
            Err(e) => panic!("built-in demo scenario is invalid: {e}"),
        }
    }

    /// Parse and validate a scenario.
    pub fn from_toml(text: &str) -> Result<Scenario, ScenarioError> {
        let s: Scenario = toml::from_str(text)?;
        s.validate()?;
        Ok(s)
    }

    /// Read, parse and validate a scenario file.
    pub fn load(path: &Path) -> Result<Scenario, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Scenario::from_toml(&text)
    }

    /// Serialise back to TOML.
    pub fn to_toml(&self) -> Result<String, toml::ser::Error> {
        toml::to_string(self)
    }

    /// The CapBall effects of `[capball.truth]`: finite, periods > 0, harmonics ≥ 1 (serde reads
    /// the axes, A or C).
    fn validate_capball_effects(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        let t = &self.capball.truth;
        if let Some(c) = &t.cyclic_drift {
            if !(c.period_s.is_finite() && c.period_s > 0.0) {
                return bad("capball.truth.cyclic_drift.period_s must be > 0 (seconds)".into());
            }
            if c.amplitude_um
                .iter()
                .chain(&c.phase_rad)
                .any(|v| !v.is_finite())
            {
                return bad(
                    "capball.truth.cyclic_drift: amplitude_um and phase_rad must be finite numbers"
                        .into(),
                );
            }
        }
        if t.gain_pct
            .iter()
            .any(|g| !(g.is_finite() && g.abs() < 50.0))
        {
            return bad("capball.truth.gain_pct must be finite percentages below 50".into());
        }
        if !(t.pose_noise_um.is_finite() && t.pose_noise_um >= 0.0) {
            return bad("capball.truth.pose_noise_um must be ≥ 0".into());
        }
        for (i, h) in t.axis_errors.iter().enumerate() {
            if h.harmonic == 0 {
                return bad(format!(
                    "capball.truth.axis_errors[{i}]: harmonic must be ≥ 1"
                ));
            }
            if h.cos_um.iter().chain(&h.sin_um).any(|v| !v.is_finite()) {
                return bad(format!(
                    "capball.truth.axis_errors[{i}]: cos_um and sin_um must be finite"
                ));
            }
        }
        Ok(())
    }

    /// Check every value a device or the physics relies on.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        if !finite_pos(self.time_scale) {
            return bad(format!("time_scale must be > 0, got {}", self.time_scale));
        }
        if !(0.2..=100.0).contains(&self.batch_ms) {
            return bad(format!(
                "batch_ms must be within 0.2..=100, got {}",
                self.batch_ms
            ));
        }
        self.validate_program()?;
        self.validate_axis_and_environment()?;
        self.validate_devices()?;
        self.validate_capball_truth()?;
        self.validate_capball_effects()?;
        if !finite_pos(self.psd.sum_pa) {
            return bad("psd.sum_pa must be > 0".into());
        }
        if let Some(t) = &self.thermal {
            t.check().map_err(ScenarioError::Invalid)?;
        }
        self.validate_faults()
    }

    /// The pose table and the program's times.
    fn validate_program(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        let p = &self.program;
        if p.poses.is_empty() {
            return bad("program.poses is empty: give at least one pose".into());
        }
        if p.poses.len() > u16::MAX as usize {
            return bad(format!(
                "program.poses has {} rows, at most 65535 fit a trigger frame",
                p.poses.len()
            ));
        }
        for (what, v) in [
            ("program.move_s", p.move_s),
            ("program.dwell_s", p.dwell_s),
            ("program.lead_in_s", p.lead_in_s),
            ("program.lead_out_s", p.lead_out_s),
            ("program.start_delay_s", p.start_delay_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{what} must be a finite number ≥ 0, got {v}"));
            }
        }
        for (i, r) in p.poses.iter().enumerate() {
            for v in [r.move_s, r.dwell_s].into_iter().flatten() {
                if !(v.is_finite() && v >= 0.0) {
                    return bad(format!(
                        "pose {}: move_s/dwell_s must be ≥ 0, got {v}",
                        i + 1
                    ));
                }
            }
            for v in [r.x_mm, r.y_mm, r.z_mm, r.a_deg, r.c_deg] {
                if !v.is_finite() {
                    return bad(format!("pose {}: coordinates must be finite", i + 1));
                }
            }
            let n = r.number(i);
            if n == 0 {
                return bad(format!("row {}: pose number 0 is the program's", i + 1));
            }
            let first = p.poses.iter().enumerate().find(|(j, q)| q.number(*j) == n);
            if first.is_some_and(|(_, q)| q.coords() != r.coords()) {
                return bad(format!(
                    "row {}: pose {n} is given again at other coordinates",
                    i + 1
                ));
            }
        }
        Ok(())
    }

    /// Ringing, material sensors and the axis model.
    fn validate_axis_and_environment(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        if !(finite_pos(self.ringing.decay_s) && self.ringing.frequency_hz >= 0.0) {
            return bad("ringing.decay_s must be > 0 and ringing.frequency_hz ≥ 0".into());
        }
        let n_mat = self.environment.material_c.len();
        if !(1..=3).contains(&n_mat) {
            return bad(format!(
                "environment.material_c must have 1 to 3 sensors, got {n_mat}"
            ));
        }
        let a = &self.axis;
        if a.targets_mm.is_empty()
            || a.systematic_up_um.len() != a.targets_mm.len()
            || a.systematic_down_um.len() != a.targets_mm.len()
        {
            return bad("axis: targets_mm, systematic_up_um and systematic_down_um must be non-empty and of equal length".into());
        }
        if !(a.noise_um.is_finite() && a.noise_um >= 0.0) {
            return bad("axis.noise_um must be ≥ 0".into());
        }
        Ok(())
    }

    /// Identities, CapBall sensor directions and polynomials.
    fn validate_devices(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        for (name, id) in [
            ("interferometer", &self.interferometer.identity),
            ("capball", &self.capball.identity),
            ("psd", &self.psd.identity),
        ] {
            if !(id.clock_ppm.is_finite() && id.clock_ppm.abs() < 10_000.0) {
                return bad(format!(
                    "{name}.identity.clock_ppm must be within ±10000, got {}",
                    id.clock_ppm
                ));
            }
            if id.serial.contains([',', '\n', '\r']) || id.firmware.contains([',', '\n', '\r']) {
                return bad(format!(
                    "{name}.identity: serial and firmware must not contain commas or line ends"
                ));
            }
        }
        // A noise that is not a finite number ≥ 0 used to turn silently into no noise at all.
        for (what, v) in [
            (
                "interferometer.sample_noise_nm",
                self.interferometer.sample_noise_nm,
            ),
            ("capball.noise_um", self.capball.noise_um),
            ("psd.noise_um", self.psd.noise_um),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{what} must be a finite number ≥ 0, got {v}"));
            }
        }
        for (i, dir) in self.capball.sensor_directions.iter().enumerate() {
            let n = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
            if !finite_pos(n) {
                return bad(format!(
                    "capball.sensor_directions[{i}] must be a non-zero vector"
                ));
            }
        }
        for (i, c) in self.capball.poly.iter().enumerate() {
            if !finite_pos(c[0]) {
                return bad(format!(
                    "capball.poly[{i}]: c1 must be > 0 µm/V, got {}",
                    c[0]
                ));
            }
        }
        Ok(())
    }

    /// The CapBall's 14 parameters and its linear drift.
    fn validate_capball_truth(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        let truth = self.capball.truth.errors().to_vector();
        for (name, v) in geometry::capball::PARAM_NAMES.iter().zip(truth) {
            // The sensors read ±100 µm: errors beyond a millimetre are a typo (mm for µm).
            if !(v.is_finite() && v.abs() <= 1000.0) {
                return bad(format!(
                    "capball.truth.{}: {v} is not a plausible error (finite, |value| ≤ 1000)",
                    name.to_lowercase()
                ));
            }
        }
        if self
            .capball
            .truth
            .drift_um_per_h
            .iter()
            .any(|v| !v.is_finite())
        {
            return bad("capball.truth.drift_um_per_h must be finite numbers".into());
        }
        Ok(())
    }

    /// Fault rates, unplugs and beam interruptions.
    fn validate_faults(&self) -> Result<(), ScenarioError> {
        let bad = |m: String| Err(ScenarioError::Invalid(m));
        for (name, f) in [
            ("interferometer", &self.faults.interferometer),
            ("capball", &self.faults.capball),
            ("psd", &self.faults.psd),
        ] {
            let total = f.garbage_rate + f.bad_checksum_rate + f.truncated_rate + f.drop_rate;
            for v in [
                f.garbage_rate,
                f.bad_checksum_rate,
                f.truncated_rate,
                f.drop_rate,
            ] {
                if !(0.0..=1.0).contains(&v) {
                    return bad(format!(
                        "faults.{name}: rates are probabilities in 0..=1, got {v}"
                    ));
                }
            }
            if total > 1.0 {
                return bad(format!("faults.{name}: the rates add up to {total} > 1"));
            }
        }
        for u in &self.faults.unplugs {
            if !(u.at_s >= 0.0 && u.duration_s >= 0.0) {
                return bad("faults.unplugs: at_s and duration_s must be ≥ 0".into());
            }
        }
        for b in &self.faults.beam_interruptions {
            if !(b.at_s >= 0.0 && b.duration_s > 0.0) {
                return bad("faults.beam_interruptions: at_s ≥ 0 and duration_s > 0".into());
            }
        }
        Ok(())
    }

    /// The pose table as the CSV the daemon is configured with (`pose,x_mm,y_mm,z_mm,a_deg,c_deg`).
    pub fn trajectory_csv(&self) -> String {
        let mut s = String::from("pose,x_mm,y_mm,z_mm,a_deg,c_deg\n");
        let mut seen = std::collections::BTreeSet::new();
        for (i, r) in self.program.poses.iter().enumerate() {
            if !seen.insert(r.number(i)) {
                continue;
            }
            s.push_str(&format!(
                "{},{},{},{},{},{}\n",
                r.number(i),
                r.x_mm,
                r.y_mm,
                r.z_mm,
                r.a_deg,
                r.c_deg
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demo_parses_and_round_trips() {
        let d = Scenario::demo();
        assert_eq!(d.program.poses.len(), 129);
        let text = d.to_toml().expect("serialise");
        assert_eq!(Scenario::from_toml(&text).expect("parse back"), d);
    }

    #[test]
    fn demo_fits_the_time_budget_and_dwells_hold_150_samples_at_1_khz() {
        let d = Scenario::demo();
        let total = d.program_duration_s();
        // The CapBall's identification and validation runs hold 2.4 of its cooling cycles.
        assert!(total < 65.0, "demo program takes {total} s");
        let settle = d.ringing.settle_s();
        // Ringing 2 µm decaying with τ = 20 ms is below 1 nm after τ·ln(2000) = 0.152 s.
        assert!((settle - 0.02 * 2000f64.ln()).abs() < 1e-12);
        for (i, p) in d.program.poses.iter().enumerate() {
            let dwell = p.dwell_s.unwrap_or(d.program.dwell_s);
            // Reversal points are not measured (dwell 0); every other pose holds 150 samples.
            assert!(
                dwell == 0.0 || dwell >= settle + 0.150,
                "pose {}: dwell {dwell}",
                i + 1
            );
        }
    }

    #[test]
    fn unknown_keys_are_errors() {
        let text = DEMO_TOML.replace("batch_ms = 2.0", "batch_ms = 2.0\nbatchms = 3.0");
        let e = Scenario::from_toml(&text).expect_err("unknown key");
        assert!(e.to_string().contains("batchms"), "{e}");
        let text = DEMO_TOML.replace(
            "sample_noise_nm = 15.0",
            "sample_noise_nm = 15.0\nnoise = 1.0",
        );
        assert!(Scenario::from_toml(&text).is_err());
        // The 14 CapBall parameters are read into geometry's types: a misspelt one is an
        // error too, and one left out is.
        let text = DEMO_TOML.replace("ey0c_um = 4.0", "ey0c_mu = 4.0");
        let e = Scenario::from_toml(&text).expect_err("misspelt CapBall parameter");
        assert!(e.to_string().contains("ey0c"), "{e}");
    }

    #[test]
    fn out_of_range_values_are_explained() {
        let mut s = Scenario::demo();
        s.environment.material_c.clear();
        let e = s.validate().expect_err("no material sensor");
        assert!(e.to_string().contains("material_c"), "{e}");
        let mut s = Scenario::demo();
        s.faults.psd.drop_rate = 1.5;
        assert!(s.validate().is_err());
        let mut s = Scenario::demo();
        s.axis.systematic_up_um.pop();
        assert!(s.validate().is_err());
        let mut s = Scenario::demo();
        s.program.poses.clear();
        assert!(s.validate().unwrap_err().to_string().contains("poses"));
        let mut s = Scenario::demo();
        s.capball.truth.link.ey0c_um = 4000.0;
        assert!(s.validate().unwrap_err().to_string().contains("ey0c_um"));
        let mut s = Scenario::demo();
        s.capball.truth.drift_um_per_h[1] = f64::NAN;
        assert!(s.validate().is_err());
        let mut s = Scenario::demo();
        s.psd.noise_um = f64::INFINITY;
        let e = s.validate().expect_err("infinite noise");
        assert!(e.to_string().contains("psd.noise_um"), "{e}");
        let mut s = Scenario::demo();
        s.interferometer.sample_noise_nm = -1.0;
        assert!(s.validate().is_err());
    }

    #[test]
    fn trajectory_csv_has_one_row_per_pose() {
        let d = Scenario::demo();
        let csv = d.trajectory_csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], "pose,x_mm,y_mm,z_mm,a_deg,c_deg");
        assert_eq!(lines.len(), 130);
        assert_eq!(lines[1], "1,2.312,0,0,0,0");
        assert!(lines[129].starts_with("129,200,0,400,"));
    }

    #[test]
    fn slow_quantity() {
        let s = Slow {
            mean: 20.0,
            amplitude: 0.5,
            period_s: 100.0,
            phase_rad: 0.0,
            drift_per_h: 3.6,
        };
        assert!((s.at(25.0) - (20.0 + 0.025 + 0.5)).abs() < 1e-12);
    }
}
