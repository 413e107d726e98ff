//! Stamping a sample: its wrapping sequence number and device clock unwrapped to u64, the gaps
//! and restarts they show, and the device time mapped onto the host axis by the clock fit
//! ([`detect::ClockFit`]). Pure bookkeeping: no I/O, no events.

use detect::{ClockFit, Unwrap};

/// What the stamper made of one data frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Stamp {
    /// Sequence number, unwrapped.
    pub seq: u64,
    /// Device clock, µs, unwrapped.
    pub device_t_us: u64,
    /// Device time on the host axis, ns since the Unix epoch (offset-only until the fit has
    /// enough points: [`ClockFit::estimate`]).
    pub fitted_ns: u64,
    /// Samples missing between the previous frame and this one (0: none).
    pub missed: u64,
    /// The sequence or the device clock stepped back: the device restarted under us; counting
    /// and the clock fit started afresh (not a gap).
    pub restarted: bool,
}

/// Unwraps a device's sequence and clock and fits its clock against the host's.
#[derive(Debug, Clone)]
pub(crate) struct SampleStamper {
    fit: ClockFit,
    seq: Unwrap,
    dev_t: Unwrap,
    /// Samples per device µs, to resolve sequence wraps across long gaps.
    rate_per_us: Option<f64>,
}

impl SampleStamper {
    /// A stamper for a device whose sequence has `seq_bits` and whose clock has `t_bits`.
    pub(crate) fn new(seq_bits: u32, t_bits: u32) -> Self {
        SampleStamper {
            fit: ClockFit::default(),
            seq: Unwrap::new(seq_bits),
            dev_t: Unwrap::new(t_bits),
            rate_per_us: None,
        }
    }

    /// The configured sample rate, used as a hint across sequence wraps.
    pub(crate) fn set_rate(&mut self, rate_hz: u32) {
        self.rate_per_us = (rate_hz > 0).then_some(rate_hz as f64 * 1e-6);
    }

    /// A new connection: the device may have restarted its sequence and clock.
    pub(crate) fn reset(&mut self) {
        self.seq.reset();
        self.dev_t.reset();
        self.fit.reset();
    }

    /// Fitted drift of the device clock, ppm (None until fitted).
    pub(crate) fn drift_ppm(&self) -> Option<f64> {
        self.fit.drift_ppm()
    }

    /// Stamp a frame carrying `raw_seq` and `raw_t_us` that arrived at `host_ns`.
    pub(crate) fn stamp(&mut self, raw_seq: u64, raw_t_us: u64, host_ns: u64) -> Stamp {
        let prev_t = self.dev_t.last();
        let prev_seq = self.seq.last();
        let mut restarted = false;
        let (seq, t) = match self.dev_t.push(raw_t_us) {
            Some(t) => {
                let hint = match (prev_t, self.rate_per_us) {
                    (Some(pt), Some(r)) => Some(((t.saturating_sub(pt)) as f64 * r).round() as u64),
                    _ => None,
                };
                match self.seq.push_hint(raw_seq, hint) {
                    Some(s) if prev_seq.is_none_or(|p| s > p) => (s, t),
                    _ => {
                        restarted = true;
                        self.restart(raw_seq, raw_t_us)
                    }
                }
            }
            None => {
                restarted = true;
                self.restart(raw_seq, raw_t_us)
            }
        };
        let missed = match prev_seq {
            Some(p) if !restarted && seq > p + 1 => seq - p - 1,
            _ => 0,
        };
        self.fit.push(t, host_ns);
        let fitted_ns = self.fit.estimate(t).unwrap_or(host_ns);
        Stamp {
            seq,
            device_t_us: t,
            fitted_ns,
            missed,
            restarted,
        }
    }

    /// The device restarted its sequence or clock under us: not a gap; start afresh.
    fn restart(&mut self, raw_seq: u64, raw_t_us: u64) -> (u64, u64) {
        self.fit.reset();
        let s = self.seq.rebase(raw_seq);
        let t = self.dev_t.rebase(raw_t_us);
        (s, t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_wraps_and_restarts_by_hand() {
        // u16 sequence, u32 clock at 1 kHz.
        let mut s = SampleStamper::new(16, 32);
        s.set_rate(1000);
        assert_eq!(s.stamp(65_534, 0, 0).missed, 0);
        // 65534 → 1 across the wrap: 65535 and 0 are missing.
        let st = s.stamp(1, 3000, 3_000_000);
        assert_eq!((st.seq, st.missed, st.restarted), (65_537, 2, false));
        // The clock steps back: a restart, not a gap.
        let st = s.stamp(7, 10, 4_000_000);
        assert!(st.restarted);
        assert_eq!(st.missed, 0);
    }
}
