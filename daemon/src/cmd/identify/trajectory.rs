//! `metrolog identify trajectory`: a CapBall identification trajectory
//! (`pose,x_mm,y_mm,z_mm,a_deg,c_deg`).

use std::path::PathBuf;

use anyhow::Context;
use geometry::capball::{CapballSetup, TrajectorySpec};
use metrolog_log::trajectory::{TrajectoryRow, write_trajectory};
use nalgebra::Vector3;

use crate::cmd::input::{load_machine, numbers_arg};

#[derive(Debug, clap::Args)]
pub struct TrajectoryArgs {
    /// Output file (CSV).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 807)]
    pub poses: usize,
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub a_start_deg: f64,
    #[arg(long, default_value_t = -90.0, allow_hyphen_values = true)]
    pub a_end_deg: f64,
    #[arg(long, default_value_t = 6.0)]
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
    if a.poses < 5 {
        anyhow::bail!(
            "--poses {}: at least 5 poses are needed for 14 parameters",
            a.poses
        );
    }
    let mut spec = TrajectorySpec {
        n_poses: a.poses,
        a_start_deg: a.a_start_deg,
        a_end_deg: a.a_end_deg,
        c_turns: a.c_turns,
    };
    if a.reverse_a {
        spec = spec.reversed_a();
    }
    let poses = setup.trajectory(&spec);
    let rows: Vec<TrajectoryRow> = (1..)
        .zip(&poses)
        .map(|(k, p)| trajectory_row(k, p))
        .collect();
    std::fs::write(&a.out, write_trajectory(&rows))
        .with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "{} poses written to {}; identification Jacobian condition number {:.1}",
        poses.len(),
        a.out.display(),
        setup.condition_number(&poses)
    );
    Ok(())
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
