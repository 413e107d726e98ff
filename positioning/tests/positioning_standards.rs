//! Positioning standards (`docs/methods.md` "Positioning standards") against independent
//! expectations: a small run worked by hand for each family, the ISO 230-2 evaluation of a
//! published measured run, and a second implementation in Python (standard library only,
//! `tests/data/standards_reference.py`) on simulated runs.

use positioning::axis_model::{AxisModel, Effect};
use positioning::positioning_data::{PositioningData, simulate, standard_schedule};
use positioning::standards::{STANDARD_NAMES, Standard, StandardResult, evaluate};

const HAND: &str = "cycle,direction,index,target_mm,deviation_um
1,+,1,0,1
1,+,2,10,4
1,-,2,10,5
1,-,1,0,0
2,+,1,0,2
2,+,2,10,4
2,-,2,10,7
2,-,1,0,0
3,+,1,0,3
3,+,2,10,4
3,-,2,10,6
3,-,1,0,3
";

fn close(r: &StandardResult, sym: &str, want: f64) {
    let v = r
        .value(sym)
        .unwrap_or_else(|| panic!("{}: {sym} not computed", r.designation));
    assert!(
        (v - want).abs() < 1e-9,
        "{} {sym}: {v} != {want}",
        r.designation
    );
}

#[test]
fn vdi3441_worked_by_hand() {
    // Target 1: x̄↑=2 s↑=1, x̄↓=1 s↓=√3 → x̄=1.5, U=1, Ps=6(1+√3)/2.
    // Target 2: x̄↑=4 s↑=0, x̄↓=6 s↓=1 → x̄=5, U=2, Ps=3.
    // P = max(1.5+(1+Ps1)/2, 5+2.5) − min(1.5−(1+Ps1)/2, 2.5) = 7.5 + 0.5 + 1.5√3.
    let d = PositioningData::from_csv_str(HAND).unwrap();
    let r = evaluate(&d, Standard::Vdi3441);
    let s3 = 3f64.sqrt();
    close(&r, "Pa", 3.5);
    close(&r, "Ps max", 3.0 + 3.0 * s3);
    close(&r, "P̄s", 3.0 + 1.5 * s3);
    close(&r, "U max", 2.0);
    close(&r, "Ū", 1.5);
    close(&r, "P", 8.0 + 1.5 * s3);
}

#[test]
fn iso230_2_1988_worked_by_hand() {
    // ±3 s: R_1 = max(3 + 3√3 + 1, 6, 6√3) = 6√3, R_2 = max(0 + 3 + 2, 0, 6) = 6;
    // A: highest band 6 + 3 = 9 (target 2 ↓), lowest 1 − 3√3 (target 1 ↓).
    let d = PositioningData::from_csv_str(HAND).unwrap();
    let r = evaluate(&d, Standard::Iso230_2_1988);
    let s3 = 3f64.sqrt();
    close(&r, "R", 6.0 * s3);
    close(&r, "R↑", 6.0);
    close(&r, "A", 8.0 + 3.0 * s3);
    close(&r, "B", 2.0);
    close(&r, "M", 3.5);
    // The 2014 edition on the same readings (±2 s), as worked in positioning_iso230.rs.
    let r14 = evaluate(&d, Standard::Iso230_2_2014);
    close(&r14, "R", 4.0 * s3);
    close(&r14, "A", 7.0 + 2.0 * s3);
}

#[test]
fn published_run_by_iso_2014_and_its_adoptions() {
    // PSI ecmccfg test report (fixture header): A = 8.881e-5 mm, B = 1.22e-5 mm,
    // M = 2.77e-5 mm, A↑ = 6.428e-5 mm; the adoptions (JIS, GB/T) give the same numbers.
    let d = PositioningData::from_csv_path(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/psi_ecmc_iso230.csv"
    )))
    .unwrap();
    for st in [
        Standard::Iso230_2_2014,
        Standard::Iso230_2_1997,
        Standard::JisB6192,
        Standard::Gb17421_2_2000,
        Standard::Gb17421_2_2016,
    ] {
        let r = evaluate(&d, st);
        for (sym, mm) in [
            ("A", 8.881e-5),
            ("B", 1.22e-5),
            ("M", 2.77e-5),
            ("A↑", 6.428e-5),
        ] {
            let v = r.value(sym).unwrap() / 1000.0;
            assert!((v - mm).abs() <= 1e-3 * mm, "{st:?} {sym}: {v} vs {mm}");
        }
    }
}

#[test]
fn names_parse_and_unknown_names_say_what_is_known() {
    for (n, st) in STANDARD_NAMES {
        assert_eq!(n.parse::<Standard>().unwrap(), *st);
    }
    assert_eq!(
        "ISO230-2:1997".parse::<Standard>().unwrap(),
        Standard::Iso230_2_1997
    );
    let e = "din-1234".parse::<Standard>().unwrap_err();
    assert!(e.contains("vdi3441") && e.contains("din-1234"), "{e}");
}

#[test]
fn single_pass_gives_no_scatter_parameters_and_says_so() {
    let one: String = HAND.lines().take(5).collect::<Vec<_>>().join("\n");
    let d = PositioningData::from_csv_str(&one).unwrap();
    let r = evaluate(&d, Standard::Vdi3441);
    assert!(r.value("P").is_none() && r.value("Ps max").is_none());
    assert!(r.value("Pa").is_some());
    assert!(
        r.notes
            .iter()
            .any(|n| n.contains("fewer than two readings"))
    );
}

fn python_available() -> bool {
    std::process::Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

#[test]
fn every_standard_agrees_with_an_independent_python_implementation() {
    if !python_available() {
        eprintln!("SKIPPED: python3 is not available");
        return;
    }
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/standards_reference.py"
    );
    let mut compared = 0;
    for seed in 0..5u64 {
        let m = 5 + seed as usize;
        let model = AxisModel {
            axis: "X".into(),
            targets_mm: (0..m).map(|i| i as f64 * 41.7 + 0.3 * i as f64).collect(),
            systematic_up_um: (0..m).map(|i| (i as f64 * 0.9).sin() * 4.0).collect(),
            systematic_down_um: (0..m).map(|i| (i as f64 * 0.9).cos() * 3.0 - 2.5).collect(),
            noise_um: 0.4 + 0.2 * seed as f64,
            effects: vec![Effect::LinearDrift { rate_um_per_h: 1.5 }],
        };
        let d = simulate(&model, &standard_schedule(m, 5, 8.0), seed);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.csv");
        std::fs::write(&path, d.to_csv_string()).unwrap();
        let back = PositioningData::from_csv_path(&path).unwrap();
        let out = std::process::Command::new("python3")
            .arg(script)
            .arg(&path)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let py: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        for (_, st) in STANDARD_NAMES {
            let r = evaluate(&back, *st);
            let want = py[&r.designation]
                .as_object()
                .unwrap_or_else(|| panic!("python has no {}", r.designation));
            assert_eq!(want.len(), r.parameters.len(), "{}", r.designation);
            for (sym, v) in want {
                let a = r.value(sym).unwrap_or(f64::NAN);
                let b = v.as_f64().unwrap();
                assert!(
                    (a - b).abs() < 1e-9 * (1.0 + b.abs()),
                    "seed {seed} {} {sym}: rust {a} python {b}",
                    r.designation
                );
                compared += 1;
            }
        }
    }
    assert!(compared > 300, "{compared}");
}
