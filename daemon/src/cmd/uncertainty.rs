//! `metrolog uncertainty BUDGET.toml`: evaluate an uncertainty budget by the GUM law of
//! propagation (JCGM 100) and/or adaptive Monte Carlo (JCGM 101), with the §8 validation.

use std::fmt::Write as _;
use std::io::IsTerminal as _;
use std::path::PathBuf;

use anyhow::Context as _;
use indicatif::{ProgressBar, ProgressStyle};
use uncertainty::{Budget, McOptions, McProgress, Method, Report};

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
    /// A fixed number of Monte Carlo trials instead of the adaptive procedure.
    #[arg(long)]
    pub trials: Option<usize>,
    /// Significant digits for the adaptive tolerance (JCGM 101 §7.9.2; overrides the budget's).
    #[arg(long)]
    pub ndig: Option<u32>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(&args.budget)
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
    let bar = show_bar.then(|| progress_bar(&opts));
    let cb = |p: &McProgress| {
        if let Some(b) = &bar {
            update_bar(b, p);
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
        print!("{}", render(&report, &budget));
    }
    Ok(())
}

pub(crate) fn progress_bar(opts: &McOptions) -> ProgressBar {
    match opts.fixed_trials {
        Some(n) => {
            let b = ProgressBar::new(n as u64);
            b.set_style(
                ProgressStyle::with_template("Monte Carlo {bar:40} {pos}/{len} trials ({eta})")
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            b
        }
        None => {
            let b = ProgressBar::new_spinner();
            b.set_style(
                ProgressStyle::with_template("{spinner} adaptive Monte Carlo: {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            b.enable_steady_tick(std::time::Duration::from_millis(120));
            b
        }
    }
}

pub(crate) fn update_bar(b: &ProgressBar, p: &McProgress) {
    if b.length().is_some() {
        b.set_position(p.trials as u64);
    } else {
        let ratio = p
            .worst_ratio
            .map(|r| format!(", worst 2s/δ = {r:.2} (stops at ≤ 1)"))
            .unwrap_or_default();
        b.set_message(format!(
            "sequence {}, {} trials{ratio}",
            p.sequences, p.trials
        ));
    }
}

/// About 6 significant digits, plain notation for ordinary magnitudes.
fn num(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let mag = x.abs().log10().floor() as i32;
    if !(-4..=9).contains(&mag) {
        return format!("{x:.5e}");
    }
    let decimals = (5 - mag).max(0) as usize;
    format!("{x:.decimals$}")
}

fn render(r: &Report, budget: &Budget) -> String {
    let mut s = String::new();
    let unit = |j: usize| {
        r.units
            .get(j)
            .cloned()
            .flatten()
            .map(|u| format!(" {u}"))
            .unwrap_or_default()
    };
    let _ = writeln!(s, "{}", r.title);
    if let Some(g) = &r.gum {
        let _ = writeln!(
            s,
            "\nGUM (JCGM 100), coverage probability {}:",
            g.coverage_probability
        );
        for (j, o) in g.outputs.iter().enumerate() {
            let nu = o.dof_eff.map_or("∞".to_string(), |v| format!("{v:.1}"));
            let _ = writeln!(
                s,
                "  {} = {}{u}   u_c = {}{u}   ν_eff = {nu}   k = {:.3}   U = {}{u}   [{}, {}]",
                o.name,
                num(o.estimate),
                num(o.standard_uncertainty),
                o.coverage_factor,
                num(o.expanded_uncertainty),
                num(o.interval[0]),
                num(o.interval[1]),
                u = unit(j)
            );
            let _ = writeln!(
                s,
                "    {:<16} {:>14} {:>12} {:>8} {:>14} {:>12}",
                "input", "estimate", "u(x)", "ν", "c", "c·u(x)"
            );
            for l in &o.budget {
                let nu = if l.dof.is_finite() {
                    format!("{:.1}", l.dof)
                } else {
                    "∞".into()
                };
                let unit_in = budget
                    .inputs
                    .iter()
                    .find(|i| i.name == l.input)
                    .and_then(|i| i.unit.clone())
                    .unwrap_or_default();
                let _ = writeln!(
                    s,
                    "    {:<16} {:>14} {:>12} {:>8} {:>14} {:>12}  {unit_in}",
                    l.input,
                    num(l.estimate),
                    num(l.standard_uncertainty),
                    nu,
                    num(l.sensitivity),
                    num(l.contribution)
                );
            }
        }
        if g.outputs.len() > 1 {
            let _ = writeln!(s, "  output correlation:");
            for (o, row) in g.outputs.iter().zip(&g.output_correlation) {
                let cells: Vec<String> = row.iter().map(|v| format!("{v:>7.3}")).collect();
                let _ = writeln!(s, "    {:<10} {}", o.name, cells.join(" "));
            }
        }
    }
    if let Some(m) = &r.monte_carlo {
        let _ = writeln!(
            s,
            "\nMonte Carlo (JCGM 101): {} trials in {} sequence(s){}",
            m.trials,
            m.sequences,
            if m.converged {
                ""
            } else {
                " — NOT stabilised: the trial limit was reached first"
            }
        );
        for (j, o) in m.outputs.iter().enumerate() {
            let _ = writeln!(
                s,
                "  {} = {}{u}   u = {}{u}   {:.0} % symmetric [{}, {}]   shortest [{}, {}]   δ = {}",
                o.name,
                num(o.estimate),
                num(o.standard_uncertainty),
                100.0 * m.coverage_probability,
                num(o.symmetric_interval[0]),
                num(o.symmetric_interval[1]),
                num(o.shortest_interval[0]),
                num(o.shortest_interval[1]),
                num(o.tolerance),
                u = unit(j)
            );
        }
    }
    for v in &r.validation {
        let _ = writeln!(
            s,
            "  validation of GUM by MC (JCGM 101 §8) for {}: d_low = {}, d_high = {}, δ = {} → {}",
            v.output,
            num(v.d_low),
            num(v.d_high),
            num(v.tolerance),
            v.message()
        );
    }
    s
}
