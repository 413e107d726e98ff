//! `metrolog identify`: machine errors from CapBall (paper 001) or PSD laser-frame (paper 003)
//! measurements, CapBall trajectories and sensor-frame calibration.

use std::path::{Path, PathBuf};

use anyhow::Context;
use geometry::capball::{self, CapballSetup, Identification, PARAM_NAMES, TrajectorySpec};
use geometry::kinematics::{Machine, Pose};
use geometry::psd_frame::{self, PsdLayout};
use metrolog_log::trajectory::{TrajectoryRow, write_trajectory};
use nalgebra::Vector3;

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Identify the 8 link + 6 setup errors of a five-axis machine from a CapBall dataset.
    ///
    /// DATA: CSV `run,pose,time_s,x_mm,y_mm,z_mm,a_deg,c_deg,ex_um,ey_um,ez_um` (shared
    /// dataset format; volumetric errors in the machine frame, µm). Each run is identified
    /// separately. The ball position is found from the poses (the table point under the tool).
    Capball(CapballArgs),
    /// Derive 13 errors from PSD laser-frame readings, relative to a reference run.
    ///
    /// DATA: CSV `run,segment,point,r1_um,r2_um`: segment 1..5 (S1 along Y at x_lo, S2 along X
    /// at y_hi, S3 along Y at x_hi, S4 along X at y_lo, S5 along Z), point 1..n in ascending
    /// coordinate (S1: 7 points = the first 7 Y positions of S3; others 11), (r1, r2) =
    /// (ex, ez) on S1/S3, (ey, ez) on S2/S4, (ex, ey) on S5, µm. See
    /// geometry/src/psd_frame.md for the model.
    Psd(PsdArgs),
    /// Write a CapBall identification trajectory (`pose,x_mm,y_mm,z_mm,a_deg,c_deg`).
    Trajectory(TrajectoryArgs),
    /// Sensor-frame calibration `T = M S⁺` from the 5×5×5 cube of programmed moves.
    ///
    /// DATA: CSV `mx_um,my_um,mz_um,s1_um,s2_um,s3_um` (programmed displacement, sensor readings).
    SensorFrame(SensorFrameArgs),
}

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
    pub mc: super::identify_mc::CapballMcArgs,
}

#[derive(Debug, clap::Args)]
pub struct PsdArgs {
    /// PSD readings (CSV).
    pub data: PathBuf,
    /// Run number of the reference run.
    #[arg(long)]
    pub reference: u32,
    /// Layout `x_lo,x_hi,y_lo,y_hi,z0,z1` in mm (default: paper 003's 0,184,0,167,0,350).
    #[arg(long, allow_hyphen_values = true)]
    pub layout: Option<String>,
    /// Standard uncertainty of one reading, µm, for the uncertainty of the derived errors
    /// (one value for every reading; `--uncertainty mc --budget FILE` uses the
    /// position-dependent budget of paper 003 instead).
    #[arg(long, default_value_t = 0.2)]
    pub sigma_um: f64,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub mc: super::identify_psd_mc::PsdMcArgs,
}

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

#[derive(Debug, clap::Args)]
pub struct SensorFrameArgs {
    pub data: PathBuf,
    #[arg(long)]
    pub json: bool,
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Capball(a) => run_capball(a),
        Command::Psd(a) => run_psd(a),
        Command::Trajectory(a) => run_trajectory(a),
        Command::SensorFrame(a) => run_sensor_frame(a),
    }
}

fn read(p: &Path) -> anyhow::Result<String> {
    if p.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    {
        anyhow::bail!(
            "{}: this input must be a CSV file (`identify capball` reads MCAP logs; the PSD \
             13-error identification needs the 51-point laser frame and a reference run as CSV — \
             a log's single PSD segment gives its straightness, printed by `metrolog demo`)",
            p.display()
        );
    }
    std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))
}

/// CapBall records from a CSV dataset or an MCAP log (the poses that hold the tool on the
/// ball, see [`metrolog_analysis::capball`]).
fn load_capball(p: &Path, machine: &Machine) -> anyhow::Result<Vec<capball::CapballRecord>> {
    if metrolog_analysis::is_mcap(p) {
        let cb = super::progress::read_contents(p, "reading")
            .and_then(|log| metrolog_analysis::capball::capball_from_contents(&log, machine))
            .with_context(|| {
                format!(
                    "reading the CapBall poses of {} (identify capball reads a run's MCAP log or a CSV dataset)",
                    p.display()
                )
            })?;
        report_skipped(p, &cb.skipped);
        return Ok(cb.records);
    }
    capball::parse_dataset(&read(p)?).with_context(|| format!("{}", p.display()))
}

fn report_skipped(p: &Path, skipped: &[(u32, String)]) {
    for (pose, status) in skipped {
        eprintln!("{}: CapBall pose {pose} skipped ({status})", p.display());
    }
}

fn machine_from(p: &Option<PathBuf>) -> anyhow::Result<Machine> {
    Ok(match p {
        Some(p) => {
            Machine::from_toml(&read(p)?).with_context(|| format!("machine {}", p.display()))?
        }
        None => Machine::from_config(&CapballSetup::paper_machine_config())?,
    })
}

fn numbers(s: &str, n: usize, what: &str) -> anyhow::Result<Vec<f64>> {
    let v: Result<Vec<f64>, _> = s.split(',').map(|x| x.trim().parse::<f64>()).collect();
    match v {
        Ok(v) if v.len() == n && v.iter().all(|x| x.is_finite()) => Ok(v),
        _ => anyhow::bail!("{what} `{s}`: expected {n} comma-separated numbers"),
    }
}

fn split_runs(recs: &[capball::CapballRecord]) -> Vec<(u32, Vec<Pose>, Vec<[f64; 3]>)> {
    let mut runs: Vec<(u32, Vec<Pose>, Vec<[f64; 3]>)> = Vec::new();
    for r in recs {
        match runs.iter_mut().find(|x| x.0 == r.run) {
            Some(x) => {
                x.1.push(r.pose);
                x.2.push(r.e_um);
            }
            None => runs.push((r.run, vec![r.pose], vec![r.e_um])),
        }
    }
    runs
}

fn run_capball(a: CapballArgs) -> anyhow::Result<()> {
    let mut machine = machine_from(&a.machine)?;
    let recs = if metrolog_analysis::is_mcap(&a.data) && a.machine.is_none() {
        // No machine given: the log's poses choose the kinematic convention.
        let cb = super::progress::read_contents(&a.data, "reading")
            .and_then(|log| metrolog_analysis::capball::capball_from_contents_auto(&log))
            .with_context(|| {
                format!(
                    "reading the CapBall poses of {} (identify capball reads a run's MCAP log or a CSV dataset)",
                    a.data.display()
                )
            })?;
        report_skipped(&a.data, &cb.skipped);
        eprintln!("{}: machine {}", a.data.display(), cb.machine_name);
        machine = cb.machine;
        cb.records
    } else {
        load_capball(&a.data, &machine)?
    };
    if a.mc.uncertainty.is_some() {
        return super::identify_mc::run(&a.data, &machine, &recs, &a.mc, a.json);
    }
    let mut runs = split_runs(&recs);
    if let Some(r) = a.run {
        runs.retain(|x| x.0 == r);
        if runs.is_empty() {
            anyhow::bail!("run {r} is not in {}", a.data.display());
        }
    }
    let validation = match &a.validate {
        Some(p) => {
            let v = load_capball(p, &machine)?;
            Some(split_runs(&v))
        }
        None => None,
    };
    let mut results = Vec::new();
    let mut extra = Vec::new();
    for (run, poses, meas) in &runs {
        let setup = CapballSetup::with_ball_from_poses(machine.clone(), poses)
            .with_context(|| format!("run {run}"))?;
        let id = setup
            .identify(poses, meas)
            .with_context(|| format!("run {run}"))?;
        let val = match &validation {
            Some(v) => {
                let (vp, vm): (Vec<Pose>, Vec<[f64; 3]>) =
                    v.iter().fold((vec![], vec![]), |mut acc, x| {
                        acc.0.extend_from_slice(&x.1);
                        acc.1.extend_from_slice(&x.2);
                        acc
                    });
                let rms = setup.validation_rms_um(&id, &vp, &vm)?;
                let times: Vec<Option<f64>> = validation_records(&a, &machine)?
                    .iter()
                    .map(|r| r.time_s)
                    .collect();
                let res = pose_residuals(&setup, &id, &vp, &vm, &times);
                Some((rms, res))
            }
            None => None,
        };
        let times: Vec<Option<f64>> = recs
            .iter()
            .filter(|r| r.run == *run)
            .map(|r| r.time_s)
            .collect();
        let own = pose_residuals(&setup, &id, poses, meas, &times);
        let warning = val
            .as_ref()
            .and_then(|(v, _)| excess_warning(&id, v, validation_len(validation.as_deref())));
        if let Some(w) = &warning {
            eprintln!("run {run}: warning: {w}");
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
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({ "runs": v }))?
        );
        return Ok(());
    }
    for (run, ball, id, val) in &results {
        print_identification(*run, ball, id, val.as_ref());
    }
    Ok(())
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

fn validation_records(
    a: &CapballArgs,
    machine: &Machine,
) -> anyhow::Result<Vec<capball::CapballRecord>> {
    match &a.validate {
        Some(p) => load_capball(p, machine),
        None => Ok(Vec::new()),
    }
}

/// One run of a dataset: number, poses, measured values.
type RunData = (u32, Vec<Pose>, Vec<[f64; 3]>);

fn validation_len(v: Option<&[RunData]>) -> usize {
    v.map(|runs| runs.iter().map(|r| r.1.len()).sum())
        .unwrap_or(0)
}

/// A warning when the validation residual exceeds what white noise of the identification's
/// level explains: the ratio of mean squares beyond 5 standard deviations of its spread
/// (`2/n_val + 2/dof`, equations counted per channel).
fn excess_warning(id: &Identification, val_rms: &[f64; 3], n_val_poses: usize) -> Option<String> {
    let s2 = id.residual_sigma_um.powi(2);
    let n_val = 3 * n_val_poses;
    if s2 <= 0.0 || n_val == 0 {
        return None;
    }
    let v2 = val_rms.iter().map(|v| v * v).sum::<f64>() / 3.0;
    let ratio = v2 / s2;
    let bound = 1.0 + 5.0 * (2.0 / n_val as f64 + 2.0 / id.dof.max(1) as f64).sqrt();
    (ratio > bound).then(|| {
        format!(
            "the validation residual RMS ({:.3} µm) is {:.2}× the identification's ({:.3} µm); white noise explains at most {:.2}×: the 14-parameter model misses something that differs between the runs (a drift of the measuring loop, a sensor gain, an axis error). Run `metrolog diagnose` on a dataset holding both runs (run 1 identification, run 2 validation)",
            v2.sqrt(),
            ratio.sqrt(),
            s2.sqrt(),
            bound.sqrt()
        )
    })
}

fn print_identification(
    run: u32,
    ball: &Vector3<f64>,
    id: &Identification,
    val: Option<&[f64; 3]>,
) {
    println!(
        "run {run}: {} poses, ball at ({:.3}, {:.3}, {:.3}) mm, condition number {:.1}",
        id.n_poses, ball.x, ball.y, ball.z, id.condition_number
    );
    println!("  {:<12} {:>12} {:>12}", "parameter", "value", "u (k=1)");
    for ((name, p), u) in PARAM_NAMES.iter().zip(&id.params).zip(&id.std_uncertainty) {
        println!("  {name:<12} {p:>12.3} {u:>12.3}");
    }
    let r = id.residual_rms_um;
    println!(
        "  identification residual RMS x {:.3} y {:.3} z {:.3} µm (s = {:.3} µm)",
        r[0], r[1], r[2], id.residual_sigma_um
    );
    if let Some(v) = val {
        println!(
            "  validation residual RMS     x {:.3} y {:.3} z {:.3} µm",
            v[0], v[1], v[2]
        );
    }
}

fn run_trajectory(a: TrajectoryArgs) -> anyhow::Result<()> {
    let machine = machine_from(&a.machine)?;
    let ball = match &a.ball_mm {
        Some(s) => {
            let v = numbers(s, 3, "--ball-mm")?;
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

fn run_sensor_frame(a: SensorFrameArgs) -> anyhow::Result<()> {
    let text = read(&a.data)?;
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let h = rdr.headers()?.clone();
    let names = ["mx_um", "my_um", "mz_um", "s1_um", "s2_um", "s3_um"];
    let idx: Vec<usize> = names
        .iter()
        .map(|n| {
            h.iter()
                .position(|x| x == *n)
                .ok_or_else(|| anyhow::anyhow!("missing column `{n}` (need {names:?})"))
        })
        .collect::<anyhow::Result<_>>()?;
    let (mut m, mut s) = (Vec::new(), Vec::new());
    for (i, rec) in rdr.records().enumerate() {
        let rec = rec?;
        let v: Vec<f64> = idx
            .iter()
            .map(|&k| rec.get(k).unwrap_or("").parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("row {}: not a number", i + 2))?;
        m.push(Vector3::new(v[0], v[1], v[2]));
        s.push(Vector3::new(v[3], v[4], v[5]));
    }
    let f = capball::calibrate_sensor_frame(&m, &s)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&f)?);
        return Ok(());
    }
    println!(
        "sensor frame from {} points (residual RMS {:.3} µm)",
        f.n_points, f.residual_rms_um
    );
    for row in &f.t {
        println!(
            "  [{:>10.6} {:>10.6} {:>10.6} {:>10.3}]",
            row[0], row[1], row[2], row[3]
        );
    }
    println!(
        "gains {:.5} {:.5} {:.5} ({:+.2} %, {:+.2} %, {:+.2} %)",
        f.gains[0],
        f.gains[1],
        f.gains[2],
        f.gain_error_pct[0],
        f.gain_error_pct[1],
        f.gain_error_pct[2]
    );
    let n = f.non_orthogonality_urad;
    println!(
        "non-orthogonality (cosines) t1·t2 {:.0} t1·t3 {:.0} t2·t3 {:.0} µrad",
        n[0], n[1], n[2]
    );
    let o = f.offsets_um;
    println!(
        "offsets {:.3} {:.3} {:.3} µm; last row {:?}",
        o[0], o[1], o[2], f.last_row
    );
    Ok(())
}

fn run_psd(a: PsdArgs) -> anyhow::Result<()> {
    let layout = match &a.layout {
        Some(s) => {
            let v = numbers(s, 6, "--layout")?;
            PsdLayout {
                x_lo: v[0],
                x_hi: v[1],
                y_lo: v[2],
                y_hi: v[3],
                z0: v[4],
                z1: v[5],
                ..PsdLayout::paper()
            }
        }
        None => PsdLayout::paper(),
    };
    if !(a.sigma_um.is_finite() && a.sigma_um >= 0.0) {
        anyhow::bail!("--sigma-um {}: must be a non-negative number", a.sigma_um);
    }
    let runs = psd_frame::parse_readings_csv(&layout, &read(&a.data)?)
        .with_context(|| format!("{}", a.data.display()))?;
    let reference = runs
        .iter()
        .find(|r| r.0 == a.reference)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "reference run {} is not in {}",
                a.reference,
                a.data.display()
            )
        })?
        .1
        .clone();
    // Reference subtraction doubles the variance of every reading.
    let u = psd_frame::derive_uncertainty(&layout, a.sigma_um * 2f64.sqrt())?;
    let mut out = Vec::new();
    for (run, r) in runs.iter().filter(|r| r.0 != a.reference) {
        let e = psd_frame::derive_errors(&layout, &r.minus(&reference)?)
            .with_context(|| format!("run {run}"))?;
        out.push((*run, e));
    }
    if out.is_empty() {
        anyhow::bail!("{} holds only the reference run", a.data.display());
    }
    if a.mc.uncertainty.is_some() {
        return super::identify_psd_mc::run(&layout, a.reference, &out, &a.mc, a.json);
    }
    if a.json {
        let v: Vec<_> = out
            .iter()
            .map(|(run, e)| serde_json::json!({ "run": run, "errors": e, "names": e.names(), "std_uncertainty": u }))
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({ "reference": a.reference, "runs": v })
            )?
        );
        return Ok(());
    }
    for (run, e) in &out {
        println!("run {run} − run {}:", a.reference);
        let names = e.names();
        let ui = |n: &str| {
            names
                .iter()
                .position(|x| x == n)
                .map(|k| u[k])
                .unwrap_or(f64::NAN)
        };
        println!(
            "  squareness EC0Y {:.2} EB0Z {:.2} EA0Z {:.2} µrad (u {:.2} {:.2} {:.2})",
            e.ec0y_urad,
            e.eb0z_urad,
            e.ea0z_urad,
            ui("EC0Y_urad"),
            ui("EB0Z_urad"),
            ui("EA0Z_urad")
        );
        let span = |v: &[f64]| {
            v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
        };
        println!(
            "  positioning change over the travel: X {:.2} µm, Y {:.2} µm",
            e.exx_um.last().unwrap_or(&0.0) - e.exx_um.first().unwrap_or(&0.0),
            e.eyy_um.last().unwrap_or(&0.0) - e.eyy_um.first().unwrap_or(&0.0)
        );
        println!(
            "  straightness ranges EYX {:.2} EZX {:.2} EXY {:.2} EZY {:.2} EXZ {:.2} EYZ {:.2} µm",
            span(&e.eyx_um),
            span(&e.ezx_um),
            span(&e.exy_um),
            span(&e.ezy_um),
            span(&e.exz_um),
            span(&e.eyz_um)
        );
        println!(
            "  roll ranges EAX {:.2} EBY {:.2} µrad",
            span(&e.eax_urad),
            span(&e.eby_urad)
        );
    }
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
