//! `metrolog thermal fit DATA.csv -o MODEL.json`: fit and write the thermal model, print it in
//! physical terms.

use std::path::PathBuf;

use anyhow::Context as _;

use crate::cmd::input::{load_thermal, print_out, write_output};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Thermal test (CSV: `time_s`, temperatures `_c`, displacements `_um`, optional
    /// `spindle_rpm`), or a run's log (.mcap: `/temperature` and the measuring pose's values).
    pub input: PathBuf,
    /// Where to write the model (JSON).
    #[arg(short = 'o', long = "out", value_name = "MODEL.json")]
    pub out: PathBuf,
    /// Only these sensors may be used (comma-separated names without `_c`) [default: all].
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    pub sensors: Vec<String>,
    /// Contiguous time blocks held out in turn to judge each step [default: 8, fewer (at least
    /// 3) for a test of under 80 samples].
    #[arg(long, value_name = "N")]
    pub blocks: Option<usize>,
    /// Most terms per channel.
    #[arg(long, default_value_t = 6, value_name = "N")]
    pub max_terms: usize,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let ds = load_thermal(&a.input)?;
    anyhow::ensure!(
        !ds.channel_names.is_empty(),
        "{}: no displacement column (a name ending `_um`, e.g. `x_um`); a model is fitted to \
         measured displacements",
        a.input.display()
    );
    for s in &a.sensors {
        anyhow::ensure!(
            ds.sensor_index(s).is_some(),
            "--sensors: `{s}` is not a sensor of {} (its sensors: {})",
            a.input.display(),
            ds.sensor_names.join(", ")
        );
    }
    let opts = thermal::FitOptions {
        blocks: super::blocks_for(ds.len(), a.blocks),
        max_terms: a.max_terms,
        sensors: (!a.sensors.is_empty()).then(|| a.sensors.clone()),
        ..thermal::FitOptions::default()
    };
    let model = thermal::fit(&ds, &opts)
        .with_context(|| format!("fitting the thermal model of {}", a.input.display()))?;
    let json = model_json(&model)?;
    write_output(&a.out, &json)?;
    let hours = (ds.time_s[ds.len() - 1] - ds.time_s[0]) / 3600.0;
    let text = format!(
        "Thermal model of {} ({} samples over {hours:.2} h, {} sensors{}), written to {}\n\n{}",
        a.input.display(),
        ds.len(),
        ds.sensor_names.len(),
        if ds.spindle_rpm.is_some() {
            ", spindle speed"
        } else {
            ", no spindle speed"
        },
        a.out.display(),
        model.describe()
    );
    print_out(&text)
}

/// The model as JSON, refused when any of its numbers is not finite (serde_json would write
/// `null`, which no reader could take back as a number).
pub(crate) fn model_json(model: &thermal::ThermalModel) -> anyhow::Result<String> {
    for c in &model.channels {
        let all = c.numbers();
        anyhow::ensure!(
            all.iter().all(|v| v.is_finite()),
            "the fitted model of `{}` holds a non-finite number; not written (the data are \
             probably degenerate: a constant or duplicated column)",
            c.channel
        );
    }
    Ok(serde_json::to_string_pretty(model)? + "\n")
}
