//! The live view (docs/live-view.md) during a simulated run, checked from outside:
//!
//! 1. Foxglove's own protocol client (npm `@foxglove/ws-protocol`, `tests/js/live_client.cjs`)
//!    subscribes to every advertised channel before the CNC program starts; every message it
//!    receives must be in the log, byte for byte, on the same topic at the same log time, its
//!    protobuf messages must decode with the advertised schemas, and it must receive every
//!    `/pose` of the log (unless the daemon reported skipping messages for it).
//! 2. The operator page rendered by headless Chromium (driven through the DevTools protocol by
//!    `tests/js/render_page.cjs`, which waits until the page shows pose rows) shows pose values,
//!    which must be pose values of the log; its screenshot is kept in the test's target
//!    directory (`live_page_chromium.png`).
//!
//! Needs node with the npm packages `.ci/run` installs into `.ci/npm`, and `chromium`; without
//! them the parts say so and skip, except in CI (`CI` set), where they fail.

use std::collections::{BTreeMap, HashSet};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use metrolog_log::topics::PoseMsg;
use serde_json::Value;

mod log_common;

/// Generous: a loaded 2-core CI runner; every wait ends as soon as its condition holds.
const LIMIT: Duration = Duration::from_secs(120);

fn skip_or_fail(msg: &str) {
    assert!(std::env::var_os("CI").is_none(), "{msg}");
    println!("SKIPPED: {msg}");
}

fn node_modules() -> Option<PathBuf> {
    let dir = match std::env::var_os("METROLOG_NPM_DIR") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../.ci/npm"),
    };
    let modules = dir.join("node_modules");
    let node = Command::new("node").arg("--version").output().is_ok();
    if node && modules.join("@foxglove/ws-protocol").exists() && modules.join("ws").exists() {
        return Some(modules);
    }
    skip_or_fail(&format!(
        "the live client check needs node and the npm packages @foxglove/ws-protocol, ws and protobufjs in {} (.ci/run installs them)",
        modules.display()
    ));
    None
}

fn chromium() -> Option<PathBuf> {
    let found = ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .find(|c| {
            Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
        .map(PathBuf::from);
    if found.is_none() {
        skip_or_fail("the operator page check needs chromium (apt-get install chromium)");
    }
    found
}

/// The lines a child prints on one of its pipes, as they come, and all of them at the end.
fn lines_of(pipe: impl std::io::Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(pipe).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits for a line containing `needle` (keeping every line in `seen`).
fn wait_line(rx: &mpsc::Receiver<String>, needle: &str, seen: &mut Vec<String>) -> String {
    let t0 = std::time::Instant::now();
    while t0.elapsed() < LIMIT {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(l) => {
                seen.push(l.clone());
                if l.contains(needle) {
                    return l;
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
    }
    panic!("no line with {needle:?}; seen:\n{}", seen.join("\n"));
}

fn drain(rx: &mpsc::Receiver<String>, seen: &mut Vec<String>) {
    seen.extend(rx.iter());
}

/// Every message of the log: (topic, log time, bytes).
fn log_messages(path: &Path) -> Vec<(String, u64, Vec<u8>)> {
    let (v, summary) = log_common::messages(path);
    assert!(summary.clean_close, "{summary:?}");
    v
}

fn count(msgs: &[(String, u64, Vec<u8>)], topic: &str) -> usize {
    msgs.iter().filter(|m| m.0 == topic).count()
}

fn check_client(out: &str, log: &[(String, u64, Vec<u8>)], stderr: &str) {
    let r: Value = serde_json::from_str(out).unwrap();
    assert_eq!(r["problems"], serde_json::json!([]), "{}", r["problems"]);
    assert!(r["server"].as_str().unwrap().starts_with("metrolog"));
    let in_log: HashSet<(&str, u64, &[u8])> = log
        .iter()
        .map(|(t, ns, d)| (t.as_str(), *ns, d.as_slice()))
        .collect();
    let mut got: BTreeMap<String, usize> = BTreeMap::new();
    for m in r["received"].as_array().unwrap() {
        let topic = m["topic"].as_str().unwrap();
        let ns: u64 = m["log_ns"].as_str().unwrap().parse().unwrap();
        let data = data_encoding::BASE64
            .decode(m["data"].as_str().unwrap().as_bytes())
            .unwrap();
        assert!(
            in_log.contains(&(topic, ns, data.as_slice())),
            "{topic} at {ns} received but not in the log: {}",
            String::from_utf8_lossy(&data)
        );
        *got.entry(topic.to_string()).or_default() += 1;
    }
    println!("received by the Foxglove client: {got:?}");
    // The daemon says when it skipped messages for a slow client (a loaded machine).
    let skipped = stderr.lines().any(|l| {
        l.contains("skipped for it so far")
            || l.split("left; ")
                .nth(1)
                .and_then(|r| r.split(' ').next())
                .is_some_and(|n| n != "0")
    });
    let poses = count(log, "/pose");
    assert!(poses > 0);
    if skipped {
        assert!(got.get("/pose").copied().unwrap_or(0) > 0, "{stderr}");
    } else {
        assert_eq!(got.get("/pose").copied().unwrap_or(0), poses, "every /pose");
    }
    for topic in [
        "/status",
        "/event",
        "/cnc/trigger",
        "/interferometer/position",
    ] {
        assert!(
            got.get(topic).copied().unwrap_or(0) > 0,
            "nothing on {topic}"
        );
    }
    // Raw topics decimated to the default `raw_hz` of 10: received batches at least 100 ms
    // apart in log time, while the log holds batches closer than that. (Not a count ratio: on
    // a loaded machine the log's batches grow and fewer of them are written per second.)
    let raw = "/interferometer/position";
    let mut live_ns = received_ns(&r, raw);
    live_ns.sort_unstable();
    let closest = live_ns.windows(2).map(|w| w[1] - w[0]).min();
    assert!(
        closest.is_some_and(|d| d >= 100_000_000),
        "{raw} batches received {closest:?} ns apart"
    );
    let mut log_ns: Vec<u64> = log.iter().filter(|m| m.0 == raw).map(|m| m.1).collect();
    log_ns.sort_unstable();
    assert!(
        log_ns.windows(2).any(|w| w[1] - w[0] < 100_000_000),
        "the log's {raw} batches are all 100 ms apart: nothing to decimate"
    );
}

/// Log times of the messages on `topic` the client received.
fn received_ns(r: &Value, topic: &str) -> Vec<u64> {
    r["received"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["topic"] == topic)
        .map(|m| m["log_ns"].as_str().unwrap().parse().unwrap())
        .collect()
}

/// The value of `name="..."` in `s`.
fn attr<'a>(s: &'a str, name: &str) -> Option<&'a str> {
    let start = s.find(&format!("{name}=\""))? + name.len() + 2;
    s[start..].split('"').next()
}

/// Pose rows of the rendered page: (instrument, pose, channel, value as shown).
fn shown_poses(dom: &str) -> Vec<(String, u32, String, String)> {
    let mut v = Vec::new();
    for row in dom.split("<tr class=\"pose\"").skip(1) {
        let row = row.split("</tr>").next().unwrap_or("");
        let (Some(inst), Some(pose)) = (attr(row, "data-instrument"), attr(row, "data-pose"))
        else {
            continue;
        };
        for span in row.split("<span class=\"value\"").skip(1) {
            if let (Some(c), Some(x)) = (attr(span, "data-channel"), attr(span, "data-value")) {
                v.push((inst.into(), pose.parse().unwrap(), c.into(), x.into()));
            }
        }
    }
    v
}

/// The operator page rendered by Chromium once `selector` matches (`tests/js/render_page.cjs`
/// waits through the DevTools protocol): its HTML; the screenshot is kept as `shot`.
fn render_dom(bin: &Path, modules: &Path, url: &str, selector: &str, shot: &str) -> String {
    let shot = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(shot);
    let _ = std::fs::remove_file(&shot);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/js/render_page.cjs");
    let profile = tempfile::tempdir().unwrap();
    let out = Command::new("node")
        .arg(script)
        .arg(bin)
        .arg(url)
        .arg(selector)
        .arg(&shot)
        .arg(profile.path())
        .env("NODE_PATH", modules)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let png = std::fs::read(&shot).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{} bytes",
        png.len()
    );
    eprintln!("screenshot kept: {}", shot.display());
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The page once it shows pose rows.
fn render_page(bin: &Path, modules: &Path, url: &str) -> Vec<(String, u32, String, String)> {
    let dom = render_dom(
        bin,
        modules,
        url,
        "tr.pose span.value",
        "live_page_chromium.png",
    );
    let shown = shown_poses(&dom);
    assert!(!shown.is_empty(), "no pose value on the page");
    shown
}

fn check_page(shown: &[(String, u32, String, String)], log: &[(String, u64, Vec<u8>)]) {
    let poses: Vec<PoseMsg> = log
        .iter()
        .filter(|m| m.0 == "/pose")
        .map(|m| serde_json::from_slice(&m.2).unwrap())
        .collect();
    for (inst, pose, channel, value) in shown {
        let found = poses.iter().any(|p| {
            p.instrument.name() == inst
                && p.pose == *pose
                && p.mean
                    .get(channel)
                    .is_some_and(|x| format!("{x:.3}") == *value)
        });
        assert!(
            found,
            "the page shows {inst} pose {pose} {channel} = {value}, not in the log"
        );
    }
    println!("the page shows {} pose values, all in the log", shown.len());
}

/// A child killed if the test ends early (a failed assertion must not leave a daemon behind).
struct Reaped(Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `metrolog run --config CFG` with its stderr read line by line, once its live view listens:
/// the daemon, its stderr lines, the lines seen so far and the line with the page's address.
fn start_live(cfg: &Path) -> (Reaped, mpsc::Receiver<String>, Vec<String>, String) {
    let mut daemon = Reaped(
        Command::new(env!("CARGO_BIN_EXE_metrolog"))
            .args(["run", "--config"])
            .arg(cfg)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let err_rx = lines_of(daemon.0.stderr.take().unwrap());
    let mut err = Vec::new();
    let line = wait_line(&err_rx, "live view: operator page http://", &mut err);
    (daemon, err_rx, err, line)
}

/// The daemon on `toml` with its live view, then the simulator's program started once every
/// device is configured and the CAN channel open (a program start frame sent into a closed
/// channel would make the run start mid-program): as [`start_live`], with the page's address.
async fn run_program_live(
    dir: &Path,
    toml: &str,
    sim: &sim::SimHandle,
) -> (Reaped, mpsc::Receiver<String>, Vec<String>, String) {
    let cfg = dir.join("metrolog.toml");
    std::fs::write(&cfg, format!("{toml}\n[live]\nlisten = \"127.0.0.1:0\"\n")).unwrap();
    let (daemon, err_rx, err, line) = start_live(&cfg);
    let url = page_url(&line);
    tokio::time::timeout(LIMIT, sim.wait_active(&sim::Device::ALL))
        .await
        .expect("the daemon did not open every device");
    sim.start_program();
    (daemon, err_rx, err, url)
}

/// The operator page's address in the daemon's `live view: operator page URL …` line.
fn page_url(line: &str) -> String {
    line.split("page ")
        .nth(1)
        .unwrap()
        .split(' ')
        .next()
        .unwrap()
        .to_string()
}

fn sigterm(child: &Child) {
    let pid = libc::pid_t::try_from(child.id()).unwrap();
    // SAFETY: kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(pid, libc::SIGTERM) }, 0);
}

fn the_log(dir: &Path) -> PathBuf {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "mcap"))
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_live_view_streams_what_the_log_holds_and_the_page_shows_poses() {
    let modules = node_modules();
    let browser = chromium();
    let dir = tempfile::tempdir().unwrap();
    let (ports, logs) = (dir.path().join("ports"), dir.path().join("logs"));
    std::fs::create_dir_all(&ports).unwrap();
    let mut sc = sim::Scenario::demo();
    sc.program.poses.truncate(6);
    sc.program.start = sim::ProgramStart::Manual;
    let sim = sim::Sim::start(sc, &ports).unwrap();
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, false).unwrap();
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, format!("{toml}\n[live]\nlisten = \"127.0.0.1:0\"\n")).unwrap();

    let (mut daemon, err_rx, mut err, line) = start_live(&cfg);
    let addr = line
        .split("http://")
        .nth(1)
        .unwrap()
        .split('/')
        .next()
        .unwrap()
        .to_string();

    let mut client = modules.as_ref().map(|m| {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/js/live_client.cjs");
        let mut c = Command::new("node")
            .arg(script)
            .arg(format!("ws://{addr}"))
            .env("NODE_PATH", m)
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let rx = lines_of(c.stdout.take().unwrap());
        let mut out = Vec::new();
        wait_line(&rx, "subscribed", &mut out);
        (Reaped(c), rx)
    });
    // Every device configured and the CAN channel open (the program start frame is not sent
    // into a closed channel, which would make the run start mid-program).
    tokio::time::timeout(LIMIT, sim.wait_active(&sim::Device::ALL))
        .await
        .expect("the daemon did not open every device");
    sim.start_program();
    tokio::time::timeout(LIMIT, sim.program_done())
        .await
        .unwrap();

    let url = format!("http://{addr}/");
    let shown = match (&browser, &modules) {
        (Some(b), Some(m)) => Some(render_page(b, m, &url)),
        _ => None,
    };
    sigterm(&daemon.0);
    let status = daemon.0.wait().unwrap();
    drain(&err_rx, &mut err);
    let stderr = err.join("\n");
    assert!(status.success(), "{stderr}");
    sim.shutdown().await;
    let log = log_messages(&the_log(&logs));
    if let Some((c, rx)) = client.as_mut() {
        let mut out = Vec::new();
        let result = wait_line(rx, "\"received\"", &mut out);
        assert!(c.0.wait().unwrap().success());
        check_client(&result, &log, &stderr);
    }
    if let Some(shown) = shown {
        check_page(&shown, &log);
    }
}

/// Temperature rows of the rendered page: (sensor, value as shown).
fn shown_temperatures(dom: &str) -> Vec<(String, String)> {
    dom.split("<tr class=\"temp\"")
        .skip(1)
        .filter_map(|row| {
            let row = row.split("</tr>").next().unwrap_or("");
            Some((
                attr(row, "data-channel")?.into(),
                attr(row, "data-value")?.into(),
            ))
        })
        .collect()
}

/// The page shows the temperature module's channels by the names of `[temperature]`, each a
/// value of the log's `/temperature` (the page decodes the protobuf batch itself), an open
/// sensor as a fault; Foxglove's client decodes the live `/temperature` batches with the
/// advertised schema, each byte-identical to one of the log. The module is the simulated one
/// (`sim::modbus`), with a timeout, an exception and a bad CRC injected: each is counted once
/// in `/status`, and every other answer is a sample of the log.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_the_temperatures() {
    use sim::modbus::{ModbusFault, Reply};
    let (Some(modules), Some(browser)) = (node_modules(), chromium()) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (link, logs) = (dir.path().join("temp"), dir.path().join("logs"));
    let module = sim::modbus::ModbusModule::start(
        &link,
        sim::modbus::ModbusModuleConfig {
            unit: 4,
            channels: 3,
            ..Default::default()
        },
        std::sync::Arc::new(|t| vec![Some(20.0 + 0.1 * t), Some(-3.5), None]),
    )
    .unwrap();
    let mut toml = format!(
        "[run]\nmachine = \"m\"\noutput_dir = \"{}\"\n[live]\nlisten = \"127.0.0.1:0\"\n[temperature]\nport = \"{}\"\nunit = 4\npoll_period_s = 0.2\ntimeout_s = 2.0\n",
        logs.display(),
        link.display()
    );
    for name in ["spindle", "air", "open"] {
        toml += &format!("[[temperature.sensors]]\nname = \"{name}\"\n");
    }
    let cfg = dir.path().join("metrolog.toml");
    std::fs::write(&cfg, toml).unwrap();
    let (mut daemon, err_rx, mut err, line) = start_live(&cfg);
    let url = page_url(&line);
    let ws = url
        .replace("http://", "ws://")
        .trim_end_matches('/')
        .to_string();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/js/live_client.cjs");
    let mut client = Reaped(
        Command::new("node")
            .arg(script)
            .arg(&ws)
            .env("NODE_PATH", &modules)
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let client_rx = lines_of(client.0.stdout.take().unwrap());
    let mut client_out = Vec::new();
    wait_line(&client_rx, "subscribed", &mut client_out);
    module.inject([
        ModbusFault::NoAnswer,
        ModbusFault::Exception(protocol::modbus::exception::DEVICE_BUSY),
        ModbusFault::BadCrc,
    ]);
    let dom = render_dom(
        &browser,
        &modules,
        &url,
        "tr.temp td[data-value]",
        "live_page_temperatures.png",
    );
    // The faults are behind, and answers after them (at 5 polls a second).
    let t0 = std::time::Instant::now();
    while module
        .answered()
        .iter()
        .rev()
        .take_while(|a| matches!(a.reply, Reply::Registers(_)))
        .count()
        < 3
        || module.answered().len() < 8
    {
        assert!(t0.elapsed() < LIMIT, "{:?}", module.answered());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    sigterm(&daemon.0);
    let status = daemon.0.wait().unwrap();
    drain(&err_rx, &mut err);
    assert!(status.success(), "{}", err.join("\n"));
    let answered = module.answered();
    module.shutdown().await;
    let log = log_messages(&the_log(&logs));

    // Foxglove's client: no problem, /temperature live, each message one of the log's.
    let result = wait_line(&client_rx, "\"received\"", &mut client_out);
    assert!(client.0.wait().unwrap().success());
    let r: Value = serde_json::from_str(&result).unwrap();
    assert_eq!(r["problems"], serde_json::json!([]), "{}", r["problems"]);
    let live: Vec<&Value> = r["received"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["topic"] == "/temperature")
        .collect();
    assert!(!live.is_empty(), "no /temperature received live");
    for m in live {
        let ns: u64 = m["log_ns"].as_str().unwrap().parse().unwrap();
        let data = data_encoding::BASE64
            .decode(m["data"].as_str().unwrap().as_bytes())
            .unwrap();
        assert!(
            log.iter()
                .any(|(t, n, d)| t == "/temperature" && *n == ns && *d == data),
            "a /temperature at {ns} received live is not in the log"
        );
    }

    let shown = shown_temperatures(&dom);
    let names: Vec<&str> = shown.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["spindle", "air", "open"], "{dom}");
    assert_eq!(shown[1].1, "-3.50");
    assert_eq!(shown[2].1, "NaN");
    // The spindle value shown is one the log holds (to the page's two decimals).
    let spindle: f64 = shown[0].1.parse().unwrap();
    let mut logged = Vec::new();
    let mut last_status = None;
    for (topic, log_ns, data) in log.iter().cloned() {
        if topic == "/status" {
            last_status = Some(serde_json::from_slice::<Value>(&data).unwrap());
        }
        if let Ok(Some(metrolog_log::topics::LogMessage::Samples(ss))) =
            metrolog_log::topics::decode_message(&topic, "protobuf", log_ns, &data)
        {
            for s in ss {
                if let drivers::SampleValues::Temperature { values_c } = s.values {
                    logged.push(values_c[0]);
                }
            }
        }
    }
    assert!(!logged.is_empty(), "no /temperature in the log");
    // Each fault counted once; every register answer a sample (the last may have come while
    // the driver stopped), none lost.
    let c = &last_status.unwrap()["instruments"]["temperature"];
    for kind in ["timeout", "exception", "bad_crc"] {
        assert_eq!(c["rejections"][kind], 1, "{kind}: {c}");
    }
    let registers = answered
        .iter()
        .filter(|a| matches!(a.reply, Reply::Registers(_)))
        .count();
    assert!(
        logged.len() == registers || logged.len() + 1 == registers,
        "{} samples, {registers} answers",
        logged.len()
    );
    assert!(
        logged.iter().any(|v| (v - spindle).abs() <= 0.005 + 1e-9),
        "{spindle} is not among the logged {logged:?}"
    );
}

/// The trajectory file the simulator wrote, read here by hand: pose -> (x, y, z) mm.
fn trajectory_rows(path: &Path) -> BTreeMap<u32, [f64; 3]> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            let xyz = [1, 2, 3].map(|i| f[i].parse::<f64>().unwrap());
            (f[0].parse().unwrap(), xyz)
        })
        .collect()
}

/// The text of the first element of `dom` with `id="..."`'s attribute `name`.
fn attr_of_id<'a>(dom: &'a str, id: &str, name: &str) -> &'a str {
    let at = dom
        .find(&format!("id=\"{id}\""))
        .unwrap_or_else(|| panic!("no #{id}"));
    let start = dom[..at].rfind('<').unwrap();
    let tag = &dom[start..start + dom[start..].find('>').unwrap()];
    attr(tag, name).unwrap_or_else(|| panic!("no {name} on #{id}: {tag}"))
}

/// The essentials (alarms, the pose being measured, live readings, current pose, counters,
/// faults) lie inside the viewport of a 1280x800 Chromium window (1280x713 with headless
/// Chromium 13x's window frame): the page measures their boxes itself.
fn assert_fits(dom: &str) {
    let body = &dom[dom.find("<body").unwrap()..];
    let body = &body[..body.find('>').unwrap()];
    let viewport = attr(body, "data-viewport").unwrap_or("");
    let (w, h) = viewport.split_once('x').unwrap_or(("0", "0"));
    let (w, h): (u32, u32) = (w.parse().unwrap(), h.parse().unwrap());
    assert!(w == 1280 && (600..=800).contains(&h), "{body}");
    assert_eq!(
        attr(body, "data-outside"),
        Some(""),
        "outside the window: {body}"
    );
    println!("the essentials fit a {viewport} viewport");
}

/// The operator's screen during a run with faults: the pose being measured as "pose k of N"
/// with its target from the trajectory, alarms as banners (PSD unplugged, beam lost, datum
/// lost), the PSD's current pose no longer green, a live reading per instrument, the reconnect
/// in the faults list when the PSD is plugged in again, everything essential inside 1280x800.
/// Screenshots: `live_page_running.png`, `live_page_alarms.png`, `live_page_reconnect.png`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_the_pose_being_measured_and_alarms() {
    let (Some(modules), Some(browser)) = (node_modules(), chromium()) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (ports, logs) = (dir.path().join("ports"), dir.path().join("logs"));
    std::fs::create_dir_all(&ports).unwrap();
    let mut sc = sim::Scenario::demo();
    sc.program.start = sim::ProgramStart::Manual;
    sc.faults = Default::default();
    sc.faults.beam_interruptions = vec![sim::scenario::Timed {
        at_s: 4.0,
        duration_s: 600.0,
    }];
    let sim = sim::Sim::start(sc, &ports).unwrap();
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, false).unwrap();
    let trajectory = trajectory_rows(&ports.join("trajectory.csv"));
    let (mut daemon, err_rx, mut err, url) = run_program_live(dir.path(), &toml, &sim).await;
    let url = url.as_str();

    // Running: a PSD pose value is shown, the pose being measured with its target, and the
    // triggers are counted (they read 0 until the 256th trigger before).
    let dom = render_dom(
        &browser,
        &modules,
        url,
        "body:has(#posek[data-of]):has(#settle[data-last-counts*=\"psd:\"]):has(tr.counter[data-instrument=\"trigger\"]:not([data-samples=\"0\"])) tr.pose[data-instrument=\"psd\"]",
        "live_page_running.png",
    );
    assert_fits(&dom);
    let k: u32 = attr_of_id(&dom, "posek", "data-pose").parse().unwrap();
    let n: usize = attr_of_id(&dom, "posek", "data-of").parse().unwrap();
    assert_eq!(n, trajectory.len());
    let shown: Vec<f64> = attr_of_id(&dom, "target", "data-xyz")
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!(shown, trajectory[&k].to_vec(), "target of pose {k}");
    // A finished dwell's samples per instrument, against the window of the config
    // ([detector] samples, 150 by default): every instrument delivered some.
    assert_eq!(attr_of_id(&dom, "settle", "data-window"), "150");
    let counts: BTreeMap<&str, u64> = attr_of_id(&dom, "settle", "data-last-counts")
        .split(',')
        .filter_map(|c| c.split_once(':'))
        .map(|(i, n)| (i, n.parse().unwrap()))
        .collect();
    // The beam breaks 4 s into the program; on a loaded host the page may be first read after
    // that, when the interferometer's last dwell had no valid sample (and the page says so).
    let beam_broken = dom.contains("data-kind=\"beam\"");
    for inst in ["interferometer", "capball", "psd"] {
        assert!(
            counts.get(inst).is_some_and(|n| *n > 0) || (inst == "interferometer" && beam_broken),
            "{inst}: {counts:?}"
        );
    }
    let value = attr_of_id(&dom, "tile-interferometer", "data-value");
    assert!(
        value.parse::<f64>().is_ok(),
        "interferometer reading {value}"
    );

    // The PSD unplugged and the beam broken: alarms, and the PSD's old pose not green.
    sim.unplug(sim::Device::Psd).await.unwrap();
    let dom = render_dom(
        &browser,
        &modules,
        url,
        "#alarms:has([data-kind=\"beam\"]):has([data-kind=\"datum\"]) [data-kind=\"unplugged\"]",
        "live_page_alarms.png",
    );
    assert_fits(&dom);
    assert!(dom.contains(">PSD UNPLUGGED since "), "{dom}");
    assert!(dom.contains(">BEAM LOST: interferometer signal "), "{dom}");
    // Invalid, whatever else the tile says: on a loaded machine the readings may also have
    // gone stale by the time the page is rendered ("tile invalid stale" in one CI run).
    let classes = attr_of_id(&dom, "tile-interferometer", "class");
    assert!(
        classes.split_whitespace().any(|c| c == "invalid"),
        "the reading is not marked invalid ({classes}): {dom}"
    );
    assert!(
        dom.contains("<tr class=\"pose old\" data-instrument=\"psd\""),
        "the PSD's old pose is still shown as current: {dom}"
    );

    // Plugged in again: the reconnect is in the faults list.
    sim.replug(sim::Device::Psd).await.unwrap();
    let dom = render_dom(
        &browser,
        &modules,
        url,
        "tr.fault[data-kind=\"reconnected\"][data-instrument=\"psd\"]",
        "live_page_reconnect.png",
    );
    assert_fits(&dom);
    assert!(dom.contains("data-kind=\"disconnected\" data-instrument=\"psd\""));
    // The beam break's loss of datum is in the faults list too (its `/event` of kind datum).
    assert!(
        dom.contains("data-kind=\"datum lost\" data-instrument=\"interferometer\""),
        "no datum lost in the faults list: {dom}"
    );
    sigterm(&daemon.0);
    let status = daemon.0.wait().unwrap();
    drain(&err_rx, &mut err);
    assert!(status.success(), "{}", err.join("\n"));
    sim.shutdown().await;
}

/// The program the machine runs is not the trajectory the daemon was given (every X 10 mm
/// off, as with a wrong trajectory file): every interferometer value is more than 2 mm from
/// its target, none is shown as a measurement, the page raises `OFF TARGET` and the terminal
/// says `off target at pose k`. Screenshot: `live_page_off_target.png`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_raises_off_target_when_values_are_not_their_poses() {
    let (Some(modules), Some(browser)) = (node_modules(), chromium()) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (ports, logs) = (dir.path().join("ports"), dir.path().join("logs"));
    std::fs::create_dir_all(&ports).unwrap();
    let mut sc = sim::Scenario::demo();
    sc.program.start = sim::ProgramStart::Manual;
    sc.faults = Default::default();
    let sim = sim::Sim::start(sc, &ports).unwrap();
    let toml = metrolog::cmd::sim::write_daemon_config(&sim, &ports, &logs, false).unwrap();
    // The daemon's trajectory: the simulator's, every X 10 mm further.
    let traj = ports.join("trajectory.csv");
    let text = std::fs::read_to_string(&traj).unwrap();
    let mut lines = text.lines();
    let mut shifted = format!("{}\n", lines.next().unwrap());
    for l in lines {
        let mut f: Vec<String> = l.split(',').map(str::to_string).collect();
        f[1] = (f[1].parse::<f64>().unwrap() + 10.0).to_string();
        shifted += &(f.join(",") + "\n");
    }
    std::fs::write(&traj, shifted).unwrap();
    let (mut daemon, err_rx, mut err, url) = run_program_live(dir.path(), &toml, &sim).await;
    let url = url.as_str();
    let said = wait_line(&err_rx, "interferometer: off target at pose", &mut err);
    let dom = render_dom(
        &browser,
        &modules,
        url,
        // The banner naming the interferometer's pose (a page that connected between the
        // interferometer's value and the CapBall's of the same dwell names only the latter
        // until the next pose's: seen in 2 of about 10 runs; why the first was not among the
        // latched values it got is not known).
        "#alarms [data-kind=\"target\"][data-pose]",
        "live_page_off_target.png",
    );
    assert_fits(&dom);
    assert!(
        dom.contains(">OFF TARGET: interferometer pose "),
        "no OFF TARGET banner: {dom}"
    );
    // No interferometer pose value on the page is shown as a measurement; they are off_target.
    let rows: Vec<&str> = dom
        .split("<tr class=\"pose\" data-instrument=\"interferometer\"")
        .skip(1)
        .map(|r| r.split("</tr>").next().unwrap_or(""))
        .collect();
    assert!(
        rows.iter().any(|r| r.contains(">off_target</td>")),
        "{said}\n{dom}"
    );
    assert!(
        !rows.iter().any(|r| r.contains(">ok</td>")),
        "{said}\n{dom}"
    );
    // The CapBall's and the PSD's values of those poses came from the same dwells: not ok.
    let off: Vec<&str> = rows
        .iter()
        .filter(|r| r.contains(">off_target</td>"))
        .filter_map(|r| attr(r, "data-pose"))
        .collect();
    for inst in ["capball", "psd"] {
        for row in dom
            .split(&format!("<tr class=\"pose\" data-instrument=\"{inst}\""))
            .skip(1)
            .map(|r| r.split("</tr>").next().unwrap_or(""))
            .filter(|r| attr(r, "data-pose").is_some_and(|p| off.contains(&p)))
        {
            assert!(!row.contains(">ok</td>"), "{inst}: {row}");
        }
    }
    sigterm(&daemon.0);
    let status = daemon.0.wait().unwrap();
    drain(&err_rx, &mut err);
    assert!(status.success(), "{}", err.join("\n"));
    sim.shutdown().await;
}
