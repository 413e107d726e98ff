//! `metrolog plan positioning`: the ISO 230-2 test of one axis — targets, cycle, the
//! trajectory the daemon runs with and the part program in a controller's dialect
//! (`docs/methods.md` "Planning a positioning test"). `metrolog plan thermal`: a thermal run
//! ([`thermal`]).

pub mod thermal;

use std::path::PathBuf;

use anyhow::Context as _;
use metrolog_log::trajectory::{TrajectoryRow, write_trajectory};
use positioning::plan::{Dialect, PlanOptions, plan};

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Plan an ISO 230-2 positioning test: trajectory CSV and part program.
    Positioning(PositioningArgs),
    /// Plan a thermal run: the measuring pose every N minutes for H hours, a spindle speed
    /// schedule, the trajectory CSV and the part program (LinuxCNC).
    Thermal(thermal::ThermalArgs),
}

#[derive(Debug, clap::Args)]
pub struct PositioningArgs {
    /// Axis: X, Y or Z.
    #[arg(long, default_value = "X")]
    pub axis: char,
    /// Start of the travel the test may use, machine coordinates, mm.
    #[arg(long)]
    pub from: f64,
    /// End of the travel the test may use, machine coordinates, mm.
    #[arg(long)]
    pub to: f64,
    /// Number of targets (ISO 230-2: at least 5, and 5 per metre).
    #[arg(long, default_value_t = 11)]
    pub targets: usize,
    /// Number of bidirectional cycles (ISO 230-2: 5).
    #[arg(long, default_value_t = 5)]
    pub cycles: usize,
    /// Plan below ISO 230-2's minimums (5 targets per metre and 5 in all, 5 cycles) for this
    /// reason, printed in the program header.
    #[arg(long, value_name = "REASON")]
    pub below_iso_minimum: Option<String>,
    /// Seed of the random target offsets (the same seed gives the same targets).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Largest random offset of a target from the even grid, mm [default: a tenth of the
    /// target interval; use at least half the screw pitch].
    #[arg(long, value_name = "MM")]
    pub offset: Option<f64>,
    /// Travel past the end targets before each reversal, mm; the targets lie this far inside
    /// --from/--to, so no move leaves that travel.
    #[arg(long, default_value_t = 5.0)]
    pub overrun: f64,
    /// Dwell at each target, s.
    #[arg(long, default_value_t = 2.0)]
    pub dwell: f64,
    /// Feed, mm/min.
    #[arg(long, default_value_t = 1000.0)]
    pub feed: f64,
    /// M-function that pulses the exact-stop trigger (not LinuxCNC, which uses M64 P0).
    #[arg(long, default_value_t = 101)]
    pub trigger_m: u32,
    /// Part program dialect: sinumerik, fanuc, heidenhain or linuxcnc.
    #[arg(long, default_value = "sinumerik")]
    pub dialect: Dialect,
    /// Directory for trajectory.csv and the part program.
    #[arg(long, short = 'o', default_value = ".")]
    pub out: PathBuf,
}

pub fn run(c: Command) -> anyhow::Result<()> {
    let a = match c {
        Command::Positioning(a) => a,
        Command::Thermal(a) => return thermal::run(a),
    };
    let o = PlanOptions {
        axis: a.axis.to_ascii_uppercase(),
        from_mm: a.from,
        to_mm: a.to,
        targets: a.targets,
        cycles: a.cycles,
        below_iso_minimum: a.below_iso_minimum.clone(),
        seed: a.seed,
        max_offset_mm: a.offset,
        overrun_mm: a.overrun,
        dwell_s: a.dwell,
        feed_mm_min: a.feed,
        trigger_m: a.trigger_m,
    };
    let p = plan(&o)?;
    let rows: Vec<TrajectoryRow> = p
        .positions_xyz_mm()
        .iter()
        .enumerate()
        .map(|(i, xyz)| TrajectoryRow {
            pose: i as u32 + 1,
            x_mm: xyz[0],
            y_mm: xyz[1],
            z_mm: xyz[2],
            a_deg: None,
            c_deg: None,
        })
        .collect();
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let traj = a.out.join("trajectory.csv");
    crate::cmd::input::write_output(&traj, &write_trajectory(&rows))?;
    let ext = match a.dialect {
        Dialect::Sinumerik => "MPF",
        Dialect::Fanuc => "NC",
        Dialect::Heidenhain => "H",
        Dialect::LinuxCnc => "ngc",
    };
    let prog = a.out.join(format!("iso230_{}.{ext}", o.axis));
    crate::cmd::input::write_output(&prog, &p.part_program(a.dialect))?;
    let targets: Vec<String> = p.targets_mm.iter().map(|t| format!("{t:.3}")).collect();
    for b in positioning::plan::below_minimums(&o) {
        errln!("warning: below ISO 230-2's minimums: {b}");
    }
    crate::cmd::input::print_out(&format!(
        "targets (mm): {}\n{} poses, {} measured stops\ntrajectory: {}\npart program ({:?}): {}\n",
        targets.join(" "),
        p.poses.len(),
        p.poses.iter().filter(|x| x.target.is_some()).count(),
        traj.display(),
        a.dialect,
        prog.display()
    ))
}
