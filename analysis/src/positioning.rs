//! The ISO 230-2 positioning run of a log as a [`PositioningData`].
//!
//! # Selection and the target rule
//!
//! The run is a block of consecutive trajectory poses in which only `x` changes: it starts at
//! the first pose that has an interferometer `/pose` value and ends before the first pose
//! whose `y`, `z`, `a` or `c` differs from the first pose's (`--poses A-B` gives the block
//! instead; poses in it off the first pose's line are left out).
//!
//! The direction of a visit is the sign of the move into it (from the previous trajectory
//! pose, or from the datum for pose 1); a pose with no move keeps the previous direction.
//!
//! A target is an `x` (to 1 µm) that is approached from **both** directions in the run and has
//! at least one `ok` value. The reversal (overtravel) poses of an ISO 230-2 cycle are reached
//! from one side only — the extreme ones by construction — and so are never targets, whatever
//! their dwell. A run with no position approached from both sides is unidirectional: then
//! every position with an `ok` value is a target.
//!
//! The cycle of a visit is the count of visits of its (target, direction) so far, so a visit
//! whose value is not `ok` (beam interruption, never steady) keeps its cycle number and shows
//! up as a missing reading in the analysis.
//!
//! `time_s` counts from the run's first `ok` value (`t_first_ns`), times the run metadata's
//! `time_scale` when present (a simulated run whose slow effects run faster than real time).
//!
//! # Deviation
//!
//! The LI-80 reads the displacement from its datum, taken at connect (the driver sends
//! `DATUM`) with the machine at home; the driver compensates it for air and normalises it to
//! 20 °C with the material temperature (`position_um` is the 20 °C length). So
//! `deviation_um = position_um − (x_mm − x_datum_mm)·1000`, with `x_datum_mm` = 0 (home) unless
//! the run metadata gives `datum_x_mm`, and the data carry `material_compensation = true`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use positioning::axis_model::Direction;
use positioning::positioning_data::{PositioningData, Reading};

use crate::contents::{AnalysisError, LogContents, is_ok};
use metrolog_log::topics::PoseMsg;
use metrolog_log::trajectory::TrajectoryRow;
use types::Instrument;

/// Options of [`positioning_from_log`].
#[derive(Debug, Clone, Default)]
pub struct PositioningOptions {
    /// Trajectory file instead of the log's attachment.
    pub trajectory: Option<PathBuf>,
    /// Explicit pose range (inclusive) of the positioning run.
    pub poses: Option<(u32, u32)>,
    /// Datum position of the interferometer on X, mm (default: metadata `datum_x_mm`, else 0).
    pub datum_x_mm: Option<f64>,
}

/// `A-B` (inclusive, 1 ≤ A ≤ B).
pub fn parse_pose_range(s: &str) -> Result<(u32, u32), AnalysisError> {
    let bad = || AnalysisError::BadOption(format!("--poses `{s}`: expected A-B, e.g. 1-36"));
    let (a, b) = s.split_once('-').ok_or_else(bad)?;
    let a: u32 = a.trim().parse().map_err(|_| bad())?;
    let b: u32 = b.trim().parse().map_err(|_| bad())?;
    if a == 0 || b < a {
        return Err(bad());
    }
    Ok((a, b))
}

/// Tolerances of "the same position": 1 µm on linear axes, 0.001° on rotary ones.
const LIN_TOL_MM: f64 = 1e-3;
const ROT_TOL_DEG: f64 = 1e-3;

fn same_off_axis(a: &TrajectoryRow, b: &TrajectoryRow) -> bool {
    let rot =
        |x: Option<f64>, y: Option<f64>| (x.unwrap_or(0.0) - y.unwrap_or(0.0)).abs() <= ROT_TOL_DEG;
    (a.y_mm - b.y_mm).abs() <= LIN_TOL_MM
        && (a.z_mm - b.z_mm).abs() <= LIN_TOL_MM
        && rot(a.a_deg, b.a_deg)
        && rot(a.c_deg, b.c_deg)
}

/// Position key at 1 µm resolution.
fn key_um(x_mm: f64) -> i64 {
    (x_mm * 1000.0).round() as i64
}

/// Reads the positioning run of the log at `path` (see the module doc for the rules).
pub fn positioning_from_log(
    path: &Path,
    opts: &PositioningOptions,
) -> Result<PositioningData, AnalysisError> {
    let log = LogContents::read(path)?;
    positioning_from_contents(&log, opts)
}

/// [`positioning_from_log`] on a log already read.
pub fn positioning_from_contents(
    log: &LogContents,
    opts: &PositioningOptions,
) -> Result<PositioningData, AnalysisError> {
    let traj = log.trajectory(opts.trajectory.as_deref())?;
    let values = log.pose_values(Instrument::Interferometer);
    if values.is_empty() {
        return Err(no_data(
            log,
            "the log has no interferometer pose values".into(),
            "was the LI-80 connected and listed in the detector's instruments?",
        ));
    }
    let (lo, hi) = run_range(log, &traj, &values, opts)?;
    let datum_x_mm = datum_x_mm(log, opts)?;
    let time_scale = time_scale(log)?;
    let visits = visits(&traj, lo, hi, datum_x_mm);
    let datum_note = check_datum_epochs(log, &traj, &visits, &values)?;
    if let Some(far) = far_from_target(&traj, &visits, &values, datum_x_mm) {
        return Err(no_data(log, far, MISPLACED_HINT));
    }
    let targets = measured_targets(&traj, &visits, &values);
    if targets.len() < 2 {
        return Err(no_data(
            log,
            format!(
                "poses {}-{} hold {} measured target(s); a positioning run needs at least 2",
                traj[lo].pose,
                traj[hi].pose,
                targets.len()
            ),
            "choose the run with --poses A-B",
        ));
    }
    let t0_ns = visits
        .iter()
        .filter_map(|(i, _)| values.get(&traj[*i].pose))
        .filter(|p| is_ok(p))
        .map(|p| p.t_first_ns)
        .min()
        .unwrap_or(0);
    let mut counts: BTreeMap<(i64, bool), usize> = BTreeMap::new();
    let mut readings = Vec::new();
    for &(i, d) in &visits {
        let row = &traj[i];
        let k = key_um(row.x_mm);
        let Some(index) = targets.iter().position(|t| *t == k).map(|p| p + 1) else {
            continue;
        };
        let c = counts.entry((k, d == Direction::Up)).or_default();
        *c += 1;
        let cycle = *c;
        let Some(p) = values.get(&row.pose).filter(|p| is_ok(p)) else {
            continue; // missing reading: the analysis reports it
        };
        let Some(pos_um) = p.mean.get("position_um").copied().filter(|v| v.is_finite()) else {
            continue;
        };
        let (air_c, material_c) = environment_of(log, p);
        readings.push(Reading {
            cycle,
            direction: d,
            index,
            target_mm: row.x_mm,
            deviation_um: pos_um - (row.x_mm - datum_x_mm) * 1000.0,
            time_s: p.t_first_ns.saturating_sub(t0_ns) as f64 * 1e-9 * time_scale,
            air_c,
            material_c,
        });
    }
    let alpha = log
        .config()
        .and_then(|c| c.get("interferometer")?.get("alpha_um_per_m_k")?.as_float())
        .or_else(|| {
            log.run_metadata
                .get("alpha_um_per_m_k")
                .and_then(|s| s.parse().ok())
        });
    let mut metadata = log.run_metadata.clone();
    metadata.insert("axis".into(), "X".into());
    metadata.insert("source".into(), log.path.display().to_string());
    metadata.insert(
        "poses".into(),
        format!("{}-{}", traj[lo].pose, traj[hi].pose),
    );
    metadata.insert("datum_x_mm".into(), datum_x_mm.to_string());
    if let Some(n) = datum_note {
        metadata.insert(DATUM_NOTE_KEY.into(), n);
    }
    if let Some(n) = off_target_note(&traj, &visits, &values) {
        metadata.insert(OFF_TARGET_NOTE_KEY.into(), n);
    }
    if let Some(a) = alpha {
        metadata.insert("alpha_um_per_m_k".into(), a.to_string());
    }
    header_metadata(log, &mut metadata);
    if let Some(d) = log.damage() {
        metadata.insert(::positioning::positioning_data::LOG_DAMAGE_KEY.into(), d);
    }
    let data = PositioningData {
        axis: Some("X".into()),
        alpha_um_per_m_k: alpha,
        material_compensation: true,
        has_times: true,
        metadata,
        readings,
    };
    data.validate()?;
    Ok(data)
}

/// Key of the positioning data's metadata that notes the datum epochs a run went through
/// (shown among the report's notes).
pub const DATUM_NOTE_KEY: &str = "datum_note";

/// Run metadata key of the note on the values the daemon marked `off_target` (shown among the
/// report's notes).
pub const OFF_TARGET_NOTE_KEY: &str = "off_target_note";

/// The note on the run's `off_target` values (the daemon found them farther than the pose's
/// tolerance from their targets, docs/design.md "Values off their target"): they
/// are missing readings, and why.
fn off_target_note(
    traj: &[TrajectoryRow],
    visits: &[(usize, Direction)],
    values: &BTreeMap<u32, &PoseMsg>,
) -> Option<String> {
    let poses: Vec<String> = visits
        .iter()
        .filter_map(|(i, _)| values.get(&traj[*i].pose))
        .filter(|p| p.status == types::PoseStatus::OffTarget)
        .map(|p| p.pose.to_string())
        .collect();
    (!poses.is_empty()).then(|| {
        format!(
            "{} pose value(s) are off_target (pose {}): the interferometer read farther from the target there than its tolerance when it was recorded ({} mm, or half the way to the nearest other target but at least {} mm in runs since that rule; another pose's samples, or a zero that was not the datum); they are missing readings",
            poses.len(),
            poses.join(", "),
            types::OFF_TARGET_TOL_UM / 1000.0,
            types::OFF_TARGET_FLOOR_UM / 1000.0
        )
    })
}

/// A run whose interferometer lost its datum (beam interrupted, reconnect, a service start
/// mid-program: pose values `datum_lost`, docs/design.md "Datum epochs") holds lengths against
/// more than one zero. Accepted when every lost epoch was re-referenced at the run's reference
/// pose (its `/event` record) or a later epoch was: the `datum_lost` values are missing
/// readings, noted with their poses (returned). Refused, saying why, when a lost epoch was
/// never re-referenced, nor any after it (the
/// lengths after the loss are from another zero) or when `ok` values come from an epoch that
/// was not the run's nor re-referenced.
fn check_datum_epochs(
    log: &LogContents,
    traj: &[TrajectoryRow],
    visits: &[(usize, Direction)],
    values: &BTreeMap<u32, &PoseMsg>,
) -> Result<Option<String>, AnalysisError> {
    let in_run: Vec<&PoseMsg> = visits
        .iter()
        .filter_map(|(i, _)| values.get(&traj[*i].pose).copied())
        .collect();
    let referenced = |e: u32| log.rereferences.iter().any(|r| r.epoch == e);
    if let Some(p) = in_run
        .iter()
        .find(|p| is_ok(p) && p.datum_epoch != 0 && !referenced(p.datum_epoch))
    {
        return Err(no_data(
            log,
            format!(
                "the run mixes datum epochs without a reference: pose {} is ok in datum epoch {}, which was never re-referenced (no `epoch {} referenced` record in /event)",
                p.pose, p.datum_epoch, p.datum_epoch
            ),
            "evaluate the poses of one epoch with --poses A-B, or measure the run again",
        ));
    }
    let lost: Vec<&PoseMsg> = in_run
        .iter()
        .copied()
        .filter(|p| p.status == types::PoseStatus::DatumLost)
        .collect();
    let (Some(first), Some(last)) = (lost.first(), lost.last()) else {
        return Ok(None);
    };
    // A lost value is a missing reading when the loss was recovered: its epoch, or a later
    // one, was re-referenced (a service started mid-program loses epoch 0 and re-references
    // epoch 1).
    let recovered = |e: u32| log.rereferences.iter().any(|r| r.epoch >= e);
    if let Some(p) = lost.iter().find(|p| !recovered(p.datum_epoch)) {
        return Err(refuse_lost(log, visits, traj, p.pose, lost.len()));
    }
    let refs: Vec<String> = log
        .rereferences
        .iter()
        .map(|r| format!("epoch {} at pose {}", r.epoch, r.pose))
        .collect();
    Ok(Some(format!(
        "{} pose value(s) between poses {} and {} are datum_lost (the interferometer's datum was lost and re-referenced: {}): they are missing readings, the reference visits included",
        lost.len(),
        first.pose,
        last.pose,
        refs.join(", ")
    )))
}

/// The refusal of a run whose datum was lost at pose `first` and never re-referenced.
fn refuse_lost(
    log: &LogContents,
    visits: &[(usize, Direction)],
    traj: &[TrajectoryRow],
    first: u32,
    n_lost: usize,
) -> AnalysisError {
    let start = visits.first().map_or(first, |(i, _)| traj[*i].pose);
    let before = if first > start + 1 {
        format!(
            "evaluate the poses measured before it with --poses {start}-{}, or ",
            first - 1
        )
    } else {
        String::new()
    };
    no_data(
        log,
        format!(
            "the interferometer lost its datum at pose {first} ({n_lost} pose value(s) of the run are datum_lost) and it was never re-referenced: the lengths after it are measured from another zero and cannot be compared with the ones before",
        ),
        &format!(
            "{before}give the run a reference pose ([run] reference_pose, a pose at the datum position) so the daemon re-references there, and measure the run again"
        ),
    )
}

/// What the report's header reads from a log: the sensor (the positions are the
/// interferometer's), each instrument's `*IDN?` identity (`instrument.<name>`, the last
/// connection of each), and the ranges of the air pressure and humidity
/// (`air_pressure_kpa`, `humidity_pct`: "min / mean / max") of the environment records.
fn header_metadata(log: &LogContents, m: &mut std::collections::BTreeMap<String, String>) {
    m.entry("sensor".into())
        .or_insert_with(|| "laser interferometer (the log's /interferometer positions)".into());
    for r in &log.instrument_records {
        if let (Some(name), Some(id)) = (r.get("instrument"), r.get("identity")) {
            let port = r.get("port").map_or(String::new(), |p| format!(" on {p}"));
            m.insert(format!("instrument.{name}"), format!("{id}{port}"));
        }
    }
    let stats = |v: Vec<f64>, digits: usize, unit: &str| {
        let v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
        (!v.is_empty()).then(|| {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            format!("{lo:.digits$} / {mean:.digits$} / {hi:.digits$} {unit} (min / mean / max)")
        })
    };
    let env = log.environment.iter().filter(|e| e.valid);
    if let Some(p) = stats(env.clone().map(|e| e.air_pa / 1000.0).collect(), 3, "kPa") {
        m.insert("air_pressure_kpa".into(), p);
    }
    if let Some(h) = stats(env.map(|e| e.rh_pct).collect(), 1, "%RH") {
        m.insert("humidity_pct".into(), h);
    }
}

/// Farthest an `ok` interferometer value may be from its pose's target, µm. No machine tool
/// this evaluates errs by 2 mm; a value that far is another pose's (its dwell window was placed
/// on the wrong samples, e.g. by a timing fault while the run was recorded), or the datum
/// position is not what the log says.
pub const MAX_FROM_TARGET_UM: f64 = types::OFF_TARGET_TOL_UM;

const MISPLACED_HINT: &str = "check the datum position (the run metadata's datum_x_mm, 0 when absent); if it is right, the run's pose values cannot be trusted: measure it again";

/// The first `ok` value of the run farther than [`MAX_FROM_TARGET_UM`] from its target (its
/// reading `position_um` against `(x_mm − datum_x_mm)·1000`), described.
fn far_from_target(
    traj: &[TrajectoryRow],
    visits: &[(usize, Direction)],
    values: &BTreeMap<u32, &PoseMsg>,
    datum_x_mm: f64,
) -> Option<String> {
    visits.iter().find_map(|&(i, _)| {
        let row = &traj[i];
        let p = values.get(&row.pose).filter(|p| is_ok(p))?;
        let got = *p.mean.get("position_um")?;
        let want = (row.x_mm - datum_x_mm) * 1000.0;
        ((got - want).abs() > MAX_FROM_TARGET_UM).then(|| {
            format!(
                "pose {}'s interferometer value is ok but {:.4} mm from its target (read {:.1} µm, the target {} mm from the datum at {} mm expects {:.1} µm); no machine errs by more than {} mm: its steady window holds another pose's samples, so no value of this run can be trusted",
                row.pose,
                (got - want).abs() / 1000.0,
                got,
                row.x_mm,
                datum_x_mm,
                want,
                MAX_FROM_TARGET_UM / 1000.0
            )
        })
    })
}

fn no_data(log: &LogContents, what: String, hint: &str) -> AnalysisError {
    AnalysisError::NoData {
        path: log.path.clone(),
        what,
        hint: hint.into(),
    }
}

/// The run's range as 0-based trajectory indices `[lo, hi]`: the option's, or the first block
/// of poses with a value in which only x changes.
fn run_range(
    log: &LogContents,
    traj: &[TrajectoryRow],
    values: &BTreeMap<u32, &PoseMsg>,
    opts: &PositioningOptions,
) -> Result<(usize, usize), AnalysisError> {
    if let Some((a, b)) = opts.poses {
        if b as usize > traj.len() {
            return Err(AnalysisError::BadOption(format!(
                "--poses {a}-{b}: the trajectory has {} poses",
                traj.len()
            )));
        }
        return Ok((a as usize - 1, b as usize - 1));
    }
    let lo = traj
        .iter()
        .position(|r| values.contains_key(&r.pose))
        .ok_or_else(|| {
            no_data(
                log,
                "no interferometer pose value matches a trajectory pose".into(),
                "is this the trajectory of the run? (give it with --trajectory)",
            )
        })?;
    let mut hi = lo;
    while hi + 1 < traj.len() && same_off_axis(&traj[lo], &traj[hi + 1]) {
        hi += 1;
    }
    Ok((lo, hi))
}

fn datum_x_mm(log: &LogContents, opts: &PositioningOptions) -> Result<f64, AnalysisError> {
    if let Some(d) = opts.datum_x_mm {
        return Ok(d);
    }
    match log.run_metadata.get("datum_x_mm") {
        Some(s) => s.trim().parse::<f64>().map_err(|_| {
            no_data(
                log,
                format!("metadata datum_x_mm = `{s}` is not a number"),
                "give the datum with the option instead",
            )
        }),
        None => Ok(0.0),
    }
}

/// A simulated run may compress time (sim `time_scale`: slow effects run that much faster);
/// the readings' times are then given in the simulated machine's seconds.
pub(crate) fn time_scale(log: &LogContents) -> Result<f64, AnalysisError> {
    match log.run_metadata.get("time_scale") {
        Some(s) => s
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| {
                no_data(
                    log,
                    format!("metadata time_scale = `{s}` is not a positive number"),
                    "the log's metadata is damaged",
                )
            }),
        None => Ok(1.0),
    }
}

/// Visits of the run: (trajectory index, direction of approach).
fn visits(
    traj: &[TrajectoryRow],
    lo: usize,
    hi: usize,
    datum_x_mm: f64,
) -> Vec<(usize, Direction)> {
    let mut visits = Vec::new();
    let mut prev_dir = Direction::Up;
    for i in lo..=hi {
        let from = if i == 0 { datum_x_mm } else { traj[i - 1].x_mm };
        let dx = traj[i].x_mm - from;
        let dir = if dx > LIN_TOL_MM / 2.0 {
            Direction::Up
        } else if dx < -LIN_TOL_MM / 2.0 {
            Direction::Down
        } else {
            prev_dir
        };
        prev_dir = dir;
        // In an explicit range, poses off the line of the first one are not part of the run.
        if same_off_axis(&traj[lo], &traj[i]) {
            visits.push((i, dir));
        }
    }
    visits
}

/// The targets (position keys, µm) with an ok value — approached from both sides when the
/// run is bidirectional.
fn measured_targets(
    traj: &[TrajectoryRow],
    visits: &[(usize, Direction)],
    values: &BTreeMap<u32, &PoseMsg>,
) -> Vec<i64> {
    let mut dirs: BTreeMap<i64, (bool, bool, bool)> = BTreeMap::new();
    for &(i, d) in visits {
        let e = dirs.entry(key_um(traj[i].x_mm)).or_default();
        match d {
            Direction::Up => e.0 = true,
            Direction::Down => e.1 = true,
        }
        if values.get(&traj[i].pose).is_some_and(|p| is_ok(p)) {
            e.2 = true;
        }
    }
    let bidirectional = dirs.values().any(|(u, d, _)| *u && *d);
    dirs.iter()
        .filter(|(_, (u, d, ok))| *ok && (!bidirectional || (*u && *d)))
        .map(|(k, _)| *k)
        .collect()
}

/// Air and mean material temperature of the environment record nearest the pose's window.
fn environment_of(log: &LogContents, p: &PoseMsg) -> (Option<f64>, Option<f64>) {
    let mid_ns = p.t_first_ns / 2 + p.t_last_ns / 2;
    let env = log.environment_at(mid_ns);
    let air_c = env.map(|e| e.air_c).filter(|v| v.is_finite());
    let material_c = env.and_then(|e| {
        let m: Vec<f64> = e
            .material_c
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .collect();
        (!m.is_empty()).then(|| m.iter().sum::<f64>() / m.len() as f64)
    });
    (air_c, material_c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::LoggedPose;
    use metrolog_log::topics::PoseMsg;
    use types::PoseStatus;

    /// A log in memory: trajectory of x values (y = z = 0), interferometer value at each pose
    /// = `pos_um(pose)` (None: never steady), pose k measured at k seconds.
    fn log(xs: &[f64], pos_um: impl Fn(u32, f64) -> Option<f64>) -> LogContents {
        let mut traj = String::from("pose,x_mm,y_mm,z_mm\n");
        let mut poses = Vec::new();
        for (k, x) in xs.iter().enumerate() {
            let no = k as u32 + 1;
            traj += &format!("{no},{x},0,0\n");
            let v = pos_um(no, *x);
            poses.push(LoggedPose {
                log_ns: 0,
                msg: PoseMsg {
                    instrument: Instrument::Interferometer,
                    pose: no,
                    status: if v.is_some() {
                        PoseStatus::Ok
                    } else {
                        PoseStatus::NeverSteady
                    },
                    n: 10,
                    mean: v
                        .map(|v| [("position_um".to_string(), v)].into())
                        .unwrap_or_default(),
                    std: BTreeMap::new(),
                    t_first_ns: no as u64 * 1_000_000_000,
                    t_last_ns: no as u64 * 1_000_000_000,
                    datum_epoch: 0,
                },
            });
        }
        LogContents {
            path: "mem.mcap".into(),
            poses,
            attachments: [(
                metrolog_log::TRAJECTORY_ATTACHMENT.to_string(),
                traj.into_bytes(),
            )]
            .into(),
            ..LogContents::default()
        }
    }

    #[test]
    fn a_run_whose_datum_was_lost_is_refused_with_the_pose_and_the_range_before() {
        // Up 10, 20, 30, back to 0, then up again; the datum is lost from pose 5 on (as after
        // a reconnect the LI-80 reads about 0 wherever the axis stands).
        let xs = [10.0, 20.0, 30.0, 0.0, 10.0, 20.0, 30.0];
        let mut l = log(&xs, |no, x| Some(if no < 5 { x * 1000.0 } else { 0.0045 }));
        for p in l.poses.iter_mut().filter(|p| p.msg.pose >= 5) {
            p.msg.status = PoseStatus::DatumLost;
            p.msg.mean.clear();
        }
        let e = positioning_from_contents(&l, &PositioningOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("lost its datum at pose 5 (3 pose value(s)"),
            "{e}"
        );
        assert!(e.contains("--poses 1-4"), "{e}");
        // The poses before it are a run of their own.
        let d = positioning_from_contents(
            &l,
            &PositioningOptions {
                poses: Some((1, 4)),
                ..PositioningOptions::default()
            },
        )
        .unwrap();
        // 10, 20, 30 and the return to 0, all on the run's first zero.
        assert_eq!(d.readings.len(), 4);
        assert!(d.readings.iter().all(|r| r.deviation_um.abs() < 1e-9));
    }

    /// A value `ok` but 100 mm off its target (seen once in a HIL run under overload: pose 12
    /// read the X 0 of pose 13) refuses the run; 1.9 mm of error is still a machine's.
    #[test]
    fn a_value_another_pose_s_is_refused_and_a_large_error_is_not() {
        let xs = [100.0, 200.0, 0.0, 100.0, 200.0, 0.0];
        let l = log(&xs, |no, x| Some(if no == 5 { -2.8 } else { x * 1000.0 }));
        let e = positioning_from_contents(&l, &PositioningOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("pose 5's interferometer value is ok but 200.0028 mm"),
            "{e}"
        );
        assert!(e.contains("another pose's samples"), "{e}");
        let l = log(&xs, |_, x| Some(x * 1000.0 + 1900.0));
        let d = positioning_from_contents(&l, &PositioningOptions::default()).unwrap();
        assert!(
            d.readings
                .iter()
                .all(|r| (r.deviation_um - 1900.0).abs() < 1e-6)
        );
        // The same 100 mm misreading is fine when the datum really is elsewhere.
        let l = log(&xs, |_, x| Some((x - 50.0) * 1000.0));
        let opts = PositioningOptions {
            datum_x_mm: Some(50.0),
            ..PositioningOptions::default()
        };
        assert!(positioning_from_contents(&l, &opts).is_ok());
    }

    /// The same misreading, caught by the daemon (`off_target`): a missing reading, named in
    /// the notes with its pose, and the run is evaluated.
    #[test]
    fn a_value_the_daemon_marked_off_target_is_a_missing_reading_with_a_note() {
        let xs = [100.0, 200.0, 0.0, 100.0, 200.0, 0.0];
        let mut l = log(&xs, |no, x| Some(if no == 5 { -2.8 } else { x * 1000.0 }));
        for p in l.poses.iter_mut().filter(|p| p.msg.pose == 5) {
            p.msg.status = PoseStatus::OffTarget;
        }
        let d = positioning_from_contents(&l, &PositioningOptions::default()).unwrap();
        assert_eq!(d.readings.len(), 5);
        let note = &d.metadata[OFF_TARGET_NOTE_KEY];
        assert!(
            note.starts_with("1 pose value(s) are off_target (pose 5)"),
            "{note}"
        );
        assert!(
            note.contains("than its tolerance") && note.contains("(2 mm, or half the way"),
            "{note}"
        );
    }

    #[test]
    fn unidirectional_run_takes_every_measured_position() {
        // Two cycles up 10, 20, 30 with a return to 0 (not measured) in between.
        let xs = [10.0, 20.0, 30.0, 0.0, 10.0, 20.0, 30.0];
        let l = log(&xs, |no, x| {
            (x > 0.0).then_some(x * 1000.0 + no as f64 * 0.1)
        });
        let d = positioning_from_contents(&l, &PositioningOptions::default()).unwrap();
        assert_eq!((d.n_targets(), d.n_cycles(), d.readings.len()), (3, 2, 6));
        assert!(d.readings.iter().all(|r| r.direction == Direction::Up));
        // Pose 6 = 20 mm in cycle 2: 0.6 µm.
        let r = d
            .readings
            .iter()
            .find(|r| r.cycle == 2 && r.index == 2)
            .unwrap();
        assert!((r.deviation_um - 0.6).abs() < 1e-9);
        assert!((r.time_s - 5.0).abs() < 1e-9);
    }

    #[test]
    fn datum_from_metadata_and_repeated_pose_keeps_direction() {
        // Datum at x = 5 mm: reading = (x − 5)·1000 + 0.25. Pose 3 repeats pose 2 (no move):
        // a second up visit of 20 mm.
        let xs = [10.0, 20.0, 20.0, 25.0, 20.0, 10.0, 5.0];
        let mut l = log(&xs, |_, x| Some((x - 5.0) * 1000.0 + 0.25));
        l.run_metadata.insert("datum_x_mm".into(), "5".into());
        let d = positioning_from_contents(&l, &PositioningOptions::default()).unwrap();
        // Targets approached both ways: 10 and 20 (25 and 5 are reversals).
        assert_eq!(d.targets_mm(), vec![10.0, 20.0]);
        let up20: Vec<usize> = d
            .readings
            .iter()
            .filter(|r| r.index == 2 && r.direction == Direction::Up)
            .map(|r| r.cycle)
            .collect();
        assert_eq!(up20, vec![1, 2]);
        assert!(
            d.readings
                .iter()
                .all(|r| (r.deviation_um - 0.25).abs() < 1e-9)
        );
    }

    /// Up 10, 20, 30, down to 0 (the reference pose), up again twice; the datum lost from pose
    /// 2 (epoch 1): poses 2-4 `datum_lost`; `epoch 1 referenced at pose 4` when `referenced`.
    fn epoch_log(referenced: bool) -> LogContents {
        let xs = [10.0, 20.0, 30.0, 0.0, 10.0, 20.0, 30.0, 20.0, 10.0, 0.0];
        let mut l = log(&xs, |_, x| Some(x * 1000.0));
        for p in l.poses.iter_mut().filter(|p| p.msg.pose >= 2) {
            p.msg.datum_epoch = 1;
            if p.msg.pose <= 4 {
                p.msg.status = PoseStatus::DatumLost;
                p.msg.mean.clear();
            }
        }
        if referenced {
            l.rereferences
                .push(crate::contents::Rereference { epoch: 1, pose: 4 });
        }
        l
    }

    #[test]
    fn a_re_referenced_run_is_taken_with_its_lost_poses_missing_and_noted() {
        let d =
            positioning_from_contents(&epoch_log(true), &PositioningOptions::default()).unwrap();
        let note = &d.metadata[DATUM_NOTE_KEY];
        assert!(
            note.starts_with("3 pose value(s) between poses 2 and 4 are datum_lost")
                && note.contains("epoch 1 at pose 4"),
            "{note}"
        );
        // Pose 1 (10 up) and poses 5-9: 10 up, 20 up, 20 down, 10 down.
        assert_eq!(d.readings.len(), 5);
    }

    #[test]
    fn ok_values_of_an_epoch_never_re_referenced_refuse_the_run() {
        let mut l = epoch_log(false);
        let e = positioning_from_contents(&l, &PositioningOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("mixes datum epochs without a reference: pose 5 is ok in datum epoch 1"),
            "{e}"
        );
        // Its lost values alone (no ok value of epoch 1): the loss is named.
        for p in l.poses.iter_mut().filter(|p| p.msg.pose >= 5) {
            p.msg.status = PoseStatus::DatumLost;
        }
        let e = positioning_from_contents(&l, &PositioningOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("lost its datum at pose 2") && e.contains("never re-referenced"),
            "{e}"
        );
    }
}
