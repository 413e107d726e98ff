//! A thermal test from a run's log: the temperature module's `/temperature` samples and the
//! pose values (`/pose`) of the measuring pose the run returned to (docs/methods.md, thermal
//! model; instruments.md §5).
//!
//! One row per visit of that pose (the pose with the most `ok` values; others are left out,
//! with a note): its time is the middle of the visit's averaging windows (all instruments),
//! from the first visit, multiplied by the run's `time_scale`; each displacement column is an
//! instrument's mean ending `_um`, named `<instrument>_<quantity>` (`capball_ex_um`); each
//! temperature the mean of the sensor's readings inside the visit's window, or, with none
//! there, interpolated linearly in time between the readings either side. A sensor that has
//! no reading for some visit (an open sensor) is left out, with a note; a visit without a value
//! of every instrument is left out.
//!
//! A channel named `spindle_rpm` (the spindle drive's speed on an analogue input of the
//! module, its own `scale`) is the spindle speed, not a temperature: per visit, the root mean
//! square of its readings since the previous visit's window ended (through this window), so
//! that its square is the mean of rpm² over the step (bearing friction heat grows with it),
//! whatever the speed did between two visits.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context as _;
use metrolog_log::raw::TEMPERATURE_TOPIC;
use metrolog_log::topics::{LogMessage, PoseMsg, TopicMessage, decode_message};
use metrolog_log::{LogItem, RUN_METADATA, TEMPERATURE_SENSORS_KEY};
use types::{PoseStatus, SampleValues};

/// What the log holds that a thermal test needs.
#[derive(Default)]
struct Read {
    run: BTreeMap<String, String>,
    /// (fitted ns, °C per channel).
    temperatures: Vec<(u64, Vec<f64>)>,
    poses: Vec<PoseMsg>,
}

fn read(path: &Path) -> anyhow::Result<Read> {
    let mut r = Read::default();
    let mut bad = None;
    let summary = metrolog_log::read_log(path, |item| match item {
        LogItem::Metadata { name, map } if name == RUN_METADATA => r.run = map.clone(),
        LogItem::Message {
            topic,
            encoding,
            log_ns,
            data,
        } if topic == TEMPERATURE_TOPIC || topic == PoseMsg::TOPIC => {
            match decode_message(topic, encoding, log_ns, data) {
                Ok(Some(LogMessage::Samples(ss))) => {
                    for s in ss {
                        if let SampleValues::Temperature { values_c } = s.values {
                            r.temperatures.push((s.fitted_ns, values_c));
                        }
                    }
                }
                Ok(Some(LogMessage::Pose(p))) if p.status == PoseStatus::Ok => r.poses.push(p),
                Ok(_) => {}
                Err(e) => {
                    bad.get_or_insert(format!("a {topic} message at {log_ns} ns: {e}"));
                }
            }
        }
        _ => {}
    })
    .with_context(|| format!("reading {}", path.display()))?;
    if let Some(note) = summary.split_note() {
        errln!("note: {note}");
    }
    if let Some(e) = bad {
        anyhow::bail!("{}: {e}", path.display());
    }
    if !summary.clean_close {
        errln!(
            "note: {} was not closed cleanly; its intact part is used",
            path.display()
        );
    }
    Ok(r)
}

/// The sensor names of the run (`t<i>` for channels the metadata does not name).
fn sensor_names(run: &BTreeMap<String, String>, channels: usize) -> Vec<String> {
    let named: Vec<String> = run
        .get(TEMPERATURE_SENSORS_KEY)
        .and_then(|j| serde_json::from_str::<Vec<drivers::TempSensor>>(j).ok())
        .map(|v| v.into_iter().map(|s| s.name).collect())
        .unwrap_or_default();
    (0..channels)
        .map(|i| named.get(i).cloned().unwrap_or_else(|| format!("t{i}")))
        .collect()
}

/// One visit of the measuring pose: its window and the instruments' means ending `_um`.
struct Visit {
    from_ns: u64,
    to_ns: u64,
    mids: Vec<u64>,
    values: BTreeMap<String, f64>,
}

/// The visits of `pose`, in time order: a new visit starts when an instrument comes back.
fn visits(poses: &[PoseMsg], pose: u32) -> Vec<Visit> {
    let mut ps: Vec<&PoseMsg> = poses.iter().filter(|p| p.pose == pose).collect();
    ps.sort_by_key(|p| (p.t_first_ns, p.t_last_ns));
    let mut out: Vec<Visit> = Vec::new();
    let mut seen: Vec<types::Instrument> = Vec::new();
    for p in ps {
        if out.is_empty() || seen.contains(&p.instrument) {
            seen.clear();
            out.push(Visit {
                from_ns: p.t_first_ns,
                to_ns: p.t_last_ns,
                mids: Vec::new(),
                values: BTreeMap::new(),
            });
        }
        seen.push(p.instrument);
        let Some(v) = out.last_mut() else { continue };
        v.from_ns = v.from_ns.min(p.t_first_ns);
        v.to_ns = v.to_ns.max(p.t_last_ns);
        v.mids.push(p.t_first_ns / 2 + p.t_last_ns / 2);
        for (k, x) in &p.mean {
            if k.ends_with("_um") {
                v.values.insert(format!("{}_{k}", p.instrument.name()), *x);
            }
        }
    }
    out
}

/// Channel `i`'s temperature over `[from, to]` ns: the mean of its readings there, else the
/// linear interpolation at `mid` between the nearest readings either side; `None` when
/// neither exists.
fn temperature_at(
    temps: &[(u64, Vec<f64>)],
    i: usize,
    from: u64,
    to: u64,
    mid: u64,
) -> Option<f64> {
    let readings = temps
        .iter()
        .filter_map(|(t, v)| v.get(i).filter(|x| x.is_finite()).map(|x| (*t, *x)));
    let inside: Vec<f64> = readings
        .clone()
        .filter(|(t, _)| (from..=to).contains(t))
        .map(|(_, x)| x)
        .collect();
    if !inside.is_empty() {
        return Some(inside.iter().sum::<f64>() / inside.len() as f64);
    }
    let before = readings.clone().rev().find(|(t, _)| *t <= mid)?;
    let after = readings.clone().find(|(t, _)| *t >= mid)?;
    if after.0 == before.0 {
        return Some(before.1);
    }
    let f = (mid - before.0) as f64 / (after.0 - before.0) as f64;
    Some(before.1 + f * (after.1 - before.1))
}

/// The thermal test a log holds (see the module documentation).
pub fn dataset_from_log(path: &Path) -> anyhow::Result<thermal::ThermalDataset> {
    let mut r = read(path)?;
    r.temperatures.sort_by_key(|(t, _)| *t);
    let channels = r
        .temperatures
        .iter()
        .map(|(_, v)| v.len())
        .max()
        .unwrap_or(0);
    anyhow::ensure!(
        channels > 0,
        "{}: no /temperature samples; a thermal test from a log needs a run with a [temperature] module",
        path.display()
    );
    let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
    for p in &r.poses {
        *counts.entry(p.pose).or_default() += 1;
    }
    let Some((&pose, _)) = counts
        .iter()
        .max_by_key(|(p, n)| (**n, std::cmp::Reverse(**p)))
    else {
        anyhow::bail!(
            "{}: no pose value with status ok; a thermal test needs the displacements measured at a pose",
            path.display()
        );
    };
    if counts.len() > 1 {
        errln!(
            "note: {}: the thermal test is pose {pose} (visited most); poses {:?} are left out",
            path.display(),
            counts.keys().filter(|p| **p != pose).collect::<Vec<_>>()
        );
    }
    let vs = visits(&r.poses, pose);
    let columns: Vec<String> = {
        let mut c: Vec<String> = vs.iter().flat_map(|v| v.values.keys().cloned()).collect();
        c.sort();
        c.dedup();
        c
    };
    let names = sensor_names(&r.run, channels);
    let scale: f64 = r
        .run
        .get("time_scale")
        .and_then(|s| s.parse().ok())
        .unwrap_or(1.0);
    build(&vs, &columns, &names, &r.temperatures, scale, path)
}

fn build(
    vs: &[Visit],
    columns: &[String],
    names: &[String],
    temps: &[(u64, Vec<f64>)],
    scale: f64,
    path: &Path,
) -> anyhow::Result<thermal::ThermalDataset> {
    // Visits with a value of every column; their temperatures per channel.
    let spin = names.iter().position(|n| n == SPINDLE_CHANNEL);
    let rows: Vec<(&Visit, u64, Vec<Option<f64>>)> = vs
        .iter()
        .filter(|v| columns.iter().all(|c| v.values.contains_key(c)))
        .map(|v| {
            let mid =
                (v.mids.iter().map(|&m| m as u128).sum::<u128>() / v.mids.len() as u128) as u64;
            let t = (0..names.len())
                .map(|i| temperature_at(temps, i, v.from_ns, v.to_ns, mid))
                .collect();
            (v, mid, t)
        })
        .collect();
    let spindle_rpm = match spin {
        Some(i) => Some(spindle_per_visit(&rows, temps, i, path)?),
        None => None,
    };
    let kept: Vec<usize> = (0..names.len())
        .filter(|&i| Some(i) != spin && rows.iter().all(|(_, _, t)| t[i].is_some()))
        .collect();
    let dropped: Vec<&str> = (0..names.len())
        .filter(|i| !kept.contains(i) && Some(*i) != spin)
        .map(|i| names[i].as_str())
        .collect();
    if !dropped.is_empty() {
        errln!(
            "note: {}: sensors {dropped:?} have no reading for some visit (a sensor fault) and are left out",
            path.display()
        );
    }
    anyhow::ensure!(
        !kept.is_empty(),
        "{}: no temperature sensor has a reading for every visit",
        path.display()
    );
    let t0 = rows.first().map_or(0, |r| r.1);
    let ds = thermal::ThermalDataset {
        time_s: rows
            .iter()
            .map(|r| (r.1 - t0) as f64 * 1e-9 * scale)
            .collect(),
        spindle_rpm,
        sensor_names: kept.iter().map(|&i| names[i].clone()).collect(),
        temperatures_c: kept
            .iter()
            .map(|&i| rows.iter().map(|r| r.2[i].unwrap_or(f64::NAN)).collect())
            .collect(),
        channel_names: columns
            .iter()
            .map(|c| c.trim_end_matches("_um").to_string())
            .collect(),
        displacements_um: columns
            .iter()
            .map(|c| rows.iter().map(|r| r.0.values[c]).collect())
            .collect(),
    };
    anyhow::ensure!(
        ds.len() >= 2,
        "{}: {} visit(s) of the measuring pose with every value; a thermal test needs at least 2",
        path.display(),
        ds.len()
    );
    Ok(ds)
}

/// The module channel that carries the spindle speed (rpm), not a temperature.
pub const SPINDLE_CHANNEL: &str = "spindle_rpm";

/// Channel `i` per row: the root mean square of its readings after the previous row's window
/// through this row's (the first row: its window), else its value at the row's time.
fn spindle_per_visit(
    rows: &[(&Visit, u64, Vec<Option<f64>>)],
    temps: &[(u64, Vec<f64>)],
    i: usize,
    path: &Path,
) -> anyhow::Result<Vec<f64>> {
    let mut out = Vec::with_capacity(rows.len());
    let mut after = None;
    for (v, _, at) in rows {
        let inside: Vec<f64> = temps
            .iter()
            .filter(|(t, _)| after.map_or(*t >= v.from_ns, |a| *t > a) && *t <= v.to_ns)
            .filter_map(|(_, x)| x.get(i).copied().filter(|x| x.is_finite()))
            .collect();
        let value = if inside.is_empty() {
            at[i]
        } else {
            Some((inside.iter().map(|x| x * x).sum::<f64>() / inside.len() as f64).sqrt())
        };
        let Some(value) = value else {
            anyhow::bail!(
                "{}: `{SPINDLE_CHANNEL}` has no reading near the visit at {} ns",
                path.display(),
                v.from_ns
            );
        };
        out.push(value);
        after = Some(v.to_ns);
    }
    Ok(out)
}
