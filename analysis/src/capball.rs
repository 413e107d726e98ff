//! The CapBall poses of a log as the records `identify capball` takes.
//!
//! The CB-3 gives a `/pose` value at every pose of a run, also where the tool is nowhere near
//! the ball (the positioning run, the PSD segment). The CapBall poses are the ones that hold
//! the nominal tool point on one table point: the poses with `a`, `c` columns are grouped by
//! their nominal work point (machine kinematics, to 10 µm) and the largest group in which A or
//! C actually turns is taken. Only `ok` values are used; the others are listed as skipped.
//!
//! Runs (`docs/datasets.md`, CapBall dataset): a log holds one pose table, so the runs are
//! told apart by the A axis. The identification run sweeps A one way; where A turns back the
//! next run (the validation, A reversed) starts. A pose repeated exactly at the turn (the
//! validation starting where the identification ended) belongs to the run it starts.

use std::path::Path;

use geometry::capball::{CapballRecord, CapballSetup};
use geometry::kinematics::{Machine, Pose};
use nalgebra::Vector3;

use crate::contents::{AnalysisError, LogContents, is_ok};
use types::Instrument;

/// The CapBall dataset of a log.
#[derive(Debug, Clone)]
pub struct CapballFromLog {
    /// One record per pose with an `ok` value, in pose order; run 1 up to where A turns back,
    /// run 2 after it, and so on ([`runs_by_a_direction`]).
    pub records: Vec<CapballRecord>,
    /// Nominal ball centre (table frame) the poses hold the tool on, mm.
    pub ball_mm: Vector3<f64>,
    /// CapBall poses without a usable value: pose and status.
    pub skipped: Vec<(u32, String)>,
    /// The machine (kinematic convention) the poses were grouped with.
    pub machine: Machine,
    pub machine_name: String,
}

/// The kinematic conventions tried by [`capball_from_log`]: the `WCAYFXZT` machine of paper
/// 001 (`identify capball`'s default), and the same machine with the table's Y axis read as
/// the tool's position relative to the table (machine coordinates = R_A·R_C·ball), the
/// convention of the simulator's demo scenario.
pub fn machine_candidates() -> Vec<(String, Machine)> {
    let mut out = vec![(
        "WCAYFXZT of paper 001".to_string(),
        CapballSetup::paper_default().machine,
    )];
    let mut cfg = CapballSetup::paper_machine_config();
    cfg.axes.insert(
        "Y".into(),
        geometry::kinematics::AxisConfig {
            direction: Some([0.0, -1.0, 0.0]),
            pivot_mm: None,
        },
    );
    if let Ok(m) = Machine::from_config(&cfg) {
        out.push((
            "WCAYFXZT, y = tool relative to table (simulator convention)".to_string(),
            m,
        ));
    }
    out
}

/// The CapBall poses of the log at `path`, grouped with whichever of
/// [`machine_candidates`] holds the most poses on one ball.
pub fn capball_from_log(path: &Path) -> Result<CapballFromLog, AnalysisError> {
    let log = LogContents::read(path)?;
    capball_from_contents_auto(&log)
}

/// [`capball_from_log`] on a log already read.
pub fn capball_from_contents_auto(log: &LogContents) -> Result<CapballFromLog, AnalysisError> {
    let mut best: Option<CapballFromLog> = None;
    let mut last_err = None;
    for (name, m) in machine_candidates() {
        match capball_from_contents(log, &m) {
            Ok(mut c) => {
                c.machine_name = name;
                let n = c.records.len() + c.skipped.len();
                if best
                    .as_ref()
                    .is_none_or(|b| n > b.records.len() + b.skipped.len())
                {
                    best = Some(c);
                }
            }
            Err(e) => last_err = Some(e),
        }
    }
    match (best, last_err) {
        (Some(b), _) => Ok(b),
        (None, Some(e)) => Err(e),
        (None, None) => Err(AnalysisError::BadOption("no machine description".into())),
    }
}

/// The CapBall poses of the log at `path` on `machine`.
pub fn capball_from_log_with(
    path: &Path,
    machine: &Machine,
) -> Result<CapballFromLog, AnalysisError> {
    let log = LogContents::read(path)?;
    capball_from_contents(&log, machine)
}

/// [`capball_from_log_with`] on a log already read.
pub fn capball_from_contents(
    log: &LogContents,
    machine: &Machine,
) -> Result<CapballFromLog, AnalysisError> {
    let traj = log.trajectory(None)?;
    let values = log.pose_values(Instrument::Capball);
    let no_data = |what: &str, hint: &str| AnalysisError::NoData {
        path: log.path.clone(),
        what: what.into(),
        hint: hint.into(),
    };
    if values.is_empty() {
        return Err(no_data(
            "the log has no CapBall pose values",
            "was the CB-3 connected and listed in the detector's instruments?",
        ));
    }
    // Group the rotary poses by work point (10 µm cells, neighbours merged by distance).
    let mut groups: Vec<(Vector3<f64>, Vec<usize>)> = Vec::new();
    for (i, r) in traj.iter().enumerate() {
        let (Some(a), Some(c)) = (r.a_deg, r.c_deg) else {
            continue;
        };
        let pose = Pose {
            x_mm: r.x_mm,
            y_mm: r.y_mm,
            z_mm: r.z_mm,
            a_deg: a,
            b_deg: 0.0,
            c_deg: c,
        };
        let w = machine.nominal_work_point_mm(&pose);
        if !w.iter().all(|v| v.is_finite()) {
            continue;
        }
        match groups.iter_mut().find(|(g, _)| (g - w).norm() <= 0.01) {
            Some((_, members)) => members.push(i),
            None => groups.push((w, vec![i])),
        }
    }
    let turns = |m: &[usize]| {
        let first = &traj[m[0]];
        m.iter().any(|&i| {
            (traj[i].a_deg.unwrap_or(0.0) - first.a_deg.unwrap_or(0.0)).abs() > 1e-3
                || (traj[i].c_deg.unwrap_or(0.0) - first.c_deg.unwrap_or(0.0)).abs() > 1e-3
        })
    };
    let (ball_mm, members) = groups
        .into_iter()
        .filter(|(_, m)| turns(m))
        .max_by_key(|(_, m)| m.len())
        .ok_or_else(|| {
            no_data(
                "no poses of the trajectory hold the tool on a ball while A or C turns",
                "does the trajectory have a_deg, c_deg columns, and is the machine description right?",
            )
        })?;
    // Times in the simulated machine's seconds when the run compressed time, as positioning.
    let time_scale = super::positioning::time_scale(log)?;
    let t0 = members
        .iter()
        .filter_map(|&i| values.get(&traj[i].pose))
        .filter(|p| is_ok(p))
        .map(|p| p.t_first_ns)
        .min()
        .unwrap_or(0);
    let a_of: Vec<f64> = members
        .iter()
        .map(|&i| traj[i].a_deg.unwrap_or(0.0))
        .collect();
    let runs = runs_by_a_direction(&a_of);
    let mut records = Vec::new();
    let mut skipped = Vec::new();
    for (&i, &run) in members.iter().zip(&runs) {
        let r = &traj[i];
        let Some(p) = values.get(&r.pose) else {
            skipped.push((r.pose, "no value".to_string()));
            continue;
        };
        let e = ["ex_um", "ey_um", "ez_um"].map(|k| p.mean.get(k).copied().unwrap_or(f64::NAN));
        if !is_ok(p) || e.iter().any(|v| !v.is_finite()) {
            skipped.push((r.pose, p.status.name().to_string()));
            continue;
        }
        records.push(CapballRecord {
            run,
            pose_index: r.pose,
            time_s: Some(p.t_first_ns.saturating_sub(t0) as f64 * 1e-9 * time_scale),
            pose: Pose {
                x_mm: r.x_mm,
                y_mm: r.y_mm,
                z_mm: r.z_mm,
                a_deg: r.a_deg.unwrap_or(0.0),
                b_deg: 0.0,
                c_deg: r.c_deg.unwrap_or(0.0),
            },
            e_um: e,
        });
    }
    Ok(CapballFromLog {
        records,
        ball_mm,
        skipped,
        machine: machine.clone(),
        machine_name: machine.chain.clone(),
    })
}

/// Run number (1, 2, …) of each pose of a CapBall sequence with A angles `a_deg`: a new run
/// starts where A turns back. Poses that repeat the turning angle before the turn (the next run
/// starting where the last ended) go to the new run.
pub fn runs_by_a_direction(a_deg: &[f64]) -> Vec<u32> {
    const SAME_DEG: f64 = 1e-6;
    let mut runs = vec![1u32; a_deg.len()];
    let mut run = 1;
    let mut dir = 0.0f64;
    for i in 1..a_deg.len() {
        let d = a_deg[i] - a_deg[i - 1];
        if d.abs() > SAME_DEG {
            if dir != 0.0 && d.signum() != dir {
                run += 1;
                let mut j = i - 1;
                while j > 0 && (a_deg[j] - a_deg[j - 1]).abs() <= SAME_DEG {
                    runs[j] = run;
                    j -= 1;
                }
            }
            dir = d.signum();
        }
        runs[i] = run;
    }
    runs
}

/// An identification of the parameters a pose set can determine.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SubsetIdentification {
    /// Identified parameters: name, value, standard uncertainty (k = 1).
    pub params: Vec<(String, f64, f64)>,
    /// Parameters the poses cannot separate from the others, held at 0.
    pub fixed: Vec<String>,
    pub condition_number: f64,
    pub residual_rms_um: [f64; 3],
    pub n_poses: usize,
}

/// Condition number above which a parameter is taken as not determined (as
/// `CapballSetup::identify`).
const MAX_CONDITION: f64 = 1e8;

/// Least squares (paper 001, eq. 5) on the parameters the poses determine: while the
/// Jacobian is singular, the parameter with the largest share of the least-determined
/// direction (smallest singular value's right vector) is held at 0 and dropped. A short pose
/// sequence (the demo's 20 poses on a 4 × 5 grid of A and C) confounds some link errors with
/// the setup errors; this says which, instead of failing.
pub fn identify_subset(
    setup: &CapballSetup,
    poses: &[Pose],
    measured_um: &[[f64; 3]],
) -> Result<SubsetIdentification, AnalysisError> {
    use geometry::capball::{CapballError, PARAM_NAMES};
    use nalgebra::{DMatrix, DVector};
    let n = poses.len();
    if measured_um.len() != n {
        return Err(CapballError::LengthMismatch {
            poses: n,
            values: measured_um.len(),
        }
        .into());
    }
    let full = setup.stacked_jacobian(poses);
    let b = DVector::from_iterator(3 * n, measured_um.iter().flat_map(|m| m.iter().copied()));
    if b.iter().any(|v| !v.is_finite()) {
        return Err(CapballError::NonFinite { index: 0 }.into());
    }
    let mut keep: Vec<usize> = (0..PARAM_NAMES.len()).collect();
    loop {
        if 3 * n <= keep.len() || keep.is_empty() {
            return Err(CapballError::TooFewPoses {
                n,
                eq: 3 * n,
                need: keep.len() + 1,
            }
            .into());
        }
        let j = DMatrix::from_fn(3 * n, keep.len(), |r, c| full[(r, keep[c])]);
        let svd = geometry::linalg::svd(j.clone(), true, true)
            .ok_or(CapballError::Undecomposable("identification Jacobian"))?;
        let sv = &svd.singular_values;
        let (imax, imin) = (sv.imax(), sv.imin());
        let condition = if sv[imin] > 0.0 {
            sv[imax] / sv[imin]
        } else {
            f64::INFINITY
        };
        let Some(vt) = svd.v_t.as_ref() else {
            return Err(CapballError::Singular {
                condition,
                worst: "?".into(),
            }
            .into());
        };
        if condition.is_nan() || condition >= MAX_CONDITION {
            let v = vt.row(imin);
            let worst = (0..keep.len())
                .max_by(|&a, &c| v[a].abs().total_cmp(&v[c].abs()))
                .unwrap_or(0);
            keep.remove(worst);
            continue;
        }
        let p = svd
            .solve(&b, 0.0)
            .map_err(|e| CapballError::Dataset(e.to_string()))?;
        let resid = &b - &j * &p;
        let dof = 3 * n - keep.len();
        let s2 = resid.norm_squared() / dof as f64;
        // cov = s² V Σ⁻² Vᵀ
        let mut vs = vt.transpose();
        for i in 0..keep.len() {
            vs.column_mut(i).scale_mut(1.0 / sv[i]);
        }
        let cov = (&vs * vs.transpose()) * s2;
        let mut rms = [0.0; 3];
        for i in 0..n {
            for (k, r) in rms.iter_mut().enumerate() {
                *r += resid[3 * i + k].powi(2);
            }
        }
        for r in &mut rms {
            *r = (*r / n as f64).sqrt();
        }
        return Ok(SubsetIdentification {
            params: keep
                .iter()
                .enumerate()
                .map(|(c, &k)| {
                    (
                        PARAM_NAMES[k].to_string(),
                        p[c],
                        cov[(c, c)].max(0.0).sqrt(),
                    )
                })
                .collect(),
            fixed: (0..PARAM_NAMES.len())
                .filter(|k| !keep.contains(k))
                .map(|k| PARAM_NAMES[k].to_string())
                .collect(),
            condition_number: condition,
            residual_rms_um: rms,
            n_poses: n,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::runs_by_a_direction;

    #[test]
    fn a_reversal_starts_the_next_run() {
        // Identification 0 → −90, validation −90 → 0 starting on the same pose.
        let a = [0.0, -30.0, -60.0, -90.0, -90.0, -60.0, -30.0, 0.0];
        assert_eq!(runs_by_a_direction(&a), vec![1, 1, 1, 1, 2, 2, 2, 2]);
        // Without the repeated pose, and with a constant-A stretch inside a run.
        let a = [0.0, 0.0, -45.0, -90.0, -45.0, 0.0, 45.0];
        assert_eq!(runs_by_a_direction(&a), vec![1, 1, 1, 1, 2, 2, 2]);
        // One sweep is one run; a sequence of one pose too.
        assert_eq!(runs_by_a_direction(&[0.0, -10.0, -20.0]), vec![1, 1, 1]);
        assert_eq!(runs_by_a_direction(&[5.0]), vec![1]);
        assert!(runs_by_a_direction(&[]).is_empty());
    }
}
