//! PSD laser frame: 13 of the 21 errors of a three-axis machine from ten straightness readings
//! (paper 003, Brecher, Spierling, Fey 2022). The derivation of the measurement model is in
//! `psd_frame.md` beside this file; the short version:
//!
//! - A thermally stable frame on the table guides a laser through five segments: S1 along Y at
//!   `x_lo`, S2 along X at `y_hi`, S3 along Y at `x_hi`, S4 along X at `y_lo` (the table plane,
//!   height `z0`), S5 along Z at `(x_lo, y_lo)`. A PSD in the spindle reads, at each point, the
//!   two components of the volumetric error perpendicular to the beam, *minus the same reading
//!   of a reference run*: only changes are measured, the frame's own imperfections cancel.
//! - Points: S1 has 7 points, the first 7 of the 11 Y positions of S3 (the paper's 7 + 4 × 11);
//!   S2 and S4 share 11 X positions; S5 has 11 Z positions.
//! - Field model (first order, unmeasured pitch, yaw, Z angles and EZZ taken as zero):
//!
//!   ```text
//!   Ex = EXX(x) + EXY(y) + EXZ(z) + s_xy·(y − y_lo) + s_xz·(z − z0)
//!   Ey = EYY(y) + EYX(x) + EYZ(z) + s_yx·(x − x_lo) + s_yz·(z − z0)
//!   Ez = EZX(x) + EZY(y) + s_zx·(x − x_lo) + s_zy·(y − y_lo)
//!        + EAX(x)·(y − y_lo) − EBY(y)·(x − x_hi) + c_z
//!   ```
//!
//!   with `EXX`, `EYY` linear (two positions each), the straightnesses free of mean and slope
//!   over their segment (ISO 230-1 least-squares reference line), the rolls free of mean and
//!   slope over their points (a constant or linear roll cannot be told from a tilt or a
//!   squareness in plane measurements). Squarenesses (X the reference axis):
//!   `EC0Y = −(s_xy + s_yx)`, `EB0Z = s_xz + s_zx`, `EA0Z = −(s_yz + s_zy)`. The frame terms
//!   `s_yx` (rotation of the machine XY plane against the frame), `s_zx`, `s_zy` (tilts) and
//!   `c_z` are reported but are not machine errors.
//!
//! The derivation is linear in the readings, so [`derive_uncertainty`] propagates a reading
//! noise exactly, and a Monte Carlo can push virtual readings through [`derive_errors`].

use serde::{Deserialize, Serialize};

use crate::kinematics::{ErrorSource, Machine, Pose};

/// Errors of the PSD measurement model and its data.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PsdError {
    /// segment {segment}: expected {expected} points, got {got}
    #[error("segment {segment}: expected {expected} points, got {got}")]
    PointCount {
        segment: u8,
        expected: usize,
        got: usize,
    },
    /// segment {segment}, point {point}: a reading is not a finite number
    #[error("segment {segment}, point {point}: a reading is not a finite number")]
    NonFinite { segment: u8, point: usize },
    /// layout: {0}
    #[error("layout: {0}")]
    Layout(String),
    /// PSD readings CSV: {0}
    #[error("PSD readings CSV: {0}")]
    Csv(String),
}

/// Where the points lie (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PsdLayout {
    pub x_lo: f64,
    pub x_hi: f64,
    pub y_lo: f64,
    pub y_hi: f64,
    pub z0: f64,
    pub z1: f64,
    /// Points on S2, S3, S4, S5 (11 in the paper).
    pub n_points: usize,
    /// Points on S1 (7 in the paper), the first of S3's Y positions.
    pub n_s1: usize,
}

impl PsdLayout {
    /// The demonstrator of paper 003: X 184 mm, Y 167 mm, Z 350 mm, 7 + 4 × 11 points.
    pub fn paper() -> Self {
        Self {
            x_lo: 0.0,
            x_hi: 184.0,
            y_lo: 0.0,
            y_hi: 167.0,
            z0: 0.0,
            z1: 350.0,
            n_points: 11,
            n_s1: 7,
        }
    }

    fn check(&self) -> Result<(), PsdError> {
        let ok = self.x_hi > self.x_lo && self.y_hi > self.y_lo && self.z1 > self.z0;
        if !ok || self.n_points < 4 || self.n_s1 < 4 || self.n_s1 > self.n_points {
            return Err(PsdError::Layout(format!(
                "need x_lo < x_hi, y_lo < y_hi, z0 < z1, at least 4 points per segment and S1 no longer than S3: {self:?}"
            )));
        }
        Ok(())
    }

    fn lin(a: f64, b: f64, n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
            .collect()
    }
    pub fn xs(&self) -> Vec<f64> {
        Self::lin(self.x_lo, self.x_hi, self.n_points)
    }
    pub fn ys(&self) -> Vec<f64> {
        Self::lin(self.y_lo, self.y_hi, self.n_points)
    }
    pub fn ys1(&self) -> Vec<f64> {
        self.ys()[..self.n_s1].to_vec()
    }
    pub fn zs(&self) -> Vec<f64> {
        Self::lin(self.z0, self.z1, self.n_points)
    }

    /// Machine position of point `i` of segment `seg` (1..=5), ordered by ascending coordinate.
    pub fn position(&self, seg: u8, i: usize) -> Pose {
        match seg {
            1 => Pose::xyz(self.x_lo, self.ys()[i], self.z0),
            2 => Pose::xyz(self.xs()[i], self.y_hi, self.z0),
            3 => Pose::xyz(self.x_hi, self.ys()[i], self.z0),
            4 => Pose::xyz(self.xs()[i], self.y_lo, self.z0),
            _ => Pose::xyz(self.x_lo, self.y_lo, self.zs()[i]),
        }
    }
}

/// The ten straightness readings of one run (already minus the reference run), µm, each
/// segment ordered by ascending coordinate: S1, S3: `[ex, ez]`; S2, S4: `[ey, ez]`;
/// S5: `[ex, ey]`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PsdReadings {
    pub s1: Vec<[f64; 2]>,
    pub s2: Vec<[f64; 2]>,
    pub s3: Vec<[f64; 2]>,
    pub s4: Vec<[f64; 2]>,
    pub s5: Vec<[f64; 2]>,
}

impl PsdReadings {
    /// `self − reference`, point by point.
    pub fn minus(&self, reference: &PsdReadings) -> Result<PsdReadings, PsdError> {
        let sub = |seg: u8, a: &[[f64; 2]], b: &[[f64; 2]]| -> Result<Vec<[f64; 2]>, PsdError> {
            if a.len() != b.len() {
                return Err(PsdError::PointCount {
                    segment: seg,
                    expected: b.len(),
                    got: a.len(),
                });
            }
            Ok(a.iter()
                .zip(b)
                .map(|(p, q)| [p[0] - q[0], p[1] - q[1]])
                .collect())
        };
        Ok(PsdReadings {
            s1: sub(1, &self.s1, &reference.s1)?,
            s2: sub(2, &self.s2, &reference.s2)?,
            s3: sub(3, &self.s3, &reference.s3)?,
            s4: sub(4, &self.s4, &reference.s4)?,
            s5: sub(5, &self.s5, &reference.s5)?,
        })
    }

    fn segments(&self) -> [(u8, &Vec<[f64; 2]>); 5] {
        [
            (1, &self.s1),
            (2, &self.s2),
            (3, &self.s3),
            (4, &self.s4),
            (5, &self.s5),
        ]
    }

    /// All readings in one vector (S1 … S5, two per point).
    pub fn to_vec(&self) -> Vec<f64> {
        self.segments()
            .iter()
            .flat_map(|(_, s)| s.iter().flat_map(|p| p.iter().copied()))
            .collect()
    }

    /// The inverse of [`Self::to_vec`] for a layout.
    pub fn from_vec(layout: &PsdLayout, v: &[f64]) -> Self {
        let mut it = v.iter().copied();
        let mut take = |n: usize| -> Vec<[f64; 2]> {
            (0..n)
                .map(|_| [it.next().unwrap_or(0.0), it.next().unwrap_or(0.0)])
                .collect()
        };
        let n = layout.n_points;
        let s1 = take(layout.n_s1);
        let s2 = take(n);
        let s3 = take(n);
        let s4 = take(n);
        let s5 = take(n);
        Self { s1, s2, s3, s4, s5 }
    }
}

/// Terms of the frame's placement on the table (not machine errors).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FrameTerms {
    /// Rotation of the machine X direction against the frame about Z (`s_yx`), µrad.
    pub xy_rotation_urad: f64,
    /// Slope of Ez along X (`s_zx`), µrad.
    pub x_tilt_urad: f64,
    /// Slope of Ez along Y (`s_zy`), µrad.
    pub y_tilt_urad: f64,
    /// Ez offset `c_z`, µm.
    pub z_offset_um: f64,
}

/// The 13 errors (thermo-elastic changes against the reference run).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PsdErrors {
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    /// Y positions of the `eby_urad` values (those of S1).
    pub y_s1_mm: Vec<f64>,
    pub z_mm: Vec<f64>,
    /// Positioning of X at `x_mm` (linear between the two measured positions), µm.
    pub exx_um: Vec<f64>,
    /// Positioning of Y at `y_mm`, µm.
    pub eyy_um: Vec<f64>,
    pub eyx_um: Vec<f64>,
    pub ezx_um: Vec<f64>,
    pub exy_um: Vec<f64>,
    pub ezy_um: Vec<f64>,
    pub exz_um: Vec<f64>,
    pub eyz_um: Vec<f64>,
    /// Roll of X at `x_mm`, µrad.
    pub eax_urad: Vec<f64>,
    /// Roll of Y at `y_s1_mm`, µrad.
    pub eby_urad: Vec<f64>,
    pub ec0y_urad: f64,
    pub eb0z_urad: f64,
    pub ea0z_urad: f64,
    pub frame: FrameTerms,
}

impl PsdErrors {
    /// All values as one vector (same order as the fields), for Monte Carlo statistics.
    pub fn to_vec(&self) -> Vec<f64> {
        let mut v = Vec::new();
        for s in [
            &self.exx_um,
            &self.eyy_um,
            &self.eyx_um,
            &self.ezx_um,
            &self.exy_um,
            &self.ezy_um,
            &self.exz_um,
            &self.eyz_um,
            &self.eax_urad,
            &self.eby_urad,
        ] {
            v.extend_from_slice(s);
        }
        v.extend_from_slice(&[self.ec0y_urad, self.eb0z_urad, self.ea0z_urad]);
        v.extend_from_slice(&[
            self.frame.xy_rotation_urad,
            self.frame.x_tilt_urad,
            self.frame.y_tilt_urad,
            self.frame.z_offset_um,
        ]);
        v
    }

    /// Names matching [`Self::to_vec`].
    pub fn names(&self) -> Vec<String> {
        let mut n = Vec::new();
        let groups: [(&str, usize); 10] = [
            ("EXX_um", self.exx_um.len()),
            ("EYY_um", self.eyy_um.len()),
            ("EYX_um", self.eyx_um.len()),
            ("EZX_um", self.ezx_um.len()),
            ("EXY_um", self.exy_um.len()),
            ("EZY_um", self.ezy_um.len()),
            ("EXZ_um", self.exz_um.len()),
            ("EYZ_um", self.eyz_um.len()),
            ("EAX_urad", self.eax_urad.len()),
            ("EBY_urad", self.eby_urad.len()),
        ];
        for (g, len) in groups {
            for i in 0..len {
                n.push(format!("{g}[{}]", i + 1));
            }
        }
        for s in [
            "EC0Y_urad",
            "EB0Z_urad",
            "EA0Z_urad",
            "xy_rotation_urad",
            "x_tilt_urad",
            "y_tilt_urad",
            "z_offset_um",
        ] {
            n.push(s.to_string());
        }
        n
    }
}

/// Least-squares line through (p, v): (value at p[0], slope per mm, residuals).
fn line_fit(p: &[f64], v: &[f64]) -> (f64, f64, Vec<f64>) {
    let n = p.len() as f64;
    let pm = p.iter().sum::<f64>() / n;
    let vm = v.iter().sum::<f64>() / n;
    let sxx: f64 = p.iter().map(|x| (x - pm).powi(2)).sum();
    let sxy: f64 = p.iter().zip(v).map(|(x, y)| (x - pm) * (y - vm)).sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let resid = p
        .iter()
        .zip(v)
        .map(|(x, y)| y - vm - slope * (x - pm))
        .collect();
    (vm + slope * (p[0] - pm), slope, resid)
}

fn col(s: &[[f64; 2]], k: usize) -> Vec<f64> {
    s.iter().map(|p| p[k]).collect()
}

/// Derive the 13 errors from one run's readings (reference already subtracted).
pub fn derive_errors(layout: &PsdLayout, r: &PsdReadings) -> Result<PsdErrors, PsdError> {
    layout.check()?;
    let n = layout.n_points;
    for (seg, s) in r.segments() {
        let expected = if seg == 1 { layout.n_s1 } else { n };
        if s.len() != expected {
            return Err(PsdError::PointCount {
                segment: seg,
                expected,
                got: s.len(),
            });
        }
        if let Some(i) = s
            .iter()
            .position(|p| !p[0].is_finite() || !p[1].is_finite())
        {
            return Err(PsdError::NonFinite {
                segment: seg,
                point: i + 1,
            });
        }
    }
    let (xs, ys, ys1, zs) = (layout.xs(), layout.ys(), layout.ys1(), layout.zs());
    let dx = layout.x_hi - layout.x_lo;
    let dy = layout.y_hi - layout.y_lo;
    let m = layout.n_s1;

    // In-plane X readings along Y (S3 full, S1 the first m points).
    let (exx_hi, s_xy, exy) = line_fit(&ys, &col(&r.s3, 0));
    let diff_x: f64 = (0..m).map(|i| r.s3[i][0] - r.s1[i][0]).sum::<f64>() / m as f64;
    let exx_lo = exx_hi - diff_x;
    // In-plane Y readings along X (S4 reference line, S2 opposite).
    let (eyy_lo, s_yx, eyx) = line_fit(&xs, &col(&r.s4, 0));
    let diff_y: f64 = (0..n).map(|i| r.s2[i][0] - r.s4[i][0]).sum::<f64>() / n as f64;
    let eyy_hi = eyy_lo + diff_y;
    // Roll of X: twist of Ez between the two X lines.
    let (_, _, z2) = line_fit(&xs, &col(&r.s2, 1));
    let (z4_0, z4_slope, ezx) = line_fit(&xs, &col(&r.s4, 1));
    let eax_urad: Vec<f64> = (0..n).map(|i| (z2[i] - ezx[i]) / dy * 1e3).collect();
    // Roll of Y: twist between S1 and S3 over S1's points.
    let (_, _, z1m) = line_fit(&ys1, &col(&r.s1, 1));
    let (_, _, z3m) = line_fit(&ys1, &col(&r.s3[..m], 1));
    let eby_urad: Vec<f64> = (0..m).map(|i| (z1m[i] - z3m[i]) / dx * 1e3).collect();
    let (_, z3_slope, ezy) = line_fit(&ys, &col(&r.s3, 1));
    // Tilts, corrected for the linear terms the rolls put on the reference lines.
    let s_zy = z3_slope - eax_urad[n - 1] * 1e-3;
    let s_zx = z4_slope + eby_urad[0] * 1e-3;
    // Vertical segment.
    let (_, s_xz, exz) = line_fit(&zs, &col(&r.s5, 0));
    let (_, s_yz, eyz) = line_fit(&zs, &col(&r.s5, 1));
    let c_z = z4_0 - ezy[0] - eby_urad[0] * 1e-3 * dx;
    let exx = xs
        .iter()
        .map(|x| exx_lo + (exx_hi - exx_lo) * (x - layout.x_lo) / dx)
        .collect();
    let eyy = ys
        .iter()
        .map(|y| eyy_lo + (eyy_hi - eyy_lo) * (y - layout.y_lo) / dy)
        .collect();
    // A line of slope s µm/mm is s·1e3 µrad.
    Ok(PsdErrors {
        x_mm: xs,
        y_mm: ys,
        y_s1_mm: ys1,
        z_mm: zs,
        exx_um: exx,
        eyy_um: eyy,
        eyx_um: eyx,
        ezx_um: ezx,
        exy_um: exy,
        ezy_um: ezy,
        exz_um: exz,
        eyz_um: eyz,
        eax_urad,
        eby_urad,
        ec0y_urad: -(s_xy + s_yx) * 1e3,
        eb0z_urad: (s_xz + s_zx) * 1e3,
        ea0z_urad: -(s_yz + s_zy) * 1e3,
        frame: FrameTerms {
            xy_rotation_urad: s_yx * 1e3,
            x_tilt_urad: s_zx * 1e3,
            y_tilt_urad: s_zy * 1e3,
            z_offset_um: c_z,
        },
    })
}

/// The forward field model: what the PSD reads for given errors (the inverse of
/// [`derive_errors`] when the errors respect the gauge of the module documentation).
pub fn simulate_readings(layout: &PsdLayout, e: &PsdErrors) -> PsdReadings {
    let (xs, ys, zs) = (layout.xs(), layout.ys(), layout.zs());
    let n = layout.n_points;
    let at = |v: &Vec<f64>, i: usize| v.get(i).copied().unwrap_or(0.0);
    let f = &e.frame;
    let (s_yx, s_zx, s_zy) = (
        f.xy_rotation_urad * 1e-3,
        f.x_tilt_urad * 1e-3,
        f.y_tilt_urad * 1e-3,
    );
    let s_xy = -e.ec0y_urad * 1e-3 - s_yx;
    let s_xz = e.eb0z_urad * 1e-3 - s_zx;
    let s_yz = -e.ea0z_urad * 1e-3 - s_zy;
    let eby = |i: usize| {
        if i < e.eby_urad.len() {
            e.eby_urad[i] * 1e-3
        } else {
            0.0
        }
    };
    // Ez in the plane at grid indices (ix, iy); the roll of Y is known on S1's points only,
    // and only those points (and iy = 0 for S4) are ever needed.
    let ez = |ix: usize, iy: usize| {
        let (x, y) = (xs[ix], ys[iy]);
        at(&e.ezx_um, ix)
            + at(&e.ezy_um, iy)
            + s_zx * (x - layout.x_lo)
            + s_zy * (y - layout.y_lo)
            + at(&e.eax_urad, ix) * 1e-3 * (y - layout.y_lo)
            - eby(iy) * (x - layout.x_hi)
            + f.z_offset_um
    };
    let ex_plane = |ix: usize, iy: usize| {
        at(&e.exx_um, ix) + at(&e.exy_um, iy) + s_xy * (ys[iy] - layout.y_lo)
    };
    let ey_plane = |ix: usize, iy: usize| {
        at(&e.eyy_um, iy) + at(&e.eyx_um, ix) + s_yx * (xs[ix] - layout.x_lo)
    };
    PsdReadings {
        s1: (0..layout.n_s1)
            .map(|i| [ex_plane(0, i), ez(0, i)])
            .collect(),
        s2: (0..n).map(|i| [ey_plane(i, n - 1), ez(i, n - 1)]).collect(),
        s3: (0..n).map(|i| [ex_plane(n - 1, i), ez(n - 1, i)]).collect(),
        s4: (0..n).map(|i| [ey_plane(i, 0), ez(i, 0)]).collect(),
        s5: (0..n)
            .map(|i| {
                let dz = zs[i] - layout.z0;
                [
                    ex_plane(0, 0) + at(&e.exz_um, i) + s_xz * dz,
                    ey_plane(0, 0) + at(&e.eyz_um, i) + s_yz * dz,
                ]
            })
            .collect(),
    }
}

/// What the PSD reads on a machine described by the rigid-body kinematics (volumetric error
/// components perpendicular to each beam segment, tool point = PSD centre).
pub fn readings_from_machine(
    layout: &PsdLayout,
    machine: &Machine,
    errors: &dyn ErrorSource,
) -> PsdReadings {
    let n = layout.n_points;
    let e = |seg: u8, i: usize| machine.volumetric_error_um(&layout.position(seg, i), errors, None);
    PsdReadings {
        s1: (0..layout.n_s1)
            .map(|i| {
                let v = e(1, i);
                [v.x, v.z]
            })
            .collect(),
        s2: (0..n)
            .map(|i| {
                let v = e(2, i);
                [v.y, v.z]
            })
            .collect(),
        s3: (0..n)
            .map(|i| {
                let v = e(3, i);
                [v.x, v.z]
            })
            .collect(),
        s4: (0..n)
            .map(|i| {
                let v = e(4, i);
                [v.y, v.z]
            })
            .collect(),
        s5: (0..n)
            .map(|i| {
                let v = e(5, i);
                [v.x, v.y]
            })
            .collect(),
    }
}

/// Standard uncertainties of every derived value for independent reading noise `sigma_um`
/// per reading (after reference subtraction: double the single-run variance, paper 003 §5).
/// Exact, because the derivation is linear in the readings.
pub fn derive_uncertainty(layout: &PsdLayout, sigma_um: f64) -> Result<Vec<f64>, PsdError> {
    let zero = PsdReadings::from_vec(layout, &vec![0.0; 2 * (layout.n_s1 + 4 * layout.n_points)]);
    let base = derive_errors(layout, &zero)?.to_vec();
    let n_in = zero.to_vec().len();
    let mut var = vec![0.0; base.len()];
    for k in 0..n_in {
        let mut v = vec![0.0; n_in];
        v[k] = 1.0;
        let out = derive_errors(layout, &PsdReadings::from_vec(layout, &v))?.to_vec();
        for (j, o) in out.iter().enumerate() {
            var[j] += (o - base[j]).powi(2);
        }
    }
    Ok(var.iter().map(|v| v.sqrt() * sigma_um).collect())
}

/// Parse the PSD readings CSV: `run,segment,point,r1_um,r2_um` with `segment` 1..5, `point`
/// 1..n in ascending coordinate, and (r1, r2) = (ex, ez) on S1/S3, (ey, ez) on S2/S4, (ex, ey)
/// on S5. `#` lines are comments. Returns the runs in file order.
/// The most rows a PSD readings file may hold: 20 000 runs of the 51-point frame.
pub const MAX_READING_ROWS: usize = 1_020_000;
/// Largest reading, µm: half the diode's 10 mm.
pub const MAX_READING_UM: f64 = 5000.0;

pub fn parse_readings_csv(
    layout: &PsdLayout,
    text: &str,
) -> Result<Vec<(u32, PsdReadings)>, PsdError> {
    let err = |m: String| PsdError::Csv(m);
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let headers = rdr.headers().map_err(|e| err(e.to_string()))?.clone();
    let idx = |n: &str| {
        headers.iter().position(|h| h == n).ok_or_else(|| {
            err(format!(
                "missing column `{n}` (need run,segment,point,r1_um,r2_um)"
            ))
        })
    };
    let (ir, is, ip, i1, i2) = (
        idx("run")?,
        idx("segment")?,
        idx("point")?,
        idx("r1_um")?,
        idx("r2_um")?,
    );
    // Per run: per segment, per point, the two readings once seen.
    type Slots = Vec<Vec<Option<[f64; 2]>>>;
    let mut runs: Vec<(u32, Slots)> = Vec::new();
    for (line, rec) in rdr.records().enumerate() {
        if line >= MAX_READING_ROWS {
            return Err(err(format!(
                "more than {MAX_READING_ROWS} rows: a frame run has 51 points (split the file by run)"
            )));
        }
        let row = line + 2;
        let rec = rec.map_err(|e| err(e.to_string()))?;
        let get = |i: usize| rec.get(i).unwrap_or("");
        let int = |i: usize, name: &str| -> Result<usize, PsdError> {
            get(i).parse::<usize>().map_err(|_| {
                err(format!(
                    "row {row}: `{name}` = `{}` is not a whole number",
                    get(i)
                ))
            })
        };
        // A reading is a spot position on the 10 mm × 10 mm diode: within ±5000 µm of its
        // centre (a reading of -1e308 overflowed the derived errors to NaN).
        let num = |i: usize, name: &str| -> Result<f64, PsdError> {
            get(i)
                .parse::<f64>()
                .ok()
                .filter(|v| v.abs() <= MAX_READING_UM)
                .ok_or_else(|| {
                    err(format!(
                        "row {row}: `{name}` = `{}` is not a number within ±{MAX_READING_UM} µm (a spot on the 10 mm diode)",
                        get(i)
                    ))
                })
        };
        let run = int(ir, "run")? as u32;
        let seg = int(is, "segment")?;
        let pt = int(ip, "point")?;
        if !(1..=5).contains(&seg) {
            return Err(err(format!("row {row}: segment {seg} is not 1..5")));
        }
        let max = if seg == 1 {
            layout.n_s1
        } else {
            layout.n_points
        };
        if pt == 0 || pt > max {
            return Err(err(format!(
                "row {row}: point {pt} of segment {seg} is not 1..{max}"
            )));
        }
        let val = [num(i1, "r1_um")?, num(i2, "r2_um")?];
        let pos = match runs.iter().position(|(r, _)| *r == run) {
            Some(p) => p,
            None => {
                let segs = (1..=5)
                    .map(|s| vec![None; if s == 1 { layout.n_s1 } else { layout.n_points }])
                    .collect();
                runs.push((run, segs));
                runs.len() - 1
            }
        };
        runs[pos].1[seg - 1][pt - 1] = Some(val);
    }
    let mut out = Vec::new();
    for (run, segs) in runs {
        let mut full = Vec::new();
        for (s, pts) in segs.iter().enumerate() {
            let mut v = Vec::new();
            for (i, p) in pts.iter().enumerate() {
                v.push(p.ok_or_else(|| {
                    err(format!(
                        "run {run}: segment {} point {} is missing",
                        s + 1,
                        i + 1
                    ))
                })?);
            }
            full.push(v);
        }
        let mut it = full.into_iter();
        let mut next = || it.next().unwrap_or_default();
        out.push((
            run,
            PsdReadings {
                s1: next(),
                s2: next(),
                s3: next(),
                s4: next(),
                s5: next(),
            },
        ));
    }
    if out.is_empty() {
        return Err(err("no data rows".into()));
    }
    Ok(out)
}

/// Write readings in the CSV format of [`parse_readings_csv`].
pub fn write_readings_csv(runs: &[(u32, PsdReadings)]) -> String {
    let mut s = String::from("run,segment,point,r1_um,r2_um\n");
    for (run, r) in runs {
        for (seg, pts) in r.segments() {
            for (i, p) in pts.iter().enumerate() {
                s.push_str(&format!("{run},{seg},{},{:.4},{:.4}\n", i + 1, p[0], p[1]));
            }
        }
    }
    s
}
