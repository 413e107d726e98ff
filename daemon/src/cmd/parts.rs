//! `metrolog parts`: before/after check of measured parts (paper 004): means, standard
//! deviations, Welch t-test of the mean shift, predicted reject rates under a normal fit.

use std::path::PathBuf;

/// Compare a part dimension measured before and after a correction against its tolerance.
///
/// Each file holds one sample: one number per line, or a CSV whose column `value` (or the
/// first column named `*_mm`/`*_um`, else the first column) holds the dimension. `#` lines
/// are comments.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Sample measured before the correction.
    pub before: PathBuf,
    /// Sample measured after the correction.
    pub after: PathBuf,
    /// Tolerance limits `LO,HI`, in the unit of the samples.
    #[arg(long, value_name = "LO,HI", allow_hyphen_values = true)]
    pub tolerance: String,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

fn parse_tolerance(s: &str) -> anyhow::Result<(f64, f64)> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let bad =
        || anyhow::anyhow!("--tolerance `{s}`: expected two numbers `LO,HI`, e.g. `-0.010,0.015`");
    if parts.len() != 2 {
        return Err(bad());
    }
    let lo: f64 = parts[0].parse().map_err(|_| bad())?;
    let hi: f64 = parts[1].parse().map_err(|_| bad())?;
    Ok((lo, hi))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (lo, hi) = parse_tolerance(&args.tolerance)?;
    let read = |p: &PathBuf, which: &str| -> anyhow::Result<Vec<f64>> {
        let text = crate::cmd::input::read_text(p)?;
        Ok(positioning::parts::parse_sample(which, &text)?)
    };
    let before = read(&args.before, "before")?;
    let after = read(&args.after, "after")?;
    let r = positioning::parts::compare(&before, &after, lo, hi)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
        return Ok(());
    }
    outln!("tolerance [{lo}, {hi}]")?;
    outln!(
        "{:<8} {:>5} {:>14} {:>14} {:>18} {:>17}",
        "sample",
        "n",
        "mean",
        "std dev",
        "reject (normal) %",
        "reject (seen) %"
    )?;
    for (name, s) in [("before", &r.before), ("after", &r.after)] {
        outln!(
            "{name:<8} {:>5} {:>14.6} {:>14.6} {:>18.3} {:>17.3}",
            s.n,
            s.mean,
            s.std_dev,
            s.predicted_reject_pct,
            s.observed_reject_pct
        )?;
    }
    outln!(
        "mean shift {:.6}; Welch t = {:.3}, dof = {:.1}, p = {:.3e}: {}",
        r.mean_shift,
        r.t,
        r.dof,
        r.p_value,
        if r.significant {
            "significant at 5 %"
        } else {
            "not significant at 5 %"
        }
    )?;
    match r.variance_ratio {
        Some(f) => outln!(
            "variance ratio after/before {f:.3} (a correction of systematic errors leaves it near 1)"
        ),
        None => {
            outln!("variance ratio after/before: not defined (the before sample has no scatter)")
        }
    }
}
