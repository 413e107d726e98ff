//! `metrolog uncertainty BUDGET.toml`: evaluate an uncertainty budget by the GUM law of
//! propagation (JCGM 100) and/or adaptive Monte Carlo (JCGM 101), with the §8 validation.
//! The text report is `metrolog_analysis::uncertainty_text`.

use std::io::IsTerminal as _;
use std::path::PathBuf;

use anyhow::Context as _;
use uncertainty::{Budget, McOptions, McProgress, Method};

use crate::cmd::progress::{mc_progress_bar, update_mc_bar};

/// Which method(s) to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// GUM law of propagation only.
    Gum,
    /// Monte Carlo only.
    Mc,
    /// Both, and the validation of the GUM result by Monte Carlo.
    Both,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Budget file (TOML): inputs with distributions, correlations, the model as expressions.
    pub budget: PathBuf,
    /// Print the result as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    #[arg(long, value_enum, default_value = "both")]
    pub method: MethodArg,
    /// Write the Monte Carlo histogram beside the GUM normal density (.svg or .png).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Random seed (overrides the budget's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// A fixed number of Monte Carlo trials instead of the adaptive procedure, 1 to 20 000 000
    /// (every trial's outputs are kept for the coverage intervals: 10⁷ trials take about
    /// 240 MB per output).
    #[arg(long, value_parser = crate::cmd::input::trials_arg)]
    pub trials: Option<usize>,
    /// Significant digits for the adaptive tolerance (JCGM 101 §7.9.2; overrides the budget's),
    /// 1 to 4.
    #[arg(long, value_parser = crate::cmd::input::ndig_arg)]
    pub ndig: Option<u32>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let text = crate::cmd::input::read_text(&args.budget)
        .with_context(|| format!("reading the budget file {}", args.budget.display()))?;
    let budget = Budget::from_toml(&text)
        .with_context(|| format!("in the budget file {}", args.budget.display()))?;
    let method = match args.method {
        MethodArg::Gum => Method::Gum,
        MethodArg::Mc => Method::Mc,
        MethodArg::Both => Method::Both,
    };
    if args.plot.is_some() && method == Method::Gum {
        anyhow::bail!("--plot shows the Monte Carlo distribution: use --method mc or both");
    }
    let mut opts: McOptions = budget.mc_options();
    if let Some(s) = args.seed {
        opts.seed = s;
    }
    if let Some(t) = args.trials {
        opts.fixed_trials = Some(t);
    }
    if let Some(n) = args.ndig {
        opts.ndig = n;
    }

    let show_bar = !args.json && method != Method::Gum && std::io::stderr().is_terminal();
    let bar = show_bar.then(|| mc_progress_bar(&opts));
    let cb = |p: &McProgress| {
        if let Some(b) = &bar {
            update_mc_bar(b, p);
        }
    };
    let report = budget
        .evaluate(method, &opts, Some(&cb))
        .with_context(|| format!("evaluating {}", args.budget.display()))?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }

    if let (Some(path), Some(mc)) = (&args.plot, &report.monte_carlo) {
        crate::cmd::plots::draw_uncertainty(
            path,
            &report.title,
            &report.units,
            mc,
            report.gum.as_ref(),
        )?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        out!(
            "{}",
            metrolog_analysis::uncertainty_text::budget_text(&report, &budget)
        )?;
    }
    Ok(())
}
