//! Steady-value detection: one value per programmed pose from a sampled signal.
//!
//! Public surface (used by the daemon and replay):
//! - [`PoseValue`], [`PoseStatus`]: the result for one instrument at one pose;
//! - [`SteadyDetector`]: fed samples `(t_ns, values, valid)` and triggers ([`TriggerEvent`]) in
//!   arrival order, it emits [`PoseValue`]s; [`SteadyConfig`] holds its settings.
//!
//! # Method
//!
//! A pose value is the mean of the **first window of `samples` consecutive valid samples after
//! the exact stop that passes the steady-state test**. The test is applied per channel to the
//! window itself, so the averaged samples are exactly the tested ones:
//!
//! 1. *Stationarity* — the ratio of two variance estimates (the windowed form of the
//!    Cao–Rhinehart R statistic, i.e. the inverse von Neumann ratio):
//!    `R = s1² / s2²`, `s1² = Σ(yᵢ − ȳ)² / (n − 1)`, `s2² = Σ(yᵢ − yᵢ₋₁)² / (2(n − 1))`.
//!    For white noise both estimate σ², so `R ≈ 1` with a standard deviation of about
//!    `1/√n` (0.08 for n = 150). A trend or an oscillation slower than the sample rate
//!    (ringing after a stop, drift) inflates `s1²` but hardly `s2²`: a linear change `D` across
//!    the window gives `R ≈ 1 + D²/(12σ²)`, a sine of amplitude `A` gives `R ≈ 1 + A²/(2σ²)`.
//!    With the default `r_crit = 1.5` (six standard deviations of R above its white-noise
//!    mean for n = 150, so white noise is practically never rejected) a window is steady when
//!    residual ringing is below about σ and drift across the window below about 2.4 σ; the bias
//!    such a residue leaves in the mean is of the order of σ/√n. Correlated (AR(1), φ) noise
//!    has `R = 1/(1 − φ)`: 1.5 tolerates φ ≤ 1/3; raise `r_crit` for a smoother signal.
//! 2. *No outlier* — every sample lies within `outlier_k · s2` of the window mean. A single
//!    spike of height `h` leaves R near 1 (it inflates both estimates alike) but shifts the mean
//!    by `h/n`; with `outlier_k = 5` a window with a white-noise sample beyond 5σ occurs about
//!    once in 10⁴ windows, while a spike of 6σ or more is caught. The window then slides past
//!    the spike (the mean is of consecutive samples, never of a gap-toothed set).
//! 3. *Floor* — a channel whose window standard deviation is at most `std_floor` (channel
//!    units) counts as stationary whatever its R: a quantised signal that does not move has
//!    `s1 = s2 = 0` and R is undefined. Default 0: only an exactly constant window.
//!
//! # Triggers
//!
//! `ExactStop(k)` opens the dwell of pose k (samples with `t_ns ≥` the trigger's time);
//! `MotionStart`, `DwellEnd`, `FeedHold`, `ProgramStart`, `ProgramEnd` close an open dwell.
//! The pose number of a motion start is not used (controllers differ on whether it names the
//! pose left or the pose approached). A pose value is emitted as soon as its window is found; a dwell that closes without one
//! gets a status: [`PoseStatus::DeviceAway`] (no samples in the dwell),
//! [`PoseStatus::BeamInvalid`] (invalid samples broke every run of `samples` consecutive
//! valid ones), [`PoseStatus::NeverSteady`] otherwise (including a dwell too short for a
//! window).
//!
//! Triggers that are processed after samples with later times (queues of different lengths,
//! frames that arrived late) are handled: the detector keeps the samples since the last motion
//! start and at least the last [`LATE_MARGIN_NS`] (10 s), and starts the search at the first
//! sample at or after the trigger's time. A window is taken as soon as it is found: when an
//! exact stop is processed more than its dwell late and its own dwell holds no steady window,
//! the search can run on past the dwell's end, which is not known yet.
//!
//! *Missing exact stop.* A `DwellEnd(k)` after a `MotionStart` but without `ExactStop(k)`: the
//! detector searches the samples between the motion start and the dwell end for the first
//! steady window (motion itself is far from steady, so it is the standstill) and emits it with
//! status [`PoseStatus::TriggerMissing`] — with its mean when one was found (`n > 0`), without
//! (`n = 0`) otherwise. Consumers that take only `Ok` values are unaffected; an analysis may
//! choose to use the recovered ones. A `DwellEnd(k)` while the dwell of another pose is open
//! (a motion start was lost too) is reported `TriggerMissing` without a value: the standstill
//! cannot be told from the previous pose.
//!
//! *No triggers at all* ([`DetectorMode::Plateaus`], chosen in the settings because a run
//! cannot know in advance that no trigger will come): the detector searches
//! for a steady window, emits it as pose 1, 2, 3, … and stays on that plateau until a window
//! is both non-stationary (R > `r_crit`) and has moved away from the plateau mean by more
//! than `max(min_step, outlier_k · plateau std)` in some channel — i.e. until the axis
//! moves; drift slow enough to pass the test, ringing in place and spikes do not start a new
//! pose.
//!
//! The detector is deterministic: it uses only its inputs, in their order, with a fixed order
//! of floating-point operations, so replaying a log reproduces its pose values bit for bit.

use std::collections::VecDeque;

use types::{DetectorMode, PoseStatus, PoseValue, SteadyConfig, SteadyError, TriggerEvent};

/// Samples (in windows) kept while standing between dwells, so that an exact stop processed
/// after later samples (a longer queue) still finds the samples from its time on.
const LATE_MARGIN_WINDOWS: u64 = 4;

/// Time kept behind the newest sample in every triggered state, so that a trigger processed
/// after later samples — a frame that arrived late and is placed at the time the CNC sent it
/// (the daemon's timing model, docs/design.md) — still finds the samples from its time on
/// instead of the oldest one kept. 10 s: a debug build beside two busy loops at load average
/// 13-17 was seen to run a stream 3.7 s behind; bounded by `max_history` like everything else
/// (2¹⁸ samples: 13 s at 20 kHz).
pub const LATE_MARGIN_NS: u64 = 10_000_000_000;

/// Samples fed between two trims of the history: the history may hold up to this many
/// samples more than the states need (and than `max_history`).
const TRIM_EVERY: u64 = 32;

/// Statistics of one window.
struct Window {
    steady: bool,
    mean: Vec<f64>,
    std: Vec<f64>,
    t_first_ns: u64,
    t_last_ns: u64,
}

#[derive(Debug, Clone)]
struct Dwell {
    pose: u32,
    t_start_ns: u64,
    /// Absolute index of the first sample at or after `t_start_ns`.
    first: u64,
    /// Next window end (absolute index) to test.
    next_end: u64,
    done: bool,
}

#[derive(Debug, Clone)]
enum State {
    /// Trigger-free: looking for a plateau; windows end at or after `next_end`.
    Searching { next_end: u64 },
    /// Trigger-free: on the plateau of the last emitted pose.
    Plateau { mean: Vec<f64>, std: Vec<f64> },
    /// Triggered, between dwells: samples since the motion start (`since`, absolute index)
    /// are kept for missing-trigger recovery; `moving` is false before the first motion start.
    Idle {
        since: u64,
        since_t_ns: u64,
        moving: bool,
    },
    /// Triggered, within the dwell of a pose.
    Dwell(Dwell),
}

/// Steady-value detector of one instrument (see the module documentation).
#[derive(Debug, Clone)]
pub struct SteadyDetector {
    cfg: SteadyConfig,
    channels: usize,
    times: VecDeque<u64>,
    /// Invalid samples from the first ever fed up to and including each kept one, so that a
    /// window's validity is one subtraction (`invalid_before` counts those before `base`).
    invalid_upto: VecDeque<u64>,
    invalid_before: u64,
    values: VecDeque<f64>,
    /// Absolute index of `times[0]`.
    base: u64,
    state: State,
    next_plateau_pose: u32,
}

impl SteadyDetector {
    /// A detector for `channels` channels per sample.
    pub fn new(cfg: SteadyConfig, channels: usize) -> Result<Self, SteadyError> {
        cfg.validate()?;
        if channels == 0 {
            return Err(SteadyError::NoChannels);
        }
        let mode = cfg.mode;
        Ok(SteadyDetector {
            cfg,
            channels,
            times: VecDeque::new(),
            invalid_upto: VecDeque::new(),
            invalid_before: 0,
            values: VecDeque::new(),
            base: 0,
            state: match mode {
                DetectorMode::Plateaus => State::Searching { next_end: 0 },
                DetectorMode::Triggers => State::Idle {
                    since: 0,
                    since_t_ns: 0,
                    moving: false,
                },
            },
            next_plateau_pose: 1,
        })
    }

    pub fn config(&self) -> &SteadyConfig {
        &self.cfg
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Absolute index one past the newest sample.
    fn end(&self) -> u64 {
        self.base + self.times.len() as u64
    }

    /// Absolute index of the first kept sample with `t ≥ t_ns` (scanning back from the newest,
    /// so a clock that steps back a little earlier in the history does not matter).
    fn first_at_or_after(&self, t_ns: u64) -> u64 {
        let mut i = self.times.len();
        while i > 0 && self.times[i - 1] >= t_ns {
            i -= 1;
        }
        self.base + i as u64
    }

    /// Feed one sample. `values` must have `channels` entries (missing ones count as invalid).
    pub fn push_sample(&mut self, t_ns: u64, values: &[f64], valid: bool) -> Vec<PoseValue> {
        let ok = valid && values.len() == self.channels && values.iter().all(|v| v.is_finite());
        self.times.push_back(t_ns);
        let invalid = self
            .invalid_upto
            .back()
            .copied()
            .unwrap_or(self.invalid_before);
        self.invalid_upto.push_back(invalid + u64::from(!ok));
        if ok {
            self.values.extend(values.iter().copied());
        } else {
            self.values.extend(std::iter::repeat_n(0.0, self.channels));
        }
        let mut out = Vec::new();
        self.advance(&mut out);
        // Trimming looks up the late margin in the history: once every TRIM_EVERY samples
        // (a function of the input alone, so a replay trims where the run did).
        if self.end().is_multiple_of(TRIM_EVERY) {
            self.trim();
        }
        out
    }

    /// Feed one trigger (its time on the same axis as the samples').
    pub fn push_trigger(&mut self, event: TriggerEvent, pose: u32, t_ns: u64) -> Vec<PoseValue> {
        let mut out = Vec::new();
        if self.cfg.mode == DetectorMode::Plateaus {
            return out;
        }
        match event {
            TriggerEvent::ExactStop => {
                self.close_dwell(t_ns, &mut out);
                let first = self.first_at_or_after(t_ns);
                self.state = State::Dwell(Dwell {
                    pose,
                    t_start_ns: t_ns,
                    first,
                    next_end: first + self.cfg.samples as u64 - 1,
                    done: false,
                });
                self.advance(&mut out);
            }
            TriggerEvent::MotionStart => {
                self.close_dwell(t_ns, &mut out);
                self.state = State::Idle {
                    since: self.first_at_or_after(t_ns),
                    since_t_ns: t_ns,
                    moving: true,
                };
            }
            TriggerEvent::DwellEnd => match &self.state {
                State::Dwell(d) if d.pose == pose => {
                    self.close_dwell(t_ns, &mut out);
                    self.state = State::Idle {
                        since: self.end(),
                        since_t_ns: t_ns,
                        moving: false,
                    };
                }
                State::Dwell(_) => {
                    self.close_dwell(t_ns, &mut out);
                    out.push(Self::missing(pose, t_ns, t_ns));
                    self.state = State::Idle {
                        since: self.end(),
                        since_t_ns: t_ns,
                        moving: false,
                    };
                }
                State::Idle {
                    since,
                    since_t_ns,
                    moving: true,
                } => {
                    let (since, since_t_ns) = (*since, *since_t_ns);
                    let v =
                        match self.first_steady(since, since + self.cfg.samples as u64 - 1, t_ns) {
                            Some(w) => PoseValue {
                                pose,
                                status: PoseStatus::TriggerMissing,
                                n: self.cfg.samples,
                                mean: w.mean,
                                std: w.std,
                                t_first_ns: w.t_first_ns,
                                t_last_ns: w.t_last_ns,
                            },
                            None => Self::missing(pose, since_t_ns, t_ns),
                        };
                    out.push(v);
                    self.state = State::Idle {
                        since: self.end(),
                        since_t_ns: t_ns,
                        moving: false,
                    };
                }
                _ => {
                    out.push(Self::missing(pose, t_ns, t_ns));
                }
            },
            TriggerEvent::ProgramStart | TriggerEvent::ProgramEnd | TriggerEvent::FeedHold => {
                self.close_dwell(t_ns, &mut out);
                self.state = State::Idle {
                    since: self.end(),
                    since_t_ns: t_ns,
                    moving: false,
                };
            }
        }
        self.trim();
        out
    }

    /// End of input: closes an open dwell.
    pub fn finish(&mut self, t_ns: u64) -> Vec<PoseValue> {
        let mut out = Vec::new();
        self.close_dwell(t_ns, &mut out);
        if self.cfg.mode == DetectorMode::Triggers {
            self.state = State::Idle {
                since: self.end(),
                since_t_ns: t_ns,
                moving: false,
            };
        }
        out
    }

    fn missing(pose: u32, t_first_ns: u64, t_last_ns: u64) -> PoseValue {
        PoseValue {
            pose,
            status: PoseStatus::TriggerMissing,
            n: 0,
            mean: Vec::new(),
            std: Vec::new(),
            t_first_ns,
            t_last_ns,
        }
    }

    /// The first steady window ending at `from_end` or later whose samples all lie at or
    /// before `t_max_ns`.
    fn first_steady(&self, start: u64, from_end: u64, t_max_ns: u64) -> Option<Window> {
        // No window ends before the oldest kept sample's n-th (the history may have been
        // trimmed past `start`: times that step back, a long dwell).
        let n = self.cfg.samples as u64;
        let mut e = from_end.max(start + n - 1).max(self.base + n - 1);
        while e < self.end() {
            if self.times[(e - self.base) as usize] > t_max_ns {
                break;
            }
            if let Some(w) = self.steady_window(e) {
                return Some(w);
            }
            e += 1;
        }
        None
    }

    /// Closes an open dwell at `t_ns`, emitting its status if it has no value yet.
    fn close_dwell(&mut self, t_ns: u64, out: &mut Vec<PoseValue>) {
        let State::Dwell(d) = &self.state else { return };
        if d.done {
            return;
        }
        let (mut samples, mut invalid, mut run, mut max_run) = (0u64, 0u64, 0usize, 0usize);
        let start = d.first.max(self.base);
        for i in start..self.end() {
            let k = (i - self.base) as usize;
            if self.times[k] > t_ns {
                break;
            }
            samples += 1;
            if self.is_valid(k) {
                run += 1;
                max_run = max_run.max(run);
            } else {
                run = 0;
                invalid += 1;
            }
        }
        let status = if samples == 0 {
            PoseStatus::DeviceAway
        } else if max_run < self.cfg.samples && invalid > 0 {
            PoseStatus::BeamInvalid
        } else {
            // Long enough but never steady, or all valid but too short to settle and average.
            PoseStatus::NeverSteady
        };
        out.push(PoseValue {
            pose: d.pose,
            status,
            n: 0,
            mean: Vec::new(),
            std: Vec::new(),
            t_first_ns: d.t_start_ns,
            t_last_ns: t_ns.max(d.t_start_ns),
        });
        if let State::Dwell(d) = &mut self.state {
            d.done = true;
        }
    }

    /// Tests the windows that the newest samples complete.
    fn advance(&mut self, out: &mut Vec<PoseValue>) {
        let n = self.cfg.samples as u64;
        let end = self.end();
        match &mut self.state {
            State::Dwell(d) if !d.done => {
                let (first, from) = (d.first, d.next_end);
                let mut e = from;
                let mut found = None;
                while e < end {
                    if e + 1 >= first + n
                        && let Some(w) = self.steady_window(e)
                    {
                        found = Some(w);
                        break;
                    }
                    e += 1;
                }
                let State::Dwell(d) = &mut self.state else {
                    unreachable!()
                };
                d.next_end = e;
                if let Some(w) = found {
                    d.done = true;
                    out.push(PoseValue {
                        pose: d.pose,
                        status: PoseStatus::Ok,
                        n: self.cfg.samples,
                        mean: w.mean,
                        std: w.std,
                        t_first_ns: w.t_first_ns,
                        t_last_ns: w.t_last_ns,
                    });
                }
            }
            State::Searching { next_end } => {
                let mut e = (*next_end).max(self.base + n - 1);
                while e < end {
                    if let Some(w) = self.steady_window(e) {
                        let pose = self.next_plateau_pose;
                        self.next_plateau_pose += 1;
                        out.push(PoseValue {
                            pose,
                            status: PoseStatus::Ok,
                            n: self.cfg.samples,
                            mean: w.mean.clone(),
                            std: w.std.clone(),
                            t_first_ns: w.t_first_ns,
                            t_last_ns: w.t_last_ns,
                        });
                        self.state = State::Plateau {
                            mean: w.mean,
                            std: w.std,
                        };
                        return;
                    }
                    e += 1;
                }
                self.state = State::Searching { next_end: e };
            }
            State::Plateau { mean, std } => {
                let (pm, ps) = (mean.clone(), std.clone());
                if end < n {
                    return;
                }
                if let Some(w) = self.window(end - 1)
                    && !w.steady
                {
                    let moved = (0..self.channels).any(|c| {
                        let tol = self
                            .cfg
                            .min_step
                            .max(self.cfg.outlier_k * ps[c].max(self.cfg.std_floor));
                        (w.mean[c] - pm[c]).abs() > tol
                    });
                    if moved {
                        self.state = State::Searching {
                            next_end: end - 1 + n,
                        };
                    }
                }
            }
            _ => {}
        }
    }

    /// Whether the kept sample at `k` (index into the history) is valid.
    fn is_valid(&self, k: usize) -> bool {
        let before = if k == 0 {
            self.invalid_before
        } else {
            self.invalid_upto[k - 1]
        };
        self.invalid_upto[k] == before
    }

    /// History index of the first sample of the window of `samples` samples ending at absolute
    /// index `end_idx`, or None when it is not wholly kept or holds an invalid sample.
    fn window_start(&self, end_idx: u64) -> Option<usize> {
        let n = self.cfg.samples;
        if end_idx + 1 < self.base + n as u64 || end_idx >= self.end() {
            return None;
        }
        let k0 = (end_idx + 1 - self.base) as usize - n;
        let before = if k0 == 0 {
            self.invalid_before
        } else {
            self.invalid_upto[k0 - 1]
        };
        (self.invalid_upto[k0 + n - 1] == before).then_some(k0)
    }

    /// Mean, standard deviation and steadiness of channel `c` over the window starting at
    /// history index `k0` (the steady-state test of the module documentation).
    fn channel_stats(&self, k0: usize, c: usize) -> (f64, f64, bool) {
        let n = self.cfg.samples;
        let ch = self.channels;
        let y = |k: usize| self.values[k * ch + c];
        let mut sum = 0.0;
        for k in k0..k0 + n {
            sum += y(k);
        }
        let m = sum / n as f64;
        let (mut ss, mut sd, mut max_dev) = (0.0f64, 0.0f64, 0.0f64);
        let mut prev = y(k0);
        for k in k0..k0 + n {
            let v = y(k);
            let dev = v - m;
            ss += dev * dev;
            let d = v - prev;
            sd += d * d;
            prev = v;
            max_dev = max_dev.max(dev.abs());
        }
        let s1_sq = ss / (n - 1) as f64;
        let s2_sq = sd / (2 * (n - 1)) as f64;
        let s1 = s1_sq.sqrt();
        let s2 = s2_sq.sqrt();
        let floor = self.cfg.std_floor;
        let stationary = s1 <= floor || s1_sq <= self.cfg.r_crit * s2_sq;
        let no_outlier = max_dev <= self.cfg.outlier_k * s2.max(floor);
        (m, s1, stationary && no_outlier)
    }

    /// Statistics of the window of `samples` samples ending at absolute index `end_idx`, or
    /// None when it is not wholly kept or holds an invalid sample.
    fn window(&self, end_idx: u64) -> Option<Window> {
        let k0 = self.window_start(end_idx)?;
        let ch = self.channels;
        let mut mean = Vec::with_capacity(ch);
        let mut std = Vec::with_capacity(ch);
        let mut steady = true;
        for c in 0..ch {
            let (m, s1, ok) = self.channel_stats(k0, c);
            steady &= ok;
            mean.push(m);
            std.push(s1);
        }
        Some(Window {
            steady,
            mean,
            std,
            t_first_ns: self.times[k0],
            t_last_ns: self.times[k0 + self.cfg.samples - 1],
        })
    }

    /// [`Self::window`] when it is steady. The windows tested while a signal settles are
    /// mostly not: the test stops at the first channel that fails, and the statistics are
    /// gathered (the same arithmetic again) only for the steady one.
    fn steady_window(&self, end_idx: u64) -> Option<Window> {
        let k0 = self.window_start(end_idx)?;
        if (0..self.channels).all(|c| self.channel_stats(k0, c).2) {
            self.window(end_idx)
        } else {
            None
        }
    }

    /// Drops samples no state needs any more.
    fn trim(&mut self) {
        let n = self.cfg.samples as u64;
        let end = self.end();
        let recent = end.saturating_sub(n);
        // The first sample within LATE_MARGIN_NS of the newest (times are in arrival order and
        // nearly sorted: a clock fit's small steps back do not matter for a margin).
        let late = {
            let cutoff = self
                .times
                .back()
                .map_or(0, |t| t.saturating_sub(LATE_MARGIN_NS));
            self.base + self.times.partition_point(|&t| t < cutoff) as u64
        };
        let keep_from = match &self.state {
            State::Searching { .. } | State::Plateau { .. } => recent,
            // Moving: everything since the motion start (missing-exact-stop recovery).
            State::Idle {
                since,
                moving: true,
                ..
            } => (*since).min(recent).min(late),
            // Standing between dwells: a margin for an exact stop processed late.
            State::Idle { .. } => end.saturating_sub(LATE_MARGIN_WINDOWS * n).min(late),
            State::Dwell(d) if !d.done => d.first.min(recent).min(late),
            State::Dwell(_) => recent.min(late),
        };
        let keep_from = keep_from.max(end.saturating_sub(self.cfg.max_history as u64));
        let drop = keep_from
            .saturating_sub(self.base)
            .min(self.times.len() as u64) as usize;
        if drop == 0 {
            return;
        }
        self.invalid_before = self.invalid_upto[drop - 1];
        self.times.drain(..drop);
        self.invalid_upto.drain(..drop);
        self.values.drain(..drop * self.channels);
        self.base += drop as u64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    const FS_HZ: f64 = 1000.0;
    const T0_NS: u64 = 1_700_000_000_000_000_000;
    const SIGMA: f64 = 0.01;
    const N: usize = 150;

    fn t_ns(t_s: f64) -> u64 {
        (T0_NS as i64 + (t_s * 1e9).round() as i64) as u64
    }

    enum Ev {
        S(u64, Vec<f64>, bool),
        T(TriggerEvent, u32, u64),
    }

    /// Samples of `f(t_s)` plus white noise from `t_from_s` to `t_to_s` at 1 kHz.
    fn sampled(f: impl Fn(f64) -> f64, t_from_s: f64, t_to_s: f64, seed: u64) -> Vec<Ev> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, SIGMA).unwrap();
        let mut out = Vec::new();
        let mut i = (t_from_s * FS_HZ).round() as i64;
        while (i as f64) / FS_HZ < t_to_s {
            let t = i as f64 / FS_HZ;
            out.push(Ev::S(t_ns(t), vec![f(t) + noise.sample(&mut rng)], true));
            i += 1;
        }
        out
    }

    fn trig(kind: TriggerEvent, pose: u32, t_s: f64) -> Ev {
        Ev::T(kind, pose, t_ns(t_s))
    }

    /// Sorted by time; a trigger goes before samples of the same time.
    fn merge(mut evs: Vec<Ev>) -> Vec<Ev> {
        evs.sort_by_key(|e| match e {
            Ev::S(t, ..) => (*t, 1),
            Ev::T(_, _, t) => (*t, 0),
        });
        evs
    }

    fn run(cfg: SteadyConfig, channels: usize, evs: &[Ev]) -> Vec<PoseValue> {
        let mut d = SteadyDetector::new(cfg, channels).unwrap();
        let mut out = Vec::new();
        let mut last = T0_NS;
        for e in evs {
            match e {
                Ev::S(t, v, ok) => {
                    last = *t;
                    out.extend(d.push_sample(*t, v, *ok))
                }
                Ev::T(k, p, t) => out.extend(d.push_trigger(*k, *p, *t)),
            }
        }
        out.extend(d.finish(last));
        out
    }

    /// Move from `from` to `to` between `t_move_s` and `t_stop_s` (linear), then ring with
    /// amplitude `ring` decaying with `tau_s` at 40 Hz, plus `drift_per_s` after the stop.
    fn axis(
        from: f64,
        to: f64,
        t_move_s: f64,
        t_stop_s: f64,
        ring: f64,
        tau_s: f64,
        drift_per_s: f64,
    ) -> impl Fn(f64) -> f64 {
        move |t| {
            if t < t_move_s {
                from
            } else if t < t_stop_s {
                from + (to - from) * (t - t_move_s) / (t_stop_s - t_move_s)
            } else {
                let dt = t - t_stop_s;
                to + ring * (-dt / tau_s).exp() * (2.0 * std::f64::consts::PI * 40.0 * dt).sin()
                    + drift_per_s * dt
            }
        }
    }

    fn mean_of_first_after(evs: &[Ev], t_from: u64, n: usize) -> f64 {
        let v: Vec<f64> = evs
            .iter()
            .filter_map(|e| match e {
                Ev::S(t, v, true) if *t >= t_from => Some(v[0]),
                _ => None,
            })
            .take(n)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    }

    /// Tolerance of a mean of N white-noise samples: 4 standard errors.
    fn tol() -> f64 {
        4.0 * SIGMA / (N as f64).sqrt()
    }

    #[test]
    fn ringing_after_the_stop_is_excluded() {
        let (ring, tau) = (2.0, 0.1);
        let f = axis(0.0, 100.0, 0.0, 0.5, ring, tau, 0.0);
        let mut evs = sampled(&f, -0.2, 2.5, 1);
        evs.push(trig(TriggerEvent::MotionStart, 0, 0.0));
        evs.push(trig(TriggerEvent::ExactStop, 1, 0.5));
        evs.push(trig(TriggerEvent::DwellEnd, 1, 2.5));
        let evs = merge(evs);
        // A naive mean of the 150 samples after the stop holds the ringing.
        let naive = mean_of_first_after(&evs, t_ns(0.5), N);
        assert!((naive - 100.0).abs() > 10.0 * tol(), "naive {naive}");
        let out = run(SteadyConfig::default(), 1, &evs);
        assert_eq!(out.len(), 1, "{out:?}");
        let p = &out[0];
        assert_eq!((p.pose, p.status, p.n), (1, PoseStatus::Ok, N));
        assert!((p.mean[0] - 100.0).abs() < tol(), "mean {}", p.mean[0]);
        // The window starts once the ringing envelope is of the order of the noise: not before
        // it fell below 4σ, not long after it fell below σ/2.
        let start_s = (p.t_first_ns - t_ns(0.5)) as f64 * 1e-9;
        let lo = tau * (ring / (4.0 * SIGMA)).ln();
        let hi = tau * (ring / (0.5 * SIGMA)).ln();
        assert!(
            start_s > lo && start_s < hi,
            "window starts {start_s} s after the stop, expected {lo}..{hi}"
        );
        assert_eq!(p.t_last_ns - p.t_first_ns, (N as u64 - 1) * 1_000_000);
        // The test admits a residue up to R = r_crit: std ≤ √1.5·σ (plus the scatter of R).
        assert!(
            p.std[0] > 0.8 * SIGMA && p.std[0] < 1.5f64.sqrt() * 1.15 * SIGMA,
            "std {}",
            p.std[0]
        );
    }

    #[test]
    fn drift_in_the_dwell_takes_the_first_settled_window() {
        // Drift of one sigma per window length: slow enough to pass the test.
        let (ring, tau, drift) = (1.0, 0.08, SIGMA / 0.15);
        let f = axis(0.0, 50.0, 0.0, 0.4, ring, tau, drift);
        let mut evs = sampled(&f, 0.0, 4.0, 2);
        evs.push(trig(TriggerEvent::MotionStart, 0, 0.0));
        evs.push(trig(TriggerEvent::ExactStop, 7, 0.4));
        evs.push(trig(TriggerEvent::DwellEnd, 7, 4.0));
        let out = run(SteadyConfig::default(), 1, &merge(evs));
        assert_eq!(out.len(), 1);
        let p = &out[0];
        assert_eq!((p.pose, p.status), (7, PoseStatus::Ok));
        let start_s = (p.t_first_ns - t_ns(0.4)) as f64 * 1e-9;
        let lo = tau * (ring / (4.0 * SIGMA)).ln();
        let hi = tau * (ring / (0.5 * SIGMA)).ln();
        assert!(
            start_s > lo && start_s < hi,
            "window starts {start_s} s after the stop"
        );
        // A linear drift averages to its value at the window centre.
        let centre_s = ((p.t_first_ns + p.t_last_ns) / 2 - t_ns(0.4)) as f64 * 1e-9;
        let expected = 50.0 + drift * centre_s;
        assert!(
            (p.mean[0] - expected).abs() < tol(),
            "mean {} expected {expected}",
            p.mean[0]
        );
        // The end of the dwell is far off: the first window matters.
        assert!(drift * (3.6 - centre_s) > 10.0 * tol());
    }

    #[test]
    fn a_spike_is_not_averaged() {
        let spike = 200.0 * SIGMA;
        let f = axis(0.0, 20.0, 0.0, 0.3, 0.0, 0.1, 0.0);
        let mut evs = sampled(&f, 0.0, 2.0, 3);
        // Spike 60 samples after the stop.
        let t_spike = t_ns(0.36);
        for e in evs.iter_mut() {
            if let Ev::S(t, v, _) = e
                && *t == t_spike
            {
                v[0] += spike;
            }
        }
        evs.push(trig(TriggerEvent::MotionStart, 0, 0.0));
        evs.push(trig(TriggerEvent::ExactStop, 2, 0.3));
        evs.push(trig(TriggerEvent::DwellEnd, 2, 2.0));
        let evs = merge(evs);
        let naive = mean_of_first_after(&evs, t_ns(0.3), N);
        assert!((naive - 20.0).abs() > 3.0 * tol(), "naive {naive}");
        let out = run(SteadyConfig::default(), 1, &evs);
        assert_eq!(out.len(), 1);
        let p = &out[0];
        assert_eq!(p.status, PoseStatus::Ok);
        assert!((p.mean[0] - 20.0).abs() < tol(), "mean {}", p.mean[0]);
        assert!(
            !(p.t_first_ns..=p.t_last_ns).contains(&t_spike),
            "window holds the spike"
        );
    }

    #[test]
    fn missing_exact_stop_is_recovered_and_flagged() {
        let f = axis(5.0, 30.0, 0.0, 0.5, 1.0, 0.08, 0.0);
        let mut evs = sampled(&f, -0.5, 2.5, 4);
        evs.push(trig(TriggerEvent::MotionStart, 3, 0.0));
        evs.push(trig(TriggerEvent::DwellEnd, 4, 2.5));
        let out = run(SteadyConfig::default(), 1, &merge(evs));
        assert_eq!(out.len(), 1, "{out:?}");
        let p = &out[0];
        assert_eq!((p.pose, p.status, p.n), (4, PoseStatus::TriggerMissing, N));
        assert!((p.mean[0] - 30.0).abs() < tol(), "mean {}", p.mean[0]);
        assert!(p.t_first_ns > t_ns(0.5));
    }

    #[test]
    fn missing_exact_stop_and_motion_start_gives_no_value() {
        // Pose 1 measured, then its motion start and pose 2's exact stop are lost.
        let f = |t: f64| {
            if t < 1.0 {
                10.0
            } else if t < 1.5 {
                10.0 + 20.0 * (t - 1.0)
            } else {
                20.0
            }
        };
        let mut evs = sampled(f, 0.0, 3.0, 5);
        evs.push(trig(TriggerEvent::ExactStop, 1, 0.0));
        evs.push(trig(TriggerEvent::DwellEnd, 2, 3.0));
        let out = run(SteadyConfig::default(), 1, &merge(evs));
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!((out[0].pose, out[0].status), (1, PoseStatus::Ok));
        assert!((out[0].mean[0] - 10.0).abs() < tol());
        assert_eq!(
            (out[1].pose, out[1].status, out[1].n),
            (2, PoseStatus::TriggerMissing, 0)
        );
    }

    #[test]
    fn late_trigger_time_and_late_processing() {
        // The exact stop is stamped 0.8 s after the axis settled: the value is the same plateau.
        let f = axis(0.0, 42.0, 0.0, 0.5, 2.0, 0.1, 0.0);
        let mut evs = sampled(&f, 0.0, 3.0, 6);
        evs.push(trig(TriggerEvent::MotionStart, 0, 0.0));
        evs.push(trig(TriggerEvent::ExactStop, 1, 1.3));
        evs.push(trig(TriggerEvent::DwellEnd, 1, 3.0));
        let evs = merge(evs);
        let in_order = run(SteadyConfig::default(), 1, &evs);
        assert_eq!(in_order.len(), 1);
        let p = &in_order[0];
        assert_eq!(p.status, PoseStatus::Ok);
        assert!((p.mean[0] - 42.0).abs() < tol());
        // Steady at once: the window starts at the trigger.
        assert_eq!(p.t_first_ns, t_ns(1.3));

        // The same trigger processed 500 samples late (a longer queue): identical result.
        let mut late: Vec<Ev> = Vec::new();
        let mut held = None;
        let mut count_after = 0;
        for e in evs {
            match e {
                Ev::T(TriggerEvent::ExactStop, p, t) => {
                    held = Some(Ev::T(TriggerEvent::ExactStop, p, t))
                }
                Ev::S(..) if held.is_some() => {
                    late.push(e);
                    count_after += 1;
                    if count_after == 500 {
                        late.push(held.take().unwrap());
                    }
                }
                e => late.push(e),
            }
        }
        assert_eq!(run(SteadyConfig::default(), 1, &late), in_order);
    }

    #[test]
    fn statuses_of_unmeasurable_poses() {
        let cfg = SteadyConfig::default();
        // No samples during the dwell.
        let mut evs = sampled(|_| 1.0, 0.0, 1.0, 7);
        evs.extend(sampled(|_| 1.0, 3.0, 4.0, 8));
        evs.push(trig(TriggerEvent::ExactStop, 1, 1.2));
        evs.push(trig(TriggerEvent::DwellEnd, 1, 2.8));
        let out = run(cfg.clone(), 1, &merge(evs));
        assert_eq!(out.len(), 1);
        assert_eq!(
            (out[0].status, out[0].n, out[0].t_first_ns, out[0].t_last_ns),
            (PoseStatus::DeviceAway, 0, t_ns(1.2), t_ns(2.8))
        );

        // Beam interrupted every 100 samples: never 150 consecutive valid ones.
        let mut evs = sampled(|_| 1.0, 0.0, 2.0, 9);
        for (i, e) in evs.iter_mut().enumerate() {
            if let Ev::S(_, _, ok) = e
                && i % 100 == 0
            {
                *ok = false;
            }
        }
        evs.push(trig(TriggerEvent::ExactStop, 1, 0.1));
        evs.push(trig(TriggerEvent::DwellEnd, 1, 1.9));
        let out = run(cfg.clone(), 1, &merge(evs));
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].status, PoseStatus::BeamInvalid);

        // Vibration that never decays.
        let mut evs = sampled(
            |t| (2.0 * std::f64::consts::PI * 5.0 * t).sin(),
            0.0,
            2.0,
            10,
        );
        evs.push(trig(TriggerEvent::ExactStop, 1, 0.1));
        evs.push(trig(TriggerEvent::MotionStart, 1, 1.9));
        let out = run(cfg, 1, &merge(evs));
        assert_eq!(out.len(), 1);
        assert_eq!((out[0].pose, out[0].status), (1, PoseStatus::NeverSteady));
    }

    #[test]
    fn feed_hold_and_program_end_close_the_dwell() {
        // Feed hold 0.1 s after the stop, while it still rings: never steady, and nothing
        // after the hold is taken for the pose even though the axis then stands still.
        let f = axis(0.0, 10.0, 0.0, 0.5, 2.0, 0.1, 0.0);
        let mut evs = sampled(&f, 0.0, 3.0, 15);
        evs.push(trig(TriggerEvent::ExactStop, 1, 0.5));
        evs.push(trig(TriggerEvent::FeedHold, 0, 0.6));
        evs.push(trig(TriggerEvent::ExactStop, 2, 1.5));
        evs.push(trig(TriggerEvent::ProgramEnd, 0, 1.55));
        let out = run(SteadyConfig::default(), 1, &merge(evs));
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(
            (out[0].pose, out[0].status, out[0].t_last_ns),
            (1, PoseStatus::NeverSteady, t_ns(0.6))
        );
        // Pose 2: only 50 samples before the program end: too short, not a beam problem.
        assert_eq!((out[1].pose, out[1].status), (2, PoseStatus::NeverSteady));
    }

    #[test]
    fn all_channels_must_settle() {
        // Channel 1 rings much longer than channel 0.
        let f0 = axis(0.0, 1.0, 0.0, 0.2, 0.5, 0.02, 0.0);
        let f1 = axis(0.0, -3.0, 0.0, 0.2, 3.0, 0.15, 0.0);
        let a = sampled(&f0, 0.0, 3.0, 11);
        let b = sampled(&f1, 0.0, 3.0, 12);
        let mut evs: Vec<Ev> = a
            .into_iter()
            .zip(b)
            .map(|(x, y)| match (x, y) {
                (Ev::S(t, v0, _), Ev::S(_, v1, _)) => Ev::S(t, vec![v0[0], v1[0]], true),
                _ => unreachable!(),
            })
            .collect();
        evs.push(trig(TriggerEvent::ExactStop, 1, 0.2));
        let out = run(SteadyConfig::default(), 2, &merge(evs));
        assert_eq!(out.len(), 1);
        let p = &out[0];
        assert!(
            (p.mean[0] - 1.0).abs() < tol() && (p.mean[1] + 3.0).abs() < tol(),
            "{p:?}"
        );
        let start_s = (p.t_first_ns - t_ns(0.2)) as f64 * 1e-9;
        assert!(
            start_s > 0.15 * (3.0 / (4.0 * SIGMA)).ln(),
            "started {start_s}"
        );
    }

    #[test]
    fn trigger_free_plateaus_are_found_and_numbered() {
        // Five stops 1 mm apart, 1.5 s dwell, ringing after each stop, a slow drift on all.
        let targets = [0.0, 1000.0, 2000.0, 3000.0, 4000.0];
        let f = move |t: f64| {
            let cycle = 2.0;
            let k = ((t / cycle).floor() as usize).min(targets.len() - 1);
            let tc = t - k as f64 * cycle;
            let from = if k == 0 { -1000.0 } else { targets[k - 1] };
            axis(from, targets[k], 0.0, 0.5, 2.0, 0.08, 0.0)(tc) + 0.002 * t
        };
        let evs = sampled(f, 0.0, 10.0, 13);
        let cfg = SteadyConfig {
            mode: DetectorMode::Plateaus,
            ..SteadyConfig::default()
        };
        let out = run(cfg, 1, &evs);
        assert_eq!(out.len(), 5, "{out:?}");
        for (i, p) in out.iter().enumerate() {
            assert_eq!((p.pose, p.status), (i as u32 + 1, PoseStatus::Ok));
            let centre_s = ((p.t_first_ns + p.t_last_ns) / 2 - T0_NS) as f64 * 1e-9;
            let expected = targets[i] + 0.002 * centre_s;
            assert!(
                (p.mean[0] - expected).abs() < tol(),
                "pose {} mean {} expected {expected}",
                p.pose,
                p.mean[0]
            );
        }
    }

    #[test]
    fn deterministic_bit_for_bit() {
        let f = axis(0.0, 100.0, 0.0, 0.5, 2.0, 0.1, 0.01);
        let mut evs = sampled(&f, 0.0, 2.0, 14);
        evs.push(trig(TriggerEvent::ExactStop, 1, 0.5));
        let evs = merge(evs);
        let a = run(SteadyConfig::default(), 1, &evs);
        let b = run(SteadyConfig::default(), 1, &evs);
        assert_eq!(a.len(), 1);
        assert_eq!(a[0].mean[0].to_bits(), b[0].mean[0].to_bits());
        assert_eq!(a[0].std[0].to_bits(), b[0].std[0].to_bits());
    }

    #[test]
    fn bad_settings_are_refused() {
        let bad = |f: fn(&mut SteadyConfig)| {
            let mut c = SteadyConfig::default();
            f(&mut c);
            SteadyDetector::new(c, 1).unwrap_err()
        };
        assert_eq!(bad(|c| c.samples = 2), SteadyError::TooFewSamples(2));
        assert!(matches!(
            bad(|c| c.r_crit = f64::NAN),
            SteadyError::BadThreshold("r_crit", _)
        ));
        assert!(matches!(
            bad(|c| c.std_floor = -1.0),
            SteadyError::Negative("std_floor", _)
        ));
        assert_eq!(
            bad(|c| c.max_history = 10),
            SteadyError::HistoryTooShort(10, 150)
        );
        assert_eq!(
            SteadyDetector::new(SteadyConfig::default(), 0).unwrap_err(),
            SteadyError::NoChannels
        );
    }

    mod prop {
        use super::super::*;
        use proptest::prelude::*;

        #[derive(Debug, Clone)]
        enum In {
            S(u64, f64, f64, bool),
            T(u8, u32, u64),
        }

        fn input() -> impl Strategy<Value = In> {
            prop_oneof![
                8 => (0u64..5_000_000, prop_oneof![Just(f64::NAN), Just(f64::INFINITY), -1e3f64..1e3], -1.0f64..1.0, any::<bool>())
                    .prop_map(|(t, a, b, v)| In::S(t, a, b, v)),
                1 => (0u8..6, 0u32..5, 0u64..5_000_000).prop_map(|(k, p, t)| In::T(k, p, t)),
            ]
        }

        fn kind(k: u8) -> TriggerEvent {
            [
                TriggerEvent::MotionStart,
                TriggerEvent::ExactStop,
                TriggerEvent::DwellEnd,
                TriggerEvent::ProgramStart,
                TriggerEvent::ProgramEnd,
                TriggerEvent::FeedHold,
            ][k as usize]
        }

        fn feed(mode: DetectorMode, ins: &[In]) -> Vec<PoseValue> {
            let cfg = SteadyConfig {
                samples: 5,
                mode,
                max_history: 64,
                ..SteadyConfig::default()
            };
            let mut d = SteadyDetector::new(cfg, 2).unwrap();
            let mut out = Vec::new();
            let mut t_sorted = 0u64;
            for i in ins {
                match *i {
                    In::S(dt, a, b, v) => {
                        // Mostly increasing times with occasional steps back.
                        t_sorted = (t_sorted + dt / 1000).saturating_sub(if dt % 17 == 0 {
                            dt
                        } else {
                            0
                        });
                        out.extend(d.push_sample(t_sorted, &[a, b], v));
                    }
                    In::T(k, p, dt) => out.extend(d.push_trigger(kind(k), p, t_sorted + dt % 3000)),
                }
            }
            out.extend(d.finish(t_sorted));
            out
        }

        proptest! {
            #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]
            /// Any input, in any order: no panic, well-formed values, the same output twice.
            #[test]
            fn any_input_gives_well_formed_values(ins in prop::collection::vec(input(), 0..400)) {
                for mode in [DetectorMode::Triggers, DetectorMode::Plateaus] {
                    let out = feed(mode, &ins);
                    for v in &out {
                        if v.n == 0 {
                            prop_assert!(v.mean.is_empty() && v.std.is_empty());
                            prop_assert!(v.status != PoseStatus::Ok);
                        } else {
                            prop_assert_eq!(v.n, 5);
                            prop_assert_eq!(v.mean.len(), 2);
                            prop_assert!(v.mean.iter().chain(&v.std).all(|x| x.is_finite()));
                        }
                    }
                    let again = feed(mode, &ins);
                    prop_assert_eq!(format!("{out:?}"), format!("{again:?}"));
                }
            }
        }
    }
}
