//! A deterministic synthetic run — driver events of all instruments and the CNC triggers of a
//! pose sequence — for the log's tests and benchmarks (no devices, no clocks, no threads).
//!
//! Each pose: motion (ramp) of `move_s`, exact stop, ringing that decays, dwell of `dwell_s`,
//! dwell end. Noise from a fixed-seed generator, so a run is the same every time.

use crate::{Counters, DriverEvent, Instrument, Sample, SampleValues, Trigger};
use protocol::can::TriggerEvent;

/// Shape of a synthetic run.
#[derive(Debug, Clone)]
pub struct SyntheticRun {
    pub start_ns: u64,
    pub li80_hz: f64,
    pub cb3_hz: f64,
    pub psd_hz: f64,
    /// Axis targets, mm; pose k (1-based) is `targets_mm[k-1]`.
    pub targets_mm: Vec<f64>,
    pub move_s: f64,
    pub dwell_s: f64,
    /// Ringing amplitude after each stop, µm, and its decay time, s.
    pub ring_um: f64,
    pub ring_tau_s: f64,
    pub noise_um: f64,
    /// Emit triggers (false: a trigger-free run).
    pub triggers: bool,
    /// Every k-th PSD sample is dark (no light: x, y NaN, sum 0, invalid); 0 = never.
    pub psd_dark_every: u64,
    /// Polls per second of a Modbus temperature module of [`SyntheticRun::TEMPERATURES`]
    /// channels (the last an open sensor: NaN, the sample invalid); 0 = no module.
    pub temperature_hz: f64,
    pub seed: u64,
}

impl Default for SyntheticRun {
    fn default() -> Self {
        SyntheticRun {
            start_ns: 1_795_305_600_000_000_000,
            li80_hz: 1000.0,
            cb3_hz: 1000.0,
            psd_hz: 100.0,
            targets_mm: vec![0.0, 50.0, 100.0, 150.0, 200.0],
            move_s: 0.5,
            dwell_s: 2.5,
            ring_um: 2.0,
            ring_tau_s: 0.08,
            noise_um: 0.01,
            triggers: true,
            psd_dark_every: 0,
            temperature_hz: 0.0,
            seed: 1,
        }
    }
}

impl SyntheticRun {
    /// Channels of the synthetic temperature module.
    pub const TEMPERATURES: usize = 3;

    /// A run of two poses at low rates (a few kB of log): fuzz seeds and reader tests.
    pub fn small() -> SyntheticRun {
        SyntheticRun {
            targets_mm: vec![0.0, 25.0],
            dwell_s: 0.05,
            move_s: 0.02,
            li80_hz: 200.0,
            cb3_hz: 100.0,
            psd_hz: 50.0,
            seed: 1,
            ..SyntheticRun::default()
        }
    }

    /// Duration of the run, s.
    pub fn duration_s(&self) -> f64 {
        self.targets_mm.len() as f64 * (self.move_s + self.dwell_s) + 0.5
    }

    /// The calibration the synthetic CB-3 samples are converted with (10 µm/V sensors, the
    /// machine error 1.25 × the sensor distances); a log of the run stores it.
    pub fn capball_calibration() -> protocol::convert::CapBallCalibration {
        use protocol::convert::{CapBallCalibration, CapBallPoly, CapBallTransform};
        let mut t = CapBallTransform::IDENTITY;
        for (i, row) in t.t.iter_mut().take(3).enumerate() {
            row[i] = 1.25;
        }
        CapBallCalibration {
            poly: [CapBallPoly::NOMINAL; 3],
            transform: t,
        }
    }

    /// The machine error seen by the CapBall at pose k (µm), and by the PSD (µm).
    pub fn capball_error_um(k: usize) -> [f64; 3] {
        [0.5 * k as f64, -0.25 * k as f64, 0.1]
    }
    pub fn psd_error_um(k: usize) -> [f64; 2] {
        [1.0 + 0.2 * k as f64, -0.3 * k as f64]
    }

    /// (pose index 0-based or None while before the first stop, offset to the ringing start s,
    /// position fraction of the motion) at time `t` s since start.
    fn phase(&self, t: f64) -> (usize, f64, f64) {
        let cycle = self.move_s + self.dwell_s;
        let k = ((t / cycle).floor().max(0.0) as usize).min(self.targets_mm.len() - 1);
        let tc = t - k as f64 * cycle;
        if tc < self.move_s {
            (k, -1.0, tc / self.move_s)
        } else {
            (k, tc - self.move_s, 1.0)
        }
    }

    fn ring(&self, since_stop_s: f64) -> f64 {
        if since_stop_s < 0.0 {
            return 0.0;
        }
        self.ring_um
            * (-since_stop_s / self.ring_tau_s).exp()
            * (2.0 * std::f64::consts::PI * 40.0 * since_stop_s).sin()
    }

    /// The events, in host-time order.
    pub fn events(&self) -> SyntheticEvents<'_> {
        let mut trig = Vec::new();
        let cycle = self.move_s + self.dwell_s;
        if self.triggers {
            trig.push((0.0, TriggerEvent::ProgramStart, 0u16));
            for k in 0..self.targets_mm.len() {
                let t0 = k as f64 * cycle;
                let pose = (k + 1) as u16;
                trig.push((t0 + 1e-4, TriggerEvent::MotionStart, pose.saturating_sub(1)));
                trig.push((t0 + self.move_s, TriggerEvent::ExactStop, pose));
                trig.push((t0 + cycle - 1e-3, TriggerEvent::DwellEnd, pose));
            }
            trig.push((self.duration_s() - 0.1, TriggerEvent::ProgramEnd, 0));
        }
        SyntheticEvents {
            run: self,
            rng: self.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1,
            next: [
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                temperature_start(self.temperature_hz),
            ],
            count: [0; 6],
            trig,
            ti: 0,
            pending: Vec::new(),
            started: false,
        }
    }
}

/// When the temperature stream starts: never without a module.
fn temperature_start(hz: f64) -> f64 {
    if hz > 0.0 { 0.0 } else { f64::INFINITY }
}

/// Iterator over the events of a [`SyntheticRun`].
pub struct SyntheticEvents<'a> {
    run: &'a SyntheticRun,
    rng: u64,
    /// Next time (s) of: li80 position, li80 environment, cb3, psd, counters, temperatures.
    next: [f64; 6],
    count: [u64; 6],
    trig: Vec<(f64, TriggerEvent, u16)>,
    ti: usize,
    pending: Vec<DriverEvent>,
    started: bool,
}

impl SyntheticEvents<'_> {
    fn uniform(&mut self) -> f64 {
        // xorshift64*: plenty for test noise.
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        ((self.rng.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
    /// The connections of the instruments (four, five with a temperature module), first of
    /// all events.
    fn connect_all(&mut self) -> Option<DriverEvent> {
        self.started = true;
        self.next[4] = 1.0;
        let mut all = vec![
            (Instrument::Interferometer, "LI-80,SN1234,FW2.1"),
            (Instrument::Capball, "CB-3,SN77,FW1.4"),
            (Instrument::Psd, "PSD-2,SN5,FW3.0"),
            (Instrument::Trigger, "SLCAN,V1013"),
        ];
        if self.run.temperature_hz > 0.0 {
            all.push((
                Instrument::Thermometer,
                "Modbus RTU temperature module, unit 1",
            ));
        }
        for (i, id) in all {
            self.pending.push(DriverEvent::Connected {
                instrument: i,
                port: format!("/dev/ttyV{}", i as u8),
                identity: id.into(),
            });
        }
        self.pending.pop()
    }

    fn next_trigger(&mut self) -> DriverEvent {
        let (tt, ev, pose) = self.trig[self.ti];
        self.ti += 1;
        DriverEvent::Trigger(Trigger {
            event: ev,
            pose,
            nc_ms: (tt * 1000.0) as u32,
            host_ns: self.ns(tt),
        })
    }

    /// The once-a-second counters of every instrument.
    fn push_counters(&mut self, seq: u64) -> Option<DriverEvent> {
        let mut all = vec![
            (Instrument::Interferometer, self.count[0]),
            (Instrument::Capball, self.count[2]),
            (Instrument::Psd, self.count[3]),
            (Instrument::Trigger, self.ti as u64),
        ];
        if self.run.temperature_hz > 0.0 {
            all.push((Instrument::Thermometer, self.count[5]));
        }
        for (i, n) in all {
            let mut c = Counters {
                samples: n,
                clock_drift_ppm: Some(1.5),
                ..Counters::default()
            };
            c.rejections
                .insert(protocol::RejectKind::BadChecksum, seq / 10);
            self.pending.push(DriverEvent::Counters {
                instrument: i,
                counters: c,
            });
        }
        self.pending.pop()
    }

    /// The temperature module's channels at `t` s: a warming spindle, the air, an open sensor.
    fn temperatures_at(&mut self, t: f64) -> Vec<f64> {
        let mut v = vec![
            20.0 + 2.0 * (1.0 - (-t / 600.0).exp()) + 0.02 * self.gauss(),
            20.5 + 0.02 * self.gauss(),
        ];
        v.resize(SyntheticRun::TEMPERATURES, f64::NAN);
        v
    }

    /// The values of stream `which` (0 position, 1 environment, 2 CapBall, 3 PSD) at `t` s.
    fn values_at(&mut self, which: usize, t: f64) -> (Instrument, SampleValues) {
        let r = self.run;
        let (k, since, frac) = r.phase(t);
        let from = if k == 0 {
            r.targets_mm[0] - 10.0
        } else {
            r.targets_mm[k - 1]
        };
        let pos_um = 1000.0 * (from + (r.targets_mm[k] - from) * frac);
        let ring = r.ring(since);
        let moving_err = if since < 0.0 {
            3.0 * (frac * std::f64::consts::PI).sin()
        } else {
            0.0
        };
        let noise = r.noise_um;
        match which {
            0 => {
                let p = pos_um + ring + noise * self.gauss();
                let raw_nm = (p * 1000.0).round() as i64;
                (
                    Instrument::Interferometer,
                    SampleValues::Position {
                        raw_nm,
                        position_um: p,
                        sig: 87,
                        flags: 0,
                    },
                )
            }
            1 => (
                Instrument::Interferometer,
                SampleValues::Environment {
                    air_c: 20.1 + 0.01 * self.gauss(),
                    air_pa: 101_325.0 + 2.0 * self.gauss(),
                    rh_pct: 45.0 + 0.1 * self.gauss(),
                    material_c: vec![20.3, 20.4 + 0.01 * self.gauss()],
                    n_air: 1.000_271_3,
                },
            ),
            2 => {
                let e0 = SyntheticRun::capball_error_um(k);
                let mut e = [0.0; 3];
                for (c, ec) in e.iter_mut().enumerate() {
                    *ec = e0[c] + moving_err + 0.5 * ring + noise * self.gauss();
                }
                // As the CB-3 driver does: ADC codes converted with the calibration (the
                // codes of the sensor distances d = 0.8·e).
                let cal = SyntheticRun::capball_calibration();
                let codes = e.map(|x| {
                    let code = (0.8 * x / 10.0 * protocol::cb3::CODE_FULL_SCALE
                        / protocol::cb3::VOLTS_FULL_SCALE)
                        .round();
                    code.clamp(
                        -protocol::cb3::CODE_FULL_SCALE,
                        protocol::cb3::CODE_MAX as f64,
                    ) as i32
                });
                let c = cal.convert(codes);
                let (v, d, e) = (c.volts, c.d_um, c.e_um);
                (
                    Instrument::Capball,
                    SampleValues::Capball {
                        volts: v,
                        d_um: d,
                        e_um: e,
                        flags: 0,
                    },
                )
            }
            _ => {
                let e0 = SyntheticRun::psd_error_um(k);
                (
                    Instrument::Psd,
                    SampleValues::Psd {
                        x_um: e0[0] + moving_err + ring + noise * self.gauss(),
                        y_um: e0[1] + ring + noise * self.gauss(),
                        sum_pa: 1.2e6,
                        head_c: 21.0,
                    },
                )
            }
        }
    }

    fn ns(&self, t: f64) -> u64 {
        self.run.start_ns + (t * 1e9).round() as u64
    }
}

impl Iterator for SyntheticEvents<'_> {
    type Item = DriverEvent;

    fn next(&mut self) -> Option<DriverEvent> {
        if let Some(e) = self.pending.pop() {
            return Some(e);
        }
        if !self.started {
            return self.connect_all();
        }
        let r = self.run;
        let rates_hz = [r.li80_hz, 1.0, r.cb3_hz, r.psd_hz, 1.0, r.temperature_hz];
        let t_trig = self.trig.get(self.ti).map(|x| x.0).unwrap_or(f64::INFINITY);
        let (mut which, mut t) = (usize::MAX, t_trig);
        for (i, &tn) in self.next.iter().enumerate() {
            if tn < t {
                (which, t) = (i, tn);
            }
        }
        if t >= r.duration_s() {
            return None;
        }
        if which == usize::MAX {
            return Some(self.next_trigger());
        }
        self.count[which] += 1;
        // From the count, not accumulated: exact sample times (counters start at 1 s).
        let first = if which == 4 { 1.0 } else { 0.0 };
        self.next[which] = first + self.count[which] as f64 / rates_hz[which];
        let seq = self.count[which];
        // Host arrival a little after the device time (transport latency, jitter).
        let host_ns = self.ns(t) + 300_000 + (self.uniform() * 200_000.0) as u64;
        let mut sample = Sample {
            instrument: Instrument::Psd,
            seq,
            device_t_us: (t * 1e6) as u64,
            host_ns,
            fitted_ns: self.ns(t),
            valid: true,
            values: SampleValues::Psd {
                x_um: f64::NAN,
                y_um: f64::NAN,
                sum_pa: 0.0,
                head_c: 21.0,
            },
        };
        match which {
            4 => return self.push_counters(seq),
            // A dark PSD sample: no light, no position.
            3 if r.psd_dark_every > 0 && seq.is_multiple_of(r.psd_dark_every) => {
                sample.valid = false;
            }
            5 => {
                sample.instrument = Instrument::Thermometer;
                sample.values = SampleValues::Temperature {
                    values_c: self.temperatures_at(t),
                };
                // The last channel is an open sensor.
                sample.valid = false;
            }
            _ => (sample.instrument, sample.values) = self.values_at(which, t),
        }
        Some(DriverEvent::Sample(sample))
    }
}
