//! Results by the standards a customer names, as text and as CSV files (`analyze positioning
//! --standard ... --csv DIR`): readings, per-target statistics and each standard's parameters,
//! so a spreadsheet or a customer's own tool can take them over.

use std::fmt::Write as _;
use std::path::Path;

use positioning::iso230::TargetStats;
use positioning::positioning_data::PositioningData;
use positioning::standards::StandardResult;

/// A number for people: fixed decimals, never "-0.000".
pub fn num(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// A result for people: [`num`] of a finite value; a NaN or an infinity is never printed as a
/// result but as "not determined (why)".
pub fn result_or(v: f64, decimals: usize, why: &str) -> String {
    if v.is_finite() {
        num(v, decimals)
    } else {
        format!("not determined ({why})")
    }
}

/// "x 1.000 y 2.000 z 3.000" of three results, or "not determined (why)" when any is not finite.
pub fn xyz_or(v: [f64; 3], decimals: usize, why: &str) -> String {
    if v.iter().all(|x| x.is_finite()) {
        format!(
            "x {} y {} z {}",
            num(v[0], decimals),
            num(v[1], decimals),
            num(v[2], decimals)
        )
    } else {
        format!("not determined ({why})")
    }
}

fn opt(v: Option<f64>, decimals: usize) -> String {
    v.map(|v| num(v, decimals)).unwrap_or_else(|| "—".into())
}

/// The standards' parameters as text tables.
pub fn render_standards(results: &[StandardResult]) -> String {
    let mut s = String::new();
    for r in results {
        let _ = writeln!(s, "\n{} (bands {}):", r.designation, r.coverage);
        for p in &r.parameters {
            let _ = writeln!(
                s,
                "  {:<7} {:<72} {:>9} µm",
                p.symbol,
                p.name,
                opt(p.value_um, 2)
            );
        }
        for n in &r.notes {
            let _ = writeln!(s, "  note: {n}");
        }
    }
    s
}

fn csv_opt(v: Option<f64>) -> String {
    v.map(|v| format!("{v}")).unwrap_or_default()
}

/// Per-target ISO 230-2 statistics as CSV.
pub fn targets_csv(t: &[TargetStats]) -> String {
    let mut s = String::from(
        "index,target_mm,n_up,n_down,mean_up_um,mean_down_um,s_up_um,s_down_um,b_um,r_up_um,r_down_um,r_um,mean_um\n",
    );
    for x in t {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{}",
            x.index,
            x.target_mm,
            x.n_up,
            x.n_down,
            csv_opt(x.mean_up_um),
            csv_opt(x.mean_down_um),
            csv_opt(x.s_up_um),
            csv_opt(x.s_down_um),
            csv_opt(x.b_um),
            csv_opt(x.r_up_um),
            csv_opt(x.r_down_um),
            csv_opt(x.r_um),
            csv_opt(x.mean_um)
        );
    }
    s
}

fn quote(s: &str) -> String {
    format!("\"{}\"", s.replace('"', "\"\""))
}

/// Every standard's parameters as CSV: `standard,symbol,name,value_um`.
pub fn results_csv(results: &[StandardResult]) -> String {
    let mut s = String::from("standard,symbol,name,value_um\n");
    for r in results {
        for p in &r.parameters {
            let _ = writeln!(
                s,
                "{},{},{},{}",
                quote(&r.designation),
                quote(&p.symbol),
                quote(&p.name),
                csv_opt(p.value_um)
            );
        }
    }
    s
}

/// Writes `readings.csv` (the dataset format), `targets.csv` and `results.csv` into `dir`.
pub fn write_csv_dir(
    dir: &Path,
    data: &PositioningData,
    targets: &[TargetStats],
    results: &[StandardResult],
) -> std::io::Result<Vec<std::path::PathBuf>> {
    std::fs::create_dir_all(dir)?;
    // A rotary run's units (deg, mdeg…) head every file: the column names keep `_mm`/`_um`.
    let u = data.units();
    let head = if u != positioning::units::Units::default() {
        format!(
            "# target_unit: {}\n# deviation_unit: {}\n",
            u.target, u.deviation
        )
    } else {
        String::new()
    };
    let files = [
        ("readings.csv", data.to_csv_string()),
        ("targets.csv", head.clone() + &targets_csv(targets)),
        ("results.csv", head + &results_csv(results)),
    ];
    let mut out = Vec::new();
    for (name, text) in files {
        let p = dir.join(name);
        std::fs::write(&p, text)?;
        out.push(p);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_negative_zero() {
        assert_eq!(num(-0.0001, 2), "0.00");
        assert_eq!(num(-0.01, 2), "-0.01");
        assert_eq!(num(2.71849, 3), "2.718");
    }
}
