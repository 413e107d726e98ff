//! PSD-2 transimpedance board (instruments.md §3).

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Instant;

use protocol::psd::{Command, DataLine, Line, SystErr};
use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::device::{
    Cadence, Ctx, Fault, FaultDice, Model, POWER_UP_RATE_HZ, count_fate, garbage_text,
};
use crate::instrument::Device;
use crate::record::{Fate, SentSample, SentValues};
use crate::scenario::Psd;
use crate::shared::Shared;

/// Half the diode's side, µm (10 mm × 10 mm duolateral PSD).
const HALF_SIDE_UM: f64 = 5_000.0;
/// SCPI error queue length (IEEE 488.2: at least 2; overflow replaces the last entry).
const ERR_QUEUE: usize = 10;

pub(crate) struct Psd2 {
    cfg: Psd,
    dice: FaultDice,
    noise: Normal<f64>,
    rate_hz: u32,
    stream: Option<Cadence>,
    seq: u64,
    errors: VecDeque<SystErr>,
}

impl Psd2 {
    pub(crate) fn new(shared: &Arc<Shared>) -> Psd2 {
        let sc = &shared.world.scenario;
        Psd2 {
            noise: Normal::new(0.0, sc.psd.noise_um.max(0.0))
                .unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero std")),
            cfg: sc.psd.clone(),
            dice: FaultDice::new(sc.faults.psd),
            rate_hz: POWER_UP_RATE_HZ as u32,
            stream: None,
            seq: 0,
            errors: VecDeque::new(),
        }
    }

    fn push_error(&mut self, code: i32, text: &str) {
        if self.errors.len() >= ERR_QUEUE {
            self.errors.pop_back();
            self.errors.push_back(SystErr {
                code: -350,
                text: "Queue overflow".into(),
            });
        } else {
            self.errors.push_back(SystErr {
                code,
                text: text.into(),
            });
        }
    }

    fn answer(&self, ctx: &mut Ctx, line: &str, reply: String) {
        let reply = reply.trim_end_matches(['\r', '\n']).to_string();
        protocol::psd::encode_line(&Line::Answer(reply.clone()), ctx.out);
        ctx.shared
            .lock_record()
            .psd
            .commands
            .push((line.to_string(), reply));
    }

    /// Photocurrents and head temperature at `at`.
    fn reading(&self, ctx: &mut Ctx, at: Instant) -> DataLine {
        let w = &ctx.shared.world;
        let ph = w.phase(ctx.program_s(at));
        let t = ctx.slow_t(at);
        let c = w.coords(ph);
        let (mut x, mut y) = w.psd_spot_um(&c);
        let d = w.thermal_um(t);
        x += d[0];
        y += d[1];
        let ring = w.ringing_um(ph) * self.cfg.ringing_gain;
        x += ring + self.noise.sample(ctx.rng);
        y += 0.6 * ring + self.noise.sample(ctx.rng);
        let s = self.cfg.sum_pa;
        // x = (L/2)·(x2 − x1)/(x2 + x1) with x1 + x2 = s.
        let split = |p: f64| {
            let r = (p / HALF_SIDE_UM).clamp(-1.0, 1.0);
            let hi = (0.5 * s * (1.0 + r)).round().max(0.0) as u64;
            let lo = (0.5 * s * (1.0 - r)).round().max(0.0) as u64;
            (lo, hi)
        };
        let (x1, x2) = split(x);
        let (y1, y2) = split(y);
        let head_mc = (self.cfg.head_c.at(t) * 1e3).round() as i32;
        DataLine {
            seq: 0,
            t_us: 0,
            x1_pa: x1,
            x2_pa: x2,
            y1_pa: y1,
            y2_pa: y2,
            head_mc,
        }
    }

    fn send_sample(&mut self, ctx: &mut Ctx, dev_us: f64, samples: &mut Vec<SentSample>) {
        let at = ctx.clock.instant(dev_us);
        let t_us = dev_us.round() as u64;
        let seq = self.cfg.identity.seq_start.wrapping_add(self.seq);
        self.seq += 1;
        let mut d = self.reading(ctx, at);
        d.seq = seq as u32;
        d.t_us = t_us;
        let mut garbage = false;
        let fate = match ctx.link_fate() {
            Some(f) => f,
            None => match self.dice.roll(ctx.rng, false) {
                Fault::None | Fault::BadChecksum => Fate::Sent,
                Fault::Garbage => {
                    garbage = true;
                    ctx.faults.garbage += 1;
                    // Starts like a data line so the host counts it as a broken one, not
                    // as the answer to a query.
                    ctx.out.extend_from_slice(b"D,");
                    garbage_text(ctx.rng, ctx.out);
                    ctx.out.push(b'\n');
                    Fate::Sent
                }
                Fault::Truncated => Fate::Truncated,
                Fault::Dropped => Fate::Dropped,
            },
        };
        count_fate(ctx.faults, fate);
        match fate {
            Fate::NotConnected if ctx.keep_unsent => {
                ctx.unsent.clear();
                protocol::psd::encode_data(&d, ctx.unsent);
            }
            Fate::Sent => protocol::psd::encode_data(&d, ctx.out),
            Fate::Truncated => {
                let mut line = Vec::new();
                protocol::psd::encode_data(&d, &mut line);
                // Cut before the last comma: at least one field is missing.
                let last_comma = line.iter().rposition(|&b| b == b',').unwrap_or(2);
                let cut = ctx.rng.random_range(2..=last_comma.max(2));
                line.truncate(cut);
                line.push(b'\n');
                ctx.out.extend_from_slice(&line);
            }
            _ => {}
        }
        samples.push(SentSample {
            power_up: ctx.power_up,
            seq,
            t_us,
            true_s: ctx.sim_s(at),
            values: SentValues::Psd {
                x1_pa: d.x1_pa,
                x2_pa: d.x2_pa,
                y1_pa: d.y1_pa,
                y2_pa: d.y2_pa,
                head_mc: d.head_mc,
            },
            fate,
            garbage_before: garbage,
        });
    }
}

impl Model for Psd2 {
    const DEVICE: Device = Device::Psd;

    fn activity(&self) -> (bool, u32) {
        (self.stream.is_some(), self.rate_hz)
    }

    fn power_up(&mut self, _ctx: &mut Ctx) {
        self.rate_hz = POWER_UP_RATE_HZ as u32;
        self.stream = None;
        self.seq = 0;
        self.errors.clear();
    }

    fn command(&mut self, line: &str, ctx: &mut Ctx) {
        if line.trim().is_empty() {
            return;
        }
        match Command::parse(line) {
            Some(Command::Idn) => {
                let s = format!(
                    "PSD-2,{},{}",
                    self.cfg.identity.serial, self.cfg.identity.firmware
                );
                self.answer(ctx, line, s);
            }
            Some(Command::Opc) => self.answer(ctx, line, "1".into()),
            Some(Command::SystErr) => {
                let e = self.errors.pop_front().unwrap_or_else(SystErr::no_error);
                self.answer(ctx, line, e.to_line());
            }
            Some(Command::ConfRate(hz)) => {
                if protocol::psd::RATE_HZ.contains(&hz) {
                    self.rate_hz = hz;
                    if let Some(c) = &self.stream {
                        self.stream = Some(Cadence::new(hz as f64, c.next_us()));
                    }
                } else {
                    self.push_error(-222, "Data out of range");
                }
                ctx.shared
                    .lock_record()
                    .psd
                    .commands
                    .push((line.to_string(), String::new()));
            }
            Some(Command::InitCont(on)) => {
                if on && self.stream.is_none() {
                    let now = ctx.now;
                    self.stream = Some(Cadence::new(self.rate_hz as f64, ctx.clock.dev_us(now)));
                } else if !on {
                    self.stream = None;
                }
                ctx.shared
                    .lock_record()
                    .psd
                    .commands
                    .push((line.to_string(), String::new()));
            }
            None => {
                self.push_error(-113, "Undefined header");
                ctx.shared
                    .lock_record()
                    .psd
                    .commands
                    .push((line.to_string(), String::new()));
            }
        }
    }

    fn tick(&mut self, ctx: &mut Ctx) {
        let Some(mut cad) = self.stream else { return };
        let now_us = ctx.clock.dev_us(ctx.now);
        let mut samples = Vec::new();
        while let Some(t) = cad.take_due(now_us) {
            self.send_sample(ctx, t, &mut samples);
        }
        self.stream = Some(cad);
        if !samples.is_empty() {
            ctx.record_samples(samples);
        }
    }
}
