//! The candidate effects of a CapBall diagnosis as extra columns of the identification
//! least squares (`docs/datasets.md`, CapBall effects table), and the least-squares helpers.
//!
//! Rows are laid out as in [`CapballSetup::stacked_jacobian`]: pose `i`, channel `k` (x, y, z
//! in the machine frame) is row `3 i + k`.

use nalgebra::{DMatrix, DVector, Vector3};

use geometry::capball::{CapballSetup, N_PARAMS};
use geometry::capball_effects::{
    AxisHarmonic, CapballEffect, CapballEffectKind, Channel, CyclicDrift, RotaryAxis, housing,
};
use geometry::kinematics::Pose;

/// One CapBall run: poses in measuring order, their times and the measured volumetric errors.
#[derive(Debug, Clone, PartialEq)]
pub struct CapballRun {
    pub poses: Vec<Pose>,
    /// Seconds (any origin, but the same clock for every run of a dataset).
    pub time_s: Vec<f64>,
    pub e_um: Vec<[f64; 3]>,
    /// The stacked identification Jacobian, computed once per diagnosis (the kinematics cost
    /// far more than the least squares); filled only on the diagnosis's own copies.
    jac: std::sync::OnceLock<DMatrix<f64>>,
}

impl CapballRun {
    pub fn new(poses: Vec<Pose>, time_s: Vec<f64>, e_um: Vec<[f64; 3]>) -> Self {
        CapballRun {
            poses,
            time_s,
            e_um,
            jac: std::sync::OnceLock::new(),
        }
    }
    /// A copy without the cached Jacobian (the diagnosis fills it for its one setup).
    pub(crate) fn fresh(&self) -> Self {
        Self::new(self.poses.clone(), self.time_s.clone(), self.e_um.clone())
    }
    /// The stacked Jacobian of the poses for `setup`.
    pub(crate) fn jac(&self, setup: &CapballSetup) -> &DMatrix<f64> {
        self.jac.get_or_init(|| setup.stacked_jacobian(&self.poses))
    }
    pub fn len(&self) -> usize {
        self.poses.len()
    }
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }
    /// Measured values stacked as the identification right-hand side.
    pub(crate) fn rhs(&self) -> DVector<f64> {
        DVector::from_iterator(
            3 * self.len(),
            self.e_um.iter().flat_map(|e| e.iter().copied()),
        )
    }
}

/// A candidate effect of the search: a [`CapballEffect`] with its non-linear parameter fixed
/// and its linear ones (the columns' coefficients) still to fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Candidate {
    /// `rate_um_per_h` {x, y, z}: three columns `t·e_k` (t in hours).
    LinearDrift,
    /// Sine and cosine of time at one period, per machine direction: six columns.
    CyclicDrift { period_s: f64 },
    /// One channel's reading scaled by `1 + g`: one column, the model's own value on that channel.
    SensorGain { channel: Channel },
    /// Harmonic `k` of a rotary axis angle, a displacement in the axis's housing frame (for C
    /// the A cradle, for A the machine frame): six columns (cos, sin) × (three directions).
    AxisError { axis: RotaryAxis, harmonic: u32 },
}

impl Candidate {
    /// The effect this candidate is a form of.
    pub fn kind(&self) -> CapballEffectKind {
        match self {
            Candidate::LinearDrift => CapballEffectKind::LinearDrift,
            Candidate::CyclicDrift { .. } => CapballEffectKind::CyclicDrift,
            Candidate::SensorGain { .. } => CapballEffectKind::SensorGain,
            Candidate::AxisError { .. } => CapballEffectKind::AxisError,
        }
    }

    /// The effect with the columns' coefficients `b` (as [`Candidate::columns`] orders them).
    pub fn effect(&self, b: &DVector<f64>) -> CapballEffect {
        let at = |i: usize| b.get(i).copied().unwrap_or(0.0);
        match *self {
            Candidate::LinearDrift => CapballEffect::LinearDrift {
                rate_um_per_h: std::array::from_fn(at),
            },
            // b_sin·sin(ωt) + b_cos·cos(ωt) = a·sin(ωt + φ), φ = atan2(b_cos, b_sin).
            Candidate::CyclicDrift { period_s } => CapballEffect::CyclicDrift(CyclicDrift {
                period_s,
                amplitude_um: std::array::from_fn(|k| {
                    let (s, c) = (at(2 * k), at(2 * k + 1));
                    (s * s + c * c).sqrt()
                }),
                phase_rad: std::array::from_fn(|k| at(2 * k + 1).atan2(at(2 * k))),
            }),
            Candidate::SensorGain { channel } => CapballEffect::SensorGain {
                channel,
                gain_pct: 100.0 * at(0),
            },
            Candidate::AxisError { axis, harmonic } => CapballEffect::AxisError(AxisHarmonic {
                axis,
                harmonic,
                cos_um: std::array::from_fn(|d| at(2 * d)),
                sin_um: std::array::from_fn(|d| at(2 * d + 1)),
            }),
        }
    }
    pub fn n_cols(&self) -> usize {
        match self {
            Candidate::LinearDrift => 3,
            Candidate::CyclicDrift { .. } | Candidate::AxisError { .. } => 6,
            Candidate::SensorGain { .. } => 1,
        }
    }
    /// Functions of time (a drift of the measuring loop): their coefficients belong to one run
    /// and are fitted again on the validation run; the others describe the machine or the
    /// sensor and carry over unchanged.
    pub fn is_time_effect(&self) -> bool {
        matches!(self, Candidate::LinearDrift | Candidate::CyclicDrift { .. })
    }

    /// The columns of this effect for a run; `model_um` is the current model's value per row
    /// (needed by the sensor gain, which scales what the machine presents to the sensor).
    pub fn columns(&self, run: &CapballRun, model_um: &DVector<f64>) -> DMatrix<f64> {
        let n = run.len();
        let mut x = DMatrix::zeros(3 * n, self.n_cols());
        for i in 0..n {
            let t = run.time_s[i];
            match *self {
                Candidate::LinearDrift => {
                    for k in 0..3 {
                        x[(3 * i + k, k)] = t / 3600.0;
                    }
                }
                Candidate::CyclicDrift { period_s } => {
                    let w = std::f64::consts::TAU * t / period_s;
                    for k in 0..3 {
                        x[(3 * i + k, 2 * k)] = w.sin();
                        x[(3 * i + k, 2 * k + 1)] = w.cos();
                    }
                }
                Candidate::SensorGain { channel } => {
                    let k = channel.index();
                    x[(3 * i + k, 0)] = model_um[3 * i + k];
                }
                Candidate::AxisError { axis, harmonic } => {
                    let pose = &run.poses[i];
                    let (theta, frame) = housing(axis, pose);
                    let arg = harmonic as f64 * theta;
                    for d in 0..3 {
                        let u = frame * Vector3::ith(d, 1.0);
                        for k in 0..3 {
                            x[(3 * i + k, 2 * d)] = arg.cos() * u[k];
                            x[(3 * i + k, 2 * d + 1)] = arg.sin() * u[k];
                        }
                    }
                }
            }
        }
        x
    }
}

/// A least-squares solution: coefficients, residual, RSS and the unscaled covariance (AᵀA)⁻¹.
#[derive(Debug, Clone)]
pub(crate) struct Fit {
    pub coef: DVector<f64>,
    pub resid: DVector<f64>,
    pub rss: f64,
    pub cov_unscaled: DMatrix<f64>,
}

/// Least squares over the rows where `keep` is true (the others get residual 0 and no weight).
/// `None` when the columns are (numerically) dependent.
pub(crate) fn lstsq(a: &DMatrix<f64>, y: &DVector<f64>, keep: &[bool]) -> Option<Fit> {
    let (m, p) = a.shape();
    let mut aw = a.clone();
    let mut yw = y.clone();
    for r in 0..m {
        if !keep[r] {
            aw.row_mut(r).fill(0.0);
            yw[r] = 0.0;
        }
    }
    // Normalise the columns so that the rank test does not depend on their units.
    let scale: Vec<f64> = (0..p).map(|c| aw.column(c).norm().max(1e-300)).collect();
    for (c, s) in scale.iter().enumerate() {
        aw.column_mut(c).unscale_mut(*s);
    }
    let svd = geometry::linalg::svd(aw.clone(), true, true)?;
    let sv = &svd.singular_values;
    let smax = sv.max();
    if smax <= 0.0 || sv.min() <= smax * 1e-9 {
        return None;
    }
    let (u, vt) = (svd.u.as_ref()?, svd.v_t.as_ref()?);
    let mut uty = u.transpose() * &yw;
    for i in 0..p {
        uty[i] /= sv[i];
    }
    let mut coef = vt.transpose() * uty;
    let mut vs = vt.transpose();
    for i in 0..p {
        vs.column_mut(i).unscale_mut(sv[i]);
    }
    let mut cov = &vs * vs.transpose();
    for i in 0..p {
        coef[i] /= scale[i];
        for k in 0..p {
            cov[(i, k)] /= scale[i] * scale[k];
        }
    }
    let mut resid = y - a * &coef;
    for r in 0..m {
        if !keep[r] {
            resid[r] = 0.0;
        }
    }
    let rss = resid.norm_squared();
    Some(Fit {
        coef,
        resid,
        rss,
        cov_unscaled: cov,
    })
}

/// `[J | X₁ | X₂ …]` for a run.
pub(crate) fn design(
    setup: &CapballSetup,
    run: &CapballRun,
    extra: &[DMatrix<f64>],
) -> DMatrix<f64> {
    let j = run.jac(setup);
    let k: usize = extra.iter().map(|x| x.ncols()).sum();
    let mut a = DMatrix::zeros(j.nrows(), N_PARAMS + k);
    a.columns_mut(0, N_PARAMS).copy_from(j);
    let mut c = N_PARAMS;
    for x in extra {
        a.columns_mut(c, x.ncols()).copy_from(x);
        c += x.ncols();
    }
    a
}

/// Fraction of the energy of `v` that lies in the column space of `j` (what the 14 parameters
/// can take up), 0..1.
pub(crate) fn absorbed_fraction(j: &DMatrix<f64>, v: &DVector<f64>, keep: &[bool]) -> f64 {
    let mut vk = v.clone();
    for (r, k) in keep.iter().enumerate() {
        if !k {
            vk[r] = 0.0;
        }
    }
    let total = vk.norm_squared();
    if total <= 0.0 {
        return 0.0;
    }
    match lstsq(j, &vk, keep) {
        Some(f) => (1.0 - f.rss / total).clamp(0.0, 1.0),
        None => 0.0,
    }
}

/// `n` values from `lo` to `hi`, evenly spaced in the logarithm.
pub(crate) fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}
