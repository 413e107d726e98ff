//! The demo's thermal segment: a thermal run ([`crate::cmd::plan::thermal`]) of the simulated
//! thermal machine ([`sim::thermal`]: a spindle speed schedule heating the head, the head
//! heating the column, the air varying), time compressed [`THERMAL_TIME_SCALE`]×, logged by
//! the very acquisition `metrolog run` runs with the CapBall as the probe nest and the
//! simulated Modbus temperature module (sensors plus the spindle speed channel); then `thermal
//! fit`, `thermal diagnose` and `analyze thermal` on the log.
//!
//! [`thermal_run`] is also what the daemon test of a thermal run drives (through the binary).

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use sim::Scenario;
use sim::modbus::{ModbusModule, ModbusModuleConfig};
use sim::scenario::{Faults, PoseRow};
use sim::thermal::{Node, SPINDLE_CHANNEL, SpindleStep, ThermalMachine, ThermalSensor};

use crate::cmd::plan::thermal::{MEASURE_POSE, PARK_POSE, ThermalPlan, ThermalPlanOptions};

/// Machine seconds per real second in the demo's thermal run: four hours in 30 s.
pub const THERMAL_TIME_SCALE: f64 = 480.0;
/// Real seconds of a dwell at the measuring pose (ringing settled, then 150 samples at
/// 20 kHz) and of a move, whatever the compression (the plan's dwell and move times are these
/// times the compression: 96 s and 38.4 s of machine time at 480×).
const DWELL_REAL_S: f64 = 0.2;
const MOVE_REAL_S: f64 = 0.08;
/// The CB-3's rate in a thermal run: a steady window of 150 samples lasts 7.5 ms, 5.4 s of
/// machine time at 480×, short enough for the thermal drift to stay below the noise.
pub const THERMAL_CB3_RATE_HZ: u32 = 20_000;
/// Register scale of the simulated module's temperatures, °C per count.
const MODULE_SCALE_C: f64 = 0.01;

/// The demo's machine: a 12 kJ/K spindle head heated by its bearings, a 25 kJ/K column, the
/// air swinging ±0.3 K over 4 h. Sensors on the head and in the air; none on the column (the
/// heat path no sensor sees).
pub fn demo_machine() -> ThermalMachine {
    ThermalMachine {
        ambient_c: sim::scenario::Slow {
            mean: 20.0,
            amplitude: 0.3,
            period_s: 4.0 * 3600.0,
            phase_rad: 0.0,
            drift_per_h: 0.0,
        },
        spindle: Vec::new(),
        heat_w_per_krpm2: 2.5,
        head_j_per_k: 12_000.0,
        column_j_per_k: 25_000.0,
        head_air_w_per_k: 5.0,
        head_column_w_per_k: 3.0,
        column_air_w_per_k: 8.0,
        head_um_per_k: [0.0, 0.0, -1.2],
        column_um_per_k: [4.0, 0.0, 0.0],
        sensors: vec![
            ThermalSensor {
                name: "spindle_head".into(),
                location: "spindle housing, front bearing".into(),
                node: Node::Head,
            },
            ThermalSensor {
                name: "air".into(),
                location: "air beside the machine".into(),
                node: Node::Air,
            },
        ],
        step_s: 2.0,
    }
}

/// The demo's plan: the CapBall pose every 3 min for 4 h (81 visits: the fit's 8 held-out
/// blocks need 80); the machine at rest for 15 min (where the fit takes its references),
/// the spindle at 2000 rpm for an hour, 5000 rpm for an hour and a half, then stopped.
pub fn demo_plan(time_scale: f64) -> anyhow::Result<ThermalPlan> {
    crate::cmd::plan::thermal::plan_thermal(&ThermalPlanOptions {
        measure: [120.0, 80.0, 100.0, 0.0, 0.0],
        park: [120.0, 80.0, 160.0, 0.0, 0.0],
        every_s: 180.0,
        duration_s: 4.0 * 3600.0,
        dwell_s: DWELL_REAL_S * time_scale,
        move_s: MOVE_REAL_S * time_scale,
        spindle: vec![(900.0, 2000.0), (4500.0, 5000.0), (9900.0, 0.0)],
    })
}

/// The scenario of a thermal run: the demo's instruments without their injected faults or the
/// CapBall's drifts, the plan's program compressed `time_scale`×, and `machine` with the
/// plan's spindle speeds.
pub fn thermal_scenario(
    plan: &ThermalPlan,
    mut machine: ThermalMachine,
    time_scale: f64,
) -> Scenario {
    let mut s = Scenario::demo();
    s.time_scale = time_scale;
    s.faults = Faults::default();
    s.ringing.amplitude_um = 0.5;
    let t = &mut s.capball.truth;
    t.cyclic_drift = None;
    t.drift_um_per_h = [0.0; 3];
    t.pose_noise_um = 0.0;
    let o = &plan.options;
    let row = |pose: u32, p: [f64; 5], move_s: f64, dwell_s: f64| PoseRow {
        pose: Some(pose as u16),
        x_mm: p[0],
        y_mm: p[1],
        z_mm: p[2],
        a_deg: p[3],
        c_deg: p[4],
        move_s: Some(move_s / time_scale),
        dwell_s: Some(dwell_s / time_scale),
    };
    s.program.poses = plan
        .cycles
        .iter()
        .flat_map(|c| {
            [
                row(MEASURE_POSE, o.measure, o.move_s, o.dwell_s),
                row(PARK_POSE, o.park, o.move_s, c.wait_s),
            ]
        })
        .collect();
    s.program.home = sim::Coords {
        x_mm: o.park[0],
        y_mm: o.park[1],
        z_mm: o.park[2],
        a_deg: o.park[3],
        c_deg: o.park[4],
    };
    // The plan counts from the first motion; the simulation from the program start.
    let lead = s.program.lead_in_s * time_scale;
    machine.spindle = plan
        .speed_steps()
        .iter()
        .map(|(at, rpm)| SpindleStep {
            at_s: if *at == 0.0 { 0.0 } else { at + lead },
            rpm: *rpm,
        })
        .collect();
    s.thermal = Some(machine);
    s
}

/// Starts the simulated temperature module of `sim`'s thermal machine behind `link`: one
/// channel per sensor (0.01 °C per count), then the spindle speed (1 rpm per count).
pub fn start_module(sim: &sim::SimHandle, link: &Path) -> anyhow::Result<ModbusModule> {
    let machine = sim
        .scenario()
        .thermal
        .as_ref()
        .context("the scenario has no [thermal] machine")?;
    let channels = sim.thermal_channels().context("no thermal machine")?;
    let n = machine.sensors.len();
    let mut scales = vec![None; n];
    scales.push(Some(1.0));
    let cfg = ModbusModuleConfig {
        channels: n as u16 + 1,
        scale_c: MODULE_SCALE_C,
        baud: 115_200,
        channel_scales: scales,
        ..ModbusModuleConfig::default()
    };
    ModbusModule::start(link, cfg, channels)
        .with_context(|| format!("cannot start the temperature module at {}", link.display()))
}

/// The config text without the sections named (the whole `[name]` block each).
fn without_sections(toml: &str, names: &[&str]) -> String {
    let mut skip = false;
    let mut out = String::new();
    for line in toml.lines() {
        let t = line.trim();
        if t.starts_with('[') {
            skip = names.iter().any(|n| t == format!("[{n}]"));
        }
        if !skip {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// A metrolog.toml for a thermal run on `sim`: the CapBall (at [`THERMAL_CB3_RATE_HZ`]), the
/// trigger and the temperature module behind `module_link`, polled every 50 ms (24 s of
/// machine time at 480×).
pub fn thermal_config(
    sim: &sim::SimHandle,
    ports: &Path,
    out: &Path,
    module_link: &Path,
) -> anyhow::Result<String> {
    let base = crate::cmd::sim_config::write_daemon_config_with_rates(
        sim,
        ports,
        out,
        true,
        [
            crate::cmd::sim_config::SIM_LI80_RATE_HZ,
            THERMAL_CB3_RATE_HZ,
            crate::cmd::sim_config::SIM_PSD_RATE_HZ,
        ],
    )?;
    let toml = without_sections(&base, &["interferometer", "psd"]);
    Ok(toml + &temperature_section(sim, module_link)?)
}

/// The `[temperature]` section of the simulated module behind `module_link` (started by
/// [`start_module`]): its sensors by name and location, then the spindle speed channel.
pub fn temperature_section(sim: &sim::SimHandle, module_link: &Path) -> anyhow::Result<String> {
    let mut toml = format!(
        "\n[temperature]\nport = {:?}\nunit = 1\nbaud = 115200\nscale_c = {MODULE_SCALE_C}\npoll_period_s = 0.05\ntimeout_s = 0.2\nsilence_s = 10\n",
        module_link.display().to_string()
    );
    let machine = sim
        .scenario()
        .thermal
        .as_ref()
        .context("the scenario has no [thermal] machine")?;
    for s in &machine.sensors {
        toml += &format!(
            "[[temperature.sensors]]\nname = {:?}\nlocation = {:?}\n",
            s.name, s.location
        );
    }
    toml += &format!(
        "[[temperature.sensors]]\nname = \"{SPINDLE_CHANNEL}\"\nlocation = \"spindle drive speed output on an analogue input, 1 rpm per count\"\nscale = 1.0\n"
    );
    Ok(toml)
}

/// The paths of a thermal run's config and log.
pub struct ThermalRun {
    pub config: PathBuf,
    pub log: PathBuf,
    pub visits: usize,
}

/// Runs `scenario` (with `[thermal]`) through the acquisition, in this process, the module on
/// `dir/ports/temp`; returns where the log is.
pub async fn thermal_run(scenario: Scenario, dir: &Path) -> anyhow::Result<ThermalRun> {
    let ports = dir.join("ports");
    std::fs::create_dir_all(&ports)
        .with_context(|| format!("cannot create {}", ports.display()))?;
    let visits = scenario
        .program
        .poses
        .iter()
        .filter(|p| p.pose == Some(MEASURE_POSE as u16))
        .count();
    let total = scenario.program.poses.len() as u64;
    let sim = sim::Sim::start(scenario, &ports)?;
    let link = ports.join("temp");
    let module = start_module(&sim, &link)?;
    let toml = thermal_config(&sim, &ports, dir, &link)?;
    let config = dir.join("metrolog.toml");
    std::fs::write(&config, &toml).with_context(|| format!("cannot write {}", config.display()))?;
    let cfg = crate::acquire::config::Config::load(&config)?;
    let (progress_tx, progress) = tokio::sync::watch::channel(Default::default());
    let stop = tokio_util::sync::CancellationToken::new();
    let run = crate::cmd::run::acquire(
        &cfg,
        crate::cmd::run::Acquire {
            notifier: crate::acquire::service::Notifier::from_env(),
            stop: stop.clone(),
            progress: Some(progress_tx),
            keep_poses: false,
            handle_signals: true,
        },
    );
    let instruments = cfg.instruments();
    let control = super::control(&sim, &instruments, progress, &stop, total);
    let (report, control) = tokio::join!(run, control);
    let report = report?;
    control?;
    sim.shutdown().await;
    module.shutdown().await;
    Ok(ThermalRun {
        config,
        log: report.log_path,
        visits,
    })
}

/// The thermal segment of `metrolog demo`: the run, then the analyses of its log.
pub async fn demo_segment(out: &Path) -> anyhow::Result<PathBuf> {
    let dir = out.join("thermal");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let plan = demo_plan(THERMAL_TIME_SCALE)?;
    let scenario = thermal_scenario(&plan, demo_machine(), THERMAL_TIME_SCALE);
    println!(
        "\nthermal run (simulated machine, TIME COMPRESSED {THERMAL_TIME_SCALE:.0}×: {:.1} h of machine time in about {:.0} s): {} visits of the CapBall pose, one every {:.0} min; spindle {}",
        plan.options.duration_s / 3600.0,
        scenario.program_duration_s(),
        plan.cycles.len(),
        plan.options.every_s / 60.0,
        plan.speed_steps()
            .iter()
            .map(|(t, r)| format!("{r:.0} rpm from {:.0} min", t / 60.0))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let r = thermal_run(scenario, &dir).await?;
    println!("  log: {} ({})", r.log.display(), r.config.display());
    print_machine_truth(&demo_machine());
    Ok(r.log)
}

/// What the simulated machine is, in the terms a fit can be held against.
fn print_machine_truth(m: &ThermalMachine) {
    let g = m.head_column_w_per_k + m.column_air_w_per_k;
    let tau_c = m.column_j_per_k / g;
    println!(
        "  simulation truth: head {:.0} kJ/K, column {:.0} kJ/K (no sensor), {:.1} W per (1000 rpm)²; \
         capball_ez = {:+.2} µm/K × head rise (sensor spindle_head, no lag); capball_ex = {:+.2} µm/K × column rise, \
         which lags the head by τ = C_c/(G_hc + G_ca) = {:.1} min with {:.3} µm/K of the head's rise and {:.3} µm/K of the air's",
        m.head_j_per_k / 1e3,
        m.column_j_per_k / 1e3,
        m.heat_w_per_krpm2,
        m.head_um_per_k[2],
        m.column_um_per_k[0],
        tau_c / 60.0,
        m.column_um_per_k[0] * m.head_column_w_per_k / g,
        m.column_um_per_k[0] * m.column_air_w_per_k / g,
    );
}

/// `thermal fit`, `thermal diagnose` and `analyze thermal` on the log, as those commands print
/// them.
pub fn print_analyses(log: &Path, out: &Path) {
    let model = out.join("thermal").join("thermal-model.json");
    println!(
        "\n$ metrolog thermal fit {} -o {}",
        log.display(),
        model.display()
    );
    report(crate::cmd::thermal::fit::run(
        crate::cmd::thermal::fit::Args {
            input: log.to_path_buf(),
            out: model,
            sensors: Vec::new(),
            blocks: None,
            max_terms: 6,
        },
    ));
    println!("\n$ metrolog thermal diagnose {}", log.display());
    report(crate::cmd::thermal::diagnose::run(
        crate::cmd::thermal::diagnose::Args {
            input: log.to_path_buf(),
            json: false,
        },
    ));
    println!("\n$ metrolog analyze thermal {}", log.display());
    report(crate::cmd::thermal::iso230_3::run(
        crate::cmd::thermal::iso230_3::Args {
            input: log.to_path_buf(),
            probes: None,
            probe_spacing_mm: None,
            json: false,
        },
    ));
}

fn report(r: anyhow::Result<()>) {
    if let Err(e) = r {
        println!("  could not run: {e:#}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scenario_repeats_the_two_poses_and_fits_the_plan() {
        let plan = demo_plan(THERMAL_TIME_SCALE).unwrap();
        let s = thermal_scenario(&plan, demo_machine(), THERMAL_TIME_SCALE);
        s.validate().unwrap();
        assert_eq!(s.program.poses.len(), 2 * plan.cycles.len());
        assert_eq!(s.trajectory_csv().lines().count(), 3);
        // The program's machine time is the plan's (plus the lead-in and -out).
        let machine = s.program_duration_s() * THERMAL_TIME_SCALE;
        let planned = plan.cycles.last().unwrap().park_s;
        assert!(
            (machine - planned - (s.program.lead_in_s + s.program.lead_out_s) * THERMAL_TIME_SCALE)
                .abs()
                < 1e-6,
            "{machine} vs {planned}"
        );
        assert!(s.program_duration_s() < 32.0, "{}", s.program_duration_s());
    }

    #[test]
    fn sections_are_dropped_whole() {
        let t = "[run]\na = 1\n[psd]\nport = 2\n[trigger]\nb = 3\n";
        assert_eq!(
            without_sections(t, &["psd"]),
            "[run]\na = 1\n[trigger]\nb = 3\n"
        );
    }
}
