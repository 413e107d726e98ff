//! `metrolog run --config FILE`: the acquisition service (what systemd starts).
//!
//! Starts the configured drivers, one bounded queue to the pipeline, a steady-value detector per
//! instrument and the MCAP writer (one file per run in `[run] output_dir`); writes `/status` once
//! a second; tells systemd READY, STATUS, WATCHDOG and STOPPING. Ends cleanly on SIGTERM/SIGINT,
//! and at the CNC's program end when `[run] stop_at_program_end = true`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use drivers::{DriverEvent, HostClock, Instrument};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

use crate::acquire::config::{Config, TriggerConfig};
use crate::acquire::pipeline::{
    self, ConnectPolicy, Outcome, Pipeline, PipelineConfig, Status, StopReason,
};
use crate::acquire::service::{self, Notifier};
use crate::acquire::storage;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The configuration file (see deploy/metrolog.toml for every key).
    #[arg(long, short, value_name = "FILE")]
    pub config: PathBuf,
    /// Only check the configuration and its devices and say what would run (every mistake
    /// at once; exit 78 when there is one).
    #[arg(long)]
    pub check: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    service::init_tracing();
    // The same checks as --check: a missing port or one given twice stops the start (78).
    let cfg = Config::load_checked(&args.config)?;
    let notes = cfg.notes();
    if args.check {
        for n in &notes {
            println!("note: {n}");
        }
        println!("{}: valid; {}", cfg.path.display(), describe(&cfg));
        return Ok(());
    }
    for n in &notes {
        tracing::warn!("{n}");
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let notifier = Notifier::from_env();
    let report = rt.block_on(acquire(
        &cfg,
        Acquire {
            notifier: notifier.clone(),
            stop: CancellationToken::new(),
            progress: None,
            keep_poses: false,
            handle_signals: true,
        },
    ))?;
    let st = &report.outcome.status;
    if report.outcome.reason == StopReason::LogFailed {
        let why = st.log_failed.clone().unwrap_or_default();
        // STATUS= stays visible in `systemctl status` after the exit.
        notifier.status(&st.summary());
        tracing::error!(
            "run stopped: the log could not be written; {} keeps what was written before ({})",
            report.log_path.display(),
            st.summary()
        );
        return Err(crate::exit::LogWriteFailed(why).into());
    }
    if report.outcome.reason == StopReason::NothingConnected {
        notifier.status(&st.summary());
        let why = st.nothing_connected.clone().unwrap_or_default();
        return Err(crate::exit::NothingConnected(format!(
            "nothing connected {why}; plug the instruments in (or fix their ports), then start the service again"
        ))
        .into());
    }
    tracing::info!(
        "run ended ({}); log {}; {}; queue at most {} of {}; pose latency at most {:.1} ms",
        report.reason_text(),
        report.log_path.display(),
        st.summary(),
        st.queue_max,
        st.queue_capacity,
        st.pose_latency_max_ms
    );
    Ok(())
}

/// One line on what a config runs.
pub fn describe(cfg: &Config) -> String {
    let mut parts = Vec::new();
    if let Some(c) = &cfg.interferometer {
        parts.push(format!("LI-80 on {} at {} Hz", c.port, c.rate_hz));
    }
    if let Some(c) = &cfg.capball {
        parts.push(format!(
            "CB-3 on {} at {} Hz",
            c.driver.port, c.driver.rate_hz
        ));
    }
    if let Some(c) = &cfg.psd {
        parts.push(format!(
            "PSD-2 on {} at {} Hz ({} baud)",
            c.port, c.rate_hz, c.baud
        ));
    }
    if let Some(c) = &cfg.temperature {
        parts.push(format!(
            "{} temperatures (Modbus unit {}) on {} every {} s",
            c.sensors.len(),
            c.unit,
            c.port,
            c.poll_period_s
        ));
    }
    match &cfg.trigger {
        Some(TriggerConfig::Slcan(s)) => parts.push(format!(
            "triggers via SLCAN on {} (id {:#x})",
            s.port, s.can_id
        )),
        Some(TriggerConfig::SocketCan(s)) => parts.push(format!(
            "triggers via SocketCAN {} (id {:#x})",
            s.interface, s.can_id
        )),
        None => parts.push("no triggers (plateau detection)".into()),
    }
    format!(
        "machine {}, logs to {}, {}",
        cfg.run.machine,
        cfg.run.output_dir.display(),
        parts.join(", ")
    )
}

/// The "nothing connected" alarm of a config: `[run] connect_timeout_s`, waiting when a device
/// is `hotplug`.
fn connect_policy(cfg: &Config) -> ConnectPolicy {
    let mut ports = Vec::new();
    if let Some(c) = &cfg.interferometer {
        ports.push((Instrument::Interferometer, c.port.clone()));
    }
    if let Some(c) = &cfg.capball {
        ports.push((Instrument::Capball, c.driver.port.clone()));
    }
    if let Some(c) = &cfg.psd {
        ports.push((Instrument::Psd, c.port.clone()));
    }
    match &cfg.trigger {
        Some(TriggerConfig::Slcan(s)) => ports.push((Instrument::Trigger, s.port.clone())),
        Some(TriggerConfig::SocketCan(s)) => ports.push((Instrument::Trigger, s.interface.clone())),
        None => {}
    }
    ConnectPolicy {
        timeout: Duration::from_secs(cfg.run.connect_timeout_s),
        wait: cfg.ports.iter().any(|p| p.hotplug),
        ports,
    }
}

/// How an acquisition is run (the service and the demo differ only here).
pub struct Acquire {
    pub notifier: Notifier,
    /// Cancel to end the run from outside (demo).
    pub stop: CancellationToken,
    /// Receives the status after every pose value and every second.
    pub progress: Option<watch::Sender<Status>>,
    /// Keep every pose value for the report.
    pub keep_poses: bool,
    /// End on SIGTERM / SIGINT.
    pub handle_signals: bool,
}

/// What a finished acquisition hands back.
#[derive(Debug)]
pub struct RunReport {
    pub log_path: PathBuf,
    pub outcome: Outcome,
    /// The signal that ended the run, if one did.
    pub signal: Option<&'static str>,
}

impl RunReport {
    pub fn reason_text(&self) -> String {
        match (&self.outcome.reason, self.signal) {
            (_, Some(sig)) => sig.to_string(),
            (StopReason::ProgramEnd, _) => "program end".into(),
            (StopReason::Cancelled, _) => "stopped".into(),
            (StopReason::DriversGone, _) => "every driver ended".into(),
            (StopReason::LogFailed, _) => "the log could not be written".into(),
            (StopReason::NothingConnected, _) => "nothing connected".into(),
        }
    }
}

/// How long stopping drivers may take before the pipeline closes the log without them.
const DRIVER_STOP_TIMEOUT: Duration = Duration::from_secs(3);

/// Run one acquisition from a validated config until stopped.
pub async fn acquire(cfg: &Config, opts: Acquire) -> anyhow::Result<RunReport> {
    let clock = HostClock::new();
    // Retention and the low-space warning before the new log takes any space.
    let disk_alarm = storage::DiskAlarm::default();
    if cfg.run.output_dir.is_dir() {
        let low = storage::apply_and_report(
            &cfg.storage,
            &cfg.run.output_dir,
            None,
            &storage::Statvfs,
            &disk_alarm,
        );
        if let Some(w) = low {
            tracing::warn!("{w}");
        }
        storage::room_to_start(&cfg.run.output_dir, &storage::Statvfs)
            .map_err(crate::exit::LogCreateFailed)?;
    }
    let mut recorder = crate::acquire::run_log::open_log(cfg, &clock)
        .map_err(|e| crate::exit::LogCreateFailed(format!("{e:#}")))?;
    let log_path = recorder.path().to_path_buf();
    tracing::info!("logging to {}", log_path.display());
    let live = start_live(cfg, &log_path).await;
    let storage_cancel = CancellationToken::new();
    tokio::spawn(storage::watch(
        storage::Watch::service(
            cfg.storage.clone(),
            cfg.run.output_dir.clone(),
            log_path.clone(),
            disk_alarm.clone(),
        ),
        storage_cancel.clone(),
    ));
    let _stop_storage = storage_cancel.drop_guard();
    if let Some(l) = &live {
        recorder.set_tap(l.tap());
    }

    let (tx, rx) = mpsc::channel::<DriverEvent>(pipeline::QUEUE_CAPACITY);
    let drivers_cancel = CancellationToken::new();
    let pipeline_cancel = CancellationToken::new();

    let (datum_tx, datum_rx) = tokio::sync::mpsc::unbounded_channel();
    let datum = cfg.interferometer.as_ref().map(|_| pipeline::DatumControl {
        commands: datum_tx,
        reference_poses: cfg.run.reference_poses.clone(),
        settle: Duration::from_secs_f64(cfg.run.reference_settle_s),
    });
    let pl = Pipeline::new(
        PipelineConfig {
            instruments: cfg.instruments(),
            stop_at_program_end: cfg.run.stop_at_program_end,
            keep_poses: opts.keep_poses,
            connect: Some(connect_policy(cfg)),
            disk_alarm: Some(disk_alarm),
            trajectory: trajectory_rows(cfg),
            datum,
        },
        clock,
        Box::new(recorder),
    );
    let progress = opts
        .progress
        .unwrap_or_else(|| watch::channel(Status::default()).0);
    let pipeline_thread = pipeline::spawn(
        pl,
        rx,
        pipeline_cancel.clone(),
        opts.notifier.clone(),
        progress,
    )
    .context("cannot start the pipeline thread")?;

    drivers::set_read_coalesce(cfg.run.read_coalesce);
    let mut handles = Vec::new();
    if let Some(c) = &cfg.interferometer {
        handles.push(drivers::spawn_li80_with(
            c.clone(),
            clock,
            tx.clone(),
            drivers_cancel.child_token(),
            drivers::Li80Control {
                commands: Some(datum_rx),
            },
        ));
    }
    if let Some(c) = &cfg.capball {
        handles.push(drivers::spawn_cb3(
            c.driver.clone(),
            clock,
            tx.clone(),
            drivers_cancel.child_token(),
        ));
    }
    if let Some(c) = &cfg.psd {
        handles.push(drivers::spawn_psd(
            c.clone(),
            clock,
            tx.clone(),
            drivers_cancel.child_token(),
        ));
    }
    if let Some(c) = &cfg.temperature {
        handles.push(drivers::spawn_modbus_temperature(
            c.clone(),
            clock,
            tx.clone(),
            drivers_cancel.child_token(),
        ));
    }
    match &cfg.trigger {
        Some(TriggerConfig::Slcan(c)) => handles.push(drivers::spawn_slcan(
            c.clone(),
            clock,
            tx.clone(),
            drivers_cancel.child_token(),
        )),
        Some(TriggerConfig::SocketCan(c)) => handles.push(drivers::spawn_socketcan(
            c.clone(),
            clock,
            tx.clone(),
            drivers_cancel.child_token(),
        )),
        None => {}
    }
    // Only the drivers hold senders now: when they all end, the pipeline sees it.
    drop(tx);
    opts.notifier
        .ready(&format!("acquiring: {}", describe(cfg)));
    tracing::info!("acquiring: {}", describe(cfg));

    let (done_tx, mut done_rx) = tokio::sync::oneshot::channel();
    std::thread::Builder::new()
        .name("pipeline-join".into())
        .spawn(move || {
            let r = pipeline_thread.join();
            let _ = done_tx.send(r);
        })
        .context("cannot start a thread")?;

    let signals = async {
        if opts.handle_signals {
            service::shutdown_signal().await
        } else {
            std::future::pending().await
        }
    };
    let mut signal = None;
    let mut early = None;
    tokio::select! {
        s = signals => {
            tracing::info!("{s}: stopping");
            signal = Some(s);
        }
        _ = opts.stop.cancelled() => {}
        r = &mut done_rx => { early = Some(r); }
    }
    opts.notifier.stopping();
    drivers_cancel.cancel();
    // Let the drivers put their last samples in the queue, but do not wait on a stuck one.
    let stop_drivers = async {
        for h in handles {
            let _ = h.await;
        }
    };
    if tokio::time::timeout(DRIVER_STOP_TIMEOUT, stop_drivers)
        .await
        .is_err()
    {
        tracing::warn!(
            "a driver did not stop within {DRIVER_STOP_TIMEOUT:?}; closing the log without it"
        );
    }
    pipeline_cancel.cancel();
    let joined = match early {
        Some(r) => r,
        None => done_rx.await,
    };
    let outcome = match joined {
        Ok(Ok(r)) => r?,
        Ok(Err(_)) | Err(_) => {
            return Err(crate::exit::PipelinePanicked.into());
        }
    };
    if let Some(l) = live {
        l.stop().await;
    }
    Ok(RunReport {
        log_path,
        outcome,
        signal,
    })
}

/// The run's pose table (empty without a trajectory).
fn trajectory_rows(cfg: &Config) -> Vec<metrolog_log::trajectory::TrajectoryRow> {
    cfg.run
        .trajectory
        .iter()
        .flat_map(|t| t.rows.iter().cloned())
        .collect()
}

/// The live view of `[live]`, if configured. One that cannot start is reported and left out:
/// the measurement runs without it.
async fn start_live(cfg: &Config, log_path: &std::path::Path) -> Option<crate::live::LiveView> {
    let live = cfg.live.as_ref()?;
    let session = log_path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let run = crate::live::RunInfo {
        machine: cfg.run.machine.clone(),
        session,
        temperature_sensors: cfg
            .temperature
            .iter()
            .flat_map(|t| t.sensors.iter().map(|s| s.name.clone()))
            .collect(),
        trajectory: trajectory_rows(cfg),
        window_samples: cfg.detector.samples,
    };
    match crate::live::LiveView::start(live, run).await {
        Ok(l) => Some(l),
        Err(e) => {
            tracing::error!("live view not started: {e:#}; the run goes on without it");
            None
        }
    }
}
