//! Hostile inputs (issue 27): every command ends with a clear error — no panic, abort or hang,
//! no NaN or infinity in a result, nothing left behind by a failed write.
//!
//! The committed corpus is `daemon/tests/hostile/` (one file per case; `{c}` below); [`CASES`]
//! lists each run: the command line, the exit code it must end with (the README's table: 1 a
//! bad input, 2 a bad command line) and words its message must hold. Inputs too large to
//! commit (a million-row CSV, a 300 000-term budget), a FIFO and damaged logs are made by the
//! tests below. Every run has a memory limit (address space) and a deadline far beyond its
//! need, so an unbounded allocation fails and a hang is reported instead of blocking the suite.

mod log_common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

/// Where the corpus is.
fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/hostile")
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

/// The most address space a run may take: a hostile input that makes a command allocate
/// without bound fails here (the issue saw 21 GB, 1.6 TB and exabytes asked for).
const MEMORY_LIMIT: u64 = 4 << 30;

/// A run that takes longer has hung (the slowest case here needs a few seconds).
const DEADLINE: Duration = Duration::from_secs(240);

/// `metrolog ARGS` under the memory limit; its output, or a panic naming the hang.
fn metrolog(args: &[String]) -> Output {
    use std::os::unix::process::CommandExt as _;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_metrolog"));
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            let lim = libc::rlimit {
                rlim_cur: MEMORY_LIMIT,
                rlim_max: MEMORY_LIMIT,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let child = cmd.spawn().expect("metrolog starts");
    let pid = child.id();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(DEADLINE) {
        Ok(out) => out.expect("metrolog's output is read"),
        Err(_) => {
            // SAFETY: kill(2) on the child this test started.
            unsafe { libc::kill(pid as i32, libc::SIGKILL) };
            panic!("metrolog {args:?} hung: no end within {DEADLINE:?}");
        }
    }
}

/// One hostile run: the command line (`{c}` the corpus, `{x}` the examples, `{o}` an empty
/// output directory), the exit code and words of its message (stderr, or stdout for code 0).
struct Case {
    args: &'static str,
    code: i32,
    words: &'static [&'static str],
}

const fn case(args: &'static str, code: i32, words: &'static [&'static str]) -> Case {
    Case { args, code, words }
}

/// The table. Codes: 0 done, 1 a bad input (what to fix named), 2 a bad command line.
const CASES: &[Case] = &[
    // plan: positions, counts and rates within what a machine can have.
    case(
        "plan positioning --from 0 --to 1e308 -o {o}",
        1,
        &["--to", "100000 mm"],
    ),
    case(
        "plan positioning --from 0 --to inf -o {o}",
        1,
        &["--to", "100000 mm"],
    ),
    case(
        "plan positioning --from nan --to 100 -o {o}",
        1,
        &["--from", "100000 mm"],
    ),
    case(
        "plan positioning --from=-1e300 --to 0 -o {o}",
        1,
        &["--from", "100000 mm"],
    ),
    case(
        "plan positioning --from 0 --to 500 --cycles 1000000 -o {o}",
        1,
        &["1000000 cycles", "100000 measured stops"],
    ),
    case(
        "plan positioning --from 0 --to 500 --targets 100000 -o {o}",
        1,
        &["measured stops"],
    ),
    case(
        "plan positioning --from 0 --to 500 --feed 1e300 -o {o}",
        1,
        &["--feed"],
    ),
    case(
        "plan positioning --from 0 --to 500 --feed nan -o {o}",
        1,
        &["--feed"],
    ),
    case(
        "plan positioning --from 0 --to 500 --dwell inf -o {o}",
        1,
        &["--dwell"],
    ),
    case(
        "plan positioning --from 0 --to 500 --overrun inf -o {o}",
        1,
        &["overrun"],
    ),
    case(
        "plan positioning --from 0 --to 500 --offset nan -o {o}",
        1,
        &["offset"],
    ),
    case(
        "plan positioning --from 0 --to 500 --cycles 1e6 -o {o}",
        2,
        &["--cycles"],
    ),
    // Monte Carlo settings: bounded like --trials.
    case(
        "identify capball {x}/models/capball_identification.csv --uncertainty mc --ndig 99",
        2,
        &["--ndig", "1 to 4"],
    ),
    case(
        "identify capball {x}/models/capball_identification.csv --uncertainty mc --drift-harmonics 0",
        2,
        &["--drift-harmonics"],
    ),
    case(
        "uncertainty {x}/budgets/jcgm101_9_2_2_additive_normal.toml --ndig 4000000000",
        2,
        &["--ndig", "1 to 4"],
    ),
    case(
        "uncertainty {c}/budget-trials-huge.toml",
        1,
        &["trials", "20000000"],
    ),
    case(
        "uncertainty {c}/budget-ndig-huge.toml",
        1,
        &["ndig", "1 to 4"],
    ),
    case(
        "uncertainty {c}/budget-coverage-nan.toml",
        1,
        &["coverage_probability"],
    ),
    // Found by tests/sweep/hostile_sweep.py: model values each finite but too large to
    // average ("b = -inf °C u = inf °C"), a tool offset of 1e308 ("largest volumetric error
    // inf µm"), a reading uncertainty of 1e308 ("u inf inf inf").
    case(
        "uncertainty {c}/budget-mean-1e308.toml",
        1,
        &["not a finite number", "too large"],
    ),
    // Found by the hostile sweep (seed 31): a finite reading of -1e308 µm gave "EA0Z NaN",
    // "EYZ -inf"; a reading is a spot on the 10 mm diode.
    case(
        "identify psd {c}/psd-reading-1e308.csv --reference 0",
        1,
        &["r2_um", "5000 µm"],
    ),
    // Found by the hostile sweep (seed 23): the other targets without scatter made the local
    // anomaly's ratio and significance infinite ("significance inf", "x̄ NaN µm").
    case(
        "diagnose {c}/positioning-one-scatter.csv",
        0,
        &["No finding"],
    ),
    // A before sample without scatter printed "variance ratio after/before inf".
    case(
        "parts {c}/parts-before-constant.csv {x}/models/parts_after.csv --tolerance=-10,10",
        0,
        &["variance ratio after/before: not defined"],
    ),
    // A value quoted in the message: its escape sequences (clear the screen, set the window
    // title) reached the terminal verbatim.
    case(
        "parts {c}/parts-escape-in-a-value.csv {x}/models/parts_after.csv --tolerance=-10,10",
        1,
        &["line 3", "is not a number", "\u{fffd}[2J"],
    ),
    // Found by the budget_path fuzz target: ν_eff of 7·10²⁶ (a dominant input without ν) made
    // statrs' t quantile loop for ever; the expansion about the normal quantile answers.
    case(
        "uncertainty {c}/budget-dof-1e8.toml --method gum",
        0,
        &["k = 2.576"],
    ),
    case(
        "volumetric --errors {x}/models/component_errors.csv --machine {c}/machine-tool-offset-1e308.toml --grid 0:400:3,0:300:3,0:200:3 --out {o}/t.csv",
        1,
        &["tool_offset_mm", "100000 mm"],
    ),
    case(
        "identify psd {x}/models/psd_readings.csv --reference 0 --sigma-um 1e308",
        1,
        &["--sigma-um", "5000"],
    ),
    case(
        "identify psd {x}/models/psd_readings.csv --reference 0 --layout 0,1e-320,0,167,0,350",
        1,
        &["--layout", "at least 1 mm"],
    ),
    case(
        "identify capball {x}/models/capball_identification.csv --uncertainty mc --sensor-u-um 1e308,1,1",
        1,
        &["--sensor-u-um", "10000"],
    ),
    // Budget expressions: depth limits, not a stack overflow.
    case(
        "uncertainty {c}/budget-nested-30000.toml",
        1,
        &["deeper than 256", "intermediate"],
    ),
    case(
        "uncertainty {c}/budget-signs-50000.toml",
        1,
        &["deeper than 256"],
    ),
    // CapBall values out of range: refused at read, never to the SVD.
    case(
        "identify capball {c}/capball-c-1e160.csv",
        1,
        &["c_deg", "range"],
    ),
    case(
        "identify capball {c}/capball-a-inf.csv",
        1,
        &["a_deg", "finite"],
    ),
    case(
        "identify capball {c}/capball-x-1e300.csv",
        1,
        &["x_mm", "range"],
    ),
    case(
        "identify capball {c}/capball-e-nan.csv",
        1,
        &["ex_um", "finite"],
    ),
    case("diagnose {c}/capball-c-1e160.csv", 1, &["c_deg", "range"]),
    // Files that are not MCAP logs.
    case("info {c}/empty.mcap", 1, &["not an MCAP log", "empty"]),
    case("info {c}/csv-named.mcap", 1, &["not an MCAP log", "magic"]),
    case("info {c}/random.mcap", 1, &["not an MCAP log"]),
    case("info {c}", 1, &["not an MCAP log", "not a regular file"]),
    case("replay {c}/random.mcap", 1, &["not an MCAP log"]),
    case(
        "replay {c}/empty.mcap -o {o}/replayed.mcap",
        1,
        &["not an MCAP log"],
    ),
    case(
        "recover {c}/random.mcap -o {o}/fixed.mcap",
        1,
        &["not an MCAP log"],
    ),
    case(
        "recover {c}/csv-named.mcap -o {o}/fixed.mcap",
        1,
        &["not an MCAP log"],
    ),
    case(
        "recover {c}/magic-only.mcap -o {o}/fixed.mcap",
        1,
        &["not one message", "nothing written"],
    ),
    case(
        "analyze positioning {c}/empty.mcap",
        1,
        &["not an MCAP log"],
    ),
    case("diagnose {c}/random.mcap", 1, &["not an MCAP log"]),
    case("analyze positioning {c}/random.csv", 1, &["random.csv"]),
    // Positioning values out of range.
    case(
        "analyze positioning {c}/positioning-dev-1e308.csv",
        1,
        &["deviation_um", "line 4"],
    ),
    case(
        "analyze positioning {c}/positioning-dev-inf.csv",
        1,
        &["deviation_um"],
    ),
    case(
        "analyze positioning {c}/positioning-dev-nan.csv",
        1,
        &["deviation_um"],
    ),
    case(
        "diagnose {c}/positioning-dev-1e308.csv",
        1,
        &["deviation_um"],
    ),
    case(
        "analyze positioning {c}/positioning-time-1e308.csv",
        1,
        &["time_s"],
    ),
    // A run without scatter: the ratios over zero are not determined, never NaN.
    case(
        "analyze positioning {c}/positioning-flat.csv",
        0,
        &["not determined"],
    ),
    // Volumetric: grid and table values within a machine's travel and a physical error; a
    // machine without errors gives zeros, never NaN; a failed run writes no table.
    case(
        "volumetric --machine {x}/models/machine_3axis.toml --errors {x}/models/component_errors.csv --grid 0:1e308:3,0:400:9,0:300:7 --out {o}/comp.csv --siemens {o}/cec.ini",
        1,
        &["grid", "100000 mm"],
    ),
    case(
        "volumetric --machine {x}/models/machine_3axis.toml --errors {c}/volumetric-value-1e300.csv --grid 0:500:11,0:400:9,0:300:7 --out {o}/comp.csv",
        1,
        &["row 3", "value 1e300"],
    ),
    case(
        "volumetric --machine {x}/models/machine_3axis.toml --errors {c}/volumetric-position-1e300.csv --grid 0:500:11,0:400:9,0:300:7 --out {o}/comp.csv",
        1,
        &["row 3", "position_mm"],
    ),
    case(
        "volumetric --machine {x}/models/machine_3axis.toml --errors {c}/volumetric-zero.csv --grid 0:500:11,0:400:9,0:300:7 --out {o}/comp.csv --siemens {o}/cec.ini",
        0,
        &["largest volumetric error 0.00"],
    ),
    case(
        "volumetric --machine {x}/models/machine_3axis.toml --errors {c}/volumetric-zero.csv --grid 100:100:1,0:0:1,0:0:1 --out {o}/comp.csv --json",
        0,
        &["max_norm_um"],
    ),
    // A thermal test with every column constant: no spread to fit, no NaN in any result.
    case(
        "thermal fit {c}/thermal-constant.csv -o {o}/model.json",
        0,
        &["held-out RMS 0.000"],
    ),
    case("thermal diagnose {c}/thermal-constant.csv", 0, &[]),
    case("thermal diagnose {c}/thermal-constant.csv --json", 0, &[]),
    case(
        "analyze thermal {c}/thermal-constant.csv --probes ch1,ch1,ch2,ch2,ch1 --probe-spacing-mm 100",
        0,
        &["ETVE"],
    ),
    case(
        "analyze thermal {c}/thermal-constant.csv --json",
        0,
        &["etve_um"],
    ),
    // PSD frame readings without any spread (every reading 0.5 µm): zeros, never NaN.
    case(
        "identify psd {c}/psd-constant.csv --reference 1",
        0,
        &["straightness ranges"],
    ),
    case(
        "identify psd {c}/psd-constant.csv --reference 1 --json",
        0,
        &["errors"],
    ),
    case("diagnose {c}/positioning-flat.csv", 0, &[]),
    case("report {c}/positioning-flat.csv -o {o}/report.html", 0, &[]),
    #[cfg(feature = "plot")]
    case(
        "diagnose {c}/positioning-flat.csv --plot {o}/diagnosis.svg",
        0,
        &[],
    ),
    #[cfg(feature = "plot")]
    case(
        "analyze positioning {c}/positioning-flat.csv --plot {o}/run.svg",
        0,
        &[],
    ),
];

/// A NaN or an infinity written as a number ("NaN", "inf", "-inf", "Infinity").
fn non_finite_token(text: &str) -> Option<String> {
    let re = regex::Regex::new(r"(?i)(^|[^a-z_])([+-]?(nan|inf|infinity))($|[^a-z_])")
        .expect("the pattern compiles");
    re.captures(text).map(|c| c[0].to_string())
}

fn expand(args: &str, out: &Path) -> Vec<String> {
    let (c, x, o) = (corpus(), examples(), out.to_path_buf());
    args.split_whitespace()
        .map(|a| {
            a.replace("{c}", &c.display().to_string())
                .replace("{x}", &x.display().to_string())
                .replace("{o}", &o.display().to_string())
        })
        .collect()
}

/// What every run must hold: the code, the words, no panic, no non-finite number in a result
/// (stdout and the files written), nothing left in `{o}` by a failed run.
fn check(args: &[String], out_dir: &Path, o: &Output, code: i32, words: &[&str]) -> Vec<String> {
    let mut bad = Vec::new();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    let said = if code == 0 {
        format!("{stdout}{stderr}")
    } else {
        stderr.to_string()
    };
    if o.status.code() != Some(code) {
        bad.push(format!("exit {:?}, expected {code}", o.status.code()));
    }
    if stderr.contains("panicked") || stderr.contains("RUST_BACKTRACE") {
        bad.push("panicked".into());
    }
    for w in words {
        if !said.contains(w) {
            bad.push(format!("no `{w}` in the message"));
        }
    }
    if let Some(t) = non_finite_token(&stdout) {
        bad.push(format!("stdout holds `{t}`"));
    }
    // Nothing read from an input reaches the terminal as a control sequence.
    let control = |c: char| c.is_control() && !matches!(c, '\n' | '\r' | '\t');
    for (name, text) in [("stdout", &stdout), ("stderr", &stderr)] {
        if let Some(c) = text.chars().find(|&c| control(c)) {
            bad.push(format!("{name} holds the control character {c:?}"));
        }
    }
    let written: Vec<PathBuf> = std::fs::read_dir(out_dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    if code != 0 && !written.is_empty() {
        bad.push(format!("a failed run left {written:?}"));
    }
    // The text files written (a log is binary: its bytes are no numbers to read).
    for f in &written {
        let Ok(text) = String::from_utf8(std::fs::read(f).unwrap_or_default()) else {
            continue;
        };
        if let Some(t) = non_finite_token(&text) {
            bad.push(format!("{} holds `{t}`", f.display()));
        }
    }
    bad.into_iter()
        .map(|b| format!("metrolog {}: {b}\n--- stderr:\n{stderr}", args.join(" ")))
        .collect()
}

#[test]
fn every_corpus_case_ends_as_listed() {
    let mut failures = Vec::new();
    for (k, c) in CASES.iter().enumerate() {
        let tmp = tempfile::tempdir().expect("a temporary directory");
        let out_dir = tmp.path().join(format!("out{k}"));
        std::fs::create_dir(&out_dir).expect("the output directory");
        let args = expand(c.args, &out_dir);
        let o = metrolog(&args);
        failures.extend(check(&args, &out_dir, &o, c.code, c.words));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

/// Every file of the corpus is used by a case (a file added without a case tests nothing).
#[test]
fn every_corpus_file_has_a_case() {
    for e in std::fs::read_dir(corpus()).expect("the corpus") {
        let name = e
            .expect("an entry")
            .file_name()
            .to_string_lossy()
            .into_owned();
        assert!(
            CASES
                .iter()
                .any(|c| c.args.contains(&format!("{{c}}/{name}"))),
            "{name} has no case"
        );
    }
}

#[test]
fn the_non_finite_check_finds_what_it_must() {
    for t in ["x NaN µm", "noise inf", "-inf", "RMS x nan y", "Infinity"] {
        assert!(non_finite_token(t).is_some(), "{t}");
    }
    for t in [
        "info",
        "infinite",
        "not determined",
        "financial",
        "nano",
        "Inflow",
    ] {
        assert!(non_finite_token(t).is_none(), "{t}");
    }
}

/// Runs `args` (with `{o}` an empty output directory) and checks it as a corpus case.
fn run_case(args: &str, code: i32, words: &[&str]) -> (Output, PathBuf, tempfile::TempDir) {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let out_dir = tmp.path().join("out");
    std::fs::create_dir(&out_dir).expect("the output directory");
    let argv = expand(args, &out_dir);
    let o = metrolog(&argv);
    let bad = check(&argv, &out_dir, &o, code, words);
    assert!(bad.is_empty(), "{}", bad.join("\n\n"));
    (o, out_dir, tmp)
}

/// A FIFO where a file is expected is refused at once (opening it would wait for a writer
/// forever).
#[test]
fn a_fifo_as_input_is_refused_not_waited_on() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let fifo = tmp.path().join("input.csv");
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
    let log = tmp.path().join("input.mcap");
    nix::unistd::mkfifo(&log, nix::sys::stat::Mode::S_IRWXU).expect("mkfifo");
    let f = fifo.display().to_string();
    let l = log.display().to_string();
    for args in [
        format!("analyze positioning {f}"),
        format!("diagnose {f}"),
        format!("identify capball {f}"),
        format!("uncertainty {f}"),
        format!("info {l}"),
        format!("replay {l}"),
        format!("recover {l} -o {{o}}/fixed.mcap"),
        format!("analyze positioning {l}"),
    ] {
        run_case(&args, 1, &["not a regular file"]);
    }
}

/// A million-row positioning CSV is refused with the limit, within the memory limit (it grew
/// to 21 GB in `diagnose`).
#[test]
fn a_million_row_csv_is_refused_with_the_limit() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let path = tmp.path().join("big.csv");
    let mut t = String::from("cycle,direction,index,target_mm,deviation_um,time_s\n");
    for k in 0..1_000_000usize {
        let (c, i) = (k / 1000 + 1, k % 1000 + 1);
        t += &format!("{c},+,{i},{i},1.5,{k}\n");
    }
    std::fs::write(&path, t).expect("the CSV");
    let p = path.display();
    for cmd in ["diagnose", "analyze positioning"] {
        run_case(&format!("{cmd} {p}"), 1, &["100000"]);
    }
}

/// A run within the reader's limit but too large for the diagnosis's memory (5 cycles of
/// 2 000 targets: 20 000 readings) is refused with the limit; `analyze` still takes it.
#[test]
fn a_run_too_large_to_diagnose_is_refused_with_the_limit() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let path = tmp.path().join("wide.csv");
    let mut t = String::from("cycle,direction,index,target_mm,deviation_um,time_s\n");
    let mut k = 0;
    for c in 1..=5 {
        for up in [true, false] {
            for j in 0..2000 {
                let i = if up { j + 1 } else { 2000 - j };
                k += 1;
                let d = if up { "+" } else { "-" };
                t += &format!("{c},{d},{i},{},{}.5,{k}\n", i * 2, k % 7);
            }
        }
    }
    std::fs::write(&path, t).expect("the CSV");
    let p = path.display();
    run_case(
        &format!("diagnose {p}"),
        1,
        &["too many to diagnose", "5000000"],
    );
    run_case(&format!("analyze positioning {p}"), 0, &[]);
}

/// 20 000 cycles (80 000 readings, within the reader's limit) chart in a bounded file: at most
/// `MAX_RUNS_DRAWN` runs are drawn per direction and the legend says so (50 000 cycles made a
/// 121 MB SVG in 234 s).
#[cfg(feature = "plot")]
#[test]
fn a_run_of_many_cycles_charts_in_a_bounded_file() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let path = tmp.path().join("long.csv");
    let mut t = String::from("cycle,direction,index,target_mm,deviation_um,time_s\n");
    let mut k = 0;
    for c in 1..=20_000 {
        for (d, order) in [("+", [1, 2]), ("-", [2, 1])] {
            for i in order {
                k += 1;
                t += &format!("{c},{d},{i},{},{}.5,{k}\n", i * 100, k % 7);
            }
        }
    }
    std::fs::write(&path, t).expect("the CSV");
    let p = path.display();
    let (_, out, _tmp) = run_case(
        &format!("analyze positioning {p} --plot {{o}}/run.svg"),
        0,
        &[],
    );
    let svg = std::fs::read_to_string(out.join("run.svg")).expect("the chart");
    assert!(svg.len() < 8 << 20, "chart of {} bytes", svg.len());
    assert!(svg.contains("200 of 20000 cycles drawn"), "legend");
}

/// A thermal test past `thermal::MAX_SIZE` (100 000 samples of 16 sensors: `thermal diagnose`
/// took 0.83 GB, and the 256 MiB text limit alone allowed 17 times that) is refused by `fit`
/// and `diagnose` with the limit and what to do; `analyze thermal` (linear in the samples)
/// still takes it.
#[test]
fn a_thermal_test_too_large_to_model_is_refused_with_the_limit() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let path = tmp.path().join("long.csv");
    let mut t = String::from("time_s,ch1_um");
    for k in 1..=16 {
        t += &format!(",t{k}_c");
    }
    t.push('\n');
    for r in 0..100_000 {
        t += &format!("{},{}", 15 * r, (r % 97) as f64 * 0.01);
        for k in 1..=16 {
            t += &format!(",{}", 20.0 + ((r * k) % 89) as f64 * 0.001);
        }
        t.push('\n');
    }
    std::fs::write(&path, t).expect("the CSV");
    let p = path.display();
    for args in [
        format!("thermal diagnose {p}"),
        format!("thermal fit {p} -o {{o}}/m.json"),
    ] {
        run_case(
            &args,
            1,
            &["too many to model", "1500000", "split it in time"],
        );
    }
    run_case(&format!("analyze thermal {p}"), 0, &[]);
}

/// A CapBall dataset past `geometry::capball::MAX_DATASET_ROWS` (a million rows took 0.9 GB
/// to identify; the text limit allowed three times that) is refused with the limit.
#[test]
fn a_capball_dataset_too_long_is_refused_with_the_limit() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let path = tmp.path().join("long.csv");
    let mut t = String::from("pose,x_mm,y_mm,z_mm,a_deg,c_deg,ex_um,ey_um,ez_um\n");
    for r in 0..200_001 {
        t += &format!("{},{},0,0,0,{},0.1,0.2,0.3\n", r + 1, r % 100, r % 360);
    }
    std::fs::write(&path, t).expect("the CSV");
    run_case(
        &format!("identify capball {}", path.display()),
        1,
        &["more than 200000 rows", "split the file"],
    );
}

/// A 300 000-term budget expression is refused (it overflowed the stack).
#[test]
fn a_300000_term_budget_expression_is_refused() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let path = tmp.path().join("terms.toml");
    let expr = vec!["X"; 300_000].join(" + ");
    std::fs::write(
        &path,
        format!(
            "title = \"hostile\"\n[[input]]\nname = \"X\"\ndistribution = \"normal\"\nmean = 0\nu = 1\n\n\
             [[output]]\nname = \"Y\"\nexpr = \"{expr}\"\n"
        ),
    )
    .expect("the budget");
    run_case(
        &format!("uncertainty {}", path.display()),
        1,
        &["longer than"],
    );
}

/// A cleanly closed log with one chunk cut out: `info` and `recover` report the missing
/// messages (they said "closed cleanly" and "intact"), an analysis says the log is damaged.
#[test]
fn a_log_with_a_chunk_removed_is_reported_damaged() {
    use metrolog_log::LogOptions;
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let opts = LogOptions {
        chunk_size: 16 << 10,
        ..LogOptions::default()
    };
    let run = drivers::synthetic::SyntheticRun::default();
    let w = log_common::write_run_with(tmp.path(), "full.mcap", &run, opts);
    let full = std::fs::read(&w.path).expect("the log");
    let cut = without_one_chunk(&full);
    let damaged = tmp.path().join("damaged.mcap");
    std::fs::write(&damaged, cut).expect("the damaged log");
    let d = damaged.display();

    let (o, _, _t) = run_case(&format!("info {d}"), 0, &["DAMAGED", "missing"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(!text.contains("closed     cleanly ("), "{text}");
    run_case(
        &format!("recover {d} -o {{o}}/fixed.mcap"),
        0,
        &["damage:", "missing"],
    );
    let (o, _, _t) = run_case(&format!("replay {d}"), 0, &["damaged"]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("missing"));
    // An analysis says the log is damaged and that its result is built on part of the run.
    let o = metrolog(&expand(&format!("analyze positioning {d}"), tmp.path()));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("is damaged") && err.contains("part of the run") && err.contains("missing"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// The bytes of an MCAP file with its second chunk (and the message indexes after it)
/// removed: every record stays whole, the summary still counts the removed messages.
fn without_one_chunk(file: &[u8]) -> Vec<u8> {
    const CHUNK: u8 = 0x06;
    const MESSAGE_INDEX: u8 = 0x07;
    let mut at = 8;
    let mut records = Vec::new();
    while at + 9 <= file.len() {
        let op = file[at];
        let len = u64::from_le_bytes(file[at + 1..at + 9].try_into().expect("8 bytes")) as usize;
        records.push((op, at, at + 9 + len));
        at += 9 + len;
        if op == 0x02 {
            break; // footer
        }
    }
    let chunks: Vec<usize> = (0..records.len())
        .filter(|&k| records[k].0 == CHUNK)
        .collect();
    assert!(chunks.len() >= 3, "the test log needs several chunks");
    let k = chunks[1];
    let mut end = records[k].2;
    for r in &records[k + 1..] {
        if r.0 != MESSAGE_INDEX {
            break;
        }
        end = r.2;
    }
    let mut out = file[..records[k].1].to_vec();
    out.extend_from_slice(&file[end..]);
    out
}

/// A failed `recover` leaves nothing behind, so the next one into the same name succeeds (it
/// failed with "File exists"); `replay -o` of a bad input leaves no empty log.
#[test]
fn failed_writes_leave_nothing_behind() {
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let run = drivers::synthetic::SyntheticRun::default();
    let w = log_common::write_run(tmp.path(), "good.mcap", &run);
    let out = tmp.path().join("fixed.mcap");
    let c = corpus();
    let o = metrolog(&[
        "recover".into(),
        c.join("random.mcap").display().to_string(),
        "-o".into(),
        out.display().to_string(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(!out.exists());
    let o = metrolog(&[
        "recover".into(),
        w.path.display().to_string(),
        "-o".into(),
        out.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.exists());
    let leftovers: Vec<_> = std::fs::read_dir(tmp.path())
        .expect("the directory")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}
