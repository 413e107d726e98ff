//! CapBall: link errors of a five-axis machine (paper 001, Andolfatto, Mayer et al.).
//!
//! The machine holds the nominal tool point on the centre of a master ball on the table while
//! A and C turn; three capacitive sensors in the spindle read the volumetric error
//! `ΔE = p_tool − p_ball` (machine frame, µm). The model is linear in 14 parameters
//! (`ΔE_i = J(pose_i) · p`, paper eq. 1–4), solved with the pseudo-inverse (eq. 5).
//!
//! # The 14 parameters (a choice the paper leaves open; its Table 1 is not in our copy)
//!
//! For the `WCAYFXZT` machine (C table on an A trunnion on Y; X and Z carry the spindle), with
//! one ball and constant tool orientation, many link errors are confounded with the setup
//! errors: a translation of the A axis along Y or Z is a combination of the tool offset, the
//! ball position and `EY0C`; `EX0C` equals `tool_x − ball_x` when A runs along X; the zero
//! offsets `EA0A`, `EC0C` and the translation along an axis's own line are invisible or
//! confounded too. What stays identifiable, and what we identify (paper 001 names them the
//! link errors):
//!
//! | parameter | meaning | unit |
//! |---|---|---|
//! | `EC0Y` | squareness of Y to X (rotation of the Y direction about Z) | µrad |
//! | `EB0Z` | squareness of Z to X (rotation of the Z direction about Y) | µrad |
//! | `EA0Z` | squareness of Z to Y (rotation of the Z direction about X) | µrad |
//! | `EB0A`, `EC0A` | orientation of the A axis line about Y and Z | µrad |
//! | `EA0C`, `EB0C` | orientation of the C axis line about X and Y (relative to A) | µrad |
//! | `EY0C` | offset of the C axis line from the A axis along Y | µm |
//!
//! and the six setup errors: ball centre (actual − nominal, table frame) and tool point
//! (actual − nominal, spindle frame), µm. Sign conventions are those of [`crate::kinematics`]
//! (errors of the relative motion of the tool against the workpiece).
//!
//! The identification Jacobian is analytic (small-displacement screws moved to the tool point,
//! [`CapballSetup::jacobian`]); tests check it against a numerical derivative of the exact
//! forward kinematics ([`CapballSetup::jacobian_numeric`]).

use nalgebra::{DMatrix, DVector, Matrix3, Matrix4, SMatrix, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use crate::kinematics::{
    AxisConfig, AxisName, ErrorSource, KinematicsError, Machine, MachineConfig, Pose,
    SmallDisplacement, link_sensitivity,
};

/// Number of identified parameters (8 link + 6 setup).
pub const N_PARAMS: usize = 14;

/// Names of the parameters, in the order of the parameter vector.
pub const PARAM_NAMES: [&str; N_PARAMS] = [
    "EC0Y_urad",
    "EB0Z_urad",
    "EA0Z_urad",
    "EB0A_urad",
    "EC0A_urad",
    "EA0C_urad",
    "EB0C_urad",
    "EY0C_um",
    "ball_x_um",
    "ball_y_um",
    "ball_z_um",
    "tool_x_um",
    "tool_y_um",
    "tool_z_um",
];

/// Errors of CapBall identification and calibration.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CapballError {
    /// {n} poses give {eq} equations for {need} parameters: measure more poses
    #[error("{n} poses give {eq} equations for {need} parameters: measure more poses")]
    TooFewPoses { n: usize, eq: usize, need: usize },
    /// {poses} poses but {values} measured values: every pose needs one (ex, ey, ez)
    #[error("{poses} poses but {values} measured values: every pose needs one (ex, ey, ez)")]
    LengthMismatch { poses: usize, values: usize },
    /// pose {index}: a position or measured value is not a finite number
    #[error("pose {index}: a position or measured value is not a finite number")]
    NonFinite { index: usize },
    /// the trajectory does not excite every parameter (condition number {condition:.3e}); the least determined is {worst}: sweep A and C over wider ranges
    #[error(
        "the trajectory does not excite every parameter (condition number {condition:.3e}); the least determined is {worst}: sweep A and C over wider ranges"
    )]
    Singular { condition: f64, worst: String },
    /// pose {index}: volumetric error of {value_um:.0} µm is implausible for a CapBall (range about ±1000 µm): are the values in µm?
    #[error(
        "pose {index}: volumetric error of {value_um:.0} µm is implausible for a CapBall (range about ±1000 µm): are the values in µm?"
    )]
    Implausible { index: usize, value_um: f64 },
    /// the poses do not keep the tool on one ball position (spread {spread_mm:.3} mm): check the machine description (chain, pivots) or the pose columns
    #[error(
        "the poses do not keep the tool on one ball position (spread {spread_mm:.3} mm): check the machine description (chain, pivots) or the pose columns"
    )]
    NotOnBall { spread_mm: f64 },
    /// the sensor-frame calibration needs at least 4 non-coplanar points, got {0}
    #[error("the sensor-frame calibration needs at least 4 non-coplanar points, got {0}")]
    CalibrationPoints(usize),
    /// machine description: {0}
    #[error("machine description: {0}")]
    Machine(#[from] KinematicsError),
    /// CapBall dataset: {0}
    #[error("CapBall dataset: {0}")]
    Dataset(String),
    /// the {0} cannot be decomposed (values far outside a machine's range make the SVD diverge): check the dataset's poses and values
    #[error(
        "the {0} cannot be decomposed (values far outside a machine's range make the SVD diverge): check the dataset's poses and values"
    )]
    Undecomposable(&'static str),
}

/// The eight link errors (see the module table).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct LinkErrors {
    pub ec0y_urad: f64,
    pub eb0z_urad: f64,
    pub ea0z_urad: f64,
    pub eb0a_urad: f64,
    pub ec0a_urad: f64,
    pub ea0c_urad: f64,
    pub eb0c_urad: f64,
    pub ey0c_um: f64,
}

/// The six setup errors: ball centre (table frame) and tool point (spindle frame), µm.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SetupErrors {
    pub ball_x_um: f64,
    pub ball_y_um: f64,
    pub ball_z_um: f64,
    pub tool_x_um: f64,
    pub tool_y_um: f64,
    pub tool_z_um: f64,
}

/// Link and setup errors together, as a parameter vector and an [`ErrorSource`].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct CapballErrors {
    pub link: LinkErrors,
    pub setup: SetupErrors,
}

impl CapballErrors {
    pub fn to_vector(&self) -> [f64; N_PARAMS] {
        let l = &self.link;
        let s = &self.setup;
        [
            l.ec0y_urad,
            l.eb0z_urad,
            l.ea0z_urad,
            l.eb0a_urad,
            l.ec0a_urad,
            l.ea0c_urad,
            l.eb0c_urad,
            l.ey0c_um,
            s.ball_x_um,
            s.ball_y_um,
            s.ball_z_um,
            s.tool_x_um,
            s.tool_y_um,
            s.tool_z_um,
        ]
    }

    pub fn from_slice(p: &[f64]) -> Self {
        let g = |i: usize| p.get(i).copied().unwrap_or(0.0);
        Self {
            link: LinkErrors {
                ec0y_urad: g(0),
                eb0z_urad: g(1),
                ea0z_urad: g(2),
                eb0a_urad: g(3),
                ec0a_urad: g(4),
                ea0c_urad: g(5),
                eb0c_urad: g(6),
                ey0c_um: g(7),
            },
            setup: SetupErrors {
                ball_x_um: g(8),
                ball_y_um: g(9),
                ball_z_um: g(10),
                tool_x_um: g(11),
                tool_y_um: g(12),
                tool_z_um: g(13),
            },
        }
    }
}

impl ErrorSource for CapballErrors {
    fn link(&self, axis: AxisName) -> SmallDisplacement {
        let l = &self.link;
        let (rot, trans) = match axis {
            AxisName::Y => (Vector3::new(0.0, 0.0, l.ec0y_urad), Vector3::zeros()),
            AxisName::Z => (
                Vector3::new(l.ea0z_urad, l.eb0z_urad, 0.0),
                Vector3::zeros(),
            ),
            AxisName::A => (
                Vector3::new(0.0, l.eb0a_urad, l.ec0a_urad),
                Vector3::zeros(),
            ),
            AxisName::C => (
                Vector3::new(l.ea0c_urad, l.eb0c_urad, 0.0),
                Vector3::new(0.0, l.ey0c_um, 0.0),
            ),
            _ => (Vector3::zeros(), Vector3::zeros()),
        };
        SmallDisplacement {
            rot_urad: rot,
            trans_um: trans,
        }
    }
    fn tool_offset_um(&self) -> Vector3<f64> {
        Vector3::new(
            self.setup.tool_x_um,
            self.setup.tool_y_um,
            self.setup.tool_z_um,
        )
    }
    fn work_point_um(&self) -> Vector3<f64> {
        Vector3::new(
            self.setup.ball_x_um,
            self.setup.ball_y_um,
            self.setup.ball_z_um,
        )
    }
}

/// A five-axis machine with a master ball: the geometry the CapBall model needs.
#[derive(Debug, Clone, PartialEq)]
pub struct CapballSetup {
    pub machine: Machine,
    /// Nominal ball centre in the table (workpiece) frame, mm.
    pub ball_mm: Vector3<f64>,
}

/// Where each parameter enters the chain: (axis, component 0..6 of the link displacement).
const LINK_SLOTS: [(AxisName, usize); 8] = [
    (AxisName::Y, 2),
    (AxisName::Z, 1),
    (AxisName::Z, 0),
    (AxisName::A, 1),
    (AxisName::A, 2),
    (AxisName::C, 0),
    (AxisName::C, 1),
    (AxisName::C, 4),
];

/// Result of an identification.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Identification {
    pub errors: CapballErrors,
    /// Parameter vector in the order of [`PARAM_NAMES`].
    pub params: Vec<f64>,
    /// Standard uncertainties `sqrt(diag(cov))`, same units.
    pub std_uncertainty: Vec<f64>,
    /// Parameter covariance `s² (JᵀJ)⁻¹`, row-major 14×14.
    pub covariance: Vec<Vec<f64>>,
    /// Condition number of the identification Jacobian (columns in µm/µm and µm/µrad).
    pub condition_number: f64,
    /// RMS of the residuals in X, Y, Z, µm.
    pub residual_rms_um: [f64; 3],
    /// Residual standard deviation `s = sqrt(RSS / (3n − 14))`, µm.
    pub residual_sigma_um: f64,
    pub n_poses: usize,
    pub dof: usize,
    /// Residuals per pose (measured − model), µm.
    #[serde(skip)]
    pub residuals_um: Vec<[f64; 3]>,
}

/// A validation residual larger than white noise at the identification's level explains: the
/// ratio of mean squares (validation over identification) beyond 5 standard deviations of its
/// spread under white noise, `2/n_val + 2/dof` (equations counted per channel). See
/// [`Identification::validation_excess`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValidationExcess {
    /// Validation residual RMS over the three channels, µm.
    pub validation_rms_um: f64,
    /// The identification's residual standard deviation `s`, µm.
    pub identification_sigma_um: f64,
    /// Ratio of the mean squares, validation over identification.
    pub ratio: f64,
    /// The largest ratio white noise explains (1 + 5 standard deviations of the ratio).
    pub bound: f64,
}

impl Identification {
    /// Whether the residual RMS of `n_val_poses` validation poses (`val_rms_um`, per channel)
    /// exceeds what white noise of this identification's level explains: `Some` when the
    /// ratio of mean squares passes its 5σ bound; `None` when it does not, or when there is no
    /// residual level or no validation pose to compare.
    pub fn validation_excess(
        &self,
        val_rms_um: &[f64; 3],
        n_val_poses: usize,
    ) -> Option<ValidationExcess> {
        let s2 = self.residual_sigma_um.powi(2);
        let n_val = 3 * n_val_poses;
        if s2 <= 0.0 || n_val == 0 {
            return None;
        }
        let v2 = val_rms_um.iter().map(|v| v * v).sum::<f64>() / 3.0;
        let ratio = v2 / s2;
        let bound = 1.0 + 5.0 * (2.0 / n_val as f64 + 2.0 / self.dof.max(1) as f64).sqrt();
        (ratio > bound).then(|| ValidationExcess {
            validation_rms_um: v2.sqrt(),
            identification_sigma_um: s2.sqrt(),
            ratio,
            bound,
        })
    }
}

/// An identification trajectory: A and C sweep together (a spiral over the sphere of the ball).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TrajectorySpec {
    pub n_poses: usize,
    pub a_start_deg: f64,
    pub a_end_deg: f64,
    /// Number of C revolutions over the trajectory.
    pub c_turns: f64,
}

impl Default for TrajectorySpec {
    /// The scale of paper 001: 807 poses.
    fn default() -> Self {
        Self {
            n_poses: 807,
            a_start_deg: 0.0,
            a_end_deg: -90.0,
            c_turns: 6.0,
        }
    }
}

impl TrajectorySpec {
    /// The validation trajectory of paper 001: the same sweep with A running the other way.
    pub fn reversed_a(&self) -> Self {
        Self {
            a_start_deg: self.a_end_deg,
            a_end_deg: self.a_start_deg,
            ..*self
        }
    }
}

impl CapballSetup {
    /// The `WCAYFXZT` machine of paper 001 with A along X, C along Z, both through the
    /// origin, and a ball at (120, 80, 100) mm on the table (our choice; the paper does not
    /// give its ball position).
    pub fn paper_default() -> Self {
        let machine =
            Machine::from_chain("WCAYFXZT").unwrap_or_else(|_| unreachable!("fixed chain"));
        Self {
            machine,
            ball_mm: Vector3::new(120.0, 80.0, 100.0),
        }
    }

    /// A setup from a machine description (TOML) and a ball position.
    pub fn new(cfg: &MachineConfig, ball_mm: Vector3<f64>) -> Result<Self, CapballError> {
        let machine = Machine::from_config(cfg)?;
        for a in [
            AxisName::X,
            AxisName::Y,
            AxisName::Z,
            AxisName::A,
            AxisName::C,
        ] {
            if machine.joint(a).is_none() {
                return Err(CapballError::Machine(KinematicsError::BadChain(format!(
                    "{} (the CapBall model needs axes X, Y, Z, A and C)",
                    machine.chain
                ))));
            }
        }
        Ok(Self { machine, ball_mm })
    }

    /// The machine description of [`Self::paper_default`], as a config.
    pub fn paper_machine_config() -> MachineConfig {
        let mut axes = std::collections::BTreeMap::new();
        axes.insert(
            "A".into(),
            AxisConfig {
                direction: Some([1.0, 0.0, 0.0]),
                pivot_mm: Some([0.0; 3]),
            },
        );
        axes.insert(
            "C".into(),
            AxisConfig {
                direction: Some([0.0, 0.0, 1.0]),
                pivot_mm: Some([0.0; 3]),
            },
        );
        MachineConfig {
            chain: "WCAYFXZT".into(),
            tool_offset_mm: [0.0; 3],
            axes,
        }
    }

    /// Find the ball from the poses (the table point under the tool), checking that every
    /// pose holds the tool on the same point within 10 µm.
    pub fn with_ball_from_poses(machine: Machine, poses: &[Pose]) -> Result<Self, CapballError> {
        if poses.is_empty() {
            return Err(CapballError::TooFewPoses {
                n: 0,
                eq: 0,
                need: N_PARAMS,
            });
        }
        let pts: Vec<Vector3<f64>> = poses
            .iter()
            .map(|p| machine.nominal_work_point_mm(p))
            .collect();
        let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
        let spread = pts.iter().map(|p| (p - mean).norm()).fold(0.0, f64::max);
        if spread.is_nan() || spread > 0.01 {
            return Err(CapballError::NotOnBall { spread_mm: spread });
        }
        Ok(Self {
            machine,
            ball_mm: mean,
        })
    }

    /// The pose that holds the nominal tool point on the ball at angles `a_deg`, `c_deg`.
    pub fn pose_for(&self, a_deg: f64, c_deg: f64) -> Pose {
        let p = Pose {
            a_deg,
            c_deg,
            ..Pose::default()
        };
        self.machine.inverse_linear(&p, self.ball_mm)
    }

    /// Identification trajectory: A runs linearly from start to end while C turns `c_turns`
    /// revolutions, X/Y/Z keep the tool on the ball.
    pub fn trajectory(&self, spec: &TrajectorySpec) -> Vec<Pose> {
        let n = spec.n_poses.max(1);
        (0..n)
            .map(|i| {
                let t = if n > 1 {
                    i as f64 / (n - 1) as f64
                } else {
                    0.0
                };
                let a = spec.a_start_deg + (spec.a_end_deg - spec.a_start_deg) * t;
                let c = (360.0 * spec.c_turns * t).rem_euclid(360.0);
                self.pose_for(a, c)
            })
            .collect()
    }

    /// What the CapBall reads at a pose (exact rigid-body forward model), µm, machine frame.
    /// This is the model the simulator uses.
    pub fn volumetric_error_um(&self, errors: &CapballErrors, pose: &Pose) -> Vector3<f64> {
        self.machine
            .volumetric_error_um(pose, errors, Some(self.ball_mm))
    }

    /// Analytic identification Jacobian at a pose (3 × 14): each column is the small
    /// displacement screw of one parameter moved to the tool point (paper 001, eq. 1).
    pub fn jacobian(&self, pose: &Pose) -> SMatrix<f64, 3, N_PARAMS> {
        let frames = self.machine.joint_frames(pose);
        let p = self.machine.nominal_tool_point_mm(pose);
        let (r_tool, r_work) = self.machine.end_rotations(pose);
        let mut j = SMatrix::<f64, 3, N_PARAMS>::zeros();
        for (col, (axis, k)) in LINK_SLOTS.iter().enumerate() {
            if let Some(f) = frames.iter().find(|f| f.axis == *axis) {
                j.set_column(col, &link_sensitivity(f, *k, &p));
            }
        }
        // Ball displaced by +δ in the table frame lowers p_tool − p_ball.
        j.fixed_view_mut::<3, 3>(0, 8).copy_from(&(-r_work));
        j.fixed_view_mut::<3, 3>(0, 11).copy_from(&r_tool);
        j
    }

    /// Numerical Jacobian of the exact forward model (central differences, 1 µm / 1 µrad).
    pub fn jacobian_numeric(&self, pose: &Pose) -> SMatrix<f64, 3, N_PARAMS> {
        let mut j = SMatrix::<f64, 3, N_PARAMS>::zeros();
        let h = 1.0;
        for k in 0..N_PARAMS {
            let mut plus = [0.0; N_PARAMS];
            plus[k] = h;
            let mut minus = [0.0; N_PARAMS];
            minus[k] = -h;
            let ep = self.volumetric_error_um(&CapballErrors::from_slice(&plus), pose);
            let em = self.volumetric_error_um(&CapballErrors::from_slice(&minus), pose);
            j.set_column(k, &((ep - em) / (2.0 * h)));
        }
        j
    }

    /// The stacked identification Jacobian (3n × 14) of a trajectory.
    pub fn stacked_jacobian(&self, poses: &[Pose]) -> DMatrix<f64> {
        let mut j = DMatrix::zeros(3 * poses.len(), N_PARAMS);
        for (i, p) in poses.iter().enumerate() {
            j.view_mut((3 * i, 0), (3, N_PARAMS))
                .copy_from(&self.jacobian(p));
        }
        j
    }

    /// Condition number of a trajectory's identification Jacobian.
    pub fn condition_number(&self, poses: &[Pose]) -> f64 {
        let sv = self.stacked_jacobian(poses).singular_values();
        let max = sv.max();
        let min = sv.min();
        if min > 0.0 { max / min } else { f64::INFINITY }
    }

    /// Least-squares identification of the 14 parameters (paper 001, eq. 5) with covariance.
    pub fn identify(
        &self,
        poses: &[Pose],
        measured_um: &[[f64; 3]],
    ) -> Result<Identification, CapballError> {
        let n = poses.len();
        if measured_um.len() != n {
            return Err(CapballError::LengthMismatch {
                poses: n,
                values: measured_um.len(),
            });
        }
        // One more equation than parameters, so that a residual variance exists.
        if 3 * n <= N_PARAMS {
            return Err(CapballError::TooFewPoses {
                n,
                eq: 3 * n,
                need: N_PARAMS,
            });
        }
        for (i, (p, m)) in poses.iter().zip(measured_um).enumerate() {
            if p.check_finite().is_err() || m.iter().any(|v| !v.is_finite()) {
                return Err(CapballError::NonFinite { index: i + 1 });
            }
            if let Some(v) = m.iter().copied().find(|v| v.abs() > 5000.0) {
                return Err(CapballError::Implausible {
                    index: i + 1,
                    value_um: v,
                });
            }
        }
        let j = self.stacked_jacobian(poses);
        let b = DVector::from_iterator(3 * n, measured_um.iter().flat_map(|m| m.iter().copied()));
        // Thin QR first: the SVD then works on a 14 × 14 matrix (the 807-pose budget is 5 ms).
        let qr = j.clone().qr();
        let r = qr.r();
        let mut qtb = b.clone();
        qr.q_tr_mul(&mut qtb);
        let qtb14 = qtb.rows(0, N_PARAMS).into_owned();
        let svd = crate::linalg::svd(r, true, true)
            .ok_or(CapballError::Undecomposable("identification Jacobian"))?;
        let (Some(u), Some(vt)) = (svd.u.as_ref(), svd.v_t.as_ref()) else {
            return Err(CapballError::Singular {
                condition: f64::INFINITY,
                worst: "?".into(),
            });
        };
        let sv = &svd.singular_values;
        let (mut imax, mut imin) = (0, 0);
        for i in 0..sv.len() {
            if sv[i] > sv[imax] {
                imax = i;
            }
            if sv[i] < sv[imin] {
                imin = i;
            }
        }
        let condition = if sv[imin] > 0.0 {
            sv[imax] / sv[imin]
        } else {
            f64::INFINITY
        };
        if condition.is_nan() || condition >= 1e8 {
            let v = vt.row(imin);
            let worst = (0..N_PARAMS)
                .max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()))
                .map(|k| PARAM_NAMES[k].to_string())
                .unwrap_or_default();
            return Err(CapballError::Singular { condition, worst });
        }
        let uty = u.transpose() * qtb14;
        let mut s_inv_uty = uty.clone();
        for i in 0..N_PARAMS {
            s_inv_uty[i] /= sv[i];
        }
        let p = vt.transpose() * s_inv_uty;
        let resid = &b - &j * &p;
        let dof = 3 * n - N_PARAMS;
        let rss = resid.norm_squared();
        let s2 = rss / dof as f64;
        let mut vs = vt.transpose();
        for i in 0..N_PARAMS {
            let f = 1.0 / sv[i];
            vs.column_mut(i).scale_mut(f);
        }
        let cov = (&vs * vs.transpose()) * s2;
        let mut rms = [0.0; 3];
        let mut residuals = Vec::with_capacity(n);
        for i in 0..n {
            let r3 = [resid[3 * i], resid[3 * i + 1], resid[3 * i + 2]];
            for k in 0..3 {
                rms[k] += r3[k] * r3[k];
            }
            residuals.push(r3);
        }
        for v in &mut rms {
            *v = (*v / n as f64).sqrt();
        }
        let params: Vec<f64> = p.iter().copied().collect();
        Ok(Identification {
            errors: CapballErrors::from_slice(&params),
            std_uncertainty: (0..N_PARAMS).map(|i| cov[(i, i)].max(0.0).sqrt()).collect(),
            covariance: (0..N_PARAMS)
                .map(|i| (0..N_PARAMS).map(|k| cov[(i, k)]).collect())
                .collect(),
            params,
            condition_number: condition,
            residual_rms_um: rms,
            residual_sigma_um: s2.sqrt(),
            n_poses: n,
            dof,
            residuals_um: residuals,
        })
    }

    /// RMS per direction of `measured − model(identified)` on another trajectory (validation).
    pub fn validation_rms_um(
        &self,
        ident: &Identification,
        poses: &[Pose],
        measured_um: &[[f64; 3]],
    ) -> Result<[f64; 3], CapballError> {
        if measured_um.len() != poses.len() {
            return Err(CapballError::LengthMismatch {
                poses: poses.len(),
                values: measured_um.len(),
            });
        }
        if poses.is_empty() {
            return Err(CapballError::TooFewPoses {
                n: 0,
                eq: 0,
                need: 1,
            });
        }
        let p = DVector::from_column_slice(&ident.params);
        let mut rms = [0.0; 3];
        for (i, (pose, m)) in poses.iter().zip(measured_um).enumerate() {
            if pose.check_finite().is_err() || m.iter().any(|v| !v.is_finite()) {
                return Err(CapballError::NonFinite { index: i + 1 });
            }
            let model = self.jacobian(pose) * &p;
            for k in 0..3 {
                rms[k] += (m[k] - model[k]).powi(2);
            }
        }
        for v in &mut rms {
            *v = (*v / poses.len() as f64).sqrt();
        }
        Ok(rms)
    }
}

/// The forward model of [`CapballSetup::paper_default`]: link and setup errors plus a pose
/// (x, y, z in mm, a, c in degrees) → volumetric error (ex, ey, ez) in µm. What `sim/` calls.
pub fn forward_um(link: &LinkErrors, setup: &SetupErrors, pose: &Pose) -> [f64; 3] {
    let e = CapballSetup::paper_default().volumetric_error_um(
        &CapballErrors {
            link: *link,
            setup: *setup,
        },
        pose,
    );
    [e.x, e.y, e.z]
}

/// Identification on the machine of [`CapballSetup::paper_default`] (for the uncertainty
/// evaluation, which pushes virtual measurements through it).
pub fn identify(poses: &[Pose], measured_um: &[[f64; 3]]) -> Result<Identification, CapballError> {
    CapballSetup::paper_default().identify(poses, measured_um)
}

// ---------------------------------------------------------------------------------------------
// Sensor frame (paper 001, section 2.3): T = M S⁺ over a 5×5×5 cube of programmed moves.

/// Result of the sensor-frame calibration (the quantities of paper 001, Table 2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorFrame {
    /// The 4×4 transform, row-major: machine displacement = T · [sensor readings; 1].
    pub t: [[f64; 4]; 4],
    /// Norms of the three sensor columns `t_i` (1 for perfect gains).
    pub gains: [f64; 3],
    /// Gain deviations from 1, percent.
    pub gain_error_pct: [f64; 3],
    /// Non-orthogonality: `t_1·t_2`, `t_1·t_3`, `t_2·t_3` of the normalised columns, µrad
    /// (the cosine of the angle between sensor directions; 0 for orthogonal sensors).
    pub non_orthogonality_urad: [f64; 3],
    /// Offsets (last column), µm.
    pub offsets_um: [f64; 3],
    /// Last row of T (ideally 0 0 0 1).
    pub last_row: [f64; 4],
    /// RMS of `T·S − M` over the points, µm.
    pub residual_rms_um: f64,
    pub n_points: usize,
}

impl SensorFrame {
    pub fn matrix(&self) -> Matrix4<f64> {
        Matrix4::from_fn(|i, k| self.t[i][k])
    }

    /// Sensor readings → machine-frame displacement, µm.
    pub fn apply(&self, readings_um: &Vector3<f64>) -> Vector3<f64> {
        let v = self.matrix() * Vector4::new(readings_um.x, readings_um.y, readings_um.z, 1.0);
        Vector3::new(v.x, v.y, v.z)
    }
}

/// The programmed points of the calibration cube: `n`³ points spaced evenly in
/// `[−half_width, +half_width]` per axis, µm (paper 001: n = 5, 125 points).
pub fn cube_points_um(half_width_um: f64, n: usize) -> Vec<Vector3<f64>> {
    let n = n.max(2);
    let step = 2.0 * half_width_um / (n - 1) as f64;
    let mut out = Vec::with_capacity(n * n * n);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                out.push(Vector3::new(
                    -half_width_um + i as f64 * step,
                    -half_width_um + j as f64 * step,
                    -half_width_um + k as f64 * step,
                ));
            }
        }
    }
    out
}

/// Sensor-frame calibration: `T = M S⁺` (paper 001, eq. 8), M the programmed displacements
/// and S the sensor readings, both µm, in homogeneous coordinates.
pub fn calibrate_sensor_frame(
    programmed_um: &[Vector3<f64>],
    readings_um: &[Vector3<f64>],
) -> Result<SensorFrame, CapballError> {
    let n = programmed_um.len();
    if readings_um.len() != n {
        return Err(CapballError::LengthMismatch {
            poses: n,
            values: readings_um.len(),
        });
    }
    if n < 4 {
        return Err(CapballError::CalibrationPoints(n));
    }
    for (i, (m, s)) in programmed_um.iter().zip(readings_um).enumerate() {
        if m.iter().chain(s.iter()).any(|v| !v.is_finite()) {
            return Err(CapballError::NonFinite { index: i + 1 });
        }
    }
    let hm = DMatrix::from_fn(4, n, |r, c| if r < 3 { programmed_um[c][r] } else { 1.0 });
    let hs = DMatrix::from_fn(4, n, |r, c| if r < 3 { readings_um[c][r] } else { 1.0 });
    let svd = crate::linalg::svd(hs.clone(), true, true)
        .ok_or(CapballError::Undecomposable("sensor readings' matrix"))?;
    let (sv_min, sv_max) = (svd.singular_values.min(), svd.singular_values.max());
    if sv_min <= sv_max * 1e-10 {
        return Err(CapballError::CalibrationPoints(n));
    }
    let pinv = svd
        .pseudo_inverse(sv_max * 1e-12)
        .map_err(|_| CapballError::CalibrationPoints(n))?;
    let t = &hm * pinv;
    let t4 = Matrix4::from_fn(|i, k| t[(i, k)]);
    let cols: Vec<Vector3<f64>> = (0..3)
        .map(|k| Vector3::new(t4[(0, k)], t4[(1, k)], t4[(2, k)]))
        .collect();
    let gains = [cols[0].norm(), cols[1].norm(), cols[2].norm()];
    let u: Vec<Vector3<f64>> = cols.iter().map(|c| c / c.norm()).collect();
    let resid = &t * &hs - &hm;
    let rms = (resid.rows(0, 3).norm_squared() / (3 * n) as f64).sqrt();
    Ok(SensorFrame {
        t: std::array::from_fn(|i| std::array::from_fn(|k| t4[(i, k)])),
        gains,
        gain_error_pct: gains.map(|g| (g - 1.0) * 100.0),
        non_orthogonality_urad: [
            u[0].dot(&u[1]) * 1e6,
            u[0].dot(&u[2]) * 1e6,
            u[1].dot(&u[2]) * 1e6,
        ],
        offsets_um: [t4[(0, 3)], t4[(1, 3)], t4[(2, 3)]],
        last_row: [t4[(3, 0)], t4[(3, 1)], t4[(3, 2)], t4[(3, 3)]],
        residual_rms_um: rms,
        n_points: n,
    })
}

/// What the three sensors read for a machine-frame displacement `m_um`, given the true sensor
/// directions as the columns of `directions` (gains included) and offsets: `m = D s + o`, so
/// `s = D⁻¹ (m − o)`. For simulation of the calibration cube.
pub fn sensor_readings_um(
    directions: &Matrix3<f64>,
    offsets_um: &Vector3<f64>,
    m_um: &Vector3<f64>,
) -> Vector3<f64> {
    directions
        .try_inverse()
        .map(|inv| inv * (m_um - offsets_um))
        .unwrap_or_else(Vector3::zeros)
}

// ---------------------------------------------------------------------------------------------
// Datasets (docs/datasets.md): `run,pose,time_s,x_mm,y_mm,z_mm,a_deg,c_deg,ex_um,ey_um,ez_um`.

/// One row of a CapBall dataset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CapballRecord {
    pub run: u32,
    pub pose_index: u32,
    pub time_s: Option<f64>,
    pub pose: Pose,
    pub e_um: [f64; 3],
}

/// The physical range of a CapBall dataset column: past it a number is a damaged file or a
/// unit mistake (an angle of 10¹⁶⁰° made the identification's SVD loop forever).
fn dataset_range(name: &str) -> (f64, f64, &'static str) {
    match name {
        "a_deg" | "c_deg" => (
            -1e5,
            1e5,
            "an axis angle in degrees (±10⁵°, some 280 turns)",
        ),
        "ex_um" | "ey_um" | "ez_um" => (-1e5, 1e5, "a volumetric error in µm (±100 mm)"),
        "time_s" => (-1e9, 1e9, "a time since the start (±30 years)"),
        _ => (-1e6, 1e6, "a machine position in mm (±1 km)"),
    }
}

/// Parse a CapBall dataset (CSV text). Lines starting with `#` are comments; columns in any
/// order; unknown columns are ignored.
/// The most rows a CapBall dataset may hold (identification memory is about 0.9 kB per row).
pub const MAX_DATASET_ROWS: usize = 200_000;

pub fn parse_dataset(text: &str) -> Result<Vec<CapballRecord>, CapballError> {
    let err = |m: String| CapballError::Dataset(m);
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(text.as_bytes());
    let headers = rdr.headers().map_err(|e| err(e.to_string()))?.clone();
    let col = |name: &str| headers.iter().position(|h| h == name);
    for h in headers.iter() {
        if matches!(h, "ex_mm" | "ey_mm" | "ez_mm" | "ex" | "ey" | "ez") {
            return Err(err(format!(
                "column `{h}`: volumetric errors must be given in µm as ex_um, ey_um, ez_um"
            )));
        }
        if matches!(h, "a_rad" | "c_rad") {
            return Err(err(format!(
                "column `{h}`: angles must be given in degrees as a_deg, c_deg"
            )));
        }
    }
    let need = [
        "pose", "x_mm", "y_mm", "z_mm", "a_deg", "c_deg", "ex_um", "ey_um", "ez_um",
    ];
    let mut idx = Vec::new();
    for n in need {
        idx.push(
            col(n)
                .ok_or_else(|| err(format!("missing column `{n}` (header must name {need:?})")))?,
        );
    }
    let run_col = col("run");
    let time_col = col("time_s");
    let mut out = Vec::new();
    for (line, rec) in rdr.records().enumerate() {
        if line >= MAX_DATASET_ROWS {
            return Err(err(format!(
                "more than {MAX_DATASET_ROWS} rows: a CapBall run has tens to a few thousand poses (1 000 000 rows took 0.9 GB to identify); split the file by run"
            )));
        }
        let rec = rec.map_err(|e| err(e.to_string()))?;
        let row = line + 2;
        let num = |i: usize, name: &str| -> Result<f64, CapballError> {
            let s = rec.get(i).unwrap_or("");
            let v = s
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    err(format!(
                        "row {row}: column `{name}`: `{s}` is not a finite number"
                    ))
                })?;
            let (lo, hi, what) = dataset_range(name);
            if !(lo..=hi).contains(&v) {
                return Err(err(format!(
                    "row {row}: column `{name}`: `{s}` is outside the range of {what}: {lo} to {hi}"
                )));
            }
            Ok(v)
        };
        let int = |i: usize, name: &str| -> Result<u32, CapballError> {
            let s = rec.get(i).unwrap_or("");
            s.parse::<u32>().map_err(|_| {
                err(format!(
                    "row {row}: column `{name}`: `{s}` is not a whole number"
                ))
            })
        };
        let pose = Pose {
            x_mm: num(idx[1], "x_mm")?,
            y_mm: num(idx[2], "y_mm")?,
            z_mm: num(idx[3], "z_mm")?,
            a_deg: num(idx[4], "a_deg")?,
            b_deg: 0.0,
            c_deg: num(idx[5], "c_deg")?,
        };
        out.push(CapballRecord {
            run: match run_col {
                Some(i) => int(i, "run")?,
                None => 1,
            },
            pose_index: int(idx[0], "pose")?,
            time_s: match time_col {
                Some(i) if !rec.get(i).unwrap_or("").is_empty() => Some(num(i, "time_s")?),
                _ => None,
            },
            pose,
            e_um: [
                num(idx[6], "ex_um")?,
                num(idx[7], "ey_um")?,
                num(idx[8], "ez_um")?,
            ],
        });
    }
    if out.is_empty() {
        return Err(err("no data rows".into()));
    }
    Ok(out)
}

/// Poses and measured errors of the records of one run, in file order: the inputs of
/// [`CapballSetup::identify`] (an adapter from logged pose values produces the same pair).
pub fn split_run(records: &[CapballRecord], run: u32) -> (Vec<Pose>, Vec<[f64; 3]>) {
    records
        .iter()
        .filter(|r| r.run == run)
        .map(|r| (r.pose, r.e_um))
        .unzip()
}

/// Join per-pose values (1-based pose index of the trajectory, `[ex, ey, ez]` µm, e.g. the
/// steady values of a log's CapBall pose topic) with the trajectory's poses: the adapter from
/// logged pose values to [`CapballSetup::identify`]. A pose index outside the trajectory is an
/// error; poses without a value are skipped.
pub fn join_pose_values(
    trajectory: &[Pose],
    values: &[(u32, [f64; 3])],
) -> Result<(Vec<Pose>, Vec<[f64; 3]>), CapballError> {
    let mut poses = Vec::with_capacity(values.len());
    let mut meas = Vec::with_capacity(values.len());
    for (k, e) in values {
        let p = (*k as usize)
            .checked_sub(1)
            .and_then(|i| trajectory.get(i))
            .ok_or_else(|| {
                CapballError::Dataset(format!(
                    "pose index {k} is not in the trajectory (1..{})",
                    trajectory.len()
                ))
            })?;
        poses.push(*p);
        meas.push(*e);
    }
    Ok((poses, meas))
}

/// Write a dataset in the format of [`parse_dataset`].
pub fn write_dataset(records: &[CapballRecord]) -> String {
    let mut s = String::from("run,pose,time_s,x_mm,y_mm,z_mm,a_deg,c_deg,ex_um,ey_um,ez_um\n");
    for r in records {
        let t = r.time_s.map(|t| format!("{t:.3}")).unwrap_or_default();
        s.push_str(&format!(
            "{},{},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.4},{:.4},{:.4}\n",
            r.run,
            r.pose_index,
            t,
            r.pose.x_mm,
            r.pose.y_mm,
            r.pose.z_mm,
            r.pose.a_deg,
            r.pose.c_deg,
            r.e_um[0],
            r.e_um[1],
            r.e_um[2]
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn identification(sigma_um: f64, dof: usize) -> Identification {
        Identification {
            errors: CapballErrors::default(),
            params: vec![0.0; 14],
            std_uncertainty: vec![0.0; 14],
            covariance: Vec::new(),
            condition_number: 1.0,
            residual_rms_um: [sigma_um; 3],
            residual_sigma_um: sigma_um,
            n_poses: (dof + 14) / 3,
            dof,
            residuals_um: Vec::new(),
        }
    }

    #[test]
    fn validation_excess_is_the_variance_ratio_beyond_five_sigma() {
        // s = 1 µm, 1000 degrees of freedom, 100 validation poses (300 equations): the ratio
        // of mean squares may reach 1 + 5·√(2/300 + 2/1000) = 1.4655 under white noise.
        let id = identification(1.0, 1000);
        let bound = 1.0 + 5.0 * (2.0f64 / 300.0 + 2.0 / 1000.0).sqrt();
        assert_eq!(id.validation_excess(&[1.0; 3], 100), None);
        // RMS 1.2 µm: ratio 1.44, inside.
        assert_eq!(id.validation_excess(&[1.2; 3], 100), None);
        // RMS 1.25 µm: ratio 1.5625, beyond.
        let e = id.validation_excess(&[1.25; 3], 100).unwrap();
        assert!((e.ratio - 1.5625).abs() < 1e-12);
        assert!((e.bound - bound).abs() < 1e-12);
        assert!((e.validation_rms_um - 1.25).abs() < 1e-12);
        assert_eq!(e.identification_sigma_um, 1.0);
        // The channels' mean squares are averaged: one channel at √3 × 1.25 µm is the same.
        let one = id
            .validation_excess(&[1.25 * 3f64.sqrt(), 0.0, 0.0], 100)
            .unwrap();
        assert!((one.ratio - e.ratio).abs() < 1e-12);
        // Fewer validation poses widen the bound: 10 poses (30 equations) allow 2.30.
        assert_eq!(id.validation_excess(&[1.25; 3], 10), None);
    }

    #[test]
    fn validation_excess_needs_a_noise_level_and_validation_poses() {
        assert_eq!(
            identification(0.0, 1000).validation_excess(&[5.0; 3], 100),
            None
        );
        assert_eq!(
            identification(1.0, 1000).validation_excess(&[5.0; 3], 0),
            None
        );
        // No degrees of freedom counts as one: the bound is wide but the test still runs.
        assert!(
            identification(1.0, 0)
                .validation_excess(&[50.0; 3], 100)
                .is_some()
        );
    }
}
