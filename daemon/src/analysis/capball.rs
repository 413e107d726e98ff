//! The CapBall poses of a log as the records `identify capball` takes.
//!
//! The CB-3 gives a `/pose` value at every pose of a run, also where the tool is nowhere near
//! the ball (the positioning run, the PSD segment). The CapBall poses are the ones that hold
//! the nominal tool point on one table point: the poses with `a`, `c` columns are grouped by
//! their nominal work point (machine kinematics, to 10 µm) and the largest group in which A or
//! C actually turns is taken. Only `ok` values are used; the others are listed as skipped.

use std::path::Path;

use metrology::capball::{CapballRecord, CapballSetup};
use metrology::kinematics::{Machine, Pose};
use nalgebra::Vector3;

use super::{AnalysisError, LogContents, is_ok};
use crate::log::topics::PoseInstrument;

/// The CapBall dataset of a log.
#[derive(Debug, Clone)]
pub struct CapballFromLog {
    /// Run 1, one record per pose with an `ok` value, in pose order.
    pub records: Vec<CapballRecord>,
    /// Nominal ball centre (table frame) the poses hold the tool on, mm.
    pub ball_mm: Vector3<f64>,
    /// CapBall poses without a usable value: pose and status.
    pub skipped: Vec<(u32, String)>,
}

/// [`capball_from_log_with`] on the machine of paper 001 (`identify capball`'s default).
pub fn capball_from_log(path: &Path) -> Result<CapballFromLog, AnalysisError> {
    let machine = CapballSetup::paper_default().machine;
    capball_from_log_with(path, &machine)
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
    let values = log.pose_values(PoseInstrument::Capball);
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
    let t0 = members
        .iter()
        .filter_map(|&i| values.get(&traj[i].pose))
        .filter(|p| is_ok(p))
        .map(|p| p.t_first_ns)
        .min()
        .unwrap_or(0);
    let mut records = Vec::new();
    let mut skipped = Vec::new();
    for &i in &members {
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
            run: 1,
            pose_index: r.pose,
            time_s: Some(p.t_first_ns.saturating_sub(t0) as f64 * 1e-9),
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
    })
}
