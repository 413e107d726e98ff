//! `metrolog plan thermal`: a thermal run (ISO 230-3 style, `docs/methods.md` "Planning a
//! thermal run") — the machine returns to the measuring pose every N minutes for H hours,
//! waiting at a park pose in between, while the spindle runs a speed schedule and the
//! temperature module is logged. One steady value per visit, as for any pose.
//!
//! The spindle keeps turning during a visit: the instruments measure without contact (the
//! CapBall's capacitive probes around the ball in the spindle, the PSD's beam), so the heat
//! source is not interrupted by the measurement. Speed changes are made at the park pose, at
//! the first arrival there at or after the schedule's time.

use std::path::PathBuf;

use anyhow::Context as _;
use metrolog_log::trajectory::{TrajectoryRow, write_trajectory};

/// The measuring pose's number in the trajectory and the trigger frames.
pub const MEASURE_POSE: u32 = 1;
/// The park pose's number.
pub const PARK_POSE: u32 = 2;

/// What a thermal run does.
#[derive(Debug, Clone, PartialEq)]
pub struct ThermalPlanOptions {
    /// Measuring pose: x, y, z mm, a, c degrees.
    pub measure: [f64; 5],
    /// Park pose (where the machine waits between visits).
    pub park: [f64; 5],
    /// Time from one visit to the next, s.
    pub every_s: f64,
    /// Length of the run, s.
    pub duration_s: f64,
    /// Dwell at the measuring pose, s.
    pub dwell_s: f64,
    /// Time a move between the two poses is given, s.
    pub move_s: f64,
    /// Spindle speed schedule: (from s after the start, rpm), in time order; 0 before the first.
    pub spindle: Vec<(f64, f64)>,
}

/// One cycle: a visit of the measuring pose, then the wait at the park pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cycle {
    /// Exact stop at the measuring pose, s after the start.
    pub measure_s: f64,
    /// Arrival at the park pose, s after the start (where the speed is set).
    pub park_s: f64,
    /// Wait at the park pose, s (0 after the last visit).
    pub wait_s: f64,
    /// Spindle speed set at the park arrival, rpm.
    pub rpm: f64,
}

/// A planned thermal run.
#[derive(Debug, Clone, PartialEq)]
pub struct ThermalPlan {
    pub options: ThermalPlanOptions,
    /// The speed set before the first visit (at the park pose, at time 0), rpm.
    pub start_rpm: f64,
    pub cycles: Vec<Cycle>,
}

/// The speed the schedule asks for at `t_s`.
fn scheduled_rpm(schedule: &[(f64, f64)], t_s: f64) -> f64 {
    schedule
        .iter()
        .take_while(|(at, _)| *at <= t_s)
        .last()
        .map_or(0.0, |(_, r)| *r)
}

/// Plans the run: the first visit one move after the start, then one every `every_s`.
pub fn plan_thermal(o: &ThermalPlanOptions) -> anyhow::Result<ThermalPlan> {
    let fine = |v: f64| v.is_finite() && v > 0.0;
    anyhow::ensure!(
        fine(o.every_s) && fine(o.duration_s) && fine(o.move_s) && fine(o.dwell_s),
        "--every-min, --hours, --move-s and --dwell-s must be > 0"
    );
    anyhow::ensure!(
        o.every_s >= 2.0 * o.move_s + o.dwell_s,
        "a visit every {} s leaves no time at the park pose: it takes two moves of {} s and a dwell of {} s",
        o.every_s,
        o.move_s,
        o.dwell_s
    );
    anyhow::ensure!(
        o.spindle.windows(2).all(|w| w[0].0 <= w[1].0)
            && o.spindle
                .iter()
                .all(|(t, r)| t.is_finite() && r.is_finite() && *r >= 0.0),
        "--spindle: MIN:RPM steps in time order, speeds ≥ 0"
    );
    let n = (o.duration_s / o.every_s).floor() as usize + 1;
    let cycles = (0..n)
        .map(|k| {
            let measure_s = o.move_s + k as f64 * o.every_s;
            let park_s = measure_s + o.dwell_s + o.move_s;
            let last = k + 1 == n;
            Cycle {
                measure_s,
                park_s,
                wait_s: if last {
                    0.0
                } else {
                    o.every_s - 2.0 * o.move_s - o.dwell_s
                },
                rpm: if last {
                    0.0
                } else {
                    scheduled_rpm(&o.spindle, park_s)
                },
            }
        })
        .collect();
    Ok(ThermalPlan {
        start_rpm: scheduled_rpm(&o.spindle, 0.0),
        options: o.clone(),
        cycles,
    })
}

fn row(pose: u32, p: [f64; 5]) -> TrajectoryRow {
    TrajectoryRow {
        pose,
        x_mm: p[0],
        y_mm: p[1],
        z_mm: p[2],
        a_deg: Some(p[3]),
        c_deg: Some(p[4]),
    }
}

impl ThermalPlan {
    /// The trajectory the daemon runs with: the measuring pose and the park pose.
    pub fn trajectory(&self) -> Vec<TrajectoryRow> {
        vec![
            row(MEASURE_POSE, self.options.measure),
            row(PARK_POSE, self.options.park),
        ]
    }

    /// The spindle speed the program sets from each instant on: (s after the start, rpm).
    pub fn speed_steps(&self) -> Vec<(f64, f64)> {
        let mut v = vec![(0.0, self.start_rpm)];
        for c in &self.cycles {
            if v.last().is_some_and(|(_, r)| *r != c.rpm) {
                v.push((c.park_s, c.rpm));
            }
        }
        v
    }

    /// The part program in LinuxCNC G-code (the dialect's words as for `plan positioning`:
    /// G53 machine coordinates, M68 E0 pose index, M64/M65 P0 trigger, G4 dwell, S/M3/M5).
    pub fn linuxcnc_program(&self, feed_mm_min: f64) -> String {
        let o = &self.options;
        // A and C only on a machine that has them (a pose given with them, or not at 0).
        let rotary = [o.measure, o.park]
            .iter()
            .any(|p| p[3] != 0.0 || p[4] != 0.0);
        let mv = |p: [f64; 5]| {
            let ac = if rotary {
                format!(" A{:.3} C{:.3}", p[3], p[4])
            } else {
                String::new()
            };
            format!(
                "G53 G1 X{:.3} Y{:.3} Z{:.3}{ac} F{feed_mm_min:.0}",
                p[0], p[1], p[2]
            )
        };
        let speed = |rpm: f64| {
            if rpm > 0.0 {
                format!("S{rpm:.0} M3")
            } else {
                "M5".to_string()
            }
        };
        let mut l = vec![
            format!(
                "(thermal run written by metrolog plan thermal: {} visits of pose {MEASURE_POSE}, one every {:.1} min over {:.2} h)",
                self.cycles.len(),
                o.every_s / 60.0,
                o.duration_s / 3600.0
            ),
            format!("(dwell {} s at pose {MEASURE_POSE}; the machine waits at pose {PARK_POSE} in between; the spindle keeps its speed during a visit)", o.dwell_s),
            "(trigger: digital output 0 M64 P0 with the pose index on analog output 0; the PLC sends the CAN trigger frame, docs/instruments.md 4)".into(),
            "G21 G90 G61.1".into(),
            format!("M68 E0 Q{PARK_POSE}"),
            mv(o.park),
            speed(self.start_rpm),
        ];
        let mut rpm = self.start_rpm;
        for (k, c) in self.cycles.iter().enumerate() {
            l.push(format!(
                "(visit {} at {:.1} min)",
                k + 1,
                c.measure_s / 60.0
            ));
            for (pose, p, dwell) in [
                (MEASURE_POSE, o.measure, o.dwell_s),
                (PARK_POSE, o.park, 0.0),
            ] {
                l.push(format!("M68 E0 Q{pose}"));
                l.push(mv(p));
                l.push("M64 P0".into());
                l.push(format!("G4 P{dwell}"));
                l.push("M65 P0".into());
            }
            if c.rpm != rpm {
                l.push(speed(c.rpm));
                rpm = c.rpm;
            }
            if c.wait_s > 0.0 {
                l.push(format!("G4 P{:.1}", c.wait_s));
            }
        }
        l.push("M5".into());
        l.push("M2".into());
        l.join("\n") + "\n"
    }
}

#[derive(Debug, clap::Args)]
pub struct ThermalArgs {
    /// Measuring pose: X,Y,Z[,A,C] machine coordinates (mm, degrees).
    #[arg(
        long,
        value_delimiter = ',',
        required = true,
        allow_negative_numbers = true
    )]
    pub pose: Vec<f64>,
    /// Park pose between visits: X,Y,Z[,A,C].
    #[arg(
        long,
        value_delimiter = ',',
        required = true,
        allow_negative_numbers = true
    )]
    pub park: Vec<f64>,
    /// Minutes from one visit to the next.
    #[arg(long, default_value_t = 10.0)]
    pub every_min: f64,
    /// Length of the run, hours.
    #[arg(long, default_value_t = 4.0)]
    pub hours: f64,
    /// Dwell at the measuring pose, s.
    #[arg(long, default_value_t = 5.0)]
    pub dwell_s: f64,
    /// Time allowed for a move between the poses, s.
    #[arg(long, default_value_t = 10.0)]
    pub move_s: f64,
    /// Feed of the moves, mm/min.
    #[arg(long, default_value_t = 2000.0)]
    pub feed: f64,
    /// Spindle speed schedule: MIN:RPM steps (e.g. 0:2000,60:4000,150:0).
    #[arg(long, value_delimiter = ',', value_name = "MIN:RPM")]
    pub spindle: Vec<String>,
    /// Directory for trajectory.csv and thermal_run.ngc.
    #[arg(long, short = 'o', default_value = ".")]
    pub out: PathBuf,
}

fn pose5(v: &[f64], what: &str) -> anyhow::Result<[f64; 5]> {
    anyhow::ensure!(
        (3..=5).contains(&v.len()) && v.iter().all(|x| x.is_finite()),
        "{what}: give X,Y,Z[,A,C] as finite numbers"
    );
    let mut p = [0.0; 5];
    p[..v.len()].copy_from_slice(v);
    Ok(p)
}

fn parse_spindle(steps: &[String]) -> anyhow::Result<Vec<(f64, f64)>> {
    steps
        .iter()
        .map(|s| {
            let (m, r) = s
                .split_once(':')
                .with_context(|| format!("--spindle step `{s}` is not MIN:RPM"))?;
            let m: f64 = m
                .trim()
                .parse()
                .with_context(|| format!("--spindle `{s}`"))?;
            let r: f64 = r
                .trim()
                .parse()
                .with_context(|| format!("--spindle `{s}`"))?;
            Ok((m * 60.0, r))
        })
        .collect()
}

pub fn run(a: ThermalArgs) -> anyhow::Result<()> {
    let o = ThermalPlanOptions {
        measure: pose5(&a.pose, "--pose")?,
        park: pose5(&a.park, "--park")?,
        every_s: a.every_min * 60.0,
        duration_s: a.hours * 3600.0,
        dwell_s: a.dwell_s,
        move_s: a.move_s,
        spindle: parse_spindle(&a.spindle)?,
    };
    let p = plan_thermal(&o)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let traj = a.out.join("trajectory.csv");
    crate::cmd::input::write_output(&traj, &write_trajectory(&p.trajectory()))?;
    let prog = a.out.join("thermal_run.ngc");
    crate::cmd::input::write_output(&prog, &p.linuxcnc_program(a.feed))?;
    let steps: Vec<String> = p
        .speed_steps()
        .iter()
        .map(|(t, r)| format!("{:.1} min: {r:.0} rpm", t / 60.0))
        .collect();
    crate::cmd::input::print_out(&format!(
        "{} visits of pose {MEASURE_POSE}, one every {:.1} min over {:.2} h; park pose {PARK_POSE}\nspindle: {}\ntrajectory: {}\npart program (LinuxCNC): {}\nlog the temperatures (and the spindle speed as the channel `spindle_rpm`) with a [temperature] section\n",
        p.cycles.len(),
        a.every_min,
        a.hours,
        steps.join(", "),
        traj.display(),
        prog.display()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn visits_every_n_minutes_and_speed_changes_at_the_park_pose() {
        let o = ThermalPlanOptions {
            measure: [100.0, 50.0, 200.0, 0.0, 0.0],
            park: [0.0; 5],
            every_s: 600.0,
            duration_s: 3600.0,
            dwell_s: 5.0,
            move_s: 10.0,
            spindle: vec![(0.0, 2000.0), (1500.0, 4000.0)],
        };
        let p = plan_thermal(&o).unwrap();
        assert_eq!(p.cycles.len(), 7);
        assert_eq!(p.cycles[3].measure_s, 10.0 + 1800.0);
        // The 25-minute step is made at the first park arrival after it: 30 min + 25 s.
        assert_eq!(
            p.speed_steps(),
            vec![(0.0, 2000.0), (1825.0, 4000.0), (3625.0, 0.0)]
        );
        let prog = p.linuxcnc_program(2000.0);
        assert_eq!(prog.matches("M68 E0 Q1").count(), 7);
        assert!(
            prog.contains("S4000 M3") && prog.ends_with("M5\nM2\n"),
            "{prog}"
        );
        assert!(plan_thermal(&ThermalPlanOptions { every_s: 20.0, ..o }).is_err());
    }
}
