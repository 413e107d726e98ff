//! Test generator: a small lumped thermal network of its own (no code shared with the
//! analysis), integrated with explicit Euler sub-steps, driven by a spindle speed schedule and
//! ambient, read by noisy sensors. Each class hides some effects from the static regression.

#![allow(dead_code)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Effects a run can hide.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Effect {
    /// The displacement comes from a mass heated only through the sensed housing.
    Lag,
    /// The displacement comes partly from the spindle mass no sensor reads.
    Unseen,
    /// As `Unseen`, with the spindle cooled harder while it turns (coolant, air flow).
    Asymmetry,
    /// An extra sensor on the column that is noisy and jumps.
    Noisy,
    /// Two extra sensors reading the column with the first: three near-copies.
    Collinear,
}

pub const CLASSES: &[&[Effect]] = &[
    &[],
    &[Effect::Lag],
    &[Effect::Unseen],
    &[Effect::Asymmetry],
    &[Effect::Noisy],
    &[Effect::Collinear],
    &[Effect::Lag, Effect::Unseen],
    &[Effect::Lag, Effect::Asymmetry],
    &[Effect::Lag, Effect::Noisy],
    &[Effect::Lag, Effect::Collinear],
    &[Effect::Unseen, Effect::Noisy],
    &[Effect::Unseen, Effect::Collinear],
    &[Effect::Asymmetry, Effect::Noisy],
    &[Effect::Asymmetry, Effect::Collinear],
    &[Effect::Noisy, Effect::Collinear],
];

pub fn class_name(c: &[Effect]) -> String {
    if c.is_empty() {
        return "none".into();
    }
    c.iter()
        .map(|e| format!("{e:?}").to_lowercase())
        .collect::<Vec<_>>()
        .join("+")
}

/// The finding kinds (as `Finding::kind`) a class should produce.
pub fn expected_kinds(c: &[Effect]) -> Vec<&'static str> {
    let mut v = vec![];
    for e in c {
        match e {
            Effect::Lag => v.push("lag"),
            Effect::Unseen => v.push("unseen heat source"),
            Effect::Asymmetry => v.extend(["unseen heat source", "heating/cooling asymmetry"]),
            Effect::Noisy => v.push("noisy sensor"),
            Effect::Collinear => v.push("collinear sensors"),
        }
    }
    v
}

// Nodes of the network.
const S: usize = 0; // spindle bearings (never read), cooled by a chiller held at 20 °C
const H: usize = 1; // spindle housing
const C: usize = 2; // column
const L: usize = 3; // a mass heated only through the housing (never read)

struct Network {
    cap: [f64; 4],     // J/K
    g_sa: f64,         // W/K spindle-chiller at rest
    g_sa_running: f64, // spindle-chiller while turning (more coolant flow)
    motor_share: f64,  // heat into the housing per unit of the spindle's
    g_ha: f64,
    g_hc: f64,
    g_ca: f64,
    g_lh: f64,
    heat_per_krpm2: f64, // W per (1000 rpm)^2
}

impl Network {
    fn derivative(&self, t: &[f64; 4], ambient: f64, krpm: f64) -> [f64; 4] {
        let g_sa = if krpm > 0.0 {
            self.g_sa_running
        } else {
            self.g_sa
        };
        let q = self.heat_per_krpm2 * krpm * krpm;
        let f_hc = self.g_hc * (t[H] - t[C]);
        let f_lh = self.g_lh * (t[H] - t[L]);
        [
            (q - g_sa * (t[S] - 20.0)) / self.cap[S],
            (self.motor_share * q - f_hc - f_lh - self.g_ha * (t[H] - ambient)) / self.cap[H],
            (f_hc - self.g_ca * (t[C] - ambient)) / self.cap[C],
            f_lh / self.cap[L],
        ]
    }
}

/// One generated run as CSV text, with what a bound on separability needs: the
/// displacement without its noise and the inputs as the CSV has them.
pub struct Run {
    pub csv: String,
    /// Displacement without noise, µm (the CSV's `x_um` less its noise, unrounded).
    pub truth_um: Vec<f64>,
    /// Per row: time (s), speed (rpm) and the temperatures the sensors read, without their
    /// noise: housing, column, ambient (°C).
    pub inputs: Vec<[f64; 5]>,
}

fn speed_schedule(rng: &mut ChaCha8Rng, hours: f64) -> Vec<(f64, f64)> {
    let mut out = vec![];
    let mut t = rng.random_range(0.2..0.6) * 3600.0;
    out.push((0.0, 0.0));
    while t < hours * 3600.0 {
        let rpm = [2000.0, 3000.0, 4000.0, 5000.0, 6000.0][rng.random_range(0..5)];
        out.push((t, rpm));
        t += rng.random_range(1.5..3.0) * 3600.0;
        out.push((t, 0.0));
        t += rng.random_range(1.5..3.0) * 3600.0;
    }
    out
}

fn rpm_at(schedule: &[(f64, f64)], t: f64) -> f64 {
    schedule
        .iter()
        .rev()
        .find(|(s, _)| *s <= t)
        .map_or(0.0, |(_, r)| *r)
}

/// Generates a run of `hours` sampled every `dt_s` with the effects of `class`.
pub fn generate(class: &[Effect], seed: u64, hours: f64, dt_s: f64) -> Run {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let has = |e: Effect| class.contains(&e);
    let asym = has(Effect::Asymmetry);
    let unseen = has(Effect::Unseen) || asym;
    // Time constants: spindle 15-30 min at rest (3-5x shorter while turning with asymmetry), housing ~1-2 h, column several hours, L 40-90 min.
    let tau_s = rng.random_range(15.0..30.0) * 60.0;
    let g_sa = 10.0;
    let g_sa_running = if asym {
        g_sa * rng.random_range(3.0..5.0)
    } else {
        g_sa
    };
    let cap_s = tau_s * g_sa;
    let tau_l = rng.random_range(40.0..90.0) * 60.0;
    let g_lh = 1.0;
    let net = Network {
        cap: [
            cap_s,
            rng.random_range(5.0..8.0) * 3600.0 * 12.0,
            rng.random_range(6.0..10.0) * 3600.0 * 6.0,
            tau_l * g_lh,
        ],
        g_sa,
        g_sa_running,
        motor_share: 2.0,
        g_ha: 6.0,
        g_hc: 2.0,
        g_ca: 4.0,
        g_lh,
        heat_per_krpm2: rng.random_range(1.5..3.0),
    };
    let schedule = speed_schedule(&mut rng, hours);
    let amb_period = rng.random_range(16.0..30.0) * 3600.0;
    let amb_phase = rng.random_range(0.0..std::f64::consts::TAU);
    let amb_amp = rng.random_range(0.8..1.5);
    let ambient = |t: f64| {
        20.0 + amb_amp
            * ((std::f64::consts::TAU * t / amb_period + amb_phase).sin() - amb_phase.sin())
    };
    let mut temp = [20.0; 4];
    let n = (hours * 3600.0 / dt_s) as usize;
    let sub = 10;
    let mut rows: Vec<(f64, f64, [f64; 4], f64)> = Vec::with_capacity(n);
    for k in 0..n {
        let t = k as f64 * dt_s;
        let rpm = rpm_at(&schedule, t);
        rows.push((t, rpm, temp, ambient(t)));
        for j in 0..sub {
            let tt = t + j as f64 * dt_s / sub as f64;
            let d = net.derivative(&temp, ambient(tt), rpm / 1000.0);
            for i in 0..4 {
                temp[i] += d[i] * dt_s / sub as f64;
            }
        }
    }
    // Displacement, µm per K of each mass.
    let a_h = rng.random_range(2.0..4.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let a_c = rng.random_range(2.0..4.0);
    let a_s = rng.random_range(1.5..3.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let noise_d = Normal::new(0.0, 0.1).unwrap_or_else(|_| unreachable!());
    let noise_t = Normal::new(0.0, 0.01).unwrap_or_else(|_| unreachable!());
    let noise_copy = Normal::new(0.0, 0.03).unwrap_or_else(|_| unreachable!());
    let noise_bad = Normal::new(0.0, 0.15).unwrap_or_else(|_| unreachable!());
    let jump_at: Vec<usize> = (0..3)
        .map(|_| rng.random_range(n / 10..n * 9 / 10))
        .collect();
    let jump_size: Vec<f64> = (0..3)
        .map(|_| rng.random_range(0.6..1.2) * if rng.random_bool(0.5) { 1.0 } else { -1.0 })
        .collect();
    let mut header = String::from("time_s,spindle_rpm,x_um,housing_c,column_c,ambient_c");
    if has(Effect::Noisy) {
        header += ",column_b_c";
    }
    if has(Effect::Collinear) {
        header += ",column_c2_c,column_c3_c";
    }
    let mut csv = format!("# generated: {}\n{header}\n", class_name(class));
    let first = rows[0].2;
    let (mut truth_um, mut inputs) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for (k, (t, rpm, m, amb)) in rows.iter().enumerate() {
        let drive = if has(Effect::Lag) {
            a_h * (m[L] - first[L])
        } else {
            a_h * (m[H] - first[H])
        };
        let mut d = drive + a_c * (m[C] - first[C]) + noise_d.sample(&mut rng);
        let mut clean = drive + a_c * (m[C] - first[C]);
        if unseen {
            d += a_s * (m[S] - first[S]);
            clean += a_s * (m[S] - first[S]);
        }
        truth_um.push(clean);
        let read = [
            m[H] + noise_t.sample(&mut rng),
            m[C] + noise_t.sample(&mut rng),
            amb + noise_t.sample(&mut rng),
        ];
        inputs.push([*t, *rpm, m[H], m[C], *amb]);
        let mut line = format!(
            "{t},{rpm},{d:.4},{:.4},{:.4},{:.4}",
            read[0], read[1], read[2]
        );
        if has(Effect::Noisy) {
            let jump: f64 = jump_at
                .iter()
                .zip(&jump_size)
                .filter(|(a, _)| k >= **a)
                .map(|(_, s)| s)
                .sum();
            line += &format!(",{:.4}", m[C] + jump + noise_bad.sample(&mut rng));
        }
        if has(Effect::Collinear) {
            for _ in 0..2 {
                line += &format!(",{:.4}", m[C] + noise_copy.sample(&mut rng));
            }
        }
        csv += &line;
        csv.push('\n');
    }
    Run {
        csv,
        truth_um,
        inputs,
    }
}
