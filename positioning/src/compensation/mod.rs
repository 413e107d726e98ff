//! Pitch-error (leadscrew) compensation tables from a positioning run, one writer per
//! controller dialect, and the prediction of the ISO 230-2 result after the table is loaded
//! (`docs/methods.md` "Pitch-error compensation"; each dialect's semantics and the manual
//! page it comes from are listed there and in the dialect's file).
//!
//! Every table is built from the same *error curve*: the measured mean deviation (actual −
//! nominal, µm) interpolated linearly at equally spaced table points aligned on the reference
//! point (the machine's home unless chosen), and re-referenced so that the error at the
//! reference point is zero (a controller takes its reference point as exact; a constant
//! cannot be compensated by a pitch table). Each dialect then encodes the error, or the
//! correction (−error), absolute or incremental, in its units, and quantises it as the
//! control stores it. [`CompensationTable`] keeps, beside the files, the *correction* the
//! control adds to the commanded position at each point as decoded from the file's own
//! numbers, and [`apply`] uses it the way the controls do (linear interpolation between
//! points, end values held outside).

mod fanuc;
mod heidenhain;
mod linuxcnc;
mod remeasure;
mod sinumerik;

pub use remeasure::{Remeasured, TargetBeforeAfter, remeasured};

use serde::{Deserialize, Serialize};

use crate::axis_model::Direction;
use crate::iso230::{AxisStats, evaluate};
use crate::positioning_data::PositioningData;

/// A controller's compensation dialect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Dialect {
    Sinumerik,
    Fanuc,
    Heidenhain,
    LinuxCnc,
}

impl std::str::FromStr for Dialect {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "sinumerik" | "siemens" => Ok(Dialect::Sinumerik),
            "fanuc" => Ok(Dialect::Fanuc),
            "heidenhain" => Ok(Dialect::Heidenhain),
            "linuxcnc" => Ok(Dialect::LinuxCnc),
            _ => Err(format!(
                "unknown dialect `{s}` (known: sinumerik, fanuc, heidenhain, linuxcnc)"
            )),
        }
    }
}

/// How the two directions of approach are compensated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Mode {
    /// One table from the mean bidirectional deviation x̄ = (x̄↑ + x̄↓)/2; no backlash value.
    Mean,
    /// One table from the positive-direction deviation x̄↑ plus a backlash value
    /// b = mean(x̄↓ − x̄↑) that the control adds on negative-direction moves.
    Backlash,
    /// One table per direction (x̄↑ and x̄↓), where the dialect has direction-dependent tables.
    Bidirectional,
}

/// What to build.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    pub dialect: Dialect,
    pub mode: Mode,
    /// Table point spacing, mm; default: the mean target spacing of the run.
    pub spacing_mm: Option<f64>,
    /// Reference (home) position, mm; default: the run's metadata `home_mm`, else 0 mm (the
    /// machine zero, where a machine referenced with its home at 0 sits).
    pub reference_mm: Option<f64>,
    /// The axis name as the control knows it (e.g. `X1`, `AX1`); default: the run's axis.
    pub axis_name: Option<String>,
    /// Axis number for dialects that address axes by number (Fanuc parameter axis, LinuxCNC
    /// joint), 1-based.
    pub axis_number: usize,
    /// FANUC: the largest compensation value one point may hold, in detection units × the
    /// magnification (the control model's limit); default [`FANUC_POINT_LIMIT`].
    pub point_limit: Option<u32>,
}

/// FANUC's per-point limit when none is given: ±127 (parameter data range of Series 0i/16i/
/// 18i/30i pitch data; older controls allow ±7, give `point_limit` for them).
pub const FANUC_POINT_LIMIT: u32 = 127;

/// The most table points any dialect is asked to hold (LinuxCNC takes 256, FANUC and SINUMERIK
/// a few hundred to a few thousand): past it the spacing is a mistake, refused before a table
/// of that size is allocated (a spacing of 1e-9 mm asked for 1.6 TB).
pub const MAX_TABLE_POINTS: f64 = 10_000.0;

/// A finite reference near the machine and a table of at most [`MAX_TABLE_POINTS`].
fn check_table_size(
    lo: f64,
    hi: f64,
    reference: f64,
    spacing: f64,
) -> Result<(), CompensationError> {
    if !(reference.is_finite() && reference.abs() <= 1e6) {
        return Err(CompensationError::BadReference(reference));
    }
    let span_mm = hi.max(reference) - lo.min(reference);
    let points = (span_mm / spacing).ceil() + 1.0;
    if !(points.is_finite() && points <= MAX_TABLE_POINTS) {
        return Err(CompensationError::TooManyPoints {
            spacing_mm: spacing,
            span_mm,
            points,
            min_spacing_mm: span_mm / (MAX_TABLE_POINTS - 1.0),
        });
    }
    Ok(())
}

/// Why no table could be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CompensationError {
    #[error(
        "the run has no mean deviation in the {0} direction at two targets or more: measure the axis bidirectionally (ISO 230-2 cycle) first"
    )]
    NotEnoughData(&'static str),
    #[error("spacing must be a positive number of mm (got {0})")]
    BadSpacing(f64),
    #[error(
        "the reference point must be a finite position within ±1 km of the machine zero, in mm (got {0})"
    )]
    BadReference(f64),
    #[error(
        "a spacing of {spacing_mm} mm over {span_mm} mm makes {points} table points; a controller's \
         table holds at most a few hundred to a few thousand: choose a spacing of at least {min_spacing_mm} mm"
    )]
    TooManyPoints {
        spacing_mm: f64,
        span_mm: f64,
        points: f64,
        min_spacing_mm: f64,
    },
    #[error("{dialect:?}: {message}")]
    Unsupported { dialect: Dialect, message: String },
    #[error("{dialect:?}: {message}")]
    Limit { dialect: Dialect, message: String },
    #[error("bad metadata `home_mm: {0}`: expected a number of mm")]
    BadHome(String),
    #[error(
        "axis name {name:?} ({source_of}) cannot go into a controller file: a controller axis name is letters followed by optional digits, at most {MAX_AXIS_NAME} characters (X, X1, AX1); set --axis-name"
    )]
    BadAxisName {
        name: String,
        source_of: &'static str,
    },
    #[error(
        "{dialect:?}: axis number {number} is out of range: give --axis-number 1 to {max}{why}"
    )]
    BadAxisNumber {
        dialect: Dialect,
        number: usize,
        max: usize,
        why: &'static str,
    },
    #[error(
        "{0} is not a finite number: the run holds a non-finite deviation or position; fix or remove that reading (no controller file is written with NaN or infinity)"
    )]
    NotFinite(&'static str),
}

/// The longest axis name written (SINUMERIK machine axis names such as `AX1`, `X1`; FANUC and
/// LinuxCNC do not write it into the file's syntax but into its name).
pub const MAX_AXIS_NAME: usize = 8;

/// The largest axis number: FANUC parameter axes (`N03620A<n>`) 1 to 32, the writer's limit.
pub const MAX_AXIS_NUMBER: usize = 32;

/// LinuxCNC 2.9's `EMCMOT_MAX_JOINTS` (`src/emc/motion/emcmotcfg.h`): joints 0 to 15.
pub const LINUXCNC_MAX_JOINTS: usize = 16;

/// A controller axis name: ASCII letters, then optional ASCII digits (X, X1, AX1), at most
/// [`MAX_AXIS_NAME`] characters. Anything else (a path, `]`, `=`, `;`, a space, a newline)
/// would change the syntax of the file it is written into or the file's name.
pub fn check_axis_name(name: &str, source_of: &'static str) -> Result<(), CompensationError> {
    let letters = name.bytes().take_while(u8::is_ascii_alphabetic).count();
    let ok = letters > 0
        && name.len() <= MAX_AXIS_NAME
        && name.bytes().skip(letters).all(|b| b.is_ascii_digit());
    if ok {
        Ok(())
    } else {
        Err(CompensationError::BadAxisName {
            name: name.to_string(),
            source_of,
        })
    }
}

/// The axis number the dialect can address: 0 is refused, not taken as 1.
fn check_axis_number(dialect: Dialect, number: usize) -> Result<(), CompensationError> {
    let (max, why) = match dialect {
        Dialect::LinuxCnc => (
            LINUXCNC_MAX_JOINTS,
            " (joint = axis number − 1; LinuxCNC 2.9 has joints 0 to 15)",
        ),
        _ => (MAX_AXIS_NUMBER, ""),
    };
    if (1..=max).contains(&number) {
        Ok(())
    } else {
        Err(CompensationError::BadAxisNumber {
            dialect,
            number,
            max,
            why,
        })
    }
}

/// A table as the control will apply it: the correction it adds to the commanded position
/// (µm, the negative of the error it removes) at each point, decoded from the file's own
/// numbers after the dialect's quantisation, and the backlash value, µm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompensationTable {
    pub dialect: Dialect,
    pub mode: Mode,
    pub reference_mm: f64,
    pub points_mm: Vec<f64>,
    /// Correction the control adds on positive-direction moves (all moves in `Mean`), µm.
    pub correction_up_um: Vec<f64>,
    /// Correction the control adds on negative-direction moves (`Bidirectional`), or the
    /// positive-direction correction less the backlash (`Backlash`), µm.
    pub correction_down_um: Vec<f64>,
    /// Backlash value written to the control, µm (`Backlash` mode).
    pub backlash_um: Option<f64>,
    /// The files to load: (suggested file name, text).
    pub files: Vec<(String, String)>,
    /// What the commissioning engineer must set or check on the control.
    pub notes: Vec<String>,
}

/// The error curve before the dialect's conventions.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Curve {
    pub axis: String,
    pub axis_number: usize,
    pub reference_mm: f64,
    pub spacing_mm: f64,
    pub points_mm: Vec<f64>,
    /// Index of the reference point in `points_mm`.
    pub reference_index: usize,
    pub up_um: Vec<f64>,
    pub down_um: Vec<f64>,
    pub backlash_um: Option<f64>,
    pub mode: Mode,
}

impl Curve {
    /// Every number a writer puts into a file is finite: the guard each writer calls first.
    pub(crate) fn check_finite(&self) -> Result<(), CompensationError> {
        let all = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !(self.reference_mm.is_finite() && self.spacing_mm.is_finite()) {
            return Err(CompensationError::NotFinite(
                "the reference point or spacing",
            ));
        }
        if !all(&self.points_mm) {
            return Err(CompensationError::NotFinite("a table point"));
        }
        if !(all(&self.up_um) && all(&self.down_um)) {
            return Err(CompensationError::NotFinite("a compensation value"));
        }
        if self.backlash_um.is_some_and(|b| !b.is_finite()) {
            return Err(CompensationError::NotFinite("the backlash"));
        }
        Ok(())
    }
}

/// Linear interpolation in a sorted table, holding the end values outside it.
pub fn interpolate(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    match xs.iter().position(|&p| p > x) {
        None => *ys.last().unwrap_or(&0.0),
        Some(0) => ys[0],
        Some(i) => {
            let (x0, x1, y0, y1) = (xs[i - 1], xs[i], ys[i - 1], ys[i]);
            y0 + (y1 - y0) * (x - x0) / (x1 - x0)
        }
    }
}

/// Per-target means (position, x̄↑, x̄↓) sorted by position, targets lacking one direction
/// left out of that direction's curve.
fn means(data: &PositioningData) -> [(Vec<f64>, Vec<f64>); 2] {
    let r = evaluate(data);
    let mut t: Vec<_> = r.targets.iter().collect();
    t.sort_by(|a, b| a.target_mm.total_cmp(&b.target_mm));
    let curve = |f: &dyn Fn(&crate::iso230::TargetStats) -> Option<f64>| {
        t.iter()
            .filter_map(|x| f(x).map(|v| (x.target_mm, v)))
            .unzip::<f64, f64, Vec<f64>, Vec<f64>>()
    };
    [curve(&|x| x.mean_up_um), curve(&|x| x.mean_down_um)]
}

/// The machine's home, mm: metadata `home_mm`, else 0 (machine zero).
fn home_mm(data: &PositioningData) -> Result<f64, CompensationError> {
    match data.metadata.get("home_mm") {
        None => Ok(0.0),
        Some(v) => v
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| CompensationError::BadHome(v.clone())),
    }
}

pub(crate) fn curve(data: &PositioningData, o: &Options) -> Result<Curve, CompensationError> {
    let [(xu, yu), (xd, yd)] = means(data);
    if xu.len() < 2 {
        return Err(CompensationError::NotEnoughData("positive"));
    }
    if xd.len() < 2 {
        return Err(CompensationError::NotEnoughData("negative"));
    }
    let (lo, hi) = (xu[0].min(xd[0]), xu[xu.len() - 1].max(xd[xd.len() - 1]));
    let spacing = o
        .spacing_mm
        .unwrap_or((hi - lo) / (data.n_targets().max(2) - 1) as f64);
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(CompensationError::BadSpacing(spacing));
    }
    let reference = match o.reference_mm {
        Some(r) => r,
        None => home_mm(data)?,
    };
    check_table_size(lo, hi, reference, spacing)?;
    // Points aligned on the reference, covering the travel and the reference.
    let k0 = ((lo.min(reference) - reference) / spacing + 1e-9).floor() as i64;
    let k1 = ((hi.max(reference) - reference) / spacing - 1e-9).ceil() as i64;
    let points_mm: Vec<f64> = (k0..=k1).map(|k| reference + k as f64 * spacing).collect();
    let reference_index = (-k0) as usize;
    let at = |xs: &[f64], ys: &[f64]| -> Vec<f64> {
        points_mm.iter().map(|&p| interpolate(xs, ys, p)).collect()
    };
    let (up, down) = (at(&xu, &yu), at(&xd, &yd));
    let (mut up_um, mut down_um, backlash_um) = match o.mode {
        Mode::Mean => {
            let m: Vec<f64> = up.iter().zip(&down).map(|(a, b)| 0.5 * (a + b)).collect();
            (m.clone(), m, None)
        }
        Mode::Backlash => {
            let b = down.iter().zip(&up).map(|(d, u)| d - u).sum::<f64>() / up.len() as f64;
            let d: Vec<f64> = up.iter().map(|u| u + b).collect();
            (up, d, Some(b))
        }
        Mode::Bidirectional => (up, down, None),
    };
    let e0 = up_um[reference_index];
    for v in up_um.iter_mut().chain(down_um.iter_mut()) {
        *v -= e0;
    }
    let axis = match (&o.axis_name, &data.axis) {
        (Some(a), _) => (a.clone(), "--axis-name"),
        (None, Some(a)) => (a.clone(), "the run's axis, `# axis:` or the log's metadata"),
        (None, None) => ("X".to_string(), "default"),
    };
    check_axis_name(&axis.0, axis.1)?;
    check_axis_number(o.dialect, o.axis_number)?;
    Ok(Curve {
        axis: axis.0,
        axis_number: o.axis_number,
        reference_mm: reference,
        spacing_mm: spacing,
        points_mm,
        reference_index,
        up_um,
        down_um,
        backlash_um,
        mode: o.mode,
    })
}

/// Builds the table for a run in the chosen dialect.
pub fn build(data: &PositioningData, o: &Options) -> Result<CompensationTable, CompensationError> {
    let mut o = o.clone();
    if o.dialect == Dialect::Sinumerik && o.axis_name.is_none() {
        // LEC tables address the machine axis (K3 §4.4.2.3's example: `X1`).
        let a = data.axis.clone().unwrap_or_else(|| "X".into());
        check_axis_name(&a, "the run's axis, `# axis:` or the log's metadata")?;
        o.axis_name = Some(format!("{a}1"));
    }
    if o.dialect == Dialect::Fanuc {
        let c = curve(data, &o)?;
        o.spacing_mm = Some(fanuc::spacing_mm(c.spacing_mm));
    }
    let c = curve(data, &o)?;
    let mut t = match o.dialect {
        Dialect::Sinumerik => sinumerik::write(&c),
        Dialect::Fanuc => fanuc::write(&c, o.point_limit.unwrap_or(FANUC_POINT_LIMIT)),
        Dialect::Heidenhain => heidenhain::write(&c),
        Dialect::LinuxCnc => linuxcnc::write(&c),
    }?;
    if o.mode == Mode::Mean
        && let Some(b) = evaluate(data).axis.b
    {
        t.notes.push(format!(
            "a Mean table leaves the reversal error: B = {b:.2} µm stays after loading it (the table corrects the mean of both directions, each direction keeps half the backlash); use --backlash or --bidirectional (LinuxCNC, HEIDENHAIN) to remove it"
        ));
    }
    let [(xu, _), _] = means(data);
    if let (Some(lo), Some(hi)) = (xu.first(), xu.last())
        && !(*lo..=*hi).contains(&c.reference_mm)
    {
        t.notes.push(format!(
            "the reference point {:.4} mm lies outside the measured targets ({lo:.4} … {hi:.4} mm): the table holds the nearest measured error up to it; measure from the home position, or set --reference-point",
            c.reference_mm
        ));
    }
    Ok(t)
}

/// The run as it would read with the table loaded: each reading plus the correction the
/// control adds at its target for its direction of approach (interpolated linearly between
/// table points, end values held, as the controls do). The correction moves the axis, so the
/// deviation it leaves is the measured one plus the correction (the error's own slope over
/// a correction of a few µm is neglected).
pub fn apply(data: &PositioningData, t: &CompensationTable) -> PositioningData {
    let mut out = data.clone();
    for r in &mut out.readings {
        let ys = match r.direction {
            Direction::Up => &t.correction_up_um,
            Direction::Down => &t.correction_down_um,
        };
        r.deviation_um += interpolate(&t.points_mm, ys, r.target_mm);
    }
    out.metadata
        .insert("compensation".into(), format!("predicted, {:?}", t.dialect));
    out
}

/// ISO 230-2 before and predicted after compensation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verification {
    pub before: AxisStats,
    pub after: AxisStats,
}

pub fn verify(data: &PositioningData, t: &CompensationTable) -> Verification {
    Verification {
        before: evaluate(data).axis,
        after: evaluate(&apply(data, t)).axis,
    }
}
