//! Multi-output adaptive Monte Carlo of the CapBall link and setup errors (paper 001).
//!
//! The identification is linear, `p̂ = J⁺·ΔE` (paper 001, pseudo-inverse of the stacked
//! Jacobian), so one trial is `p = p̂ + J⁺·e + J⁺·d(φ)`: `e` is the per-point noise (sensor
//! noise and frame-transform dispersion, and for the *statistical* drift model the ISO/TR 230-9
//! drift term, all normal and independent per point and direction), `d(φ)` the *cyclic* drift of
//! the measuring loop at the measurement times of the poses with a random start phase φ.
//!
//! Why the cyclic drift costs almost nothing per trial: the drift is a Fourier series in time,
//! so `J⁺·d(φ) = Σ_k cos(kφ)·A_k + sin(kφ)·B_k` with the 14-vectors `A_k`, `B_k` computed once.
//! The per-point noise is generated in full (2421 normals per trial for 807 poses); a batch of
//! trials, noise, drift and p̂ together, is one matrix product (docs/methods.md, "Speed of the
//! CapBall Monte Carlo").
//!
//! Any Jacobian plugs in ([`CapballMc::new`] takes `J` as a matrix); [`Paper001Case`] uses the
//! machine's own (`crate::capball`, the WCAYFXZT machine of paper 001).

use nalgebra::DMatrix;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, StandardNormal};
use serde::Serialize;

use super::UncertaintyError;
use super::mc::{McResult, TrialSource};
use super::normals::FastNormals;

/// One harmonic of a periodic drift: `cos_um·cos(kωt) + sin_um·sin(kωt)` per direction x, y, z.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriftHarmonic {
    pub order: u32,
    pub cos_um: [f64; 3],
    pub sin_um: [f64; 3],
}

/// The measuring loop's drift as a periodic function of time (paper 001, cyclic method: the
/// spindle's cooling cycles).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CyclicDrift {
    pub period_s: f64,
    pub harmonics: Vec<DriftHarmonic>,
}

impl CyclicDrift {
    /// A sinusoidal drift with the given peak-to-valley per direction.
    pub fn sine(period_s: f64, peak_to_valley_um: [f64; 3]) -> CyclicDrift {
        CyclicDrift {
            period_s,
            harmonics: vec![DriftHarmonic {
                order: 1,
                cos_um: [0.0; 3],
                sin_um: peak_to_valley_um.map(|v| v / 2.0),
            }],
        }
    }

    /// A cooling-cycle shape: a slow rise and a faster fall (first three harmonics of a
    /// sawtooth, scaled to the given peak-to-valley per direction).
    pub fn cooling_cycle(period_s: f64, peak_to_valley_um: [f64; 3]) -> CyclicDrift {
        // Sawtooth Fourier coefficients 1/k; three harmonics span about 1.63 peak to valley
        // (sampled numerically below), scaled to the requested range.
        let raw = |t: f64| -> f64 {
            (1..=3)
                .map(|k| (std::f64::consts::TAU * k as f64 * t).sin() / k as f64)
                .sum()
        };
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for i in 0..4000 {
            let v = raw(i as f64 / 4000.0);
            lo = lo.min(v);
            hi = hi.max(v);
        }
        let scale = 1.0 / (hi - lo);
        CyclicDrift {
            period_s,
            harmonics: (1..=3)
                .map(|k| DriftHarmonic {
                    order: k,
                    cos_um: [0.0; 3],
                    sin_um: peak_to_valley_um.map(|v| v * scale / k as f64),
                })
                .collect(),
        }
    }

    /// The drift at time `t_s`.
    pub fn value_um(&self, t_s: f64) -> [f64; 3] {
        let w = std::f64::consts::TAU / self.period_s;
        let mut d = [0.0; 3];
        for h in &self.harmonics {
            let (s, c) = (h.order as f64 * w * t_s).sin_cos();
            for (a, da) in d.iter_mut().enumerate() {
                *da += h.cos_um[a] * c + h.sin_um[a] * s;
            }
        }
        d
    }

    /// Peak-to-valley per direction (sampled over one period): E_VE of ISO/TR 230-9.
    pub fn peak_to_valley_um(&self) -> [f64; 3] {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for i in 0..2000 {
            let v = self.value_um(self.period_s * i as f64 / 2000.0);
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]]
    }
}

/// How the drift of the measuring loop enters the simulation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum DriftModel {
    None,
    /// ISO/TR 230-9 statistical treatment: a normal term of standard deviation `u_um` per
    /// direction, drawn independently for every point.
    Statistical {
        u_um: [f64; 3],
    },
    /// Periodic function of time with a random start phase per trial.
    Cyclic(CyclicDrift),
}

impl DriftModel {
    /// The statistical model from the drift range E_VE (peak to valley) per direction:
    /// u_EVE = E_VE/(2√3), the range read as the full width of a rectangular distribution
    /// (ISO/TR 230-9's treatment of an environmental variation error).
    pub fn statistical_from_range(e_ve_um: [f64; 3]) -> DriftModel {
        DriftModel::Statistical {
            u_um: e_ve_um.map(|e| e / (2.0 * 3f64.sqrt())),
        }
    }
}

/// The uncertainty sources of paper 001.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CapballSources {
    /// Standard uncertainty of the sensor outputs (Type A), per direction, per point.
    pub sensor_u_um: [f64; 3],
    /// Dispersion of the sensor-to-machine frame transformation, per direction, per point
    /// (paper 001 models it as normal with the standard deviations of 500 calibration points).
    pub frame_u_um: [f64; 3],
    pub drift: DriftModel,
}

impl CapballSources {
    /// The same sources with only one kept (for the contribution of each source, Table 5).
    pub fn only(&self, source: Source) -> CapballSources {
        CapballSources {
            sensor_u_um: if source == Source::Sensor {
                self.sensor_u_um
            } else {
                [0.0; 3]
            },
            frame_u_um: if source == Source::Frame {
                self.frame_u_um
            } else {
                [0.0; 3]
            },
            drift: if source == Source::Drift {
                self.drift.clone()
            } else {
                DriftModel::None
            },
        }
    }
}

/// One uncertainty source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Source {
    Sensor,
    Frame,
    Drift,
}

/// Trials are projected in batches of this many (one matrix product per batch).
const BATCH: usize = 50;

/// The CapBall Monte Carlo model: a [`TrialSource`] with 14 (or `J.ncols()`) outputs.
#[derive(Debug, Clone)]
pub struct CapballMc {
    names: Vec<String>,
    p_hat: Vec<f64>,
    /// J⁺ (n_params × 3·n_poses).
    pinv: DMatrix<f64>,
    /// Standard deviation of the per-point normal noise for each row of ΔE.
    sigma: Vec<f64>,
    /// (order k, A_k, B_k): the cyclic drift's projection.
    drift_terms: Vec<(u32, Vec<f64>, Vec<f64>)>,
    /// The whole trial as one product, `p = M·v` for a batch of columns v:
    /// `M = [N | 0 | A_1 B_1 … A_m B_m | p̂]`, `v = [z; z′; cos k₁φ; sin k₁φ; …; 1]`. N projects
    /// the unit normals z: σ-scaled J⁺ (per point), or in the reduced form a square root of
    /// J⁺ΣJ⁺ᵀ. The zero columns take the normals z′ that pad z to a multiple of 4 (the
    /// generator's lane width) and the two whose direction is the start phase φ.
    project: DMatrix<f64>,
    /// Normals drawn per trial (z and z′): a multiple of 4.
    n_fill: usize,
    /// True when the per-point noise is drawn directly in parameter space: n_params normals per
    /// trial instead of 3·n_poses. Exact (same distribution) because the per-point noise is
    /// Gaussian and the identification linear.
    reduced: bool,
}

/// Worker scratch: the columns v of a batch and the harmonics of one start phase.
pub struct CapballScratch {
    v: DMatrix<f64>,
    /// cos(kφ), sin(kφ) for k = 0..=max order (angle-addition recurrence).
    harm: Vec<(f64, f64)>,
}

/// `[noise | 0 | A_1 B_1 … | p̂]` (see `CapballMc::project`) and the number of normals per trial.
fn trial_matrix(
    noise: &DMatrix<f64>,
    drift_terms: &[(u32, Vec<f64>, Vec<f64>)],
    p_hat: &[f64],
) -> (DMatrix<f64>, usize) {
    let n_fill = (noise.ncols() + 2).div_ceil(4) * 4;
    let cols = n_fill + 2 * drift_terms.len() + 1;
    let mut m = DMatrix::zeros(noise.nrows(), cols);
    m.columns_mut(0, noise.ncols()).copy_from(noise);
    for (j, (_, a, b)) in drift_terms.iter().enumerate() {
        m.column_mut(n_fill + 2 * j).copy_from_slice(a);
        m.column_mut(n_fill + 2 * j + 1).copy_from_slice(b);
    }
    m.column_mut(cols - 1).copy_from_slice(p_hat);
    (m, n_fill)
}

/// Moore–Penrose pseudo-inverse of a full-column-rank `J` by SVD.
pub fn pseudo_inverse(j: &DMatrix<f64>) -> Result<DMatrix<f64>, UncertaintyError> {
    let n = j.ncols();
    let svd = geometry::linalg::svd(j.clone(), true, true).ok_or_else(|| {
        UncertaintyError::Invalid(
            "the identification Jacobian cannot be decomposed (non-finite or extreme values)"
                .into(),
        )
    })?;
    let smax = svd.singular_values.max();
    let smin = svd.singular_values.min();
    if smin.is_nan() || smin <= smax * 1e-12 {
        return Err(UncertaintyError::Invalid(format!(
            "the identification Jacobian is rank deficient ({n} parameters, condition number {:.3e}): \
             the poses do not separate all parameters",
            smax / smin
        )));
    }
    svd.pseudo_inverse(smax * 1e-13)
        .map_err(|e| UncertaintyError::Invalid(format!("pseudo-inverse failed: {e}")))
}

impl CapballMc {
    /// `j`: identification Jacobian (3 rows per pose, x y z; µm per parameter unit); `p_hat`:
    /// the identified parameters (the mean of the repeated identifications in paper 001);
    /// `times_s`: measurement time of each pose from the start of the trajectory.
    pub fn new(
        j: &DMatrix<f64>,
        p_hat: &[f64],
        names: &[String],
        times_s: &[f64],
        sources: &CapballSources,
    ) -> Result<CapballMc, UncertaintyError> {
        let n_params = j.ncols();
        if j.nrows() != 3 * times_s.len() {
            return Err(UncertaintyError::Invalid(format!(
                "the Jacobian has {} rows for {} poses (3 rows per pose expected)",
                j.nrows(),
                times_s.len()
            )));
        }
        if p_hat.len() != n_params || names.len() != n_params {
            return Err(UncertaintyError::Invalid(format!(
                "{} parameter values and {} names for a Jacobian with {n_params} columns",
                p_hat.len(),
                names.len()
            )));
        }
        let all = sources
            .sensor_u_um
            .iter()
            .chain(&sources.frame_u_um)
            .copied()
            .chain(match &sources.drift {
                DriftModel::Statistical { u_um } => u_um.to_vec(),
                _ => vec![],
            });
        if all.clone().any(|u| !(u >= 0.0 && u.is_finite())) {
            return Err(UncertaintyError::Invalid(
                "standard uncertainties must be finite and ≥ 0".into(),
            ));
        }
        let pinv = pseudo_inverse(j)?;
        let stat = match &sources.drift {
            DriftModel::Statistical { u_um } => *u_um,
            _ => [0.0; 3],
        };
        let sigma: Vec<f64> = (0..j.nrows())
            .map(|r| {
                let a = r % 3;
                (sources.sensor_u_um[a].powi(2) + sources.frame_u_um[a].powi(2) + stat[a].powi(2))
                    .sqrt()
            })
            .collect();
        let mut drift_terms = Vec::new();
        if let DriftModel::Cyclic(cd) = &sources.drift {
            if cd.period_s.is_nan() || cd.period_s <= 0.0 {
                return Err(UncertaintyError::Invalid(
                    "the drift period must be positive".into(),
                ));
            }
            let w = std::f64::consts::TAU / cd.period_s;
            for h in &cd.harmonics {
                let k = h.order as f64;
                let mut u = nalgebra::DVector::zeros(j.nrows());
                let mut v = nalgebra::DVector::zeros(j.nrows());
                for (i, t) in times_s.iter().enumerate() {
                    let (s, c) = (k * w * t).sin_cos();
                    for a in 0..3 {
                        // d(t + φ/ω) = cos(kφ)·(a·cos + b·sin) + sin(kφ)·(−a·sin + b·cos).
                        u[3 * i + a] = h.cos_um[a] * c + h.sin_um[a] * s;
                        v[3 * i + a] = -h.cos_um[a] * s + h.sin_um[a] * c;
                    }
                }
                let pa = &pinv * u;
                let pb = &pinv * v;
                drift_terms.push((h.order, pa.as_slice().to_vec(), pb.as_slice().to_vec()));
            }
        }
        // σ folded into J⁺'s columns: the trials project unit normals.
        let mut pinv_sigma = pinv.clone();
        for (c, sd) in sigma.iter().enumerate() {
            pinv_sigma.column_mut(c).scale_mut(*sd);
        }
        let (project, n_fill) = trial_matrix(&pinv_sigma, &drift_terms, p_hat);
        Ok(CapballMc {
            names: names.to_vec(),
            p_hat: p_hat.to_vec(),
            pinv,
            sigma,
            drift_terms,
            project,
            n_fill,
            reduced: false,
        })
    }

    /// Draws the per-point Gaussian noise in parameter space (see the `reduced` field): the
    /// same distribution of the outputs at a small fraction of the cost per trial.
    pub fn with_reduced_noise(mut self) -> CapballMc {
        let mut scaled = self.pinv.clone();
        for (c, s) in self.sigma.iter().enumerate() {
            scaled.column_mut(c).scale_mut(*s);
        }
        let cov = &scaled * scaled.transpose();
        // Symmetric square root by eigen-decomposition: works for a singular covariance too
        // (a source switched off).
        let eig = cov.symmetric_eigen();
        let sqrt_vals = eig.eigenvalues.map(|v| v.max(0.0).sqrt());
        let l = &eig.eigenvectors * nalgebra::DMatrix::from_diagonal(&sqrt_vals);
        (self.project, self.n_fill) = trial_matrix(&l, &self.drift_terms, &self.p_hat);
        self.reduced = true;
        self
    }

    /// J⁺, for simulations that identify from simulated measurements.
    pub fn pseudo_inverse(&self) -> &DMatrix<f64> {
        &self.pinv
    }
}

impl TrialSource for CapballMc {
    type Scratch = CapballScratch;

    fn n_outputs(&self) -> usize {
        self.p_hat.len()
    }

    fn output_names(&self) -> Vec<String> {
        self.names.clone()
    }

    fn scratch(&self) -> CapballScratch {
        // The reduced path takes a whole block in one product (23 × BLOCK_TRIALS); the
        // per-point path BATCH trials (2431 × BATCH).
        let cols = if self.reduced {
            super::mc::BLOCK_TRIALS
        } else {
            BATCH
        };
        let max_order = self.drift_terms.iter().map(|t| t.0).max().unwrap_or(0);
        CapballScratch {
            v: DMatrix::zeros(self.project.ncols(), cols),
            harm: vec![(1.0, 0.0); max_order as usize + 1],
        }
    }

    /// Trials of a block draw their normals four at a time ([`FastNormals`]) from generators
    /// seeded from the block's ChaCha8 stream (the block's seed fixes everything). A batch of
    /// trials is one matrix product written straight into `out` (trial-major is column-major
    /// n_outputs × n_trials). See docs/methods.md, "Speed of the CapBall Monte Carlo".
    fn fill(&self, rng: &mut ChaCha8Rng, s: &mut CapballScratch, out: &mut [f64]) {
        let mut normals = FastNormals::from_rng(rng);
        let n_out = self.p_hat.len();
        let n_trials = out.len() / n_out;
        let (rows, batch) = s.v.shape();
        let mut done = 0;
        while done < n_trials {
            let nb = batch.min(n_trials - done);
            for v in s.v.as_mut_slice()[..rows * nb].chunks_exact_mut(rows) {
                self.trial_column(&mut normals, &mut s.harm, v);
            }
            let mut y = nalgebra::DMatrixViewMut::from_slice(
                &mut out[done * n_out..(done + nb) * n_out],
                n_out,
                nb,
            );
            y.gemm(1.0, &self.project, &s.v.columns(0, nb), 0.0);
            done += nb;
        }
    }
}

impl CapballMc {
    /// One trial's column v (see `CapballMc::project`): the normals, then cos(kφ), sin(kφ) of a
    /// uniform start phase φ, then 1. φ is the direction of the last two normals (uniform on
    /// the circle for independent normals), which spares a sin_cos per trial; the harmonics
    /// follow by the angle-addition recurrence.
    fn trial_column(&self, normals: &mut FastNormals, harm: &mut [(f64, f64)], v: &mut [f64]) {
        let n = self.n_fill;
        normals.fill(&mut v[..n]);
        let (a, b) = (v[n - 2], v[n - 1]);
        let r = (a * a + b * b).sqrt();
        let (c1, s1) = if r > 0.0 { (a / r, b / r) } else { (1.0, 0.0) };
        for k in 1..harm.len() {
            let (c, s) = harm[k - 1];
            harm[k] = (c * c1 - s * s1, s * c1 + c * s1);
        }
        let rest = &mut v[n..];
        for (j, (k, _, _)) in self.drift_terms.iter().enumerate() {
            (rest[2 * j], rest[2 * j + 1]) = harm[*k as usize];
        }
        if let Some(one) = rest.last_mut() {
            *one = 1.0;
        }
    }
}

/// Simulated repeated identifications on a machine whose measuring loop drifts cyclically:
/// run `r` starts at `first_start_s + r·run_period_s` (back-to-back trajectories, as the ten
/// runs of paper 001 over about three hours), each with fresh sensor and frame noise.
/// Returns the identified parameter vectors.
#[allow(clippy::too_many_arguments)]
pub fn simulate_identifications(
    j: &DMatrix<f64>,
    p_true: &[f64],
    times_s: &[f64],
    sensor_u_um: [f64; 3],
    frame_u_um: [f64; 3],
    drift: &CyclicDrift,
    first_start_s: f64,
    run_period_s: f64,
    n_runs: usize,
    seed: u64,
) -> Result<Vec<Vec<f64>>, UncertaintyError> {
    let pinv = pseudo_inverse(j)?;
    let p = nalgebra::DVector::from_column_slice(p_true);
    let clean = j * p;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut runs = Vec::with_capacity(n_runs);
    for r in 0..n_runs {
        let t0 = first_start_s + r as f64 * run_period_s;
        let mut de = clean.clone();
        for (i, t) in times_s.iter().enumerate() {
            let d = drift.value_um(t0 + t);
            for a in 0..3 {
                let zs: f64 = StandardNormal.sample(&mut rng);
                let zf: f64 = StandardNormal.sample(&mut rng);
                de[3 * i + a] += d[a] + sensor_u_um[a] * zs + frame_u_um[a] * zf;
            }
        }
        runs.push((&pinv * de).as_slice().to_vec());
    }
    Ok(runs)
}

/// How often observed values fall inside the Monte Carlo coverage intervals.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CoverageCheck {
    /// Per parameter: the fraction of runs inside its probabilistically symmetric interval.
    pub per_parameter: Vec<f64>,
    /// Over all parameters and runs.
    pub overall: f64,
    /// Per parameter: the runs' standard deviation divided by the Monte Carlo u.
    pub spread_ratio: Vec<f64>,
}

/// Compares repeated identifications with the Monte Carlo intervals (paper 001, figures of
/// the statistical and cyclic methods against ten identifications).
pub fn coverage_check(mc: &McResult, runs: &[Vec<f64>]) -> CoverageCheck {
    let n = mc.outputs.len();
    let mut per = vec![0.0; n];
    let mut ratio = vec![0.0; n];
    for (j, o) in mc.outputs.iter().enumerate() {
        let [lo, hi] = o.symmetric_interval;
        let inside = runs.iter().filter(|r| r[j] >= lo && r[j] <= hi).count();
        per[j] = inside as f64 / runs.len().max(1) as f64;
        let m = runs.iter().map(|r| r[j]).sum::<f64>() / runs.len() as f64;
        let sd = (runs.iter().map(|r| (r[j] - m).powi(2)).sum::<f64>()
            / (runs.len() as f64 - 1.0).max(1.0))
        .sqrt();
        ratio[j] = sd / o.standard_uncertainty;
    }
    CoverageCheck {
        overall: per.iter().sum::<f64>() / n.max(1) as f64,
        per_parameter: per,
        spread_ratio: ratio,
    }
}

/// The case of paper 001 on our model of its machine: the identification Jacobian of the
/// WCAYFXZT machine along the 807-pose trajectory (`crate::capball`), poses 0.75 s apart (about
/// 10 minutes per trajectory), and sources of the magnitudes the paper describes (its exact
/// values are not in the text we have). Used by the tests, the benchmark and the report.
#[derive(Debug, Clone)]
pub struct Paper001Case {
    pub jacobian: DMatrix<f64>,
    pub times_s: Vec<f64>,
    pub names: Vec<String>,
    /// The parameters the simulated machine really has (µm, µrad).
    pub p_true: Vec<f64>,
    pub sensor_u_um: [f64; 3],
    pub frame_u_um: [f64; 3],
    /// The measuring loop's real drift: a cooling cycle of 25 min, 2/2/6 µm peak to valley
    /// (x, y, z; the paper saw a larger drift along z than along x and y).
    pub drift: CyclicDrift,
    /// Start-to-start time of back-to-back identification runs (18 min, paper 001: ten runs in
    /// about three hours).
    pub run_period_s: f64,
}

impl Paper001Case {
    pub fn paper001() -> Paper001Case {
        use geometry::capball::{CapballSetup, PARAM_NAMES, TrajectorySpec};
        let setup = CapballSetup::paper_default();
        let poses = setup.trajectory(&TrajectorySpec::default());
        let times_s = (0..poses.len()).map(|i| i as f64 * 0.75).collect();
        Paper001Case {
            jacobian: setup.stacked_jacobian(&poses),
            times_s,
            names: PARAM_NAMES.iter().map(|s| s.to_string()).collect(),
            p_true: vec![
                12.0, -8.0, 25.0, -15.0, 20.0, -30.0, 18.0, 40.0, 5.0, -3.0, 7.0, 2.0, -4.0, 6.0,
            ],
            sensor_u_um: [0.1, 0.1, 0.1],
            frame_u_um: [0.3, 0.3, 0.3],
            drift: CyclicDrift::cooling_cycle(1500.0, [2.0, 2.0, 6.0]),
            run_period_s: 1080.0,
        }
    }

    /// Sources with the cyclic drift model.
    pub fn cyclic_sources(&self) -> CapballSources {
        CapballSources {
            sensor_u_um: self.sensor_u_um,
            frame_u_um: self.frame_u_um,
            drift: DriftModel::Cyclic(self.drift.clone()),
        }
    }

    /// Sources with the ISO/TR 230-9 statistical drift model from the same drift's range.
    pub fn statistical_sources(&self) -> CapballSources {
        CapballSources {
            sensor_u_um: self.sensor_u_um,
            frame_u_um: self.frame_u_um,
            drift: DriftModel::statistical_from_range(self.drift.peak_to_valley_um()),
        }
    }

    /// The Monte Carlo model around `p_hat` with `sources`.
    pub fn monte_carlo_model(
        &self,
        p_hat: &[f64],
        sources: &CapballSources,
    ) -> Result<CapballMc, UncertaintyError> {
        CapballMc::new(&self.jacobian, p_hat, &self.names, &self.times_s, sources)
    }
}

/// One parameter's line of paper 001's Table 5: the width of the 95 % coverage interval
/// (probabilistically symmetric) with all sources and with each source alone.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SourceWidths {
    pub name: String,
    pub total: f64,
    pub drift: f64,
    pub sensor: f64,
    pub frame: f64,
    /// √(drift² + sensor² + frame²): what the widths would give if they added like standard
    /// uncertainties. Paper 001 finds it *below* the total for every parameter: with a cyclic
    /// (arcsine-like) drift the widths do not add in quadrature.
    pub quadrature: f64,
}

fn width(o: &super::McOutput) -> f64 {
    o.symmetric_interval[1] - o.symmetric_interval[0]
}

/// The per-source coverage-interval widths of paper 001's Table 5: four Monte Carlo runs with
/// the same options (all sources, then each alone). `build` makes the model for a set of
/// sources (e.g. `|s| CapballMc::new(&j, &p, &names, &t, s)`).
pub fn source_widths(
    build: &dyn Fn(&CapballSources) -> Result<CapballMc, UncertaintyError>,
    sources: &CapballSources,
    opts: &super::McOptions,
    progress: Option<&(dyn Fn(&super::McProgress) + Sync)>,
) -> Result<(McResult, Vec<SourceWidths>), UncertaintyError> {
    let run = |s: &CapballSources| super::mc::run(&build(s)?, opts, progress);
    let total = run(sources)?;
    let drift = run(&sources.only(Source::Drift))?;
    let sensor = run(&sources.only(Source::Sensor))?;
    let frame = run(&sources.only(Source::Frame))?;
    let widths = (0..total.outputs.len())
        .map(|j| {
            let (d, s, f) = (
                width(&drift.outputs[j]),
                width(&sensor.outputs[j]),
                width(&frame.outputs[j]),
            );
            SourceWidths {
                name: total.outputs[j].name.clone(),
                total: width(&total.outputs[j]),
                drift: d,
                sensor: s,
                frame: f,
                quadrature: (d * d + s * s + f * f).sqrt(),
            }
        })
        .collect();
    Ok((total, widths))
}

/// Parses a drift record taken at one fixed pose (docs/datasets.md, CapBall dataset):
/// CSV `time_s,ex_um,ey_um,ez_um`, `#` lines are comments, columns in any order.
pub fn parse_drift_record(text: &str) -> Result<Vec<(f64, [f64; 3])>, UncertaintyError> {
    let bad = |m: String| UncertaintyError::Format(format!("drift record: {m}"));
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let headers = rdr.headers().map_err(|e| bad(e.to_string()))?.clone();
    let col = |n: &str| {
        headers.iter().position(|h| h == n).ok_or_else(|| {
            bad(format!(
                "no `{n}` column (expected time_s,ex_um,ey_um,ez_um)"
            ))
        })
    };
    let idx = [col("time_s")?, col("ex_um")?, col("ey_um")?, col("ez_um")?];
    let mut out = Vec::new();
    for (line, rec) in rdr.records().enumerate() {
        let rec = rec.map_err(|e| bad(e.to_string()))?;
        let mut v = [0.0; 4];
        for (k, i) in idx.iter().enumerate() {
            let s = rec.get(*i).unwrap_or("");
            v[k] = s
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| bad(format!("row {}: `{s}` is not a number", line + 2)))?;
        }
        out.push((v[0], [v[1], v[2], v[3]]));
    }
    if out.windows(2).any(|w| w[1].0 <= w[0].0) {
        return Err(bad("time_s must increase from row to row".into()));
    }
    Ok(out)
}

/// Least-squares fit of a mean plus `harmonics` harmonics of period `period_s` to each
/// direction; returns the harmonics and the residual sum of squares over x, y, z.
fn fit_harmonics(record: &[(f64, [f64; 3])], period_s: f64, harmonics: u32) -> (CyclicDrift, f64) {
    let n = record.len();
    let m = 1 + 2 * harmonics as usize;
    let w = std::f64::consts::TAU / period_s;
    let a = DMatrix::from_fn(n, m, |i, c| {
        if c == 0 {
            return 1.0;
        }
        let k = c.div_ceil(2) as f64;
        let (s, co) = (k * w * record[i].0).sin_cos();
        if c % 2 == 1 { co } else { s }
    });
    let svd = geometry::linalg::svd(a.clone(), true, true);
    let mut hs: Vec<DriftHarmonic> = (1..=harmonics)
        .map(|k| DriftHarmonic {
            order: k,
            cos_um: [0.0; 3],
            sin_um: [0.0; 3],
        })
        .collect();
    let mut rss = 0.0;
    for d in 0..3 {
        let b = nalgebra::DVector::from_iterator(n, record.iter().map(|r| r.1[d]));
        let Some(Ok(x)) = svd.as_ref().map(|s| s.solve(&b, 1e-12)) else {
            return (
                CyclicDrift {
                    period_s,
                    harmonics: hs,
                },
                f64::INFINITY,
            );
        };
        rss += (&a * &x - &b).norm_squared();
        for (k, h) in hs.iter_mut().enumerate() {
            h.cos_um[d] = x[1 + 2 * k];
            h.sin_um[d] = x[2 + 2 * k];
        }
    }
    (
        CyclicDrift {
            period_s,
            harmonics: hs,
        },
        rss,
    )
}

impl CyclicDrift {
    /// Fits the cyclic drift of paper 001 to a drift record: the period (scanned from four
    /// sample spacings up to the record's length, then refined), and per direction the
    /// amplitude and shape as `harmonics` Fourier terms (3 follow a cooling cycle's slow rise
    /// and fast fall). The record must span at least one full period; a best period at the
    /// record's length means it does not, and is refused.
    pub fn fit(
        record: &[(f64, [f64; 3])],
        harmonics: u32,
    ) -> Result<CyclicDrift, UncertaintyError> {
        let h = harmonics.max(1);
        let n = record.len();
        if n < 4 * (1 + 2 * h as usize) {
            return Err(UncertaintyError::Invalid(format!(
                "the drift record has {n} rows; fitting {h} harmonics needs at least {}",
                4 * (1 + 2 * h as usize)
            )));
        }
        let span = record[n - 1].0 - record[0].0;
        let dt = span / (n - 1) as f64;
        let (p_min, p_max) = (4.0 * dt * h as f64, span);
        if p_min >= p_max {
            return Err(UncertaintyError::Invalid(
                "the drift record is too short or too coarse to show a cycle".into(),
            ));
        }
        // Log-spaced scan, then golden-section refinement around the best candidate.
        let steps = 400;
        let period = |i: f64| p_min * (p_max / p_min).powf(i / steps as f64);
        let rss = |p: f64| fit_harmonics(record, p, h).1;
        let best = (0..=steps)
            .map(|i| (i, rss(period(i as f64))))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0, |b| b.0);
        let (mut lo, mut hi) = (
            period(best as f64 - 1.0),
            period(best as f64 + 1.0).min(p_max),
        );
        let g = 0.5 * (5f64.sqrt() - 1.0);
        for _ in 0..40 {
            let (a, b) = (hi - g * (hi - lo), lo + g * (hi - lo));
            if rss(a) < rss(b) {
                hi = b;
            } else {
                lo = a;
            }
        }
        let p = 0.5 * (lo + hi);
        if p > 0.95 * span {
            return Err(UncertaintyError::Invalid(format!(
                "the drift record ({span:.0} s) does not cover a full cycle (best period \
                 {p:.0} s): record for longer, or use --drift statistical"
            )));
        }
        Ok(fit_harmonics(record, p, h).0)
    }
}

/// E_VE of ISO/TR 230-9 from a drift record: the peak-to-valley per direction.
pub fn drift_range_um(record: &[(f64, [f64; 3])]) -> [f64; 3] {
    let mut r = [0.0; 3];
    for (d, rd) in r.iter_mut().enumerate() {
        let (lo, hi) = record
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                (l.min(x.1[d]), h.max(x.1[d]))
            });
        *rd = if hi >= lo { hi - lo } else { 0.0 };
    }
    r
}

/// Paper 001's Monte Carlo set up from a measured CapBall dataset (docs/datasets.md): each run
/// identified separately, the first `warmup_runs` left out (paper 001 drops 5 of 15: the joints
/// were still warming), the Monte Carlo centred on the mean of the kept runs as in the paper,
/// its Jacobian and pose times from the first kept run.
#[derive(Debug, Clone)]
pub struct MeasuredCapball {
    pub jacobian: DMatrix<f64>,
    /// Time of each pose from the start of the run (s).
    pub times_s: Vec<f64>,
    pub names: Vec<String>,
    /// Mean of the kept runs' identified parameters.
    pub p_hat: Vec<f64>,
    /// The kept runs and their identified parameters (for [`coverage_check`]).
    pub runs: Vec<(u32, Vec<f64>)>,
    /// The runs left out as warm-up.
    pub warmup: Vec<u32>,
    /// Residual standard deviation of the first kept run (µm): the scatter the 14 parameters do
    /// not explain, for comparison with the sensor and frame uncertainties given.
    pub residual_sigma_um: f64,
}

impl MeasuredCapball {
    pub fn from_records(
        machine: &geometry::kinematics::Machine,
        records: &[geometry::capball::CapballRecord],
        warmup_runs: usize,
    ) -> Result<MeasuredCapball, UncertaintyError> {
        use geometry::capball::{CapballSetup, PARAM_NAMES, split_run};
        let mut run_ids: Vec<u32> = records.iter().map(|r| r.run).collect();
        run_ids.sort_unstable();
        run_ids.dedup();
        if run_ids.len() <= warmup_runs {
            return Err(UncertaintyError::Invalid(format!(
                "the dataset has {} run(s); {warmup_runs} warm-up run(s) leave none",
                run_ids.len()
            )));
        }
        let (warmup, kept) = run_ids.split_at(warmup_runs);
        let mut runs = Vec::new();
        let mut first = None;
        for &run in kept {
            let (poses, meas) = split_run(records, run);
            let fail = |e: geometry::capball::CapballError| {
                UncertaintyError::Invalid(format!("run {run}: {e}"))
            };
            let setup =
                CapballSetup::with_ball_from_poses(machine.clone(), &poses).map_err(fail)?;
            let id = setup.identify(&poses, &meas).map_err(fail)?;
            if first.is_none() {
                let times: Option<Vec<f64>> = records
                    .iter()
                    .filter(|r| r.run == run)
                    .map(|r| r.time_s)
                    .collect();
                let times = times.ok_or_else(|| {
                    UncertaintyError::Invalid(format!(
                        "run {run} has no time_s for every pose: the cyclic drift needs the \
                         measurement times (or use the statistical drift model)"
                    ))
                });
                first = Some((setup.stacked_jacobian(&poses), times, id.residual_sigma_um));
            }
            runs.push((run, id.params));
        }
        let Some((jacobian, times, residual_sigma_um)) = first else {
            return Err(UncertaintyError::Invalid("no run to identify".into()));
        };
        // Times are only needed by the cyclic model; without them, pose indices stand in and
        // the statistical model (which ignores time) still runs.
        let times_s = match times {
            Ok(t) => {
                let t0 = t.first().copied().unwrap_or(0.0);
                t.iter().map(|v| v - t0).collect()
            }
            Err(_) => Vec::new(),
        };
        let n = runs.len() as f64;
        let p_hat = (0..PARAM_NAMES.len())
            .map(|j| runs.iter().map(|r| r.1[j]).sum::<f64>() / n)
            .collect();
        Ok(MeasuredCapball {
            jacobian,
            times_s,
            names: PARAM_NAMES.iter().map(|s| s.to_string()).collect(),
            p_hat,
            runs,
            warmup: warmup.to_vec(),
            residual_sigma_um,
        })
    }

    /// The Monte Carlo model with `sources`.
    pub fn model(&self, sources: &CapballSources) -> Result<CapballMc, UncertaintyError> {
        let times: Vec<f64> = if self.times_s.is_empty() {
            if matches!(sources.drift, DriftModel::Cyclic(_)) {
                return Err(UncertaintyError::Invalid(
                    "the dataset has no time_s: the cyclic drift needs the measurement times \
                     (or use the statistical drift model)"
                        .into(),
                ));
            }
            (0..self.jacobian.nrows() / 3).map(|i| i as f64).collect()
        } else {
            self.times_s.clone()
        };
        CapballMc::new(&self.jacobian, &self.p_hat, &self.names, &times, sources)
    }

    /// The identified parameters of the kept runs (for [`coverage_check`]).
    pub fn run_params(&self) -> Vec<Vec<f64>> {
        self.runs.iter().map(|r| r.1.clone()).collect()
    }
}
