//! Planning an ISO 230-2 positioning test of one linear axis (`docs/methods.md` "Planning a
//! positioning test"): the targets with a random offset per target, the bidirectional
//! cycle with overrun for the reversal, and the part program that drives the machine
//! through it in a controller's dialect, with the exact-stop trigger the daemon listens to
//! (`docs/instruments.md` §4). The trajectory CSV is the daemon's pose table
//! (`pose,x_mm,y_mm,z_mm`); its row numbers are the pose indices the trigger carries.

mod programs;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::axis_model::Direction;
pub use crate::compensation::Dialect;

/// What to plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanOptions {
    /// Axis letter: X, Y or Z.
    pub axis: char,
    pub from_mm: f64,
    pub to_mm: f64,
    /// Number of targets m (ISO 230-2: at least 5 per metre, at least 5).
    pub targets: usize,
    /// Number of bidirectional cycles n (ISO 230-2: 5).
    pub cycles: usize,
    /// Why the plan may fall below ISO 230-2's minimums (targets, cycles); printed in the
    /// program header. `None`: the minimums are enforced.
    pub below_iso_minimum: Option<String>,
    /// Seed of the random offsets.
    pub seed: u64,
    /// Largest random offset |r|, mm; default a tenth of the interval.
    pub max_offset_mm: Option<f64>,
    /// Travel past the end targets before each reversal, mm; the targets lie this far inside
    /// `from_mm`…`to_mm`, so that every move stays inside the given travel.
    pub overrun_mm: f64,
    /// Dwell at each target, s.
    pub dwell_s: f64,
    /// Feed, mm/min.
    pub feed_mm_min: f64,
    /// The M-function that pulses the exact-stop trigger (the PLC sends the CAN frame with
    /// the pose index it finds in the program's parameter [`POSE_PARAMETER`]).
    pub trigger_m: u32,
}

impl Default for PlanOptions {
    fn default() -> Self {
        PlanOptions {
            axis: 'X',
            from_mm: 0.0,
            to_mm: 500.0,
            targets: 11,
            cycles: 5,
            below_iso_minimum: None,
            seed: 1,
            max_offset_mm: None,
            overrun_mm: 5.0,
            dwell_s: 2.0,
            feed_mm_min: 1000.0,
            trigger_m: 101,
        }
    }
}

/// The program parameter (R/#/Q number) that carries the pose index for the trigger.
pub const POSE_PARAMETER: u32 = 100;

/// The largest machine coordinate a plan takes, mm (100 m: past the travel of any machine
/// tool; a larger number is a typing error and would overflow the programmed positions).
pub const MAX_COORDINATE_MM: f64 = 100_000.0;

/// The most measured stops a plan may have: the positioning reader's limit (`MAX_READINGS`),
/// so every planned run can be analysed; `--cycles 1000000` wrote an 894 MB trajectory.
pub const MAX_STOPS: usize = crate::positioning_data::MAX_READINGS;

/// The longest dwell, s (an hour), and the fastest feed, mm/min (1 000 m/min).
pub const MAX_DWELL_S: f64 = 3_600.0;
pub const MAX_FEED_MM_MIN: f64 = 1_000_000.0;

/// Why no plan could be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PlanError {
    #[error("{0}")]
    Bad(String),
}

/// One programmed stop.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Row of the trajectory, from 1.
    pub pose: usize,
    pub position_mm: f64,
    /// `Some((cycle, direction, target index))` for a measured stop, `None` for a reversal.
    pub target: Option<(usize, Direction, usize)>,
}

/// A planned test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub options: PlanOptions,
    /// The targets P_i, mm.
    pub targets_mm: Vec<f64>,
    pub poses: Vec<Pose>,
}

/// ISO 230-2's minimums for a measured length: targets (5 per metre and at least 5) and
/// bidirectional cycles (5).
pub fn iso_minimums(length_mm: f64) -> (usize, usize) {
    let per_metre = (5.0 * length_mm / 1000.0 - 1e-9).ceil().max(0.0) as usize;
    (per_metre.max(5), 5)
}

/// The first and last nominal target: the travel less the overrun at each end.
fn span(o: &PlanOptions) -> (f64, f64) {
    (o.from_mm + o.overrun_mm, o.to_mm - o.overrun_mm)
}

/// What falls below ISO 230-2's minimums, in words; empty when nothing does.
pub fn below_minimums(o: &PlanOptions) -> Vec<String> {
    let (lo, hi) = span(o);
    let (m, n) = iso_minimums(hi - lo);
    let mut out = vec![];
    if o.targets < m {
        out.push(format!(
            "{} targets over {:.0} mm (ISO 230-2: at least 5 per metre and 5 in all, here {m})",
            o.targets,
            hi - lo
        ));
    }
    if o.cycles < n {
        out.push(format!("{} cycles (ISO 230-2: {n})", o.cycles));
    }
    out
}

fn check(o: &PlanOptions) -> Result<(), PlanError> {
    let bad = |m: &str| Err(PlanError::Bad(m.to_string()));
    if !"XYZ".contains(o.axis) {
        return bad("--axis must be X, Y or Z");
    }
    let coordinate = |x: f64| x.is_finite() && x.abs() <= MAX_COORDINATE_MM;
    if !(coordinate(o.from_mm) && coordinate(o.to_mm)) {
        return Err(PlanError::Bad(format!(
            "--from {:?} and --to {:?} must be positions within ±{MAX_COORDINATE_MM} mm",
            o.from_mm, o.to_mm
        )));
    }
    if o.to_mm <= o.from_mm {
        return bad("--to must be greater than --from");
    }
    if o.targets < 2 || o.cycles < 1 {
        return bad("a test needs at least 2 targets and 1 cycle (ISO 230-2: 5 targets, 5 cycles)");
    }
    if o.targets.saturating_mul(o.cycles).saturating_mul(2) > MAX_STOPS {
        return Err(PlanError::Bad(format!(
            "{} targets × {} cycles × 2 directions is more than {MAX_STOPS} measured stops; \
             plan fewer cycles or targets (ISO 230-2: 5 cycles)",
            o.targets, o.cycles
        )));
    }
    if !((0.0..=MAX_DWELL_S).contains(&o.dwell_s)
        && o.overrun_mm >= 0.0
        && o.feed_mm_min > 0.0
        && o.feed_mm_min <= MAX_FEED_MM_MIN)
    {
        return Err(PlanError::Bad(format!(
            "--overrun must not be negative, --dwell must be 0 to {MAX_DWELL_S} s and --feed \
             above 0 up to {MAX_FEED_MM_MIN} mm/min"
        )));
    }
    let (lo, hi) = span(o);
    if hi <= lo {
        return bad(
            "the overrun at both ends leaves no travel for the targets: --overrun must be below half of --to minus --from",
        );
    }
    let below = below_minimums(o);
    let reason = o.below_iso_minimum.as_deref().map(str::trim);
    if !below.is_empty() && reason.is_none_or(str::is_empty) {
        return Err(PlanError::Bad(format!(
            "{}: raise them, or give the reason with --below-iso-minimum \"REASON\" (it is printed in the program header)",
            below.join("; ")
        )));
    }
    let p = (hi - lo) / (o.targets - 1) as f64;
    if o.max_offset_mm
        .is_some_and(|r| !(0.0..p / 2.0).contains(&r))
    {
        return bad("the random offset must be below half the target interval");
    }
    Ok(())
}

/// Plans the test: P_i = from + overrun + (i − 1)p + r_i, r_i uniform in ±r_max (the first
/// target only upward, the last only downward); each cycle runs from P_1 − overrun (≥ from)
/// up through the targets to P_m + overrun (≤ to) and back down through them to
/// P_1 − overrun, so no move leaves the given travel.
pub fn plan(o: &PlanOptions) -> Result<Plan, PlanError> {
    check(o)?;
    let m = o.targets;
    let (first, last) = span(o);
    let p = (last - first) / (m - 1) as f64;
    let r_max = o.max_offset_mm.unwrap_or(0.1 * p);
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let targets_mm: Vec<f64> = (0..m)
        .map(|i| {
            let (lo, hi) = match i {
                0 => (0.0, r_max),
                _ if i == m - 1 => (-r_max, 0.0),
                _ => (-r_max, r_max),
            };
            let r = if hi > lo {
                rng.random_range(lo..=hi)
            } else {
                0.0
            };
            // Programmed to 1 µm: what the controller can be told.
            ((first + i as f64 * p + r) * 1e3).round() / 1e3
        })
        .collect();
    let mut poses = Vec::new();
    let mut push = |position_mm: f64, target| {
        poses.push(Pose {
            pose: poses.len() + 1,
            position_mm,
            target,
        })
    };
    // Inside the travel even after the targets' rounding to 1 µm.
    let (below, above) = (
        (targets_mm[0] - o.overrun_mm).max(o.from_mm),
        (targets_mm[m - 1] + o.overrun_mm).min(o.to_mm),
    );
    push(below, None);
    for c in 1..=o.cycles {
        for (i, &t) in targets_mm.iter().enumerate() {
            push(t, Some((c, Direction::Up, i + 1)));
        }
        push(above, None);
        for (i, &t) in targets_mm.iter().enumerate().rev() {
            push(t, Some((c, Direction::Down, i + 1)));
        }
        push(below, None);
    }
    Ok(Plan {
        options: o.clone(),
        targets_mm,
        poses,
    })
}

impl Plan {
    /// Machine positions (x, y, z mm) of each pose, in trajectory order: the rows of the
    /// daemon's trajectory (`docs/instruments.md` §4; written by `metrolog_log::trajectory`).
    pub fn positions_xyz_mm(&self) -> Vec<[f64; 3]> {
        let k = (self.options.axis as u8 - b'X') as usize;
        self.poses
            .iter()
            .map(|p| {
                let mut xyz = [0.0; 3];
                xyz[k] = p.position_mm;
                xyz
            })
            .collect()
    }

    /// The part program in a dialect.
    pub fn part_program(&self, d: Dialect) -> String {
        programs::program(self, d)
    }
}
