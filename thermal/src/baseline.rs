//! The static reference: each displacement channel least-squares on all temperatures.

use crate::cv::{BlockStats, Blocks, heldout_residuals};
use crate::dataset::ThermalDataset;
use crate::error::ThermalError;
use crate::predict::{ChannelPrediction, Prediction, check_finite};
use serde::{Deserialize, Serialize};

/// One channel of the static fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StaticChannel {
    /// Channel name.
    pub channel: String,
    /// Intercept, µm (displacement at 0 °C on every sensor: not physical, only a constant).
    pub intercept_um: f64,
    /// µm per K, one per sensor in the dataset's order.
    pub coefficients_um_per_k: Vec<f64>,
    /// RMS of the residuals of the fit, µm.
    pub fit_rms_um: f64,
    /// RMS of the residuals of each time block predicted from the others, µm.
    pub heldout_rms_um: f64,
}

/// The static all-temperature least-squares fit of every channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StaticFit {
    /// Sensor names, in the order of the coefficients.
    pub sensors: Vec<String>,
    /// One fit per displacement channel.
    pub channels: Vec<StaticChannel>,
}

/// Fits every displacement channel on all temperatures plus an intercept.
///
/// `blocks` contiguous time blocks are held out in turn for `heldout_rms_um`.
pub fn static_fit(ds: &ThermalDataset, blocks: usize) -> Result<StaticFit, ThermalError> {
    if ds.channel_names.is_empty() {
        return Err(ThermalError::Mismatch {
            what: "the dataset has no displacement column (`_um`) to fit".into(),
        });
    }
    if ds.len() < 4 * (ds.sensor_names.len() + 1) || ds.len() < 2 * blocks {
        return Err(ThermalError::TooFewSamples {
            what: format!(
                "{} samples for {} sensors and {blocks} blocks",
                ds.len(),
                ds.sensor_names.len()
            ),
        });
    }
    let b = Blocks::contiguous(ds.len(), blocks);
    let cols: Vec<&[f64]> = ds.temperatures_c.iter().map(|v| v.as_slice()).collect();
    let mut channels = vec![];
    for (name, y) in ds.channel_names.iter().zip(&ds.displacements_um) {
        channels.push(fit_channel(name, &cols, y, &b)?);
    }
    Ok(StaticFit {
        sensors: ds.sensor_names.clone(),
        channels,
    })
}

fn fit_channel(
    name: &str,
    cols: &[&[f64]],
    y: &[f64],
    b: &Blocks,
) -> Result<StaticChannel, ThermalError> {
    let nonfinite = || ThermalError::NonFinite {
        what: format!("static fit of `{name}`"),
    };
    let stats = BlockStats::new(cols, y, b);
    let beta = stats.coefficients(None).ok_or_else(nonfinite)?;
    let heldout = heldout_residuals(cols, y, b).ok_or_else(nonfinite)?;
    let fit_sse: f64 = (0..y.len())
        .map(|i| (y[i] - crate::cv::predict_row(&beta, cols, i)).powi(2))
        .sum();
    let ch = StaticChannel {
        channel: name.to_string(),
        intercept_um: beta[0],
        coefficients_um_per_k: beta.iter().skip(1).copied().collect(),
        fit_rms_um: (fit_sse / y.len() as f64).sqrt(),
        heldout_rms_um: rms(&heldout),
    };
    let all = ch.coefficients_um_per_k.iter().chain([
        &ch.intercept_um,
        &ch.fit_rms_um,
        &ch.heldout_rms_um,
    ]);
    if all.into_iter().all(|v| v.is_finite()) {
        Ok(ch)
    } else {
        Err(nonfinite())
    }
}

pub(crate) fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

impl StaticFit {
    /// Displacements predicted from the temperatures of `ds` (no interval: the static fit
    /// is the reference, not a model to trust).
    pub fn predict(&self, ds: &ThermalDataset) -> Result<Prediction, ThermalError> {
        let idx: Vec<usize> = self
            .sensors
            .iter()
            .map(|s| {
                ds.sensor_index(s).ok_or_else(|| ThermalError::Mismatch {
                    what: format!("sensor `{s}` of the fit is not in the dataset"),
                })
            })
            .collect::<Result<_, _>>()?;
        let channels = self
            .channels
            .iter()
            .map(|ch| {
                let values: Vec<f64> = (0..ds.len())
                    .map(|i| {
                        ch.intercept_um
                            + idx
                                .iter()
                                .zip(&ch.coefficients_um_per_k)
                                .map(|(&s, a)| a * ds.temperatures_c[s][i])
                                .sum::<f64>()
                    })
                    .collect();
                ChannelPrediction {
                    channel: ch.channel.clone(),
                    lower_um: values.clone(),
                    upper_um: values.clone(),
                    values_um: values,
                }
            })
            .collect();
        let p = Prediction {
            time_s: ds.time_s.clone(),
            channels,
        };
        check_finite(&p)?;
        Ok(p)
    }
}
