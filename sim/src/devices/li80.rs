//! LI-80 laser interferometer (instruments.md §1).

use std::sync::Arc;
use std::time::Instant;

use protocol::li80::{Answer, Command, EnvFrame, ErrFrame, PosFlags, PosFrame};
use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::device::{
    Cadence, Ctx, Fault, FaultDice, Model, POWER_UP_RATE_HZ, count_fate, garbage_text,
};
use crate::instrument::Device;
use crate::record::{Fate, SentEnv, SentSample, SentValues};
use crate::scenario::{Interferometer, Timed};
use crate::shared::Shared;

/// CO2 content assumed by the device's environment model and the host's compensation, ppm.
const CO2_PPM: f64 = protocol::edlen::LI80_CO2_PPM;
/// Counts lost in a beam interruption: the reading is off by up to this much afterwards.
const LOST_COUNTS_MAX_UM: f64 = 50.0;

pub(crate) struct Li80 {
    cfg: Interferometer,
    alpha: f64,
    interruptions: Vec<Timed>,
    dice: FaultDice,
    noise: Normal<f64>,
    rate_hz: u32,
    stream: Option<Cadence>,
    env_next_us: f64,
    seq: u64,
    env_seq: u64,
    /// Length (at 20 °C) from home at which the displacement counter reads zero, µm.
    datum_l20_um: f64,
    /// Counts lost in beam interruptions since the last datum, µm.
    lost_um: f64,
    /// Program time from which readings carry "datum lost" (until `DATUM`).
    datum_lost_from: Option<f64>,
    /// Which interruptions have begun / ended.
    begun: Vec<bool>,
    ended: Vec<bool>,
    last_raw_nm: i64,
}

impl Li80 {
    pub(crate) fn new(shared: &Arc<Shared>) -> Li80 {
        let sc = &shared.world.scenario;
        let cfg = sc.interferometer.clone();
        let n = sc.faults.beam_interruptions.len();
        Li80 {
            alpha: cfg.alpha_um_per_m_k * 1e-6,
            noise: Normal::new(0.0, cfg.sample_noise_nm.max(0.0))
                .unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero std")),
            cfg,
            interruptions: sc.faults.beam_interruptions.clone(),
            dice: FaultDice::new(sc.faults.interferometer),
            rate_hz: POWER_UP_RATE_HZ as u32,
            stream: None,
            env_next_us: 0.0,
            seq: 0,
            env_seq: 0,
            datum_l20_um: 0.0,
            lost_um: 0.0,
            datum_lost_from: None,
            begun: vec![false; n],
            ended: vec![false; n],
            last_raw_nm: 0,
        }
    }

    /// Length at 20 °C from home to the reflector, including the ringing, at `at`, µm.
    fn l20_um(&self, ctx: &Ctx, at: Instant) -> f64 {
        let w = &ctx.shared.world;
        let ph = w.phase(ctx.program_s(at));
        w.axis_length20_um(ph, ctx.slow_t(at)) + w.ringing_um(ph) * self.cfg.ringing_gain
    }

    /// Rounded environment as the device reports it.
    fn env(&self, ctx: &Ctx, at: Instant) -> (f64, f64, f64, Vec<f64>) {
        let (t, p, h, m) = ctx.shared.world.environment(ctx.slow_t(at));
        let r = |v: f64, k: f64| (v * k).round() / k;
        (
            r(t, 1e3),
            r(p, 10.0),
            r(h, 100.0),
            m.iter().map(|&v| r(v, 1e3)).collect(),
        )
    }

    /// The displacement the device measures in air: the true length, expanded from 20 °C to
    /// the material temperature, times the refractive index (so the host's `raw/n` and
    /// `L·(1 − α·(T − 20))` give back the 20 °C length).
    fn raw_nm(&self, ctx: &mut Ctx, at: Instant) -> i64 {
        let t = ctx.slow_t(at);
        let (air_c, air_pa, rh, mat) = ctx.shared.world.environment(t);
        let tm = mat.iter().sum::<f64>() / mat.len().max(1) as f64;
        let n = protocol::edlen::refractive_index(
            protocol::edlen::LI80_VACUUM_WAVELENGTH_NM,
            air_c,
            air_pa,
            rh,
            CO2_PPM,
        );
        let l20 = self.l20_um(ctx, at) - self.datum_l20_um + self.lost_um;
        let l = l20 / (1.0 - self.alpha * (tm - 20.0));
        let noise = self.noise.sample(ctx.rng);
        (n * l * 1e3 + noise).round() as i64
    }

    fn in_gap(&self, sp: Option<f64>) -> Option<usize> {
        let sp = sp?;
        self.interruptions
            .iter()
            .position(|b| sp >= b.at_s && sp < b.at_s + b.duration_s)
    }

    fn answer(&self, ctx: &mut Ctx, line: &str, a: Answer) {
        let text = a.to_line();
        ctx.out.extend_from_slice(text.as_bytes());
        let text = text.trim_end().to_string();
        ctx.shared
            .lock_record()
            .interferometer
            .commands
            .push((line.to_string(), text));
    }

    fn send_env(&mut self, ctx: &mut Ctx, at: Instant, t_us: u64) {
        let (air_c, air_pa, rh_pct, material_c) = self.env(ctx, at);
        let seq = self.env_seq;
        self.env_seq += 1;
        let fate = ctx.link_fate().unwrap_or(Fate::Sent);
        if fate == Fate::Sent {
            let f = EnvFrame {
                seq: seq as u32,
                t_us,
                air_c,
                air_pa,
                rh_pct,
                material_c: material_c.clone(),
            };
            protocol::li80::encode_env(&f, ctx.out);
        }
        let rec = SentEnv {
            power_up: ctx.power_up,
            seq,
            t_us,
            true_s: ctx.sim_s(at),
            air_c,
            air_pa,
            rh_pct,
            material_c,
            fate,
        };
        ctx.shared.lock_record().interferometer.env.push(rec);
    }

    fn send_pos(&mut self, ctx: &mut Ctx, dev_us: f64, samples: &mut Vec<SentSample>) {
        let at = ctx.clock.instant(dev_us);
        let t_us = dev_us.round() as u64;
        let seq = self.cfg.identity.seq_start.wrapping_add(self.seq);
        self.seq += 1;
        let sp = ctx.program_s(at);
        let gap = self.in_gap(sp).is_some();
        let mut flags = 0u32;
        let (raw_nm, sig) = if gap {
            flags |= PosFlags::BEAM_LOW;
            let jitter: i64 = ctx.rng.random_range(-5_000..5_000);
            (self.last_raw_nm + jitter, ctx.rng.random_range(2..20u8))
        } else {
            let raw = self.raw_nm(ctx, at);
            self.last_raw_nm = raw;
            let s = self.cfg.sig_pct as i32 + ctx.rng.random_range(-2..=2);
            (raw, s.clamp(0, 100) as u8)
        };
        if matches!((self.datum_lost_from, sp), (Some(from), Some(s)) if s >= from) {
            flags |= PosFlags::DATUM_LOST;
        }
        let frame = PosFrame {
            seq: seq as u32,
            t_us,
            raw_nm,
            sig,
            flags: PosFlags(flags),
        };
        let mut garbage = false;
        let fate = match ctx.link_fate() {
            Some(f) => f,
            None => match self.dice.roll(ctx.rng, true) {
                Fault::None => Fate::Sent,
                Fault::Garbage => {
                    garbage = true;
                    ctx.faults.garbage += 1;
                    ctx.out.push(b'$');
                    garbage_text(ctx.rng, ctx.out);
                    ctx.out.extend_from_slice(b"\r\n");
                    Fate::Sent
                }
                Fault::BadChecksum => Fate::BadChecksum,
                Fault::Truncated => Fate::Truncated,
                Fault::Dropped => Fate::Dropped,
            },
        };
        count_fate(ctx.faults, fate);
        match fate {
            Fate::NotConnected if ctx.keep_unsent => {
                ctx.unsent.clear();
                protocol::li80::encode_pos(&frame, ctx.unsent);
            }
            Fate::Sent => protocol::li80::encode_pos(&frame, ctx.out),
            Fate::BadChecksum => {
                let mut line = Vec::new();
                protocol::li80::encode_pos(&frame, &mut line);
                corrupt_digit(&mut line, ctx);
                ctx.out.extend_from_slice(&line);
            }
            Fate::Truncated => {
                let mut line = Vec::new();
                protocol::li80::encode_pos(&frame, &mut line);
                // Cut before the `*HH`, so the line can never pass as a frame.
                let star = line.iter().position(|&b| b == b'*').unwrap_or(line.len());
                let cut = ctx.rng.random_range(2..star.max(3));
                line.truncate(cut.min(line.len()));
                line.extend_from_slice(b"\r\n");
                ctx.out.extend_from_slice(&line);
            }
            _ => {}
        }
        samples.push(SentSample {
            power_up: ctx.power_up,
            seq,
            t_us,
            true_s: ctx.sim_s(at),
            values: SentValues::Pos { raw_nm, sig, flags },
            fate,
            garbage_before: garbage,
        });
    }

    /// Beam interruptions begin and end with true time, streaming or not.
    fn beam(&mut self, ctx: &mut Ctx) {
        let Some(sp) = ctx.program_s(ctx.now) else {
            return;
        };
        for i in 0..self.interruptions.len() {
            let b = self.interruptions[i];
            if !self.begun[i] && sp >= b.at_s {
                self.begun[i] = true;
                ctx.faults.beam_interruptions += 1;
                if self.datum_lost_from.is_none() {
                    self.datum_lost_from = Some(b.at_s);
                }
                if ctx.link_fate().is_none() {
                    let f = ErrFrame {
                        code: 3,
                        text: "beam lost".into(),
                    };
                    protocol::li80::encode_err(&f, ctx.out);
                }
            }
            if !self.ended[i] && sp >= b.at_s + b.duration_s {
                self.ended[i] = true;
                let mag = ctx.rng.random_range(1.0..LOST_COUNTS_MAX_UM);
                self.lost_um += if ctx.rng.random_bool(0.5) { mag } else { -mag };
            }
        }
    }
}

/// Replace the first digit of the sequence field by another digit: the XOR checksum then
/// cannot match.
fn corrupt_digit(line: &mut [u8], ctx: &mut Ctx) {
    let start = line
        .iter()
        .position(|&b| b == b',')
        .map(|i| i + 1)
        .unwrap_or(0);
    if let Some(i) = line[start..].iter().position(|b| b.is_ascii_digit()) {
        let b = &mut line[start + i];
        let shift: u8 = ctx.rng.random_range(1..10);
        *b = b'0' + (*b - b'0' + shift) % 10;
    }
}

impl Model for Li80 {
    const DEVICE: Device = Device::Interferometer;

    fn activity(&self) -> (bool, u32) {
        (self.stream.is_some(), self.rate_hz)
    }

    fn power_up(&mut self, ctx: &mut Ctx) {
        self.rate_hz = POWER_UP_RATE_HZ as u32;
        self.stream = None;
        self.seq = 0;
        self.env_seq = 0;
        // The displacement counter starts at zero where the reflector stands at power-up.
        self.datum_l20_um = self.l20_um(ctx, ctx.now);
        self.lost_um = 0.0;
        self.datum_lost_from = None;
    }

    fn command(&mut self, line: &str, ctx: &mut Ctx) {
        let reply = match Command::parse(line) {
            Ok(Command::Idn) => Answer::Idn {
                serial: self.cfg.identity.serial.clone(),
                firmware: self.cfg.identity.firmware.clone(),
            },
            Ok(Command::Rate(hz)) => {
                if protocol::li80::RATE_HZ.contains(&hz) {
                    self.rate_hz = hz;
                    if let Some(c) = &self.stream {
                        // The new rate takes effect from the next sample on.
                        self.stream = Some(Cadence::new(hz as f64, c.next_us()));
                    }
                    Answer::Ok
                } else {
                    Answer::Err {
                        code: 2,
                        text: "rate out of range".into(),
                    }
                }
            }
            Ok(Command::Stream(on)) => {
                if on && self.stream.is_none() {
                    let now_us = ctx.clock.dev_us(ctx.now);
                    self.stream = Some(Cadence::new(self.rate_hz as f64, now_us));
                    self.env_next_us = now_us;
                } else if !on {
                    self.stream = None;
                }
                Answer::Ok
            }
            Ok(Command::Datum) => {
                self.datum_l20_um = self.l20_um(ctx, ctx.now);
                self.lost_um = 0.0;
                self.datum_lost_from = None;
                ctx.shared
                    .lock_record()
                    .interferometer
                    .datums_s
                    .push(ctx.sim_s(ctx.now));
                Answer::Ok
            }
            Ok(Command::EnvQuery) => {
                let t_us = ctx.clock.dev_us(ctx.now).round() as u64;
                self.send_env(ctx, ctx.now, t_us);
                ctx.shared
                    .lock_record()
                    .interferometer
                    .commands
                    .push((line.to_string(), "$ENV".into()));
                return;
            }
            Err(_) => Answer::Err {
                code: 1,
                text: "unknown command".into(),
            },
        };
        self.answer(ctx, line, reply);
    }

    fn tick(&mut self, ctx: &mut Ctx) {
        self.beam(ctx);
        let Some(mut cad) = self.stream else { return };
        let now_us = ctx.clock.dev_us(ctx.now);
        let mut samples = Vec::new();
        loop {
            let pos_t = cad.next_us();
            if self.env_next_us <= pos_t && self.env_next_us <= now_us {
                let t = self.env_next_us;
                self.env_next_us += 1e6;
                self.send_env(ctx, ctx.clock.instant(t), t.round() as u64);
                continue;
            }
            match cad.take_due(now_us) {
                Some(t) => self.send_pos(ctx, t, &mut samples),
                None => break,
            }
        }
        self.stream = Some(cad);
        if !samples.is_empty() {
            ctx.record_samples(samples);
        }
    }

    fn tick_unplugged(&mut self, _ctx: &mut Ctx) {}
}
