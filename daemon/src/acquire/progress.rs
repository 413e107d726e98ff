//! What the operator reads on the terminal and in systemd's `STATUS=` while a run goes on
//! (README, "Reading the run on the terminal"): one line per finished pose, "pose k of N", its
//! target and every instrument's value with its status, and the alarms that hold now.

use std::fmt::Write;

use drivers::Instrument;
use metrolog_log::topics::PoseMsg;
use metrolog_log::trajectory::TrajectoryRow;
use types::PoseStatus;

/// The pose's place in the run: `pose k of N` (`pose k` without a trajectory).
pub fn pose_of(pose: u32, trajectory: &[TrajectoryRow]) -> String {
    if trajectory.is_empty() {
        format!("pose {pose}")
    } else {
        format!("pose {pose} of {}", trajectory.len())
    }
}

/// The line for one finished pose: "pose 31 of 129 (target X 399.050 Y 0.000 Z 0.000 mm):
/// interferometer position_um 399055.123 ok, psd x_um 1.200 y_um -0.300 never_steady".
/// `values` are the pose's values (any order; those of other poses are left out).
pub fn pose_line(pose: u32, trajectory: &[TrajectoryRow], values: &[PoseMsg]) -> String {
    let mut s = pose_of(pose, trajectory);
    if let Some(r) = trajectory.iter().find(|r| r.pose == pose) {
        let _ = write!(
            s,
            " (target X {:.3} Y {:.3} Z {:.3} mm)",
            r.x_mm, r.y_mm, r.z_mm
        );
    }
    s.push(':');
    let mut first = true;
    for v in values.iter().filter(|v| v.pose == pose) {
        s.push_str(if first { " " } else { ", " });
        first = false;
        s.push_str(v.instrument.name());
        for (ch, m) in &v.mean {
            let _ = write!(s, " {ch} {m:.3}");
        }
        let _ = write!(s, " {}", v.status.name());
    }
    if first {
        s.push_str(" no values");
    }
    s
}

/// The alarm a pose value raises on its instrument, if any (`None` for a good value).
/// `device_away` raises none: every reversal point without a dwell gives it (a false alarm
/// every few poses), and an unplugged device is told by its connection ("unplugged").
pub fn alarm_of(status: PoseStatus) -> Option<&'static str> {
    match status {
        PoseStatus::Ok
        | PoseStatus::NeverSteady
        | PoseStatus::TriggerMissing
        | PoseStatus::DeviceAway => None,
        PoseStatus::BeamInvalid => Some("beam lost"),
        PoseStatus::DatumLost => Some("datum lost"),
        PoseStatus::OffTarget => Some("off target"),
    }
}

/// The alarms as one text: "interferometer unplugged, psd beam lost" or "ok".
pub fn alarms_text(alarms: &[(Instrument, String)]) -> String {
    if alarms.is_empty() {
        return "ok".to_string();
    }
    let v: Vec<String> = alarms
        .iter()
        .map(|(i, a)| format!("{} {a}", i.name()))
        .collect();
    v.join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn row(pose: u32, x: f64) -> TrajectoryRow {
        TrajectoryRow {
            pose,
            x_mm: x,
            y_mm: 0.0,
            z_mm: -5.5,
            a_deg: None,
            c_deg: None,
        }
    }

    fn value(instrument: Instrument, pose: u32, status: PoseStatus, ch: &[(&str, f64)]) -> PoseMsg {
        PoseMsg {
            instrument,
            pose,
            status,
            n: 10,
            mean: ch.iter().map(|(c, m)| (c.to_string(), *m)).collect(),
            std: BTreeMap::new(),
            t_first_ns: 0,
            t_last_ns: 0,
            datum_epoch: 0,
        }
    }

    #[test]
    fn a_pose_line_names_k_of_n_the_target_and_every_value() {
        let traj = [row(1, 0.0), row(2, 399.05), row(3, 302.197)];
        let values = [
            value(
                Instrument::Interferometer,
                2,
                PoseStatus::Ok,
                &[("position_um", 399055.0)],
            ),
            value(Instrument::Interferometer, 3, PoseStatus::Ok, &[]),
            value(
                Instrument::Psd,
                2,
                PoseStatus::NeverSteady,
                &[("x_um", 1.2), ("y_um", -0.3)],
            ),
        ];
        // Written out by hand: the line an operator reads.
        assert_eq!(
            pose_line(2, &traj, &values),
            "pose 2 of 3 (target X 399.050 Y 0.000 Z -5.500 mm): interferometer position_um \
             399055.000 ok, psd x_um 1.200 y_um -0.300 never_steady"
        );
        assert_eq!(pose_line(7, &[], &[]), "pose 7: no values");
    }

    #[test]
    fn alarms_read_ok_when_none_hold() {
        assert_eq!(alarms_text(&[]), "ok");
        let a = [
            (Instrument::Psd, "unplugged".to_string()),
            (Instrument::Interferometer, "datum lost".to_string()),
        ];
        assert_eq!(alarms_text(&a), "psd unplugged, interferometer datum lost");
        assert_eq!(alarm_of(PoseStatus::DatumLost), Some("datum lost"));
        assert_eq!(alarm_of(PoseStatus::OffTarget), Some("off target"));
        assert_eq!(alarm_of(PoseStatus::Ok), None);
        assert_eq!(alarm_of(PoseStatus::DeviceAway), None);
    }
}
