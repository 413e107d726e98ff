//! Detection of hidden thermal effects on the generator's runs (tests/common): the share of
//! runs of each class whose effects are all named, and of runs naming an effect not there.

mod common;

use common::{CLASSES, class_name, expected_kinds, generate};
use thermal::{DiagnoseOptions, ThermalDataset, diagnose};

struct Row {
    class: String,
    runs: usize,
    detected: usize,
    false_runs: usize,
}

fn sweep(runs: usize, seed0: u64) -> Vec<Row> {
    let opts = DiagnoseOptions::default();
    let mut rows = vec![];
    let only = only_classes();
    for (ci, class) in CLASSES.iter().enumerate() {
        if only.as_ref().is_some_and(|o| !o.contains(&ci)) {
            continue;
        }
        let expect = expected_kinds(class);
        let mut row = Row {
            class: class_name(class),
            runs,
            detected: 0,
            false_runs: 0,
        };
        for r in 0..runs {
            let seed = seed0 + 1000 * ci as u64 + r as u64;
            let run = generate(class, seed, 20.0, 60.0);
            let ds = ThermalDataset::from_csv(&run.csv).expect("generated CSV reads");
            let d = diagnose(&ds, &opts).expect("diagnosis runs");
            let kinds: Vec<&str> = d.channels[0].findings.iter().map(|f| f.kind()).collect();
            if expect.iter().all(|k| kinds.contains(k)) {
                row.detected += 1;
            } else {
                eprintln!("{} seed {seed} missed: {kinds:?}", row.class);
            }
            if kinds.iter().any(|k| !expect.contains(k)) {
                row.false_runs += 1;
                eprintln!("{} seed {seed}: {kinds:?}", row.class);
            }
        }
        rows.push(row);
    }
    rows
}

/// The numbers a calibration aid's variable holds ("runs seed0 ..."), if set.
fn env_numbers(var: &str) -> Option<Vec<u64>> {
    let spec = std::env::var(var).ok()?;
    Some(
        spec.split_whitespace()
            .map(|v| v.parse().unwrap())
            .collect(),
    )
}

/// The class indices THERMAL_CLASSES names, if set (calibration aids only).
fn only_classes() -> Option<Vec<usize>> {
    env_numbers("THERMAL_CLASSES").map(|v| v.into_iter().map(|c| c as usize).collect())
}

fn print_table(rows: &[Row]) {
    eprintln!("| class | runs | all effects named | runs naming an effect not there |");
    eprintln!("|---|---|---|---|");
    for r in rows {
        let det = if r.class == "none" {
            "–".to_string()
        } else {
            format!("{:.1} %", 100.0 * r.detected as f64 / r.runs as f64)
        };
        eprintln!(
            "| {} | {} | {det} | {:.1} % |",
            r.class,
            r.runs,
            100.0 * r.false_runs as f64 / r.runs as f64
        );
    }
}

fn check(rows: &[Row], min_detect: f64, max_false: f64) {
    print_table(rows);
    let total: usize = rows.iter().map(|r| r.runs).sum();
    let false_runs: usize = rows.iter().map(|r| r.false_runs).sum();
    let low: Vec<&str> = rows
        .iter()
        .filter(|r| r.class != "none" && (r.detected as f64) < min_detect * r.runs as f64)
        .map(|r| r.class.as_str())
        .collect();
    assert!(
        low.is_empty(),
        "classes detected in under {:.0} % of runs: {low:?}",
        100.0 * min_detect
    );
    let f = false_runs as f64 / total as f64;
    assert!(
        f <= max_false,
        "runs with false findings {:.1} % > {:.1} %",
        100.0 * f,
        100.0 * max_false
    );
}

#[test]
#[ignore = "passes now (every class named in 6 of 6, no run names an effect not there); the same runs are held to the same counts by fast_sweep_holds_its_current_level, which CI runs"]
fn hidden_effects_are_named_fast() {
    let rows = sweep(6, 1);
    check(&rows, 5.0 / 6.0, 0.05);
}

/// The default (CI) guard, ~80-140 s on a loaded 2-core machine: the same 6 runs per class,
/// held to what the code reaches now (not the targets; docs/methods.md): each class named in
/// at least as many runs as now, and no more runs naming an effect not there than now (none
/// of the 90).
#[test]
fn fast_sweep_holds_its_current_level() {
    // (class, least runs of 6 with every effect named, most runs naming one not there)
    const LEVEL: &[(&str, usize, usize)] = &[
        ("none", 0, 0),
        ("lag", 6, 0),
        ("unseen", 6, 0),
        ("asymmetry", 6, 0),
        ("noisy", 6, 0),
        ("collinear", 6, 0),
        ("lag+unseen", 6, 0),
        ("lag+asymmetry", 6, 0),
        ("lag+noisy", 6, 0),
        ("lag+collinear", 6, 0),
        ("unseen+noisy", 6, 0),
        ("unseen+collinear", 6, 0),
        ("asymmetry+noisy", 6, 0),
        ("asymmetry+collinear", 6, 0),
        ("noisy+collinear", 6, 0),
    ];
    let rows = sweep(6, 1);
    print_table(&rows);
    for r in &rows {
        let Some(&(_, least, most)) = LEVEL.iter().find(|l| l.0 == r.class) else {
            panic!("class {} has no held level", r.class);
        };
        assert!(
            r.class == "none" || r.detected >= least,
            "{}: {} of 6 named, held at {least}",
            r.class,
            r.detected
        );
        assert!(
            r.false_runs <= most,
            "{}: {} of 6 runs name an effect not there, held at {most}",
            r.class,
            r.false_runs
        );
    }
}

#[test]
#[ignore = "100 runs per class (~12 min unloaded): passes (every class named in ≥ 95 %: lag+unseen 96 %, the others 98-100 %; 0.4 % of all runs name an effect not there, over 2 % only in unseen, 3 %); lag+unseen on 200 other seeds 94.5 %; table in docs/methods.md"]
fn hidden_effects_are_named_sweep() {
    let rows = sweep(100, 100_000);
    check(&rows, 0.95, 0.02);
}

/// The sweep on other seeds: THERMAL_SWEEP="runs seed0" (calibrate on seeds apart from the
/// reported 100 000+); THERMAL_CLASSES="7 12" limits it to those class indices.
#[test]
#[ignore = "a calibration aid: THERMAL_SWEEP='40 500000' cargo test ... sweep_on_seeds -- --ignored --nocapture"]
fn sweep_on_seeds() {
    let Some(v) = env_numbers("THERMAL_SWEEP") else {
        return;
    };
    print_table(&sweep(v[0] as usize, v[1]));
}

/// Prints what the ladder saw on one run: THERMAL_RUN="class-index seed".
#[test]
#[ignore = "a debugging aid: THERMAL_RUN='2 2002' cargo test ... show_one_run -- --ignored --nocapture"]
fn show_one_run() {
    let Some(v) = env_numbers("THERMAL_RUN") else {
        return;
    };
    let (ci, seed) = (v[0] as usize, v[1]);
    let run = generate(CLASSES[ci], seed, 20.0, 60.0);
    let ds = ThermalDataset::from_csv(&run.csv).unwrap();
    let d = diagnose(&ds, &DiagnoseOptions::default()).unwrap();
    eprintln!("{}", d.render());
}

/// Calibration dump: every candidate finding with its held-out statistics, thresholds off.
/// THERMAL_DUMP="runs seed0 [1: default thresholds]" (calibrate on seeds apart from the reported 100 000+);
/// THERMAL_CLASSES="7 12" limits it to those class indices; THERMAL_LAG_BESIDE_T="2" sets
/// the least t of a lag beside spindle heat.
#[test]
#[ignore = "a calibration aid: THERMAL_DUMP='20 500000 [1]' cargo test ... dump_candidates -- --ignored --nocapture"]
fn dump_candidates() {
    let Some(v) = env_numbers("THERMAL_DUMP") else {
        return;
    };
    let (runs, seed0) = (v[0], v[1]);
    let mut opts = DiagnoseOptions::default();
    if v.get(2) != Some(&1) {
        opts.finding_rule.min_t = f64::NEG_INFINITY;
        opts.asymmetry_min_t = f64::NEG_INFINITY;
        opts.lag_beside_heat_min_t = f64::NEG_INFINITY;
        opts.min_effect_noise_ratio = 0.0;
        opts.vif_limit = 1.0;
    }
    if let Ok(t) = std::env::var("THERMAL_LAG_BESIDE_T") {
        opts.lag_beside_heat_min_t = t.parse().unwrap();
    }
    let only = only_classes();
    for (ci, class) in CLASSES.iter().enumerate() {
        if only.as_ref().is_some_and(|o| !o.contains(&ci)) {
            continue;
        }
        for r in 0..runs {
            let seed = seed0 + 1000 * ci as u64 + r;
            let run = generate(class, seed, 20.0, 60.0);
            let ds = ThermalDataset::from_csv(&run.csv).unwrap();
            let d = diagnose(&ds, &opts).unwrap();
            let ch = &d.channels[0];
            let line = serde_json::json!({
                "class": class_name(class), "seed": seed, "noise": ch.noise_um,
                "expect": expected_kinds(class), "findings": ch.findings, "ladder": ch.ladder,
            });
            println!("DUMP {line}");
        }
    }
}
