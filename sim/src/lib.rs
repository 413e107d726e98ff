//! Simulated instruments of metrolog, speaking the exact wire formats of
//! `docs/instruments.md` on pseudo-terminals, driven by one [`Scenario`].
//!
//! Four devices run as tokio tasks, each behind its own pty published under a stable symlink
//! in a directory of your choice (as a udev rule would publish a real adapter):
//!
//! | [`Device`] | link | speaks |
//! |---|---|---|
//! | `Interferometer` | `<dir>/li80` | LI-80 ASCII, `$POS` / `$ENV` / `$ERR` lines |
//! | `Capball` | `<dir>/cb3` | CB-3 COBS frames |
//! | `Psd` | `<dir>/psd2` | PSD-2 SCPI and `D,` lines |
//! | `Trigger` | `<dir>/slcan` | SLCAN adapter carrying the CNC's trigger frames |
//!
//! The host opens a link like a serial port (the baud rate is ignored). Each device comes up
//! in its power-up state: not streaming, 10 Hz (the data sheet's common default, also for the
//! CB-3, whose `RATE` accepts only 100–20000), clock and sequence at the scenario's start
//! values; the host must configure it. Every byte is written by the `protocol` crate's
//! encoders; commands are parsed by its command parsers.
//!
//! # Timing
//! Each streaming device has its own clock running `clock_ppm` fast against true time. Every
//! `batch_ms` (2 ms) a device writes, in one write, all samples its clock says are due, each
//! evaluated at its own instant, so rates up to LI-80 10 kHz, CB-3 20 kHz and PSD-2 1 kHz hold
//! at once. While no host has a port open the device writes nothing (the samples are recorded
//! as [`Fate::NotConnected`]); a host that stops reading loses samples beyond 256 KiB
//! ([`Fate::Overflow`]).
//!
//! # The program
//! The CNC program (moves, dwells, trigger frames `4`, then per pose `1`, `2`, `3`, then `5`)
//! starts as the scenario says ([`ProgramStart`]): by default only when
//! [`SimHandle::start_program`] is called, so a caller can first wait until its drivers
//! stream; `on_can_open` starts it when the host opens the SLCAN channel (`O`), `after_delay`
//! on its own. [`SimHandle::program_done`] resolves after the program-end frame.
//! Timed faults (beam interruptions, unplugs) count from the program start.
//! [`SimHandle::state`] and [`SimHandle::wait_active`] tell what the devices are doing as seen
//! from the device side (plugged, host connected, streaming / CAN channel open, rate), so a
//! caller can wait until its drivers have configured everything before starting the program.
//!
//! # Faults
//! Per streaming device (probabilities per sample, optional cap): garbage bursts (one
//! rejected line or frame each), wrong checksum / CRC, truncated lines or frames, dropped
//! samples (sequence gaps), and optionally a sample's tail at the start of a reconnect. Timed:
//! LI-80 beam interruptions (`sig` < 25, `$ERR,3,beam lost`, datum lost until `DATUM`),
//! unplug/replug of any device. The CNC program can leave out chosen trigger frames.
//! [`Record`] holds every sample as generated with its [`Fate`] and exact counts
//! ([`FaultCounts`]).
//!
//! # The physics
//! See [`physics`]: machine position along an S-shaped move profile, damped ringing after each
//! exact stop, the X axis deviation from `positioning::axis_model::AxisModel` (one random draw
//! per visit, since repeatability belongs to the positioning), the LI-80's reading in air
//! (`raw = n·L20/(1 − α(T_mat − 20))`, so the host's `raw/n` and material compensation give
//! the 20 °C length back), the CapBall error from a [`CapballTruth`] (by default
//! [`scenario::CapballModel`]: metrology's CapBall model of paper 001, the same geometry the
//! identification uses) through the sensors' directions, offsets and inverse polynomials to 24-bit codes, and the PSD spot from
//! straightness polynomials to photocurrents. Slow effects run `time_scale` times faster.
//! The true values per pose are in [`Record::truth`]. A LinuxCNC comp file loaded into the X
//! axis ([`Scenario::axis_comp`], [`ScrewComp`]; `metrolog sim --apply-comp`) moves it by the
//! trim of the direction of motion, as LinuxCNC's motion does: the verification run of a
//! compensation table.
//!
//! Not modelled: the LI-80 over-speed flag (bit 2 is never set). `$ENV` lines have their own
//! sequence counter, independent of `$POS`.
//!
//! ```no_run
//! # async fn demo() -> Result<(), sim::SimError> {
//! let dir = std::path::Path::new("/tmp/metrolog-sim");
//! let sim = sim::Sim::start(sim::Scenario::demo(), dir)?;
//! let li80 = sim.port(sim::Device::Interferometer); // <dir>/li80 -> /dev/pts/N
//! // ... open the ports, configure, start streaming ...
//! sim.start_program();
//! sim.program_done().await;
//! let record = sim.record();
//! println!("{} poses, {} LI-80 samples", record.truth.len(), record.interferometer.samples.len());
//! sim.shutdown().await;
//! # Ok(()) }
//! ```

pub mod axis_comp;
mod device;
mod devices;
mod error;
mod instrument;
pub mod modbus;
pub mod physics;
mod pty;
pub mod record;
pub mod scenario;
mod shared;
mod slow;
pub mod thermal;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tokio::sync::{mpsc, watch};

pub use axis_comp::{CompFileError, ScrewComp};
pub use error::SimError;
pub use instrument::Device;
pub use physics::{CapballTruth, PoseTiming, Schedule};
pub use record::{Fate, FaultCounts, PoseTruth, Record, SentSample, SentValues, TriggerFate};
pub use scenario::{Coords, ProgramStart, Scenario, ScenarioError};
pub use shared::DeviceState;

use physics::World;
use shared::{Control, ProgramState, Shared};

/// Entry point: `Sim::start`.
pub struct Sim;

impl Sim {
    /// Start the four simulated devices with their links in `dir` (created if missing), using
    /// the scenario's default CapBall model. Must be called inside a tokio runtime.
    pub fn start(scenario: Scenario, dir: &Path) -> Result<SimHandle, SimError> {
        let truth: Arc<dyn CapballTruth> = Arc::new(physics::CachedCapballModel::new(
            scenario.capball.truth.clone(),
        ));
        Sim::start_with(scenario, dir, truth)
    }

    /// As [`Sim::start`], with another model of the CapBall's true volumetric error.
    pub fn start_with(
        scenario: Scenario,
        dir: &Path,
        capball_truth: Arc<dyn CapballTruth>,
    ) -> Result<SimHandle, SimError> {
        scenario.validate()?;
        let runtime = tokio::runtime::Handle::try_current().map_err(|_| SimError::NoRuntime)?;
        std::fs::create_dir_all(dir).map_err(|source| SimError::Dir {
            path: dir.display().to_string(),
            source,
        })?;
        let seed = scenario.seed;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let world = World::new(scenario, capball_truth, &mut rng);
        let (program, _) = watch::channel(ProgramState::default());
        let mut senders = Vec::new();
        let mut receivers = Vec::new();
        for _ in Device::ALL {
            let (tx, rx) = mpsc::channel(8);
            senders.push(tx);
            receivers.push(rx);
        }
        let shared = Arc::new(Shared {
            world,
            t0: Instant::now(),
            program,
            states: watch::channel([DeviceState::default(); 4]).0,
            record: Mutex::new(Record::default()),
            controls: senders,
            runtime: runtime.clone(),
        });
        let mut ports = Vec::new();
        let mut tasks = Vec::new();
        for (d, rx) in Device::ALL.into_iter().zip(receivers) {
            let link = dir.join(d.link_name());
            let dev_rng = ChaCha8Rng::seed_from_u64(
                seed ^ (0x9E37_79B9_7F4A_7C15u64.wrapping_mul(d.index() as u64 + 1)),
            );
            let task = devices::spawn(d, shared.clone(), link.clone(), dev_rng, rx, &runtime)?;
            ports.push(link);
            tasks.push(task);
        }
        let sc = &shared.world.scenario.program;
        if sc.start == ProgramStart::AfterDelay {
            let at = shared.t0 + Duration::from_secs_f64(sc.start_delay_s);
            shared.start_program_at(at);
        }
        Ok(SimHandle {
            shared,
            ports,
            tasks,
            dir: dir.to_path_buf(),
        })
    }
}

/// A running simulation. Dropping it aborts the devices; [`SimHandle::shutdown`] stops them in
/// order.
pub struct SimHandle {
    shared: Arc<Shared>,
    ports: Vec<PathBuf>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
    dir: PathBuf,
}

impl SimHandle {
    /// The stable path of a device's port (`<dir>/li80`, ...), a symlink to its current pts.
    pub fn port(&self, d: Device) -> PathBuf {
        self.ports[d.index()].clone()
    }

    /// The directory holding the links.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The scenario in use.
    pub fn scenario(&self) -> &Scenario {
        &self.shared.world.scenario
    }

    /// The program's schedule (real seconds after the program start).
    pub fn schedule(&self) -> &Schedule {
        &self.shared.world.schedule
    }

    /// A snapshot of everything sent so far and the truth.
    pub fn record(&self) -> Record {
        self.shared.lock_record().clone()
    }

    /// Run `f` on the record without cloning it (it is large at high rates).
    pub fn with_record<T>(&self, f: impl FnOnce(&Record) -> T) -> T {
        f(&self.shared.lock_record())
    }

    /// Unplug a device: its link disappears, the host's reads end; returns once done.
    pub async fn unplug(&self, d: Device) -> Result<(), SimError> {
        self.shared.control(d, Control::Unplug).await
    }

    /// Plug a device in again: a new pty behind the same link, in its power-up state.
    /// Returns the new `/dev/pts/N`.
    pub async fn replug(&self, d: Device) -> Result<PathBuf, SimError> {
        self.shared.control(d, Control::Replug).await?
    }

    /// What a device is doing now.
    pub fn state(&self, d: Device) -> DeviceState {
        self.shared.states.borrow()[d.index()]
    }

    /// Resolves once every device in `devices` is active: streaming, or for
    /// [`Device::Trigger`] its CAN channel open. What `metrolog demo` waits for before
    /// [`SimHandle::start_program`].
    pub async fn wait_active(&self, devices: &[Device]) {
        let mut rx = self.shared.states.subscribe();
        let _ = rx
            .wait_for(|s| devices.iter().all(|d| s[d.index()].active))
            .await;
    }

    /// Start the CNC program now (no effect if it already started).
    pub fn start_program(&self) {
        self.shared.start_program_at(Instant::now());
    }

    /// Whether the program has started.
    pub fn program_started(&self) -> bool {
        self.shared.program.borrow().started.is_some()
    }

    /// Resolves once the program has started.
    pub async fn wait_program_started(&self) {
        let mut rx = self.shared.program.subscribe();
        let _ = rx.wait_for(|p| p.started.is_some()).await;
    }

    /// Resolves once the program-end frame has been sent (or was due, when the adapter is
    /// unplugged or its channel closed).
    pub async fn program_done(&self) {
        let mut rx = self.shared.program.subscribe();
        let _ = rx.wait_for(|p| p.done).await;
    }

    /// The channels of a simulated temperature module ([`modbus::ModbusModule::start`]) on
    /// this machine: each `[thermal]` sensor's node temperature (°C), then the spindle speed
    /// (rpm, [`thermal::SPINDLE_CHANNEL`]), at the machine time of the instant the module
    /// answers (scaled from the program start; at rest before it). `None` without `[thermal]`.
    pub fn thermal_channels(&self) -> Option<modbus::Temperatures> {
        self.shared.world.thermal.as_ref()?;
        let shared = self.shared.clone();
        Some(Arc::new(move |_| {
            let w = &shared.world;
            let started = shared.program.borrow().started;
            let s = started.map_or(0.0, |st| {
                Instant::now().saturating_duration_since(st).as_secs_f64()
            });
            w.thermal
                .as_ref()
                .map_or_else(Vec::new, |t| t.channels(s * w.scenario.time_scale))
        }))
    }

    /// Real seconds the program takes from its start to the program-end frame.
    pub fn program_duration_s(&self) -> f64 {
        self.shared.world.schedule.end_s
    }

    /// Stop every device: ptys closed, links removed.
    pub async fn shutdown(mut self) {
        for d in Device::ALL {
            let _ = self.shared.control(d, Control::Shutdown).await;
        }
        for t in std::mem::take(&mut self.tasks) {
            let _ = t.await;
        }
    }
}

impl Drop for SimHandle {
    /// Without [`SimHandle::shutdown`]: abort the device tasks (closing their ptys) and remove
    /// the links.
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
        if !self.tasks.is_empty() {
            for p in &self.ports {
                let _ = std::fs::remove_file(p);
            }
        }
    }
}
