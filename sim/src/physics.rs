//! The simulated machine: where it is at a given instant, what each instrument truly sees
//! there, and the program's schedule. Everything here is a pure function of true time, so a
//! sample's value depends only on the instant its device clock stamps, never on when the
//! device task happened to run.

use metrology::axis_model::{AxisModel, Direction};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::scenario::{Axis, Capball, Coords, LinkErrors, Program, Psd, Scenario};

/// Timing of one pose, real seconds after the program start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseTiming {
    pub motion_start_s: f64,
    pub exact_stop_s: f64,
    pub dwell_end_s: f64,
}

/// When everything happens, real seconds after the program start.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    pub poses: Vec<PoseTiming>,
    /// The program-end frame.
    pub end_s: f64,
}

impl Schedule {
    pub fn new(p: &Program) -> Schedule {
        let mut t = p.lead_in_s;
        let mut poses = Vec::with_capacity(p.poses.len());
        for r in &p.poses {
            let m = r.move_s.unwrap_or(p.move_s);
            let d = r.dwell_s.unwrap_or(p.dwell_s);
            poses.push(PoseTiming {
                motion_start_s: t,
                exact_stop_s: t + m,
                dwell_end_s: t + m + d,
            });
            t += m + d;
        }
        Schedule {
            poses,
            end_s: t + p.lead_out_s,
        }
    }
}

/// What the machine is doing at an instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Phase {
    /// Before the first motion start (at home) or after the program.
    Idle,
    /// Moving to pose index `to` (0-based) from the previous pose (`None` = home).
    Moving { to: usize, frac: f64 },
    /// Standing at pose index `at` (0-based), `since_s` after its exact stop.
    Standing { at: usize, since_s: f64 },
}

/// The true value of one visit of a pose by the interferometer axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisVisit {
    /// 0-based index of the nearest target of the axis model.
    pub target_index: usize,
    pub direction: Direction,
    /// Random part drawn for this visit (noise and outliers of the axis model), µm.
    pub random_um: f64,
}

/// The true volumetric error at a pose: swap in another model through this trait.
pub trait CapballTruth: Send + Sync {
    /// Error of the tool centre point relative to the ball in the machine frame, µm, at axis
    /// positions `pose` and scaled time `t_s`.
    fn error_um(&self, pose: &Coords, t_s: f64) -> [f64; 3];
}

impl<F> CapballTruth for F
where
    F: Fn(&Coords, f64) -> [f64; 3] + Send + Sync,
{
    fn error_um(&self, pose: &Coords, t_s: f64) -> [f64; 3] {
        self(pose, t_s)
    }
}

impl CapballTruth for LinkErrors {
    fn error_um(&self, pose: &Coords, t_s: f64) -> [f64; 3] {
        let ra = rot_x(pose.a_deg.to_radians());
        let rc = rot_z(pose.c_deg.to_radians());
        let da = [0.0, self.a_offset_um[0], self.a_offset_um[1]];
        let dc = [self.c_offset_um[0], self.c_offset_um[1], 0.0];
        // (I − R)·δ: a rotation about a centre line displaced by δ moves the ball by that much.
        let ea = sub(da, mul(&ra, da));
        let ec = mul(&ra, sub(dc, mul(&rc, dc)));
        // A tilt θ of the C axis rotates the ball position p by θ × p (small angles).
        let th = [self.c_tilt_urad[0] * 1e-6, self.c_tilt_urad[1] * 1e-6, 0.0];
        let p_um = [
            self.ball_mm[0] * 1e3,
            self.ball_mm[1] * 1e3,
            self.ball_mm[2] * 1e3,
        ];
        let et = mul(&ra, mul(&rc, cross(th, p_um)));
        let mut e = [0.0; 3];
        for i in 0..3 {
            e[i] = self.setup_offset_um[i]
                + self.drift_um_per_h[i] * t_s / 3600.0
                + ea[i]
                + ec[i]
                + et[i];
        }
        e
    }
}

type M3 = [[f64; 3]; 3];

fn rot_x(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
}
fn rot_z(a: f64) -> M3 {
    let (s, c) = a.sin_cos();
    [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
}
fn mul(m: &M3, v: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalised_directions(c: &Capball) -> M3 {
    let mut n = c.sensor_directions;
    for row in &mut n {
        let len = (row[0] * row[0] + row[1] * row[1] + row[2] * row[2]).sqrt();
        for v in row.iter_mut() {
            *v /= len;
        }
    }
    n
}

fn invert3(m: &M3) -> Option<M3> {
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det.abs() < 1e-12 {
        return None;
    }
    let mut r = [[0.0; 3]; 3];
    #[allow(clippy::needless_range_loop)] // cofactor indices, clearer as numbers
    for i in 0..3 {
        for j in 0..3 {
            let (a, b) = ((j + 1) % 3, (j + 2) % 3);
            let (c, d) = ((i + 1) % 3, (i + 2) % 3);
            r[i][j] = (m[a][c] * m[b][d] - m[a][d] * m[b][c]) / det;
        }
    }
    Some(r)
}

/// `T` with `v = T·[d; 1]` for the sensor geometry `d = N·v + d0`: `T = [N⁻¹, −N⁻¹·d0; 0 1]`.
/// Sensor directions that are not independent give the identity.
pub fn capball_host_transform(c: &Capball) -> [[f64; 4]; 4] {
    let n = normalised_directions(c);
    let Some(ni) = invert3(&n) else {
        return [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
    };
    let t = mul(&ni, c.zero_offset_um);
    [
        [ni[0][0], ni[0][1], ni[0][2], -t[0]],
        [ni[1][0], ni[1][1], ni[1][2], -t[1]],
        [ni[2][0], ni[2][1], ni[2][2], -t[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Volts for distance change `d_um` through the inverse of `d = c1·V + c2·V² + c3·V³`
/// (Newton from the linear guess; the polynomial is monotonic over the ±10 V range in use).
pub fn volts_for_um(poly: &[f64; 3], d_um: f64) -> f64 {
    let mut v = d_um / poly[0];
    for _ in 0..30 {
        let f = poly[0] * v + poly[1] * v * v + poly[2] * v * v * v - d_um;
        let df = poly[0] + 2.0 * poly[1] * v + 3.0 * poly[2] * v * v;
        if df.abs() < 1e-12 {
            break;
        }
        let step = f / df;
        v -= step;
        if step.abs() < 1e-15 {
            break;
        }
    }
    v
}

/// The simulated world: the scenario's physics, evaluated at instants.
pub struct World {
    pub scenario: Scenario,
    pub schedule: Schedule,
    pub visits: Vec<AxisVisit>,
    pub capball_truth: std::sync::Arc<dyn CapballTruth>,
    sensor_n: M3,
}

impl World {
    pub fn new(
        scenario: Scenario,
        capball_truth: std::sync::Arc<dyn CapballTruth>,
        rng: &mut ChaCha8Rng,
    ) -> World {
        let schedule = Schedule::new(&scenario.program);
        let visits = draw_visits(&scenario, rng);
        let sensor_n = normalised_directions(&scenario.capball);
        World {
            scenario,
            schedule,
            visits,
            capball_truth,
            sensor_n,
        }
    }

    /// The machine's phase at `s` real seconds after the program start (`None`: not started).
    pub fn phase(&self, s: Option<f64>) -> Phase {
        let Some(s) = s else { return Phase::Idle };
        let poses = &self.schedule.poses;
        if poses.is_empty() || s < poses[0].motion_start_s {
            return Phase::Idle;
        }
        // Index of the last pose whose motion has started.
        let i = poses.partition_point(|p| p.motion_start_s <= s) - 1;
        let p = poses[i];
        if s < p.exact_stop_s {
            let dur = p.exact_stop_s - p.motion_start_s;
            let frac = if dur > 0.0 {
                (s - p.motion_start_s) / dur
            } else {
                1.0
            };
            Phase::Moving { to: i, frac }
        } else {
            Phase::Standing {
                at: i,
                since_s: s - p.exact_stop_s,
            }
        }
    }

    fn pose(&self, i: usize) -> Coords {
        self.scenario.program.poses[i].coords()
    }

    fn previous(&self, i: usize) -> Coords {
        if i == 0 {
            self.scenario.program.home
        } else {
            self.pose(i - 1)
        }
    }

    /// Axis positions at a phase (smooth S-shaped motion profile between poses).
    pub fn coords(&self, ph: Phase) -> Coords {
        match ph {
            Phase::Idle => self.scenario.program.home,
            Phase::Standing { at, .. } => self.pose(at),
            Phase::Moving { to, frac } => {
                let a = self.previous(to);
                let b = self.pose(to);
                let k = 0.5 - 0.5 * (std::f64::consts::PI * frac.clamp(0.0, 1.0)).cos();
                let l = |x: f64, y: f64| x + (y - x) * k;
                Coords {
                    x_mm: l(a.x_mm, b.x_mm),
                    y_mm: l(a.y_mm, b.y_mm),
                    z_mm: l(a.z_mm, b.z_mm),
                    a_deg: l(a.a_deg, b.a_deg),
                    c_deg: l(a.c_deg, b.c_deg),
                }
            }
        }
    }

    /// Damped oscillation after the exact stop, µm (before gain).
    pub fn ringing_um(&self, ph: Phase) -> f64 {
        match ph {
            Phase::Standing { since_s, .. } => {
                let r = &self.scenario.ringing;
                r.amplitude_um
                    * (-since_s / r.decay_s).exp()
                    * (std::f64::consts::TAU * r.frequency_hz * since_s).sin()
            }
            _ => 0.0,
        }
    }

    /// True deviation of the X axis at visit `i` (0-based pose), scaled time `t_s`, µm.
    pub fn axis_deviation_at_visit_um(&self, i: usize, t_s: f64) -> f64 {
        let v = self.visits[i];
        self.scenario
            .axis
            .deterministic_um(v.target_index, v.direction, t_s)
            + v.random_um
    }

    /// True deviation of the X axis (indicated minus programmed, at 20 °C), µm. Zero at home:
    /// the datum is taken there. During a move the deviation blends from visit to visit.
    pub fn axis_deviation_um(&self, ph: Phase, t_s: f64) -> f64 {
        match ph {
            Phase::Idle => 0.0,
            Phase::Standing { at, .. } => self.axis_deviation_at_visit_um(at, t_s),
            Phase::Moving { to, frac } => {
                let a = if to == 0 {
                    0.0
                } else {
                    self.axis_deviation_at_visit_um(to - 1, t_s)
                };
                let b = self.axis_deviation_at_visit_um(to, t_s);
                a + (b - a) * frac.clamp(0.0, 1.0)
            }
        }
    }

    /// Length from home to the reflector as it is at 20 °C, µm.
    pub fn axis_length20_um(&self, ph: Phase, t_s: f64) -> f64 {
        let home = self.scenario.program.home.x_mm;
        (self.coords(ph).x_mm - home) * 1e3 + self.axis_deviation_um(ph, t_s)
    }

    /// Air temperature, pressure, humidity and material temperatures at scaled time `t_s`.
    pub fn environment(&self, t_s: f64) -> (f64, f64, f64, Vec<f64>) {
        let e = &self.scenario.environment;
        (
            e.air_c.at(t_s),
            e.air_pa.at(t_s),
            e.rh_pct.at(t_s),
            e.material_c.iter().map(|m| m.at(t_s)).collect(),
        )
    }

    /// Sensor distance changes (µm, noise-free) for a machine-frame error `e_um`.
    pub fn capball_sensor_um(&self, e_um: [f64; 3]) -> [f64; 3] {
        let d = mul(&self.sensor_n, e_um);
        let z = self.scenario.capball.zero_offset_um;
        [d[0] + z[0], d[1] + z[1], d[2] + z[2]]
    }

    /// True PSD spot position (x, y) µm at axis positions `c`.
    pub fn psd_spot_um(&self, c: &Coords) -> (f64, f64) {
        let p: &Psd = &self.scenario.psd;
        let u = match p.along {
            Axis::X => c.x_mm,
            Axis::Y => c.y_mm,
            Axis::Z => c.z_mm,
        } / 100.0;
        let poly = |k: &[f64]| k.iter().rev().fold(0.0, |acc, &ck| acc * u + ck);
        (poly(&p.straightness_x_um), poly(&p.straightness_y_um))
    }
}

impl World {
    /// The CNC's trigger events in order: (real seconds after the program start, event, pose).
    pub fn trigger_events(&self) -> Vec<(f64, protocol::can::TriggerEvent, u16)> {
        use protocol::can::TriggerEvent as E;
        let mut v = vec![(0.0, E::ProgramStart, 0)];
        for (i, p) in self.schedule.poses.iter().enumerate() {
            let pose = (i + 1) as u16;
            v.push((p.motion_start_s, E::MotionStart, pose));
            v.push((p.exact_stop_s, E::ExactStop, pose));
            v.push((p.dwell_end_s, E::DwellEnd, pose));
        }
        v.push((self.schedule.end_s, E::ProgramEnd, 0));
        v
    }

    /// The true values at every pose, evaluated in the middle of the settled dwell.
    pub fn truth(&self) -> Vec<crate::record::PoseTruth> {
        let settle = self.scenario.ringing.settle_s();
        let scale = self.scenario.time_scale;
        let mut out = Vec::with_capacity(self.schedule.poses.len());
        for (i, p) in self.schedule.poses.iter().enumerate() {
            let from = (p.exact_stop_s + settle).min(p.dwell_end_s);
            let eval_s = 0.5 * (from + p.dwell_end_s);
            let t = eval_s * scale;
            let c = self.pose(i);
            let v = self.visits[i];
            let dev = self.axis_deviation_at_visit_um(i, t);
            let rate = (self.axis_deviation_at_visit_um(i, t + scale)
                - self.axis_deviation_at_visit_um(i, (t - scale).max(0.0)))
                / if t >= scale { 2.0 } else { 1.0 + t / scale };
            let (air_c, _, _, mat) = self.environment(t);
            let (px, py) = self.psd_spot_um(&c);
            out.push(crate::record::PoseTruth {
                pose: (i + 1) as u16,
                x_mm: c.x_mm,
                y_mm: c.y_mm,
                z_mm: c.z_mm,
                a_deg: c.a_deg,
                c_deg: c.c_deg,
                motion_start_s: p.motion_start_s,
                exact_stop_s: p.exact_stop_s,
                dwell_end_s: p.dwell_end_s,
                eval_s,
                target_index: v.target_index + 1,
                direction: v.direction,
                deviation_um: dev,
                deviation_rate_um_per_s: rate,
                capball_e_um: self.capball_truth.error_um(&c, t),
                psd_x_um: px,
                psd_y_um: py,
                material_c: mat.iter().sum::<f64>() / mat.len().max(1) as f64,
                air_c,
            });
        }
        out
    }
}

fn nearest_target(m: &AxisModel, x_mm: f64) -> usize {
    let mut best = 0;
    for (i, t) in m.targets_mm.iter().enumerate() {
        if (t - x_mm).abs() < (m.targets_mm[best] - x_mm).abs() {
            best = i;
        }
    }
    best
}

/// One random draw per visit of a pose: the axis model's repeatability belongs to the
/// positioning of the machine, so it is constant over a dwell, not white from sample to sample.
fn draw_visits(s: &Scenario, rng: &mut ChaCha8Rng) -> Vec<AxisVisit> {
    let m = &s.axis;
    let mut prev_x = s.program.home.x_mm;
    let mut prev_dir = Direction::Up;
    let mut out = Vec::with_capacity(s.program.poses.len());
    for r in &s.program.poses {
        let dir = if r.x_mm > prev_x + 1e-9 {
            Direction::Up
        } else if r.x_mm < prev_x - 1e-9 {
            Direction::Down
        } else {
            prev_dir
        };
        let idx = nearest_target(m, r.x_mm);
        let std = m.noise_std_um(idx);
        let mut random_um = if std > 0.0 {
            Normal::new(0.0, std).map(|n| n.sample(rng)).unwrap_or(0.0)
        } else {
            0.0
        };
        if let Some((rate, mag)) = m.outliers()
            && rng.random_bool(rate.clamp(0.0, 1.0))
        {
            random_um += if rng.random_bool(0.5) { mag } else { -mag };
        }
        out.push(AxisVisit {
            target_index: idx,
            direction: dir,
            random_um,
        });
        prev_x = r.x_mm;
        prev_dir = dir;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn volts_inverse_of_polynomial() {
        let p = [10.0, 0.02, -0.001];
        for v in [-9.0, -1.0, 0.0, 0.3, 7.5] {
            let d = p[0] * v + p[1] * v * v + p[2] * v * v * v;
            assert!((volts_for_um(&p, d) - v).abs() < 1e-12);
        }
    }

    #[test]
    fn host_transform_inverts_sensor_geometry() {
        let c = Capball::default();
        let t = capball_host_transform(&c);
        let e = [3.0, -7.0, 11.0];
        let n = normalised_directions(&c);
        let d = mul(&n, e);
        let d = [
            d[0] + c.zero_offset_um[0],
            d[1] + c.zero_offset_um[1],
            d[2] + c.zero_offset_um[2],
        ];
        for i in 0..3 {
            let v = t[i][0] * d[0] + t[i][1] * d[1] + t[i][2] * d[2] + t[i][3];
            assert!((v - e[i]).abs() < 1e-9, "{i}: {v} vs {}", e[i]);
        }
    }

    #[test]
    fn link_errors_vanish_at_zero_rotation_without_setup() {
        let l = LinkErrors {
            setup_offset_um: [0.0; 3],
            drift_um_per_h: [0.0; 3],
            c_tilt_urad: [0.0; 2],
            ..LinkErrors::default()
        };
        let e = l.error_um(&Coords::default(), 0.0);
        assert!(e.iter().all(|v| v.abs() < 1e-12));
        // C by 180°: (I − R)·δC = 2·δC.
        let e = l.error_um(
            &Coords {
                c_deg: 180.0,
                ..Coords::default()
            },
            0.0,
        );
        assert!((e[0] - 2.0 * l.c_offset_um[0]).abs() < 1e-9);
        assert!((e[1] - 2.0 * l.c_offset_um[1]).abs() < 1e-9);
    }
}
