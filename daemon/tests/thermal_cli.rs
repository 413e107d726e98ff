//! `metrolog thermal fit | predict | diagnose` and `metrolog analyze thermal` end to end.
//!
//! The real-data tests read `../shared/real/thermal/fl_thermal_train.csv` (relative to the
//! repository root; the FL_THERMAL spindle test); without it they say so and pass, except in CI
//! (`CI=true`), where they fail.

use std::path::{Path, PathBuf};
use std::process::Command;

struct Out {
    code: Option<i32>,
    stdout: String,
    stderr: String,
}

fn metrolog(args: &[&str]) -> Out {
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(args)
        .output()
        .unwrap();
    Out {
        code: out.status.code(),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

fn ok(args: &[&str]) -> String {
    let o = metrolog(args);
    assert_eq!(o.code, Some(0), "metrolog {args:?}: {}", o.stderr);
    o.stdout
}

fn real_file() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/real/thermal/fl_thermal_train.csv");
    if p.exists() {
        return Some(p);
    }
    assert!(
        std::env::var("CI").map_or(true, |v| v != "true"),
        "{} is missing in CI",
        p.display()
    );
    eprintln!("{} is absent: real-data test skipped", p.display());
    None
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A CSV table: header names and numeric rows (comments dropped).
struct Table {
    names: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl Table {
    fn read(text: &str) -> Table {
        let mut lines = text
            .lines()
            .filter(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty());
        let names = lines
            .next()
            .unwrap()
            .split(',')
            .map(|n| n.trim().to_string())
            .collect();
        let rows = lines
            .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
            .collect();
        Table { names, rows }
    }

    fn col(&self, name: &str) -> Vec<f64> {
        let j = self
            .names
            .iter()
            .position(|n| n == name)
            .unwrap_or_else(|| panic!("no column {name} in {:?}", self.names));
        self.rows.iter().map(|r| r[j]).collect()
    }

    /// The rows `range` with only the columns `keep` says yes to, as CSV.
    fn csv(&self, range: std::ops::Range<usize>, keep: impl Fn(&str) -> bool) -> String {
        let cols: Vec<usize> = (0..self.names.len())
            .filter(|&j| keep(&self.names[j]))
            .collect();
        let mut out = cols
            .iter()
            .map(|&j| self.names[j].as_str())
            .collect::<Vec<_>>()
            .join(",")
            + "\n";
        for r in &self.rows[range] {
            let line: Vec<String> = cols.iter().map(|&j| r[j].to_string()).collect();
            out += &line.join(",");
            out.push('\n');
        }
        out
    }
}

/// Least squares by Householder QR: the coefficients minimising |A x − y| (A: rows × cols).
#[allow(clippy::needless_range_loop)] // matrix indices read as the algebra
fn least_squares(mut a: Vec<Vec<f64>>, mut y: Vec<f64>) -> Vec<f64> {
    let (m, n) = (a.len(), a[0].len());
    for k in 0..n {
        let norm = (k..m).map(|i| a[i][k] * a[i][k]).sum::<f64>().sqrt();
        let alpha = if a[k][k] > 0.0 { -norm } else { norm };
        let mut v: Vec<f64> = (k..m).map(|i| a[i][k]).collect();
        v[0] -= alpha;
        let vv: f64 = v.iter().map(|x| x * x).sum();
        if vv == 0.0 {
            continue;
        }
        for j in k..n {
            let d: f64 = (k..m).map(|i| v[i - k] * a[i][j]).sum::<f64>() * 2.0 / vv;
            for i in k..m {
                a[i][j] -= d * v[i - k];
            }
        }
        let d: f64 = (k..m).map(|i| v[i - k] * y[i]).sum::<f64>() * 2.0 / vv;
        for i in k..m {
            y[i] -= d * v[i - k];
        }
    }
    let mut x = vec![0.0; n];
    for k in (0..n).rev() {
        let s: f64 = (k + 1..n).map(|j| a[k][j] * x[j]).sum();
        x[k] = (y[k] - s) / a[k][k];
    }
    x
}

fn rms(e: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = e.fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    (s / n as f64).sqrt()
}

/// Fit on the first 60 % of the real file, predict the rest from temperatures and speed only
/// (the lags run over the fitting part first), and compare with the static all-temperature
/// least-squares fit computed here.
#[test]
fn fit_predict_beats_the_static_fit_on_the_real_file() {
    let Some(real) = real_file() else { return };
    let table = Table::read(&std::fs::read_to_string(&real).unwrap());
    let n = table.rows.len();
    let cut = n * 6 / 10;
    let dir = tempfile::tempdir().unwrap();
    let (train, inputs, model, pred) = (
        dir.path().join("train.csv"),
        dir.path().join("test_inputs.csv"),
        dir.path().join("model.json"),
        dir.path().join("pred.csv"),
    );
    std::fs::write(&train, table.csv(0..cut, |_| true)).unwrap();
    std::fs::write(&inputs, table.csv(cut..n, |c| !c.ends_with("_um"))).unwrap();

    let fit_text = ok(&["thermal", "fit", s(&train), "-o", s(&model)]);
    println!("{fit_text}");
    assert!(
        fit_text.contains("µm/K") || fit_text.contains("µm per"),
        "{fit_text}"
    );
    assert!(
        fit_text.contains(" min"),
        "time constants in min: {fit_text}"
    );
    let pred_text = ok(&[
        "thermal",
        "predict",
        s(&model),
        s(&inputs),
        "--history",
        s(&train),
        "-o",
        s(&pred),
    ]);
    println!("{pred_text}");
    let pred_csv = std::fs::read_to_string(&pred).unwrap();
    assert!(!pred_csv.to_lowercase().contains("nan") && !pred_csv.contains("inf"));
    let p = Table::read(&pred_csv);
    assert_eq!(p.rows.len(), n - cut);
    assert_eq!(p.col("time_s"), table.col("time_s")[cut..].to_vec());

    // Static reference: each channel on every temperature plus an intercept, fitted on the
    // first 60 %, applied to the rest.
    let temps: Vec<&String> = table.names.iter().filter(|c| c.ends_with("_c")).collect();
    let row = |i: usize| -> Vec<f64> {
        std::iter::once(1.0)
            .chain(
                temps
                    .iter()
                    .map(|t| table.rows[i][table.names.iter().position(|c| c == *t).unwrap()]),
            )
            .collect()
    };
    let design: Vec<Vec<f64>> = (0..cut).map(row).collect();
    let channels: Vec<&String> = table.names.iter().filter(|c| c.ends_with("_um")).collect();
    let (mut model_sq, mut static_sq) = (0.0, 0.0);
    println!("channel  static RMS  model RMS (µm, last 40 %)");
    for ch in &channels {
        let y = table.col(ch);
        let beta = least_squares(design.clone(), y[..cut].to_vec());
        let stat = rms((cut..n).map(|i| {
            let r = row(i);
            y[i] - r.iter().zip(&beta).map(|(a, b)| a * b).sum::<f64>()
        }));
        let pm = p.col(ch);
        let modl = rms((cut..n).map(|i| y[i] - pm[i - cut]));
        // Each interval column brackets the prediction.
        let (lo, hi) = (
            p.col(&ch.replace("_um", "_lower_um")),
            p.col(&ch.replace("_um", "_upper_um")),
        );
        assert!((0..pm.len()).all(|i| lo[i] <= pm[i] && pm[i] <= hi[i]));
        println!("{ch:<8} {stat:>10.3} {modl:>10.3}");
        static_sq += stat * stat;
        model_sq += modl * modl;
    }
    let (stat, modl) = (
        (static_sq / channels.len() as f64).sqrt(),
        (model_sq / channels.len() as f64).sqrt(),
    );
    println!(
        "all      {stat:>10.3} {modl:>10.3}  ratio {:.2}",
        modl / stat
    );
    assert!(modl < stat, "model RMS {modl:.3} µm, static {stat:.3} µm");
}

#[test]
fn diagnose_names_an_effect_on_the_real_file() {
    let Some(real) = real_file() else { return };
    let text = ok(&["thermal", "diagnose", s(&real)]);
    println!("{text}");
    assert!(text.contains("finding:"), "{text}");
    assert!(!text.contains("findings: none") || text.matches("finding:").count() > 0);
    // A lag, heat source or asymmetry is named on a gain: its t is positive (a lag chosen
    // over spindle heat once read "1.036 → 1.299 µm, t = -1.7" on ch5).
    for line in text.lines().filter(|l| {
        l.contains("finding: the displacement lags")
            || l.contains("finding: a heat source")
            || l.contains("finding: spindle heating")
    }) {
        let t: f64 = line
            .rsplit("t = ")
            .next()
            .and_then(|v| v.trim_end_matches(')').parse().ok())
            .unwrap_or_else(|| panic!("no t in {line}"));
        assert!(t > 0.0, "an effect named on a loss: {line}");
    }
}

#[test]
fn analyze_thermal_gives_the_hand_computed_etve_and_distortion() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("iso.csv");
    // x1 ranges from -1.5 to 4.0 (ETVE 5.5 µm), z from 0 to 2.25 (2.25 µm).
    std::fs::write(
        &f,
        "# ISO 230-3 spindle test\n\
         time_s,room_c,x1_um,x2_um,y1_um,y2_um,z_um\n\
         0,20.0,1.0,1.0,0.0,0.5,0.0\n\
         600,20.4,-1.5,-1.0,0.3,0.5,0.75\n\
         1200,20.9,4.0,5.0,-0.2,1.1,2.25\n\
         1800,20.7,2.0,2.5,0.1,0.6,1.0\n",
    )
    .unwrap();
    let text = ok(&["analyze", "thermal", s(&f)]);
    println!("{text}");
    assert!(text.contains("5.500 µm"), "{text}");
    let j: serde_json::Value = serde_json::from_str(&ok(&[
        "analyze",
        "thermal",
        s(&f),
        "--json",
        "--probes",
        "x1,x2_um,y1,y2,z",
        "--probe-spacing-mm",
        "100",
    ]))
    .unwrap();
    let etve = |c: &str| {
        j["etve"]
            .as_array()
            .unwrap()
            .iter()
            .find(|e| e["channel"] == c)
            .unwrap()["etve_um"]
            .as_f64()
            .unwrap()
    };
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
    assert!(close(etve("x1"), 5.5));
    assert!(close(etve("x2"), 6.0));
    assert!(close(etve("y1"), 0.5));
    assert!(close(etve("y2"), 0.6));
    assert!(close(etve("z"), 2.25));
    let m = &j["spindle"]["max"];
    // X: x1 − x1(0) = 0, −2.5, 3, 1 → 3; Y: 0, 0.3, −0.2, 0.1 → 0.3; Z → 2.25.
    assert!(close(m["x_um"].as_f64().unwrap(), 3.0), "{m}");
    assert!(close(m["y_um"].as_f64().unwrap(), 0.3), "{m}");
    assert!(close(m["z_um"].as_f64().unwrap(), 2.25), "{m}");
    // B = ((x2 − x2(0)) − (x1 − x1(0))) / 100 mm: 0, 0.5, 1.0, 0.5 µm → 10 µrad at most.
    assert!(close(m["b_urad"].as_f64().unwrap(), 10.0), "{m}");
    // A = ((y2 − y2(0)) − (y1 − y1(0))) / 100 mm: 0, −0.3, 0.8, 0 µm → 8 µrad.
    assert!(close(m["a_urad"].as_f64().unwrap(), 8.0), "{m}");

    let o = metrolog(&[
        "analyze",
        "thermal",
        s(&f),
        "--probes",
        "x1,x2,y1,y2,w",
        "--probe-spacing-mm",
        "100",
    ]);
    assert_eq!(o.code, Some(1));
    assert!(o.stderr.contains("`w`"), "{}", o.stderr);
}

#[test]
fn malformed_csv_exits_non_zero_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("bad.csv");
    std::fs::write(&f, "time_s,t1_c,x_um\n0,20,0\n15,20.1,0.2\n30,abc,0.3\n").unwrap();
    for args in [
        vec!["thermal", "fit", s(&f), "-o", "/dev/null"],
        vec!["thermal", "diagnose", s(&f)],
        vec!["analyze", "thermal", s(&f)],
    ] {
        let o = metrolog(&args);
        assert_eq!(o.code, Some(1), "{args:?}: {}", o.stderr);
        assert!(o.stderr.contains("line 4"), "{args:?}: {}", o.stderr);
        assert!(o.stderr.contains("t1"), "{args:?}: {}", o.stderr);
    }
}

/// A small synthetic test: x follows sensor a through a lag, y follows b directly.
fn synthetic() -> String {
    let mut s = String::from("time_s,spindle_rpm,a_c,b_c,x_um,y_um\n");
    let mut lag = 0.0;
    for i in 0..600 {
        let t = i as f64 * 30.0;
        let a = 20.0 + 2.0 * (t / 5000.0).sin() + 0.01 * ((i * 7919 % 13) as f64 - 6.0);
        let b = 21.0 + 1.5 * (t / 3100.0).cos() + 0.01 * ((i * 104729 % 11) as f64 - 5.0);
        lag += (a - 20.0 - lag) * (1.0 - (-30.0f64 / 900.0).exp());
        let x = 3.0 * lag + 0.02 * ((i * 31 % 7) as f64 - 3.0);
        let y = -1.5 * (b - 21.0) + 0.02 * ((i * 17 % 5) as f64 - 2.0);
        s += &format!(
            "{t},{},{a},{b},{x},{y}\n",
            if i % 200 < 100 { 2000 } else { 0 }
        );
    }
    s
}

/// A short test (55 visits, as a run that lost some): fit and diagnose hold out 5 blocks of 11
/// and say so; 8 blocks asked for are refused with what is needed.
#[test]
fn a_short_test_is_fitted_on_fewer_blocks_with_a_note() {
    let dir = tempfile::tempdir().unwrap();
    let (data, model) = (dir.path().join("data.csv"), dir.path().join("model.json"));
    let short: String = synthetic()
        .lines()
        .take(56)
        .map(|l| l.to_string() + "\n")
        .collect();
    std::fs::write(&data, short).unwrap();
    let note = "note: 55 samples: 5 held-out time blocks instead of 8";
    for args in [
        vec!["thermal", "fit", s(&data), "-o", s(&model)],
        vec!["thermal", "diagnose", s(&data)],
    ] {
        let o = metrolog(&args);
        assert_eq!(o.code, Some(0), "metrolog {args:?}: {}", o.stderr);
        assert!(o.stderr.contains(note), "{args:?}: {}", o.stderr);
    }
    assert!(model.exists());
    let o = metrolog(&["thermal", "fit", s(&data), "-o", s(&model), "--blocks", "8"]);
    assert_ne!(o.code, Some(0));
    assert!(
        o.stderr
            .contains("8 blocks on 55 samples: use 3 or more blocks of 10 samples or more"),
        "{}",
        o.stderr
    );
    assert!(!o.stderr.contains(note), "{}", o.stderr);
}

#[test]
fn predict_refuses_missing_sensors_and_unwritable_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let (data, model, pred) = (
        dir.path().join("data.csv"),
        dir.path().join("model.json"),
        dir.path().join("pred.csv"),
    );
    std::fs::write(&data, synthetic()).unwrap();
    let text = ok(&["thermal", "fit", s(&data), "-o", s(&model)]);
    println!("{text}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&model).unwrap()).unwrap();
    assert_eq!(m["channels"].as_array().unwrap().len(), 2);

    // Predict from temperatures and speed alone.
    let t = Table::read(&synthetic());
    let inputs = dir.path().join("inputs.csv");
    std::fs::write(&inputs, t.csv(0..600, |c| !c.ends_with("_um"))).unwrap();
    ok(&["thermal", "predict", s(&model), s(&inputs), "-o", s(&pred)]);
    let p = Table::read(&std::fs::read_to_string(&pred).unwrap());
    assert_eq!(
        p.names,
        [
            "time_s",
            "x_um",
            "x_lower_um",
            "x_upper_um",
            "y_um",
            "y_lower_um",
            "y_upper_um"
        ]
    );
    let err = rms(t.col("x_um").iter().zip(p.col("x_um")).map(|(a, b)| a - b));
    assert!(err < 0.5, "x RMS {err}");

    // Every sensor the model uses must be there: the message names the missing one.
    let used: Vec<String> = m["channels"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|c| c["terms"].as_array().unwrap().clone())
        .filter_map(|t| t["input"]["name"].as_str().map(str::to_string))
        .collect();
    assert!(!used.is_empty(), "{m}");
    let gone = &used[0];
    let lacking = dir.path().join("lacking.csv");
    std::fs::write(&lacking, t.csv(0..600, |c| c != format!("{gone}_c"))).unwrap();
    let before = std::fs::read_to_string(&pred).unwrap();
    let o = metrolog(&["thermal", "predict", s(&model), s(&lacking), "-o", s(&pred)]);
    assert_eq!(o.code, Some(1), "{}", o.stderr);
    assert!(o.stderr.contains(&format!("`{gone}_c`")), "{}", o.stderr);
    assert_eq!(
        std::fs::read_to_string(&pred).unwrap(),
        before,
        "output left as it was"
    );

    // Not a model.
    let o = metrolog(&["thermal", "predict", s(&data), s(&inputs), "-o", s(&pred)]);
    assert_eq!(o.code, Some(1));
    assert!(o.stderr.contains("is not a thermal model"), "{}", o.stderr);

    // An output that cannot be written: the I/O error code, and no temporary file left.
    let nowhere = dir.path().join("no/such/dir/pred.csv");
    let o = metrolog(&[
        "thermal",
        "predict",
        s(&model),
        s(&inputs),
        "-o",
        s(&nowhere),
    ]);
    assert_eq!(o.code, Some(74), "{}", o.stderr);
    assert!(o.stderr.contains("cannot write"), "{}", o.stderr);
    let o = metrolog(&["thermal", "fit", s(&data), "-o", s(&nowhere)]);
    assert_eq!(o.code, Some(74), "{}", o.stderr);
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// `metrolog sim --thermal` serves the simulated temperature module beside the instruments and
/// writes a config that reads it: the config passes `run --check` (ports that exist, one
/// instrument per port) while the simulator runs, and names every sensor and the spindle speed.
#[test]
fn sim_thermal_serves_the_temperature_module_its_config_reads() {
    use std::io::BufRead as _;
    let dir = tempfile::tempdir().unwrap();
    let sim_dir = dir.path().join("sim");
    let mut child = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["sim", "--thermal", "--start-delay-s", "1000", "--dir"])
        .arg(&sim_dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
    let mut seen = vec![];
    // The config is printed once every port is open (a condition, not a time).
    for l in lines.by_ref() {
        let l = l.unwrap();
        let done = l.starts_with("run the daemon with");
        seen.push(l);
        if done {
            break;
        }
    }
    let out = seen.join("\n");
    let cfg = sim_dir.join("metrolog.toml");
    let check = metrolog(&["run", "--check", "--config", cfg.to_str().unwrap()]);
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let status = child.wait().unwrap();
    assert!(out.contains("temperature"), "{out}");
    let toml = std::fs::read_to_string(&cfg).unwrap();
    assert!(toml.contains("[temperature]"), "{toml}");
    assert!(toml.contains("name = \"spindle_rpm\""), "{toml}");
    assert_eq!(check.code, Some(0), "{}\n{}", check.stdout, check.stderr);
    assert!(status.success(), "sim: {status:?}");
}
