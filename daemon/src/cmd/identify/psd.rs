//! `metrolog identify psd`: the 13 errors of the PSD laser frame (paper 003) relative to a
//! reference run, with their uncertainty from one reading uncertainty or, with
//! `--uncertainty mc`, from the Monte Carlo of [`super::psd_mc`].

use std::path::PathBuf;

use anyhow::Context;
use geometry::psd_frame::{self, PsdLayout};

use super::psd_mc::{self, PsdMcArgs};
use crate::cmd::input::{numbers_arg, read_csv};

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
    pub mc: PsdMcArgs,
}

pub fn run(a: PsdArgs) -> anyhow::Result<()> {
    let layout = match &a.layout {
        Some(s) => {
            let v = numbers_arg(s, 6, "--layout")?;
            check_layout(&v)?;
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
    // A reading's uncertainty cannot exceed half the diode (10 mm × 10 mm).
    if !(a.sigma_um.is_finite() && (0.0..=5000.0).contains(&a.sigma_um)) {
        anyhow::bail!(
            "--sigma-um {}: must be a number from 0 to 5000 µm (half the PSD's 10 mm)",
            a.sigma_um
        );
    }
    let runs = psd_frame::parse_readings_csv(&layout, &read_csv(&a.data)?)
        .with_context(|| format!("{}", a.data.display()))?;
    let out = errors_against(&layout, &runs, a.reference)
        .with_context(|| format!("{}", a.data.display()))?;
    // Reference subtraction doubles the variance of every reading.
    let u = psd_frame::derive_uncertainty(&layout, a.sigma_um * 2f64.sqrt())?;
    if a.mc.uncertainty.is_some() {
        return psd_mc::run(&layout, a.reference, &out, &a.mc, a.json);
    }
    if a.json {
        let v: Vec<_> = out
            .iter()
            .map(|(run, e)| serde_json::json!({ "run": run, "errors": e, "names": e.names(), "std_uncertainty": u }))
            .collect();
        outln!(
            "{}",
            serde_json::to_string_pretty(
                &serde_json::json!({ "reference": a.reference, "runs": v })
            )?
        )?;
        return Ok(());
    }
    out!("{}", errors_text(a.reference, &out, &u))?;
    Ok(())
}

/// Every run's errors relative to the reference run (the runs of a readings file).
pub(crate) fn errors_against(
    layout: &PsdLayout,
    runs: &[(u32, psd_frame::PsdReadings)],
    reference: u32,
) -> anyhow::Result<Vec<(u32, psd_frame::PsdErrors)>> {
    let reference_readings = &runs
        .iter()
        .find(|r| r.0 == reference)
        .ok_or_else(|| anyhow::anyhow!("reference run {reference} is not in the file"))?
        .1;
    let mut out = Vec::new();
    for (run, r) in runs.iter().filter(|r| r.0 != reference) {
        let e = psd_frame::derive_errors(layout, &r.minus(reference_readings)?)
            .with_context(|| format!("run {run}"))?;
        out.push((*run, e));
    }
    anyhow::ensure!(!out.is_empty(), "the file holds only the reference run");
    Ok(out)
}

/// The text report: per run, the squareness with its uncertainty `u` (in the order of
/// [`psd_frame::PsdErrors::names`]), the positioning change and the ranges of the rest.
pub(crate) fn errors_text(
    reference: u32,
    out: &[(u32, psd_frame::PsdErrors)],
    u: &[f64],
) -> String {
    use std::fmt::Write as _;
    let span = |v: &[f64]| {
        v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
    };
    let mut t = String::new();
    for (run, e) in out {
        let names = e.names();
        let ui = |n: &str| {
            names
                .iter()
                .position(|x| x == n)
                .and_then(|k| u.get(k).copied())
                .unwrap_or(f64::NAN)
        };
        let _ = writeln!(t, "run {run} − run {reference}:");
        let _ = writeln!(
            t,
            "  squareness EC0Y {:.2} EB0Z {:.2} EA0Z {:.2} µrad (u {:.2} {:.2} {:.2})",
            e.ec0y_urad,
            e.eb0z_urad,
            e.ea0z_urad,
            ui("EC0Y_urad"),
            ui("EB0Z_urad"),
            ui("EA0Z_urad")
        );
        let _ = writeln!(
            t,
            "  positioning change over the travel: X {:.2} µm, Y {:.2} µm",
            e.exx_um.last().unwrap_or(&0.0) - e.exx_um.first().unwrap_or(&0.0),
            e.eyy_um.last().unwrap_or(&0.0) - e.eyy_um.first().unwrap_or(&0.0)
        );
        let _ = writeln!(
            t,
            "  straightness ranges EYX {:.2} EZX {:.2} EXY {:.2} EZY {:.2} EXZ {:.2} EYZ {:.2} µm",
            span(&e.eyx_um),
            span(&e.ezx_um),
            span(&e.exy_um),
            span(&e.ezy_um),
            span(&e.exz_um),
            span(&e.eyz_um)
        );
        let _ = writeln!(
            t,
            "  roll ranges EAX {:.2} EBY {:.2} µrad",
            span(&e.eax_urad),
            span(&e.eby_urad)
        );
    }
    t
}

/// A frame's layout: positions within ±100000 mm and each pair (x, y, z) at least 1 mm apart,
/// low before high (a frame of 1e-320 mm divided the squareness by zero).
fn check_layout(v: &[f64]) -> anyhow::Result<()> {
    let within = v.iter().all(|x| x.is_finite() && x.abs() <= 100_000.0);
    let spans = v.chunks(2).all(|p| p[1] - p[0] >= 1.0);
    if !(within && spans) {
        anyhow::bail!(
            "--layout {v:?}: x_lo,x_hi,y_lo,y_hi,z0,z1 in mm within ±100000, each high at least 1 mm above its low"
        );
    }
    Ok(())
}
