//! Evaluates a budget file by GUM and Monte Carlo with validation, as `metrolog uncertainty
//! FILE --method both` does, and prints the intervals and the wall-clock time: the figures of
//! docs/methods.md without building the binary.
//!
//!     cargo run --release -p metrolog-uncertainty --example budget -- FILE [SEED] [mc]
//!
//! `mc` runs the Monte Carlo alone (the adaptive procedure of JCGM 101 §7.9, no validation).

use uncertainty::budget::{Budget, Method};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = args.next().ok_or("usage: budget FILE [SEED] [mc]")?;
    let text = std::fs::read_to_string(&path)?;
    let b = Budget::from_toml(&text)?;
    let mut opts = b.mc_options();
    if let Some(s) = args.next() {
        opts.seed = s.parse()?;
    }
    let method = match args.next().as_deref() {
        Some("mc") => Method::Mc,
        _ => Method::Both,
    };
    let t0 = std::time::Instant::now();
    let mut r = b.evaluate(method, &opts, None)?;
    if r.gum.is_none() {
        r.gum = Some(b.gum()?);
    }
    let dt = t0.elapsed().as_secs_f64();
    println!("{}", r.title);
    if let (Some(g), Some(m)) = (&r.gum, &r.monte_carlo) {
        println!(
            "MC: {} trials, {} sequences, stabilised: {}, {dt:.2} s",
            m.trials, m.sequences, m.converged
        );
        for (go, mo) in g.outputs.iter().zip(&m.outputs) {
            println!(
                "  {}: GUM {:.6} u {:.6} [{:.6}, {:.6}]   MC {:.6} u {:.6} [{:.6}, {:.6}]",
                go.name,
                go.estimate,
                go.standard_uncertainty,
                go.interval[0],
                go.interval[1],
                mo.estimate,
                mo.standard_uncertainty,
                mo.symmetric_interval[0],
                mo.symmetric_interval[1]
            );
        }
    }
    for v in &r.validation {
        println!(
            "  {}: d_low {:.3e} d_high {:.3e} δ {:.1e}: {}",
            v.output,
            v.d_low,
            v.d_high,
            v.tolerance,
            v.message()
        );
    }
    Ok(())
}
