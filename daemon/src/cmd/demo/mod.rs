//! `metrolog demo [--out DIR]`: a complete measurement on simulated instruments.
//!
//! Starts the simulated LI-80, CB-3, PSD-2 and SLCAN adapter of the built-in demo scenario on
//! pseudo-terminals, writes a metrolog.toml for them, and runs the very acquisition `metrolog
//! run` runs (real drivers, real pipeline, real MCAP writer) through the scenario's CNC program:
//! an ISO 230-2 style interferometer run on one axis, a CapBall pose sequence and a PSD segment.
//! Then it compares every steady value with the simulation's true value and prints a report.
//! Then it closes the compensation loop ([`verify`]): the LinuxCNC table of the run, loaded
//! into the simulated axis, and the positioning run measured again with it. Last, a thermal
//! run of the simulated thermal machine, time compressed ([`thermal`]), and the thermal model
//! fitted to its log.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use drivers::Instrument;
use sim::{PoseTruth, Scenario};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use crate::acquire::config::Config;
use crate::acquire::pipeline::Status;
use crate::acquire::service::Notifier;
use crate::cmd::run::{Acquire, RunReport, acquire};
use metrolog_log::topics::PoseMsg;
use types::PoseStatus;

pub mod thermal;
pub mod verify;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Where the demo puts its config, port links and MCAP log.
    #[arg(long, value_name = "DIR", default_value = "./metrolog-demo")]
    pub out: PathBuf,
    /// Run only the thermal segment (the thermal run, time compressed, and its analyses).
    #[arg(long)]
    pub thermal_only: bool,
}

/// How long the instruments may take to connect and stream before the program starts.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(20);

pub fn run(args: Args) -> anyhow::Result<()> {
    crate::acquire::service::init_tracing_with_default("warn");
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let out = std::fs::canonicalize(&args.out)
        .with_context(|| format!("cannot resolve {}", args.out.display()))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    if args.thermal_only {
        let log = rt.block_on(thermal::demo_segment(&out))?;
        thermal::print_analyses(&log, &out);
        return Ok(());
    }
    let (report, truth, home_x_mm) = rt.block_on(demo(out.clone()))?;
    // Poses without a dwell (the reversal moves of the ISO 230-2 cycles) are not measured.
    let reversals: Vec<u32> = Scenario::demo()
        .program
        .poses
        .iter()
        .enumerate()
        .filter(|(_, p)| p.dwell_s == Some(0.0))
        .map(|(i, _)| i as u32 + 1)
        .collect();
    print_report(&report, &truth, home_x_mm, &reversals);
    print_analysis(&report);
    print_capball_truth();
    let l = rt.block_on(verify::compensate_and_verify(&report.log_path, &out))?;
    print_loop(&l);
    let log = rt.block_on(thermal::demo_segment(&out))?;
    thermal::print_analyses(&log, &out);
    Ok(())
}

/// The compensate-and-verify loop's files and its measured before/after.
fn print_loop(l: &verify::Loop) {
    println!(
        "\ncompensate and verify: LinuxCNC table ({:?}, {} points, reference {:.3} mm) from the calibration run",
        l.table.mode,
        l.table.points_mm.len(),
        l.table.reference_mm
    );
    for f in &l.files {
        println!("  wrote {}", f.display());
    }
    println!("  verification log: {}\n", l.verify_log.display());
    print!(
        "{}",
        crate::cmd::compensate::before_after_text(&l.remeasured, Some(&l.predicted))
    );
    println!(
        "  a pitch table removes the error that repeats at each target; A and R keep the drift within the run (the axis's thermal expansion and cyclic drift above), and the mean deviations after keep a constant offset (the error at the reference point, which the table takes as exact)\n  compare any two runs: metrolog compensate verify BEFORE.mcap AFTER.mcap"
    );
}

/// What the simulation put into the CapBall data, to hold against the report's CapBall
/// identification and diagnosis (the demo scenario's `[capball.truth]`).
fn print_capball_truth() {
    let t = Scenario::demo().capball.truth;
    let e = t.errors().to_vector();
    let params: Vec<String> = geometry::capball::PARAM_NAMES
        .iter()
        .zip(e)
        .map(|(n, v)| format!("{n} {v:.2}"))
        .collect();
    println!(
        "\nsimulation truth of the CapBall poses:\n  {}",
        params.join("   ")
    );
    if let Some(c) = &t.cyclic_drift {
        let a = c.amplitude_um;
        println!(
            "  cyclic_drift: period {:.0} s ({:.1} min) of machine time, amplitude x {:.2} y {:.2} \
             z {:.2} µm (half peak-to-valley); per-visit scatter {:.2} µm",
            c.period_s,
            c.period_s / 60.0,
            a[0],
            a[1],
            a[2],
            t.pose_noise_um
        );
    }
}

async fn demo(out: PathBuf) -> anyhow::Result<(RunReport, Vec<PoseTruth>, f64)> {
    let scenario = Scenario::demo();
    let home_x_mm = scenario.program.home.x_mm;
    let (report, truth) = sim_run(scenario, &out, "metrolog demo").await?;
    Ok((report, truth, home_x_mm))
}

/// One run of `scenario` on simulated instruments through the very acquisition `metrolog run`
/// runs: port links in `dir/ports`, the config `dir/metrolog.toml`, the log in `dir`. The CNC
/// program starts once every instrument streams; `what` names the run in the first line
/// printed. Returns the run's report and the simulation's per-pose truth.
pub async fn sim_run(
    scenario: Scenario,
    dir: &Path,
    what: &str,
) -> anyhow::Result<(RunReport, Vec<PoseTruth>)> {
    let ports = dir.join("ports");
    std::fs::create_dir_all(&ports)
        .with_context(|| format!("cannot create {}", ports.display()))?;
    let total = scenario.program.poses.len() as u64;
    let sim = sim::Sim::start(scenario, &ports)?;
    let toml = crate::cmd::sim::write_daemon_config(&sim, &ports, dir, true)?;
    let cfg_path = dir.join("metrolog.toml");
    std::fs::write(&cfg_path, &toml)
        .with_context(|| format!("cannot write {}", cfg_path.display()))?;
    // Through the same loader as the service, so the demo checks the config path too.
    let cfg = Config::load(&cfg_path)?;
    println!(
        "{what}: simulated instruments on {}; CNC program of {total} poses, about {:.0} s",
        ports.display(),
        sim.program_duration_s()
    );

    let (progress_tx, progress) = watch::channel(Status::default());
    let stop = CancellationToken::new();
    let run = acquire(
        &cfg,
        Acquire {
            notifier: Notifier::from_env(),
            stop: stop.clone(),
            progress: Some(progress_tx),
            keep_poses: true,
            handle_signals: true,
        },
    );
    let instruments = cfg.instruments();
    let control = control(&sim, &instruments, progress, &stop, total);
    let (report, control) = tokio::join!(run, control);
    let report = report?;
    control?;
    let truth = sim.record().truth;
    sim.shutdown().await;
    Ok((report, truth))
}

/// Starts the CNC program when every instrument streams, as an operator would, and shows the
/// progress until the run ends (or stops it when the program overruns by 20 s).
async fn control(
    sim: &sim::SimHandle,
    instruments: &[Instrument],
    mut progress: watch::Receiver<Status>,
    stop: &CancellationToken,
    total: u64,
) -> anyhow::Result<()> {
    let wait = async {
        loop {
            {
                let st = progress.borrow_and_update();
                let ready = instruments.iter().all(|i| {
                    st.instruments.get(i).is_some_and(|s| {
                        s.connected && (*i == Instrument::Trigger || s.received > 0)
                    })
                });
                if ready {
                    return;
                }
            }
            if progress.changed().await.is_err() {
                return;
            }
        }
    };
    if tokio::time::timeout(CONNECT_TIMEOUT, wait).await.is_err() {
        let st = progress.borrow().clone();
        stop.cancel();
        return Err(anyhow::anyhow!(
            "the instruments did not all stream within {CONNECT_TIMEOUT:?}: {}",
            st.summary()
        ));
    }
    sim.start_program();
    let bar = indicatif::ProgressBar::new(total);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} poses {pos}/{len} [{bar:40}] {elapsed_precise} {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let deadline =
        tokio::time::Instant::now() + Duration::from_secs_f64(sim.program_duration_s() + 20.0);
    loop {
        {
            let st = progress.borrow_and_update();
            bar.set_position((st.last_pose as u64).min(total));
            bar.set_message(format!("{} samples, {} faults", st.samples(), st.faults()));
        }
        tokio::select! {
            r = progress.changed() => if r.is_err() { break },
            _ = tokio::time::sleep_until(deadline) => {
                bar.println("the program did not end in time; stopping");
                stop.cancel();
                break;
            }
        }
    }
    bar.finish();
    Ok(())
}

/// What one instrument measured against the simulation's truth.
struct Comparison {
    instrument: Instrument,
    ok: usize,
    other: Vec<(u32, &'static str)>,
    max_err_um: f64,
    rms_err_um: f64,
}

fn compare(
    report: &RunReport,
    truth: &[PoseTruth],
    home_x_mm: f64,
    reversals: &[u32],
    instrument: Instrument,
) -> Comparison {
    let mut c = Comparison {
        instrument,
        ok: 0,
        other: Vec::new(),
        max_err_um: 0.0,
        rms_err_um: 0.0,
    };
    let mut sum2 = 0.0;
    for v in report
        .outcome
        .poses
        .iter()
        .filter(|v| v.instrument == instrument)
    {
        if reversals.contains(&v.pose) {
            continue;
        }
        if v.status != PoseStatus::Ok {
            c.other.push((v.pose, v.status.name()));
            continue;
        }
        let Some(t) = truth.iter().find(|t| u32::from(t.pose) == v.pose) else {
            continue;
        };
        let Some(err) = error_um(v, t, home_x_mm) else {
            continue;
        };
        c.ok += 1;
        sum2 += err * err;
        c.max_err_um = c.max_err_um.max(err);
    }
    if c.ok > 0 {
        c.rms_err_um = (sum2 / c.ok as f64).sqrt();
    }
    c
}

/// Distance between a steady value and the true value, µm (vector norm for CapBall and PSD).
fn error_um(v: &PoseMsg, t: &PoseTruth, home_x_mm: f64) -> Option<f64> {
    let m = |k: &str| v.mean.get(k).copied();
    Some(match v.instrument {
        // The interferometer reads the 20 °C length from the datum at home: programmed
        // displacement plus the axis deviation.
        Instrument::Interferometer => {
            let expected = (t.x_mm - home_x_mm) * 1e3 + t.deviation_um;
            (m("position_um")? - expected).abs()
        }
        Instrument::Capball => {
            let e = [m("ex_um")?, m("ey_um")?, m("ez_um")?];
            (0..3)
                .map(|k| (e[k] - t.capball_e_um[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        }
        Instrument::Psd => {
            ((m("x_um")? - t.psd_x_um).powi(2) + (m("y_um")? - t.psd_y_um).powi(2)).sqrt()
        }
        Instrument::Trigger | Instrument::Thermometer => return None,
    })
}

fn print_report(report: &RunReport, truth: &[PoseTruth], home_x_mm: f64, reversals: &[u32]) {
    let st = &report.outcome.status;
    println!(
        "\nrun ended at {} after {:.1} s",
        report.reason_text(),
        st.uptime_s
    );
    println!(
        "poses programmed: {} ({} of them reversals without dwell, not measured); pose values written: {} ({} ok)",
        truth.len(),
        reversals.len(),
        st.poses,
        st.poses_ok
    );
    println!("\nsteady values against the simulation's true values (at mid-dwell):");
    println!(
        "  {:<15} {:>9} {:>14} {:>14}  not measured",
        "instrument", "ok poses", "max |err| µm", "rms err µm"
    );
    for i in Instrument::POSE_VALUED {
        let c = compare(report, truth, home_x_mm, reversals, i);
        let other = if c.other.is_empty() {
            "-".to_string()
        } else {
            c.other
                .iter()
                .map(|(p, s)| format!("pose {p}: {s}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        println!(
            "  {:<15} {:>9} {:>14.3} {:>14.3}  {other}",
            c.instrument.name(),
            c.ok,
            c.max_err_um,
            c.rms_err_um
        );
    }
    println!(
        "\ncounters (the demo scenario injects garbage, bad checksums and dropped samples; they are caught and counted here):"
    );
    println!(
        "  {:<15} {:>9} {:>6} {:>11} {:>8} {:>10} {:>8} {:>8}",
        "instrument",
        "received",
        "gaps",
        "gap samples",
        "rejects",
        "reconnects",
        "dropped",
        "invalid"
    );
    for (i, s) in &st.instruments {
        let d = &s.driver;
        println!(
            "  {:<15} {:>9} {:>6} {:>11} {:>8} {:>10} {:>8} {:>8}",
            i.name(),
            s.received,
            d.gaps,
            d.gap_samples,
            d.rejections.values().sum::<u64>(),
            d.reconnects,
            d.dropped,
            d.invalid
        );
    }
    println!(
        "  queue: most {} of {} waiting; pose latency at most {:.1} ms; log write errors {}",
        st.queue_max, st.queue_capacity, st.pose_latency_max_ms, st.log_errors
    );
    println!("\nlog: {}", report.log_path.display());
    println!(
        "  inspect:  metrolog info {}\n  replay:   metrolog replay {}",
        report.log_path.display(),
        report.log_path.display()
    );
}

/// The analysis of the demo's own log, exactly as the analysis commands compute it: ISO 230-2
/// positioning accuracy of the interferometer run, the diagnosis against the simulation model,
/// the CapBall identification and the PSD segment's straightness.
fn print_analysis(report: &RunReport) {
    println!("\nanalysis of {}:", report.log_path.display());
    match metrolog_analysis::demo_report(&report.log_path) {
        Ok(text) => println!("{text}"),
        Err(e) => println!("  the analysis could not run: {e:#}"),
    }
}
