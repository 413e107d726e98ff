//! A machine tool as a kinematic chain (ISO 10791-6 / ISO 230-7 chain strings such as
//! `WCAYFXZT`), with exact rigid-body transforms and small error displacements at each joint.
//!
//! Conventions (written down because every model in this crate depends on them):
//! - The chain string reads from workpiece `W` to tool `T` through the frame (bed) `F`. Axes
//!   between `W` and `F` carry the workpiece, axes between `F` and `T` carry the tool.
//! - Axis values follow ISO 841: a positive value moves the *tool relative to the workpiece* in
//!   the positive direction. A workpiece-side carriage therefore physically moves by `−q`, a
//!   workpiece-side rotary table turns by `−θ`.
//! - Errors are those of the *relative motion of the tool against the workpiece* (ISO 230-1,
//!   3.4): a positive `EXX` puts the tool further along +X relative to the workpiece, whichever
//!   side carries the X axis. For a workpiece-side component the physical displacement of the
//!   component is the opposite; the code applies that sign, callers never do.
//! - Translations are in µm, rotations in µrad, positions in mm, angles in degrees.
//! - A linear axis link error is the tilt of its direction of travel (squareness, e.g. `EC0Y` is
//!   a rotation of the Y direction about Z) plus a constant offset; the carriage orientation is
//!   not tilted by it. A rotary axis link error is the location (translation of the pivot) and
//!   orientation (tilt of the axis line about the pivot) of the axis (ISO 230-7 `EX0C`, `EA0C`).
//! - Motion errors of a carriage (`δ(q)`, `ε(q)`) act at the carriage's reference point, which
//!   coincides with the chain origin at zero axis positions: the lever arm of an angular error is
//!   the vector from that point to the tool point (Abbe offsets follow from the chain).
//! - The volumetric error is `p_tool − p_work`, actual positions of the tool point and of the
//!   workpiece point nominally under it, in frame (machine) coordinates, in µm.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Errors of machine descriptions.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum KinematicsError {
    /// chain "{0}" must read like "WCAYFXZT": W first, T last, one F, axes X Y Z A B C at most once each
    #[error(
        "chain \"{0}\" must read like \"WCAYFXZT\": W first, T last, one F, axes X Y Z A B C at most once each"
    )]
    BadChain(String),
    /// axis {0} in the machine description is not in the chain
    #[error("axis {0} in the machine description is not in the chain")]
    UnknownAxis(String),
    /// axis {axis}: direction {dir:?} has zero length
    #[error("axis {axis}: direction {dir:?} has zero length")]
    ZeroDirection { axis: String, dir: [f64; 3] },
    /// pose value for axis {0} is not a finite number
    #[error("pose value for axis {0} is not a finite number")]
    NonFinitePose(String),
    /// machine description is not valid TOML: {0}
    #[error("machine description is not valid TOML: {0}")]
    Toml(String),
    /// {what} = {value:?}: every length must be a finite number within ±100000 mm
    #[error(
        "{what} = {value:?}: every length must be a finite number within ±100000 mm (a machine's size)"
    )]
    OutOfRange { what: String, value: [f64; 3] },
}

/// The largest length (mm) a machine description may hold: tool offsets and pivots.
pub const MAX_LENGTH_MM: f64 = 100_000.0;

/// A length triple of a machine description within [`MAX_LENGTH_MM`].
fn check_length(what: impl Fn() -> String, v: [f64; 3]) -> Result<(), KinematicsError> {
    if v.iter().all(|x| x.is_finite() && x.abs() <= MAX_LENGTH_MM) {
        Ok(())
    } else {
        Err(KinematicsError::OutOfRange {
            what: what(),
            value: v,
        })
    }
}

/// One of the six ISO axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum AxisName {
    X,
    Y,
    Z,
    A,
    B,
    C,
}

impl AxisName {
    pub const ALL: [AxisName; 6] = [Self::X, Self::Y, Self::Z, Self::A, Self::B, Self::C];

    pub fn from_char(c: char) -> Option<Self> {
        Some(match c.to_ascii_uppercase() {
            'X' => Self::X,
            'Y' => Self::Y,
            'Z' => Self::Z,
            'A' => Self::A,
            'B' => Self::B,
            'C' => Self::C,
            _ => return None,
        })
    }

    pub fn is_linear(self) -> bool {
        matches!(self, Self::X | Self::Y | Self::Z)
    }

    /// Index 0..6 in `ALL`.
    pub fn index(self) -> usize {
        self as usize
    }

    /// Nominal direction: X, A along x; Y, B along y; Z, C along z.
    pub fn nominal_direction(self) -> Vector3<f64> {
        match self {
            Self::X | Self::A => Vector3::x(),
            Self::Y | Self::B => Vector3::y(),
            Self::Z | Self::C => Vector3::z(),
        }
    }

    pub fn letter(self) -> char {
        ['X', 'Y', 'Z', 'A', 'B', 'C'][self.index()]
    }
}

/// Which branch of the chain carries an axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Side {
    Workpiece,
    Tool,
}

/// One joint of the chain.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    pub axis: AxisName,
    pub side: Side,
    /// Unit direction of travel (linear) or of the rotation axis (rotary), in the parent frame.
    pub direction: Vector3<f64>,
    /// A point on the rotation axis in the parent frame, mm (rotary axes only).
    pub pivot_mm: Vector3<f64>,
}

/// Per-axis settings in a machine description.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisConfig {
    /// Direction of the axis in its parent frame (normalised on load); nominal if absent.
    #[serde(default)]
    pub direction: Option<[f64; 3]>,
    /// A point on a rotary axis, mm, in its parent frame (default: origin).
    #[serde(default)]
    pub pivot_mm: Option<[f64; 3]>,
}

/// A machine description as stored in TOML:
///
/// ```toml
/// chain = "WCAYFXZT"
/// tool_offset_mm = [0.0, 0.0, 0.0]
/// [axes.A]
/// direction = [1.0, 0.0, 0.0]
/// pivot_mm = [0.0, 0.0, 0.0]
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineConfig {
    pub chain: String,
    /// Tool point relative to the last tool-side carriage, mm.
    #[serde(default)]
    pub tool_offset_mm: [f64; 3],
    #[serde(default)]
    pub axes: BTreeMap<String, AxisConfig>,
}

/// A machine: the two branches of its chain, each ordered from the frame outwards.
#[derive(Debug, Clone, PartialEq)]
pub struct Machine {
    pub chain: String,
    /// Frame → … → workpiece.
    pub workpiece_joints: Vec<Joint>,
    /// Frame → … → tool.
    pub tool_joints: Vec<Joint>,
    /// Tool point in the last tool-side carriage frame, mm.
    pub tool_offset_mm: Vector3<f64>,
}

/// Axis positions of one pose (mm and degrees; absent axes are 0).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    #[serde(default)]
    pub a_deg: f64,
    #[serde(default)]
    pub b_deg: f64,
    #[serde(default)]
    pub c_deg: f64,
}

impl Pose {
    pub fn new(x_mm: f64, y_mm: f64, z_mm: f64, a_deg: f64, c_deg: f64) -> Self {
        Self {
            x_mm,
            y_mm,
            z_mm,
            a_deg,
            b_deg: 0.0,
            c_deg,
        }
    }

    pub fn xyz(x_mm: f64, y_mm: f64, z_mm: f64) -> Self {
        Self {
            x_mm,
            y_mm,
            z_mm,
            ..Self::default()
        }
    }

    /// Value of one axis: mm for linear, degrees for rotary.
    pub fn get(&self, axis: AxisName) -> f64 {
        match axis {
            AxisName::X => self.x_mm,
            AxisName::Y => self.y_mm,
            AxisName::Z => self.z_mm,
            AxisName::A => self.a_deg,
            AxisName::B => self.b_deg,
            AxisName::C => self.c_deg,
        }
    }

    pub fn set(&mut self, axis: AxisName, v: f64) {
        match axis {
            AxisName::X => self.x_mm = v,
            AxisName::Y => self.y_mm = v,
            AxisName::Z => self.z_mm = v,
            AxisName::A => self.a_deg = v,
            AxisName::B => self.b_deg = v,
            AxisName::C => self.c_deg = v,
        }
    }

    pub fn check_finite(&self) -> Result<(), KinematicsError> {
        for a in AxisName::ALL {
            if !self.get(a).is_finite() {
                return Err(KinematicsError::NonFinitePose(a.letter().to_string()));
            }
        }
        Ok(())
    }
}

/// A small rigid displacement: rotation vector in µrad, translation in µm.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SmallDisplacement {
    pub rot_urad: Vector3<f64>,
    pub trans_um: Vector3<f64>,
}

impl SmallDisplacement {
    pub const ZERO: Self = Self {
        rot_urad: Vector3::new(0.0, 0.0, 0.0),
        trans_um: Vector3::new(0.0, 0.0, 0.0),
    };

    fn negated(self) -> Self {
        Self {
            rot_urad: -self.rot_urad,
            trans_um: -self.trans_um,
        }
    }

    /// The exact rigid transform (translation then rotation about the local origin), mm.
    fn isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.trans_um * 1e-3),
            UnitQuaternion::from_scaled_axis(self.rot_urad * 1e-6),
        )
    }
}

/// Where the errors of a machine come from. Every method defaults to "no error".
pub trait ErrorSource {
    /// Constant link error of an axis (see the module conventions).
    fn link(&self, _axis: AxisName) -> SmallDisplacement {
        SmallDisplacement::ZERO
    }
    /// Position-dependent motion error of an axis at value `q` (mm or degrees).
    fn motion(&self, _axis: AxisName, _q: f64) -> SmallDisplacement {
        SmallDisplacement::ZERO
    }
    /// Error of the tool point in the last tool carriage frame, µm.
    fn tool_offset_um(&self) -> Vector3<f64> {
        Vector3::zeros()
    }
    /// Error of the workpiece point (e.g. master ball): actual minus nominal position in the
    /// workpiece frame, µm (a physical displacement, unlike the relative-motion errors).
    fn work_point_um(&self) -> Vector3<f64> {
        Vector3::zeros()
    }
}

/// A machine without errors.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoErrors;
impl ErrorSource for NoErrors {}

impl MachineConfig {
    pub fn from_toml(s: &str) -> Result<Self, KinematicsError> {
        toml::from_str(s).map_err(|e| KinematicsError::Toml(e.to_string()))
    }
}

impl Machine {
    /// A machine with nominal axis directions, pivots at the origin and no tool offset.
    pub fn from_chain(chain: &str) -> Result<Self, KinematicsError> {
        Self::from_config(&MachineConfig {
            chain: chain.to_string(),
            tool_offset_mm: [0.0; 3],
            axes: BTreeMap::new(),
        })
    }

    pub fn from_toml(s: &str) -> Result<Self, KinematicsError> {
        Self::from_config(&MachineConfig::from_toml(s)?)
    }

    pub fn from_config(cfg: &MachineConfig) -> Result<Self, KinematicsError> {
        let bad = || KinematicsError::BadChain(cfg.chain.clone());
        check_length(|| "tool_offset_mm".into(), cfg.tool_offset_mm)?;
        let chars: Vec<char> = cfg
            .chain
            .trim()
            .chars()
            .map(|c| c.to_ascii_uppercase())
            .collect();
        if chars.len() < 3 || chars[0] != 'W' || *chars.last().unwrap_or(&' ') != 'T' {
            return Err(bad());
        }
        let inner = &chars[1..chars.len() - 1];
        let f_pos = inner.iter().position(|&c| c == 'F').ok_or_else(bad)?;
        if inner.iter().filter(|&&c| c == 'F').count() != 1 {
            return Err(bad());
        }
        let mut seen = Vec::new();
        let mut make = |c: char, side: Side| -> Result<Joint, KinematicsError> {
            let axis = AxisName::from_char(c).ok_or_else(bad)?;
            if seen.contains(&axis) {
                return Err(bad());
            }
            seen.push(axis);
            let ac = cfg
                .axes
                .get(&axis.letter().to_string())
                .cloned()
                .unwrap_or_default();
            let dir = match ac.direction {
                Some(d) => {
                    let v = Vector3::from(d);
                    if !v.norm().is_finite() || v.norm() <= 1e-12 {
                        return Err(KinematicsError::ZeroDirection {
                            axis: c.to_string(),
                            dir: d,
                        });
                    }
                    v.normalize()
                }
                None => axis.nominal_direction(),
            };
            let pivot = ac.pivot_mm.unwrap_or([0.0; 3]);
            check_length(|| format!("axes.{c}.pivot_mm"), pivot)?;
            Ok(Joint {
                axis,
                side,
                direction: dir,
                pivot_mm: Vector3::from(pivot),
            })
        };
        // Workpiece branch written W..F: reverse it to read frame → workpiece.
        let mut workpiece_joints = Vec::new();
        for &c in inner[..f_pos].iter().rev() {
            workpiece_joints.push(make(c, Side::Workpiece)?);
        }
        let mut tool_joints = Vec::new();
        for &c in &inner[f_pos + 1..] {
            tool_joints.push(make(c, Side::Tool)?);
        }
        for key in cfg.axes.keys() {
            let known = key.chars().count() == 1
                && key
                    .chars()
                    .next()
                    .and_then(AxisName::from_char)
                    .is_some_and(|a| seen.contains(&a));
            if !known {
                return Err(KinematicsError::UnknownAxis(key.clone()));
            }
        }
        Ok(Self {
            chain: chars.iter().collect(),
            workpiece_joints,
            tool_joints,
            tool_offset_mm: Vector3::from(cfg.tool_offset_mm),
        })
    }

    /// The axes of the machine in chain order (workpiece side first).
    pub fn axes(&self) -> Vec<AxisName> {
        self.workpiece_joints
            .iter()
            .rev()
            .chain(self.tool_joints.iter())
            .map(|j| j.axis)
            .collect()
    }

    pub fn joint(&self, axis: AxisName) -> Option<&Joint> {
        self.workpiece_joints
            .iter()
            .chain(self.tool_joints.iter())
            .find(|j| j.axis == axis)
    }

    /// Transform of one joint (parent → child) at value `q`, with its errors.
    pub(crate) fn joint_transform(
        j: &Joint,
        q: f64,
        link: SmallDisplacement,
        motion: SmallDisplacement,
    ) -> Isometry3<f64> {
        // Workpiece side: the component moves opposite to the relative motion (ISO 841), and its
        // physical errors are the opposite of the relative-motion errors (module conventions).
        let (sign, link_d, motion_d) = match j.side {
            Side::Tool => (1.0, link, motion),
            Side::Workpiece => (-1.0, link.negated(), motion.negated()),
        };
        if j.axis.is_linear() {
            // Squareness tilts the direction of travel only; its sign is not flipped because the
            // tilted direction is that of the relative motion.
            let d = j.direction + (link.rot_urad * 1e-6).cross(&j.direction);
            let travel = Translation3::from(d * (sign * q) + link_d.trans_um * 1e-3);
            Isometry3::from_parts(travel, UnitQuaternion::identity()) * motion_d.isometry()
        } else {
            let p = j.pivot_mm;
            let rot = UnitQuaternion::from_scaled_axis(j.direction * (sign * q.to_radians()));
            Isometry3::from_parts(Translation3::from(p), UnitQuaternion::identity())
                * link_d.isometry()
                * Isometry3::from_parts(Translation3::identity(), rot)
                * motion_d.isometry()
                * Isometry3::from_parts(Translation3::from(-p), UnitQuaternion::identity())
        }
    }

    fn branch(joints: &[Joint], pose: &Pose, err: &dyn ErrorSource) -> Isometry3<f64> {
        let mut t = Isometry3::identity();
        for j in joints {
            let q = pose.get(j.axis);
            t *= Self::joint_transform(j, q, err.link(j.axis), err.motion(j.axis, q));
        }
        t
    }

    /// Nominal tool point in frame coordinates, mm.
    pub fn nominal_tool_point_mm(&self, pose: &Pose) -> Vector3<f64> {
        (Self::branch(&self.tool_joints, pose, &NoErrors) * Point3::from(self.tool_offset_mm))
            .coords
    }

    /// Nominal tool point in workpiece coordinates, mm: the workpiece point under the tool.
    pub fn nominal_work_point_mm(&self, pose: &Pose) -> Vector3<f64> {
        let w = Self::branch(&self.workpiece_joints, pose, &NoErrors);
        (w.inverse() * Point3::from(self.nominal_tool_point_mm(pose))).coords
    }

    /// Nominal frame → workpiece transform.
    pub fn nominal_workpiece_frame(&self, pose: &Pose) -> Isometry3<f64> {
        Self::branch(&self.workpiece_joints, pose, &NoErrors)
    }

    /// Volumetric error at a pose, µm: actual tool point minus actual position of `work_point_mm`
    /// (workpiece coordinates; `None` = the point nominally under the tool), frame coordinates.
    pub fn volumetric_error_um(
        &self,
        pose: &Pose,
        err: &dyn ErrorSource,
        work_point_mm: Option<Vector3<f64>>,
    ) -> Vector3<f64> {
        let w_point = work_point_mm.unwrap_or_else(|| self.nominal_work_point_mm(pose));
        let tw = Self::branch(&self.workpiece_joints, pose, err);
        let tt = Self::branch(&self.tool_joints, pose, err);
        let p_tool = tt * Point3::from(self.tool_offset_mm + err.tool_offset_um() * 1e-3);
        let p_work = tw * Point3::from(w_point + err.work_point_um() * 1e-3);
        (p_tool - p_work) * 1e3
    }

    /// Axis values of the linear axes that put the nominal tool point on workpiece point
    /// `work_point_mm`, rotary axes taken from `pose` (exact: the tool point is affine in the
    /// linear axes once the rotary axes are fixed).
    pub fn inverse_linear(&self, pose: &Pose, work_point_mm: Vector3<f64>) -> Pose {
        let lin: Vec<AxisName> = self.axes().into_iter().filter(|a| a.is_linear()).collect();
        let f = |p: &Pose| self.nominal_work_point_mm(p);
        let mut base = *pose;
        for &a in &lin {
            base.set(a, 0.0);
        }
        let p0 = f(&base);
        let mut m = Matrix3::zeros();
        for (k, &a) in lin.iter().enumerate().take(3) {
            let mut p = base;
            p.set(a, 1.0);
            m.set_column(k, &(f(&p) - p0));
        }
        let mut out = base;
        if let Some(inv) = m.try_inverse() {
            let q = inv * (work_point_mm - p0);
            for (k, &a) in lin.iter().enumerate().take(3) {
                out.set(a, q[k]);
            }
        }
        out
    }

    /// World placement (frame coordinates) of the point where each joint's errors act, at the
    /// nominal pose: for joint `i`, the frame just after its nominal motion (linear axes) or at
    /// its pivot before its rotation (rotary axes), plus the parent frame rotation.
    pub(crate) fn joint_frames(&self, pose: &Pose) -> Vec<JointFrame> {
        let mut out = Vec::new();
        for joints in [&self.workpiece_joints, &self.tool_joints] {
            let mut t = Isometry3::identity();
            for j in joints.iter() {
                let q = pose.get(j.axis);
                let parent = t;
                let sign = if j.side == Side::Tool { 1.0 } else { -1.0 };
                let child = parent
                    * Self::joint_transform(j, q, SmallDisplacement::ZERO, SmallDisplacement::ZERO);
                let (link_origin, motion_frame) = if j.axis.is_linear() {
                    (parent.translation.vector, child)
                } else {
                    let pivot = parent * Point3::from(j.pivot_mm);
                    let rot =
                        UnitQuaternion::from_scaled_axis(j.direction * (sign * q.to_radians()));
                    let mf = parent
                        * Isometry3::from_parts(
                            Translation3::from(j.pivot_mm),
                            UnitQuaternion::identity(),
                        )
                        * Isometry3::from_parts(Translation3::identity(), rot);
                    (pivot.coords, mf)
                };
                out.push(JointFrame {
                    axis: j.axis,
                    q,
                    parent_rot: *parent.rotation.to_rotation_matrix().matrix(),
                    link_origin_mm: link_origin,
                    motion_rot: *motion_frame.rotation.to_rotation_matrix().matrix(),
                    motion_origin_mm: motion_frame.translation.vector,
                    direction_parent: j.direction,
                });
                t = child;
            }
        }
        out
    }

    /// Nominal tool frame rotation and workpiece frame rotation.
    pub(crate) fn end_rotations(&self, pose: &Pose) -> (Matrix3<f64>, Matrix3<f64>) {
        let tt = Self::branch(&self.tool_joints, pose, &NoErrors);
        let tw = Self::branch(&self.workpiece_joints, pose, &NoErrors);
        (
            *tt.rotation.to_rotation_matrix().matrix(),
            *tw.rotation.to_rotation_matrix().matrix(),
        )
    }
}

/// Placement of a joint's error frames at a nominal pose (frame coordinates).
#[derive(Debug, Clone)]
pub(crate) struct JointFrame {
    pub axis: AxisName,
    pub q: f64,
    pub parent_rot: Matrix3<f64>,
    pub link_origin_mm: Vector3<f64>,
    pub motion_rot: Matrix3<f64>,
    pub motion_origin_mm: Vector3<f64>,
    pub direction_parent: Vector3<f64>,
}

/// First-order effect on the volumetric error (µm) of a unit link error component of a joint:
/// `k` 0..3 = rotation about x, y, z (per µrad), 3..6 = translation x, y, z (per µm).
/// This is the small-displacement screw of paper 001 moved to the tool point `p_mm`.
pub(crate) fn link_sensitivity(f: &JointFrame, k: usize, p_mm: &Vector3<f64>) -> Vector3<f64> {
    let e = |i: usize| Vector3::ith(i, 1.0);
    if k < 3 {
        let w = f.parent_rot * e(k);
        if f.axis.is_linear() {
            // Tilted direction of travel: the relative motion q·d gains q·(ε × d).
            f.parent_rot * (e(k).cross(&f.direction_parent)) * (f.q * 1e-3)
        } else {
            w.cross(&(p_mm - f.link_origin_mm)) * 1e-3
        }
    } else {
        f.parent_rot * e(k - 3)
    }
}

/// First-order effect (µm) of a unit motion error component of a joint (as in
/// [`link_sensitivity`]), acting at the carriage reference point.
pub(crate) fn motion_sensitivity(f: &JointFrame, k: usize, p_mm: &Vector3<f64>) -> Vector3<f64> {
    let e = |i: usize| Vector3::ith(i, 1.0);
    if k < 3 {
        (f.motion_rot * e(k)).cross(&(p_mm - f.motion_origin_mm)) * 1e-3
    } else {
        f.motion_rot * e(k - 3)
    }
}

/// Rotation matrix helper for tests and the small-angle cross-checks.
pub fn rotation_urad(rot_urad: Vector3<f64>) -> Matrix3<f64> {
    *Rotation3::from_scaled_axis(rot_urad * 1e-6).matrix()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chain_parsing() {
        let m = Machine::from_chain("WCAYFXZT").unwrap();
        let w: Vec<_> = m.workpiece_joints.iter().map(|j| j.axis).collect();
        assert_eq!(w, vec![AxisName::Y, AxisName::A, AxisName::C]);
        let t: Vec<_> = m.tool_joints.iter().map(|j| j.axis).collect();
        assert_eq!(t, vec![AxisName::X, AxisName::Z]);
        assert!(Machine::from_chain("WCAYXZT").is_err());
        assert!(Machine::from_chain("WXXFZT").is_err());
        assert!(Machine::from_chain("CAYFXZT").is_err());
    }

    #[test]
    fn nominal_tool_follows_axis_values() {
        // ISO 841: the tool moves +q relative to the workpiece whichever side carries the axis.
        let m = Machine::from_chain("WYFXZT").unwrap();
        let p = m.nominal_work_point_mm(&Pose::xyz(10.0, 20.0, 30.0));
        assert!((p - Vector3::new(10.0, 20.0, 30.0)).norm() < 1e-12);
    }

    #[test]
    fn positioning_error_sign_is_relative_motion() {
        struct Exx;
        impl ErrorSource for Exx {
            fn motion(&self, a: AxisName, _q: f64) -> SmallDisplacement {
                if a == AxisName::Y {
                    SmallDisplacement {
                        rot_urad: Vector3::zeros(),
                        trans_um: Vector3::new(0.0, 5.0, 0.0),
                    }
                } else {
                    SmallDisplacement::ZERO
                }
            }
        }
        for chain in ["WYFXZT", "WFXYZT"] {
            let m = Machine::from_chain(chain).unwrap();
            let e = m.volumetric_error_um(&Pose::xyz(1.0, 2.0, 3.0), &Exx, None);
            assert!(
                (e - Vector3::new(0.0, 5.0, 0.0)).norm() < 1e-9,
                "{chain}: {e}"
            );
        }
    }
}
