//! The daemon config (`metrolog.toml`) for the simulated instruments of a running simulator:
//! its ports, rates, the CapBall's calibration and transform, the trigger. Written by
//! `metrolog sim`, the demo, the thermal run and the tests.

use std::path::Path;

use anyhow::Context;
use sim::{Device, SimHandle};

/// Device rates the generated daemon config asks for, within each data sheet. The LI-80 runs at
/// its full 10 kHz: the demo scenario compresses an hour of thermal drift into 30 s (about
/// 0.6 µm/s on the axis), and a window of 150 samples must be short (15 ms) for that drift to
/// stay below the noise, or the steady test rightly refuses it. The CB-3 runs at 10 kHz for the
/// same reason: the CapBall's 25-minute cooling cycle (3 µm) compressed 120× moves 1.5 µm/s,
/// 0.23 µm over 150 samples at 1 kHz (noise 0.02 µm: never steady), 0.02 µm at 10 kHz.
pub const SIM_LI80_RATE_HZ: u32 = 10_000;
pub const SIM_CB3_RATE_HZ: u32 = 10_000;
pub const SIM_PSD_RATE_HZ: u32 = 1000;

/// Write the trajectory and CapBall transform of a running simulation into `dir` and return a
/// metrolog.toml that reads its ports.
pub fn write_daemon_config(
    sim: &SimHandle,
    dir: &Path,
    output_dir: &Path,
    stop_at_program_end: bool,
) -> anyhow::Result<String> {
    write_daemon_config_with_rates(
        sim,
        dir,
        output_dir,
        stop_at_program_end,
        [SIM_LI80_RATE_HZ, SIM_CB3_RATE_HZ, SIM_PSD_RATE_HZ],
    )
}

/// [`write_daemon_config`] with the LI-80, CB-3 and PSD-2 rates given (benchmarks).
pub fn write_daemon_config_with_rates(
    sim: &SimHandle,
    dir: &Path,
    output_dir: &Path,
    stop_at_program_end: bool,
    rates_hz: [u32; 3],
) -> anyhow::Result<String> {
    let sc = sim.scenario();
    let trajectory = dir.join("trajectory.csv");
    std::fs::write(&trajectory, sc.trajectory_csv())
        .with_context(|| format!("cannot write {}", trajectory.display()))?;
    let t = sc.capball_transform();
    let transform = dir.join("capball-T.csv");
    let text: String = t
        .iter()
        .map(|r| format!("{:.12e},{:.12e},{:.12e},{:.12e}\n", r[0], r[1], r[2], r[3]))
        .collect();
    std::fs::write(
        &transform,
        format!("# sensor-to-machine transform of the simulated CapBall\n{text}"),
    )
    .with_context(|| format!("cannot write {}", transform.display()))?;
    let poly = sc.capball.poly;
    let poly = format!(
        "[[{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}], [{:?}, {:?}, {:?}]]",
        poly[0][0],
        poly[0][1],
        poly[0][2],
        poly[1][0],
        poly[1][1],
        poly[1][2],
        poly[2][0],
        poly[2][1],
        poly[2][2]
    );
    let q = |p: &Path| format!("{:?}", p.display().to_string());
    Ok(format!(
        r#"# metrolog.toml for the simulated instruments of `metrolog sim` ({dir})
[run]
machine = "sim"
output_dir = {out}
trajectory = {traj}
stop_at_program_end = {stop}
time_scale = {time_scale:?}       # the simulator's slow effects run this much faster than real time

[detector]
samples = 150

[interferometer]
port = {li80}
rate_hz = {li80_rate}
alpha_um_per_m_k = {alpha:?}

[capball]
port = {cb3}
rate_hz = {cb3_rate}
poly = {poly}
transform = {tf}

[psd]
port = {psd}
baud = 921600
rate_hz = {psd_rate}
min_sum_pa = 100000

[trigger]
slcan = {slcan}
can_id = {can_id:#x}
"#,
        dir = dir.display(),
        out = q(output_dir),
        traj = q(&trajectory),
        stop = stop_at_program_end,
        time_scale = sc.time_scale,
        li80 = q(&sim.port(Device::Interferometer)),
        li80_rate = rates_hz[0],
        alpha = sc.interferometer.alpha_um_per_m_k,
        cb3 = q(&sim.port(Device::Capball)),
        cb3_rate = rates_hz[1],
        tf = q(&transform),
        psd = q(&sim.port(Device::Psd)),
        psd_rate = rates_hz[2],
        slcan = q(&sim.port(Device::Trigger)),
        can_id = sc.trigger.can_id,
    ))
}
