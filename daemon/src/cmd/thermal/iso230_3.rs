//! `metrolog analyze thermal DATA.csv`: the ISO 230-3 evaluation of a thermal test — the
//! environmental temperature variation error (ETVE) of every displacement channel and, with
//! five probes named, the thermal distortion caused by the rotating spindle.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use serde::Serialize;
use thermal::iso230_3::{self, DistortionMaxima, FiveProbes};

use crate::cmd::input::{load_thermal, print_out};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Thermal test (CSV: `time_s`, temperatures `_c`, displacements `_um`), or a run's log
    /// (.mcap: `/temperature` and the measuring pose's values).
    pub input: PathBuf,
    /// The five probe channels of the spindle test, in the order X1,X2,Y1,Y2,Z (column names,
    /// with or without `_um`); X1/Y1 near the spindle nose, X2/Y2 further along the mandrel.
    #[arg(long, value_name = "X1,X2,Y1,Y2,Z", requires = "probe_spacing_mm")]
    pub probes: Option<String>,
    /// Distance between the near (X1, Y1) and far (X2, Y2) probes along the mandrel, mm.
    #[arg(long, value_name = "MM", requires = "probes")]
    pub probe_spacing_mm: Option<f64>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
pub(crate) struct Report {
    duration_s: f64,
    samples: usize,
    etve: Vec<Etve>,
    #[serde(skip_serializing_if = "Option::is_none")]
    spindle: Option<Spindle>,
}

#[derive(Debug, Serialize)]
struct Etve {
    channel: String,
    etve_um: f64,
}

#[derive(Debug, Serialize)]
struct Spindle {
    /// The probe channels, X1, X2, Y1, Y2, Z.
    probes: [String; 5],
    probe_spacing_mm: f64,
    max: DistortionMaxima,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let ds = load_thermal(&a.input)?;
    let probes = match (&a.probes, a.probe_spacing_mm) {
        (Some(p), Some(mm)) => Some((p.as_str(), mm)),
        _ => None,
    };
    let r = evaluate(&ds, probes, &a.input)?;
    let text = if a.json {
        serde_json::to_string_pretty(&r)? + "\n"
    } else {
        render(&r, &a.input.display().to_string())
    };
    print_out(&text)
}

/// The ISO 230-3 numbers of a dataset: every channel's ETVE and, with five probes named and
/// their spacing, the spindle's thermal distortion. Refused when any number is not finite.
pub(crate) fn evaluate(
    ds: &thermal::ThermalDataset,
    probes: Option<(&str, f64)>,
    input: &std::path::Path,
) -> anyhow::Result<Report> {
    anyhow::ensure!(
        !ds.channel_names.is_empty(),
        "{}: no displacement column (a name ending `_um`, e.g. `x_um`) to evaluate",
        input.display()
    );
    let mut etve = vec![];
    for (name, d) in ds.channel_names.iter().zip(&ds.displacements_um) {
        let e = iso230_3::etve(d).with_context(|| format!("ETVE of `{name}`"))?;
        etve.push(Etve {
            channel: name.clone(),
            etve_um: e,
        });
    }
    let spindle = match probes {
        Some((p, mm)) => Some(spindle(ds, p, mm, input)?),
        None => None,
    };
    let r = Report {
        duration_s: ds.time_s[ds.len() - 1] - ds.time_s[0],
        samples: ds.len(),
        etve,
        spindle,
    };
    check_finite(&r)?;
    Ok(r)
}

fn spindle(
    ds: &thermal::ThermalDataset,
    probes: &str,
    spacing_mm: f64,
    input: &std::path::Path,
) -> anyhow::Result<Spindle> {
    let names: Vec<String> = probes
        .split(',')
        .map(|s| s.trim().trim_end_matches("_um").to_string())
        .collect();
    anyhow::ensure!(
        names.len() == 5 && names.iter().all(|n| !n.is_empty()),
        "--probes `{probes}`: name five displacement columns, X1,X2,Y1,Y2,Z (e.g. \
         --probes ch1,ch2,ch3,ch4,ch5)"
    );
    let mut series = vec![];
    for n in &names {
        let i = ds.channel_index(n).with_context(|| {
            format!(
                "--probes: `{n}` is not a displacement column of {} (its columns: {})",
                input.display(),
                ds.channel_names
                    .iter()
                    .map(|c| format!("{c}_um"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?;
        series.push(ds.displacements_um[i].as_slice());
    }
    let d = iso230_3::spindle_distortion(
        FiveProbes {
            x1_um: series[0],
            x2_um: series[1],
            y1_um: series[2],
            y2_um: series[3],
            z_um: series[4],
        },
        spacing_mm,
    )
    .context("--probe-spacing-mm")?;
    let probes: [String; 5] = names.try_into().expect("five names checked above");
    Ok(Spindle {
        probes,
        probe_spacing_mm: spacing_mm,
        max: d.max,
    })
}

fn check_finite(r: &Report) -> anyhow::Result<()> {
    let mut all: Vec<f64> = r.etve.iter().map(|e| e.etve_um).collect();
    if let Some(s) = &r.spindle {
        let m = s.max;
        all.extend([m.x_um, m.y_um, m.z_um, m.a_urad, m.b_urad]);
    }
    anyhow::ensure!(
        all.iter().all(|v| v.is_finite()),
        "a result came out non-finite; nothing printed (check the displacement columns)"
    );
    Ok(())
}

pub(crate) fn render(r: &Report, input: &str) -> String {
    let mut s = format!(
        "ISO 230-3 thermal evaluation of {input} ({} samples over {:.2} h)\n\n\
         Environmental temperature variation error (ETVE: range of the displacement over the test)\n",
        r.samples,
        r.duration_s / 3600.0
    );
    for e in &r.etve {
        let _ = writeln!(s, "  {:<12} {:>10.3} µm", e.channel, e.etve_um);
    }
    if let Some(sp) = &r.spindle {
        let [x1, x2, y1, y2, z] = &sp.probes;
        let m = sp.max;
        let _ = write!(
            s,
            "\nThermal distortion caused by the rotating spindle (probes X1 {x1}, X2 {x2}, Y1 {y1}, \
             Y2 {y2}, Z {z}; spacing {} mm), largest change from the first reading\n\
             \x20 X  {:>10.3} µm\n  Y  {:>10.3} µm\n  Z  {:>10.3} µm\n  A  {:>10.3} µrad (tilt in YZ)\n  B  {:>10.3} µrad (tilt in XZ)\n",
            sp.probe_spacing_mm, m.x_um, m.y_um, m.z_um, m.a_urad, m.b_urad
        );
    }
    s
}
