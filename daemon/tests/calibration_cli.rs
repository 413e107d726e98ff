//! The laser calibration of an axis from the command line: `plan` → (run) → `analyze
//! --standard` / `report` → `compensate`, on the published measured run
//! (`positioning/tests/data/psi_ecmc_iso230.csv`). The report is rendered by headless Chromium
//! when it is installed (`.ci/run` installs it as root) and its DOM checked for the key numbers;
//! the screenshot stays in the target directory as an artifact.

use std::path::{Path, PathBuf};
use std::process::Command;

use positioning::positioning_data::PositioningData;
use positioning::standards::{Standard, evaluate};

const RUN: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../positioning/tests/data/psi_ecmc_iso230.csv"
);

mod cli_common;
use cli_common::metrolog;

#[test]
fn plan_writes_a_trajectory_the_daemon_reads_and_a_program() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    for dialect in ["sinumerik", "fanuc", "heidenhain", "linuxcnc"] {
        metrolog(&[
            "plan",
            "positioning",
            "--axis",
            "X",
            "--from",
            "0",
            "--to",
            "500",
            "--targets",
            "11",
            "--cycles",
            "5",
            "--seed",
            "3",
            "--dialect",
            dialect,
            "-o",
            d,
        ]);
    }
    let traj = std::fs::read_to_string(dir.path().join("trajectory.csv")).unwrap();
    let rows = metrolog_log::trajectory::parse_trajectory(&traj).unwrap();
    assert_eq!(rows.len(), 1 + 5 * 24);
    for ext in ["MPF", "NC", "H", "ngc"] {
        let p = dir.path().join(format!("iso230_X.{ext}"));
        assert!(
            std::fs::read_to_string(&p).unwrap().lines().count() > 500,
            "{}",
            p.display()
        );
    }
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["plan", "positioning", "--from", "10", "--to", "0", "-o", d])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--to must be greater"));
}

#[test]
fn analyze_by_several_standards_with_csv_export() {
    let dir = tempfile::tempdir().unwrap();
    let text = metrolog(&[
        "analyze",
        "positioning",
        RUN,
        "--standard",
        "vdi3441,jis-b6192",
        "--csv",
        dir.path().to_str().unwrap(),
    ]);
    assert!(
        text.contains("VDI/DGQ 3441:1977") && text.contains("JIS B 6192:1999"),
        "{text}"
    );
    let res = std::fs::read_to_string(dir.path().join("results.csv")).unwrap();
    assert_eq!(res.lines().count(), 1 + 6 + 12);
    let readings = std::fs::read_to_string(dir.path().join("readings.csv")).unwrap();
    assert_eq!(
        PositioningData::from_csv_str(&readings)
            .unwrap()
            .readings
            .len(),
        50
    );
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["analyze", "positioning", RUN, "--standard", "din-1"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown standard"));
}

#[test]
fn compensate_writes_the_table_and_predicts_the_result() {
    let dir = tempfile::tempdir().unwrap();
    let text = metrolog(&[
        "compensate",
        "positioning",
        RUN,
        "--dialect",
        "linuxcnc",
        "--bidirectional",
        "-o",
        dir.path().to_str().unwrap(),
    ]);
    assert!(text.contains("predicted after compensation"), "{text}");
    let comp = std::fs::read_to_string(dir.path().join("m1_comp.txt")).unwrap();
    assert!(comp.lines().count() >= 5);
    let json = metrolog(&[
        "compensate",
        "positioning",
        RUN,
        "--dialect",
        "sinumerik",
        "--backlash",
        "--json",
        "-o",
        dir.path().to_str().unwrap(),
    ]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let (before, after) = (
        v["iso230_2_before"]["E"].as_f64().unwrap(),
        v["iso230_2_predicted_after"]["E"].as_f64().unwrap(),
    );
    assert!(after < before, "E {before} → {after}");
}

fn chromium() -> Option<PathBuf> {
    ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .find_map(|c| {
            let ok = Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success());
            ok.then(|| PathBuf::from(c))
        })
}

fn headless(bin: &Path, profile: &Path, extra: &[String], html: &Path) -> std::process::Output {
    Command::new(bin)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(format!("file://{}", html.display()))
        .output()
        .unwrap()
}

#[test]
fn report_renders_in_chromium_with_the_key_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let html = dir.path().join("report.html");
    metrolog(&[
        "report",
        RUN,
        "-o",
        html.to_str().unwrap(),
        "--standard",
        "iso230-2:2014,vdi3441",
        "--operator",
        "A. Tester",
        "--instrument",
        "LI-80 s/n 0042",
        "--tolerance",
        "E=0.01,R=5",
    ]);
    let text = std::fs::read_to_string(&html).unwrap();
    // Self-contained: no scripts, no external resources.
    for external in ["<script", "<link", "src=", "url("] {
        assert!(!text.contains(external), "{external} in the report");
    }
    assert!(!text.contains("-0.00"), "negative zero printed");
    let d = PositioningData::from_csv_path(Path::new(RUN)).unwrap();
    let iso = evaluate(&d, Standard::Iso230_2_2014);
    let vdi = evaluate(&d, Standard::Vdi3441);
    let want = [
        format!("{:.2}", iso.value("A").unwrap()),
        format!("{:.2}", vdi.value("P").unwrap()),
    ];
    for w in &want {
        assert!(text.contains(w), "{w} not in the report");
    }
    let Some(bin) = chromium() else {
        eprintln!("SKIPPED: chromium not installed (apt-get install chromium)");
        return;
    };
    let profile = tempfile::tempdir().unwrap();
    let dom = headless(&bin, profile.path(), &["--dump-dom".into()], &html);
    assert!(
        dom.status.success(),
        "{}",
        String::from_utf8_lossy(&dom.stderr)
    );
    let dom = String::from_utf8_lossy(&dom.stdout);
    assert!(
        dom.contains("A. Tester") && dom.contains("LI-80 s/n 0042"),
        "header"
    );
    for w in &want {
        assert!(dom.contains(w.as_str()), "{w} not in the rendered DOM");
    }
    assert!(dom.matches("<svg").count() >= 2, "both charts rendered");
    // The budget of the results: a run without a `sensor` names its missing terms, U is a
    // lower bound; no interferometer figures; the decisions under the tolerances.
    for w in [
        "u_DEVICE",
        "MISSING",
        "U is a lower bound",
        "Report ID",
        "Statistics per target",
        "ISO 14253-1",
        "data-decision=\"E\"><b>FAIL</b>",
        "data-decision=\"R\"><b>PASS</b>",
    ] {
        assert!(dom.contains(w), "{w} not in the rendered DOM");
    }
    assert!(!dom.contains("interferometer reading") && !dom.contains("normalised to 20 °C from"));
    let shot = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report_chromium.png");
    let _ = std::fs::remove_file(&shot);
    let profile2 = tempfile::tempdir().unwrap();
    let out = headless(
        &bin,
        profile2.path(),
        &[
            format!("--screenshot={}", shot.display()),
            "--window-size=1100,2400".into(),
        ],
        &html,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let png = std::fs::read(&shot).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 20_000,
        "screenshot {} bytes",
        png.len()
    );
    eprintln!("screenshot kept: {}", shot.display());
}

/// A tool the test needs: in CI (`CI` set, where `.ci/run` installs it) its absence fails the
/// test; elsewhere the test is skipped with a message.
fn have(found: bool, what: &str) -> bool {
    if !found {
        assert!(
            std::env::var_os("CI").is_none(),
            "{what} is missing in CI (.ci/run installs it)"
        );
        eprintln!("SKIPPED: {what} not installed");
    }
    found
}

#[test]
fn report_prints_to_pdf_with_the_key_numbers() {
    let pdftotext = Command::new("pdftotext")
        .arg("-v")
        .output()
        .is_ok_and(|o| o.status.success());
    if !have(chromium().is_some(), "chromium (apt-get install chromium)")
        || !have(pdftotext, "pdftotext (apt-get install poppler-utils)")
    {
        return;
    }
    let pdf = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report.pdf");
    let _ = std::fs::remove_file(&pdf);
    let out = metrolog(&[
        "report",
        RUN,
        "-o",
        pdf.to_str().unwrap(),
        "--operator",
        "A. Tester",
    ]);
    assert!(out.contains("printed by"), "{out}");
    let bytes = std::fs::read(&pdf).unwrap();
    assert!(bytes.starts_with(b"%PDF-"), "not a PDF");
    // poppler's reader, not ours, takes the text back out of the PDF.
    let text = Command::new("pdftotext")
        .args([pdf.to_str().unwrap(), "-"])
        .output()
        .unwrap();
    assert!(text.status.success());
    let text = String::from_utf8_lossy(&text.stdout);
    let d = PositioningData::from_csv_path(Path::new(RUN)).unwrap();
    let iso = evaluate(&d, Standard::Iso230_2_2014);
    for s in ["A", "E", "R"] {
        let want = format!("{:.2}", iso.value(s).unwrap());
        assert!(text.contains(&want), "{s} = {want} not in the PDF text");
    }
    assert!(text.contains("A. Tester") && text.contains("Positioning accuracy"));
    eprintln!("PDF kept: {}", pdf.display());
    // Both at once: the HTML and, with --pdf, its print.
    let dir = tempfile::tempdir().unwrap();
    let (html, pdf2) = (dir.path().join("r.html"), dir.path().join("r.pdf"));
    metrolog(&[
        "report",
        RUN,
        "-o",
        html.to_str().unwrap(),
        "--pdf",
        pdf2.to_str().unwrap(),
    ]);
    assert!(
        std::fs::read_to_string(&html)
            .unwrap()
            .starts_with("<!DOCTYPE html>")
    );
    assert!(std::fs::read(&pdf2).unwrap().starts_with(b"%PDF-"));
}

#[test]
fn report_pdf_without_a_browser_says_what_to_install() {
    let dir = tempfile::tempdir().unwrap();
    let pdf = dir.path().join("report.pdf");
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["report", RUN, "-o", pdf.to_str().unwrap()])
        .env("PATH", dir.path())
        .env_remove("METROLOG_BROWSER")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "no browser, yet it succeeded");
    assert!(err.contains("apt-get install chromium"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!pdf.exists(), "nothing written");
}

/// `compensate verify`: the run a table came from against a re-measurement, both measured.
/// The re-measurement here is the published run with each target's mean deviation per
/// direction taken out (what an exact bidirectional table would leave): E after is computed
/// independently from that CSV, and must be what the command prints.
#[test]
fn compensate_verify_compares_two_measured_runs() {
    let dir = tempfile::tempdir().unwrap();
    let before = PositioningData::from_csv_path(Path::new(RUN)).unwrap();
    let mut after = before.clone();
    let mean = |t: f64, d| {
        let v: Vec<f64> = before
            .readings
            .iter()
            .filter(|r| r.target_mm == t && r.direction == d)
            .map(|r| r.deviation_um)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    for r in &mut after.readings {
        r.deviation_um -= mean(r.target_mm, r.direction);
    }
    let after_csv = dir.path().join("after.csv");
    std::fs::write(&after_csv, after.to_csv_string()).unwrap();
    let e = |d: &PositioningData| positioning::iso230::evaluate(d).axis.e.unwrap();
    let (eb, ea) = (e(&before), e(&after));
    assert!(ea < 0.05 * eb, "{eb} → {ea}");

    let text = metrolog(&["compensate", "verify", RUN, after_csv.to_str().unwrap()]);
    assert!(text.contains("measured before   measured after"), "{text}");
    let row = text
        .lines()
        .find(|l| l.trim_start().starts_with("E "))
        .unwrap();
    let nums: Vec<f64> = row
        .split_whitespace()
        .skip(1)
        .map(|x| x.parse().unwrap())
        .collect();
    assert!(
        (nums[0] - eb).abs() < 0.006 && (nums[1] - ea).abs() < 0.006,
        "{row} vs {eb} {ea}"
    );
    let json = metrolog(&[
        "compensate",
        "verify",
        RUN,
        after_csv.to_str().unwrap(),
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert!((v["after"]["E"].as_f64().unwrap() - ea).abs() < 1e-9);
    assert_eq!(
        v["targets"].as_array().unwrap().len(),
        before.n_targets(),
        "every target measured again"
    );
}

/// `metrolog sim --apply-comp` loads the file as LinuxCNC does and refuses, with the reason,
/// a file LinuxCNC would load as an empty table (a comment line at the top).
#[test]
fn sim_refuses_a_comp_file_linuxcnc_would_load_empty() {
    let dir = tempfile::tempdir().unwrap();
    let comp = dir.path().join("x_comp.txt");
    std::fs::write(&comp, "# X axis\n0 0 0\n100 -0.001 -0.002\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["sim", "--dir"])
        .arg(dir.path().join("sim"))
        .arg("--apply-comp")
        .arg(&comp)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("stops at the first line that is not three numbers"),
        "{err}"
    );
}
