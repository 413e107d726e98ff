//! Hardware-in-loop: the real `metrolog run` binary against the simulated instruments on
//! pseudo-terminals, with faults injected, read back by an independent Python reader
//! (`tests/py/read_log.py`: the `mcap` and `jsonschema` packages).
//!
//! 1. A run that ends by itself at the CNC's program end: exit code 0, a complete log whose
//!    messages all match their schemas, pose values next to the simulation's true values, and
//!    counters that saw the injected faults.
//! 2. A run SIGKILLed in the middle: the log's intact prefix reads, up to about a second
//!    before the kill.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use sim::scenario::{MissingTrigger, StreamFaults, Unplug};
use sim::{Device, ProgramStart, Scenario};

/// The demo scenario cut to its first 11 poses (pose 6 is a reversal without dwell), started
/// 2 s after the daemon opens the CAN channel, with faults on every stream.
fn scenario() -> Scenario {
    let mut s = Scenario::demo();
    s.program.poses.truncate(11);
    s.program.start = ProgramStart::OnCanOpen;
    s.program.start_delay_s = 2.0;
    // The CapBall values are checked against the per-pose truth at mid-dwell to 0.1 µm: without
    // the demo's per-visit scatter (0.15 µm, not in that truth) and its cooling cycle (1.5 µm/s
    // at the demo's time scale: 0.15 µm between the window early in the dwell and mid-dwell).
    s.capball.truth.pose_noise_um = 0.0;
    s.capball.truth.cyclic_drift = None;
    let stream = StreamFaults {
        garbage_rate: 2e-4,
        bad_checksum_rate: 2e-4,
        truncated_rate: 1e-4,
        drop_rate: 1e-4,
        ..StreamFaults::default()
    };
    s.faults.interferometer = stream;
    s.faults.capball = stream;
    s.faults.psd = StreamFaults {
        bad_checksum_rate: 0.0,
        ..stream
    };
    s.faults.beam_interruptions.clear();
    // The CB-3 is unplugged for 0.4 s during pose 2's move and dwell.
    s.faults.unplugs = vec![Unplug {
        device: Device::Capball,
        at_s: 0.75,
        duration_s: 0.4,
    }];
    // The CNC forgets the exact stop of pose 4.
    s.faults.missing_triggers = vec![MissingTrigger {
        pose: 4,
        event: protocol::can::TriggerEvent::ExactStop,
    }];
    s
}

fn python_ok() -> bool {
    match Command::new("python3")
        .args(["-c", "import mcap, jsonschema, google.protobuf"])
        .output()
    {
        Ok(o) if o.status.success() => true,
        _ => {
            println!(
                "SKIPPED the Python checks: python3 with the mcap and jsonschema packages is not available (pip install mcap jsonschema; .ci/run does)"
            );
            false
        }
    }
}

fn read_log(path: &Path) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/read_log.py");
    let out = Command::new("python3")
        .arg(script)
        .arg(path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "read_log.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn start_daemon(config: &Path) -> Child {
    start_daemon_notified(config, None)
}

/// The daemon, with systemd's `NOTIFY_SOCKET` at `notify` when given.
fn start_daemon_notified(config: &Path, notify: Option<&Path>) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_metrolog"));
    if let Some(n) = notify {
        cmd.env("NOTIFY_SOCKET", n);
    }
    cmd.args(["run", "--config"])
        .arg(config)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn the_log(dir: &Path) -> PathBuf {
    let logs: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    assert_eq!(logs.len(), 1, "one log per run: {logs:?}");
    logs[0].clone()
}

/// Runs the daemon on `cfg` until the simulated program ends it (`stop_at_program_end`), with a
/// deadline far past the program; its stderr, once it exited 0.
async fn run_program_to_end(cfg: &Path, sim: &sim::SimHandle) -> String {
    run_program_to_end_notified(cfg, sim, None).await
}

/// [`run_program_to_end`] with systemd's notifications sent to `notify`.
async fn run_program_to_end_notified(
    cfg: &Path,
    sim: &sim::SimHandle,
    notify: Option<&Path>,
) -> String {
    let mut child = start_daemon_notified(cfg, notify);
    let limit = Duration::from_secs_f64(sim.program_duration_s() + 40.0);
    let status = wait_exit(&mut child, limit).await;
    let stderr = child.wait_with_output_stderr();
    assert!(
        status.success(),
        "metrolog run failed ({status}):\n{stderr}"
    );
    stderr
}

async fn wait_exit(child: &mut Child, limit: Duration) -> std::process::ExitStatus {
    let t0 = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st;
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output_stderr();
            panic!("metrolog run did not end within {limit:?}; stderr:\n{out}");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// The poses the terminal lines tell ("pose k of 11 (target X … Y … Z … mm): …"), each
/// target checked against the scenario's program (the simulator's, not the daemon's, table).
fn pose_lines(stderr: &str, sc: &Scenario) -> std::collections::BTreeSet<u64> {
    let n = sc.program.poses.len();
    let mut told = std::collections::BTreeSet::new();
    for line in stderr.lines().filter(|l| l.contains(" INFO ")) {
        let Some(rest) = line.split(" pose ").nth(1) else {
            continue;
        };
        let Some((k, rest)) = rest.split_once(&format!(" of {n}")) else {
            continue;
        };
        let Ok(k) = k.parse::<u64>() else { continue };
        if let Some(p) = (k as usize)
            .checked_sub(1)
            .and_then(|i| sc.program.poses.get(i))
        {
            let target = format!(
                " (target X {:.3} Y {:.3} Z {:.3} mm): ",
                p.x_mm, p.y_mm, p.z_mm
            );
            assert!(rest.starts_with(&target), "{line}: target {target}");
        }
        told.insert(k);
    }
    assert!(!told.is_empty(), "no pose lines: {stderr}");
    told
}

/// systemd's notifications, read as they come from a socket the test binds (a full datagram
/// queue would block the daemon's sends).
struct Notifications {
    listening: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: std::thread::JoinHandle<Vec<String>>,
}

impl Notifications {
    fn listen(path: &Path) -> Notifications {
        let sock = std::os::unix::net::UnixDatagram::bind(path).unwrap();
        sock.set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        let listening = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
        let on = listening.clone();
        let thread = std::thread::spawn(move || {
            let mut states = Vec::new();
            let mut buf = vec![0u8; 65536];
            while on.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(n) = sock.recv(&mut buf) {
                    states.push(String::from_utf8_lossy(&buf[..n]).to_string());
                }
            }
            states
        });
        Notifications { listening, thread }
    }

    fn stop(self) -> Vec<String> {
        self.listening
            .store(false, std::sync::atomic::Ordering::Relaxed);
        self.thread.join().unwrap()
    }
}

trait StderrText {
    fn wait_with_output_stderr(&mut self) -> String;
}
impl StderrText for Child {
    fn wait_with_output_stderr(&mut self) -> String {
        use std::io::Read;
        let _ = self.wait();
        let mut s = String::new();
        if let Some(mut e) = self.stderr.take() {
            let _ = e.read_to_string(&mut s);
        }
        s
    }
}

/// Poll the run's log in `dir` (its intact prefix, as written so far) until a message on
/// `topic` is in it or `limit` has passed. Returns whether it was seen.
async fn wait_for_topic(dir: &Path, topic: &str, limit: Duration) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < limit {
        let log = std::fs::read_dir(dir).ok().and_then(|d| {
            d.filter_map(|e| e.ok().map(|e| e.path()))
                .find(|p| p.extension().is_some_and(|e| e == "mcap"))
        });
        if let Some(log) = log {
            let mut found = false;
            let _ = metrolog_log::reader::read_log_until(&log, |item| match item {
                metrolog_log::reader::LogItem::Message { topic: t, .. } if t == topic => {
                    found = true;
                    std::ops::ControlFlow::Break(())
                }
                _ => std::ops::ControlFlow::Continue(()),
            });
            if found {
                return true;
            }
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    false
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_with_faults_ends_at_program_end_and_the_log_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    let sim = sim::Sim::start(scenario(), &ports).unwrap();
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, true).unwrap();
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();

    let notify_path = dir.path().join("notify.sock");
    let notify = Notifications::listen(&notify_path);
    let stderr = run_program_to_end_notified(&cfg, &sim, Some(&notify_path)).await;
    assert!(stderr.contains("program end"), "{stderr}");
    let told = pose_lines(&stderr, &scenario());
    let states = notify.stop();
    // systemd's STATUS= leads with "pose k/N" once a pose is done, then the alarms (or ok),
    // then the device faults; the stream defects are named apart.
    assert!(
        states.iter().any(|s| s.contains("STATUS=pose ")
            && s.contains("/11, ")
            && s.contains(", faults ")
            && s.contains("stream defects ")),
        "{states:?}"
    );
    let record = sim.record();
    sim.shutdown().await;
    let log = the_log(&logs);
    if !python_ok() {
        return;
    }
    let r = read_log(&log);
    assert_eq!(r["complete"], true, "{}", r["read_error"]);
    assert_eq!(r["n_errors"], 0, "schema violations: {}", r["errors"]);
    for topic in [
        "/interferometer/position",
        "/interferometer/environment",
        "/capball/sample",
        "/psd/sample",
        "/cnc/trigger",
        "/pose",
        "/status",
        "/event",
    ] {
        assert!(
            r["counts"][topic].as_u64().unwrap_or(0) > 0,
            "no {topic}: {}",
            r["counts"]
        );
    }
    let att: Vec<&str> = r["attachments"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_str().unwrap())
        .collect();
    assert!(
        att.contains(&"metrolog.toml") && att.contains(&"trajectory.csv"),
        "{att:?}"
    );

    // Pose values against the simulation's truth (independent: the sim's physics at mid-dwell).
    // Under heavy load (issue 15, load average ~22) this failed before the triggers were
    // placed by their NC clock: "ok" values ~100 mm off, of the next or the previous pose. The
    // same log replayed with the trigger placed at its arrival time shows what that did in
    // this run (printed: the evidence the timing model is the cause; docs/design.md).
    let poses = r["poses"].as_array().unwrap();
    // One terminal line per pose that has values in the log, no more.
    let logged: std::collections::BTreeSet<u64> =
        poses.iter().filter_map(|p| p["pose"].as_u64()).collect();
    assert_eq!(told, logged, "pose lines on stderr vs poses in the log");
    let (ok, wrong) = check_poses(poses, &record);
    let (delays, arrival_wrong) = arrival_model_in_this_run(&log, &record);
    println!(
        "trigger frames' arrival delay (host arrival - NC-fitted time), ms: max {:.1}, \
         exact stops {:?}; placed by arrival this run would have had {} misplaced ok values{}",
        delays.iter().map(|d| d.1).fold(0.0, f64::max),
        delays,
        arrival_wrong.len(),
        if arrival_wrong.is_empty() {
            String::new()
        } else {
            format!(":\n{}", arrival_wrong.join("\n"))
        }
    );
    if !wrong.is_empty() {
        // Keep the log for a look (the temporary directory goes with the panic).
        let kept = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("svc_hil-misplaced-{}.mcap", std::process::id()));
        let _ = std::fs::copy(&log, &kept);
        println!("log kept: {}", kept.display());
    }
    assert!(wrong.is_empty(), "{}\n{}", wrong.join("\n"), r["poses"]);
    // What was not ok, and why (the status says it: gap, away, too few samples...).
    let not_ok: Vec<String> = r["poses"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["status"] != "ok")
        .map(|p| {
            format!(
                "{} pose {}: {} (n {})",
                p["instrument"], p["pose"], p["status"], p["n"]
            )
        })
        .collect();
    // Every pose the simulated instrument streamed through (each sample of its dwell sent
    // intact or with a single injected fault; none lost to "not connected" — the CB-3's
    // unplug and its reconnect, which takes seconds on a loaded machine — or to a port the
    // host did not read in time) has an "ok" value; pose 4 (no exact stop) and the reversal
    // (no dwell) never do. The injected single-sample faults cannot keep a 0.4 s dwell from
    // a steady window, so one pose of slack is plenty.
    for (inst, dev) in [
        ("interferometer", sim::Device::Interferometer),
        ("capball", sim::Device::Capball),
        ("psd", sim::Device::Psd),
    ] {
        let streamed = streamed_poses(&record, dev);
        let got = ok.get(inst).copied().unwrap_or(0);
        assert!(
            streamed.len() >= 3 && got + 1 >= streamed.len(),
            "{inst}: {got} ok of {} streamed poses {streamed:?}; {ok:?}; not ok: {not_ok:#?}",
            streamed.len()
        );
    }

    // The counters saw the injected faults.
    let st = &r["last_status"]["instruments"];
    let rej = |i: &str| -> u64 {
        st[i]["rejections"]
            .as_object()
            .unwrap()
            .values()
            .map(|v| v.as_u64().unwrap())
            .sum()
    };
    let f = &record.interferometer.faults;
    assert!(
        rej("interferometer") >= f.bad_checksum + f.garbage.min(1),
        "{st}"
    );
    assert!(
        st["interferometer"]["gap_samples"].as_u64().unwrap() >= f.dropped,
        "{st}"
    );
    let f = &record.capball.faults;
    assert!(rej("capball") >= f.bad_checksum, "{st}");
    assert!(
        st["capball"]["reconnects"].as_u64().unwrap() >= 1,
        "the unplugged CB-3 came back: {st}"
    );
    assert_eq!(
        st["interferometer"]["dropped"], 0,
        "nothing dropped between drivers and pipeline"
    );
}

/// The pose values against the simulation's truth: "ok" values per instrument, and those
/// farther from the truth than the sim's noise allows. Pose 4 (exact stop left out) must
/// not be "ok".
fn check_poses(
    poses: &[Value],
    record: &sim::Record,
) -> (std::collections::BTreeMap<String, usize>, Vec<String>) {
    let home_x_mm = scenario().program.home.x_mm;
    let mut ok = std::collections::BTreeMap::<String, usize>::new();
    let mut wrong = Vec::new();
    for p in poses {
        let inst = p["instrument"].as_str().unwrap();
        let pose = p["pose"].as_u64().unwrap() as u16;
        let status = p["status"].as_str().unwrap();
        if pose == 4 {
            assert_ne!(status, "ok", "pose 4 lost its exact stop: {p}");
        }
        if status != "ok" {
            continue;
        }
        *ok.entry(inst.to_string()).or_default() += 1;
        let t = record.truth.iter().find(|t| t.pose == pose).unwrap();
        let m = |k: &str| p["mean"][k].as_f64().unwrap();
        // Tolerances: the sim's noise averaged over 150 samples is far below these; what is
        // left is the slow drift between the window (early in the dwell) and mid-dwell.
        let (err, tol) = match inst {
            "interferometer" => (
                (m("position_um") - ((t.x_mm - home_x_mm) * 1e3 + t.deviation_um)).abs(),
                0.5,
            ),
            "capball" => (
                ((m("ex_um") - t.capball_e_um[0]).powi(2)
                    + (m("ey_um") - t.capball_e_um[1]).powi(2)
                    + (m("ez_um") - t.capball_e_um[2]).powi(2))
                .sqrt(),
                0.1,
            ),
            "psd" => (
                ((m("x_um") - t.psd_x_um).powi(2) + (m("y_um") - t.psd_y_um).powi(2)).sqrt(),
                0.1,
            ),
            other => panic!("unknown instrument {other}"),
        };
        if err >= tol {
            wrong.push(format!("{inst} pose {pose}: {err} µm from the truth: {p}"));
        }
    }
    (ok, wrong)
}

/// The measurable poses (a dwell, an exact stop) through whose whole dwell the simulated
/// device sent every sample (intact, or with a single-sample injected fault).
fn streamed_poses(record: &sim::Record, dev: sim::Device) -> Vec<u16> {
    let start = record.program_started_s.unwrap_or(0.0);
    let samples = &record.device(dev).samples;
    record
        .truth
        .iter()
        .filter(|t| t.pose != 4 && t.dwell_end_s - t.exact_stop_s > 0.1)
        .filter(|t| {
            let (a, b) = (start + t.exact_stop_s, start + t.dwell_end_s);
            let mut inside = samples.iter().filter(|s| s.true_s >= a && s.true_s <= b);
            let mut n = 0;
            let all = inside.all(|s| {
                n += 1;
                !matches!(s.fate, sim::Fate::NotConnected | sim::Fate::Overflow)
            });
            all && n > 0
        })
        .map(|t| t.pose)
        .collect()
}

/// The log of this run replayed with the triggers at their arrival time (the timing model
/// before the NC clock fit): the exact stops' arrival delays (pose, ms) as the NC clock fit
/// sees them, and the misplaced "ok" values that model gives.
fn arrival_model_in_this_run(log: &Path, record: &sim::Record) -> (Vec<(u16, f64)>, Vec<String>) {
    use metrolog::cmd::replay::{ReplayOptions, replay};
    use metrolog_log::TriggerTime;
    let opts = ReplayOptions {
        trigger_time: Some(TriggerTime::Arrival),
        ..ReplayOptions::default()
    };
    let out = replay(log, &opts).unwrap();
    let poses: Vec<Value> = out
        .replayed
        .iter()
        .map(|(_, p)| serde_json::to_value(p).unwrap())
        .collect();
    let (_, wrong) = check_poses(&poses, record);
    let mut nc = detect::NcClock::default();
    let mut delays = Vec::new();
    let _ = metrolog_log::reader::read_log_until(log, |item| {
        if let metrolog_log::reader::LogItem::Message {
            topic: "/cnc/trigger",
            encoding,
            log_ns,
            data,
        } = item
            && let Ok(Some(metrolog_log::topics::LogMessage::Trigger(msg))) =
                metrolog_log::topics::decode_message("/cnc/trigger", encoding, log_ns, data)
        {
            // A trigger's log time is its host arrival time.
            let t = nc.time(msg.nc_ms, log_ns);
            if msg.event == protocol::can::TriggerEvent::ExactStop {
                delays.push((msg.pose, (log_ns - t) as f64 / 1e6));
            }
        }
        std::ops::ControlFlow::Continue(())
    });
    (delays, wrong)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_killed_in_the_middle_leaves_a_readable_log() {
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    let mut sc = scenario();
    sc.faults = Default::default();
    let sim = sim::Sim::start(sc, &ports).unwrap();
    // The run goes on after the program end (the instruments keep streaming), so the kill
    // always comes in the middle of it: on a loaded machine the first /pose can reach the file
    // only as the 6 s program ends, and a run that stops there would have closed its file.
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, false).unwrap();
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();

    let mut child = start_daemon(&cfg);
    tokio::time::timeout(Duration::from_secs(60), sim.wait_program_started())
        .await
        .expect("the program started");
    // Kill once the log on disk holds a pose value (not after a fixed time: on a loaded
    // machine the first pose can take longer to reach the file). The deadline is generous.
    let seen = wait_for_topic(&logs, "/pose", Duration::from_secs(90)).await;
    assert!(
        seen,
        "no /pose reached the log within 90 s of the program start; stderr:\n{}",
        child.wait_with_output_stderr()
    );
    assert!(
        child.try_wait().unwrap().is_none(),
        "still running before the kill"
    );
    let kill_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGKILL,
    )
    .unwrap();
    let status = child.wait().unwrap();
    assert!(!status.success());
    sim.shutdown().await;
    let log = the_log(&logs);
    if !python_ok() {
        return;
    }
    let r = read_log(&log);
    assert_eq!(
        r["complete"], false,
        "a killed writer cannot have closed the file"
    );
    assert_eq!(
        r["n_errors"], 0,
        "schema violations in the prefix: {}",
        r["errors"]
    );
    assert!(
        r["counts"]["/interferometer/position"]
            .as_u64()
            .unwrap_or(0)
            > 10_000,
        "{}",
        r["counts"]
    );
    assert!(
        r["counts"]["/pose"].as_u64().unwrap_or(0) > 0,
        "{}",
        r["counts"]
    );
    let last_ns = r["last_ns"].as_u64().unwrap();
    let lost_s = kill_ns.saturating_sub(last_ns) as f64 / 1e9;
    // Chunks are flushed at least once a second.
    assert!(lost_s < 2.0, "the log ends {lost_s:.2} s before the kill");
}

/// A small tmpfs mounted for the life of the value (unmounted on drop).
struct SmallFs(PathBuf);

impl SmallFs {
    /// Mount a tmpfs of `size` (e.g. "1m") on `dir`; None (with the reason) when not root or
    /// the mount is refused (a container without CAP_SYS_ADMIN).
    fn mount(dir: &Path, size: &str) -> Result<SmallFs, String> {
        // SAFETY: geteuid has no preconditions and cannot fail.
        if unsafe { libc::geteuid() } != 0 {
            return Err("not root".into());
        }
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir)
            .output()
            .map_err(|e| format!("mount: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "mount refused: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
        Ok(SmallFs(dir.to_path_buf()))
    }
}

impl Drop for SmallFs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// A full disk: the daemon writes its log to a 1 MiB tmpfs while the instruments stream at
/// full rates. At the first failed write the run stops: exit 74 (EX_IOERR) within the deadline
/// (it does not spin on the failing write), the journal (stderr) and systemd's STATUS (read
/// from a NOTIFY_SOCKET the test binds) say so, and the file's prefix reads.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn full_disk_stops_the_run_with_exit_74_and_a_readable_log() {
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    std::fs::create_dir_all(&logs).unwrap();
    let _fs = match SmallFs::mount(&logs, "1m") {
        Ok(fs) => fs,
        Err(why) => {
            println!("SKIPPED the disk-full test: cannot mount a small tmpfs ({why}); run as root");
            return;
        }
    };
    let mut sc = scenario();
    sc.faults = Default::default();
    let sim = sim::Sim::start(sc, &ports).unwrap();
    // The run would go on past program end: only the full disk can end it.
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, false).unwrap();
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();
    let notify_path = dir.path().join("notify.sock");
    let notify = std::os::unix::net::UnixDatagram::bind(&notify_path).unwrap();
    // Read the notifications as they come, like systemd: a full datagram queue would block
    // the daemon's sends.
    notify
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let listening = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let listener = {
        let listening = listening.clone();
        std::thread::spawn(move || {
            let mut states = Vec::new();
            let mut buf = vec![0u8; 65536];
            while listening.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(n) = notify.recv(&mut buf) {
                    states.push(String::from_utf8_lossy(&buf[..n]).to_string());
                }
            }
            states
        })
    };

    let mut child = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["run", "--config"])
        .arg(&cfg)
        .env("RUST_LOG", "info")
        .env("NOTIFY_SOCKET", &notify_path)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = wait_exit(&mut child, Duration::from_secs(180)).await;
    let stderr = child.wait_with_output_stderr();
    sim.shutdown().await;
    assert_eq!(
        status.code(),
        Some(metrolog::exit::IO_ERROR as i32),
        "{status}\n{stderr}"
    );
    assert!(
        stderr.contains("stopping the run") && stderr.contains("No space left on device"),
        "{stderr}"
    );
    listening.store(false, std::sync::atomic::Ordering::Relaxed);
    let states = listener.join().unwrap();
    assert!(
        states.iter().any(|s| s.contains("READY=1")),
        "READY before the failure: {states:?}"
    );
    assert!(
        states
            .iter()
            .any(|s| s.contains("STATUS=LOG WRITE FAILED, run stopped")),
        "systemd's STATUS says the log failed: {states:?}"
    );
    // The prefix reads with our reader (and, where Python is, with the mcap package).
    let log = the_log(&logs);
    let mut topics = std::collections::BTreeSet::new();
    let summary = metrolog_log::read_log(&log, |item| {
        if let metrolog_log::LogItem::Message { topic, .. } = item {
            topics.insert(topic.to_string());
        }
    })
    .unwrap();
    // The prefix up to the failed write reads whole (how many messages fill 1 MiB depends
    // on the batch sizes, which grow on a loaded machine: 191 seen under load, > 1000 quiet).
    assert!(
        summary.messages > 10 && summary.bytes_read + 64 * 1024 >= summary.file_bytes,
        "{summary:?}"
    );
    assert!(topics.contains("/interferometer/position"), "{topics:?}");
    if python_ok() {
        let r = read_log(&log);
        assert_eq!(r["n_errors"], 0, "schema violations: {}", r["errors"]);
        assert!(
            r["counts"]["/interferometer/position"]
                .as_u64()
                .unwrap_or(0)
                > 1000,
            "{}",
            r["counts"]
        );
    }
}

/// The LI-80 unplugged for 0.4 s during pose 2 of the ISO 230-2 run: after the reconnect its
/// lengths are from another zero, so no later interferometer pose value is `ok` (they are
/// `datum_lost`), every `ok` value is next to the simulation's truth (checked by the
/// independent Python reader), and `metrolog analyze positioning` refuses the run, naming the
/// pose, instead of computing R and A from two zeros.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn interferometer_unplug_loses_the_datum_and_the_analysis_refuses_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    let mut sc = scenario();
    sc.faults.unplugs = vec![Unplug {
        device: Device::Interferometer,
        at_s: 0.75,
        duration_s: 0.4,
    }];
    let sim = sim::Sim::start(sc, &ports).unwrap();
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, true).unwrap();
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();
    run_program_to_end(&cfg, &sim).await;
    let record = sim.record();
    sim.shutdown().await;
    let log = the_log(&logs);

    let contents = metrolog_analysis::LogContents::read(&log).unwrap();
    let li: Vec<&metrolog_log::topics::PoseMsg> = contents
        .poses
        .iter()
        .map(|p| &p.msg)
        .filter(|p| p.instrument == types::Instrument::Interferometer)
        .collect();
    let statuses: Vec<(u32, &str)> = li.iter().map(|p| (p.pose, p.status.name())).collect();
    let first_lost = li
        .iter()
        .filter(|p| p.status == types::PoseStatus::DatumLost)
        .map(|p| p.pose)
        .min()
        .unwrap_or_else(|| panic!("no datum_lost pose after the unplug: {statuses:?}"));
    // While the LI-80 is away its poses are `device_away` (the reconnect can take seconds on a
    // loaded machine); from the reconnect on, `datum_lost`. Never `ok` again after the unplug.
    let first_not_ok = li
        .iter()
        .filter(|p| p.status != types::PoseStatus::Ok)
        .map(|p| p.pose)
        .min()
        .unwrap();
    assert!(first_not_ok <= 3, "{statuses:?}");
    assert!(
        li.iter()
            .all(|p| p.status != types::PoseStatus::Ok || p.pose < first_not_ok),
        "an ok value after the unplug: {statuses:?}"
    );
    if python_ok() {
        let r = read_log(&log);
        let (_, wrong) = check_poses(r["poses"].as_array().unwrap(), &record);
        assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    }

    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["analyze", "positioning"])
        .arg(&log)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains(&format!("lost its datum at pose {first_lost}")),
        "{err}"
    );
    println!("interferometer poses: {statuses:?}\nanalyze positioning: {err}");
}

/// Retention on a real small file system (a 4 MiB tmpfs; root only): three old runs of 1 MiB
/// leave about 1 MB free; with `min_free_gb = 0.0025` the start deletes the oldest two (free
/// space read by statvfs after each) and keeps the newest, before the new run's log is created.
#[test]
fn retention_frees_a_small_file_system_oldest_run_first() {
    let dir = tempfile::tempdir().unwrap();
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&logs).unwrap();
    let _fs = match SmallFs::mount(&logs, "4m") {
        Ok(fs) => fs,
        Err(why) => {
            println!("SKIPPED the retention test: cannot mount a small tmpfs ({why}); run as root");
            return;
        }
    };
    let now = std::time::SystemTime::now();
    let names = [
        "metrolog-m-1.mcap",
        "metrolog-m-2.mcap",
        "metrolog-m-3.mcap",
    ];
    for (k, name) in names.iter().enumerate() {
        let p = logs.join(name);
        std::fs::write(&p, vec![7u8; 1 << 20]).unwrap();
        let age = Duration::from_secs(86_400 * (3 - k as u64));
        std::fs::File::options()
            .write(true)
            .open(&p)
            .unwrap()
            .set_modified(now - age)
            .unwrap();
    }
    let (out, err) = run_config(
        dir.path(),
        &format!(
            "[run]\nmachine = \"m\"\noutput_dir = {:?}\nconnect_timeout_s = 1\n[storage]\nmin_free_gb = 0.0025\nwarn_free_gb = 0\n[interferometer]\nport = \"/dev/null\"\n",
            logs.display().to_string()
        ),
    );
    assert_eq!(
        out.status.code(),
        Some(metrolog::exit::NOTHING_CONNECTED as i32),
        "{err}"
    );
    let deleted: Vec<&str> = err
        .lines()
        .filter(|l| l.contains("retention: deleted"))
        .collect();
    assert_eq!(deleted.len(), 2, "{err}");
    assert!(
        deleted[0].contains(names[0]) && deleted[1].contains(names[1]),
        "{err}"
    );
    assert!(!logs.join(names[0]).exists() && !logs.join(names[1]).exists());
    assert!(logs.join(names[2]).exists());
    let s = nix::sys::statvfs::statvfs(&logs).unwrap();
    let free = s.blocks_available() as u64 * s.fragment_size() as u64;
    assert!(free >= 2_000_000, "{free}");
}

/// Old runs on a small file system (a 16 MiB tmpfs; root only): three runs of 4 MiB, the
/// oldest split in two parts, leave about 4 MB free.
fn old_runs(logs: &Path) -> Vec<(&'static str, Vec<&'static str>)> {
    let runs = vec![
        (
            "metrolog-m-20260101T000000Z",
            vec![
                "metrolog-m-20260101T000000Z-p0001.mcap",
                "metrolog-m-20260101T000000Z-p0002.mcap",
            ],
        ),
        (
            "metrolog-m-20260102T000000Z",
            vec!["metrolog-m-20260102T000000Z.mcap"],
        ),
        (
            "metrolog-m-20260103T000000Z",
            vec!["metrolog-m-20260103T000000Z.mcap"],
        ),
    ];
    let now = std::time::SystemTime::now();
    for (k, (_, files)) in runs.iter().enumerate() {
        for f in files {
            let p = logs.join(f);
            std::fs::write(&p, vec![7u8; (4 << 20) / files.len()]).unwrap();
            let age = Duration::from_secs(86_400 * (3 - k as u64));
            std::fs::File::options()
                .write(true)
                .open(&p)
                .unwrap()
                .set_modified(now - age)
                .unwrap();
        }
    }
    runs
}

/// The bytes of the files of the current run (`metrolog-m-2…-pNNNN.mcap` not among `old`).
fn current_parts(logs: &Path, old: &[&str]) -> Vec<(PathBuf, u64)> {
    let mut v: Vec<(PathBuf, u64)> = std::fs::read_dir(logs)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            n.contains("-p0") && !old.iter().any(|o| n.starts_with(o))
        })
        .map(|e| (e.path(), e.metadata().map(|m| m.len()).unwrap_or(0)))
        .collect();
    v.sort();
    v
}

/// A split run keeps running on a small file system while retention frees the old runs: on a
/// 16 MiB tmpfs with about 4 MB free and `min_free_gb = 0.0035`, the run (at full rates, in
/// parts of 1 MB) writes more than was free at its start; retention deletes the old runs
/// whole, oldest first (both parts of the split one), never a part of the current run, and
/// the run is never stopped for space (it ends at SIGTERM with exit 0; every part there and
/// read as one run). Without the retention the run stops at ENOSPC (exit 74): the disk-full
/// test above.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_split_run_keeps_running_while_retention_frees_old_runs() {
    let dir = tempfile::tempdir().unwrap();
    let ports = dir.path().join("ports");
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    std::fs::create_dir_all(&logs).unwrap();
    let _fs = match SmallFs::mount(&logs, "16m") {
        Ok(fs) => fs,
        Err(why) => {
            println!(
                "SKIPPED the split retention test: cannot mount a small tmpfs ({why}); run as root"
            );
            return;
        }
    };
    let old = old_runs(&logs);
    let old_names: Vec<&str> = old.iter().map(|(r, _)| *r).collect();
    let free_at_start = {
        let s = nix::sys::statvfs::statvfs(&logs).unwrap();
        s.blocks_available() as u64 * s.fragment_size() as u64
    };
    let mut sc = scenario();
    sc.faults = Default::default();
    let sim = sim::Sim::start(sc, &ports).unwrap();
    let mut toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, false).unwrap();
    toml += "\n[storage]\nmin_free_gb = 0.0035\nwarn_free_gb = 0\nsplit_mb = 1\n";
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();
    let mut child = start_daemon(&cfg);
    // Until the run has written 1.5× what was free at its start (or it ended).
    let t0 = Instant::now();
    let written = loop {
        let w: u64 = current_parts(&logs, &old_names).iter().map(|p| p.1).sum();
        if w > free_at_start * 3 / 2 || child.try_wait().unwrap().is_some() {
            break w;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "the run wrote only {w} bytes in 300 s"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert!(
        child.try_wait().unwrap().is_none(),
        "the run ended by itself after {written} bytes:\n{}",
        child.wait_with_output_stderr()
    );
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    let status = wait_exit(&mut child, Duration::from_secs(60)).await;
    let stderr = child.wait_with_output_stderr();
    sim.shutdown().await;
    assert!(status.success(), "{status}\n{stderr}");
    assert!(!stderr.contains("No space left"), "{stderr}");

    // The current run: parts 1..n, none missing, read as one run (our reader, from part 2).
    let parts = current_parts(&logs, &old_names);
    assert!(parts.len() >= 4, "{parts:?}");
    let (mut messages, mut statuses) = (0, 0u64);
    let summary = metrolog_log::read_log(&parts[1].0, |item| {
        if let metrolog_log::LogItem::Message { topic, .. } = item {
            messages += 1;
            statuses += u64::from(topic == "/status");
        }
    })
    .unwrap();
    assert!(
        summary.error.is_none() && summary.clean_close,
        "{summary:?}"
    );
    let files: Vec<PathBuf> = parts.iter().map(|p| p.0.clone()).collect();
    assert_eq!(summary.parts, files);
    assert!(messages > 1000, "{messages}");
    // Each part alone, read by the independent Python reader: closed, schema-valid, with the
    // run metadata and the config and trajectory; their /status records add up to the run's.
    if python_ok() {
        let mut py_statuses = 0;
        for (p, _) in &parts {
            let r = read_log(p);
            assert_eq!(r["complete"], true, "{p:?}: {}", r["read_error"]);
            assert_eq!(r["n_errors"], 0, "{p:?}: {}", r["errors"]);
            let att = r["attachments"].to_string();
            assert!(
                att.contains("metrolog.toml") && att.contains("trajectory.csv"),
                "{p:?}: {att}"
            );
            assert!(!r["metadata"]["metrolog.run"].is_null(), "{p:?}");
            py_statuses += r["counts"]["/status"].as_u64().unwrap_or(0);
        }
        assert_eq!(py_statuses, statuses);
    }

    // Retention deleted old runs whole, oldest first, and nothing of the current run.
    let deleted: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("retention: deleted"))
        .collect();
    assert!(!deleted.is_empty(), "{stderr}");
    for (k, line) in deleted.iter().enumerate() {
        assert!(line.contains(old_names[k]), "{k}: {line}\n{stderr}");
    }
    assert!(deleted[0].contains("all 2 parts"), "{}", deleted[0]);
    let left: Vec<String> = std::fs::read_dir(&logs)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| old_names.iter().any(|o| n.starts_with(o)))
        .collect();
    for (run, files) in &old[..deleted.len()] {
        assert!(!left.iter().any(|n| n.starts_with(run)), "{run}: {left:?}");
        assert!(files.iter().all(|f| !logs.join(f).exists()));
    }
    println!(
        "free at start {free_at_start} B; the run wrote {written} B in {} parts; retention: {deleted:?}",
        parts.len()
    );
}

/// A full disk with nothing retention may delete: the start exits 73 with what to do and
/// leaves no empty log behind (a 1 MiB tmpfs filled by another file; root only).
#[test]
fn a_full_disk_refuses_the_start_without_an_empty_log() {
    let dir = tempfile::tempdir().unwrap();
    let logs = dir.path().join("logs");
    std::fs::create_dir_all(&logs).unwrap();
    let _fs = match SmallFs::mount(&logs, "1m") {
        Ok(fs) => fs,
        Err(why) => {
            println!(
                "SKIPPED the full-disk start test: cannot mount a small tmpfs ({why}); run as root"
            );
            return;
        }
    };
    // Fill it (the write stops at ENOSPC).
    let filler = logs.join("other-data.bin");
    let _ = std::fs::write(&filler, vec![1u8; 2 << 20]);
    let (out, err) = run_config(
        dir.path(),
        &format!(
            "[run]\nmachine = \"m\"\noutput_dir = {:?}\n[interferometer]\nport = \"/dev/null\"\n",
            logs.display().to_string()
        ),
    );
    assert_eq!(
        out.status.code(),
        Some(metrolog::exit::CANT_CREATE as i32),
        "{err}"
    );
    assert!(
        err.contains("a run needs at least 256 KiB to start"),
        "{err}"
    );
    let names: Vec<String> = std::fs::read_dir(&logs)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["other-data.bin"]);
}

/// `metrolog run` on the config `text`, written to `dir/m.toml`: its output and its stderr.
fn run_config(dir: &Path, text: &str) -> (std::process::Output, String) {
    let cfg = dir.join("m.toml");
    std::fs::write(&cfg, text).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["run", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    (out, err)
}

// ---------------------------------------------------------------------------------------------
// Datum epochs (issue 26, docs/design.md "Datum epochs"): reconnects, a beam break and a
// service restart mid-program, with reference poses at X 0.

/// Three bidirectional cycles over X 100 and 200 mm (0 → 100 → 200 → 300 → 200 → 100 → 0),
/// poses 1, 7, 13, 19 at X 0 (the datum position) with a longer dwell: the reference poses.
/// No stream faults; the scenario's other settings as [`scenario`].
fn datum_scenario() -> Scenario {
    let mut s = scenario();
    s.faults = Default::default();
    let row = s.program.poses[0];
    let cycle = [0.0, 100.0, 200.0, 300.0, 200.0, 100.0];
    let mut poses: Vec<sim::scenario::PoseRow> = (0..3)
        .flat_map(|_| cycle)
        .chain([0.0])
        .map(|x_mm| sim::scenario::PoseRow {
            x_mm,
            y_mm: 0.0,
            z_mm: 0.0,
            dwell_s: (x_mm == 0.0).then_some(0.8),
            ..row
        })
        .collect();
    poses[0].move_s = Some(0.1);
    s.program.poses = poses;
    s
}

const REFERENCE_POSES: &str = "reference_pose = [1, 7, 13, 19]\nreference_settle_s = 0.2\n";

/// Program time of pose `k`'s motion start plus `after_s`.
fn during_pose(sc: &Scenario, k: usize, after_s: f64) -> f64 {
    sim::Schedule::new(&sc.program).poses[k - 1].motion_start_s + after_s
}

/// The simulator and a daemon config for it with the reference poses (and `stop`: end at the
/// program end).
fn datum_setup(sc: Scenario, dir: &Path, stop: bool) -> (sim::SimHandle, PathBuf, PathBuf) {
    let ports = dir.join("ports");
    let logs = dir.join("logs");
    std::fs::create_dir_all(&ports).unwrap();
    let sim = sim::Sim::start(sc, &ports).unwrap();
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, stop)
        .unwrap()
        .replacen(
            "stop_at_program_end",
            &format!("{REFERENCE_POSES}stop_at_program_end"),
            1,
        );
    let cfg = dir.join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();
    (sim, cfg, logs)
}

/// Every `ok` value of the log against the simulation's truth, the interferometer's by its
/// datum epoch: epoch 0 from home, a re-referenced epoch from where the axis stood when the
/// simulated LI-80 took that `DATUM` (its record, the truth's deviation at that visit moved by
/// its drift to that instant). The DATUM must fall inside the reference pose's dwell, after
/// the exact stop (the axis stood). Returns the `ok` values per instrument and the wrong ones.
fn wrong_ok_values(
    log: &metrolog_analysis::LogContents,
    record: &sim::Record,
    sc: &Scenario,
) -> (std::collections::BTreeMap<&'static str, usize>, Vec<String>) {
    let home_x_mm = sc.program.home.x_mm;
    let start = record.program_started_s.unwrap_or(0.0);
    let truth = |k: u32| {
        record
            .truth
            .iter()
            .find(|t| u32::from(t.pose) == k)
            .unwrap()
    };
    let length = |k: u32, at_s: f64| {
        let t = truth(k);
        (t.x_mm - home_x_mm) * 1e3 + t.deviation_um + t.deviation_rate_um_per_s * (at_s - t.eval_s)
    };
    let mut zero = std::collections::BTreeMap::from([(0u32, 0.0)]);
    for r in &log.rereferences {
        let t = truth(r.pose);
        let datum_s = record
            .interferometer
            .datums_s
            .iter()
            .map(|d| d - start)
            .find(|d| *d > t.exact_stop_s && *d < t.dwell_end_s)
            .unwrap_or_else(|| panic!("no DATUM in pose {}'s dwell: {r:?}", r.pose));
        zero.insert(r.epoch, length(r.pose, datum_s));
    }
    let mut ok = std::collections::BTreeMap::new();
    let mut wrong = Vec::new();
    for p in log.poses.iter().map(|p| &p.msg) {
        if p.status != types::PoseStatus::Ok {
            continue;
        }
        *ok.entry(p.instrument.name()).or_default() += 1;
        let t = truth(p.pose);
        let m = |k: &str| p.mean[k];
        let (err, tol) = match p.instrument {
            types::Instrument::Interferometer => match zero.get(&p.datum_epoch) {
                Some(z) => (
                    (m("position_um") - (length(p.pose, t.eval_s) - z)).abs(),
                    0.5,
                ),
                None => (f64::INFINITY, 0.0),
            },
            types::Instrument::Capball => (
                (0..3)
                    .map(|i| (m(["ex_um", "ey_um", "ez_um"][i]) - t.capball_e_um[i]).powi(2))
                    .sum::<f64>()
                    .sqrt(),
                0.1,
            ),
            _ => (
                ((m("x_um") - t.psd_x_um).powi(2) + (m("y_um") - t.psd_y_um).powi(2)).sqrt(),
                0.1,
            ),
        };
        if err >= tol {
            wrong.push(format!("{p:?}: {err} µm from the truth"));
        }
    }
    (ok, wrong)
}

/// The interferometer's pose values: (pose, status, epoch).
fn li80_values(log: &metrolog_analysis::LogContents) -> Vec<(u32, &'static str, u32)> {
    log.poses
        .iter()
        .map(|p| &p.msg)
        .filter(|p| p.instrument == types::Instrument::Interferometer)
        .map(|p| (p.pose, p.status.name(), p.datum_epoch))
        .collect()
}

/// `metrolog analyze positioning LOG`: exit status, stdout, stderr.
fn analyze_positioning(log: &Path) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["analyze", "positioning"])
        .arg(log)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// After a lost datum the interferometer's values are `datum_lost` up to the reference visit,
/// `ok` and right from the next pose on, in epoch 1; the operator was told (ERROR, then WARN
/// with the pose); the positioning analysis takes the run with the lost poses as missing.
fn assert_re_referenced(log: &Path, record: &sim::Record, sc: &Scenario, stderr: &str) {
    let contents = metrolog_analysis::LogContents::read(log).unwrap();
    let li = li80_values(&contents);
    let (ok, wrong) = wrong_ok_values(&contents, record, sc);
    assert!(wrong.is_empty(), "{}\n{li:?}", wrong.join("\n"));
    assert!(
        stderr.contains("the interferometer's datum is lost; datum epoch 1 begins"),
        "{stderr}"
    );
    let r = contents.rereferences.first().unwrap_or_else(|| {
        panic!("no re-reference in /event: {li:?}\n{stderr}");
    });
    assert_eq!(r.epoch, 1, "{:?}", contents.rereferences);
    assert!(
        stderr.contains(&format!("interferometer re-referenced at pose {}", r.pose)),
        "{stderr}"
    );
    // The reference visit is not a measurement; every pose after it is ok in epoch 1.
    assert!(li.contains(&(r.pose, "datum_lost", 1)), "{li:?}");
    let after: Vec<_> = li.iter().filter(|v| v.0 > r.pose).collect();
    assert!(!after.is_empty(), "{li:?}");
    assert!(after.iter().all(|v| v.1 == "ok" && v.2 == 1), "{li:?}");
    println!("interferometer values: {li:?}\nok per instrument: {ok:?}");
    print_alarm_lines(stderr);
    // The epochs come from the logged samples and triggers alone: a replay gives every pose
    // value again, byte for byte.
    let rep = metrolog::cmd::replay::replay(log, &Default::default()).unwrap();
    assert_eq!(
        (rep.identical, rep.replayed.len()),
        (rep.logged.len(), rep.logged.len()),
        "replay differs"
    );
    let (success, out, err) = analyze_positioning(log);
    assert!(
        success,
        "analyze positioning refused the re-referenced run: {err}"
    );
    assert!(out.contains("are datum_lost"), "{out}");
    println!("analyze positioning:\n{out}");
}

/// The LI-80 unplugged for 0.4 s during pose 2: epoch 1 from the reconnect, re-referenced at
/// the next reference pose reached after it; the page/`STATUS=` alarm says `datum lost`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn datum_li80_unplug_is_re_referenced_at_the_reference_pose() {
    let dir = tempfile::tempdir().unwrap();
    let mut sc = datum_scenario();
    sc.faults.unplugs = vec![Unplug {
        device: Device::Interferometer,
        at_s: during_pose(&sc, 2, 0.05),
        duration_s: 0.4,
    }];
    let (sim, cfg, logs) = datum_setup(sc.clone(), dir.path(), true);
    let notify_path = dir.path().join("notify.sock");
    let notify = Notifications::listen(&notify_path);
    let stderr = run_program_to_end_notified(&cfg, &sim, Some(&notify_path)).await;
    let states = notify.stop();
    let record = sim.record();
    sim.shutdown().await;
    assert_re_referenced(&the_log(&logs), &record, &sc, &stderr);
    // Told in STATUS= (once a second): the driver's alarm while its epoch is lost, or, on a
    // loaded host whose ticks missed that interval, the pose values' one.
    assert!(
        states.iter().any(|s| {
            s.contains("interferometer datum lost (epoch 1): re-reference")
                || s.contains(", interferometer datum lost, ")
        }),
        "{states:?}"
    );
}

/// A 0.3 s beam interruption in pose 3 (the device's own "datum lost" flag): the same.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn datum_beam_break_is_re_referenced_at_the_reference_pose() {
    let dir = tempfile::tempdir().unwrap();
    let mut sc = datum_scenario();
    sc.faults.beam_interruptions = vec![sim::scenario::Timed {
        at_s: during_pose(&sc, 3, 0.2),
        duration_s: 0.3,
    }];
    let (sim, cfg, logs) = datum_setup(sc.clone(), dir.path(), true);
    let stderr = run_program_to_end(&cfg, &sim).await;
    assert!(stderr.contains("interferometer beam lost"), "{stderr}");
    let record = sim.record();
    sim.shutdown().await;
    assert_re_referenced(&the_log(&logs), &record, &sc, &stderr);
}

/// The service SIGKILLed once the first pose value is in its log, and started again while the
/// program goes on: the new service's first trigger is not the program start, so the datum it
/// took at connect is not the run's (epoch 1, lost) until the next reference pose. Its log
/// has no ok interferometer value before that, and right ones after.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn datum_service_restart_mid_program_is_re_referenced() {
    let dir = tempfile::tempdir().unwrap();
    let sc = datum_scenario();
    let (sim, cfg, logs) = datum_setup(sc.clone(), dir.path(), true);
    let mut first = start_daemon(&cfg);
    tokio::time::timeout(Duration::from_secs(60), sim.wait_program_started())
        .await
        .expect("the program started");
    let seen = wait_for_topic(&logs, "/pose", Duration::from_secs(60)).await;
    assert!(seen, "no /pose in the first run's log");
    first.kill().unwrap();
    let _ = first.wait();
    let first_log = the_log(&logs);
    let mut second = start_daemon(&cfg);
    let limit = Duration::from_secs_f64(sim.program_duration_s() + 40.0);
    let status = wait_exit(&mut second, limit).await;
    let stderr = second.wait_with_output_stderr();
    assert!(
        status.success(),
        "the restarted run failed ({status}):\n{stderr}"
    );
    assert!(
        stderr.contains("the service started mid-program"),
        "{stderr}"
    );
    let record = sim.record();
    sim.shutdown().await;
    let log = std::fs::read_dir(&logs)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "mcap") && *p != first_log)
        .expect("the restarted service's log");
    assert_re_referenced(&log, &record, &sc, &stderr);
    // The killed service's log: its prefix reads, and its ok values are right too.
    let killed = metrolog_analysis::LogContents::read(&first_log).unwrap();
    let (ok, wrong) = wrong_ok_values(&killed, &record, &sc);
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    println!("the killed service's log: ok per instrument {ok:?}");
}

/// The CB-3 and the PSD unplugged (pose 2 and pose 4): their zero is physical (no host tare),
/// so their values after the reconnect are ok and next to the truth; the interferometer keeps
/// its datum (no datum_lost anywhere).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn datum_capball_and_psd_unplugs_keep_their_values_right() {
    let dir = tempfile::tempdir().unwrap();
    let mut sc = datum_scenario();
    sc.faults.unplugs = vec![
        Unplug {
            device: Device::Capball,
            at_s: during_pose(&sc, 2, 0.05),
            duration_s: 0.4,
        },
        Unplug {
            device: Device::Psd,
            at_s: during_pose(&sc, 4, 0.05),
            duration_s: 0.4,
        },
    ];
    let (sim, cfg, logs) = datum_setup(sc.clone(), dir.path(), true);
    let stderr = run_program_to_end(&cfg, &sim).await;
    let record = sim.record();
    sim.shutdown().await;
    let contents = metrolog_analysis::LogContents::read(&the_log(&logs)).unwrap();
    let (ok, wrong) = wrong_ok_values(&contents, &record, &sc);
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    // Both came back and gave ok values after their unplug (poses 8 on: after pose 7).
    for inst in [types::Instrument::Capball, types::Instrument::Psd] {
        let late_ok = contents
            .poses
            .iter()
            .filter(|p| p.msg.instrument == inst && p.msg.pose >= 8)
            .filter(|p| p.msg.status == types::PoseStatus::Ok)
            .count();
        assert!(
            late_ok >= 5,
            "{inst:?}: {late_ok} ok values after pose 7; {ok:?}"
        );
    }
    assert!(
        contents
            .poses
            .iter()
            .all(|p| p.msg.status != types::PoseStatus::DatumLost),
        "a datum_lost value without an interferometer fault"
    );
    assert!(contents.rereferences.is_empty());
    // The run holds where the interferometer must read at each pose: an `ok` value more than
    // 2 mm from it (a dwell on another pose's samples) would have been `off_target`.
    let detector: types::DetectorSettings =
        serde_json::from_str(&contents.run_metadata["detector"]).unwrap();
    let targets = detector.position_targets.expect("no position targets");
    assert_eq!(targets.targets_um.len(), sc.program.poses.len());
    // The operator was told of both unplugs.
    assert!(
        stderr.matches("reconnect").count() + stderr.matches("connected").count() >= 2,
        "{stderr}"
    );
    println!("ok per instrument: {ok:?}");
    print_alarm_lines(&stderr);
}

/// The WARN and ERROR lines of a run (what the operator was told), for the test's output.
fn print_alarm_lines(stderr: &str) {
    for l in stderr
        .lines()
        .filter(|l| l.contains("WARN") || l.contains("ERROR"))
    {
        println!("  told: {l}");
    }
}
