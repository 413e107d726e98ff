//! `metrolog uncertainty` end to end: budget file in, JSON / text / plot out, clear errors.

use std::process::Command;

fn metrolog() -> Command {
    Command::new(env!("CARGO_BIN_EXE_metrolog"))
}

fn budget(name: &str) -> String {
    format!("{}/../examples/budgets/{name}", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn json_output_carries_gum_mc_and_validation() {
    let out = metrolog()
        .args(["uncertainty", &budget("jcgm101_9_3_mass.toml"), "--json"])
        .args(["--trials", "200000", "--seed", "3"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // JCGM 101 Table 9: GUM u = 0.0539 mg; Monte Carlo u = 0.0754 mg.
    let gu = v["gum"]["outputs"][0]["standard_uncertainty"]
        .as_f64()
        .unwrap();
    assert!((gu - 0.0539).abs() < 5e-5);
    let mu = v["monte_carlo"]["outputs"][0]["standard_uncertainty"]
        .as_f64()
        .unwrap();
    assert!((mu - 0.0754).abs() < 5e-4);
    assert_eq!(v["monte_carlo"]["trials"].as_u64(), Some(200_000));
    assert_eq!(v["validation"][0]["passed"].as_bool(), Some(false));
}

#[test]
fn gum_only_text_shows_the_budget_table() {
    let out = metrolog()
        .args([
            "uncertainty",
            &budget("jcgm100_h1_end_gauge.toml"),
            "--method",
            "gum",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    // JCGM 100 H.1: u_c = 32 nm, ν_eff = 16.7 → k = 2.92.
    assert!(text.contains("u_c = 31.66"), "{text}");
    assert!(text.contains("k = 2.921"), "{text}");
    assert!(text.contains("delta_theta"), "{text}");
    assert!(!text.contains("Monte Carlo"));
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn plot_is_written_as_svg() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("h2.svg");
    let out = metrolog()
        .args(["uncertainty", &budget("jcgm100_h2_impedance.toml")])
        .args(["--trials", "20000", "--plot"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let svg = std::fs::read_to_string(&path).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("GUM normal"));
}

#[test]
fn bad_budgets_get_errors_that_say_what_to_fix() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "title = \"x\"\n[[input]]\nname = \"a\"\ndistribution = \"normal\"\nmean = 1\nu = 1\n[[output]]\nname = \"y\"\nexpr = \"a + b\"\n",
            "unknown name `b`",
        ),
        (
            "title = \"x\"\n[[input]]\nname = \"a\"\ndistribution = \"rectangular\"\nmean = 1\nhalf_width = -1\n[[output]]\nname = \"y\"\nexpr = \"a\"\n",
            "half_width",
        ),
        (
            "title = \"x\"\n[[input]]\nname = \"a\"\ndistribution = \"normal\"\nmean = 0\nu = 1\n[[output]]\nname = \"y\"\nexpr = \"sqrt(a)\"\n",
            "not a finite number",
        ),
        ("title = \"x\"\n", "no [[output]]"),
    ];
    for (i, (text, needle)) in cases.iter().enumerate() {
        let p = dir.path().join(format!("b{i}.toml"));
        std::fs::write(&p, text).unwrap();
        let out = metrolog()
            .args(["uncertainty"])
            .arg(&p)
            .args(["--method", "mc", "--trials", "1000"])
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "case {i}: {err}");
        assert!(!err.contains("panicked"), "case {i}: {err}");
    }
    let out = metrolog()
        .args(["uncertainty", "/nonexistent/budget.toml"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("reading the budget file"));
}

fn psd_mc(extra: &[&str]) -> std::process::Output {
    let data = format!(
        "{}/../examples/models/psd_readings.csv",
        env!("CARGO_MANIFEST_DIR")
    );
    metrolog()
        .args(["identify", "psd", &data, "--reference", "1"])
        .args(["--uncertainty", "mc", "--trials", "2000", "--seed", "4"])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn identify_psd_monte_carlo_uses_the_reading_budget() {
    let b = budget("psd_frame_readings.toml");
    let out = psd_mc(&["--budget", &b, "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["study"]["monte_carlo"]["trials"].as_u64(), Some(2000));
    let names = v["names"].as_array().unwrap();
    assert_eq!(
        names.len(),
        v["expanded_uncertainty"].as_array().unwrap().len()
    );
    // Per-point U of a table-plane straightness: about 1.5 µm with the budget (paper 003
    // Table 4: 1.3–1.6), against 3.0 µm with one σ for every reading.
    let k = names.iter().position(|n| n == "EYX_um[6]").unwrap();
    let u = v["expanded_uncertainty"][k].as_f64().unwrap();
    assert!((1.2..2.0).contains(&u), "EYX[6] U {u}");
    let rows = v["study"]["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 13);
    assert_eq!(rows[4]["error"], "EZY");
    assert_eq!(rows[4]["published_um"].as_f64(), Some(3.9));
    assert_eq!(v["runs"][0]["run"].as_u64(), Some(0));
    // Text form: our Table 4 beside the paper's and U beside every derived value.
    let text = String::from_utf8(psd_mc(&["--budget", &b]).stdout).unwrap();
    assert!(
        text.contains("paper 003") && text.contains("EC0Y"),
        "{text}"
    );
    assert!(text.contains("run 0 − run 1"), "{text}");
}

#[test]
fn identify_psd_monte_carlo_errors_say_what_to_fix() {
    let out = psd_mc(&[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("needs --budget FILE"), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("b.toml");
    let text = include_str!("../../examples/budgets/psd_frame_readings.toml")
        .replace("segment = 4\n", "segment = 3\n");
    std::fs::write(&bad, text).unwrap();
    let out = psd_mc(&["--budget", bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("segment 3 must be given exactly once"),
        "{err}"
    );
}
