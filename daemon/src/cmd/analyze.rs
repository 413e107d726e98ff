//! `metrolog analyze`: evaluate a measurement. `analyze positioning` runs ISO 230-2 with the
//! thermal-drift elimination of Stejskal et al. (2017) on a positioning dataset; `analyze
//! thermal` evaluates an ISO 230-3 thermal test (`cmd::thermal::iso230_3`).

use std::path::PathBuf;

use anyhow::Context as _;
use metrolog_analysis::positioning_report::{
    analyze_positioning_given, decide_tolerances, render_text,
};
use positioning::iso230;

use crate::cmd::input::load_positioning_with;

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// ISO 230-2 positioning accuracy and repeatability of one axis, with thermal-drift
    /// elimination (adjacent-target differences).
    Positioning(PositioningArgs),
    /// ISO 230-3 thermal test: ETVE of every displacement channel and, with `--probes`, the
    /// spindle's thermal distortion (X, Y, Z drift, A and B tilt).
    Thermal(crate::cmd::thermal::iso230_3::Args),
}

#[derive(Debug, clap::Args)]
pub struct PositioningArgs {
    /// Positioning dataset (CSV, see datasets.md) or MCAP log of a run.
    pub input: PathBuf,
    #[command(flatten)]
    pub units: crate::cmd::input::UnitArgs,
    #[command(flatten)]
    pub tolerances: crate::cmd::input::ToleranceArgs,
    #[command(flatten)]
    pub assumed: crate::cmd::input::AssumeArgs,
    /// Print a JSON report instead of tables.
    #[arg(long)]
    pub json: bool,
    /// Draw the deviation charts and a target's deviation vs time (.svg or .png).
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
    /// Cycle whose target-1 reading anchors the drift-free chart [default: the first cycle
    /// after 2 h of measuring, else the last].
    #[arg(long, value_name = "N")]
    pub reference_cycle: Option<usize>,
    /// Target whose deviation vs time is plotted [default: the one with the largest classic
    /// scatter].
    #[arg(long, value_name = "INDEX")]
    pub plot_target: Option<usize>,
    /// Also evaluate by these standards (repeat or comma-separate): iso230-2:2014,
    /// iso230-2:2006, iso230-2:1997, iso230-2:1988, vdi3441, asme-b5.54, jis-b6192, gb17421.2.
    #[arg(long, value_delimiter = ',')]
    pub standard: Vec<positioning::standards::Standard>,
    /// Also write readings.csv, targets.csv and results.csv (every standard's parameters) here.
    #[arg(long, value_name = "DIR")]
    pub csv: Option<PathBuf>,
    /// MCAP log only: trajectory CSV of the run instead of the log's attachment.
    #[arg(long, value_name = "FILE")]
    pub trajectory: Option<PathBuf>,
    /// MCAP log only: the poses of the positioning run, `A-B` [default: the first block of
    /// poses in which only x changes].
    #[arg(long, value_name = "A-B")]
    pub poses: Option<String>,
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Positioning(a) => positioning(a),
        Command::Thermal(a) => crate::cmd::thermal::iso230_3::run(a),
    }
}

fn positioning(a: PositioningArgs) -> anyhow::Result<()> {
    let opts = metrolog_analysis::PositioningOptions {
        trajectory: a.trajectory.clone(),
        poses: a
            .poses
            .as_deref()
            .map(metrolog_analysis::parse_pose_range)
            .transpose()?,
        datum_x_mm: None,
    };
    let mut data = load_positioning_with(&a.input, &opts)?;
    a.units.apply(&mut data)?;
    if let Some(r) = a.reference_cycle {
        anyhow::ensure!(
            (1..=data.n_cycles()).contains(&r),
            "--reference-cycle {r} is not a cycle of this run (1..{})",
            data.n_cycles()
        );
    }
    let mut an = analyze_positioning_given(&data, a.reference_cycle, |s| a.assumed.apply(s));
    an.conformance = decide_tolerances(&an, &a.tolerances.tolerance);
    if let Some(p) = &a.plot {
        let target = match a.plot_target {
            Some(t) => {
                anyhow::ensure!(
                    (1..=data.n_targets()).contains(&t),
                    "--plot-target {t} is not a target of this run (1..{})",
                    data.n_targets()
                );
                t
            }
            None => an
                .targets
                .iter()
                .max_by(|x, y| {
                    let s = |t: &iso230::TargetStats| {
                        t.s_up_um.unwrap_or(0.0).max(t.s_down_um.unwrap_or(0.0))
                    };
                    s(x).total_cmp(&s(y))
                })
                .map(|t| t.index)
                .unwrap_or(1),
        };
        crate::cmd::plots::draw_positioning(p, &data, &an, target)
            .with_context(|| format!("drawing {}", p.display()))?;
    }
    let standards: Vec<_> = a
        .standard
        .iter()
        .map(|s| positioning::standards::evaluate(&data, *s))
        .collect();
    if let Some(dir) = &a.csv {
        metrolog_analysis::export::write_csv_dir(dir, &data, &an.targets, &standards)
            .with_context(|| format!("writing CSV into {}", dir.display()))?;
    }
    let text = if a.json {
        let mut v = serde_json::to_value(&an)?;
        if let Some(o) = v.as_object_mut().filter(|_| !standards.is_empty()) {
            o.insert("standards".into(), serde_json::to_value(&standards)?);
        }
        serde_json::to_string_pretty(&v)? + "\n"
    } else {
        let units = data.units();
        let text = render_text(&an) + &metrolog_analysis::export::render_standards(&standards);
        units
            .note()
            .map_or(String::new(), |n| format!("Note: {n}.\n"))
            + &units.relabel(&text)
    };
    crate::cmd::input::print_out(&text)
}
