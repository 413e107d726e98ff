//! A thermal run through the real daemon (`metrolog run`, the binary) against the simulator:
//! the simulated thermal machine (a two-node heat network integrated numerically, sim/thermal.rs)
//! seen by the CapBall at the measuring pose, visited every 3 min for 4 h of machine time
//! (compressed 480×), and the simulated Modbus module serving the head and air temperatures
//! and the spindle speed. `metrolog thermal fit` on the log must find the machine's thermal
//! sensitivities and the column's time constant, computed here in closed form from the
//! simulator's parameters (not by the analysis code):
//!
//! - `capball_ez` = `a_h`·(head rise): the head sensor, no lag, `a_h` µm/K;
//! - `capball_ex` = `a_c`·(column rise); with the air constant the column's ODE
//!   `C_c·dT_c/dt = G_hc·(T_h − T_c) − G_ca·(T_c − T_a)` makes its rise exactly the head's rise
//!   times `w = G_hc/(G_hc + G_ca)` through a first-order lag of `τ = C_c/(G_hc + G_ca)`; so the
//!   head sensor lagged by τ with `a_c·w` µm/K.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use metrolog::cmd::demo::thermal::{
    THERMAL_TIME_SCALE, demo_machine, start_module, thermal_config, thermal_scenario,
};
use metrolog::cmd::plan::thermal::{ThermalPlanOptions, plan_thermal};
use sim::Device;

/// The test's machine: the demo's, the air held constant (so the column's rise is exactly a
/// lag of the head's), nothing of the column seen along z.
fn machine() -> sim::thermal::ThermalMachine {
    let mut m = demo_machine();
    m.ambient_c = sim::scenario::Slow::constant(20.0);
    m.head_um_per_k = [0.0, 0.0, -1.2];
    m.column_um_per_k = [4.0, 0.0, 0.0];
    m
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

/// The term of `channel` on sensor `sensor` in the model JSON: (coefficient, τ heat, τ cool).
fn term(model: &serde_json::Value, channel: &str, sensor: &str) -> Option<(f64, f64, f64)> {
    let ch = model["channels"]
        .as_array()?
        .iter()
        .find(|c| c["channel"] == channel)?;
    let t = ch["terms"]
        .as_array()?
        .iter()
        .find(|t| t["input"]["kind"] == "sensor" && t["input"]["name"] == sensor)?;
    Some((
        t["coefficient"].as_f64()?,
        t["tau_heat_s"].as_f64()?,
        t["tau_cool_s"].as_f64()?,
    ))
}

/// Runs the daemon binary through the thermal run; returns the log and the CapBall samples the
/// simulator dropped because the host was not reading (its output buffer full).
fn run_daemon(dir: &Path) -> (PathBuf, u64) {
    let scale = THERMAL_TIME_SCALE;
    let plan = plan_thermal(&ThermalPlanOptions {
        measure: [120.0, 80.0, 100.0, 0.0, 0.0],
        park: [120.0, 80.0, 160.0, 0.0, 0.0],
        every_s: 180.0,
        duration_s: 4.0 * 3600.0,
        dwell_s: 0.2 * scale,
        move_s: 0.08 * scale,
        // At rest for the first 15 min (the references are taken there), 4000 rpm for 2 h,
        // then cooling.
        spindle: vec![(900.0, 4000.0), (8100.0, 0.0)],
    })
    .unwrap();
    let scenario = thermal_scenario(&plan, machine(), scale);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let ports = dir.join("ports");
        std::fs::create_dir_all(&ports).unwrap();
        let sim = sim::Sim::start(scenario, &ports).unwrap();
        let link = ports.join("temp");
        let module = start_module(&sim, &link).unwrap();
        let logs = dir.join("logs");
        let cfg = dir.join("metrolog.toml");
        std::fs::write(&cfg, thermal_config(&sim, &ports, &logs, &link).unwrap()).unwrap();
        let mut daemon = Command::new(env!("CARGO_BIN_EXE_metrolog"))
            .args(["run", "--config"])
            .arg(&cfg)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // The daemon has configured the CapBall and opened the CAN channel, and polls the
        // module: start the program, as an operator would.
        let ready = tokio::time::timeout(Duration::from_secs(30), async {
            sim.wait_active(&[Device::Capball, Device::Trigger]).await;
            while module.answered().is_empty() {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
        .await;
        assert!(
            ready.is_ok(),
            "the daemon did not configure the instruments"
        );
        sim.start_program();
        sim.program_done().await;
        // stop_at_program_end: the daemon ends by itself.
        let t0 = Instant::now();
        let status = loop {
            if let Some(s) = daemon.try_wait().unwrap() {
                break s;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "the daemon did not stop"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        };
        assert!(status.success(), "metrolog run failed");
        let overflow = sim.record().capball.faults.overflow;
        sim.shutdown().await;
        module.shutdown().await;
        (the_log(&logs), overflow)
    })
}

#[test]
fn thermal_fit_recovers_the_simulated_machines_sensitivities_and_time_constant() {
    let dir = tempfile::tempdir().unwrap();
    let (log, overflow) = run_daemon(dir.path());
    let model_path = dir.path().join("model.json");
    let out = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(["thermal", "fit"])
        .arg(&log)
        .arg("-o")
        .arg(&model_path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // 81 visits of the measuring pose, at least 80 % of them with every value ok. Time is
    // compressed 480× (0.2 s of real time per dwell, the most a 3-min period leaves beside the
    // moves): with this test sharing 2 cores with three others, 4 and then 10 of the 81 visits
    // ended `never_steady` (cause not established; the simulator runs in this test's process
    // and may fall behind its clock; or the daemon, starved, let the simulated CapBall's buffer
    // overflow: the count below says). The fit then holds out fewer blocks and says so. The
    // spindle speed came from the module's channel.
    let visits: usize = text
        .split(" samples over ")
        .next()
        .and_then(|h| h.rsplit('(').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(
        (65..=81).contains(&visits),
        "{visits} visits ({overflow} CapBall samples dropped by the simulator, buffer full): {text}"
    );
    if visits < 81 {
        eprintln!("{visits} of 81 visits ok; {overflow} CapBall samples dropped (buffer full)");
    }
    assert!(text.contains(", spindle speed"), "{text}");
    let model: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&model_path).unwrap()).unwrap();

    // Expected values in closed form from the simulator's parameters. Measured: ez −1.200
    // (−1.200), ex +1.095 µm/K (+1.091), τ 38.1 min (37.9); tolerances 2 %, 3 %, 5 %. (With
    // the spindle started at time 0 the references were taken on a warming head and ex came out
    // +10 %, τ +14 %: the run starts at rest.)
    let m = machine();
    let g = m.head_column_w_per_k + m.column_air_w_per_k;
    let tau_column_s = m.column_j_per_k / g;
    let ex_per_k = m.column_um_per_k[0] * m.head_column_w_per_k / g;
    let ez_per_k = m.head_um_per_k[2];
    eprintln!(
        "{text}\nexpected: capball_ez {ez_per_k:+.3} µm/K no lag; capball_ex {ex_per_k:+.3} µm/K, τ {:.1} min",
        tau_column_s / 60.0
    );

    let (k, th, tc) = term(&model, "capball_ez", "spindle_head").expect(&text);
    assert!(
        (k - ez_per_k).abs() < 0.02 * ez_per_k.abs(),
        "ez: {k} µm/K vs {ez_per_k}\n{text}"
    );
    assert!(th < 120.0 && tc < 120.0, "ez lags {th} / {tc} s\n{text}");

    let (k, th, tc) = term(&model, "capball_ex", "spindle_head").expect(&text);
    assert!(
        (k - ex_per_k).abs() < 0.03 * ex_per_k,
        "ex: {k} µm/K vs {ex_per_k}\n{text}"
    );
    for tau in [th, tc] {
        assert!(
            (tau - tau_column_s).abs() < 0.05 * tau_column_s,
            "ex: τ {tau} s vs {tau_column_s} s\n{text}"
        );
    }
}
