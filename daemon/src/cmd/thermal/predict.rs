//! `metrolog thermal predict MODEL.json DATA.csv -o PRED.csv`: displacements and their
//! prediction intervals from temperatures and spindle speed alone.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context as _;

use crate::cmd::input::{load_thermal, print_out, write_output};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Model written by `metrolog thermal fit` (JSON).
    pub model: PathBuf,
    /// Temperatures (and `spindle_rpm` if the model uses it) to predict from (CSV);
    /// displacement columns may be absent and are not used.
    pub input: PathBuf,
    /// Where to write the prediction (CSV): `time_s`, then per channel `NAME_um`,
    /// `NAME_lower_um`, `NAME_upper_um`.
    #[arg(short = 'o', long = "out", value_name = "PRED.csv")]
    pub out: PathBuf,
    /// The samples just before DATA (same sensors, e.g. the fitting test): the lags run over
    /// them first instead of starting at rest on DATA's first sample.
    #[arg(long, value_name = "FILE")]
    pub history: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let model = load_model(&a.model)?;
    let ds = load_thermal(&a.input)?;
    check_inputs(&model, &ds, &a.input)?;
    let pred = match &a.history {
        None => model.predict(&ds),
        Some(h) => {
            let hist = load_thermal(h)?;
            check_inputs(&model, &hist, h)?;
            model.predict_after(&hist, &ds)
        }
    }
    .with_context(|| format!("predicting {}", a.input.display()))?;
    let level = model.channels.first().map_or(0.95, |c| c.interval.level);
    write_output(&a.out, &prediction_csv(&pred, level)?)?;
    let mut text = format!(
        "Predicted {} channel(s) over {} samples of {}, written to {}\n",
        pred.channels.len(),
        pred.time_s.len(),
        a.input.display(),
        a.out.display()
    );
    for (c, m) in pred.channels.iter().zip(&model.channels) {
        let (lo, hi) = c
            .values_um
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                (l.min(*v), h.max(*v))
            });
        let _ = writeln!(
            text,
            "  {}: {lo:+.3} … {hi:+.3} µm, {:.0} % interval ±{:.3} µm",
            c.channel,
            100.0 * m.interval.level,
            m.interval.half_width_um
        );
    }
    if let Some(c) = pred.channels.first()
        && ds.channel_index(&c.channel).is_some()
    {
        let _ = writeln!(text, "  (the data's displacement columns were not used)");
    }
    print_out(&text)
}

fn load_model(path: &Path) -> anyhow::Result<thermal::ThermalModel> {
    let text = crate::cmd::input::read_text(path)?;
    let model: thermal::ThermalModel = serde_json::from_str(&text).with_context(|| {
        format!(
            "{} is not a thermal model (write one with `metrolog thermal fit DATA.csv -o \
             MODEL.json`)",
            path.display()
        )
    })?;
    anyhow::ensure!(
        !model.channels.is_empty(),
        "{}: the model has no channel",
        path.display()
    );
    Ok(model)
}

/// Every sensor the model uses, and the spindle speed if it uses it, must be in the data:
/// the error names each one missing.
fn check_inputs(
    model: &thermal::ThermalModel,
    ds: &thermal::ThermalDataset,
    path: &Path,
) -> anyhow::Result<()> {
    let mut missing: Vec<String> = vec![];
    for t in model.channels.iter().flat_map(|c| &c.terms) {
        let col = match &t.input {
            thermal::Input::Sensor { name, .. } if ds.sensor_index(name).is_none() => {
                format!("`{name}_c` (sensor {name})")
            }
            thermal::Input::Spindle { .. } if ds.spindle_rpm.is_none() => "`spindle_rpm`".into(),
            _ => continue,
        };
        if !missing.contains(&col) {
            missing.push(col);
        }
    }
    anyhow::ensure!(
        missing.is_empty(),
        "{} lacks what the model uses: {}; add the column(s) or fit a model without them \
         (`metrolog thermal fit --sensors ...`)",
        path.display(),
        missing.join(", ")
    );
    Ok(())
}

/// The prediction as CSV; refused if any value is not finite.
pub(crate) fn prediction_csv(p: &thermal::Prediction, level: f64) -> anyhow::Result<String> {
    for c in &p.channels {
        let all = c.values_um.iter().chain(&c.lower_um).chain(&c.upper_um);
        anyhow::ensure!(
            all.into_iter().all(|v| v.is_finite()),
            "the prediction of `{}` holds a non-finite value; not written",
            c.channel
        );
    }
    let mut s = format!(
        "# predicted by metrolog thermal predict; lower/upper: the model's {:.0} % prediction interval\ntime_s",
        100.0 * level
    );
    for c in &p.channels {
        let n = &c.channel;
        let _ = write!(s, ",{n}_um,{n}_lower_um,{n}_upper_um");
    }
    s.push('\n');
    for (i, t) in p.time_s.iter().enumerate() {
        let _ = write!(s, "{t}");
        for c in &p.channels {
            let _ = write!(s, ",{},{},{}", c.values_um[i], c.lower_um[i], c.upper_um[i]);
        }
        s.push('\n');
    }
    Ok(s)
}
