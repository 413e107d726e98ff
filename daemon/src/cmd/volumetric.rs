//! `metrolog volumetric`: volumetric error of a three-axis machine over a grid, from its 21
//! component errors (paper 004), and compensation tables.

use std::path::PathBuf;

use anyhow::Context;
use geometry::kinematics::Machine;
use geometry::volumetric::{self, ComponentErrors, GridSpec};

/// Volumetric error over the working volume and its compensation tables.
///
/// MACHINE (TOML): `chain = "WYFXZT"` (axes from workpiece W through frame F to tool T),
/// optional `tool_offset_mm = [x, y, z]` and `[axes.X] direction = [1, 0, 0]`.
///
/// ERRORS (CSV, long format): `error,position_mm,value`, one row per table point, ISO 230-1
/// names: `EXX` (positioning), `EYX`/`EZX` (straightness), `EAX` (roll), `EBX`/`ECX` (pitch,
/// yaw), likewise for Y and Z; `value` in µm for translations, µrad for rotations. The
/// squarenesses `EC0Y`, `EB0Z`, `EA0Z` (µrad) leave `position_mm` empty. Tables are
/// interpolated by natural cubic splines; beyond the table ends the end value holds.
///
/// Outputs: `--out` CSV `x_mm,y_mm,z_mm,ex_um,ey_um,ez_um,cx_um,cy_um,cz_um` (c = −e);
/// `--siemens` a SINUMERIK `%_N_NC_CEC_INI` file of nine interpolatory-compensation (CEC)
/// tables (input axis × output axis), with the part of the correction the one-dimensional
/// tables cannot represent reported.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Machine description (TOML).
    #[arg(long)]
    pub machine: PathBuf,
    /// Component errors (CSV).
    #[arg(long)]
    pub errors: PathBuf,
    /// Grid `x0:x1:nx,y0:y1:ny,z0:z1:nz` in mm.
    #[arg(long, allow_hyphen_values = true)]
    pub grid: String,
    /// Write the open compensation table (CSV) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write SINUMERIK CEC tables (`%_N_NC_CEC_INI`) here.
    #[arg(long)]
    pub siemens: Option<PathBuf>,
    /// Number of CEC tables the control holds (SINUMERIK 828D: 8); the tables with the
    /// smallest corrections are left out and listed.
    #[arg(long, default_value_t = volumetric::CEC_TABLES_840D)]
    pub cec_tables: usize,
    /// Machine axis names for the CEC tables, for X, Y, Z.
    #[arg(long, default_value = "AX1,AX2,AX3")]
    pub axis_names: String,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mtext = crate::cmd::input::read_text(&args.machine)?;
    let machine = Machine::from_toml(&mtext)
        .with_context(|| format!("machine {}", args.machine.display()))?;
    let etext = crate::cmd::input::read_text(&args.errors)?;
    let errors = ComponentErrors::from_csv(&etext)
        .with_context(|| format!("errors {}", args.errors.display()))?;
    let grid = GridSpec::parse(&args.grid)?;
    if grid.len() > 20_000_000 {
        anyhow::bail!(
            "grid of {} points is too large (limit 20 million)",
            grid.len()
        );
    }
    let mut outside = Vec::new();
    for (name, curve) in &errors.motion {
        if let Some((lo, hi)) = curve.range_mm() {
            let axis = match name.as_bytes().get(2) {
                Some(b'X') => 0,
                Some(b'Y') => 1,
                _ => 2,
            };
            let (a, b, _) = grid.ranges[axis];
            if a < lo - 1e-9 || b > hi + 1e-9 {
                outside.push(format!("{name} (table {lo}..{hi} mm)"));
            }
        }
    }
    let points = volumetric::volumetric_grid(&machine, &errors, &grid)?;
    let summary = volumetric::summarize(&points);
    if let Some(p) = &args.out {
        std::fs::write(p, volumetric::compensation_csv(&points))
            .with_context(|| format!("writing {}", p.display()))?;
    }
    let mut cec_resid = None;
    if let Some(p) = &args.siemens {
        let names: Vec<&str> = args.axis_names.split(',').map(str::trim).collect();
        if names.len() != 3 || names.iter().any(|n| n.is_empty()) {
            anyhow::bail!(
                "--axis-names `{}`: give three machine axis names for X, Y, Z, e.g. AX1,AX2,AX3",
                args.axis_names
            );
        }
        let t = machine.tool_offset_mm;
        let cec = volumetric::siemens_cec_for(
            &points,
            &grid,
            &volumetric::CecOptions {
                axis_names: [names[0], names[1], names[2]],
                max_tables: args.cec_tables.max(1),
                tool_offset_mm: Some([t.x, t.y, t.z]),
            },
        )?;
        std::fs::write(p, &cec.ini).with_context(|| format!("writing {}", p.display()))?;
        for o in &cec.omitted {
            errln!("CEC table left out (--cec-tables {}): {o}", args.cec_tables);
        }
        cec_resid = Some(cec.max_separation_residual_um);
    }
    if args.json {
        let v = serde_json::json!({
            "summary": summary,
            "tables_beyond_measured_range": outside,
            "siemens_cec_max_residual_um": cec_resid,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    outln!(
        "machine {} — {} grid points",
        machine.chain,
        summary.n_points
    )?;
    outln!(
        "largest volumetric error {:.2} µm at ({:.1}, {:.1}, {:.1}) mm; RMS x {:.2} y {:.2} z {:.2} µm",
        summary.max_norm_um,
        summary.max_at_mm[0],
        summary.max_at_mm[1],
        summary.max_at_mm[2],
        summary.rms_um[0],
        summary.rms_um[1],
        summary.rms_um[2]
    )?;
    if !outside.is_empty() {
        outln!(
            "warning: the grid goes beyond these tables (end values held): {}",
            outside.join(", ")
        )?;
    }
    if let Some(p) = &args.out {
        outln!("compensation table (CSV): {}", p.display())?;
    }
    if let (Some(p), Some(r)) = (&args.siemens, cec_resid) {
        outln!(
            "SINUMERIK CEC tables: {} (nine 1-D tables; they miss up to {r:.2} µm of the correction: the non-separable part)",
            p.display()
        )?;
    }
    Ok(())
}
