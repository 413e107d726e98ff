//! The task that runs one simulated device: its pseudo-terminal, power state, clock, the
//! command lines it receives and the batches of samples it writes.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use tokio::sync::mpsc;

use crate::error::SimError;
use crate::instrument::Device;
use crate::pty::{Pty, ReadOutcome};
use crate::record::{Fate, FaultCounts};
use crate::scenario::StreamFaults;
use crate::shared::{Control, DeviceState, Shared};

/// Default rate of every streaming device after power-up (instruments.md, common rules).
pub(crate) const POWER_UP_RATE_HZ: f64 = 10.0;

/// Pending output beyond this is discarded (the host is not reading): about 0.5 s of the
/// fastest stream.
pub(crate) const OUTPUT_CAP: usize = 256 * 1024;
/// Longest command line kept; longer input is discarded up to the next terminator.
const MAX_COMMAND: usize = 256;

/// A device's free-running clock: restarts at power-up, runs `ppm` fast against true time.
#[derive(Debug, Clone, Copy)]
pub(crate) struct DeviceClock {
    pub power_up: Instant,
    pub ppm: f64,
    pub start_us: u64,
}

impl DeviceClock {
    fn rate(&self) -> f64 {
        1.0 + self.ppm * 1e-6
    }
    /// Device time (µs, fractional) at a true instant.
    pub fn dev_us(&self, at: Instant) -> f64 {
        self.start_us as f64
            + at.saturating_duration_since(self.power_up).as_secs_f64() * self.rate() * 1e6
    }
    /// True instant of a device time.
    pub fn instant(&self, dev_us: f64) -> Instant {
        let s = ((dev_us - self.start_us as f64) / (self.rate() * 1e6)).max(0.0);
        self.power_up + Duration::from_secs_f64(s)
    }
}

/// Samples due at a fixed rate from an anchor in device time.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cadence {
    pub rate_hz: f64,
    anchor_us: f64,
    k: u64,
}

impl Cadence {
    pub fn new(rate_hz: f64, anchor_us: f64) -> Cadence {
        Cadence {
            rate_hz,
            anchor_us,
            k: 0,
        }
    }
    /// Device time of the next sample.
    pub fn next_us(&self) -> f64 {
        self.anchor_us + self.k as f64 * 1e6 / self.rate_hz
    }
    /// Take the next sample time if it is due by `now_us`.
    pub fn take_due(&mut self, now_us: f64) -> Option<f64> {
        let t = self.next_us();
        if t <= now_us {
            self.k += 1;
            Some(t)
        } else {
            None
        }
    }
}

/// A per-sample fault drawn for one sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Fault {
    None,
    Garbage,
    BadChecksum,
    Truncated,
    Dropped,
}

/// Draws the per-sample faults of a streaming device and keeps their caps.
#[derive(Debug, Clone)]
pub(crate) struct FaultDice {
    cfg: StreamFaults,
    drawn: [u64; 4],
}

impl FaultDice {
    pub fn new(cfg: StreamFaults) -> FaultDice {
        FaultDice { cfg, drawn: [0; 4] }
    }
    pub fn roll(&mut self, rng: &mut ChaCha8Rng, checksum_possible: bool) -> Fault {
        let c = &self.cfg;
        let total = c.garbage_rate + c.bad_checksum_rate + c.truncated_rate + c.drop_rate;
        if total <= 0.0 {
            return Fault::None;
        }
        let u: f64 = rng.random();
        let (kind, slot) = if u < c.garbage_rate {
            (Fault::Garbage, 0)
        } else if u < c.garbage_rate + c.bad_checksum_rate {
            (Fault::BadChecksum, 1)
        } else if u < c.garbage_rate + c.bad_checksum_rate + c.truncated_rate {
            (Fault::Truncated, 2)
        } else if u < total {
            (Fault::Dropped, 3)
        } else {
            return Fault::None;
        };
        if kind == Fault::BadChecksum && !checksum_possible {
            return Fault::None;
        }
        if c.max_each > 0 && self.drawn[slot] >= c.max_each {
            return Fault::None;
        }
        self.drawn[slot] += 1;
        kind
    }
}

/// What a model sees and writes into during one step.
pub(crate) struct Ctx<'a> {
    pub shared: &'a Arc<Shared>,
    pub rng: &'a mut ChaCha8Rng,
    pub clock: DeviceClock,
    pub now: Instant,
    /// Output of this step, appended to the device's pending bytes.
    pub out: &'a mut Vec<u8>,
    /// Bytes already waiting for the host before this step.
    pub pending: usize,
    /// A host has the port open.
    pub connected: bool,
    /// Power-up count (1-based).
    pub power_up: u32,
    /// Counters to add to the record after the step.
    pub faults: &'a mut FaultCounts,
    pub device: Device,
    /// Keep the encoding of the last sample generated while no host was connected
    /// (`mid_frame_on_open`).
    pub keep_unsent: bool,
    pub unsent: &'a mut Vec<u8>,
}

impl Ctx<'_> {
    /// The fate of a sample about to be written without an injected fault, by the link's state.
    pub fn link_fate(&self) -> Option<Fate> {
        if !self.connected {
            Some(Fate::NotConnected)
        } else if self.pending + self.out.len() > OUTPUT_CAP {
            Some(Fate::Overflow)
        } else {
            None
        }
    }
    /// Append generated samples to this device's record, up to the scenario's cap.
    pub fn record_samples(&mut self, samples: Vec<crate::record::SentSample>) {
        let cap = self.shared.world.scenario.record_max_samples;
        let dev = self.device;
        let mut rec = self.shared.lock_record();
        let r = rec.device_mut(dev);
        let room = cap.saturating_sub(r.samples.len());
        let n = samples.len();
        r.samples.extend(samples.into_iter().take(room));
        r.unrecorded += n.saturating_sub(room) as u64;
    }

    /// Real seconds since simulation start of a true instant.
    pub fn sim_s(&self, at: Instant) -> f64 {
        at.saturating_duration_since(self.shared.t0).as_secs_f64()
    }
    /// Real seconds since the program start of a true instant (`None`: not started).
    pub fn program_s(&self, at: Instant) -> Option<f64> {
        let started = self.shared.program.borrow().started?;
        Some(if at >= started {
            at.duration_since(started).as_secs_f64()
        } else {
            -started.duration_since(at).as_secs_f64()
        })
    }
    /// Scaled time of slow effects at a true instant (0 until the program starts).
    pub fn slow_t(&self, at: Instant) -> f64 {
        self.program_s(at).unwrap_or(0.0).max(0.0) * self.shared.world.scenario.time_scale
    }
}

/// A simulated device's behaviour; the runtime does the I/O.
pub(crate) trait Model: Send + 'static {
    const DEVICE: Device;
    /// Reset to the power-up state.
    fn power_up(&mut self, ctx: &mut Ctx);
    /// One command line from the host (terminator stripped).
    fn command(&mut self, line: &str, ctx: &mut Ctx);
    /// Generate what is due by `ctx.now`.
    fn tick(&mut self, ctx: &mut Ctx);
    /// Also called while unplugged, so time-driven state (a beam interruption, the CNC's
    /// trigger events) advances without a port.
    fn tick_unplugged(&mut self, _ctx: &mut Ctx) {}
    /// Streaming (the SLCAN adapter: channel open), and at what rate.
    fn activity(&self) -> (bool, u32);
    /// Bytes ending a command line.
    fn is_terminator(b: u8) -> bool {
        b == b'\n'
    }
}

enum Ev {
    Ctl(Option<Control>),
    Tick,
    Readable(bool),
}

pub(crate) struct Runner<M: Model> {
    model: M,
    shared: Arc<Shared>,
    link: PathBuf,
    rng: ChaCha8Rng,
    pty: Option<Pty>,
    clock: DeviceClock,
    connected: bool,
    pending: Vec<u8>,
    line: Vec<u8>,
    discarding: bool,
    power_up: u32,
    /// Wait for the host's bytes through the reactor (else: only on the batch timer).
    readable_ok: bool,
    /// Consecutive reactor wake-ups that brought no data.
    spurious: u32,
    mid_frame_on_open: bool,
    /// The last sample generated while no host was connected, encoded.
    unsent: Vec<u8>,
}

impl<M: Model> Runner<M> {
    pub fn new(
        model: M,
        shared: Arc<Shared>,
        link: PathBuf,
        rng: ChaCha8Rng,
        ppm: f64,
        start_us: u64,
    ) -> Self {
        Runner {
            model,
            shared,
            link,
            rng,
            pty: None,
            clock: DeviceClock {
                power_up: Instant::now(),
                ppm,
                start_us,
            },
            connected: false,
            pending: Vec::new(),
            line: Vec::new(),
            discarding: false,
            power_up: 0,
            readable_ok: true,
            spurious: 0,
            mid_frame_on_open: false,
            unsent: Vec::new(),
        }
    }

    pub fn set_mid_frame_on_open(&mut self, on: bool) {
        self.mid_frame_on_open = on;
    }

    /// Plug in: a fresh pty at the stable path, power-up state.
    pub fn plug(&mut self) -> Result<PathBuf, SimError> {
        let pty = Pty::open(&self.link).map_err(|e| SimError::Pty {
            path: self.link.display().to_string(),
            source: e,
        })?;
        let pts = pty.pts().to_path_buf();
        tracing::debug!(device = M::DEVICE.name(), link = %self.link.display(), pts = %pts.display(), "plugged in");
        self.pty = Some(pty);
        self.connected = false;
        self.pending.clear();
        self.unsent.clear();
        self.line.clear();
        self.discarding = false;
        self.power_up += 1;
        self.clock.power_up = Instant::now();
        let mut out = Vec::new();
        let mut faults = FaultCounts::default();
        {
            let mut ctx = Ctx {
                shared: &self.shared,
                rng: &mut self.rng,
                clock: self.clock,
                now: self.clock.power_up,
                out: &mut out,
                pending: 0,
                connected: false,
                power_up: self.power_up,
                faults: &mut faults,
                device: M::DEVICE,
                keep_unsent: self.mid_frame_on_open,
                unsent: &mut self.unsent,
            };
            self.model.power_up(&mut ctx);
        }
        let mut rec = self.shared.lock_record();
        let d = rec.device_mut(M::DEVICE);
        d.power_ups = self.power_up;
        add_counts(&mut d.faults, &faults);
        Ok(pts)
    }

    fn unplug(&mut self) {
        if let Some(p) = self.pty.take() {
            tracing::debug!(device = M::DEVICE.name(), "unplugged");
            p.unplug();
            self.shared
                .lock_record()
                .device_mut(M::DEVICE)
                .faults
                .unplugs += 1;
        }
        self.connected = false;
        self.pending.clear();
    }

    /// Read what the host wrote; returns the complete command lines and whether any byte came.
    fn read_host(&mut self) -> (Vec<String>, bool) {
        let mut lines = Vec::new();
        let mut got = false;
        let was_connected = self.connected;
        let Some(pty) = &self.pty else {
            return (lines, got);
        };
        let mut buf = [0u8; 1024];
        loop {
            match pty.try_read(&mut buf) {
                ReadOutcome::Data(n) => {
                    self.connected = true;
                    got = true;
                    for &b in &buf[..n] {
                        if M::is_terminator(b) {
                            if !self.discarding {
                                let s = String::from_utf8_lossy(&self.line).into_owned();
                                lines.push(s);
                            }
                            self.line.clear();
                            self.discarding = false;
                        } else if self.line.len() >= MAX_COMMAND {
                            self.discarding = true;
                        } else {
                            self.line.push(b);
                        }
                    }
                }
                ReadOutcome::Idle => {
                    self.connected = true;
                    break;
                }
                ReadOutcome::NoHost => {
                    if self.connected {
                        tracing::debug!(device = M::DEVICE.name(), "host closed the port");
                    }
                    self.connected = false;
                    self.pending.clear();
                    self.line.clear();
                    break;
                }
            }
        }
        if self.connected && !was_connected {
            self.readable_ok = true;
            self.spurious = 0;
            self.rearm();
        }
        (lines, got)
    }

    fn rearm(&mut self) {
        if let Some(Err(e)) = self.pty.as_mut().map(|p| p.rearm()) {
            tracing::warn!(device = M::DEVICE.name(), error = %e, "cannot re-register the pty; polling only");
            self.readable_ok = false;
        }
    }

    /// One step: read commands, answer, generate what is due, write. Returns whether the host
    /// sent anything.
    fn step(&mut self) -> bool {
        let now = Instant::now();
        let plugged = self.pty.is_some();
        let was_connected = self.connected;
        let (lines, got) = if plugged {
            self.read_host()
        } else {
            (Vec::new(), false)
        };
        let mut out = Vec::new();
        let mut faults = FaultCounts::default();
        {
            let mut ctx = Ctx {
                shared: &self.shared,
                rng: &mut self.rng,
                clock: self.clock,
                now,
                out: &mut out,
                pending: self.pending.len(),
                connected: self.connected,
                power_up: self.power_up,
                faults: &mut faults,
                device: M::DEVICE,
                keep_unsent: self.mid_frame_on_open,
                unsent: &mut self.unsent,
            };
            if plugged {
                for l in &lines {
                    let l = l.trim_end_matches(['\r', '\n']);
                    self.model.command(l, &mut ctx);
                }
                self.model.tick(&mut ctx);
            } else {
                self.model.tick_unplugged(&mut ctx);
            }
        }
        if self.connected && !was_connected && !self.unsent.is_empty() {
            // The host joins mid-stream: its first bytes are the end of a sample it missed.
            let cut = self.rng.random_range(1..self.unsent.len().max(2));
            let tail: Vec<u8> = self.unsent.drain(..).skip(cut).collect();
            out.splice(0..0, tail);
            faults.partial_on_open += 1;
        }
        if self.connected {
            // Only the sample generated just before a connect is ever cut.
            self.unsent.clear();
        }
        if faults != FaultCounts::default() {
            add_counts(
                &mut self.shared.lock_record().device_mut(M::DEVICE).faults,
                &faults,
            );
        }
        if self.connected {
            self.pending.extend_from_slice(&out);
            self.flush();
        }
        self.publish();
        got
    }

    /// Publish the device's state for [`crate::SimHandle::state`].
    pub(crate) fn publish(&self) {
        let (active, rate_hz) = self.model.activity();
        let st = DeviceState {
            plugged: self.pty.is_some(),
            host_connected: self.connected,
            active: active && self.pty.is_some(),
            rate_hz,
            power_ups: self.power_up,
        };
        self.shared.states.send_if_modified(|all| {
            let slot = &mut all[M::DEVICE as usize];
            if *slot != st {
                *slot = st;
                true
            } else {
                false
            }
        });
    }

    fn flush(&mut self) {
        let Some(pty) = &self.pty else { return };
        while !self.pending.is_empty() {
            match pty.try_write(&self.pending) {
                Ok(0) => break,
                Ok(n) => {
                    self.pending.drain(..n);
                }
                Err(e) => {
                    tracing::debug!(device = M::DEVICE.name(), error = %e, "pty write failed");
                    self.pending.clear();
                    break;
                }
            }
        }
    }

    pub async fn run(mut self, mut ctl: mpsc::Receiver<Control>) {
        let period = Duration::from_secs_f64(self.shared.world.scenario.batch_ms / 1e3);
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let want_read = self.pty.is_some() && self.connected && self.readable_ok;
            let pty = &self.pty;
            let readable = async move {
                match pty {
                    Some(p) => p.readable().await,
                    None => std::future::pending().await,
                }
            };
            let ev = tokio::select! {
                c = ctl.recv() => Ev::Ctl(c),
                _ = tick.tick() => Ev::Tick,
                r = readable, if want_read => Ev::Readable(r.is_ok()),
            };
            match ev {
                Ev::Ctl(Some(Control::Unplug(ack))) => {
                    self.unplug();
                    self.publish();
                    let _ = ack.send(());
                }
                Ev::Ctl(Some(Control::Replug(ack))) => {
                    self.unplug_silently();
                    let r = self.plug();
                    self.publish();
                    let _ = ack.send(r);
                }
                Ev::Ctl(Some(Control::Shutdown(ack))) => {
                    self.unplug_silently();
                    let _ = ack.send(());
                    return;
                }
                Ev::Ctl(None) => {
                    self.unplug_silently();
                    return;
                }
                Ev::Tick => {
                    self.step();
                }
                Ev::Readable(true) => {
                    // A wake-up without data while the host is connected: re-register, so a
                    // stale readiness can never turn this loop into a busy one.
                    if self.step() || !self.connected {
                        self.spurious = 0;
                    } else {
                        self.spurious += 1;
                        if self.spurious > 3 {
                            // Still no data: leave reading to the batch timer until the next
                            // (re)connect.
                            self.readable_ok = false;
                        } else {
                            self.rearm();
                        }
                    }
                }
                Ev::Readable(false) => tokio::time::sleep(period).await,
            }
        }
    }

    /// Close the pty without counting an unplug (shutdown, or replug of a plugged device).
    fn unplug_silently(&mut self) {
        if let Some(p) = self.pty.take() {
            p.unplug();
        }
        self.connected = false;
        self.pending.clear();
    }
}

fn add_counts(a: &mut FaultCounts, b: &FaultCounts) {
    a.garbage += b.garbage;
    a.bad_checksum += b.bad_checksum;
    a.truncated += b.truncated;
    a.dropped += b.dropped;
    a.beam_interruptions += b.beam_interruptions;
    a.unplugs += b.unplugs;
    a.not_connected += b.not_connected;
    a.overflow += b.overflow;
    a.partial_on_open += b.partial_on_open;
}

/// Printable garbage bytes for a line protocol, never the characters that would make it a
/// frame (`$`, `*`) or end it.
pub(crate) fn garbage_text(rng: &mut ChaCha8Rng, out: &mut Vec<u8>) {
    let n = rng.random_range(4..24);
    for _ in 0..n {
        let mut b: u8 = rng.random_range(0x21..0x7f);
        if b == b'$' || b == b'*' || b == b',' {
            b = b'#';
        }
        out.push(b);
    }
}

/// Count a sample's fate in the fault counters.
pub(crate) fn count_fate(f: &mut FaultCounts, fate: Fate) {
    match fate {
        Fate::Sent => {}
        Fate::BadChecksum => f.bad_checksum += 1,
        Fate::Truncated => f.truncated += 1,
        Fate::Dropped => f.dropped += 1,
        Fate::NotConnected => f.not_connected += 1,
        Fate::Overflow => f.overflow += 1,
    }
}
