//! The thermal model fitted and diagnosed on every file of a directory, timed: the work of
//! the `thermal_path` fuzz target (whose executions per second issue 27 counts) without the
//! fuzzer's instrumentation, and a digest of every output so a speed-up can be checked to
//! leave the results alone.
//!
//! Run: `cargo bench -p metrolog-thermal --bench corpus`. `THERMAL_BENCH_DIR` names the
//! directory (default: the committed seeds, `protocol/fuzz/corpus/thermal_path`; a fuzzer's
//! scratch corpus gives the mix of inputs it executes); `THERMAL_BENCH_OUT` writes every output
//! to that file for a line-by-line comparison.

use std::hash::{DefaultHasher, Hash, Hasher};
use std::io::Write;
use std::time::Instant;

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("thermal corpus bench: run with `cargo bench -p metrolog-thermal --bench corpus`");
        return;
    }
    let dir = std::env::var("THERMAL_BENCH_DIR").unwrap_or_else(|_| {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../protocol/fuzz/corpus/thermal_path"
        )
        .into()
    });
    let mut files: Vec<_> = match std::fs::read_dir(&dir) {
        Ok(d) => d.filter_map(|e| e.ok().map(|e| e.path())).collect(),
        Err(e) => return eprintln!("cannot read {dir}: {e}"),
    };
    files.sort();
    let mut out = std::env::var("THERMAL_BENCH_OUT")
        .ok()
        .and_then(|p| std::fs::File::create(p).ok());
    let (mut hasher, mut accepted, mut slowest) = (DefaultHasher::new(), 0, (0.0, String::new()));
    let start = Instant::now();
    for f in &files {
        let Ok(text) = std::fs::read_to_string(f) else {
            continue;
        };
        let t0 = Instant::now();
        let texts = outputs(&text);
        let s = t0.elapsed().as_secs_f64();
        if s > slowest.0 {
            slowest = (s, f.display().to_string());
        }
        accepted += usize::from(!texts.is_empty());
        for t in &texts {
            t.hash(&mut hasher);
            if let Some(o) = out.as_mut() {
                let _ = writeln!(o, "== {}\n{t}", f.display());
            }
        }
    }
    let total = start.elapsed().as_secs_f64();
    println!(
        "{} files ({accepted} read as thermal data) in {total:.2} s: {:.2} ms per file, {:.0} files/s; slowest {:.1} ms ({}); output digest {:016x}",
        files.len(),
        1e3 * total / files.len().max(1) as f64,
        files.len() as f64 / total,
        1e3 * slowest.0,
        slowest.1,
        hasher.finish(),
    );
}

/// What the fuzz target computes: the model's description and the diagnosis' text.
fn outputs(text: &str) -> Vec<String> {
    let Ok(ds) = thermal::ThermalDataset::from_csv(text) else {
        return vec![];
    };
    if ds.channel_names.is_empty() {
        return vec![];
    }
    let mut out = vec![];
    if let Ok(m) = thermal::fit(&ds, &thermal::FitOptions::default()) {
        out.push(m.describe());
    }
    if let Ok(d) = thermal::diagnose(&ds, &thermal::DiagnoseOptions::default()) {
        out.push(d.render());
    }
    out
}
