//! The simulated machine: where it is at a given instant, what each instrument truly sees
//! there, and the program's schedule. Everything here is a pure function of true time, so a
//! sample's value depends only on the instant its device clock stamps, never on when the
//! device task happened to run.

use positioning::axis_model::{AxisModel, Direction};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::scenario::{Axis, Capball, CapballModel, Coords, Program, Psd, Scenario};
use geometry::capball::CapballSetup;
use geometry::kinematics::Pose;

impl Scenario {
    /// The host-side CapBall transform `T` (4×4, `v = T·[d; 1]`) that inverts this scenario's
    /// sensor geometry exactly: what the cube calibration would find.
    pub fn capball_transform(&self) -> [[f64; 4]; 4] {
        capball_host_transform(&self.capball)
    }

    /// Real seconds from the program start to the program-end frame.
    pub fn program_duration_s(&self) -> f64 {
        Schedule::new(&self.program).end_s
    }
}

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
    /// Trim of the loaded compensation table ([`Scenario::axis_comp`]) at this visit, relative
    /// to the trim at home where the interferometer's datum is taken, µm (0 without a table).
    pub comp_um: f64,
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

/// The machine of metrology's CapBall model ([`CapballSetup::paper_default`]), built once.
pub fn capball_setup() -> &'static CapballSetup {
    static SETUP: std::sync::OnceLock<CapballSetup> = std::sync::OnceLock::new();
    SETUP.get_or_init(CapballSetup::paper_default)
}

/// The sim's axis positions as a pose of metrology's kinematics: the same machine axis values
/// (ISO 841: tool relative to workpiece), mm and degrees; the machine has no B axis.
pub fn metrology_pose(c: &Coords) -> Pose {
    Pose::new(c.x_mm, c.y_mm, c.z_mm, c.a_deg, c.c_deg)
}

/// metrology's forward chain at the sim's axis positions, ball under the tool, µm.
fn chain_error_um(errors: &geometry::capball::CapballErrors, pose: &Coords) -> [f64; 3] {
    let e = capball_setup()
        .machine
        .volumetric_error_um(&metrology_pose(pose), errors, None);
    [e.x, e.y, e.z]
}

impl CapballModel {
    /// The effects beyond the 14 parameters (`docs/datasets.md`, CapBall effects): drift of the
    /// measuring loop (linear and cyclic, by time), axis harmonics (by angle), then the gain
    /// of the reading. The per-visit scatter is the device's (it needs the visit).
    fn add_drift(&self, e: [f64; 3], pose: &Coords, t_s: f64) -> [f64; 3] {
        let h = t_s / 3600.0;
        let mut out = [0, 1, 2].map(|k| e[k] + self.drift_um_per_h[k] * h);
        if let Some(c) = &self.cyclic_drift {
            for (o, d) in out.iter_mut().zip(c.at_um(t_s)) {
                *o += d;
            }
        }
        let p = metrology_pose(pose);
        for a in &self.axis_errors {
            let d = a.error_um(&p);
            for (o, dk) in out.iter_mut().zip(d) {
                *o += dk;
            }
        }
        [0, 1, 2].map(|k| out[k] * (1.0 + self.gain_pct[k] / 100.0))
    }
}

impl CapballTruth for CapballModel {
    /// metrology's exact forward model ([`geometry::capball::forward_um`]: the rigid-body
    /// chain of [`CapballSetup::paper_default`] with these link and setup errors), plus drift.
    ///
    /// `forward_um` evaluates `p_tool − p_ball` for the ball at its nominal place; here the
    /// ball is the table point nominally under the tool, which is the same point at every pose
    /// that holds the tool on the ball (the CapBall poses, where the two agree to 1e-9 µm, see
    /// the tests). Elsewhere (the ISO 230-2 and PSD segments) the CapBall reads the machine's
    /// volumetric error as if a ball sat under the tool instead of going over range: the
    /// simulator's convention that every instrument streams valid values all program long.
    fn error_um(&self, pose: &Coords, t_s: f64) -> [f64; 3] {
        self.add_drift(chain_error_um(&self.errors(), pose), pose, t_s)
    }
}

/// [`CapballModel`] with its forward chain memoised per pose: the chain costs ~0.2 ms per
/// evaluation in debug builds, too slow for a 20 kHz stream, while the CapBall stands still
/// (or moves between two poses, see [`World::capball_error_um`]) almost all the time. Same
/// values as the model (the drift is added per call).
pub struct CachedCapballModel {
    model: CapballModel,
    errors: geometry::capball::CapballErrors,
    /// The last few (pose, chain error) pairs; a move needs its two end poses.
    cache: std::sync::Mutex<Vec<([f64; 5], [f64; 3])>>,
}

impl CachedCapballModel {
    const ENTRIES: usize = 4;

    pub fn new(model: CapballModel) -> Self {
        CachedCapballModel {
            errors: model.errors(),
            model,
            cache: std::sync::Mutex::new(Vec::with_capacity(Self::ENTRIES)),
        }
    }
}

impl CapballTruth for CachedCapballModel {
    fn error_um(&self, pose: &Coords, t_s: f64) -> [f64; 3] {
        let key = [pose.x_mm, pose.y_mm, pose.z_mm, pose.a_deg, pose.c_deg];
        let hit = self
            .cache
            .lock()
            .ok()
            .and_then(|c| c.iter().find(|(k, _)| *k == key).map(|(_, e)| *e));
        let e = match hit {
            Some(e) => e,
            None => {
                let e = chain_error_um(&self.errors, pose);
                if let Ok(mut c) = self.cache.lock() {
                    if c.len() >= Self::ENTRIES {
                        c.remove(0);
                    }
                    c.push((key, e));
                }
                e
            }
        };
        self.model.add_drift(e, pose, t_s)
    }
}

type M3 = [[f64; 3]; 3];

fn mul(m: &M3, v: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
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
    /// The thermal machine integrated over the program (machine time), when the scenario has one.
    pub thermal: Option<crate::thermal::ThermalTrack>,
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
        // Integrated a little past the program end (the devices stream on after it).
        let end_s = (schedule.end_s + 60.0) * scenario.time_scale;
        let thermal = scenario
            .thermal
            .clone()
            .map(|m| crate::thermal::ThermalTrack::new(m, end_s));
        World {
            scenario,
            schedule,
            visits,
            capball_truth,
            thermal,
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
                let k = s_curve(frac);
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

    /// The CapBall's true volumetric error at a phase, µm: the truth model at the pose, and
    /// during a move the two end poses' errors blended along the motion profile. Nothing is
    /// measured during a move (the host drops those samples); the blend keeps the stream
    /// moving smoothly at two model evaluations per move instead of one per sample.
    pub fn capball_error_um(&self, ph: Phase, t_s: f64) -> [f64; 3] {
        let d = self.thermal_um(t_s);
        let e = match ph {
            Phase::Moving { to, frac } => {
                let a = self.capball_truth.error_um(&self.previous(to), t_s);
                let b = self.capball_truth.error_um(&self.pose(to), t_s);
                let k = s_curve(frac);
                [0, 1, 2].map(|i| a[i] + (b[i] - a[i]) * k)
            }
            _ => self.capball_truth.error_um(&self.coords(ph), t_s),
        };
        [0, 1, 2].map(|k| e[k] + d[k])
    }

    /// The thermal machine's displacement of the tool against the workpiece at scaled time
    /// `t_s`, machine frame, µm (zero without `[thermal]`).
    pub fn thermal_um(&self, t_s: f64) -> [f64; 3] {
        self.thermal
            .as_ref()
            .map_or([0.0; 3], |t| t.displacement_um(t_s))
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
            + v.comp_um
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
            let pose = self.scenario.program.poses[i].number(i);
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
            let d = self.thermal_um(t);
            let (px, py) = (px + d[0], py + d[1]);
            let e = self.capball_truth.error_um(&c, t);
            out.push(crate::record::PoseTruth {
                pose: self.scenario.program.poses[i].number(i),
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
                capball_e_um: [0, 1, 2].map(|k| e[k] + d[k]),
                psd_x_um: px,
                psd_y_um: py,
                material_c: mat.iter().sum::<f64>() / mat.len().max(1) as f64,
                air_c,
            });
        }
        out
    }
}

/// Fraction of a move done at `frac` of its time: the smooth S-shaped profile of every axis.
fn s_curve(frac: f64) -> f64 {
    0.5 - 0.5 * (std::f64::consts::PI * frac.clamp(0.0, 1.0)).cos()
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

/// The trim the control of the X axis adds at commanded `x_mm` reached moving `dir`, less the
/// trim at home (the interferometer's datum; homing ends moving up), µm: the joint goes to
/// `pos-cmd + trim` (`crate::axis_comp`), so the reflector moves by the trim.
fn comp_um(s: &Scenario, x_mm: f64, dir: Direction) -> f64 {
    s.axis_comp.as_ref().map_or(0.0, |c| {
        c.trim_um(x_mm, dir) - c.trim_um(s.program.home.x_mm, Direction::Up)
    })
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
            comp_um: comp_um(s, r.x_mm, dir),
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

    fn zero_model() -> CapballModel {
        CapballModel::from_errors(&Default::default())
    }

    #[test]
    fn setup_errors_move_with_their_frames() {
        // Tool offset alone: the spindle does not turn, e = tool offset at any pose.
        let mut m = zero_model();
        m.setup.tool_x_um = 5.0;
        let p = Coords {
            a_deg: -30.0,
            c_deg: 70.0,
            ..Coords::default()
        };
        let e = m.error_um(&p, 0.0);
        assert!(
            (e[0] - 5.0).abs() < 1e-9 && e[1].abs() < 1e-9 && e[2].abs() < 1e-9,
            "{e:?}"
        );
        // Ball offset +3 µm along table X; C = 90° turns the table by −90° about Z (ISO 841:
        // C moves the tool relative to the table), so the ball sits at (0, −3, 0) µm and
        // e = p_tool − p_ball = (0, +3, 0).
        let mut m = zero_model();
        m.setup.ball_x_um = 3.0;
        let p = Coords {
            c_deg: 90.0,
            ..Coords::default()
        };
        let e = m.error_um(&p, 0.0);
        assert!(
            e[0].abs() < 1e-9 && (e[1] - 3.0).abs() < 1e-9 && e[2].abs() < 1e-9,
            "{e:?}"
        );
    }

    #[test]
    fn squareness_scales_with_the_lever_arm() {
        // EB0Z: the Z direction tilted about Y by θ; at z = 100 mm the tool moves by
        // θ × (0, 0, 100 mm) = (100 mm · θ, 0, 0) = 2 µm for θ = 20 µrad.
        let mut m = CapballModel {
            drift_um_per_h: [0.0, 0.0, 1.0],
            ..zero_model()
        };
        m.link.eb0z_urad = 20.0;
        let p = Coords {
            z_mm: 100.0,
            ..Coords::default()
        };
        let e = m.error_um(&p, 1800.0);
        assert!((e[0] - 2.0).abs() < 1e-6 && e[1].abs() < 1e-9, "{e:?}");
        assert!((e[2] - 0.5).abs() < 1e-9, "drift of half an hour: {e:?}");
    }

    #[test]
    fn capball_effects_beyond_the_14_parameters() {
        use geometry::capball_effects::{AxisHarmonic, CyclicDrift, RotaryAxis};
        let p = Coords {
            a_deg: -30.0,
            c_deg: 90.0,
            ..Coords::default()
        };
        // A cooling cycle of 1500 s, 1/1/3 µm half peak-to-valley: at a quarter period the
        // sine peaks; at a full period it is back to zero.
        let m = CapballModel {
            cyclic_drift: Some(CyclicDrift {
                period_s: 1500.0,
                amplitude_um: [1.0, 1.0, 3.0],
                phase_rad: [0.0; 3],
            }),
            ..zero_model()
        };
        let e = m.error_um(&p, 375.0);
        assert!(
            (e[0] - 1.0).abs() < 1e-9 && (e[2] - 3.0).abs() < 1e-9,
            "{e:?}"
        );
        assert!(m.error_um(&p, 1500.0)[2].abs() < 1e-9);
        // Gain: +2 % on x scales the tool offset's x.
        let mut m = CapballModel {
            gain_pct: [2.0, 0.0, 0.0],
            ..zero_model()
        };
        m.setup.tool_x_um = 10.0;
        assert!((m.error_um(&p, 0.0)[0] - 10.2).abs() < 1e-9);
        // C harmonic 2, cos along the cradle's x (= machine x, A turns about x): at C = 90°
        // cos(180°) = −1.
        let m = CapballModel {
            axis_errors: vec![AxisHarmonic {
                axis: RotaryAxis::C,
                harmonic: 2,
                cos_um: [0.5, 0.0, 0.0],
                sin_um: [0.0; 3],
            }],
            ..zero_model()
        };
        let e = m.error_um(&p, 0.0);
        assert!((e[0] + 0.5).abs() < 1e-9 && e[1].abs() < 1e-9, "{e:?}");
    }

    #[test]
    fn cached_model_gives_the_model_values() {
        let m = CapballModel {
            drift_um_per_h: [1.0, -2.0, 0.5],
            ..CapballModel::default()
        };
        let cached = CachedCapballModel::new(m.clone());
        // More poses than cache entries, each asked twice at different times.
        for i in 0..7 {
            let p = Coords {
                x_mm: 10.0 * i as f64,
                a_deg: -5.0 * i as f64,
                c_deg: 40.0 * i as f64,
                ..Coords::default()
            };
            for t in [0.0, 900.0 * i as f64] {
                assert_eq!(cached.error_um(&p, t), m.error_um(&p, t));
            }
        }
    }
}
