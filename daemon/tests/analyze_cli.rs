//! `metrolog analyze positioning` and `metrolog diagnose` end to end on dataset files.

mod cli_common;
use cli_common::outcome as metrolog;
use std::path::Path;

use positioning::axis_model::{AxisModel, Effect};
use positioning::positioning_data::{simulate, standard_schedule};

fn write_run(dir: &Path, effects: Vec<Effect>, drop_one: bool) -> String {
    let m = AxisModel {
        axis: "Y".into(),
        targets_mm: (0..11)
            .map(|i| 30.0 * i as f64 + (i % 4) as f64 * 0.7)
            .collect(),
        systematic_up_um: (0..11).map(|i| (i as f64 * 0.8).sin() * 2.0).collect(),
        systematic_down_um: (0..11)
            .map(|i| (i as f64 * 0.8).sin() * 2.0 - 1.2)
            .collect(),
        noise_um: 0.3,
        effects,
    };
    let mut d = simulate(&m, &standard_schedule(11, 12, 12.0), 7);
    if drop_one {
        d.readings.retain(|r| !(r.cycle == 3 && r.index == 5));
    }
    let path = dir.join("run.csv");
    std::fs::write(&path, d.to_csv_string()).unwrap();
    path.to_string_lossy().into_owned()
}

#[test]
fn analyze_json_has_the_contract_keys_and_says_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write_run(dir.path(), vec![], true);
    let (ok, out, err) = metrolog(&["analyze", "positioning", &csv, "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let mut keys: Vec<String> = v["iso230_2"].as_object().unwrap().keys().cloned().collect();
    keys.sort();
    let mut want: Vec<String> = [
        "B", "B_mean", "R_up", "R_down", "R", "E_up", "E_down", "E", "M", "A_up", "A_down", "A",
    ]
    .map(String::from)
    .to_vec();
    want.sort();
    assert_eq!(keys, want);
    assert!(v["iso230_2"]["A"].as_f64().unwrap() > 0.0);
    let t = v["targets"].as_array().unwrap();
    assert_eq!(t.len(), 11);
    assert_eq!(t[4]["n_up"], 11);
    assert_eq!(v["missing"].as_array().unwrap().len(), 2);
    assert!(
        v["drift_elimination"]["directions"]
            .as_array()
            .unwrap()
            .len()
            == 2
    );
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn analyze_text_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write_run(
        dir.path(),
        vec![Effect::LinearDrift { rate_um_per_h: 3.0 }],
        false,
    );
    let svg = dir.path().join("chart.svg");
    let png = dir.path().join("chart.png");
    let (ok, out, err) = metrolog(&[
        "analyze",
        "positioning",
        &csv,
        "--plot",
        svg.to_str().unwrap(),
        "--reference-cycle",
        "6",
    ]);
    assert!(ok, "{err}");
    assert!(
        out.contains("bidirectional accuracy") && out.contains("µm"),
        "{out}"
    );
    assert!(out.contains("anchored on target 1 of cycle 6"), "{out}");
    assert!(out.contains("Student t, 12 cycles"), "{out}");
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
    let (ok, _, err) = metrolog(&[
        "analyze",
        "positioning",
        &csv,
        "--plot",
        png.to_str().unwrap(),
        "--plot-target",
        "3",
    ]);
    assert!(ok, "{err}");
    assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn diagnose_finds_the_hidden_drift_and_writes_a_model_the_simulator_reads() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write_run(
        dir.path(),
        vec![Effect::CyclicDrift {
            period_s: 900.0,
            amplitude_um: 1.0,
            phase_rad: 0.3,
        }],
        false,
    );
    let model = dir.path().join("model.toml");
    let plot = dir.path().join("diag.svg");
    let (ok, out, err) = metrolog(&[
        "diagnose",
        &csv,
        "--json",
        "--write-model",
        model.to_str().unwrap(),
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["kind"], "positioning");
    assert_eq!(v["baseline"]["model"], "static");
    let f = &v["findings"][0];
    assert_eq!(f["effect"], "cyclic_drift");
    assert!((f["params"]["period_s"].as_f64().unwrap() - 900.0).abs() < 30.0);
    assert!(
        f["heldout_rms_after_um"].as_f64().unwrap() < f["heldout_rms_before_um"].as_f64().unwrap()
    );
    assert_eq!(v["extended_model"], model.to_str().unwrap());
    #[derive(serde::Deserialize)]
    struct Scenario {
        axis: AxisModel,
    }
    let m = toml::from_str::<Scenario>(&std::fs::read_to_string(&model).unwrap())
        .unwrap()
        .axis;
    assert!(matches!(m.effects[0], Effect::CyclicDrift { .. }));
    assert!(
        v["reproduction"]["s_rms_um"].as_f64().unwrap()
            < v["reproduction"]["baseline_s_rms_um"].as_f64().unwrap()
    );
    assert!(plot.exists());
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn bad_input_gets_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(
        &bad,
        "cycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n1,+,2,5,oops\n",
    )
    .unwrap();
    let (ok, _, err) = metrolog(&["analyze", "positioning", bad.to_str().unwrap()]);
    assert!(
        !ok && err.contains("line 3") && err.contains("deviation_um"),
        "{err}"
    );
    let (ok, _, err) = metrolog(&["analyze", "positioning", "/nonexistent/run.csv"]);
    assert!(!ok && err.contains("/nonexistent/run.csv"), "{err}");
    let csv = write_run(dir.path(), vec![], false);
    let (ok, _, err) = metrolog(&["analyze", "positioning", &csv, "--reference-cycle", "99"]);
    assert!(!ok && err.contains("--reference-cycle 99"), "{err}");
    let (ok, _, err) = metrolog(&["analyze", "positioning", &csv, "--plot", "x.gif"]);
    assert!(!ok && err.contains(".svg or .png"), "{err}");
    assert!(!err.contains("panicked"));
}

/// The real rotary run declares `target_unit: deg` and `deviation_unit: mdeg`: both reports
/// name those units, never mm or µm.
#[test]
fn a_rotary_run_is_reported_in_its_own_units() {
    let f = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../positioning/tests/data/real/bifrost_vactank_rotary_repeat.csv");
    let f = f.to_str().expect("utf-8 path");
    for args in [vec!["analyze", "positioning", f], vec!["diagnose", f]] {
        let (ok, out, err) = metrolog(&args);
        assert!(ok, "{args:?}: {err}");
        assert!(
            out.contains("mdeg") && out.contains("deg"),
            "{args:?}: {out}"
        );
        assert!(
            !out.contains("µm") && !out.contains(" mm"),
            "{args:?}: {out}"
        );
    }
}

/// A rotary run whose file does not declare its units: `--units deg,mdeg` gives them; a unit
/// the file declares otherwise, one unit only, or markup is refused with what to fix.
#[test]
fn units_given_on_the_command_line() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../positioning/tests/data/real/bifrost_vactank_rotary_repeat.csv");
    let text = std::fs::read_to_string(&src).unwrap();
    let bare: String = text
        .lines()
        .filter(|l| !l.contains("target_unit") && !l.contains("deviation_unit"))
        .map(|l| format!("{l}\n"))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("rotary.csv");
    std::fs::write(&f, bare).unwrap();
    let f = f.to_str().expect("utf-8 path");
    let (ok, out, err) = metrolog(&["diagnose", f]);
    assert!(
        ok && out.contains("µm"),
        "without the option: mm and µm\n{err}"
    );
    for cmd in [&["analyze", "positioning"][..], &["diagnose"][..]] {
        let args: Vec<&str> = cmd
            .iter()
            .copied()
            .chain([f, "--units", "deg,mdeg"])
            .collect();
        let (ok, out, err) = metrolog(&args);
        assert!(ok, "{args:?}: {err}");
        assert!(
            out.contains("mdeg") && !out.contains("µm"),
            "{args:?}: {out}"
        );
    }
    let declared = src.to_str().expect("utf-8 path");
    for (file, units, says) in [
        (
            declared,
            "deg,arcsec",
            "the file declares `deviation_unit: mdeg`",
        ),
        (f, "deg", "give two units"),
        (f, "deg,<b>", "is not a unit name"),
    ] {
        let (ok, _, err) = metrolog(&["diagnose", file, "--units", units]);
        assert!(!ok && err.contains(says), "{units}: {err}");
        assert!(!err.contains("panicked"));
    }
    let (ok, _, err) = metrolog(&["diagnose", declared, "--units", "deg,mdeg"]);
    assert!(ok, "the file's own units again: {err}");
}

/// The same run's signed report (HTML) and charts: the body and the axis titles name deg and
/// mdeg; the style sheet keeps its page margins in mm.
#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn a_rotary_runs_report_and_charts_are_in_its_own_units() {
    let f = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../positioning/tests/data/real/bifrost_vactank_rotary_repeat.csv");
    let f = f.to_str().expect("utf-8 path");
    let dir = tempfile::tempdir().unwrap();
    let html = dir.path().join("r.html");
    let svg = dir.path().join("p.svg");
    let dsvg = dir.path().join("d.svg");
    let p = |x: &Path| x.to_str().expect("utf-8 path").to_string();
    for args in [
        vec!["report", f, "-o", &p(&html)],
        vec!["analyze", "positioning", f, "--plot", &p(&svg)],
        vec!["diagnose", f, "--plot", &p(&dsvg)],
    ] {
        let (ok, _, err) = metrolog(&args);
        assert!(ok, "{args:?}: {err}");
    }
    let page = std::fs::read_to_string(&html).unwrap();
    let (head, body) = page.split_at(page.find("</head>").expect("a head"));
    assert!(head.contains("mm"), "the style sheet is left alone");
    assert!(body.contains("mdeg") && !body.contains("µm"), "{body}");
    for s in [&svg, &dsvg] {
        let t = std::fs::read_to_string(s).unwrap();
        assert!(t.contains("/ mdeg") && !t.contains("µm"), "{}", s.display());
    }
}

/// `--assume`: a contributor the run did not record, given by the operator, enters the budget
/// marked assumed. Checked against ISO/TR 230-9's forms written here: the device term is
/// U_cal·L/k, the cosine error L·(1 − cos θ) rectangular on [0, max] (u = max/√12).
#[test]
fn assumed_contributors_enter_the_budget_marked_as_given() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write_run(dir.path(), vec![], false);
    let (ok, out, err) = metrolog(&[
        "analyze",
        "positioning",
        &csv,
        "--json",
        "--assume",
        "device_um_per_m=1.5,misalignment_mrad=2",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let u = &v["uncertainty"];
    // The targets of write_run: 30·i + (i mod 4)·0.7 mm, i = 0..10.
    let l_m = (300.0 + 2.0 * 0.7) / 1000.0;
    let term = |sym: &str| {
        u["contributors"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["symbol"] == sym)
            .unwrap()
            .clone()
    };
    let dev = term("u_DEVICE");
    assert_eq!(dev["origin"]["origin"], "assumed", "{dev}");
    assert!(dev["origin"]["note"].as_str().unwrap().contains("--assume"));
    let want = 1.5 * l_m / 2.0;
    assert!(
        (dev["u_um"].as_f64().unwrap() - want).abs() < 1e-9,
        "{dev} vs {want}"
    );
    let mis = term("u_MISALIGNMENT");
    let want = l_m * 1e6 * (1.0 - 2e-3f64.cos()) / 12f64.sqrt();
    assert!(
        (mis["u_um"].as_f64().unwrap() - want).abs() < 1e-6 * want,
        "{mis} vs {want}"
    );
    // E: neither is missing any more; U = 2·√Σu² of what acts on it.
    let e = u["results"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["parameter"] == "E")
        .unwrap();
    let missing: Vec<&str> = e["missing"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap())
        .collect();
    assert!(
        !missing.contains(&"u_DEVICE") && !missing.contains(&"u_MISALIGNMENT"),
        "{missing:?}"
    );
    let sum: f64 = e["contributions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c[1].as_f64().unwrap().powi(2))
        .sum();
    assert!((e["expanded_um"].as_f64().unwrap() - 2.0 * sum.sqrt()).abs() < 1e-12);

    // Mistakes say what to fix.
    for (arg, words) in [
        (
            "devise_um_per_m=1",
            "not a contributor; one of: device_um_per_m",
        ),
        ("misalignment_mrad=-1", "must lie in [0, 100]"),
        ("e_ve_um=nan", "must lie in"),
        ("air_ppm", "expected KEY=VALUE"),
    ] {
        let (ok, _, err) = metrolog(&["analyze", "positioning", &csv, "--assume", arg]);
        assert!(!ok && err.contains(words), "{arg}: {err}");
    }
}
