//! From samples and triggers to `/pose` records — the same code live and in replay.
//!
//! [`PoseEngine`] holds one [`SteadyDetector`] per instrument. It is fed every sample and
//! trigger in the order they are written to the log; replay reads the log in file order and
//! feeds the very same calls, so it reproduces the logged pose values bit for bit (JSON
//! numbers are written in shortest round-trip form, so every `f64` reads back exactly).
//!
//! Time axis (docs/design.md, timing model): samples enter the detector at their clock-fitted
//! time (`Sample::fitted_ns`, the device clock mapped onto the host axis), triggers at their
//! NC clock fitted the same way ([`NcClock`], setting
//! [`TriggerTime::NcClock`]) — when each thing happened, not when it arrived. Logs written
//! before that setting placed triggers at their host arrival time ([`TriggerTime::Arrival`]);
//! replay keeps doing so for them. The fit is made here, from the `nc_ms` and arrival time
//! every `/cnc/trigger` record holds, so a replay makes the same fit in the same order.
//!
//! Order: with [`TriggerTime::NcClock`] each detector also takes the triggers in time order
//! with its samples. A trigger is held until the instrument's samples have reached its time
//! (or, for an instrument whose samples stopped, until the triggers are [`HOLD_NS`] ahead), so
//! that a sample stream that arrives late — a starved reader on a loaded host — neither has
//! its dwell closed before its samples come (`device_away`) nor has samples from before the
//! exact stop averaged into the pose (the previous pose's value). A trigger that arrives after
//! later samples finds them in the detector's history.

use std::collections::VecDeque;

use types::{
    DetectorSettings, Instrument, NC_SETTLE_US, PoseMsg, PoseStatus, PoseValue, PositionTargets,
    Sample, SampleValues, SteadyError, Trigger, TriggerEvent, TriggerTime,
};

use crate::clock::{NcClock, NcPoint};
use crate::dwell_gate::DwellGate;
use crate::steady::{LATE_MARGIN_NS, SteadyDetector};

/// How far the triggers may run ahead of an instrument's samples before they are applied
/// without them (the instrument counts as away for that time): the detector's late margin.
pub const HOLD_NS: u64 = LATE_MARGIN_NS;

/// One instrument's detector and the triggers held for it.
#[derive(Debug, Clone)]
struct Slot {
    instrument: Instrument,
    det: SteadyDetector,
    held: VecDeque<(TriggerEvent, u32, u64)>,
    /// Time of the newest sample fed.
    newest_ns: u64,
    /// Samples past the time of a trigger still waiting to be placed, in order: fed once it
    /// is (a dwell must not take samples past its end before the end is known).
    queued: VecDeque<QueuedSample>,
    /// The interferometer's datum epochs, as its samples' flags say (default for the others).
    epochs: Epochs,
    /// Where the interferometer must read at each pose (none for the other instruments).
    targets: Option<PositionTargets>,
}

/// How far from zero the reference visit's value may read for a re-reference to stand, µm: the
/// device read 0 at `DATUM` and the axis stood still, so more means the datum was taken while
/// the axis moved or rang (docs/design.md, "Datum epochs").
pub(crate) const REFERENCE_VISIT_TOL_UM: f64 = 1.0;

/// The interferometer's datum epochs, as its samples' flags say ([`types::datum_epoch`],
/// [`types::DATUM_FLAGS`]): which epoch a value was measured in, and whether that epoch's zero
/// is the run's (epoch 0) or was re-referenced (a later epoch whose samples became clean).
#[derive(Debug, Clone, Default)]
struct Epochs {
    /// The changes of (epoch, clean) in sample order, from (0, clean).
    marks: Vec<(u64, u32, bool)>,
    /// A re-reference (time, epoch) whose reference visit has not been valued yet.
    visit: Option<(u64, u32)>,
    /// Epochs whose re-reference the reference visit did not confirm.
    refused: Vec<u32>,
    /// Epoch 0 is not the run's datum: the first trigger was not the program start.
    epoch0_foreign: bool,
    /// [`DetectorSettings::datum_epochs`]; without it (old logs) only the first loss counts:
    /// every later value without a valid value is `datum_lost`.
    on: bool,
}

impl Epochs {
    fn new(on: bool) -> Epochs {
        Epochs {
            on,
            ..Epochs::default()
        }
    }

    fn started_mid_program(&mut self) {
        self.epoch0_foreign = self.on;
    }

    /// A sample at `t` with LI-80 flags `flags`.
    fn observe(&mut self, t: u64, flags: u32) {
        let now = (types::datum_epoch(flags), flags & types::DATUM_FLAGS == 0);
        let (epoch, clean) = self.state_at(u64::MAX);
        if now == (epoch, clean) {
            return;
        }
        if self.on && now == (epoch, true) && epoch > 0 {
            self.visit = Some((t, epoch));
        }
        self.marks.push((t, now.0, now.1));
    }

    /// (epoch, clean) of the samples at `t`.
    fn state_at(&self, t: u64) -> (u32, bool) {
        self.marks
            .iter()
            .rev()
            .find(|m| m.0 <= t)
            .map_or((0, true), |m| (m.1, m.2))
    }

    /// Whether values measured in `epoch` with clean samples are against the run's zero.
    fn trusted(&self, epoch: u32) -> bool {
        let foreign = epoch == 0 && self.epoch0_foreign;
        !(self.refused.contains(&epoch) || foreign)
    }

    /// The epoch of `v`; a value not against the run's zero becomes `datum_lost`: one not
    /// `ok` measured after the datum was lost, one `ok` from an epoch not the run's or
    /// spanning a change of epoch, and the reference visit (not a measurement).
    fn judge(&mut self, v: &mut PoseValue) -> u32 {
        let (epoch, clean) = self.state_at(v.t_last_ns);
        if !self.on {
            if v.status != PoseStatus::Ok && self.marks.first().is_some_and(|m| v.t_last_ns >= m.0)
            {
                v.status = PoseStatus::DatumLost;
            }
            return epoch;
        }
        if let Some((t_ref, e)) = self.visit
            && v.t_last_ns >= t_ref
        {
            self.visit = None;
            let zero = v
                .mean
                .first()
                .is_some_and(|m| m.abs() <= REFERENCE_VISIT_TOL_UM);
            if !(v.status == PoseStatus::Ok && zero && e == epoch) {
                self.refused.push(e);
            }
            v.status = PoseStatus::DatumLost;
            return epoch;
        }
        let mixed = self
            .marks
            .iter()
            .any(|m| m.0 > v.t_first_ns && m.0 <= v.t_last_ns);
        let lost = !clean || !self.trusted(epoch) || (v.status == PoseStatus::Ok && mixed);
        if lost {
            v.status = PoseStatus::DatumLost;
        }
        epoch
    }
}

/// A sample waiting in [`Slot::queued`]: time, values, channels used, valid.
type QueuedSample = (u64, [f64; 3], usize, bool);

impl Slot {
    fn out(&mut self, values: Vec<PoseValue>, out: &mut Vec<PoseMsg>) {
        for mut v in values {
            let epoch = self.epochs.judge(&mut v);
            if self.off_target(&v) {
                v.status = PoseStatus::OffTarget;
            }
            let mut msg = PoseMsg::from_value(self.instrument, &v);
            msg.datum_epoch = epoch;
            out.push(msg);
        }
    }

    /// Whether `v` is an `ok` value farther from its pose's target than the tolerance.
    fn off_target(&self, v: &PoseValue) -> bool {
        let (Some(t), Some(got)) = (&self.targets, v.mean.first()) else {
            return false;
        };
        v.status == PoseStatus::Ok
            && t.target_um(v.pose)
                .zip(t.tolerance_um(v.pose))
                .is_some_and(|(want, tol)| (got - want).abs() > tol)
    }

    /// Feeds the queued samples up to `horizon` (all with `None`), after the held triggers
    /// up to each one's time.
    fn drain(&mut self, horizon: Option<u64>, out: &mut Vec<PoseMsg>) {
        while let Some(&(t, values, n, valid)) = self.queued.front()
            && horizon.is_none_or(|h| t <= h)
        {
            self.queued.pop_front();
            self.release(|h| h <= t, out);
            let v = self.det.push_sample(t, &values[..n], valid);
            self.out(v, out);
            self.newest_ns = self.newest_ns.max(t);
        }
    }

    /// Applies the held triggers that `ready` says may go, in order.
    fn release(&mut self, ready: impl Fn(u64) -> bool, out: &mut Vec<PoseMsg>) {
        while let Some(&(kind, pose, t)) = self.held.front()
            && ready(t)
        {
            self.held.pop_front();
            let v = self.det.push_trigger(kind, pose, t);
            self.out(v, out);
        }
    }
}

/// The steady-value detectors of the interferometer, the CapBall and the PSD.
#[derive(Debug, Clone)]
pub struct PoseEngine {
    detectors: Vec<Slot>,
    /// The NC clock fit, when triggers are placed by it (and held for the samples).
    nc_clock: Option<NcClock>,
    /// Place a trigger only once the fit has settled ([`TriggerTime::NcClockSettled`]).
    settle: bool,
    /// Triggers observed, waiting for the fit to settle, in order.
    unplaced: VecDeque<(TriggerEvent, u32, NcPoint)>,
    /// A trigger came (the first one decides whether epoch 0 is the run's datum).
    trigger_seen: bool,
    /// With position targets: the other instruments' values wait for the interferometer's
    /// verdict on their pose ([`DwellGate`]).
    gate: Option<DwellGate>,
}

impl PoseEngine {
    pub fn new(settings: &DetectorSettings) -> Result<PoseEngine, SteadyError> {
        if let Some(t) = &settings.position_targets {
            t.validate()?;
        }
        let mut detectors = Vec::new();
        for (inst, cfg) in [
            (Instrument::Interferometer, &settings.interferometer),
            (Instrument::Capball, &settings.capball),
            (Instrument::Psd, &settings.psd),
        ] {
            if settings.instruments.contains(&inst) {
                detectors.push(Slot {
                    instrument: inst,
                    det: SteadyDetector::new(cfg.clone(), inst.detector_channels().len())?,
                    held: VecDeque::new(),
                    newest_ns: 0,
                    queued: VecDeque::new(),
                    epochs: Epochs::new(settings.datum_epochs),
                    targets: settings
                        .position_targets
                        .clone()
                        .filter(|_| inst == Instrument::Interferometer),
                });
            }
        }
        let nc_clock = match settings.trigger_time {
            TriggerTime::NcClock | TriggerTime::NcClockSettled => Some(NcClock::default()),
            TriggerTime::Arrival => None,
        };
        let gate = settings
            .position_targets
            .clone()
            .filter(|_| {
                settings.instruments.contains(&Instrument::Interferometer) && detectors.len() > 1
            })
            .map(DwellGate::new);
        Ok(PoseEngine {
            detectors,
            nc_clock,
            settle: settings.trigger_time == TriggerTime::NcClockSettled,
            unplaced: VecDeque::new(),
            trigger_seen: false,
            gate,
        })
    }

    /// The values that may go now (all of `out` without position targets).
    fn gated(&mut self, out: Vec<PoseMsg>) -> Vec<PoseMsg> {
        match &mut self.gate {
            Some(g) => g.pass(out),
            None => out,
        }
    }

    /// Whether a trigger is placed as it comes: not while [`TriggerTime::NcClockSettled`]
    /// waits for the NC clock fit (the first seconds of a program, or after the NC restarted).
    pub fn placing_at_once(&self) -> bool {
        !self.settle || self.nc_clock.as_ref().is_none_or(NcClock::settled)
    }

    /// The time on the host axis at which the detectors take a trigger.
    pub fn trigger_time(&mut self, t: &Trigger) -> u64 {
        match &mut self.nc_clock {
            Some(c) => c.time(t.nc_ms, t.host_ns),
            None => t.host_ns,
        }
    }

    /// Feeds a sample to its instrument's detector (environment records are not), after the
    /// held triggers up to its time.
    pub fn on_sample(&mut self, s: &Sample) -> Vec<PoseMsg> {
        let (inst, values, n): (Instrument, [f64; 3], usize) = match &s.values {
            SampleValues::Position { position_um, .. } => {
                (Instrument::Interferometer, [*position_um, 0.0, 0.0], 1)
            }
            SampleValues::Capball { e_um, .. } => (Instrument::Capball, *e_um, 3),
            SampleValues::Psd { x_um, y_um, .. } => (Instrument::Psd, [*x_um, *y_um, 0.0], 2),
            SampleValues::Environment { .. } | SampleValues::Temperature { .. } => {
                return Vec::new();
            }
        };
        let horizon = self.horizon();
        let Some(slot) = self.detectors.iter_mut().find(|d| d.instrument == inst) else {
            return Vec::new();
        };
        if let SampleValues::Position { flags, .. } = &s.values {
            slot.epochs.observe(s.fitted_ns, *flags);
            if let Some(g) = &mut self.gate {
                g.observe(s.fitted_ns, values[0], s.valid);
            }
        }
        let mut out = Vec::new();
        slot.queued.push_back((s.fitted_ns, values, n, s.valid));
        slot.drain(horizon, &mut out);
        self.gated(out)
    }

    /// The time up to which samples may be fed: that of the oldest trigger waiting to be
    /// placed, as the fit now stands (None: no trigger waits).
    fn horizon(&self) -> Option<u64> {
        let nc = self.nc_clock.as_ref()?;
        self.unplaced.front().map(|(_, _, p)| nc.place(p))
    }

    /// Feeds a trigger to every detector (held for those whose samples are behind it). With
    /// [`TriggerTime::NcClockSettled`] it first waits, with the triggers before it, until the
    /// NC clock fit has settled or run [`NC_SETTLE_US`] past it, and is placed then: the order
    /// of the trigger stream alone decides, so replay places it the same way.
    pub fn on_trigger(&mut self, t: &Trigger) -> Vec<PoseMsg> {
        let kind = t.event;
        if !self.trigger_seen {
            self.trigger_seen = true;
            if kind != TriggerEvent::ProgramStart {
                // Only the interferometer's zero is relative (docs/instruments.md).
                for slot in &mut self.detectors {
                    if slot.instrument == Instrument::Interferometer {
                        slot.epochs.started_mid_program();
                    }
                }
            }
        }
        let mut out = Vec::new();
        match (&mut self.nc_clock, self.settle) {
            (Some(nc), true) => {
                let p = nc.observe(t.nc_ms, t.host_ns);
                self.unplaced.push_back((kind, u32::from(t.pose), p));
                self.place_settled(false, &mut out);
            }
            _ => {
                let t_ns = self.trigger_time(t);
                self.dispatch(kind, u32::from(t.pose), t_ns, &mut out);
            }
        }
        self.gated(out)
    }

    /// Places the waiting triggers whose time the fit now knows (all with `all`).
    fn place_settled(&mut self, all: bool, out: &mut Vec<PoseMsg>) {
        let Some(nc) = &self.nc_clock else { return };
        let mut placed = Vec::new();
        while let Some(&(kind, pose, p)) = self.unplaced.front()
            && (all || nc.settled() || nc.since(&p) >= NC_SETTLE_US)
        {
            placed.push((kind, pose, nc.place(&p)));
            self.unplaced.pop_front();
        }
        for (kind, pose, t_ns) in placed {
            self.dispatch(kind, pose, t_ns, out);
        }
        let horizon = if all { None } else { self.horizon() };
        for slot in &mut self.detectors {
            slot.drain(horizon, out);
        }
    }

    /// Hands a placed trigger to every detector.
    fn dispatch(&mut self, kind: TriggerEvent, pose: u32, t_ns: u64, out: &mut Vec<PoseMsg>) {
        let hold = self.nc_clock.is_some();
        for slot in &mut self.detectors {
            if hold {
                slot.held.push_back((kind, pose, t_ns));
                let newest = slot.newest_ns;
                slot.release(|h| h <= newest || h.saturating_add(HOLD_NS) <= t_ns, out);
            } else {
                let v = slot.det.push_trigger(kind, pose, t_ns);
                slot.out(v, out);
            }
        }
    }

    /// End of the run: places the waiting triggers, applies the held ones and closes open
    /// dwells.
    pub fn finish(&mut self, t_ns: u64) -> Vec<PoseMsg> {
        let mut out = Vec::new();
        self.place_settled(true, &mut out);
        for slot in &mut self.detectors {
            slot.release(|_| true, &mut out);
            let v = slot.det.finish(t_ns);
            slot.out(v, &mut out);
        }
        match &mut self.gate {
            Some(g) => g.flush(out),
            None => out,
        }
    }
}

#[cfg(test)]
mod tests {
    //! The dwell of a pose must land on that pose's samples however late its trigger frames
    //! arrive (issue 15: under load, "ok" LI-80 values of the neighbouring pose, ~100 mm off).
    //! The machine, the instrument and the trigger link are generated here, with the truth.
    use super::*;

    const T0_NS: u64 = 1_800_000_000_000_000_000;
    const RATE_HZ: f64 = 5_000.0;
    const LEAD_IN_S: f64 = 0.3;
    const MOVE_S: f64 = 0.1;
    const DWELL_S: f64 = 0.4;
    const POSES: u16 = 20;
    /// Trigger frames sent in [STALL_FROM_S, STALL_TO_S) reach the host 450 ms late, in order
    /// (a starved reader on a loaded host): poses 15 and 16's frames arrive a dwell and more
    /// behind their samples.
    const STALL_FROM_S: f64 = 7.35;
    const STALL_TO_S: f64 = 8.35;
    const STALL_S: f64 = 0.45;
    /// LI-80 samples sent in [4.35 s, 5.35 s) reach the host 600 ms late, in order (its
    /// reader starved), while the trigger frames come at once: poses 9 to 12.
    const SAMPLE_STALL_FROM_S: f64 = 4.35;
    const SAMPLE_STALL_TO_S: f64 = 5.35;
    const SAMPLE_STALL_S: f64 = 0.6;
    /// With `burst`: the trigger frames of the program's first 1.45 s (program start to pose
    /// 3's exact stop) reach the host together at 1.6 s, before any prompt frame (the gap a
    /// HIL round at load average 10 showed).
    const BURST_TO_S: f64 = 1.45;
    const BURST_AT_S: f64 = 1.6;

    fn pose_start_s(k: u16) -> f64 {
        LEAD_IN_S + f64::from(k - 1) * (MOVE_S + DWELL_S)
    }
    fn pose_um(k: u16) -> f64 {
        f64::from(k) * 100_000.0
    }
    /// The machine's position at true time `t` (s after program start): a ramp during each
    /// move, standing still during each dwell.
    fn position_um(t: f64) -> f64 {
        let mut x = 0.0;
        for k in 1..=POSES {
            let m = pose_start_s(k);
            if t < m {
                break;
            }
            x = if t < m + MOVE_S {
                pose_um(k - 1) + (pose_um(k) - pose_um(k - 1)) * (t - m) / MOVE_S
            } else {
                pose_um(k)
            };
        }
        x
    }

    enum Ev {
        Sample(Sample),
        Trigger(Trigger),
    }

    /// Samples and triggers in the order the pipeline receives them (by host arrival).
    fn run_events(burst: bool) -> Vec<Ev> {
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let ns = |t: f64| T0_NS + (t * 1e9).round() as u64;
        let end_s = pose_start_s(POSES) + MOVE_S + DWELL_S + 0.2;
        let mut evs: Vec<(u64, Ev)> = Vec::new();
        // The LI-80: 5 kHz, device clock 30 ppm slow; arrival 0.1–2 ms late. Its fitted time
        // is taken as the truth here (the clock fit is tested in crate::clock).
        let n = (end_s * RATE_HZ) as u64;
        let mut last_arrival = 0.0f64;
        for i in 0..n {
            let t = i as f64 / RATE_HZ;
            let x = position_um(t) + (uniform() - 0.5) * 0.02;
            let delay = if (SAMPLE_STALL_FROM_S..SAMPLE_STALL_TO_S).contains(&t) {
                SAMPLE_STALL_S
            } else {
                1e-4 + uniform() * 2e-3
            };
            last_arrival = last_arrival.max(t + delay);
            let s = Sample {
                instrument: Instrument::Interferometer,
                seq: i,
                device_t_us: (t * 1e6 * (1.0 - 30e-6)) as u64,
                host_ns: ns(last_arrival),
                fitted_ns: ns(t),
                valid: true,
                values: SampleValues::Position {
                    raw_nm: (x * 1e3) as i64,
                    position_um: x,
                    sig: 80,
                    flags: 0,
                },
            };
            evs.push((s.host_ns, Ev::Sample(s)));
        }
        // The NC: program start, per pose motion start, exact stop, dwell end. Its clock runs
        // 50 ppm fast and wraps 3 s into the run; frames arrive 0.2–3 ms late, in order, except
        // in the stall.
        let mut frames = vec![(0.0, TriggerEvent::ProgramStart, 0)];
        for k in 1..=POSES {
            let m = pose_start_s(k);
            frames.push((m, TriggerEvent::MotionStart, k));
            frames.push((m + MOVE_S, TriggerEvent::ExactStop, k));
            frames.push((m + MOVE_S + DWELL_S, TriggerEvent::DwellEnd, k));
        }
        frames.push((end_s - 0.1, TriggerEvent::ProgramEnd, 0));
        let mut last_arrival = 0.0f64;
        for (t, event, pose) in frames {
            let delay = if burst && t < BURST_TO_S {
                BURST_AT_S - t
            } else if (STALL_FROM_S..STALL_TO_S).contains(&t) {
                STALL_S
            } else {
                2e-4 + uniform() * 2.8e-3
            };
            last_arrival = last_arrival.max(t + delay);
            let nc = (4_294_964_000.0 + t * 1e3 * (1.0 + 50e-6)).round() as u64;
            let tr = Trigger {
                event,
                pose,
                nc_ms: (nc & 0xFFFF_FFFF) as u32,
                host_ns: ns(last_arrival),
            };
            evs.push((tr.host_ns, Ev::Trigger(tr)));
        }
        evs.sort_by_key(|(t, _)| *t);
        evs.into_iter().map(|(_, e)| e).collect()
    }

    /// The LI-80 pose values of the run, by pose.
    fn poses_with(trigger_time: TriggerTime) -> Vec<PoseMsg> {
        poses_of(trigger_time, false)
    }

    fn poses_of(trigger_time: TriggerTime, burst: bool) -> Vec<PoseMsg> {
        let settings = DetectorSettings {
            instruments: vec![Instrument::Interferometer],
            trigger_time,
            ..DetectorSettings::default()
        };
        poses_by(&settings, burst)
    }

    fn poses_by(settings: &DetectorSettings, burst: bool) -> Vec<PoseMsg> {
        let mut engine = PoseEngine::new(settings).unwrap();
        let mut out = Vec::new();
        for ev in run_events(burst) {
            out.extend(match &ev {
                Ev::Sample(s) => engine.on_sample(s),
                Ev::Trigger(t) => engine.on_trigger(t),
            });
        }
        out.extend(engine.finish(u64::MAX));
        out
    }

    /// Poses whose value is not that pose's position (within 1 µm) or whose window is not the
    /// first one after the exact stop (the machine stands still from the stop on, so that
    /// window is steady), with what they got.
    fn misplaced(poses: &[PoseMsg]) -> Vec<(u32, String, f64)> {
        poses
            .iter()
            .filter_map(|p| {
                let got = p.mean.get("position_um").copied().unwrap_or(f64::NAN);
                let want = f64::from(p.pose) * 100_000.0;
                let stop_ns = T0_NS + ((pose_start_s(p.pose as u16) + MOVE_S) * 1e9) as u64;
                let late_ms = (p.t_first_ns as f64 - stop_ns as f64) / 1e6;
                (p.status.name() != "ok"
                    || (got - want).abs() > 1.0
                    || !(-0.5..5.0).contains(&late_ms))
                .then(|| {
                    (
                        p.pose,
                        format!("{} {late_ms:.1} ms after the stop", p.status.name()),
                        got,
                    )
                })
            })
            .collect()
    }

    #[test]
    fn a_dwell_lands_on_its_pose_when_its_frames_or_its_samples_arrive_late() {
        for tt in [TriggerTime::NcClockSettled, TriggerTime::NcClock] {
            let poses = poses_with(tt);
            assert_eq!(poses.len(), usize::from(POSES), "{tt:?}: {poses:#?}");
            assert_eq!(misplaced(&poses), vec![], "{tt:?}");
        }
    }

    #[test]
    fn a_late_burst_of_frames_at_the_start_is_placed_by_the_prompt_ones_after_it() {
        // Placed with the fit as it stood when they came, the burst's frames all sit at its
        // arrival: poses 1 to 3 lose their dwells. Placed once the fit has settled (the NC
        // clock 2 s past them, prompt frames in between), every pose is right.
        let poses = poses_of(TriggerTime::NcClockSettled, true);
        assert_eq!(poses.len(), usize::from(POSES), "{poses:#?}");
        assert_eq!(misplaced(&poses), vec![]);
        let before = misplaced(&poses_of(TriggerTime::NcClock, true));
        let wrong: Vec<u32> = before.iter().map(|w| w.0).collect();
        assert!(
            [1, 2, 3].iter().all(|k| wrong.contains(k)) && wrong.iter().all(|k| *k <= 3),
            "{before:?}"
        );
    }

    #[test]
    fn placed_by_arrival_the_late_streams_take_the_neighbours_values() {
        // What the daemon did before the NC clock fit (and replay still does for old logs),
        // the faults the HIL test saw under load. Samples late (poses 9-12): pose 9's dwell
        // closes before its samples come (device_away), poses 10-12 average samples from
        // before their exact stop: the previous pose's values. Frames late (poses 15-17):
        // poses 15 and 16 get the next pose's values, 100 mm off; pose 17's window is right
        // but 350 ms into its dwell. This shows the scenario above provokes both.
        let wrong = misplaced(&poses_with(TriggerTime::Arrival));
        let poses: Vec<u32> = wrong.iter().map(|w| w.0).collect();
        assert_eq!(poses, vec![9, 10, 11, 12, 15, 16, 17], "{wrong:?}");
        for (pose, status, got) in &wrong {
            let (want_status, value_of) = match pose {
                9 => ("device_away", None),
                10..=12 => ("ok", Some(pose - 1)),
                15 | 16 => ("ok", Some(pose + 1)),
                _ => ("ok", Some(*pose)),
            };
            assert!(status.starts_with(want_status), "{wrong:?}");
            if let Some(k) = value_of {
                assert!((got - f64::from(k) * 100_000.0).abs() < 1.0, "{wrong:?}");
            }
        }
    }

    /// With the trajectory's targets, the values the arrival placement takes from neighbouring
    /// poses (100 mm off) are `off_target`, not `ok`; every `ok` value left is its own pose's.
    /// The targets here are the generator's positions, not the engine's.
    #[test]
    fn with_targets_no_value_of_another_pose_is_ok() {
        let targets = types::PositionTargets {
            targets_um: (1..=POSES).map(pose_um).collect(),
            tol_um: types::OFF_TARGET_TOL_UM,
            floor_um: None,
        };
        let settings = DetectorSettings {
            instruments: vec![Instrument::Interferometer],
            trigger_time: TriggerTime::Arrival,
            position_targets: Some(targets),
            ..DetectorSettings::default()
        };
        let out = poses_by(&settings, false);
        assert_eq!(out.len(), usize::from(POSES), "{out:#?}");
        let off: Vec<u32> = out
            .iter()
            .filter(|p| p.status == PoseStatus::OffTarget)
            .map(|p| p.pose)
            .collect();
        assert_eq!(off, vec![10, 11, 12, 15, 16], "{out:#?}");
        for p in out.iter().filter(|p| p.status == PoseStatus::Ok) {
            let got = p.mean.get("position_um").copied().unwrap_or(f64::NAN);
            assert!((got - pose_um(p.pose as u16)).abs() < 1.0, "{p:?}");
        }
        // Settings that cannot work are refused, not applied.
        let mut bad = settings.clone();
        if let Some(t) = bad.position_targets.as_mut() {
            t.tol_um = f64::NAN;
        }
        assert!(PoseEngine::new(&bad).is_err());
        // The key is written only when set, and logs without it read back without targets.
        let json = serde_json::to_string(&settings).unwrap();
        let back: DetectorSettings = serde_json::from_str(&json).unwrap();
        assert_eq!(back, settings);
        let plain = serde_json::to_string(&DetectorSettings::default()).unwrap();
        assert!(!plain.contains("position_targets"), "{plain}");
    }

    /// The same run with its poses 1.2 mm apart (the interferometer's readings scaled): the
    /// neighbours' values the arrival placement takes are within the 2 mm of a fixed
    /// tolerance and passed as `ok`; with the floor set (new runs), a pose's tolerance is half
    /// the distance to its nearest other target (0.6 mm) and they are `off_target`.
    #[test]
    fn with_close_targets_a_neighbours_value_is_off_target_only_with_the_floor() {
        const SCALE: f64 = 1.2 / 100.0;
        let scaled = || {
            run_events(false).into_iter().map(|ev| match ev {
                Ev::Sample(mut s) => {
                    if let SampleValues::Position { position_um, .. } = &mut s.values {
                        *position_um *= SCALE;
                    }
                    Ev::Sample(s)
                }
                t => t,
            })
        };
        let off_with = |floor_um: Option<f64>| {
            let settings = DetectorSettings {
                instruments: vec![Instrument::Interferometer],
                trigger_time: TriggerTime::Arrival,
                position_targets: Some(types::PositionTargets {
                    targets_um: (1..=POSES).map(|k| pose_um(k) * SCALE).collect(),
                    tol_um: types::OFF_TARGET_TOL_UM,
                    floor_um,
                }),
                ..DetectorSettings::default()
            };
            let mut engine = PoseEngine::new(&settings).unwrap();
            let mut out = Vec::new();
            for ev in scaled() {
                out.extend(match &ev {
                    Ev::Sample(s) => engine.on_sample(s),
                    Ev::Trigger(t) => engine.on_trigger(t),
                });
            }
            out.extend(engine.finish(u64::MAX));
            out.iter()
                .filter(|p| p.status == PoseStatus::OffTarget)
                .map(|p| p.pose)
                .collect::<Vec<u32>>()
        };
        assert_eq!(off_with(None), Vec::<u32>::new());
        assert_eq!(
            off_with(Some(types::OFF_TARGET_FLOOR_UM)),
            vec![10, 11, 12, 15, 16]
        );
    }

    #[test]
    fn old_logs_without_the_setting_place_triggers_by_arrival() {
        let old: DetectorSettings = serde_json::from_str(r#"{"instruments":["capball"]}"#).unwrap();
        assert_eq!(old.trigger_time, TriggerTime::Arrival);
        assert!(!old.datum_epochs && DetectorSettings::default().datum_epochs);
        assert_eq!(
            DetectorSettings::default().trigger_time,
            TriggerTime::NcClockSettled
        );
        let new = serde_json::to_string(&DetectorSettings::default()).unwrap();
        assert!(
            new.contains(r#""trigger_time":"nc_clock_settled""#),
            "{new}"
        );
        let back: DetectorSettings = serde_json::from_str(&new).unwrap();
        assert_eq!(back.trigger_time, TriggerTime::NcClockSettled);
        let v01: DetectorSettings =
            serde_json::from_str(r#"{"instruments":["capball"],"trigger_time":"nc_clock"}"#)
                .unwrap();
        assert_eq!(v01.trigger_time, TriggerTime::NcClock);
    }

    /// From the first reading whose zero is not the run's (the LI-80 reconnected, or lost its
    /// datum), no pose of the interferometer is ok: each is `datum_lost` (issue: a reconnect
    /// re-zeroed the interferometer and every later value was marked ok).
    #[test]
    fn after_the_datum_is_lost_no_pose_is_ok() {
        let lost_from_s = pose_start_s(10);
        let ns = |t: f64| T0_NS + (t * 1e9).round() as u64;
        let settings = DetectorSettings {
            instruments: vec![Instrument::Interferometer],
            ..DetectorSettings::default()
        };
        let mut engine = PoseEngine::new(&settings).unwrap();
        let mut out = Vec::new();
        for ev in run_events(false) {
            out.extend(match ev {
                Ev::Sample(mut s) => {
                    if s.fitted_ns >= ns(lost_from_s)
                        && let SampleValues::Position { flags, .. } = &mut s.values
                    {
                        *flags |= types::DATUM_NOT_RUNS;
                        s.valid = false;
                    }
                    engine.on_sample(&s)
                }
                Ev::Trigger(t) => engine.on_trigger(&t),
            });
        }
        out.extend(engine.finish(u64::MAX));
        let before: Vec<_> = out.iter().filter(|p| p.pose < 10).collect();
        let after: Vec<_> = out.iter().filter(|p| p.pose >= 10).collect();
        assert!(
            before.iter().all(|p| p.status == PoseStatus::Ok),
            "{before:?}"
        );
        assert_eq!(after.len(), usize::from(POSES) - 9, "{after:?}");
        assert!(
            after.iter().all(|p| p.status == PoseStatus::DatumLost),
            "{after:?}"
        );
    }

    /// The run's events with the interferometer's datum lost from pose 10's start (epoch 1,
    /// flagged) and, when `reference_at` is given, `DATUM` taken `reference_at` s after pose
    /// 14's exact stop: from then epoch 1 is clean and reads from pose 14's position, offset
    /// by `datum_error_um` (a datum taken off the stand-still position).
    fn epoch_events(
        reference_at: Option<f64>,
        datum_error_um: f64,
        program_start: bool,
    ) -> Vec<Ev> {
        let ns = |t: f64| T0_NS + (t * 1e9).round() as u64;
        let lost = ns(pose_start_s(10));
        let referenced = reference_at.map(|d| ns(pose_start_s(14) + MOVE_S + d));
        run_events(false)
            .into_iter()
            .filter(|ev| {
                program_start
                    || !matches!(ev, Ev::Trigger(t) if t.event == TriggerEvent::ProgramStart)
            })
            .map(|ev| match ev {
                Ev::Sample(mut s) if s.fitted_ns >= lost => {
                    let clean = referenced.is_some_and(|r| s.fitted_ns >= r);
                    if let SampleValues::Position {
                        flags, position_um, ..
                    } = &mut s.values
                    {
                        *flags |= types::datum_epoch_bits(1);
                        if clean {
                            *position_um -= pose_um(14) + datum_error_um;
                        } else {
                            *flags |= types::DATUM_NOT_RUNS;
                            s.valid = false;
                        }
                    }
                    Ev::Sample(s)
                }
                ev => ev,
            })
            .collect()
    }

    fn run_engine(events: Vec<Ev>) -> Vec<PoseMsg> {
        let settings = DetectorSettings {
            instruments: vec![Instrument::Interferometer],
            ..DetectorSettings::default()
        };
        let mut engine = PoseEngine::new(&settings).unwrap();
        let mut out = Vec::new();
        for ev in events {
            out.extend(match ev {
                Ev::Sample(s) => engine.on_sample(&s),
                Ev::Trigger(t) => engine.on_trigger(&t),
            });
        }
        out.extend(engine.finish(u64::MAX));
        out
    }

    /// A lost epoch re-referenced at pose 14 (the reference visit, itself not a measurement):
    /// poses 10 to 14 are `datum_lost`, the later ones `ok` in epoch 1, each reading its
    /// length from pose 14 (the truth here, written independently of the engine).
    #[test]
    fn a_re_referenced_epoch_is_ok_again_after_its_reference_visit() {
        let out = run_engine(epoch_events(Some(0.2), 0.0, true));
        assert_eq!(out.len(), usize::from(POSES), "{out:#?}");
        for p in &out {
            let k = p.pose as u16;
            let got = p.mean.get("position_um").copied().unwrap_or(f64::NAN);
            let (status, epoch) = (p.status, p.datum_epoch);
            match k {
                1..=9 => {
                    assert_eq!((status, epoch), (PoseStatus::Ok, 0), "{p:?}");
                    assert!((got - pose_um(k)).abs() < 1.0, "{p:?}");
                }
                10..=14 => assert_eq!((status, epoch), (PoseStatus::DatumLost, 1), "{p:?}"),
                _ => {
                    assert_eq!((status, epoch), (PoseStatus::Ok, 1), "{p:?}");
                    assert!((got - (pose_um(k) - pose_um(14))).abs() < 1.0, "{p:?}");
                }
            }
        }
    }

    /// A datum taken off the stand-still position (the reference visit reads 5 µm, not 0) is
    /// not a re-reference: every later value stays `datum_lost`. Without any re-reference the
    /// same. Both fail with ok values if the engine trusted the clean flags alone.
    #[test]
    fn a_re_reference_the_visit_does_not_confirm_leaves_the_epoch_lost() {
        for events in [
            epoch_events(Some(0.2), -5.0, true),
            epoch_events(None, 0.0, true),
        ] {
            let out = run_engine(events);
            let after: Vec<_> = out.iter().filter(|p| p.pose >= 10).collect();
            assert_eq!(after.len(), usize::from(POSES) - 9);
            assert!(
                after
                    .iter()
                    .all(|p| p.status == PoseStatus::DatumLost && p.datum_epoch == 1),
                "{after:?}"
            );
        }
    }

    /// A run whose first trigger is not its program start (the service started mid-program)
    /// has no datum of its own: no value of epoch 0 is ok; those of the re-referenced epoch are.
    #[test]
    fn a_start_mid_program_has_no_datum_until_re_referenced() {
        let out = run_engine(epoch_events(Some(0.2), 0.0, false));
        for p in &out {
            let want = if p.pose <= 14 {
                PoseStatus::DatumLost
            } else {
                PoseStatus::Ok
            };
            assert_eq!(p.status, want, "{p:?}");
        }
    }
}
