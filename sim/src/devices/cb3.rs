//! CB-3 CapBall ADC (instruments.md §2).

use std::sync::Arc;
use std::time::Instant;

use protocol::cb3::{Answer, Command, Frame, SampleFrame};
use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::device::{Cadence, Ctx, Fault, FaultDice, Model, POWER_UP_RATE_HZ, count_fate};
use crate::instrument::Device;
use crate::physics::volts_for_um;
use crate::record::{Fate, SentSample, SentValues};
use crate::scenario::Capball;
use crate::shared::Shared;

const RATE_RANGE_HZ: std::ops::RangeInclusive<u32> = 100..=20_000;
/// Codes per volt: 2^23 codes for 10 V full scale.
const CODES_PER_V: f64 = 8_388_608.0 / 10.0;
const CODE_MAX: i32 = 8_388_607;
/// Direction of the machine's vibration after a stop, in the machine frame (normalised).
const RING_DIR: [f64; 3] = [0.80, 0.48, -0.36];

pub(crate) struct Cb3 {
    cfg: Capball,
    dice: FaultDice,
    noise: Normal<f64>,
    rate_hz: u32,
    stream: Option<Cadence>,
    seq: u64,
    /// Seed of the per-visit scatter, and the last visit's draw (pose index, µm).
    seed: u64,
    visit_scatter: Option<(usize, [f64; 3])>,
}

impl Cb3 {
    pub(crate) fn new(shared: &Arc<Shared>) -> Cb3 {
        let sc = &shared.world.scenario;
        Cb3 {
            noise: Normal::new(0.0, sc.capball.noise_um.max(0.0))
                .unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero std")),
            cfg: sc.capball.clone(),
            dice: FaultDice::new(sc.faults.capball),
            rate_hz: POWER_UP_RATE_HZ as u32,
            stream: None,
            seq: 0,
            seed: sc.seed,
            visit_scatter: None,
        }
    }

    fn text(&self, ctx: &mut Ctx, line: &str, reply: Answer) {
        let reply = reply.to_text();
        protocol::cb3::encode(&Frame::Text(reply.clone()), ctx.out);
        ctx.shared
            .lock_record()
            .capball
            .commands
            .push((line.to_string(), reply));
    }

    /// The measuring loop's scatter at one pose visit (`capball.truth.pose_noise_um`): drawn
    /// once per visit from the scenario seed and the pose index, so it holds through the dwell
    /// and the steady value keeps it, as on a real CapBall.
    fn scatter(&mut self, at_pose: usize) -> [f64; 3] {
        use rand::SeedableRng;
        if let Some((i, v)) = self.visit_scatter
            && i == at_pose
        {
            return v;
        }
        let sd = self.cfg.truth.pose_noise_um.max(0.0);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            self.seed ^ (at_pose as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        let n = Normal::new(0.0, sd).unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero std"));
        let v = [0, 1, 2].map(|_| n.sample(&mut rng));
        self.visit_scatter = Some((at_pose, v));
        v
    }

    /// ADC codes and over-range flags for the true error at `at`.
    fn codes(&mut self, ctx: &mut Ctx, at: Instant) -> ([i32; 3], u8) {
        let w = &ctx.shared.world;
        let sp = ctx.program_s(at);
        let ph = w.phase(sp);
        let t = ctx.slow_t(at);
        let mut e = w.capball_error_um(ph, t);
        if let crate::physics::Phase::Standing { at: pose, .. } = ph
            && self.cfg.truth.pose_noise_um > 0.0
        {
            let s = self.scatter(pose);
            for (ei, si) in e.iter_mut().zip(s) {
                *ei += si;
            }
        }
        let ring = w.ringing_um(ph) * self.cfg.ringing_gain;
        for (ei, r) in e.iter_mut().zip(RING_DIR) {
            *ei += ring * r;
        }
        let d = w.capball_sensor_um(e);
        let mut ch = [0i32; 3];
        let mut flags = 0u8;
        for i in 0..3 {
            let di = d[i] + self.noise.sample(ctx.rng);
            let v = volts_for_um(&self.cfg.poly[i], di);
            let code = (v * CODES_PER_V).round();
            if !code.is_finite() || code.abs() > CODE_MAX as f64 {
                flags |= 1 << i;
                ch[i] = if code < 0.0 { -CODE_MAX } else { CODE_MAX };
            } else {
                ch[i] = code as i32;
            }
        }
        (ch, flags)
    }

    fn send_sample(&mut self, ctx: &mut Ctx, dev_us: f64, samples: &mut Vec<SentSample>) {
        let at = ctx.clock.instant(dev_us);
        let t_us = dev_us.round() as u64;
        let seq = self.cfg.identity.seq_start.wrapping_add(self.seq);
        self.seq += 1;
        let (ch, flags) = self.codes(ctx, at);
        let frame = Frame::Sample(SampleFrame {
            seq: seq as u16,
            t_us: t_us as u32,
            ch,
            flags,
        });
        let mut garbage = false;
        let fate = match ctx.link_fate() {
            Some(f) => f,
            None => match self.dice.roll(ctx.rng, true) {
                Fault::None => Fate::Sent,
                Fault::Garbage => {
                    garbage = true;
                    ctx.faults.garbage += 1;
                    let n = ctx.rng.random_range(3..40);
                    for _ in 0..n {
                        let b: u8 = ctx.rng.random_range(1..=255);
                        ctx.out.push(b);
                    }
                    ctx.out.push(0);
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
                protocol::cb3::encode(&frame, ctx.unsent);
            }
            Fate::Sent => protocol::cb3::encode(&frame, ctx.out),
            Fate::BadChecksum => {
                let mut enc = Vec::new();
                protocol::cb3::encode(&frame, &mut enc);
                let body = &enc[..enc.len().saturating_sub(1)];
                match cobs::decode_vec(body) {
                    Ok(mut payload) if payload.len() > 7 => {
                        // Flip a bit of ch0 after the CRC was computed: length and type stay
                        // valid, only the CRC check can catch it.
                        payload[7] ^= 0x10;
                        ctx.out.extend_from_slice(&cobs::encode_vec(&payload));
                        ctx.out.push(0);
                    }
                    _ => ctx.out.extend_from_slice(&enc),
                }
            }
            Fate::Truncated => {
                let mut enc = Vec::new();
                protocol::cb3::encode(&frame, &mut enc);
                let cut = ctx.rng.random_range(2..enc.len().saturating_sub(2).max(3));
                enc.truncate(cut);
                enc.push(0);
                ctx.out.extend_from_slice(&enc);
            }
            _ => {}
        }
        samples.push(SentSample {
            power_up: ctx.power_up,
            seq,
            t_us,
            true_s: ctx.sim_s(at),
            values: SentValues::Capball { ch, flags },
            fate,
            garbage_before: garbage,
        });
    }
}

impl Model for Cb3 {
    const DEVICE: Device = Device::Capball;

    fn activity(&self) -> (bool, u32) {
        (self.stream.is_some(), self.rate_hz)
    }

    fn power_up(&mut self, _ctx: &mut Ctx) {
        self.rate_hz = POWER_UP_RATE_HZ as u32;
        self.stream = None;
        self.seq = 0;
    }

    fn command(&mut self, line: &str, ctx: &mut Ctx) {
        let reply = match Command::parse(line) {
            Some(Command::Id) => Answer::Id {
                serial: self.cfg.identity.serial.clone(),
                firmware: self.cfg.identity.firmware.clone(),
            },
            Some(Command::Rate(hz)) => {
                if RATE_RANGE_HZ.contains(&hz) {
                    self.rate_hz = hz;
                    if let Some(c) = &self.stream {
                        self.stream = Some(Cadence::new(hz as f64, c.next_us()));
                    }
                    Answer::Ok
                } else {
                    Answer::Err("rate out of range".into())
                }
            }
            Some(Command::Start) => {
                if self.stream.is_none() {
                    let now = ctx.now;
                    self.stream = Some(Cadence::new(self.rate_hz as f64, ctx.clock.dev_us(now)));
                }
                Answer::Ok
            }
            Some(Command::Stop) => {
                self.stream = None;
                Answer::Ok
            }
            None => Answer::Err("unknown command".into()),
        };
        self.text(ctx, line, reply);
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
