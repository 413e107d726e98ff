//! LinuxCNC itself as the consumer of metrolog's output (`docs/TESTING.md`,
//! `/work/shared/notes/linuxcnc-headless.md`): the generated comp file is loaded by a
//! headless simulated LinuxCNC (its own motion module, task and `linuxcncrsh`), the joint is
//! homed and moved to every table point from both sides, and the trim motion applies
//! (`joint.0.motor-pos-cmd − joint.0.pos-cmd`, relative to home) is compared with the table
//! as read here and with the known axis error it must remove; the generated part program is
//! run through LinuxCNC's interpreter (`rs274`) and its canonical commands are checked
//! against the plan. Skipped with a message when LinuxCNC is not installed; in CI
//! (`CI=true`) a missing LinuxCNC fails.

#[path = "support/comp_readers.rs"]
mod readers;

use std::io::Write as _;
use std::net::TcpStream;
use std::os::unix::process::CommandExt as _;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use positioning::axis_model::{AxisModel, Effect};
use positioning::compensation::{Dialect, Mode, Options, build};
use positioning::plan::{PlanOptions, plan};
use positioning::positioning_data::{simulate, standard_schedule};

const SIM_INI: &str = "/usr/share/doc/linuxcnc/examples/sample-configs/sim/axis/axis_mm.ini";
const RSH: &str = "127.0.0.1:5007";

/// `Some(reason)` when LinuxCNC is missing; panics in CI.
fn missing(tools: &[&str]) -> Option<String> {
    let lacking: Vec<&str> = tools
        .iter()
        .copied()
        .filter(|t| {
            !Command::new("sh")
                .args(["-c", &format!("command -v {t}")])
                .stdout(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        })
        .collect();
    let why = if !lacking.is_empty() {
        format!("{} not found", lacking.join(", "))
    } else if tools.contains(&"linuxcnc") && !Path::new(SIM_INI).exists() {
        format!("{SIM_INI} not found")
    } else {
        return None;
    };
    let msg = format!("LinuxCNC not installed ({why}; apt-get install linuxcnc-uspace)");
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "{msg}: CI must run this test"
    );
    eprintln!("skipped: {msg}");
    Some(msg)
}

/// Waits for `cond` (polled every 50 ms) up to `limit`; panics with `what` on timeout.
fn wait_for(what: &str, limit: Duration, mut cond: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !cond() {
        assert!(t0.elapsed() < limit, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout.starts_with(b"0\n"))
}

/// The package's simulated mill, copied, headless, with the comp file on joint 0 and X's
/// travel opened to −10…510 mm.
fn config(dir: &Path, comp: &str) -> PathBuf {
    let src = Path::new(SIM_INI).parent().unwrap().parent().unwrap();
    let ok = Command::new("cp")
        .arg("-r")
        .arg(src)
        .arg(dir)
        .status()
        .unwrap();
    assert!(ok.success(), "copying {}", src.display());
    let axis = dir.join("sim/axis");
    let ini = std::fs::read_to_string(axis.join("axis_mm.ini")).unwrap();
    let mut out = String::new();
    let mut section = String::new();
    for l in ini.lines() {
        if l.starts_with('[') {
            section = l.to_string();
        }
        let x = section == "[AXIS_X]" || section == "[JOINT_0]";
        let line = match l.split('=').next().unwrap_or("").trim() {
            "DISPLAY" if section == "[DISPLAY]" => "DISPLAY = linuxcncrsh".to_string(),
            "HALFILE" if l.contains("manualtoolchange") => format!("# {l}"),
            "POSTGUI_HALFILE" => format!("# {l}"),
            "MIN_LIMIT" if x => "MIN_LIMIT = -10".into(),
            "MAX_LIMIT" if x => "MAX_LIMIT = 510".into(),
            _ => l.to_string(),
        };
        out.push_str(&line);
        out.push('\n');
        if l == "[JOINT_0]" {
            out.push_str("COMP_FILE = comp.txt\nCOMP_FILE_TYPE = 1\n");
        }
    }
    std::fs::write(axis.join("axis_mm.ini"), out).unwrap();
    std::fs::write(axis.join("comp.txt"), comp).unwrap();
    axis
}

/// A running LinuxCNC; shut down (and its process group ended) on drop.
struct LinuxCnc {
    child: Child,
    rsh: TcpStream,
}

impl LinuxCnc {
    fn start(dir: &Path) -> LinuxCnc {
        assert!(
            TcpStream::connect(RSH).is_err(),
            "port 5007 is in use: another LinuxCNC is running"
        );
        let run = format!("cd '{}' && exec linuxcnc axis_mm.ini", dir.display());
        let log = std::fs::File::create(dir.join("linuxcnc.log")).unwrap();
        let mut cmd = if is_root() {
            // The real-time launcher refuses root: run as an ordinary user.
            let _ = Command::new("useradd").args(["-m", "cnc"]).status();
            let _ = Command::new("chown")
                .args(["-R", "cnc"])
                .arg(dir.parent().unwrap().parent().unwrap())
                .status();
            let mut c = Command::new("su");
            c.args(["cnc", "-c", &run]);
            c
        } else {
            let mut c = Command::new("sh");
            c.args(["-c", &run]);
            c
        };
        let child = cmd
            .process_group(0)
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .expect("starting linuxcnc");
        let mut rsh = None;
        wait_for("linuxcncrsh on port 5007", Duration::from_secs(180), || {
            rsh = TcpStream::connect(RSH).ok();
            rsh.is_some()
        });
        let mut l = LinuxCnc {
            child,
            rsh: rsh.unwrap(),
        };
        l.send(&[
            "hello EMC metrolog 1.0",
            "set enable EMCTOO",
            "set echo off",
        ]);
        l
    }

    fn send(&mut self, cmds: &[&str]) {
        for c in cmds {
            self.rsh.write_all(format!("{c}\r\n").as_bytes()).unwrap();
        }
    }

    fn pin(&self, name: &str) -> String {
        let o = Command::new("halcmd")
            .args(["getp", name])
            .output()
            .unwrap();
        String::from_utf8_lossy(&o.stdout).trim().to_string()
    }

    fn num(&self, name: &str) -> f64 {
        let v = self.pin(name);
        v.parse().unwrap_or_else(|_| panic!("{name} = `{v}`"))
    }

    /// Moves X to `x` and waits until motion stands there with the trim settled; returns
    /// (motor-pos-cmd − pos-cmd, backlash-filt), mm.
    fn move_to(&mut self, x: f64) -> (f64, f64) {
        self.send(&[&format!("set mdi G1 X{x:.4} F1800")]);
        wait_for(&format!("X at {x}"), Duration::from_secs(120), || {
            (self.num("joint.0.pos-cmd") - x).abs() < 1e-9
                && self.pin("motion.in-position") == "TRUE"
                && (self.num("joint.0.backlash-filt") - self.num("joint.0.backlash-corr")).abs()
                    < 1e-12
        });
        (
            self.num("joint.0.motor-pos-cmd") - self.num("joint.0.pos-cmd"),
            self.num("joint.0.backlash-filt"),
        )
    }
}

impl Drop for LinuxCnc {
    fn drop(&mut self) {
        self.send(&["shutdown"]);
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(60) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        // Not gone: end the process group this test started.
        let _ = Command::new("kill")
            .args(["-TERM", &format!("-{}", self.child.id())])
            .status();
        let _ = self.child.wait();
    }
}

/// The known axis error, µm (as in compensation_tables.rs).
fn truth(x: f64, up: bool) -> f64 {
    0.02 * x + 4.0 * (std::f64::consts::TAU * x / 400.0).sin() + if up { 0.0 } else { 3.0 }
}

fn table() -> positioning::compensation::CompensationTable {
    let t: Vec<f64> = (0..11)
        .map(|i| i as f64 * 50.0 + if i % 2 == 1 { 1.7 } else { 0.0 })
        .collect();
    let model = AxisModel {
        axis: "X".into(),
        systematic_up_um: t.iter().map(|&x| truth(x, true)).collect(),
        systematic_down_um: t.iter().map(|&x| truth(x, false)).collect(),
        targets_mm: t,
        noise_um: 0.3,
        effects: vec![Effect::LinearDrift { rate_um_per_h: 0.0 }],
    };
    let d = simulate(&model, &standard_schedule(11, 5, 6.0), 11);
    let o = Options {
        dialect: Dialect::LinuxCnc,
        mode: Mode::Bidirectional,
        spacing_mm: None,
        reference_mm: None,
        axis_name: None,
        axis_number: 1,
        point_limit: None,
    };
    build(&d, &o).unwrap()
}

#[test]
fn linuxcnc_motion_applies_the_comp_file_as_read_here() {
    if missing(&["linuxcnc", "halcmd"]).is_some() {
        return;
    }
    let t = table();
    let comp = &t.files.iter().find(|f| f.0 == "x_comp.txt").unwrap().1;
    let table = readers::linuxcnc(comp);
    let tmp = tempfile::tempdir().unwrap();
    let dir = config(tmp.path(), comp);
    let mut cnc = LinuxCnc::start(&dir);
    cnc.send(&[
        "set estop off",
        "set machine on",
        "set mode manual",
        "set home -1",
    ]);
    wait_for("all joints homed", Duration::from_secs(120), || {
        (0..3).all(|j| cnc.pin(&format!("joint.{j}.homed")) == "TRUE")
    });
    cnc.send(&["set mode mdi"]);
    // Home (0 mm) reached from below is the reference the table is relative to.
    cnc.move_to(-5.0);
    let (d0, f0) = cnc.move_to(0.0);
    let mut stops: Vec<(f64, bool)> = vec![];
    let pts = &table.points_mm;
    for (i, &p) in pts.iter().enumerate() {
        stops.push((p, true));
        if i + 1 < pts.len() {
            stops.push((0.5 * (p + pts[i + 1]), true));
        }
    }
    let down: Vec<(f64, bool)> = stops.iter().rev().map(|&(p, _)| (p, false)).collect();
    let (mut err, mut res) = (0.0f64, 0.0f64);
    let mut seen = vec![];
    for (k, &(x, up)) in stops
        .iter()
        .chain([(505.0, true)].iter())
        .chain(down.iter())
        .enumerate()
    {
        let (d, f) = cnc.move_to(x);
        if k == stops.len() {
            continue; // the reversal beyond the end
        }
        let shift_um = (d - d0) * 1e3;
        let want = table.at(x, up) - table.at(0.0, true);
        assert!(
            (shift_um - want).abs() < 0.2,
            "X {x} {up}: LinuxCNC shifts {shift_um:.3} µm, the table read here {want:.3}"
        );
        assert!(
            ((f - f0) * 1e3 - want).abs() < 1e-3,
            "X {x} {up}: backlash-filt {f}"
        );
        let e = truth(x, up) - truth(0.0, true);
        if pts.contains(&x) {
            err = err.max(e.abs());
            res = res.max((e + (f - f0) * 1e3).abs());
        }
        seen.push(format!(
            "{x:7.2} {}: shift {:+.3} µm, error {e:+.2}, left {:+.2}",
            if up { '+' } else { '-' },
            (f - f0) * 1e3,
            e + (f - f0) * 1e3
        ));
    }
    println!("{}", seen.join("\n"));
    println!(
        "LinuxCNC leaves {res:.2} µm of {err:.2} µm ({:.1} %) at the table's points",
        100.0 * res / err
    );
    assert!(res <= 0.15 * err, "{res} of {err}");
}

/// One canonical command: name, numeric arguments and the raw arguments.
fn canon(line: &str) -> Option<(String, Vec<f64>, String)> {
    let body = line.split("N..... ").nth(1)?;
    let (name, args) = body.split_once('(')?;
    let raw = args.trim_end_matches(')').to_string();
    let nums = raw
        .split(',')
        .filter_map(|a| a.trim().parse().ok())
        .collect();
    Some((name.to_string(), nums, raw))
}

#[test]
fn rs274_runs_the_program_through_every_target_in_machine_coordinates() {
    if missing(&["rs274"]).is_some() {
        return;
    }
    let p = plan(&PlanOptions::default()).unwrap();
    let program = p.part_program(Dialect::LinuxCnc);
    // A work offset active before the program: the moves must not follow it (G53).
    let tmp = tempfile::tempdir().unwrap();
    let ngc = tmp.path().join("test.ngc");
    std::fs::write(&ngc, format!("G10 L2 P1 X123.4\nG54\n{program}")).unwrap();
    let out = tmp.path().join("canon.txt");
    let st = Command::new("rs274")
        .arg("-g")
        .arg(&ngc)
        .arg(&out)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "rs274: {}",
        String::from_utf8_lossy(&st.stderr)
    );
    let text = std::fs::read_to_string(&out).unwrap();
    let mut offset = 0.0;
    let (mut moves, mut measured) = (vec![], vec![]);
    let mut mode = String::new();
    let mut pending: Option<(usize, f64)> = None; // pose index set, move
    let mut cmds = text.lines().filter_map(canon).peekable();
    while let Some((name, a, raw)) = cmds.next() {
        match name.as_str() {
            "SET_G5X_OFFSET" => offset = a[1],
            "SET_MOTION_CONTROL_MODE" => mode = raw,
            "SET_AUX_OUTPUT_VALUE" => pending = Some((a[1] as usize, f64::NAN)),
            "STRAIGHT_FEED" => {
                moves.push(a[0] + offset);
                if let Some((n, _)) = pending {
                    pending = Some((n, a[0] + offset));
                }
            }
            "SET_AUX_OUTPUT_BIT" => {
                let (n, x) = pending.take().expect("the pose index before the trigger");
                let dwell = cmds.next().expect("a dwell after the trigger");
                assert_eq!(dwell.0, "DWELL");
                assert_eq!(dwell.1, [p.options.dwell_s]);
                assert_eq!(
                    cmds.next().map(|c| c.0).as_deref(),
                    Some("CLEAR_AUX_OUTPUT_BIT")
                );
                assert!(
                    mode.contains("CANON_EXACT_STOP"),
                    "exact stop before pose {n}: {mode}"
                );
                measured.push((n, x));
            }
            _ => {}
        }
    }
    let want: Vec<f64> = p.poses.iter().map(|q| q.position_mm).collect();
    assert_eq!(moves.len(), want.len(), "one move per pose");
    for (m, w) in moves.iter().zip(&want) {
        assert!((m - w).abs() < 1e-4, "machine X {m} vs pose {w}");
    }
    let targets: Vec<(usize, f64)> = p
        .poses
        .iter()
        .filter(|q| q.target.is_some())
        .map(|q| (q.pose, q.position_mm))
        .collect();
    assert_eq!(measured.len(), targets.len());
    for ((n, x), (pn, px)) in measured.iter().zip(&targets) {
        assert_eq!(n, pn);
        assert!((x - px).abs() < 1e-4);
    }
}
