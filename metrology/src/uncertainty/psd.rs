//! Monte Carlo of the 13 errors the PSD laser frame measures (paper 003, §5 and Table 4):
//! virtual reading noise pushed through the measurement model ([`crate::psd_frame`]), the
//! uncertainty of each derived error read from the spread of the results.
//!
//! The measurement model is linear in the readings, so a derived error minus its true value is
//! the model applied to the noise alone; the random thermo-elastic errors the paper first
//! generates cancel out of the spread (they set where the results lie, not how they scatter),
//! and are left out.

use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, StandardNormal};
use serde::Serialize;

use super::UncertaintyError;
use super::mc::{self, McOptions, McResult, TrialSource};
use crate::psd_frame::{PsdLayout, PsdReadings, derive_errors};

/// Noise of the readings in the Monte Carlo.
struct PsdNoise {
    layout: PsdLayout,
    sigma_um: f64,
    n_in: usize,
    names: Vec<String>,
}

impl TrialSource for PsdNoise {
    type Scratch = Vec<f64>;
    fn n_outputs(&self) -> usize {
        self.names.len()
    }
    fn output_names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn scratch(&self) -> Vec<f64> {
        vec![0.0; self.n_in]
    }
    fn fill(&self, rng: &mut ChaCha8Rng, s: &mut Vec<f64>, out: &mut [f64]) {
        let n_out = self.names.len();
        for y in out.chunks_exact_mut(n_out) {
            for v in s.iter_mut() {
                let z: f64 = StandardNormal.sample(rng);
                *v = self.sigma_um * z;
            }
            match derive_errors(&self.layout, &PsdReadings::from_vec(&self.layout, s)) {
                Ok(e) => y.copy_from_slice(&e.to_vec()),
                // Cannot happen for a checked layout; NaN makes the run stop with a message.
                Err(_) => y.fill(f64::NAN),
            }
        }
    }
}

/// One line of our Table 4: the largest expanded uncertainty over the points of one error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table4Row {
    /// Error name as in paper 003 (EXX, EYX, …, EC0Y).
    pub error: String,
    /// Largest half-width of the 95 % Monte Carlo intervals over the error's points, in the
    /// error's own unit (µm, or µrad for rolls and squarenesses).
    pub expanded: f64,
    pub unit: &'static str,
    /// Angles as a length over `lever_mm` (paper 003 marks these "max. resulting linear
    /// uncertainty with respect to the measurement volume"), µm.
    pub expanded_linear_um: Option<f64>,
}

/// Runs the Table 4 study: `sigma_um` per reading (after the reference subtraction),
/// `trials` cycles (the paper ran 30 000). Angles are also given as lengths over `lever_mm`.
pub fn table4(
    layout: &PsdLayout,
    sigma_um: f64,
    trials: usize,
    seed: u64,
    lever_mm: f64,
) -> Result<(Vec<Table4Row>, McResult), UncertaintyError> {
    let n_in = 2 * (layout.n_s1 + 4 * layout.n_points);
    let zero = PsdReadings::from_vec(layout, &vec![0.0; n_in]);
    let names = derive_errors(layout, &zero)
        .map_err(|e| UncertaintyError::Invalid(format!("PSD measurement model: {e}")))?
        .names();
    let src = PsdNoise {
        layout: layout.clone(),
        sigma_um,
        n_in,
        names,
    };
    let r = mc::run(
        &src,
        &McOptions {
            fixed_trials: Some(trials),
            seed,
            ..McOptions::default()
        },
        None,
    )?;
    let groups = [
        "EXX", "EYY", "EYX", "EZX", "EXY", "EZY", "EXZ", "EYZ", "EAX", "EBY", "EC0Y", "EB0Z",
        "EA0Z",
    ];
    let rows = groups
        .iter()
        .map(|g| {
            let prefix = format!("{g}_");
            let u = r
                .outputs
                .iter()
                .filter(|o| o.name.starts_with(&prefix))
                .map(|o| 0.5 * (o.symmetric_interval[1] - o.symmetric_interval[0]))
                .fold(0.0, f64::max);
            let angle = g.starts_with("EA") || g.starts_with("EB") || g.starts_with("EC");
            Table4Row {
                error: g.to_string(),
                expanded: u,
                unit: if angle { "µrad" } else { "µm" },
                expanded_linear_um: angle.then_some(u * lever_mm * 1e-3),
            }
        })
        .collect();
    Ok((rows, r))
}
