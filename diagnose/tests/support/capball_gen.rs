//! A generator of CapBall runs with hidden effects, for the diagnosis tests.
//!
//! Its forward model is written here, separately from metrology's kinematics: the exact
//! rigid-body chain of the `WCAYFXZT` machine (A along x, C along z, both through the origin,
//! ball at (120, 80, 100) mm) built from rotation matrices, following the conventions written
//! down in `docs/methods.md` (paper 001) and the kinematics module docs: errors are those of
//! the relative motion of the tool against the workpiece, so the workpiece-side Y, A and C
//! components carry them with the opposite sign; the ball and tool errors are physical. The
//! test `generator_chain_matches_metrology` checks this chain against `forward_um` and its
//! numerical derivative against the analytic identification Jacobian.

#![allow(dead_code)]

use diagnose::capball::{CapballRun, DriftRecord};
use geometry::kinematics::Pose;
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

pub const BALL_MM: [f64; 3] = [120.0, 80.0, 100.0];

fn rot(axis: Vector3<f64>, angle_rad: f64) -> Matrix3<f64> {
    if angle_rad == 0.0 {
        return Matrix3::identity();
    }
    *Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle_rad).matrix()
}

/// A small rotation vector (µrad) as an exact rotation matrix.
fn small_rot(v_urad: Vector3<f64>) -> Matrix3<f64> {
    let n = v_urad.norm();
    if n == 0.0 {
        Matrix3::identity()
    } else {
        rot(v_urad, n * 1e-6)
    }
}

/// A motion error of a rotary axis: a translation of the axis's rotating part, in the
/// axis's housing frame, `amplitude · cos(k θ + φ) · direction`, µm.
#[derive(Debug, Clone, Copy)]
pub struct AxisMotion {
    /// 'A' or 'C'.
    pub axis: char,
    pub harmonic: u32,
    pub amplitude_um: f64,
    pub phase: f64,
    pub direction: Vector3<f64>,
    pub axial: bool,
}

impl AxisMotion {
    fn at(&self, theta_deg: f64) -> Vector3<f64> {
        self.direction
            * (self.amplitude_um
                * (self.harmonic as f64 * theta_deg.to_radians() + self.phase).cos())
    }
}

/// Link errors (EC0Y, EB0Z, EA0Z, EB0A, EC0A, EA0C, EB0C µrad; EY0C µm) and setup errors
/// (ball x y z, tool x y z, µm), in the order of `geometry::capball::PARAM_NAMES`.
pub fn exact_error_um(p: &[f64; 14], pose: &Pose, axis: Option<&AxisMotion>) -> [f64; 3] {
    let (ec0y, eb0z, ea0z) = (p[0], p[1], p[2]);
    let (eb0a, ec0a, ea0c, eb0c, ey0c) = (p[3], p[4], p[5], p[6], p[7]);
    let ball_err = Vector3::new(p[8], p[9], p[10]) * 1e-3;
    let tool_err = Vector3::new(p[11], p[12], p[13]) * 1e-3;
    // Tool side: X travels along x, Z along z tilted by (EA0Z, EB0Z).
    let dz = Vector3::z() + (Vector3::new(ea0z, eb0z, 0.0) * 1e-6).cross(&Vector3::z());
    let p_tool = Vector3::x() * pose.x_mm + dz * pose.z_mm + tool_err;
    // Workpiece side: the Y carriage moves by −y along y tilted by EC0Y.
    let dy = Vector3::y() + (Vector3::new(0.0, 0.0, ec0y) * 1e-6).cross(&Vector3::y());
    let t_y = -dy * pose.y_mm;
    // A cradle: the link error (orientation of A) is physical with the opposite sign.
    let r_a_link = small_rot(-Vector3::new(0.0, eb0a, ec0a));
    let r_a = rot(Vector3::x(), -pose.a_deg.to_radians());
    let d_a = match axis {
        Some(m) if m.axis == 'A' => m.at(pose.a_deg) * 1e-3,
        _ => Vector3::zeros(),
    };
    // C table: location (EY0C) and orientation (EA0C, EB0C), opposite sign.
    let r_c_link = small_rot(-Vector3::new(ea0c, eb0c, 0.0));
    let t_c_link = -Vector3::new(0.0, ey0c, 0.0) * 1e-3;
    let r_c = rot(Vector3::z(), -pose.c_deg.to_radians());
    let d_c = match axis {
        Some(m) if m.axis == 'C' => m.at(pose.c_deg) * 1e-3,
        _ => Vector3::zeros(),
    };
    let ball = Vector3::from(BALL_MM) + ball_err;
    // frame → Y → A → C → workpiece point
    let in_c = r_c * ball;
    let in_a = t_c_link + r_c_link * (d_c + in_c);
    let in_y = r_a_link * (d_a + r_a * in_a);
    let p_work = t_y + in_y;
    let e = (p_tool - p_work) * 1e3;
    [e.x, e.y, e.z]
}

/// The pose holding the nominal tool on the ball at angles A, C (derived here: the tool point
/// is (x, 0, z); the ball sits at Rx(−A) Rz(−C) b − y ŷ).
pub fn pose_on_ball(a_deg: f64, c_deg: f64) -> Pose {
    let w = rot(Vector3::x(), -a_deg.to_radians())
        * rot(Vector3::z(), -c_deg.to_radians())
        * Vector3::from(BALL_MM);
    Pose {
        x_mm: w.x,
        y_mm: w.y,
        z_mm: w.z,
        a_deg,
        b_deg: 0.0,
        c_deg,
    }
}

/// A spiral trajectory: A from `a0` to `a1`, C through `turns` revolutions.
pub fn trajectory(n: usize, a0: f64, a1: f64, turns: f64) -> Vec<Pose> {
    (0..n)
        .map(|i| {
            let t = i as f64 / (n - 1) as f64;
            pose_on_ball(a0 + (a1 - a0) * t, (360.0 * turns * t) % 360.0)
        })
        .collect()
}

/// Effect classes of the sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Class {
    None,
    Cyclic,
    Linear,
    Gain,
    Axis,
    Outliers,
    Two,
}

impl Class {
    pub const ALL: [Class; 7] = [
        Class::None,
        Class::Cyclic,
        Class::Linear,
        Class::Gain,
        Class::Axis,
        Class::Outliers,
        Class::Two,
    ];
    pub fn name(self) -> &'static str {
        match self {
            Class::None => "none",
            Class::Cyclic => "cyclic_drift",
            Class::Linear => "linear_drift",
            Class::Gain => "sensor_gain",
            Class::Axis => "axis_error",
            Class::Outliers => "outliers",
            Class::Two => "two effects",
        }
    }
}

/// The hidden truth of a generated dataset.
#[derive(Debug, Clone, Default)]
pub struct Truth {
    pub params: [f64; 14],
    pub noise_um: f64,
    /// Period (s) and per-axis (half peak-to-valley amplitude µm, phase rad).
    pub cyclic: Option<(f64, [(f64, f64); 3])>,
    pub linear_um_per_h: Option<[f64; 3]>,
    /// (channel, gain − 1).
    pub gain: Option<(usize, f64)>,
    pub axis: Option<AxisMotion>,
    pub outliers: usize,
    /// Names of the hidden effects.
    pub effects: Vec<&'static str>,
}

impl Truth {
    fn drift_um(&self, t: f64) -> [f64; 3] {
        let mut d = [0.0; 3];
        if let Some((period, a)) = self.cyclic {
            for k in 0..3 {
                d[k] += a[k].0 * (std::f64::consts::TAU * t / period + a[k].1).sin();
            }
        }
        if let Some(r) = self.linear_um_per_h {
            for k in 0..3 {
                d[k] += r[k] * t / 3600.0;
            }
        }
        d
    }
    /// What the CapBall reads at a pose and time (no noise).
    pub fn reading(&self, pose: &Pose, t: f64) -> [f64; 3] {
        let e = exact_error_um(&self.params, pose, self.axis.as_ref());
        let d = self.drift_um(t);
        let mut r = [e[0] + d[0], e[1] + d[1], e[2] + d[2]];
        if let Some((ch, g)) = self.gain {
            r[ch] *= 1.0 + g;
        }
        r
    }
}

pub struct Dataset {
    pub truth: Truth,
    pub ident: CapballRun,
    pub validation: CapballRun,
    pub record: Option<DriftRecord>,
}

fn sym(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let v = rng.random_range(lo..hi);
    if rng.random::<bool>() { v } else { -v }
}

fn hide(rng: &mut ChaCha8Rng, truth: &mut Truth, effect: &'static str) {
    match effect {
        "cyclic_drift" => {
            let period = rng.random_range(4.0..25.0) * 60.0;
            let a = std::array::from_fn(|_| {
                (
                    rng.random_range(0.5..3.0),
                    rng.random_range(0.0..std::f64::consts::TAU),
                )
            });
            truth.cyclic = Some((period, a));
        }
        "linear_drift" => {
            truth.linear_um_per_h = Some(std::array::from_fn(|_| sym(rng, 2.0, 10.0)));
        }
        "sensor_gain" => {
            truth.gain = Some((rng.random_range(0..3), sym(rng, 0.02, 0.05)));
        }
        "axis_error" => {
            let c_axis = rng.random::<f64>() < 0.7;
            let harmonic = if c_axis {
                rng.random_range(1..=4)
            } else {
                rng.random_range(2..=4)
            };
            // An axial once-per-revolution motion of C is a tilt of the C axis line (EA0C,
            // EB0C): the 14 parameters take it up, see `c_axial_once_per_rev_is_absorbed`.
            let axial = rng.random::<f64>() < 0.3 && !(c_axis && harmonic == 1);
            let phi = rng.random_range(0.0..std::f64::consts::TAU);
            let direction = match (c_axis, axial) {
                (true, true) => Vector3::z(),
                (true, false) => Vector3::new(phi.cos(), phi.sin(), 0.0),
                (false, true) => Vector3::x(),
                (false, false) => Vector3::new(0.0, phi.cos(), phi.sin()),
            };
            truth.axis = Some(AxisMotion {
                axis: if c_axis { 'C' } else { 'A' },
                harmonic,
                amplitude_um: rng.random_range(0.5..2.0),
                phase: rng.random_range(0.0..std::f64::consts::TAU),
                direction,
                axial,
            });
        }
        "outliers" => truth.outliers = rng.random_range(1..=4),
        _ => {}
    }
    truth.effects.push(effect);
}

fn run(
    truth: &Truth,
    poses: Vec<Pose>,
    t0: f64,
    rng: &mut ChaCha8Rng,
    noise: &Normal<f64>,
) -> CapballRun {
    let mut t = t0;
    let mut time_s = Vec::new();
    let mut e_um = Vec::new();
    for p in &poses {
        t += rng.random_range(0.7..0.8);
        time_s.push(t);
        let r = truth.reading(p, t);
        e_um.push(r.map(|v| v + noise.sample(rng)));
    }
    for _ in 0..truth.outliers {
        let i = rng.random_range(0..poses.len());
        let ch = rng.random_range(0..3);
        e_um[i][ch] += sym(
            rng,
            3.0f64.max(8.0 * truth.noise_um),
            10.0f64.max(9.0 * truth.noise_um),
        );
    }
    CapballRun::new(poses, time_s, e_um)
}

/// One dataset of a class: identification (A 0 → −90°) and validation (A −90 → 0°) runs of
/// 300–807 poses, ~0.75 s per pose, random link/setup errors and white noise 0.1–0.4 µm;
/// a drift record at A = C = 0 over the hour before when `record`.
pub fn generate(class: Class, seed: u64, record: bool) -> Dataset {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut truth = Truth::default();
    for i in 0..14 {
        truth.params[i] = match i {
            0..=6 => sym(&mut rng, 0.0, 40.0),
            7 => sym(&mut rng, 0.0, 30.0),
            _ => sym(&mut rng, 0.0, 50.0),
        };
    }
    truth.noise_um = rng.random_range(0.1..0.4);
    let all = ["cyclic_drift", "linear_drift", "sensor_gain", "axis_error"];
    match class {
        Class::None => {}
        Class::Cyclic => hide(&mut rng, &mut truth, "cyclic_drift"),
        Class::Linear => hide(&mut rng, &mut truth, "linear_drift"),
        Class::Gain => hide(&mut rng, &mut truth, "sensor_gain"),
        Class::Axis => hide(&mut rng, &mut truth, "axis_error"),
        Class::Outliers => hide(&mut rng, &mut truth, "outliers"),
        Class::Two => {
            let i = rng.random_range(0..4);
            let j = (i + rng.random_range(1..4)) % 4;
            hide(&mut rng, &mut truth, all[i]);
            hide(&mut rng, &mut truth, all[j]);
        }
    }
    let n = rng.random_range(300..=807);
    let turns = (n as f64 / 807.0 * 6.0).max(3.0);
    let noise = Normal::new(0.0, truth.noise_um).expect("noise");
    let ident = run(
        &truth,
        trajectory(n, 0.0, -90.0, turns),
        0.0,
        &mut rng,
        &noise,
    );
    let gap = rng.random_range(30.0..120.0);
    let t_end = *ident.time_s.last().expect("poses");
    let validation = run(
        &truth,
        trajectory(n, -90.0, 0.0, turns),
        t_end + gap,
        &mut rng,
        &noise,
    );
    let record = record.then(|| {
        let p = pose_on_ball(0.0, 0.0);
        let time_s: Vec<f64> = (0..720).map(|i| -3600.0 + 5.0 * i as f64).collect();
        let e_um = time_s
            .iter()
            .map(|&t| truth.reading(&p, t).map(|v| v + noise.sample(&mut rng)))
            .collect();
        DriftRecord { time_s, e_um }
    });
    Dataset {
        truth,
        ident,
        validation,
        record,
    }
}
