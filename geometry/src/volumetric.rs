//! Volumetric error of a three-axis machine from its 21 component errors (paper 004, ISO 230-1
//! names), and compensation tables.
//!
//! - The 18 motion errors of the three linear axes (`EXX` positioning, `EYX`/`EZX` straightness,
//!   `EAX` roll, `EBX`/`ECX` pitch and yaw, and likewise for Y and Z) are functions of the axis
//!   position, given as tables (natural cubic spline through the points) or polynomials; the
//!   three squarenesses `EC0Y`, `EB0Z`, `EA0Z` (X is the reference axis) are constants.
//! - They are combined with exact rigid-body transforms along the chain
//!   ([`crate::kinematics::Machine`]); [`small_angle_error_um`] is the first-order form (paper 004
//!   eq. 1 with eq. 7 dropping every product of two errors). The terms it neglects are of order
//!   `|ε|²·L + |ε|·|δ|`: for ε = 100 µrad, L = 1 m and δ = 20 µm, 0.01 µm + 0.002 µm.
//! - Paper 004's eq. 8 multiplies each axis's rotation by that axis's own coordinate only (a skew
//!   coordinate system). A rigid-body chain instead gives each angular error the lever arm from
//!   its carriage to the tool point (Abbe offsets): for X carrying Z, the pitch `EBX` acts on the
//!   Z travel and the tool length, not on the X travel. We follow the rigid-body form; both agree
//!   for the positioning and straightness terms.
//!
//! Units: translations µm, rotations µrad, positions mm.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::kinematics::{
    AxisName, ErrorSource, Joint, Machine, Pose, SmallDisplacement, link_sensitivity,
    motion_sensitivity,
};

/// Errors of volumetric models and compensation tables.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum VolumetricError {
    /// row {row}: error name `{name}` is not an ISO 230-1 name of a linear-axis error (EXX … ECZ, EC0Y, EB0Z, EA0Z)
    #[error(
        "row {row}: error name `{name}` is not an ISO 230-1 name of a linear-axis error (EXX … ECZ, EC0Y, EB0Z, EA0Z)"
    )]
    BadName { row: usize, name: String },
    /// row {row}: {msg}
    #[error("row {row}: {msg}")]
    BadRow { row: usize, msg: String },
    /// error {name}: a table needs at least 2 points with distinct positions, got {n}
    #[error("error {name}: a table needs at least 2 points with distinct positions, got {n}")]
    ShortTable { name: String, n: usize },
    /// component errors CSV: {0}
    #[error("component errors CSV: {0}")]
    Csv(String),
    /// grid `{0}`: expected three ranges like `0:500:11,0:400:9,0:300:7` (min:max:count per axis)
    #[error(
        "grid `{0}`: expected three ranges like `0:500:11,0:400:9,0:300:7` (min:max:count per axis)"
    )]
    BadGrid(String),
    /// grid `{0}`: every min and max must be within ±100000 mm (a machine's travel)
    #[error("grid `{0}`: every min and max must be within ±100000 mm (a machine's travel)")]
    GridRange(String),
    /// the machine has no linear axis {0}: the volumetric model needs X, Y and Z
    #[error("the machine has no linear axis {0}: the volumetric model needs X, Y and Z")]
    MissingAxis(char),
    /// machine axis name {0:?} cannot go into a CEC file
    #[error(
        "machine axis name {0:?} cannot go into a CEC file: a SINUMERIK machine axis name is letters followed by optional digits, at most 8 characters (AX1, X1); set --axis-names"
    )]
    BadAxisName(String),
    /// {0} is not a finite number
    #[error(
        "{0} is not a finite number: no CEC file is written with NaN or infinity; check the component errors and the grid"
    )]
    NotFinite(&'static str),
}

/// The largest axis position (mm) a grid or an error table may hold: a machine's travel.
pub const MAX_POSITION_MM: f64 = 100_000.0;

/// The largest component error value (µm or µrad) a table may hold.
pub const MAX_ERROR_VALUE: f64 = 1_000_000.0;

/// A smooth function of an axis position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ErrorCurve {
    /// Natural cubic spline through (position, value); beyond the ends the end value holds.
    Table {
        positions_mm: Vec<f64>,
        values: Vec<f64>,
        second_derivatives: Vec<f64>,
    },
    /// `Σ c_k · q^k`, q in mm.
    Polynomial { coeffs: Vec<f64> },
}

impl ErrorCurve {
    /// A table; points are sorted by position.
    pub fn table(name: &str, mut points: Vec<(f64, f64)>) -> Result<Self, VolumetricError> {
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        let distinct = points.windows(2).all(|w| w[1].0 > w[0].0);
        if points.len() < 2 || !distinct {
            return Err(VolumetricError::ShortTable {
                name: name.into(),
                n: points.len(),
            });
        }
        let x: Vec<f64> = points.iter().map(|p| p.0).collect();
        let y: Vec<f64> = points.iter().map(|p| p.1).collect();
        let m = natural_spline_second_derivatives(&x, &y);
        Ok(Self::Table {
            positions_mm: x,
            values: y,
            second_derivatives: m,
        })
    }

    pub fn eval(&self, q: f64) -> f64 {
        match self {
            Self::Polynomial { coeffs } => coeffs.iter().rev().fold(0.0, |acc, c| acc * q + c),
            Self::Table {
                positions_mm: x,
                values: y,
                second_derivatives: m,
            } => {
                let n = x.len();
                if q <= x[0] {
                    return y[0];
                }
                if q >= x[n - 1] {
                    return y[n - 1];
                }
                let i = x.partition_point(|&v| v <= q).clamp(1, n - 1) - 1;
                let h = x[i + 1] - x[i];
                let a = (x[i + 1] - q) / h;
                let b = (q - x[i]) / h;
                a * y[i]
                    + b * y[i + 1]
                    + ((a * a * a - a) * m[i] + (b * b * b - b) * m[i + 1]) * h * h / 6.0
            }
        }
    }

    /// Range covered by a table (None for a polynomial).
    pub fn range_mm(&self) -> Option<(f64, f64)> {
        match self {
            Self::Table { positions_mm, .. } => {
                Some((positions_mm[0], positions_mm[positions_mm.len() - 1]))
            }
            Self::Polynomial { .. } => None,
        }
    }
}

/// Second derivatives of the natural cubic spline (tridiagonal solve).
fn natural_spline_second_derivatives(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let mut m = vec![0.0; n];
    if n < 3 {
        return m;
    }
    let mut c_prime = vec![0.0; n];
    let mut d_prime = vec![0.0; n];
    for i in 1..n - 1 {
        let h0 = x[i] - x[i - 1];
        let h1 = x[i + 1] - x[i];
        let a = h0 / 6.0;
        let b = (h0 + h1) / 3.0;
        let c = h1 / 6.0;
        let d = (y[i + 1] - y[i]) / h1 - (y[i] - y[i - 1]) / h0;
        let denom = b - a * c_prime[i - 1];
        c_prime[i] = c / denom;
        d_prime[i] = (d - a * d_prime[i - 1]) / denom;
    }
    for i in (1..n - 1).rev() {
        m[i] = d_prime[i] - c_prime[i] * m[i + 1];
    }
    m
}

/// Component (index 0..6: rotations A, B, C then translations X, Y, Z) of an error name.
fn parse_name(name: &str) -> Option<(AxisName, usize, bool)> {
    let c: Vec<char> = name.trim().to_ascii_uppercase().chars().collect();
    let comp = |ch: char| match ch {
        'A' => Some(0),
        'B' => Some(1),
        'C' => Some(2),
        'X' => Some(3),
        'Y' => Some(4),
        'Z' => Some(5),
        _ => None,
    };
    match c.as_slice() {
        ['E', k, a] => {
            let axis = AxisName::from_char(*a).filter(|a| a.is_linear())?;
            Some((axis, comp(*k)?, false))
        }
        ['E', k, '0', a] => {
            let axis = AxisName::from_char(*a).filter(|a| a.is_linear())?;
            let k = comp(*k).filter(|&k| k < 3)?;
            Some((axis, k, true))
        }
        _ => None,
    }
}

/// ISO 230-1 name of a motion error component.
pub fn error_name(axis: AxisName, component: usize) -> String {
    format!(
        "E{}{}",
        ['A', 'B', 'C', 'X', 'Y', 'Z'][component.min(5)],
        axis.letter()
    )
}

/// The 21 errors of three linear axes (absent ones are zero).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ComponentErrors {
    /// Motion errors by ISO name (`EXX`, `EAY`, …).
    pub motion: BTreeMap<String, ErrorCurve>,
    /// Squarenesses by ISO name (`EC0Y`, `EB0Z`, `EA0Z`), µrad.
    pub squareness_urad: BTreeMap<String, f64>,
}

impl ComponentErrors {
    /// Parse the long CSV format `error,position_mm,value`: one row per table point; `value` in
    /// µm for translations (`EXX`, `EYX`, …) and µrad for rotations (`EAX`, …, `EC0Y`); a
    /// squareness row leaves `position_mm` empty. `#` lines are comments.
    pub fn from_csv(text: &str) -> Result<Self, VolumetricError> {
        let mut rdr = csv::ReaderBuilder::new()
            .comment(Some(b'#'))
            .trim(csv::Trim::All)
            .flexible(true)
            .from_reader(text.as_bytes());
        let headers = rdr
            .headers()
            .map_err(|e| VolumetricError::Csv(e.to_string()))?
            .clone();
        let col = |n: &str| {
            headers.iter().position(|h| h == n).ok_or_else(|| {
                VolumetricError::Csv(format!(
                    "missing column `{n}` (need error,position_mm,value)"
                ))
            })
        };
        let (ci, cp, cv) = (col("error")?, col("position_mm")?, col("value")?);
        let mut points: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
        let mut sq = BTreeMap::new();
        for (line, rec) in rdr.records().enumerate() {
            let row = line + 2;
            let rec = rec.map_err(|e| VolumetricError::Csv(e.to_string()))?;
            let name = rec.get(ci).unwrap_or("").trim().to_ascii_uppercase();
            let (_, _, is_sq) = parse_name(&name).ok_or_else(|| VolumetricError::BadName {
                row,
                name: name.clone(),
            })?;
            let v_s = rec.get(cv).unwrap_or("");
            let v: f64 = v_s
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or_else(|| VolumetricError::BadRow {
                    row,
                    msg: format!("value `{v_s}` is not a finite number"),
                })?;
            if v.abs() > MAX_ERROR_VALUE {
                return Err(VolumetricError::BadRow {
                    row,
                    msg: format!(
                        "value {v_s} is beyond ±{MAX_ERROR_VALUE} (µm or µrad: 1 m or 1 rad)"
                    ),
                });
            }
            if is_sq {
                sq.insert(name, v);
            } else {
                let p_s = rec.get(cp).unwrap_or("");
                let p: f64 = p_s.parse().ok().filter(|v: &f64| v.is_finite()).ok_or_else(|| VolumetricError::BadRow {
                    row,
                    msg: format!("position_mm `{p_s}` is not a finite number (only squareness rows leave it empty)"),
                })?;
                if p.abs() > MAX_POSITION_MM {
                    return Err(VolumetricError::BadRow {
                        row,
                        msg: format!("position_mm {p_s} is beyond ±{MAX_POSITION_MM} mm"),
                    });
                }
                points.entry(name).or_default().push((p, v));
            }
        }
        let mut motion = BTreeMap::new();
        for (name, pts) in points {
            motion.insert(name.clone(), ErrorCurve::table(&name, pts)?);
        }
        Ok(Self {
            motion,
            squareness_urad: sq,
        })
    }

    /// Motion error of an axis at position `q` (mm).
    pub fn displacement(&self, axis: AxisName, q: f64) -> SmallDisplacement {
        let mut v = [0.0; 6];
        for (k, slot) in v.iter_mut().enumerate() {
            if let Some(c) = self.motion.get(&error_name(axis, k)) {
                *slot = c.eval(q);
            }
        }
        SmallDisplacement {
            rot_urad: Vector3::new(v[0], v[1], v[2]),
            trans_um: Vector3::new(v[3], v[4], v[5]),
        }
    }

    fn link_of(&self, axis: AxisName) -> SmallDisplacement {
        let mut rot = Vector3::zeros();
        for k in 0..3 {
            let n = format!("E{}0{}", ['A', 'B', 'C'][k], axis.letter());
            if let Some(v) = self.squareness_urad.get(&n) {
                rot[k] = *v;
            }
        }
        SmallDisplacement {
            rot_urad: rot,
            trans_um: Vector3::zeros(),
        }
    }
}

impl ErrorSource for ComponentErrors {
    fn link(&self, axis: AxisName) -> SmallDisplacement {
        self.link_of(axis)
    }
    fn motion(&self, axis: AxisName, q: f64) -> SmallDisplacement {
        if axis.is_linear() {
            self.displacement(axis, q)
        } else {
            SmallDisplacement::ZERO
        }
    }
}

/// First-order (small-angle) volumetric error, µm: paper 004 eq. 1 with A ≈ I + ε× (eq. 7 without products of errors).
pub fn small_angle_error_um(
    machine: &Machine,
    errors: &dyn ErrorSource,
    pose: &Pose,
) -> Vector3<f64> {
    let frames = machine.joint_frames(pose);
    let p = machine.nominal_tool_point_mm(pose);
    let mut e = Vector3::zeros();
    for f in &frames {
        let m = errors.motion(f.axis, f.q);
        let l = errors.link(f.axis);
        for k in 0..6 {
            let (mv, lv) = if k < 3 {
                (m.rot_urad[k], l.rot_urad[k])
            } else {
                (m.trans_um[k - 3], l.trans_um[k - 3])
            };
            if mv != 0.0 {
                e += motion_sensitivity(f, k, &p) * mv;
            }
            if lv != 0.0 {
                e += link_sensitivity(f, k, &p) * lv;
            }
        }
    }
    let (r_tool, r_work) = machine.end_rotations(pose);
    e + r_tool * errors.tool_offset_um() - r_work * errors.work_point_um()
}

/// A regular grid over the working volume.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GridSpec {
    /// (min, max, count) per axis X, Y, Z, mm.
    pub ranges: [(f64, f64, usize); 3],
}

impl GridSpec {
    /// Parse `x0:x1:n,y0:y1:n,z0:z1:n`.
    pub fn parse(s: &str) -> Result<Self, VolumetricError> {
        let bad = || VolumetricError::BadGrid(s.to_string());
        let parts: Vec<&str> = s.split(',').collect();
        if parts.len() != 3 {
            return Err(bad());
        }
        let mut ranges = [(0.0, 0.0, 1); 3];
        for (i, p) in parts.iter().enumerate() {
            let f: Vec<&str> = p.split(':').collect();
            if f.len() != 3 {
                return Err(bad());
            }
            let a: f64 = f[0].trim().parse().map_err(|_| bad())?;
            let b: f64 = f[1].trim().parse().map_err(|_| bad())?;
            let n: usize = f[2].trim().parse().map_err(|_| bad())?;
            if !a.is_finite() || !b.is_finite() || n == 0 || (n > 1 && b <= a) || n > 10_000 {
                return Err(bad());
            }
            if a.abs() > MAX_POSITION_MM || b.abs() > MAX_POSITION_MM {
                return Err(VolumetricError::GridRange(s.to_string()));
            }
            ranges[i] = (a, b, n);
        }
        Ok(Self { ranges })
    }

    pub fn values(&self, axis: usize) -> Vec<f64> {
        let (a, b, n) = self.ranges[axis];
        if n == 1 {
            return vec![a];
        }
        (0..n)
            .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
            .collect()
    }

    pub fn len(&self) -> usize {
        self.ranges.iter().map(|r| r.2).product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// One grid point: position (mm) and volumetric error (µm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GridPoint {
    pub pos_mm: [f64; 3],
    pub error_um: [f64; 3],
}

/// Errors with the motion errors already evaluated at one grid point.
struct Tabulated<'a> {
    base: &'a ComponentErrors,
    d: [SmallDisplacement; 3],
}

impl ErrorSource for Tabulated<'_> {
    fn link(&self, axis: AxisName) -> SmallDisplacement {
        self.base.link_of(axis)
    }
    fn motion(&self, axis: AxisName, _q: f64) -> SmallDisplacement {
        if axis.is_linear() {
            self.d[axis.index()]
        } else {
            SmallDisplacement::ZERO
        }
    }
}

/// The volumetric error over a grid (exact rigid-body model), ordered x-major.
pub fn volumetric_grid(
    machine: &Machine,
    errors: &ComponentErrors,
    grid: &GridSpec,
) -> Result<Vec<GridPoint>, VolumetricError> {
    for a in [AxisName::X, AxisName::Y, AxisName::Z] {
        if machine.joint(a).is_none() {
            return Err(VolumetricError::MissingAxis(a.letter()));
        }
    }
    let vals = [grid.values(0), grid.values(1), grid.values(2)];
    // Every joint's transform (actual and nominal) once per grid line, not once per point:
    // the grid then costs a few isometry products per point (the 50³ budget is 100 ms).
    let mut actual: [Vec<Isometry3<f64>>; 3] = Default::default();
    let mut nominal: [Vec<Isometry3<f64>>; 3] = Default::default();
    for j in machine
        .workpiece_joints
        .iter()
        .chain(machine.tool_joints.iter())
    {
        let a = j.axis.index();
        if a > 2 {
            continue;
        }
        let link = errors.link_of(j.axis);
        actual[a] = vals[a]
            .iter()
            .map(|&q| Machine::joint_transform(j, q, link, errors.displacement(j.axis, q)))
            .collect();
        nominal[a] = vals[a]
            .iter()
            .map(|&q| {
                Machine::joint_transform(j, q, SmallDisplacement::ZERO, SmallDisplacement::ZERO)
            })
            .collect();
    }
    // A machine with rotary axes (held at zero here) goes through the general model.
    let linear_only = machine
        .workpiece_joints
        .iter()
        .chain(machine.tool_joints.iter())
        .all(|j| j.axis.is_linear());
    let tool = Point3::from(machine.tool_offset_mm);
    let (xs, ys, zs) = (&vals[0], &vals[1], &vals[2]);
    let out: Vec<GridPoint> = (0..xs.len())
        .into_par_iter()
        .flat_map_iter(|i| {
            let (actual, nominal) = (&actual, &nominal);
            (0..ys.len()).flat_map(move |j| {
                (0..zs.len()).map(move |k| {
                    let idx = [i, j, k];
                    let pos = [xs[i], ys[j], zs[k]];
                    let e = if linear_only {
                        let chain = |js: &[Joint], t: &[Vec<Isometry3<f64>>; 3]| {
                            js.iter().fold(Isometry3::identity(), |acc, jt| {
                                let a = jt.axis.index();
                                acc * t[a][idx[a]]
                            })
                        };
                        let tw_n = chain(&machine.workpiece_joints, nominal);
                        let tt_n = chain(&machine.tool_joints, nominal);
                        let w = tw_n.inverse_transform_point(&(tt_n * tool));
                        let p_tool = chain(&machine.tool_joints, actual) * tool;
                        let p_work = chain(&machine.workpiece_joints, actual) * w;
                        (p_tool - p_work) * 1e3
                    } else {
                        let t = Tabulated {
                            base: errors,
                            d: [
                                errors.displacement(AxisName::X, pos[0]),
                                errors.displacement(AxisName::Y, pos[1]),
                                errors.displacement(AxisName::Z, pos[2]),
                            ],
                        };
                        machine.volumetric_error_um(&Pose::xyz(pos[0], pos[1], pos[2]), &t, None)
                    };
                    GridPoint {
                        pos_mm: pos,
                        error_um: [e.x, e.y, e.z],
                    }
                })
            })
        })
        .collect();
    // A machine description with an absurd tool offset or axis geometry can still overflow:
    // nothing non-finite goes into a table.
    if out
        .iter()
        .any(|p| p.error_um.iter().any(|v| !v.is_finite()))
    {
        return Err(VolumetricError::NotFinite("a volumetric error of the grid"));
    }
    Ok(out)
}

/// Compensation table as open CSV: grid point, error and correction (= −error), µm.
pub fn compensation_csv(points: &[GridPoint]) -> String {
    let mut s = String::with_capacity(points.len() * 80);
    s.push_str("x_mm,y_mm,z_mm,ex_um,ey_um,ez_um,cx_um,cy_um,cz_um\n");
    for p in points {
        let _ = writeln!(
            s,
            "{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3}",
            p.pos_mm[0],
            p.pos_mm[1],
            p.pos_mm[2],
            p.error_um[0],
            p.error_um[1],
            p.error_um[2],
            -p.error_um[0],
            -p.error_um[1],
            -p.error_um[2]
        );
    }
    s
}

/// The Siemens tables and how well they represent the grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CecTables {
    /// The `%_N_NC_CEC_INI` file text.
    pub ini: String,
    /// Largest difference over the grid between the full correction and the sum of the
    /// tables written, µm (the non-separable part: Abbe products such as `EAX(x)·z`, plus any
    /// table left out for the control's table limit).
    pub max_separation_residual_um: f64,
    /// Tables left out because the control holds fewer (e.g. "correction of Z from X").
    pub omitted: Vec<String>,
}

/// Which control the CEC tables are for and what they are valid for.
#[derive(Debug, Clone, PartialEq)]
pub struct CecOptions<'a> {
    /// Machine axis names for X, Y, Z (e.g. `["AX1", "AX2", "AX3"]`).
    pub axis_names: [&'a str; 3],
    /// Largest number of CEC tables the control holds: 8 on the SINUMERIK 828D (its
    /// `$AN_CEC` tables 0…7), more on the 840D sl ([`CEC_TABLES_840D`]).
    pub max_tables: usize,
    /// Tool offset (tool point from the spindle gauge line, mm) the grid was computed for:
    /// the Abbe terms, hence the tables, change with it.
    pub tool_offset_mm: Option<[f64; 3]>,
}

/// The SINUMERIK 828D's number of CEC tables.
pub const CEC_TABLES_828D: usize = 8;
/// Enough for all nine tables on the 840D sl (which holds more; see `docs/methods.md`).
pub const CEC_TABLES_840D: usize = 9;

/// SINUMERIK "interpolatory compensation" (CEC, sag/cross compensation) tables for an 840D sl
/// and a tool offset not stated: [`siemens_cec_for`] with all nine tables.
pub fn siemens_cec(
    points: &[GridPoint],
    grid: &GridSpec,
    axis_names: [&str; 3],
) -> Result<CecTables, VolumetricError> {
    siemens_cec_for(
        points,
        grid,
        &CecOptions {
            axis_names,
            max_tables: CEC_TABLES_840D,
            tool_offset_mm: None,
        },
    )
}

/// One (input, output) table sampled along the grid line through the grid's first corner;
/// the constant correction at that corner goes into the X-input tables.
/// The table of `out` along `input`: the correction at each point of that axis, the others at
/// their first point. The `base` table (the first axis with more than one point) holds the
/// correction at the grid's first point too; the others hold differences from it.
fn cec_table(
    points: &[GridPoint],
    n: [usize; 3],
    (input, base): (usize, usize),
    out: usize,
) -> Vec<f64> {
    let idx = |i: usize, j: usize, k: usize| (i * n[1] + j) * n[2] + k;
    let corr = |i: usize, j: usize, k: usize| -points[idx(i, j, k)].error_um[out];
    (0..n[input])
        .map(|q| {
            let (i, j, k) = match input {
                0 => (q, 0, 0),
                1 => (0, q, 0),
                _ => (0, 0, q),
            };
            if input == base {
                corr(i, j, k)
            } else {
                corr(i, j, k) - corr(0, 0, 0)
            }
        })
        .collect()
}

/// SINUMERIK "interpolatory compensation" (CEC, sag/cross compensation) tables: up to nine
/// tables, one per (input axis, output axis) pair, so that correction_k(x, y, z) ≈
/// Σ_j table_jk(q_j).
///
/// Format from the SINUMERIK 840D sl Function Manual Extended Functions, K3 Compensation,
/// §4.4 "Interpolatory compensation" (6FC5397-1BP40-3BA1, 03/2013): system variables
/// `$AN_CEC[t,N]` (value in mm at interpolation point N), `$AN_CEC_INPUT_AXIS[t]`,
/// `$AN_CEC_OUTPUT_AXIS[t]`, `$AN_CEC_STEP[t]`, `$AN_CEC_MIN[t]`, `$AN_CEC_MAX[t]`,
/// `$AN_CEC_DIRECTION[t]`, `$AN_CEC_MULT_BY_TABLE[t]`, `$AN_CEC_IS_MODULO[t]`, in a file
/// `%_N_NC_CEC_INI` under `CHANDATA(1)`; each table is switched on by the setting data
/// SD41300 `$SN_CEC_TABLE_ENABLE[t]`, which we write. The machine data (MD18342
/// `MM_CEC_MAX_POINTS[t]`, MD32710 `CEC_ENABLE` per output axis) must be set on the control
/// by the commissioning engineer; the file's comments list them. When the control holds fewer
/// tables than nine (828D: eight), the tables with the smallest corrections are left out and
/// the residual says what that costs. Siemens VCS (volumetric compensation) uses its own
/// proprietary file format, which we do not know and do not write.
pub fn siemens_cec_for(
    points: &[GridPoint],
    grid: &GridSpec,
    o: &CecOptions,
) -> Result<CecTables, VolumetricError> {
    check_cec_input(points, grid, o)?;
    let n = [grid.ranges[0].2, grid.ranges[1].2, grid.ranges[2].2];
    let xyz = |a: usize| "XYZ".as_bytes()[a] as char;
    // An axis with one grid point has no table (a step of 0 is no table a control takes): the
    // correction does not vary along it, and its constant goes into the first axis that has more.
    let Some(base) = (0..3).find(|&a| n[a] > 1) else {
        return Err(VolumetricError::BadGrid(
            "one point on every axis: an interpolatory table needs two points along an axis".into(),
        ));
    };
    let mut all: Vec<(usize, usize, Vec<f64>)> = (0..3)
        .filter(|&i| n[i] > 1)
        .flat_map(|i| (0..3).map(move |o| (i, o)))
        .map(|(i, out)| (i, out, cec_table(points, n, (i, base), out)))
        .collect();
    let size = |v: &[f64]| v.iter().fold(0.0f64, |a, x| a.max(x.abs()));
    let mut omitted = Vec::new();
    while all.len() > o.max_tables {
        let (k, _) = all
            .iter()
            .enumerate()
            .min_by(|a, b| size(&a.1.2).total_cmp(&size(&b.1.2)))
            .unwrap_or((0, &all[0]));
        let (i, out, v) = all.remove(k);
        omitted.push(format!(
            "correction of {} from {} (up to {:.2} µm)",
            xyz(out),
            xyz(i),
            size(&v)
        ));
    }
    let mut ini = String::from(
        "%_N_NC_CEC_INI\n; written by metrolog volumetric: correction = −volumetric error\n",
    );
    match o.tool_offset_mm {
        Some(t) => {
            let _ = writeln!(
                ini,
                "; valid for the tool offset ({:.3}, {:.3}, {:.3}) mm: the Abbe terms change with the tool length",
                t[0], t[1], t[2]
            );
        }
        None => ini.push_str(
            "; tool offset not stated: valid only for the tool length the grid was measured with\n",
        ),
    }
    for s in &omitted {
        let _ = writeln!(ini, "; left out for the control's table limit: {s}");
    }
    let _ = writeln!(
        ini,
        "; set MD18342 $MN_MM_CEC_MAX_POINTS[t] >= the points of table t and MD32710 $MA_CEC_ENABLE=1 for {}, {}, {}",
        o.axis_names[0], o.axis_names[1], o.axis_names[2]
    );
    ini.push_str("CHANDATA(1)\n");
    for (t, (input, out, vals)) in all.iter().enumerate() {
        let (min, max, cnt) = grid.ranges[*input];
        let step = (max - min) / (cnt - 1) as f64;
        let _ = writeln!(
            ini,
            "; table {t}: correction of {} from the position of {}",
            xyz(*out),
            xyz(*input)
        );
        for (p, v) in vals.iter().enumerate() {
            let _ = writeln!(ini, "$AN_CEC[{t},{p}]={:.6}", v * 1e-3);
        }
        let _ = writeln!(ini, "$AN_CEC_INPUT_AXIS[{t}]=({})", o.axis_names[*input]);
        let _ = writeln!(ini, "$AN_CEC_OUTPUT_AXIS[{t}]=({})", o.axis_names[*out]);
        let _ = writeln!(ini, "$AN_CEC_STEP[{t}]={step:.6}");
        let _ = writeln!(ini, "$AN_CEC_MIN[{t}]={min:.6}");
        let _ = writeln!(ini, "$AN_CEC_MAX[{t}]={max:.6}");
        let _ = writeln!(ini, "$AN_CEC_DIRECTION[{t}]=0");
        let _ = writeln!(ini, "$AN_CEC_MULT_BY_TABLE[{t}]=0");
        let _ = writeln!(ini, "$AN_CEC_IS_MODULO[{t}]=0");
        let _ = writeln!(ini, "$SN_CEC_TABLE_ENABLE[{t}]=1");
    }
    ini.push_str("M17\n");
    let idx = |i: usize, j: usize, k: usize| (i * n[1] + j) * n[2] + k;
    let mut worst: f64 = 0.0;
    for (i, j, k) in
        (0..n[0]).flat_map(|i| (0..n[1]).flat_map(move |j| (0..n[2]).map(move |k| (i, j, k))))
    {
        for out in 0..3 {
            let sum: f64 = all
                .iter()
                .filter(|(_, o2, _)| *o2 == out)
                .map(|(input, _, v)| v[[i, j, k][*input]])
                .sum();
            worst = worst.max((sum + points[idx(i, j, k)].error_um[out]).abs());
        }
    }
    Ok(CecTables {
        ini,
        max_separation_residual_um: worst,
        omitted,
    })
}

/// What goes into a CEC file is a machine axis name (letters, then optional digits, at most 8:
/// anything else, such as `]`, `=`, `;`, `)` or a newline, would change the file's syntax) and
/// finite numbers only.
fn check_cec_input(
    points: &[GridPoint],
    grid: &GridSpec,
    o: &CecOptions,
) -> Result<(), VolumetricError> {
    for name in o.axis_names {
        let letters = name.bytes().take_while(u8::is_ascii_alphabetic).count();
        if letters == 0 || name.len() > 8 || !name.bytes().skip(letters).all(|b| b.is_ascii_digit())
        {
            return Err(VolumetricError::BadAxisName(name.to_string()));
        }
    }
    if !points
        .iter()
        .all(|p| p.error_um.iter().all(|v| v.is_finite()))
    {
        return Err(VolumetricError::NotFinite("a volumetric error of the grid"));
    }
    if !grid
        .ranges
        .iter()
        .all(|r| r.0.is_finite() && r.1.is_finite())
    {
        return Err(VolumetricError::NotFinite("a grid range"));
    }
    if o.tool_offset_mm
        .is_some_and(|t| !t.iter().all(|v| v.is_finite()))
    {
        return Err(VolumetricError::NotFinite("the tool offset"));
    }
    Ok(())
}

/// Summary of a volumetric grid: largest error magnitude and RMS per direction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridSummary {
    pub n_points: usize,
    pub max_norm_um: f64,
    pub max_at_mm: [f64; 3],
    pub rms_um: [f64; 3],
}

pub fn summarize(points: &[GridPoint]) -> GridSummary {
    let mut best = (0.0, [0.0; 3]);
    let mut rms = [0.0; 3];
    for p in points {
        let nrm = Vector3::from(p.error_um).norm();
        if nrm > best.0 {
            best = (nrm, p.pos_mm);
        }
        for (r, e) in rms.iter_mut().zip(p.error_um) {
            *r += e * e;
        }
    }
    let n = points.len().max(1) as f64;
    GridSummary {
        n_points: points.len(),
        max_norm_um: best.0,
        max_at_mm: best.1,
        rms_um: rms.map(|v| (v / n).sqrt()),
    }
}
