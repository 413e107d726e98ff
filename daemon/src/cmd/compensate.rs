//! `metrolog compensate positioning`: the controller's pitch-error compensation table from a
//! positioning run, and the ISO 230-2 result predicted after loading it (`docs/methods.md`
//! "Pitch-error compensation").

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use positioning::compensation::{Dialect, Mode, Options, build, verify};

use crate::cmd::input::{load_positioning, print_out};

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Pitch-error (leadscrew) compensation table of one axis from a positioning run.
    Positioning(PositioningArgs),
}

#[derive(Debug, clap::Args)]
pub struct PositioningArgs {
    /// Positioning dataset (CSV, see datasets.md) or MCAP log of a run.
    pub input: PathBuf,
    /// Controller: sinumerik, fanuc, heidenhain or linuxcnc.
    #[arg(long)]
    pub dialect: Dialect,
    /// Table point spacing, mm [default: the mean target spacing].
    #[arg(long, value_name = "MM")]
    pub spacing: Option<f64>,
    /// Reference (home) position of the axis, mm; the table is 0 there [default: the run's
    /// `home_mm` metadata, else 0 mm, the machine's home].
    #[arg(long, value_name = "MM")]
    pub reference_point: Option<f64>,
    /// One table per direction of approach (LinuxCNC, HEIDENHAIN).
    #[arg(long, conflicts_with = "backlash")]
    pub bidirectional: bool,
    /// One table from the positive direction plus a backlash value.
    #[arg(long)]
    pub backlash: bool,
    /// Axis name as the controller knows it [default: the run's axis; SINUMERIK: its machine
    /// axis, e.g. X1 for X, as in Siemens' K3 example].
    #[arg(long)]
    pub axis_name: Option<String>,
    /// Axis number (FANUC parameter axis, LinuxCNC joint + 1).
    #[arg(long, default_value_t = 1)]
    pub axis_number: usize,
    /// FANUC: the largest value one pitch point may hold (the control model's limit, in
    /// detection units × magnification) [default: 127; older controls: 7].
    #[arg(long, value_name = "N")]
    pub point_limit: Option<u32>,
    /// Directory for the files.
    #[arg(long, short = 'o', default_value = ".")]
    pub out: PathBuf,
    /// Print JSON (table and before/after) instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(c: Command) -> anyhow::Result<()> {
    let Command::Positioning(a) = c;
    let data = load_positioning(&a.input)?;
    let mode = match (a.bidirectional, a.backlash) {
        (true, _) => Mode::Bidirectional,
        (_, true) => Mode::Backlash,
        _ => Mode::Mean,
    };
    let o = Options {
        dialect: a.dialect,
        mode,
        spacing_mm: a.spacing,
        reference_mm: a.reference_point,
        axis_name: a.axis_name.clone(),
        axis_number: a.axis_number,
        point_limit: a.point_limit,
    };
    let t = build(&data, &o)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut written = Vec::new();
    for (name, text) in &t.files {
        let p = a.out.join(name);
        std::fs::write(&p, text).with_context(|| format!("writing {}", p.display()))?;
        written.push(p);
    }
    let v = verify(&data, &t);
    if a.json {
        let j = serde_json::json!({ "table": t, "iso230_2_before": v.before, "iso230_2_predicted_after": v.after });
        return print_out(&(serde_json::to_string_pretty(&j)? + "\n"));
    }
    let f = |x: Option<f64>| {
        x.map(|x| metrolog_analysis::export::num(x, 2))
            .unwrap_or_else(|| "—".into())
    };
    let mut s = format!(
        "{:?} table, {:?}, {} points from {:.3} to {:.3} mm, reference {:.3} mm\n",
        t.dialect,
        t.mode,
        t.points_mm.len(),
        t.points_mm[0],
        t.points_mm[t.points_mm.len() - 1],
        t.reference_mm
    );
    for p in &written {
        let _ = writeln!(s, "  wrote {}", p.display());
    }
    let _ = writeln!(
        s,
        "\nISO 230-2 (µm)     measured   predicted after compensation"
    );
    for (k, b, af) in [
        ("A", v.before.a, v.after.a),
        ("E", v.before.e, v.after.e),
        ("M", v.before.m, v.after.m),
        ("B", v.before.b, v.after.b),
        ("R", v.before.r, v.after.r),
    ] {
        let _ = writeln!(s, "  {k:<16} {:>8} {:>10}", f(b), f(af));
    }
    let _ = writeln!(s, "\nOn the control:");
    for n in &t.notes {
        let _ = writeln!(s, "  - {n}");
    }
    let _ = writeln!(
        s,
        "The prediction assumes the same repeatability and drift after compensation; measure the axis again to confirm."
    );
    print_out(&s)
}
