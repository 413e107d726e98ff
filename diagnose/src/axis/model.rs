//! The diagnosis' models: the baseline fitted from a run, the `[axis]` table written by
//! `diagnose --write-model`, and the check that a model reproduces the measured statistics.

use serde::{Deserialize, Serialize};

use super::types::Reproduction;
use positioning::axis_model::AxisModel;
use positioning::iso230;
use positioning::positioning_data::{PositioningData, schedule_of, simulate};

/// An [`AxisModel`] as the `[axis]` table of a simulator scenario: what
/// `diagnose --write-model` writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisTable {
    pub axis: AxisModel,
}

/// Reads an axis model from TOML: an `[axis]` table (as written by `--write-model` and found
/// in scenarios; other tables are ignored) or a bare model.
pub fn axis_model_from_toml(text: &str) -> Result<AxisModel, toml::de::Error> {
    #[derive(Deserialize)]
    struct Any {
        axis: toml::Value,
    }
    // A bare model has `axis = "X"` (its name); a scenario has an `[axis]` table.
    match toml::from_str::<Any>(text) {
        Ok(Any {
            axis: toml::Value::Table(t),
        }) => toml::Value::Table(t).try_into(),
        _ => toml::from_str::<AxisModel>(text),
    }
}

/// The baseline model fitted from the data: per-target, per-direction means and the pooled
/// noise, no effects.
pub fn baseline_model(data: &PositioningData) -> AxisModel {
    let rep = iso230::evaluate(data);
    let mut ss = 0.0;
    let mut dof = 0.0;
    for t in &rep.targets {
        for (s, n) in [(t.s_up_um, t.n_up), (t.s_down_um, t.n_down)] {
            if let Some(s) = s {
                ss += s * s * (n as f64 - 1.0);
                dof += n as f64 - 1.0;
            }
        }
    }
    AxisModel {
        axis: data.axis.clone().unwrap_or_else(|| "X".into()),
        targets_mm: data
            .targets_mm()
            .iter()
            .map(|x| if x.is_finite() { *x } else { 0.0 })
            .collect(),
        systematic_up_um: rep
            .targets
            .iter()
            .map(|t| t.mean_up_um.unwrap_or(0.0))
            .collect(),
        systematic_down_um: rep
            .targets
            .iter()
            .map(|t| t.mean_down_um.unwrap_or(0.0))
            .collect(),
        noise_um: if dof > 0.0 { (ss / dof).sqrt() } else { 0.0 },
        effects: Vec::new(),
    }
}

/// Simulates `model` over the same readings (cycles, directions, times) as `data`, with
/// `seeds` seeds, and measures how closely the simulated per-target ISO 230-2 statistics
/// (x̄↑ x̄↓ s↑ s↓) match the measured ones; the baseline model is scored the same way.
pub fn reproduction_check(data: &PositioningData, model: &AxisModel, seeds: usize) -> Reproduction {
    let measured = iso230::evaluate(data);
    let schedule = schedule_of(data);
    let base = baseline_model(data);
    let score = |m: &AxisModel| {
        let (mut em, mut es) = (0.0, 0.0);
        for seed in 0..seeds.max(1) {
            let sim = iso230::evaluate(&simulate(m, &schedule, 0x5eed + seed as u64));
            let (mut sm, mut nm, mut ss, mut ns) = (0.0, 0usize, 0.0, 0usize);
            for (a, b) in sim.targets.iter().zip(&measured.targets) {
                for (x, y) in [
                    (a.mean_up_um, b.mean_up_um),
                    (a.mean_down_um, b.mean_down_um),
                ] {
                    if let (Some(x), Some(y)) = (x, y) {
                        sm += (x - y).powi(2);
                        nm += 1;
                    }
                }
                for (x, y) in [(a.s_up_um, b.s_up_um), (a.s_down_um, b.s_down_um)] {
                    if let (Some(x), Some(y)) = (x, y) {
                        ss += (x - y).powi(2);
                        ns += 1;
                    }
                }
            }
            em += (sm / nm.max(1) as f64).sqrt();
            es += (ss / ns.max(1) as f64).sqrt();
        }
        let k = seeds.max(1) as f64;
        (em / k, es / k)
    };
    let (mean_rms_um, s_rms_um) = score(model);
    let (baseline_mean_rms_um, baseline_s_rms_um) = score(&base);
    Reproduction {
        mean_rms_um,
        s_rms_um,
        baseline_mean_rms_um,
        baseline_s_rms_um,
        seeds: seeds.max(1),
    }
}
