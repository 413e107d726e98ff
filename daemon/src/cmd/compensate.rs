//! `metrolog compensate positioning`: the controller's pitch-error compensation table from a
//! positioning run, and the ISO 230-2 result predicted after loading it (`docs/methods.md`
//! "Pitch-error compensation").

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use positioning::compensation::{Dialect, Mode, Options, Remeasured, build, remeasured, verify};
use positioning::iso230::AxisStats;

use crate::cmd::input::{load_positioning, print_out};

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Pitch-error (leadscrew) compensation table of one axis from a positioning run.
    Positioning(PositioningArgs),
    /// Measured before/after: the run a table was built from against the verification run
    /// measured with the table loaded (ISO 230-2 of both, mean deviations at the targets).
    Verify(VerifyArgs),
}

#[derive(Debug, clap::Args)]
pub struct VerifyArgs {
    /// The run the table was built from (CSV dataset or MCAP log).
    pub before: PathBuf,
    /// The verification run, measured with the table loaded (CSV dataset or MCAP log).
    pub after: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
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
    /// One table per direction of approach (LinuxCNC, HEIDENHAIN). Without this or
    /// --backlash the table corrects the mean of both directions and leaves the backlash (the
    /// reversal value B) as measured.
    #[arg(long, conflicts_with = "backlash")]
    pub bidirectional: bool,
    /// One table from the positive direction plus a backlash value.
    #[arg(long)]
    pub backlash: bool,
    /// Axis name as the controller knows it: letters and optional digits, at most 8 (X, X1,
    /// AX1) [default: the run's axis; SINUMERIK: its machine axis, e.g. X1 for X, as in
    /// Siemens' K3 example].
    #[arg(long)]
    pub axis_name: Option<String>,
    /// Axis number: FANUC parameter axis 1 to 32, LinuxCNC joint + 1 (1 to 16).
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
    match c {
        Command::Positioning(a) => positioning(a),
        Command::Verify(a) => verify_runs(a),
    }
}

fn verify_runs(a: VerifyArgs) -> anyhow::Result<()> {
    let before = load_positioning(&a.before)?;
    let after = load_positioning(&a.after)?;
    let r = remeasured(&before, &after);
    if a.json {
        return print_out(&(serde_json::to_string_pretty(&r)? + "\n"));
    }
    print_out(&before_after_text(&r, None))
}

fn um(x: Option<f64>) -> String {
    x.map(|x| metrolog_analysis::export::num(x, 2))
        .unwrap_or_else(|| "—".into())
}

/// Measured before → measured after (and the prediction beside it when given): ISO 230-2 of
/// both runs and the mean deviations at the targets they share.
pub fn before_after_text(r: &Remeasured, predicted: Option<&AxisStats>) -> String {
    let mut s = String::from("ISO 230-2 (µm)   measured before   measured after");
    if predicted.is_some() {
        s.push_str("   predicted after");
    }
    s.push('\n');
    let p = |f: fn(&AxisStats) -> Option<f64>| predicted.map(f);
    for (k, b, af, pr) in [
        ("E", r.before.e, r.after.e, p(|a| a.e)),
        ("A", r.before.a, r.after.a, p(|a| a.a)),
        ("B", r.before.b, r.after.b, p(|a| a.b)),
        ("R", r.before.r, r.after.r, p(|a| a.r)),
        ("M", r.before.m, r.after.m, p(|a| a.m)),
    ] {
        let _ = write!(s, "  {k:<14} {:>15} {:>16}", um(b), um(af));
        if let Some(pr) = pr {
            let _ = write!(s, " {:>17}", um(pr));
        }
        s.push('\n');
    }
    if let Some(q) = r.e_ratio() {
        let _ = writeln!(
            s,
            "  the table left {:.1} % of E, the error at the targets in both directions",
            100.0 * q
        );
    }
    let _ = writeln!(
        s,
        "\nmean deviation at the targets (µm)   before ↑   before ↓    after ↑    after ↓"
    );
    for t in &r.targets {
        let _ = writeln!(
            s,
            "  {:>12.3} mm {:>25} {:>10} {:>10} {:>10}",
            t.target_mm,
            um(t.before_up_um),
            um(t.before_down_um),
            um(t.after_up_um),
            um(t.after_down_um)
        );
    }
    if !r.unmatched_mm.is_empty() {
        let _ = writeln!(
            s,
            "  not measured again: {} mm",
            r.unmatched_mm
                .iter()
                .map(|x| format!("{x:.3}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    s
}

fn positioning(a: PositioningArgs) -> anyhow::Result<()> {
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
        "The prediction assumes the same repeatability and drift after compensation; measure the axis again with the table loaded and compare: metrolog compensate verify {} VERIFICATION_RUN",
        a.input.display()
    );
    print_out(&s)
}
