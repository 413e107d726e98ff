//! `metrolog sim [--config SCENARIO]`: only the simulated instruments, on pseudo-terminals.
//! Prints their port paths and a metrolog.toml that reads them, and runs until Ctrl-C.

use std::path::{Path, PathBuf};

use anyhow::Context;
use sim::{Device, ProgramStart, Scenario, SimHandle};

pub use super::sim_config::{
    SIM_CB3_RATE_HZ, SIM_LI80_RATE_HZ, SIM_PSD_RATE_HZ, write_daemon_config,
    write_daemon_config_with_rates,
};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scenario file (sim/scenarios/demo.toml documents every key); the built-in demo scenario
    /// when absent.
    #[arg(long, short, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Directory for the port links (li80, cb3, psd2, slcan), the trajectory and the transform
    /// files.
    #[arg(long, value_name = "DIR", default_value = "./metrolog-sim")]
    pub dir: PathBuf,
    /// Seconds from the host opening the CAN channel to the CNC program start (used when the
    /// scenario starts its program manually, which only a caller in the same process can do).
    #[arg(long, default_value_t = 3.0)]
    pub start_delay_s: f64,
    /// A LinuxCNC comp file (`COMP_FILE_TYPE = 1`, e.g. the `x_comp.txt` of `metrolog
    /// compensate positioning --dialect linuxcnc`) loaded into the simulated X axis, applied
    /// as LinuxCNC applies it: the joint moves to the commanded position plus the trim of the
    /// direction of motion. Measure again and compare with `metrolog compensate verify`.
    #[arg(long, value_name = "FILE")]
    pub apply_comp: Option<PathBuf>,
    /// The demo's thermal run instead of the positioning program: its machine heated by the
    /// spindle, time compressed 480×, the CapBall at 20 kHz and the simulated Modbus
    /// temperature module (sensors and spindle speed).
    #[arg(long, conflicts_with = "config")]
    pub thermal: bool,
}

/// Reads a LinuxCNC type-1 comp file as LinuxCNC loads it ([`sim::ScrewComp`]); lines LinuxCNC
/// would ignore are reported on stderr.
pub fn load_comp_file(path: &Path) -> anyhow::Result<sim::ScrewComp> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let comp = sim::ScrewComp::from_linuxcnc(&text)
        .with_context(|| format!("{} is not a LinuxCNC comp file", path.display()))?;
    if comp.ignored_lines > 0 {
        eprintln!(
            "warning: {}: {} line(s) after triplet {} are not three numbers; LinuxCNC ignores them and so does the simulation",
            path.display(),
            comp.ignored_lines,
            comp.nominal_mm.len()
        );
    }
    Ok(comp)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    crate::acquire::service::init_tracing();
    let mut scenario = match &args.config {
        Some(p) => Scenario::load(p)?,
        None if args.thermal => {
            use crate::cmd::demo::thermal as th;
            let plan = th::demo_plan(th::THERMAL_TIME_SCALE)?;
            th::thermal_scenario(&plan, th::demo_machine(), th::THERMAL_TIME_SCALE)
        }
        None => Scenario::demo(),
    };
    if let Some(p) = &args.apply_comp {
        scenario.axis_comp = Some(load_comp_file(p)?);
    }
    if scenario.program.start == ProgramStart::Manual {
        // Nobody in this process can press start: start when the daemon opens the CAN channel.
        scenario.program.start = ProgramStart::OnCanOpen;
        scenario.program.start_delay_s = args.start_delay_s;
    }
    std::fs::create_dir_all(&args.dir)
        .with_context(|| format!("cannot create {}", args.dir.display()))?;
    let dir = std::fs::canonicalize(&args.dir)
        .with_context(|| format!("cannot resolve {}", args.dir.display()))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(async move {
        let sim = sim::Sim::start(scenario, &dir)?;
        println!("simulated instruments running:");
        if let Some(p) = &args.apply_comp {
            println!("  the X axis applies {} (LinuxCNC screw compensation)", p.display());
        }
        for d in [Device::Interferometer, Device::Capball, Device::Psd, Device::Trigger] {
            println!("  {:<15} {}", d.name(), sim.port(d).display());
        }
        let (toml, module) = daemon_config(&sim, &dir, args.thermal)?;
        let cfg_path = dir.join("metrolog.toml");
        std::fs::write(&cfg_path, &toml).with_context(|| format!("cannot write {}", cfg_path.display()))?;
        println!("\na metrolog config for them ({}):\n\n{toml}", cfg_path.display());
        println!(
            "run the daemon with:  metrolog run --config {}\nthe CNC program ({:.0} s) starts {:.0} s after the daemon opens the CAN channel. Ctrl-C stops.",
            cfg_path.display(),
            sim.program_duration_s(),
            sim.scenario().program.start_delay_s
        );
        {
        let signal = crate::acquire::service::shutdown_signal();
        tokio::pin!(signal);
        let done = sim.program_done();
        tokio::pin!(done);
        let mut finished = false;
        loop {
            tokio::select! {
                s = &mut signal => {
                    println!("{s}: stopping the simulated instruments");
                    break;
                }
                _ = &mut done, if !finished => {
                    finished = true;
                    println!("the CNC program has ended (program-end trigger sent); Ctrl-C stops the instruments");
                }
            }
        }
        }
        sim.shutdown().await;
        if let Some(m) = module {
            m.shutdown().await;
        }
        anyhow::Ok(())
    })
}

/// The daemon's config for the simulated instruments of `dir`, and the simulated temperature
/// module (at `dir/temperature`) when the scenario has a thermal machine. The demo's thermal
/// run (`thermal`) reads the CapBall and the module, as `metrolog demo --thermal-only` does.
fn daemon_config(
    sim: &SimHandle,
    dir: &Path,
    thermal: bool,
) -> anyhow::Result<(String, Option<sim::modbus::ModbusModule>)> {
    use crate::cmd::demo::thermal as th;
    let logs = dir.join("logs");
    if sim.scenario().thermal.is_none() {
        return Ok((write_daemon_config(sim, dir, &logs, false)?, None));
    }
    let link = dir.join("temperature");
    let module = th::start_module(sim, &link)?;
    println!("  {:<15} {}", "temperature", link.display());
    let toml = if thermal {
        th::thermal_config(sim, dir, &logs, &link)?
    } else {
        write_daemon_config(sim, dir, &logs, false)? + &th::temperature_section(sim, &link)?
    };
    Ok((toml, Some(module)))
}
