//! Monte Carlo of the 13 errors the PSD laser frame measures (paper 003 §5 and Table 4;
//! docs/methods.md, "PSD frame Monte Carlo"). Each trial
//!
//! 1. draws all 21 errors of the three-axis machine (18 motion errors as random cubics over
//!    the travel, 3 squarenesses) with the peak amplitudes of the budget file;
//! 2. computes the readings on the rigid-body machine ([`geometry::kinematics`]) with all 21, and
//!    again with the 13 measurable ones only: the derivation of the latter is the true value in
//!    the model's gauge (mean- and slope-free straightnesses and rolls, `psd_frame.md`);
//! 3. adds to the measured run and to a reference run (the machine in its reference state)
//!    independent normal noise with the position-dependent standard uncertainty of each
//!    reading ([`super::psd_budget`]), and subtracts the reference run;
//! 4. derives the errors and records derived − true.
//!
//! What remains is the reading noise (√2 from the reference subtraction) and the unmeasured
//! errors (pitch and yaw of X and Y, the three Z angles, EZZ) that alias into the measured
//! ones through the lever arms of the chain. The measured errors themselves cancel (the model
//! is exact for them to first order), which the tests check.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, StandardNormal};
use serde::Serialize;

use super::UncertaintyError;
use super::mc::{self, McOptions, McProgress, McResult, TrialSource};
use super::psd_budget::PsdBudget;
use geometry::kinematics::{AxisName, ErrorSource, Machine, SmallDisplacement};
use geometry::psd_frame::{PsdLayout, PsdReadings, derive_errors, readings_from_machine};

/// The 13 errors of Table 4, in the paper's order of rows.
pub const TABLE4_ERRORS: [&str; 13] = [
    "EYX", "EZX", "EXY", "EXZ", "EZY", "EYZ", "EXX", "EYY", "EAX", "EBY", "EA0Z", "EB0Z", "EC0Y",
];

/// Paper 003 Table 4: U (k = 2, 95 %), µm; the angles as "max. resulting linear uncertainty
/// with respect to the measurement volume".
pub const TABLE4_PUBLISHED_UM: [f64; 13] = [
    1.3, 1.6, 1.5, 1.5, 3.9, 3.4, 0.4, 0.4, 8.2, 6.4, 4.2, 4.9, 4.4,
];

/// One draw of the 21 errors: per axis (X, Y, Z) and component (δx, δy, δz, εx, εy, εz) the
/// coefficients of `A·(c1·t + c2·t² + c3·t³)/3`, `t ∈ [−1, 1]` over the travel; and the
/// squarenesses EC0Y, EB0Z, EA0Z (µrad).
#[derive(Debug, Clone, Default)]
struct ThermalDraw {
    coef: [[[f64; 3]; 6]; 3],
    amp: [[f64; 6]; 3],
    travel: [[f64; 2]; 3],
    squareness: [f64; 3],
    /// Keep only the 13 measurable errors.
    measured_only: bool,
}

/// Which motion-error components of X, Y, Z the frame measures (δx δy δz εx εy εz).
const MEASURED: [[bool; 6]; 3] = [
    [true, true, true, true, false, false], // EXX EYX EZX EAX; not EBX ECX
    [true, true, true, false, true, false], // EXY EYY EZY EBY; not EAY ECY
    [true, true, false, false, false, false], // EXZ EYZ; not EZZ EAZ EBZ ECZ
];

impl ThermalDraw {
    fn draw(b: &PsdBudget, layout: &PsdLayout, rng: &mut ChaCha8Rng) -> Self {
        let t = &b.thermal_errors;
        let mut d = ThermalDraw {
            travel: [
                [layout.x_lo, layout.x_hi],
                [layout.y_lo, layout.y_hi],
                [layout.z0, layout.z1],
            ],
            ..Default::default()
        };
        for axis in 0..3 {
            for comp in 0..6 {
                d.amp[axis][comp] = match (axis, comp) {
                    (2, 2) => t.ezz_um,
                    (a, c) if a == c => t.positioning_um,
                    (_, 0..=2) => t.straightness_um,
                    (0, 3) | (1, 4) => t.roll_urad,
                    _ => t.angular_urad,
                };
                for c in d.coef[axis][comp].iter_mut() {
                    *c = rng.random_range(-1.0..=1.0);
                }
            }
        }
        for s in d.squareness.iter_mut() {
            *s = t.squareness_urad * rng.random_range(-1.0..=1.0);
        }
        d
    }

    fn value(&self, axis: usize, comp: usize, q: f64) -> f64 {
        if self.measured_only && !MEASURED[axis][comp] {
            return 0.0;
        }
        let [lo, hi] = self.travel[axis];
        let t = 2.0 * (q - lo) / (hi - lo) - 1.0;
        let c = self.coef[axis][comp];
        self.amp[axis][comp] * (c[0] * t + c[1] * t * t + c[2] * t * t * t) / 3.0
    }
}

fn axis_index(a: AxisName) -> Option<usize> {
    match a {
        AxisName::X => Some(0),
        AxisName::Y => Some(1),
        AxisName::Z => Some(2),
        _ => None,
    }
}

impl ErrorSource for ThermalDraw {
    fn link(&self, a: AxisName) -> SmallDisplacement {
        // Squareness conventions of `kinematics` (tilts of the direction of travel):
        // Y about Z is EC0Y, Z about X and Y are EA0Z and EB0Z.
        let [c0y, b0z, a0z] = self.squareness;
        let rot = match a {
            AxisName::Y => Vector3::new(0.0, 0.0, c0y),
            AxisName::Z => Vector3::new(a0z, b0z, 0.0),
            _ => Vector3::zeros(),
        };
        SmallDisplacement {
            rot_urad: rot,
            trans_um: Vector3::zeros(),
        }
    }
    fn motion(&self, a: AxisName, q: f64) -> SmallDisplacement {
        let Some(i) = axis_index(a) else {
            return SmallDisplacement::ZERO;
        };
        let v = |c: usize| self.value(i, c, q);
        SmallDisplacement {
            trans_um: Vector3::new(v(0), v(1), v(2)),
            rot_urad: Vector3::new(v(3), v(4), v(5)),
        }
    }
}

/// The trial source: see the module documentation.
struct PsdMonteCarlo<'a> {
    layout: PsdLayout,
    budget: &'a PsdBudget,
    machine: Machine,
    reading_u: Vec<f64>,
    names: Vec<String>,
}

impl TrialSource for PsdMonteCarlo<'_> {
    type Scratch = Vec<f64>;
    fn n_outputs(&self) -> usize {
        self.names.len()
    }
    fn output_names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn scratch(&self) -> Vec<f64> {
        vec![0.0; self.reading_u.len()]
    }
    fn fill(&self, rng: &mut ChaCha8Rng, s: &mut Vec<f64>, out: &mut [f64]) {
        let n_out = self.names.len();
        for y in out.chunks_exact_mut(n_out) {
            let mut draw = ThermalDraw::draw(self.budget, &self.layout, rng);
            let all = readings_from_machine(&self.layout, &self.machine, &draw).to_vec();
            draw.measured_only = true;
            let measured = readings_from_machine(&self.layout, &self.machine, &draw).to_vec();
            // The derivation is linear: derive(all + noise − reference noise) − derive(measured)
            // is the derivation of the difference.
            for (k, v) in s.iter_mut().enumerate() {
                let n_run: f64 = StandardNormal.sample(rng);
                let n_ref: f64 = StandardNormal.sample(rng);
                *v = all[k] - measured[k] + self.reading_u[k] * (n_run - n_ref);
            }
            match derive_errors(&self.layout, &PsdReadings::from_vec(&self.layout, s)) {
                Ok(e) => {
                    let (v, t) = y.split_at_mut(n_out - 2);
                    v.copy_from_slice(&e.to_vec());
                    t[0] = travel_change(&e.exx_um);
                    t[1] = travel_change(&e.eyy_um);
                }
                // Cannot happen for a checked layout; NaN makes the run stop with a message.
                Err(_) => y.fill(f64::NAN),
            }
        }
    }
}

/// Change of a positioning error over the travel (last point minus first), µm.
fn travel_change(v: &[f64]) -> f64 {
    v.last().copied().unwrap_or(0.0) - v.first().copied().unwrap_or(0.0)
}

/// Extra outputs after [`geometry::psd_frame::PsdErrors::to_vec`]: the positioning changes over
/// the travel, which Table 4's EXX and EYY are compared with (docs/methods.md).
pub const TRAVEL_OUTPUTS: [&str; 2] = ["travel_EXX_um", "travel_EYY_um"];

/// One line of our Table 4: the largest expanded uncertainty over the points of one error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table4Row {
    /// Error name as in paper 003 (EXX, EYX, …, EC0Y).
    pub error: String,
    /// Largest half-width of the 95 % Monte Carlo intervals of derived − true over the error's
    /// points, in the error's own unit (µm, or µrad for rolls and squarenesses).
    pub expanded: f64,
    pub unit: &'static str,
    /// The same in µm: angles times `lever_mm` (paper 003 marks these "max. resulting linear
    /// uncertainty with respect to the measurement volume").
    pub expanded_um: f64,
    /// Paper 003 Table 4, µm.
    pub published_um: f64,
    /// EXX, EYY: `expanded` is the change over the travel (what the frame measures; the
    /// offset is a gauge choice); this is the largest value over the points.
    pub per_point_um: Option<f64>,
}

/// The study's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table4Study {
    pub rows: Vec<Table4Row>,
    pub lever_mm: f64,
    /// Largest and smallest standard uncertainty of one reading (one run), µm.
    pub reading_u_um: [f64; 2],
    pub monte_carlo: McResult,
}

/// Runs the Monte Carlo of the 13 errors with the reading budget and the thermal-error
/// amplitudes of `budget`; angles are also given as lengths over `lever_mm`.
pub fn table4(
    layout: &PsdLayout,
    budget: &PsdBudget,
    opts: &McOptions,
    lever_mm: f64,
    progress: Option<&(dyn Fn(&McProgress) + Sync)>,
) -> Result<Table4Study, UncertaintyError> {
    let reading_u = budget.reading_u_um(layout);
    table4_with_reading_u(layout, budget, reading_u, opts, lever_mm, progress)
}

/// [`table4`] with given standard uncertainties of the readings (in the order of
/// [`PsdReadings::to_vec`]), e.g. one σ for all as before the position-dependent budget.
pub fn table4_with_reading_u(
    layout: &PsdLayout,
    budget: &PsdBudget,
    reading_u: Vec<f64>,
    opts: &McOptions,
    lever_mm: f64,
    progress: Option<&(dyn Fn(&McProgress) + Sync)>,
) -> Result<Table4Study, UncertaintyError> {
    let n_in = 2 * (layout.n_s1 + 4 * layout.n_points);
    if reading_u.len() != n_in || reading_u.iter().any(|u| !(u.is_finite() && *u >= 0.0)) {
        return Err(UncertaintyError::Invalid(format!(
            "PSD Monte Carlo: need {n_in} finite reading uncertainties ≥ 0"
        )));
    }
    if !(lever_mm.is_finite() && lever_mm > 0.0) {
        return Err(UncertaintyError::Invalid(format!(
            "PSD Monte Carlo: the lever for angles must be > 0 mm, got {lever_mm}"
        )));
    }
    let zero = PsdReadings::from_vec(layout, &vec![0.0; n_in]);
    let mut names = derive_errors(layout, &zero)
        .map_err(|e| UncertaintyError::Invalid(format!("PSD measurement model: {e}")))?
        .names();
    names.extend(TRAVEL_OUTPUTS.iter().map(|s| s.to_string()));
    let mut machine = Machine::from_chain(&budget.thermal_errors.chain).map_err(|e| {
        UncertaintyError::Invalid(format!(
            "PSD budget: thermal_errors.chain `{}`: {e}",
            budget.thermal_errors.chain
        ))
    })?;
    machine.tool_offset_mm = Vector3::from(budget.thermal_errors.tool_offset_mm);
    let src = PsdMonteCarlo {
        layout: layout.clone(),
        budget,
        machine,
        reading_u: reading_u.clone(),
        names,
    };
    let r = mc::run(&src, opts, progress)?;
    let rows = TABLE4_ERRORS
        .iter()
        .zip(TABLE4_PUBLISHED_UM)
        .map(|(g, published_um)| {
            let half = |prefix: &str| {
                r.outputs
                    .iter()
                    .filter(|o| o.name.starts_with(prefix))
                    .map(|o| 0.5 * (o.symmetric_interval[1] - o.symmetric_interval[0]))
                    .fold(0.0, f64::max)
            };
            let per_point = half(&format!("{g}_"));
            let travel = half(&format!("travel_{g}_"));
            let positioning = *g == "EXX" || *g == "EYY";
            let u = if positioning { travel } else { per_point };
            let angle = g.starts_with("EA") || g.starts_with("EB") || g.starts_with("EC");
            Table4Row {
                error: g.to_string(),
                expanded: u,
                unit: if angle { "µrad" } else { "µm" },
                expanded_um: if angle { u * lever_mm * 1e-3 } else { u },
                published_um,
                per_point_um: positioning.then_some(per_point),
            }
        })
        .collect();
    let lo = reading_u.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = reading_u.iter().cloned().fold(0.0, f64::max);
    Ok(Table4Study {
        rows,
        lever_mm,
        reading_u_um: [hi, lo],
        monte_carlo: r,
    })
}
