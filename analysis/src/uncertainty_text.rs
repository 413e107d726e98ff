//! The text report of `metrolog uncertainty BUDGET.toml`: an uncertainty budget evaluated by
//! the GUM law of propagation (JCGM 100) and/or adaptive Monte Carlo (JCGM 101), with the §8
//! validation.

use std::fmt::Write as _;

use uncertainty::{Budget, Report};

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

/// The text report of an evaluated budget: the GUM table per output with its budget lines,
/// the output correlation, the Monte Carlo result and the §8 validation.
pub fn budget_text(r: &Report, budget: &Budget) -> String {
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
