//! Predicted displacements with their intervals.

use crate::error::ThermalError;
use serde::{Deserialize, Serialize};

/// Predicted displacements of every channel of a model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Prediction {
    /// Sample times, s.
    pub time_s: Vec<f64>,
    /// One series per channel.
    pub channels: Vec<ChannelPrediction>,
}

/// One channel's predicted displacement and its prediction interval.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChannelPrediction {
    /// Channel name.
    pub channel: String,
    /// Predicted displacement, µm.
    pub values_um: Vec<f64>,
    /// Lower end of the prediction interval, µm.
    pub lower_um: Vec<f64>,
    /// Upper end of the prediction interval, µm.
    pub upper_um: Vec<f64>,
}

impl Prediction {
    /// The prediction of channel `name`.
    pub fn channel(&self, name: &str) -> Option<&ChannelPrediction> {
        self.channels.iter().find(|c| c.channel == name)
    }
}

pub(crate) fn check_finite(p: &Prediction) -> Result<(), ThermalError> {
    for c in &p.channels {
        let all = c.values_um.iter().chain(&c.lower_um).chain(&c.upper_um);
        if !all.into_iter().all(|v| v.is_finite()) {
            return Err(ThermalError::NonFinite {
                what: format!("prediction of `{}`", c.channel),
            });
        }
    }
    Ok(())
}
