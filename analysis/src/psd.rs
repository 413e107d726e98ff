//! A PSD straightness segment of a log.
//!
//! The full 13-error identification of paper 003 (`identify psd`) needs the 51-point laser
//! frame (five segments) and a reference run; a run that moves the PSD along one line gives
//! the straightness of that line only. This takes the PSD `/pose` values along one segment,
//! removes offset and slope from each channel by least squares (beam misalignment, ISO 230-1
//! §8.2 straightness "reference straight line" by least squares) and reports the residual
//! straightness, max − min of the residuals, in µm. For a segment along Z the PSD's x and y
//! channels are the straightness errors EXZ and EYZ.
//!
//! The segment: the longest block of consecutive trajectory poses with `ok` PSD values in
//! which one linear axis moves monotonically and nothing else moves (at least 3 poses; the
//! last of equal length wins), or an explicit pose range.

use std::path::Path;

use crate::contents::{AnalysisError, LogContents, is_ok};
use metrolog_log::trajectory::TrajectoryRow;
use types::Instrument;

/// One PSD point of the segment.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PsdPoint {
    pub pose: u32,
    /// Coordinate along the segment, mm.
    pub u_mm: f64,
    pub x_um: f64,
    pub y_um: f64,
    /// Residuals after removing offset and slope, µm.
    pub x_resid_um: f64,
    pub y_resid_um: f64,
}

/// The straightness of one segment.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PsdSegment {
    /// Moving axis (`X`, `Y` or `Z`).
    pub axis: char,
    pub first_pose: u32,
    pub last_pose: u32,
    pub points: Vec<PsdPoint>,
    /// Slope removed per channel, µm/mm (= mrad): the beam's misalignment.
    pub slope_x_um_per_mm: f64,
    pub slope_y_um_per_mm: f64,
    /// Straightness (max − min of the residuals) of the x and y channels, µm.
    pub straightness_x_um: f64,
    pub straightness_y_um: f64,
}

impl PsdSegment {
    /// ISO 230-1 names of the two straightness errors (`EXZ`, `EYZ` along Z ...).
    pub fn error_names(&self) -> (String, String) {
        match self.axis {
            'Z' => ("EXZ".into(), "EYZ".into()),
            'X' => ("EYX".into(), "EZX".into()),
            _ => ("EXY".into(), "EZY".into()),
        }
    }
}

fn coord(r: &TrajectoryRow, k: usize) -> f64 {
    [
        r.x_mm,
        r.y_mm,
        r.z_mm,
        r.a_deg.unwrap_or(0.0),
        r.c_deg.unwrap_or(0.0),
    ][k]
}

/// Axis (0..3) that alone moves from `a` to `b`, with the sign of the move.
fn single_move(a: &TrajectoryRow, b: &TrajectoryRow) -> Option<(usize, bool)> {
    let moved: Vec<usize> = (0..5)
        .filter(|&k| (coord(a, k) - coord(b, k)).abs() > 1e-3)
        .collect();
    match moved.as_slice() {
        [k] if *k < 3 => Some((*k, coord(b, *k) > coord(a, *k))),
        _ => None,
    }
}

/// Least-squares line `v ≈ a + b·u`: (residuals, slope).
fn detrend(u: &[f64], v: &[f64]) -> (Vec<f64>, f64) {
    let n = u.len() as f64;
    let mu = u.iter().sum::<f64>() / n;
    let mv = v.iter().sum::<f64>() / n;
    let suu: f64 = u.iter().map(|x| (x - mu) * (x - mu)).sum();
    let suv: f64 = u.iter().zip(v).map(|(x, y)| (x - mu) * (y - mv)).sum();
    let b = if suu > 0.0 { suv / suu } else { 0.0 };
    let r = u
        .iter()
        .zip(v)
        .map(|(x, y)| y - mv - b * (x - mu))
        .collect();
    (r, b)
}

fn range(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - v.iter().copied().fold(f64::INFINITY, f64::min)
}

/// The PSD segment of the log at `path` (found automatically).
pub fn psd_from_log(path: &Path) -> Result<PsdSegment, AnalysisError> {
    psd_from_log_with(path, None)
}

/// The PSD segment of the log at `path`, over `poses` (inclusive) when given.
pub fn psd_from_log_with(
    path: &Path,
    poses: Option<(u32, u32)>,
) -> Result<PsdSegment, AnalysisError> {
    let log = LogContents::read(path)?;
    psd_from_contents(&log, poses)
}

/// [`psd_from_log_with`] on a log already read.
pub fn psd_from_contents(
    log: &LogContents,
    poses: Option<(u32, u32)>,
) -> Result<PsdSegment, AnalysisError> {
    let traj = log.trajectory(None)?;
    let values = log.pose_values(Instrument::Psd);
    let no_data = |what: String| {
        AnalysisError::NoData {
        path: log.path.clone(),
        what,
        hint: "a PSD straightness segment needs at least 3 poses along one linear axis with ok PSD values".into(),
    }
    };
    let usable = |r: &TrajectoryRow| {
        values.get(&r.pose).is_some_and(|p| {
            is_ok(p)
                && p.mean.get("x_um").is_some_and(|v| v.is_finite())
                && p.mean.get("y_um").is_some_and(|v| v.is_finite())
        })
    };
    let (lo, hi, axis) = match poses {
        Some((a, b)) => {
            if b as usize > traj.len() || a == 0 || b <= a {
                return Err(AnalysisError::BadOption(format!(
                    "PSD poses {a}-{b}: the trajectory has {} poses",
                    traj.len()
                )));
            }
            let (lo, hi) = (a as usize - 1, b as usize - 1);
            let Some((k, _)) = single_move(&traj[lo], &traj[hi]) else {
                return Err(AnalysisError::BadOption(format!(
                    "PSD poses {a}-{b} do not move along one linear axis"
                )));
            };
            (lo, hi, k)
        }
        None => {
            let mut best: Option<(usize, usize, usize)> = None;
            let mut i = 0;
            while i < traj.len() {
                if !usable(&traj[i]) {
                    i += 1;
                    continue;
                }
                let mut j = i;
                let mut dir: Option<(usize, bool)> = None;
                while j + 1 < traj.len() && usable(&traj[j + 1]) {
                    match (single_move(&traj[j], &traj[j + 1]), dir) {
                        (Some(m), None) => dir = Some(m),
                        (Some(m), Some(d)) if m == d => {}
                        _ => break,
                    }
                    j += 1;
                }
                if let Some((k, _)) = dir
                    && j - i + 1 >= 3
                    && best.is_none_or(|(bl, bh, _)| j - i >= bh - bl)
                {
                    best = Some((i, j, k));
                }
                i = j.max(i + 1);
            }
            best.ok_or_else(|| no_data("no PSD segment found".into()))?
        }
    };
    let rows: Vec<&TrajectoryRow> = traj[lo..=hi].iter().filter(|r| usable(r)).collect();
    if rows.len() < 3 {
        return Err(no_data(format!(
            "poses {}-{} hold {} ok PSD value(s)",
            traj[lo].pose,
            traj[hi].pose,
            rows.len()
        )));
    }
    let get = |r: &TrajectoryRow, ch: &str| {
        values
            .get(&r.pose)
            .and_then(|p| p.mean.get(ch).copied())
            .unwrap_or(f64::NAN)
    };
    let u: Vec<f64> = rows.iter().map(|r| coord(r, axis)).collect();
    let x: Vec<f64> = rows.iter().map(|r| get(r, "x_um")).collect();
    let y: Vec<f64> = rows.iter().map(|r| get(r, "y_um")).collect();
    let (rx, bx) = detrend(&u, &x);
    let (ry, by) = detrend(&u, &y);
    let points = rows
        .iter()
        .enumerate()
        .map(|(k, r)| PsdPoint {
            pose: r.pose,
            u_mm: u[k],
            x_um: x[k],
            y_um: y[k],
            x_resid_um: rx[k],
            y_resid_um: ry[k],
        })
        .collect();
    Ok(PsdSegment {
        axis: ['X', 'Y', 'Z'][axis],
        first_pose: traj[lo].pose,
        last_pose: traj[hi].pose,
        points,
        slope_x_um_per_mm: bx,
        slope_y_um_per_mm: by,
        straightness_x_um: range(&rx),
        straightness_y_um: range(&ry),
    })
}
