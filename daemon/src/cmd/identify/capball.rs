//! `metrolog identify capball`: the 8 link + 6 setup errors of a five-axis machine from a
//! CapBall dataset or log, each run identified separately, with the residuals of a validation
//! dataset and a warning when they exceed what white noise explains.

use std::path::{Path, PathBuf};

use anyhow::Context;
use geometry::capball::{self, CapballSetup, Identification, PARAM_NAMES};
use geometry::kinematics::Pose;
use metrolog_analysis::export::{result_or, xyz_or};
use nalgebra::Vector3;

use super::capball_mc::{self, CapballMcArgs};
use crate::cmd::input::{load_capball, load_machine};

#[derive(Debug, clap::Args)]
pub struct CapballArgs {
    /// CapBall dataset (CSV) or MCAP log of a run.
    pub data: PathBuf,
    /// Validation dataset (e.g. the trajectory with A reversed): RMS of its residuals.
    #[arg(long)]
    pub validate: Option<PathBuf>,
    /// Machine description (TOML); default: the WCAYFXZT machine of paper 001.
    #[arg(long)]
    pub machine: Option<PathBuf>,
    /// Identify only this run.
    #[arg(long)]
    pub run: Option<u32>,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub mc: CapballMcArgs,
}

pub fn run(a: CapballArgs) -> anyhow::Result<()> {
    // Without --machine, a log's poses choose the kinematic convention.
    let given = match &a.machine {
        Some(p) => Some(load_machine(Some(p))?),
        None => None,
    };
    let input = load_capball(&a.data, given)?;
    report_skipped(&a.data, &input.skipped);
    if let Some(name) = &input.machine_name {
        errln!("{}: machine {name}", a.data.display());
    }
    let damage = input.damage.clone();
    // A result built on a damaged log says so before anything else (JSON: `log_damage`).
    if let Some(note) = input.damage_note().filter(|_| !a.json) {
        outln!("{note}")?;
    }
    let (machine, recs) = (input.machine, input.records);
    if a.mc.uncertainty.is_some() {
        return capball_mc::run(&a.data, &machine, &recs, &a.mc, a.json);
    }
    let mut runs = runs_of(&recs);
    if let Some(r) = a.run {
        runs.retain(|x| x.0 == r);
        if runs.is_empty() {
            anyhow::bail!("run {r} is not in {}", a.data.display());
        }
    }
    let validation = match &a.validate {
        Some(p) => {
            let v = load_capball(p, Some(machine.clone()))?;
            report_skipped(p, &v.skipped);
            Some(v.records)
        }
        None => None,
    };
    let validation_runs = validation.as_deref().map(runs_of);
    let mut results = Vec::new();
    let mut extra = Vec::new();
    for (run, poses, meas) in &runs {
        let setup = CapballSetup::with_ball_from_poses(machine.clone(), poses)
            .with_context(|| format!("run {run}"))?;
        let id = setup
            .identify(poses, meas)
            .with_context(|| format!("run {run}"))?;
        let val = match (&validation, &validation_runs) {
            (Some(records), Some(v)) => {
                let (vp, vm): (Vec<Pose>, Vec<[f64; 3]>) =
                    v.iter().fold((vec![], vec![]), |mut acc, x| {
                        acc.0.extend_from_slice(&x.1);
                        acc.1.extend_from_slice(&x.2);
                        acc
                    });
                let rms = setup.validation_rms_um(&id, &vp, &vm)?;
                let times: Vec<Option<f64>> = records.iter().map(|r| r.time_s).collect();
                let res = pose_residuals(&setup, &id, &vp, &vm, &times);
                Some((rms, res))
            }
            _ => None,
        };
        let times: Vec<Option<f64>> = recs
            .iter()
            .filter(|r| r.run == *run)
            .map(|r| r.time_s)
            .collect();
        let own = pose_residuals(&setup, &id, poses, meas, &times);
        let n_val_poses = validation.as_ref().map_or(0, Vec::len);
        let warning = val
            .as_ref()
            .and_then(|(v, _)| id.validation_excess(v, n_val_poses))
            .map(|e| metrolog_analysis::identify_text::validation_excess_warning(&e));
        if let Some(w) = &warning {
            errln!("run {run}: warning: {w}");
        }
        extra.push((own, val.as_ref().map(|x| x.1.clone()), warning));
        results.push((*run, setup.ball_mm, id, val.map(|x| x.0)));
    }
    if a.json {
        let v: Vec<_> = results
            .iter()
            .zip(&extra)
            .map(|((run, ball, id, val), (own, vres, warning))| {
                serde_json::json!({
                    "run": run,
                    "ball_mm": [ball.x, ball.y, ball.z],
                    "parameter_names": PARAM_NAMES,
                    "identification": id,
                    "validation_rms_um": val,
                    "residuals": own,
                    "validation_residuals": vres,
                    "warning": warning,
                })
            })
            .collect();
        outln!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({ "runs": v, "log_damage": damage }))?
        )?;
        return Ok(());
    }
    for (run, ball, id, val) in &results {
        out!("{}", identification_text(*run, ball, id, val.as_ref()))?;
    }
    Ok(())
}

fn report_skipped(p: &Path, skipped: &[(u32, String)]) {
    for (pose, status) in skipped {
        errln!("{}: CapBall pose {pose} skipped ({status})", p.display());
    }
}

/// One run of a dataset: number, poses, measured values.
pub(crate) type RunData = (u32, Vec<Pose>, Vec<[f64; 3]>);

/// The runs of a dataset in the order they first appear, each split by
/// [`capball::split_run`].
pub(crate) fn runs_of(recs: &[capball::CapballRecord]) -> Vec<RunData> {
    let mut ids: Vec<u32> = Vec::new();
    for r in recs {
        if !ids.contains(&r.run) {
            ids.push(r.run);
        }
    }
    ids.into_iter()
        .map(|id| {
            let (poses, meas) = capball::split_run(recs, id);
            (id, poses, meas)
        })
        .collect()
}

/// One pose's residual (measured − model), with its time and angles, for the JSON output.
#[derive(Debug, Clone, serde::Serialize)]
struct PoseResidual {
    pose: usize,
    time_s: Option<f64>,
    a_deg: f64,
    c_deg: f64,
    ex_um: f64,
    ey_um: f64,
    ez_um: f64,
}

fn pose_residuals(
    setup: &CapballSetup,
    id: &Identification,
    poses: &[Pose],
    meas: &[[f64; 3]],
    times: &[Option<f64>],
) -> Vec<PoseResidual> {
    let p = nalgebra::DVector::from_column_slice(&id.params);
    poses
        .iter()
        .zip(meas)
        .enumerate()
        .map(|(i, (pose, m))| {
            let model = setup.jacobian(pose) * &p;
            PoseResidual {
                pose: i + 1,
                time_s: times.get(i).copied().flatten(),
                a_deg: pose.a_deg,
                c_deg: pose.c_deg,
                ex_um: m[0] - model[0],
                ey_um: m[1] - model[1],
                ez_um: m[2] - model[2],
            }
        })
        .collect()
}

/// The text report of one run's identification (`val`: the validation residual RMS).
pub(crate) fn identification_text(
    run: u32,
    ball: &Vector3<f64>,
    id: &Identification,
    val: Option<&[f64; 3]>,
) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    let _ = writeln!(
        t,
        "run {run}: {} poses, ball at ({:.3}, {:.3}, {:.3}) mm, condition number {}",
        id.n_poses,
        ball.x,
        ball.y,
        ball.z,
        result_or(id.condition_number, 1, "singular")
    );
    let _ = writeln!(t, "  {:<12} {:>12} {:>12}", "parameter", "value", "u (k=1)");
    for ((name, p), u) in PARAM_NAMES.iter().zip(&id.params).zip(&id.std_uncertainty) {
        // A parameter the poses do not determine: "n/d", never NaN in the table.
        let cell = |v: f64| {
            if v.is_finite() {
                format!("{v:.3}")
            } else {
                "n/d".into()
            }
        };
        let _ = writeln!(t, "  {name:<12} {:>12} {:>12}", cell(*p), cell(*u));
    }
    let why = "residuals not finite";
    let _ = writeln!(
        t,
        "  identification residual RMS {} µm (s = {} µm)",
        xyz_or(id.residual_rms_um, 3, why),
        result_or(id.residual_sigma_um, 3, why)
    );
    if let Some(v) = val {
        let _ = writeln!(t, "  validation residual RMS     {} µm", xyz_or(*v, 3, why));
    }
    t
}
