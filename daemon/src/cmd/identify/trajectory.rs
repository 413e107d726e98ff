//! `metrolog identify trajectory`: a CapBall identification trajectory
//! (`pose,x_mm,y_mm,z_mm,a_deg,c_deg`).

use std::path::PathBuf;

use geometry::capball::{CapballSetup, TrajectorySpec};
use metrolog_log::trajectory::{TrajectoryRow, write_trajectory};
use nalgebra::Vector3;

use crate::cmd::input::{load_machine, numbers_arg};

#[derive(Debug, clap::Args)]
pub struct TrajectoryArgs {
    /// Output file (CSV).
    #[arg(long)]
    pub out: PathBuf,
    /// Poses on the trajectory (5 to 100 000; 14 parameters need at least 5, paper 001 used
    /// 807).
    #[arg(long, default_value_t = 807, value_parser = clap::value_parser!(u64).range(5..=100_000))]
    pub poses: u64,
    /// A at the first pose, degrees (−360 to 360).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = a_deg_arg)]
    pub a_start_deg: f64,
    /// A at the last pose, degrees (−360 to 360).
    #[arg(long, default_value_t = -90.0, allow_hyphen_values = true, value_parser = a_deg_arg)]
    pub a_end_deg: f64,
    /// Turns of C over the trajectory (more than 0, at most 1000).
    #[arg(long, default_value_t = 6.0, value_parser = c_turns_arg)]
    pub c_turns: f64,
    /// The validation trajectory: A runs the other way.
    #[arg(long)]
    pub reverse_a: bool,
    /// Machine description (TOML); default: the WCAYFXZT machine of paper 001.
    #[arg(long)]
    pub machine: Option<PathBuf>,
    /// Ball centre on the table `x,y,z` mm (default 120,80,100).
    #[arg(long, allow_hyphen_values = true)]
    pub ball_mm: Option<String>,
}

pub fn run(a: TrajectoryArgs) -> anyhow::Result<()> {
    let machine = load_machine(a.machine.as_ref())?;
    let ball = match &a.ball_mm {
        Some(s) => {
            let v = numbers_arg(s, 3, "--ball-mm")?;
            Vector3::new(v[0], v[1], v[2])
        }
        None => CapballSetup::paper_default().ball_mm,
    };
    if let Some(missing) = ["Y", "Z", "A", "C"]
        .iter()
        .find(|n| !machine.chain.contains(**n))
    {
        anyhow::bail!(
            "machine {}: the CapBall model needs axes Y, Z, A and C (no {missing})",
            machine.chain
        );
    }
    let setup = CapballSetup {
        machine,
        ball_mm: ball,
    };
    let mut spec = TrajectorySpec {
        n_poses: a.poses as usize,
        a_start_deg: a.a_start_deg,
        a_end_deg: a.a_end_deg,
        c_turns: a.c_turns,
    };
    if a.reverse_a {
        spec = spec.reversed_a();
    }
    let poses = setup.trajectory(&spec);
    let condition = setup.condition_number(&poses);
    if !condition.is_finite() {
        anyhow::bail!(
            "this trajectory cannot identify the 14 errors (its Jacobian is singular: A from {} to {} deg, {} turns of C); nothing written",
            a.a_start_deg,
            a.a_end_deg,
            a.c_turns
        );
    }
    let rows: Vec<TrajectoryRow> = (1..)
        .zip(&poses)
        .map(|(k, p)| trajectory_row(k, p))
        .collect();
    crate::cmd::input::write_output(&a.out, &write_trajectory(&rows))?;
    outln!(
        "{} poses written to {}; identification Jacobian condition number {condition:.1}",
        poses.len(),
        a.out.display(),
    )?;
    Ok(())
}

/// `--a-start-deg`, `--a-end-deg`: a finite angle within one turn either way.
fn a_deg_arg(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v.abs() <= 360.0 => Ok(v),
        _ => Err(format!(
            "`{s}`: an A angle is a number of degrees from -360 to 360"
        )),
    }
}

/// `--c-turns`: more than 0, at most 1000.
fn c_turns_arg(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v <= 1000.0 => Ok(v),
        _ => Err(format!(
            "`{s}`: the turns of C are a number more than 0 and at most 1000"
        )),
    }
}

/// Row `pose` (1-based) of the trajectory format for a machine pose; A and C are written (B is
/// not part of the format).
fn trajectory_row(pose: u32, p: &geometry::kinematics::Pose) -> TrajectoryRow {
    TrajectoryRow {
        pose,
        x_mm: p.x_mm,
        y_mm: p.y_mm,
        z_mm: p.z_mm,
        a_deg: Some(p.a_deg),
        c_deg: Some(p.c_deg),
    }
}
