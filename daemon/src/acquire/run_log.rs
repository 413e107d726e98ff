//! Opening the run's log: the config's policy for a run (which instruments get pose values,
//! triggers or standstill plateaus), the run metadata, and the config, trajectory and CapBall
//! transform attached, so the log replays on its own.

use std::collections::BTreeMap;

use anyhow::Context;
use drivers::HostClock;
use metrolog_log::DetectorSettings;

use super::config::Config;
use super::recorder::Recorder;
use super::sink::LiveLog;

/// The detector settings of a config: the same window length for every instrument; poses
/// delimited by the CNC's triggers when a `[trigger]` is configured, found as standstill
/// plateaus in the signal otherwise.
pub fn detector_settings(cfg: &Config) -> DetectorSettings {
    let mut s = DetectorSettings::default().with_samples(cfg.detector.samples);
    // Only the configured instruments get pose values: one left out of the run is not "away".
    s.instruments.retain(|i| match i {
        drivers::Instrument::Interferometer => cfg.interferometer.is_some(),
        drivers::Instrument::Capball => cfg.capball.is_some(),
        drivers::Instrument::Psd => cfg.psd.is_some(),
        drivers::Instrument::Trigger | drivers::Instrument::Thermometer => false,
    });
    if cfg.trigger.is_none() {
        for c in [&mut s.interferometer, &mut s.capball, &mut s.psd] {
            c.mode = types::DetectorMode::Plateaus;
        }
    }
    s.position_targets = position_targets(cfg);
    s
}

/// Where the interferometer must read at each pose of the trajectory, when its poses are the
/// CNC's (triggers) and it measures from the datum position: `(x_mm − DATUM_X_MM)·1000`.
fn position_targets(cfg: &Config) -> Option<types::PositionTargets> {
    let t = cfg.run.trajectory.as_ref()?;
    (cfg.trigger.is_some() && cfg.interferometer.is_some()).then(|| types::PositionTargets {
        targets_um: t
            .rows
            .iter()
            .map(|r| (r.x_mm - super::config::DATUM_X_MM) * 1000.0)
            .collect(),
        tol_um: types::OFF_TARGET_TOL_UM,
        floor_um: Some(types::OFF_TARGET_FLOOR_UM),
    })
}

/// The run metadata of a config, started at `now_ns`.
fn run_metadata(
    cfg: &Config,
    settings: &DetectorSettings,
    now_ns: u64,
) -> metrolog_log::RunMetadata {
    let mut extra = BTreeMap::new();
    extra.insert("config_path".to_string(), cfg.path.display().to_string());
    extra.insert(
        "stop_at_program_end".to_string(),
        cfg.run.stop_at_program_end.to_string(),
    );
    if cfg.run.time_scale != 1.0 {
        extra.insert("time_scale".to_string(), cfg.run.time_scale.to_string());
    }
    extra.insert(
        "instruments_configured".to_string(),
        cfg.instruments()
            .iter()
            .map(|i| i.name())
            .collect::<Vec<_>>()
            .join(","),
    );
    if let Some(t) = &cfg.temperature {
        extra.insert(
            metrolog_log::TEMPERATURE_SENSORS_KEY.to_string(),
            serde_json::to_string(&t.sensors).unwrap_or_default(),
        );
    }
    metrolog_log::RunMetadata {
        machine: cfg.run.machine.clone(),
        started_ns: now_ns,
        detector: settings.clone(),
        instruments: BTreeMap::new(),
        // The log stores CB-3 samples as ADC codes with this calibration (docs/log-format.md).
        capball: cfg.capball.as_ref().map(|c| c.driver.calibration()),
        extra,
    }
}

/// Open the run's MCAP log in `[run] output_dir` (created if missing) with the run metadata and
/// the config, trajectory and CapBall transform attached, so the log replays on its own.
pub fn open_log(cfg: &Config, clock: &HostClock) -> anyhow::Result<LiveLog> {
    let dir = &cfg.run.output_dir;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create the output directory {}", dir.display()))?;
    let settings = detector_settings(cfg);
    let now = clock.now_ns();
    let meta = run_metadata(cfg, &settings, now);
    let mut writer = metrolog_log::LogWriter::create_in_dir(
        dir,
        &meta,
        metrolog_log::LogOptions {
            // Durability comes from the log-sync thread of [`LiveLog`].
            fsync: false,
            split_after: cfg.storage.split_after,
            split_bytes: cfg.storage.split_bytes,
            ..metrolog_log::LogOptions::default()
        },
    )?;
    writer.attach(
        metrolog_log::CONFIG_ATTACHMENT,
        "application/toml",
        cfg.text.as_bytes(),
        now,
    )?;
    if let Some(t) = &cfg.run.trajectory {
        writer.attach(
            metrolog_log::TRAJECTORY_ATTACHMENT,
            "text/csv",
            t.text.as_bytes(),
            now,
        )?;
    }
    if let Some((_, text)) = cfg.capball.as_ref().and_then(|c| c.transform_file.as_ref()) {
        writer.attach("capball-transform.csv", "text/csv", text.as_bytes(), now)?;
    }
    LiveLog::new(Recorder::new(writer, &settings)?)
}
