//! Device-clock fitting: a robust running fit of a device clock against the host clock.
//!
//! Every sample carries the device's own clock `d` (µs) and the host's arrival time `h` (ns).
//! Arrival is the send time plus a delay that is never negative and heavy-tailed (USB polling,
//! scheduler, the driver reading in batches). A least-squares fit through all points would be
//! pulled up and tilted by those delays, so the fit is made through the *lower envelope*: the
//! device time axis is cut into windows, the point of least delay of each window is kept (the
//! sample that waited least), and the straight line `h = h0 + 1000·(d − d0) + a + c·(d − d0)`
//! is the one under all those minima that lies highest at their mean (the linear-programming
//! estimate of Moon et al. 1999: an edge of their lower convex hull). Windows in which every
//! sample was delayed (a stall) lie above it and do not matter. The slope excess `c` (ns per
//! µs) gives the drift: the device clock runs `1000/(1000 + c) − 1` fast.
//!
//! Why not least squares through the minima: on a loaded host the minimum delay of a window
//! is itself noisy and skewed (whether a read happened just after a device write), and a
//! least-squares line follows that noise; the envelope only needs the few least-delayed
//! windows near either end of the run.
//!
//! Device clocks wrap (CB-3 `t_us` is u32) and sequence numbers wrap (u16, u32): [`Unwrap`]
//! extends them to u64 before anything is fitted or counted.

use std::collections::VecDeque;

/// Robust running fit of device time (µs) against host arrival time (ns).
#[derive(Debug, Clone)]
pub struct ClockFit {
    window_us: u64,
    max_windows: usize,
    /// First point of the fit: (device µs, host ns); everything is kept relative to it so the
    /// arithmetic stays well inside f64 precision.
    origin: Option<(u64, u64)>,
    /// The window being filled: (index of the window, x of its best point, r of its best point).
    current: Option<(u64, f64, f64)>,
    /// Lower-envelope points of the closed windows: (x µs since origin, r ns excess).
    minima: VecDeque<(f64, f64)>,
    /// Fitted line `r = a + c·x`.
    line: Option<(f64, f64)>,
    /// Least excess `r` of every point so far, the first window included: the offset-only
    /// estimate [`ClockFit::estimate`] uses until the line exists.
    floor: Option<f64>,
}

/// Windows needed before the fit is used (with fewer, [`ClockFit::map`] gives `None`).
pub const MIN_WINDOWS: usize = 3;

/// Largest drift the fit will believe, ppm. The data sheets promise at most ±100 ppm; a fit
/// steeper than twice that comes from a few windows of which one was stalled (a loaded host
/// early in a run), and extrapolating such a slope moves samples by hundreds of milliseconds
/// against the triggers. Such a fit is replaced by the highest line of the bounding slope under
/// all windows.
pub const MAX_DRIFT_PPM: f64 = 200.0;

impl Default for ClockFit {
    /// Windows of 0.5 s of device time, the last 600 of them (5 minutes) in the fit.
    fn default() -> Self {
        ClockFit::new(500_000, 600)
    }
}

impl ClockFit {
    /// A fit over windows of `window_us` device microseconds, keeping the last `max_windows`.
    pub fn new(window_us: u64, max_windows: usize) -> Self {
        ClockFit {
            window_us: window_us.max(1),
            max_windows: max_windows.max(MIN_WINDOWS),
            origin: None,
            current: None,
            minima: VecDeque::new(),
            line: None,
            floor: None,
        }
    }

    /// Forget everything (the device restarted or was reconnected).
    pub fn reset(&mut self) {
        self.origin = None;
        self.current = None;
        self.minima.clear();
        self.line = None;
        self.floor = None;
    }

    /// Number of closed windows in the fit.
    #[cfg(test)]
    pub fn windows(&self) -> usize {
        self.minima.len()
    }

    fn rel(&self, device_us: u64, host_ns: u64) -> (f64, f64) {
        let (d0, h0) = self.origin.unwrap_or((device_us, host_ns));
        let x = device_us as i128 - d0 as i128;
        let r = (host_ns as i128 - h0 as i128) - x * 1000;
        (x as f64, r as f64)
    }

    /// Add one sample: unwrapped device time in µs and host arrival time in ns.
    pub fn push(&mut self, device_us: u64, host_ns: u64) {
        if self.origin.is_none() {
            self.origin = Some((device_us, host_ns));
        }
        let (x, r) = self.rel(device_us, host_ns);
        self.floor = Some(self.floor.map_or(r, |f| f.min(r)));
        let idx = (x.max(0.0) as u64) / self.window_us;
        // The first window is left out: its samples arrive while the driver is still in its
        // command exchange (reading at once, not in batches) and a device starting its stream
        // sends the first sample with no lag, so their delays sit lower than the rest and
        // would tilt the envelope.
        if idx == 0 {
            return;
        }
        // Within a window, rank points by their distance above the current line so that the
        // drift across the window does not favour one end of it.
        let c = self.line.map_or(0.0, |(_, c)| c);
        match self.current {
            Some((w, bx, br)) if w == idx => {
                if r - c * x < br - c * bx {
                    self.current = Some((w, x, r));
                }
            }
            Some((w, bx, br)) if idx > w => {
                self.minima.push_back((bx, br));
                while self.minima.len() > self.max_windows {
                    self.minima.pop_front();
                }
                self.current = Some((idx, x, r));
                self.refit();
            }
            // A point of an earlier window (out of order): ignore it.
            Some(_) => {}
            None => self.current = Some((idx, x, r)),
        }
    }

    fn refit(&mut self) {
        if self.minima.len() < MIN_WINDOWS {
            return;
        }
        let points = self.minima.make_contiguous();
        // Slope excess c (ns per device µs) of a device MAX_DRIFT_PPM fast or slow.
        let c_max = 1000.0 * MAX_DRIFT_PPM * 1e-6;
        let c = match lower_envelope_line(points) {
            Some((a, c)) if c.abs() <= c_max => {
                self.line = Some((a, c));
                return;
            }
            Some((_, c)) => c.clamp(-c_max, c_max),
            None => 0.0,
        };
        let a = points
            .iter()
            .map(|&(x, r)| r - c * x)
            .fold(f64::INFINITY, f64::min);
        if a.is_finite() {
            self.line = Some((a, c));
        }
    }

    /// Device time mapped onto the host axis, ns, once the fit has [`MIN_WINDOWS`] windows.
    pub fn map(&self, device_us: u64) -> Option<u64> {
        let (a, c) = self.line?;
        let (d0, h0) = self.origin?;
        let x = (device_us as i128 - d0 as i128) as f64;
        let h = h0 as f64 + x * 1000.0 + a + c * x;
        (h.is_finite() && h >= 0.0).then_some(h as u64)
    }

    /// Device time on the host axis from the first point on: [`ClockFit::map`] once the line
    /// is fitted; before that (the first ~2 s of a stream) the device clock shifted by the
    /// least delay seen so far, without drift (100 ppm over 2 s is 0.2 ms). The arrival time
    /// itself would be late by the whole delay of the sample, which on a loaded host is
    /// hundreds of milliseconds (docs/design.md, timing model). `None` before the first point.
    pub fn estimate(&self, device_us: u64) -> Option<u64> {
        if let Some(h) = self.map(device_us) {
            return Some(h);
        }
        let floor = self.floor?;
        let (d0, h0) = self.origin?;
        let x = (device_us as i128 - d0 as i128) as f64;
        let h = h0 as f64 + x * 1000.0 + floor;
        (h.is_finite() && h >= 0.0).then_some(h as u64)
    }

    /// Drift of the device clock against the host clock, ppm (positive: the device clock runs
    /// fast), once fitted.
    pub fn drift_ppm(&self) -> Option<f64> {
        let (_, c) = self.line?;
        // dh/dd = 1000 + c ns per device µs; device rate / host rate = 1000 / (1000 + c).
        Some((1000.0 / (1000.0 + c) - 1.0) * 1e6)
    }
}

/// The CNC's clock (`nc_ms` of every trigger frame, instruments.md §4) fitted against the
/// host clock like an instrument's device clock: the time of a trigger on the host axis is
/// when the NC says it happened, not when the frame arrived. Frames arrive late by whatever
/// the CAN adapter, the serial link and the scheduler add — on a loaded host hundreds of
/// milliseconds, more than a dwell — while the instruments' samples sit at their fitted
/// device times; a dwell opened at the arrival time then averages samples of another pose
/// (docs/design.md, timing model).
///
/// Windows of 2 s of NC time (triggers are sparse: a few per pose) over the last hour. An NC
/// clock that steps back (control restarted), jumps ahead of the host or stands still while
/// triggers keep arriving is fitted afresh from that frame on.
#[derive(Debug, Clone)]
pub struct NcClock {
    fit: ClockFit,
    nc: Unwrap,
    restarts: u64,
    /// NC time of the newest frame, µs (unwrapped, since the last restart).
    newest_us: u64,
}

/// A trigger frame as [`NcClock::observe`] saw it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NcPoint {
    /// Its NC time, µs, unwrapped.
    pub nc_us: u64,
    /// Its arrival.
    pub host_ns: u64,
    /// The fit it belongs to (restarts before it).
    pub epoch: u64,
    /// Where the fit placed it when it came.
    pub placed_ns: u64,
}

/// A trigger whose NC time maps to this much before its arrival is not late but comes from a
/// clock that stood still or stepped: the fit starts afresh. (The pipeline's queue holds about
/// a second; no real delay comes near.)
pub const NC_MAX_DELAY_NS: u64 = 10_000_000_000;
/// A trigger whose NC time maps to this much after its arrival comes from a clock that jumped
/// ahead (the fit's own error is below a millisecond or two).
pub const NC_MAX_LEAD_NS: u64 = 1_000_000_000;

impl Default for NcClock {
    fn default() -> Self {
        NcClock {
            fit: ClockFit::new(2_000_000, 1800),
            nc: Unwrap::new(32),
            restarts: 0,
            newest_us: 0,
        }
    }
}

impl NcClock {
    /// The host-axis time of a trigger stamped `nc_ms` by the NC that arrived at `host_ns`:
    /// never later than its arrival.
    pub fn time(&mut self, nc_ms: u32, host_ns: u64) -> u64 {
        self.observe(nc_ms, host_ns).placed_ns
    }

    /// Adds a trigger frame to the fit and places it with the fit as it then stands
    /// ([`NcClock::time`]); the point can be placed again later ([`NcClock::place`]), once
    /// later frames have improved the fit.
    pub fn observe(&mut self, nc_ms: u32, host_ns: u64) -> NcPoint {
        let raw = u64::from(nc_ms);
        let mut ms = match self.nc.push(raw) {
            Some(ms) => ms,
            None => {
                self.restart();
                self.nc.rebase(raw)
            }
        };
        if let Some(e) = self.fit.estimate(ms.saturating_mul(1000))
            && (host_ns.saturating_sub(e) > NC_MAX_DELAY_NS
                || e.saturating_sub(host_ns) > NC_MAX_LEAD_NS)
        {
            self.restart();
            ms = self.nc.rebase(raw);
        }
        let us = ms.saturating_mul(1000);
        self.fit.push(us, host_ns);
        self.newest_us = us;
        NcPoint {
            nc_us: us,
            host_ns,
            epoch: self.restarts,
            placed_ns: self.fit.estimate(us).unwrap_or(host_ns).min(host_ns),
        }
    }

    /// `p` placed with the fit as it stands now: never later than its arrival; where the fit
    /// was started afresh since `p` was observed, where it was placed then.
    pub fn place(&self, p: &NcPoint) -> u64 {
        if p.epoch != self.restarts {
            return p.placed_ns;
        }
        self.fit
            .estimate(p.nc_us)
            .unwrap_or(p.host_ns)
            .min(p.host_ns)
    }

    /// Whether the fit has its line (enough windows of frames): later frames then no longer
    /// move a placement by more than the fit's own error.
    pub fn settled(&self) -> bool {
        self.fit.drift_ppm().is_some()
    }

    /// How far the NC clock has run since `p`, µs (`u64::MAX` across a restart of the fit:
    /// `p` cannot be placed better any more).
    pub fn since(&self, p: &NcPoint) -> u64 {
        if p.epoch != self.restarts {
            return u64::MAX;
        }
        self.newest_us.saturating_sub(p.nc_us)
    }

    fn restart(&mut self) {
        self.restarts += 1;
        self.fit.reset();
        self.nc.reset();
    }

    /// Times the NC clock was fitted afresh (stepped back, jumped, stood still).
    pub fn restarts(&self) -> u64 {
        self.restarts
    }

    /// Fitted drift of the NC clock against the host, ppm (None until fitted).
    pub fn drift_ppm(&self) -> Option<f64> {
        self.fit.drift_ppm()
    }
}

/// The line under all `points` (sorted by x) that lies highest at their mean x: the
/// linear-programming estimate of Moon, Skelly and Towsley (1999, "Estimation and removal of
/// clock skew from network delay measurements"): minimise `Σ (r_i − a − c·x_i)` subject to
/// `r_i ≥ a + c·x_i`. Delays are never negative, so the true line lies under every point; the
/// optimum is the edge of the lower convex hull that spans the mean x. It uses the
/// least-delayed points only, so the heavy tail of the delays does not bias it, and a window
/// in which everything was delayed simply does not touch the hull.
fn lower_envelope_line(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    if points.len() < 2 {
        return None;
    }
    // Andrew's monotone chain, lower half (points arrive sorted by device time).
    let mut hull: Vec<(f64, f64)> = Vec::with_capacity(points.len());
    for &p in points {
        while hull.len() >= 2 {
            let (o, a) = (hull[hull.len() - 2], hull[hull.len() - 1]);
            let cross = (a.0 - o.0) * (p.1 - o.1) - (a.1 - o.1) * (p.0 - o.0);
            if cross <= 0.0 {
                hull.pop();
            } else {
                break;
            }
        }
        if hull.last().is_none_or(|l| p.0 > l.0) {
            hull.push(p);
        } else if let Some(l) = hull.last_mut()
            && p.1 < l.1
        {
            *l = p;
        }
    }
    let mean_x = points.iter().map(|p| p.0).sum::<f64>() / points.len() as f64;
    let edge = hull
        .windows(2)
        .find(|e| e[0].0 <= mean_x && mean_x <= e[1].0)?;
    let (p, q) = (edge[0], edge[1]);
    let c = (q.1 - p.1) / (q.0 - p.0);
    c.is_finite().then_some((p.1 - c * p.0, c))
}

/// Extends a wrapping counter of `bits` bits (sequence number, device clock) to u64.
///
/// A step forward of less than half the range is taken as forward; a larger one as a step
/// back (a repeated or restarted counter), reported by [`Unwrap::push`] as `None` so the
/// caller can count it and re-base with [`Unwrap::rebase`].
#[derive(Debug, Clone, Copy)]
pub struct Unwrap {
    bits: u32,
    last_raw: u64,
    last: Option<u64>,
}

impl Unwrap {
    pub fn new(bits: u32) -> Self {
        Unwrap {
            bits: bits.clamp(1, 64),
            last_raw: 0,
            last: None,
        }
    }

    fn mask(&self) -> u64 {
        if self.bits == 64 {
            u64::MAX
        } else {
            (1u64 << self.bits) - 1
        }
    }

    /// Forget the history; the next value starts a new unwrapped run at its raw value.
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// The last unwrapped value.
    pub fn last(&self) -> Option<u64> {
        self.last
    }

    /// Start a new run at `raw` (after a restart of the device counter).
    pub fn rebase(&mut self, raw: u64) -> u64 {
        self.last_raw = raw & self.mask();
        self.last = Some(self.last_raw);
        self.last_raw
    }

    /// The unwrapped value of `raw`, or `None` when it steps back (the caller decides).
    pub fn push(&mut self, raw: u64) -> Option<u64> {
        self.push_hint(raw, None)
    }

    /// Like [`Unwrap::push`], with a hint of how far the counter should have advanced (from
    /// another, longer clock): when given, the forward step is the one of the form
    /// `diff + k·2^bits` nearest to the hint, so that a gap longer than half the range is not
    /// mistaken for a short one.
    pub fn push_hint(&mut self, raw: u64, hint: Option<u64>) -> Option<u64> {
        let raw = raw & self.mask();
        let Some(last) = self.last else {
            return Some(self.rebase(raw));
        };
        let diff = raw.wrapping_sub(self.last_raw) & self.mask();
        let half = 1u64 << (self.bits - 1).min(63);
        let step = match hint {
            Some(h) if self.bits < 64 && h > half => {
                let range = 1u64 << self.bits;
                let k = (h.saturating_sub(diff) + range / 2) / range;
                diff + k * range
            }
            _ if diff >= half => return None,
            _ => diff,
        };
        self.last_raw = raw;
        let v = last.saturating_add(step);
        self.last = Some(v);
        Some(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A device clock running `drift_ppm` fast, sampled at `rate_hz`, arrival delays from a
    /// heavy-tailed distribution (Pareto, α = 1.2, scale 30 µs) plus occasional 20 ms stalls.
    fn simulate(drift_ppm: f64, rate_hz: f64, secs: f64, seed: u64) -> (ClockFit, Vec<(u64, u64)>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut fit = ClockFit::default();
        let host0 = 1_700_000_000_000_000_000u64;
        let dev0 = 123_456_789u64;
        let n = (secs * rate_hz) as u64;
        let mut truth = Vec::new();
        let mut stall_until = 0.0;
        for i in 0..n {
            let t_host_s = i as f64 / rate_hz; // true send time on the host axis
            let dev_us = dev0 + (t_host_s * 1e6 * (1.0 + drift_ppm * 1e-6)).round() as u64;
            let u: f64 = rng.random_range(1e-9..1.0);
            let mut delay_s = 30e-6 * u.powf(-1.0 / 1.2);
            if rng.random_range(0.0..1.0) < 0.0005 {
                stall_until = t_host_s + 0.02;
            }
            if t_host_s < stall_until {
                delay_s += stall_until - t_host_s;
            }
            let host_ns = host0 + ((t_host_s + delay_s) * 1e9) as u64;
            fit.push(dev_us, host_ns);
            truth.push((dev_us, host0 + (t_host_s * 1e9) as u64));
        }
        (fit, truth)
    }

    #[test]
    fn recovers_drift_within_a_ppm_despite_heavy_tailed_delays() {
        for (drift, seed) in [(37.0, 1), (-85.0, 2), (0.0, 3), (100.0, 4)] {
            let (fit, _) = simulate(drift, 1000.0, 30.0, seed);
            let est = fit.drift_ppm().unwrap();
            assert!(
                (est - drift).abs() < 1.0,
                "drift {drift} ppm, estimated {est} ppm"
            );
        }
    }

    #[test]
    fn plain_least_squares_would_be_biased_but_the_envelope_is_not() {
        // The mapped time sits on the lower envelope: within ~the minimum delay of the true
        // send time, far below the mean delay (Pareto α=1.2 has mean 180 µs).
        let (fit, truth) = simulate(50.0, 1000.0, 20.0, 7);
        let mut worst: f64 = 0.0;
        for &(d, t) in &truth[truth.len() / 2..] {
            let m = fit.map(d).unwrap() as f64;
            worst = worst.max((m - t as f64).abs());
        }
        assert!(
            worst < 60_000.0,
            "mapped time off the send time by {worst} ns"
        );
    }

    #[test]
    fn recovers_drift_when_the_delay_floor_is_only_reached_now_and_then() {
        // What a loaded host shows: samples are read in batches, and only now and then does a
        // read fall right after a device write (delay < 50 µs); otherwise the least delay of a
        // window is ~1.2 ms or more. Windows of 0.5 s often never reach the floor.
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let drift_ppm = -42.0;
        let mut fit = ClockFit::default();
        for i in 0..20_000u64 {
            let t_s = i as f64 / 1000.0;
            let dev_us = 4_294_000_000 + (t_s * 1e6 * (1.0 + drift_ppm * 1e-6)) as u64;
            let delay_s = if rng.random_range(0.0..1.0) < 0.002 {
                rng.random_range(0.0..50e-6)
            } else {
                1.2e-3 + rng.random_range(0.0..1.0f64).powi(3) * 10e-3
            };
            fit.push(dev_us, ((t_s + delay_s) * 1e9) as u64);
        }
        let est = fit.drift_ppm().unwrap();
        assert!((est - drift_ppm).abs() < 2.0, "{est}");
    }

    #[test]
    fn a_stalled_window_early_in_a_run_cannot_tilt_the_fit_beyond_the_data_sheet() {
        // A device with no drift; the host stalls 60 ms through the first counted window
        // (0.5-1.0 s), so every sample of it arrives late. With three windows the envelope
        // edge from that window down to the next has a slope of -60 ms per 0.5 s; the bound
        // keeps the error of the mapping 5 s later to what 200 ppm can do.
        let mut fit = ClockFit::new(500_000, 600);
        for i in 0..2_100u64 {
            let dev_us = i * 1_000; // 1 kHz
            let stall_ns = if (500_000..1_000_000).contains(&dev_us) {
                60_000_000
            } else {
                0
            };
            fit.push(dev_us, 1_000_000_000 + dev_us * 1_000 + 200_000 + stall_ns);
        }
        let drift = fit.drift_ppm().unwrap();
        assert!(drift.abs() <= MAX_DRIFT_PPM * 1.001, "{drift}");
        let mapped = fit.map(5_000_000).unwrap() as f64;
        let truth = (1_000_000_000u64 + 5_000_000 * 1_000 + 200_000) as f64;
        assert!(
            (mapped - truth).abs() < 2e6,
            "mapping off by {} ns",
            mapped - truth
        );
    }

    #[test]
    fn no_fit_before_enough_windows_and_reset_forgets() {
        let mut fit = ClockFit::new(100_000, 100);
        for i in 0..25u64 {
            fit.push(i * 10_000, 5_000_000_000 + i * 10_000_000);
        }
        // 250 ms of device time: windows 0 (left out), 1 (closed) and 2 (open).
        assert_eq!(fit.windows(), 1);
        assert!(fit.map(0).is_none() && fit.drift_ppm().is_none());
        for i in 25..55u64 {
            fit.push(i * 10_000, 5_000_000_000 + i * 10_000_000);
        }
        assert!(fit.drift_ppm().unwrap().abs() < 1e-6);
        assert_eq!(fit.map(1_000_000), Some(6_000_000_000));
        fit.reset();
        assert!(fit.map(0).is_none() && fit.windows() == 0);
    }

    #[test]
    fn drift_sign_fast_device() {
        // Device counts 1 000 100 µs per host second: 100 ppm fast.
        let mut fit = ClockFit::new(100_000, 100);
        for i in 0..100u64 {
            fit.push(i * 100_010, i * 100_000_000);
        }
        let est = fit.drift_ppm().unwrap();
        assert!((est - 100.0).abs() < 0.01, "{est}");
    }

    #[test]
    fn unwrap_u16_across_wraps_and_gaps() {
        let mut u = Unwrap::new(16);
        assert_eq!(u.push(65534), Some(65534));
        assert_eq!(u.push(65535), Some(65535));
        assert_eq!(u.push(0), Some(65536));
        assert_eq!(u.push(5), Some(65541)); // gap of 4
        assert_eq!(u.push(3), None); // step back
        assert_eq!(u.last(), Some(65541));
        assert_eq!(u.rebase(3), 3);
        assert_eq!(u.push(4), Some(4));
    }

    #[test]
    fn unwrap_with_hint_resolves_long_gaps() {
        let mut u = Unwrap::new(16);
        u.push(100);
        // 70 000 samples later by the device clock: raw = (100 + 70000) mod 65536 = 4564.
        assert_eq!(u.push_hint(4564, Some(70_000)), Some(70_100));
        // A short step with a matching hint stays short.
        assert_eq!(u.push_hint(4565, Some(1)), Some(70_101));
    }

    #[test]
    fn unwrap_u32_device_clock_and_fit_across_the_wrap() {
        // CB-3: t_us u32 wraps every 71.6 min; start 2 s before the wrap, 20 ppm slow device.
        let mut u = Unwrap::new(32);
        let mut fit = ClockFit::new(200_000, 100);
        let start = u32::MAX as u64 - 2_000_000;
        for i in 0..5000u64 {
            let host_ns = i * 1_000_000;
            let dev = start + (i as f64 * 1000.0 * (1.0 - 20e-6)) as u64;
            let raw = dev & 0xFFFF_FFFF;
            let un = u.push(raw).unwrap();
            assert_eq!(un, dev);
            fit.push(un, host_ns);
        }
        let est = fit.drift_ppm().unwrap();
        assert!((est + 20.0).abs() < 0.1, "{est}");
    }

    #[test]
    fn before_the_fit_the_estimate_sits_at_the_least_delay_not_the_arrival() {
        // A stream that starts on a loaded host: the first samples arrive 1 ms late, then a
        // stall delays everything by 300 ms. The arrival time is 300 ms late; the estimate
        // (no line yet: less than 2 s) stays within the least delay of the send time.
        let mut fit = ClockFit::default();
        assert_eq!(fit.estimate(0), None);
        let host0 = 1_000_000_000_000u64;
        for i in 0..1000u64 {
            let send_ns = host0 + i * 1_000_000;
            let delay = if i < 100 { 1_000_000 } else { 300_000_000 };
            fit.push(5_000_000 + i * 1000, send_ns + delay);
            assert!(fit.map(5_000_000 + i * 1000).is_none());
            let e = fit.estimate(5_000_000 + i * 1000).unwrap();
            assert!(
                e.abs_diff(send_ns) <= 1_000_000,
                "sample {i}: {e} vs {send_ns}"
            );
        }
    }

    #[test]
    fn nc_clock_maps_late_frames_back_to_their_nc_time_across_the_wrap() {
        // Triggers 4 a second for 60 s, NC clock 80 ppm slow starting 10 s before the u32
        // wrap; frames arrive 0.2-3 ms late, and every 7th is held up 100-900 ms.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut nc = NcClock::default();
        let host0 = 1_800_000_000_000_000_000u64;
        for i in 0..240u64 {
            let t_s = i as f64 * 0.25;
            let raw = (u32::MAX as f64 - 10_000.0 + t_s * 1e3 * (1.0 - 80e-6)).round() as u64;
            let delay_s = if i % 7 == 3 {
                rng.random_range(0.1..0.9)
            } else {
                rng.random_range(2e-4..3e-3)
            };
            let send = host0 + (t_s * 1e9) as u64;
            let got = nc.time((raw & 0xFFFF_FFFF) as u32, send + (delay_s * 1e9) as u64);
            // Within the NC clock's 1 ms resolution and the least delay.
            assert!(
                got.abs_diff(send) < 2_000_000,
                "frame {i} at {t_s} s, {delay_s} s late: {} ms off",
                got.abs_diff(send) as f64 / 1e6
            );
        }
        assert_eq!(nc.restarts(), 0);
        let d = nc.drift_ppm().unwrap();
        assert!((d + 80.0).abs() < 40.0, "drift {d} ppm");
    }

    #[test]
    fn nc_clock_restarts_when_the_control_restarts_or_its_clock_stands_still() {
        let mut nc = NcClock::default();
        let h = 1_000_000_000_000u64;
        assert_eq!(nc.time(50_000, h), h);
        assert_eq!(nc.time(50_500, h + 500_000_000), h + 500_000_000);
        // The control restarted: its clock is back at 10 ms.
        assert_eq!(nc.time(10, h + 600_000_000), h + 600_000_000);
        assert_eq!(nc.restarts(), 1);
        assert_eq!(nc.time(410, h + 1_000_000_000), h + 1_000_000_000);
        // A clock that stands still while frames keep coming for 11 s: not 11 s of delay.
        assert_eq!(nc.time(410, h + 12_000_000_000), h + 12_000_000_000);
        assert_eq!(nc.restarts(), 2);
        // A clock that jumps 5 s ahead: fitted afresh, never later than the arrival.
        assert_eq!(nc.time(5_410, h + 12_000_000_100), h + 12_000_000_100);
        assert_eq!(nc.restarts(), 3);
    }
}
