//! The thermal model: chosen sensors through first-order lags plus spindle heat, per channel.

use crate::baseline::{rms, static_fit};
use crate::cv::{BlockStats, Blocks, GainRule, forward_residuals, heldout_residuals, predict_row};
use crate::dataset::ThermalDataset;
use crate::error::ThermalError;
use crate::inputs::{Inputs, Spec, Src, tau_grid};
use crate::predict::{ChannelPrediction, Prediction, check_finite};
use crate::select::{Pool, Search, Selection};
use serde::{Deserialize, Serialize};

/// What `fit` may use and how it judges a step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitOptions {
    /// Contiguous time blocks held out in turn (8).
    pub blocks: usize,
    /// Most terms per channel (6).
    pub max_terms: usize,
    /// Whether a sensor's reading may lag (its time constant searched).
    pub sensor_lags: bool,
    /// Spindle heat inputs tried, as powers of the speed (1: rpm, 2: rpm²); empty: none.
    pub spindle_exponents: Vec<u32>,
    /// Whether the spindle input may heat and cool with different time constants.
    pub asymmetric: bool,
    /// Sensors that may be used (`None`: all).
    pub sensors: Option<Vec<String>>,
    /// The rule a step must pass on held-out blocks.
    pub rule: GainRule,
    /// Level of the prediction intervals (0.95).
    pub interval_level: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            blocks: 8,
            max_terms: 6,
            sensor_lags: true,
            spindle_exponents: vec![2],
            asymmetric: true,
            sensors: None,
            rule: GainRule {
                min_relative_gain: 0.05,
                min_t: 0.0,
            },
            interval_level: 0.95,
        }
    }
}

/// A term's input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Input {
    /// A sensor's temperature rise above `reference_c`, K.
    Sensor { name: String, reference_c: f64 },
    /// Spindle speed as (rpm / 1000)^exponent: a heat source no sensor needs to see.
    Spindle { exponent: u32 },
}

/// One term: an input through a first-order lag, times a coefficient.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Term {
    pub input: Input,
    /// Time constant while the input rises above the lagged value, s (0: no lag).
    pub tau_heat_s: f64,
    /// Time constant while it falls below, s.
    pub tau_cool_s: f64,
    /// Steady-state displacement per unit of input: µm/K, or µm per (1000 rpm)^exponent.
    pub coefficient: f64,
}

impl Term {
    /// The coefficient's unit.
    pub fn unit(&self) -> String {
        match &self.input {
            Input::Sensor { .. } => "µm/K".into(),
            Input::Spindle { exponent: 1 } => "µm per 1000 rpm".into(),
            Input::Spindle { exponent } => format!("µm per (1000 rpm)^{exponent}"),
        }
    }

    /// One line in physical terms.
    pub fn describe(&self) -> String {
        let what = match &self.input {
            Input::Sensor { name, reference_c } => {
                format!("sensor {name} (rise above {reference_c:.2} °C)")
            }
            Input::Spindle { exponent: 1 } => "spindle speed".into(),
            Input::Spindle { exponent } => format!("spindle speed^{exponent}"),
        };
        let lag = if self.tau_heat_s == self.tau_cool_s {
            if self.tau_heat_s == 0.0 {
                "no lag".into()
            } else {
                format!("lag τ = {:.1} min", self.tau_heat_s / 60.0)
            }
        } else {
            format!(
                "heating τ = {:.1} min, cooling τ = {:.1} min",
                self.tau_heat_s / 60.0,
                self.tau_cool_s / 60.0
            )
        };
        format!("{what}, {lag}: {:+.3} {}", self.coefficient, self.unit())
    }
}

/// A prediction interval and how often it held on held-out blocks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    /// Intended level (0.95).
    pub level: f64,
    /// Half-width, µm: the level's quantile of the absolute residuals of the second half's
    /// blocks, each predicted forward in time by a fit on the blocks before it.
    pub half_width_um: f64,
    /// Fraction of those forward residuals inside an interval taken from the other blocks.
    pub heldout_coverage: f64,
}

/// The model of one displacement channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChannelModel {
    pub channel: String,
    /// Displacement with every input at its reference, µm.
    pub intercept_um: f64,
    pub terms: Vec<Term>,
    /// RMS of the fit's residuals, µm.
    pub fit_rms_um: f64,
    /// RMS of the residuals of each block predicted from the others, µm.
    pub heldout_rms_um: f64,
    /// The same for the static all-temperature fit, µm.
    pub static_heldout_rms_um: f64,
    pub interval: Interval,
    /// Short-term noise of the displacement, µm (robust, from its second differences): what
    /// no model of temperatures and speed can predict. 0 in a model written before it existed.
    #[serde(default)]
    pub noise_um: f64,
}

impl ChannelModel {
    /// Every number the model holds: a model is written or used only when all are finite.
    pub fn numbers(&self) -> Vec<f64> {
        let mut all = vec![
            self.intercept_um,
            self.noise_um,
            self.fit_rms_um,
            self.heldout_rms_um,
            self.static_heldout_rms_um,
            self.interval.level,
            self.interval.half_width_um,
            self.interval.heldout_coverage,
        ];
        for t in &self.terms {
            all.extend([t.coefficient, t.tau_heat_s, t.tau_cool_s]);
            if let Input::Sensor { reference_c, .. } = &t.input {
                all.push(*reference_c);
            }
        }
        all
    }
}

/// A held-out RMS above this many times the displacement's short-term noise is mostly what the
/// model does not describe, and `describe` says so.
const MISSED_NOISE_RATIO: f64 = 2.0;

/// A fitted thermal model (serialisable to JSON).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalModel {
    pub channels: Vec<ChannelModel>,
    pub options: FitOptions,
}

/// Fits a thermal model to every displacement channel of `ds`.
/// The largest thermal test `fit` and `diagnose` take, as samples × (sensors + 1): the lagged
/// candidate columns grow with both. `tests/sweep/largest_inputs.py` measured `diagnose` at
/// about 490 bytes per unit (100 000 samples of 16 sensors: 0.83 GB); this bound keeps it
/// under about 0.75 GB — 88 000 samples of 16 sensors, 15 days at one sample every 15 s.
pub const MAX_SIZE: usize = 1_500_000;

/// Refuses a test past [`MAX_SIZE`], saying how to bring it within.
pub(crate) fn check_size(ds: &ThermalDataset) -> Result<(), ThermalError> {
    let size = ds.len() * (ds.sensor_names.len() + 1);
    if size > MAX_SIZE {
        return Err(ThermalError::Parameter {
            what: format!(
                "{} samples of {} sensors are too many to model (samples × (sensors + 1) = {size}, at most {MAX_SIZE}): thin the file (every n-th row) or split it in time",
                ds.len(),
                ds.sensor_names.len()
            ),
        });
    }
    Ok(())
}

pub fn fit(ds: &ThermalDataset, opts: &FitOptions) -> Result<ThermalModel, ThermalError> {
    check_size(ds)?;
    let stat = static_fit(ds, opts.blocks)?;
    check_options(ds, opts)?;
    let refs = reference_temperatures(ds);
    let inputs = Inputs::new(ds, &refs);
    let pool = pool(ds, opts)?;
    let mut channels = vec![];
    for (c, st) in stat.channels.iter().enumerate() {
        let search = searcher(&inputs, &ds.displacements_um[c], opts);
        let sel = search
            .select(&pool, opts.max_terms)
            .ok_or_else(|| ThermalError::NonFinite {
                what: format!("selection for `{}`", st.channel),
            })?;
        channels.push(channel_model(
            ds,
            &refs,
            &search,
            &sel,
            st.heldout_rms_um,
            opts,
        )?);
    }
    Ok(ThermalModel {
        channels,
        options: opts.clone(),
    })
}

pub(crate) fn searcher<'a>(inputs: &'a Inputs, y: &'a [f64], opts: &FitOptions) -> Search<'a> {
    Search {
        inputs,
        y,
        blocks: Blocks::contiguous(y.len(), opts.blocks),
        grid: tau_grid(&inputs.time_s),
        rule: opts.rule,
        sensor_lags: opts.sensor_lags,
        memo: Default::default(),
    }
}

/// The fewest samples a held-out block may have.
pub const MIN_BLOCK_SAMPLES: usize = 10;

fn check_options(ds: &ThermalDataset, opts: &FitOptions) -> Result<(), ThermalError> {
    let bad = |what: String| Err(ThermalError::Parameter { what });
    if opts.blocks < 3 || ds.len() < MIN_BLOCK_SAMPLES * opts.blocks {
        return bad(format!(
            "{} blocks on {} samples: use 3 or more blocks of 10 samples or more",
            opts.blocks,
            ds.len()
        ));
    }
    if !(opts.interval_level > 0.0 && opts.interval_level < 1.0) {
        return bad(format!(
            "interval level {} is not between 0 and 1",
            opts.interval_level
        ));
    }
    if opts
        .spindle_exponents
        .iter()
        .any(|&p| !(1..=3).contains(&p))
    {
        return bad("spindle exponents must be 1, 2 or 3".into());
    }
    Ok(())
}

/// Each sensor's reference: the median of its first five readings (a noisy first reading
/// should not set it).
pub(crate) fn reference_temperatures(ds: &ThermalDataset) -> Vec<f64> {
    ds.temperatures_c
        .iter()
        .map(|t| {
            let mut v: Vec<f64> = t.iter().take(5).copied().collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        })
        .collect()
}

pub(crate) fn pool(ds: &ThermalDataset, opts: &FitOptions) -> Result<Pool, ThermalError> {
    // A sensor whose reading never changes is the intercept again: a term of it can only fit
    // rounding noise, and it was chosen once per step (the same zero term listed six times).
    let sensors = match &opts.sensors {
        None => (0..ds.sensor_names.len())
            .filter(|&i| varies(&ds.temperatures_c[i]))
            .collect(),
        Some(names) => names
            .iter()
            .map(|n| {
                ds.sensor_index(n).ok_or_else(|| ThermalError::Mismatch {
                    what: format!("sensor `{n}` asked for is not in the dataset"),
                })
            })
            .collect::<Result<_, _>>()?,
    };
    let spindle = if ds.spindle_rpm.as_deref().is_some_and(varies) {
        opts.spindle_exponents.clone()
    } else {
        vec![]
    };
    Ok(Pool {
        sensors,
        spindle_exponents: spindle,
        asymmetric: opts.asymmetric,
        max_spindle_terms: usize::MAX,
    })
}

/// Whether a column holds two different values.
fn varies(v: &[f64]) -> bool {
    v.iter().any(|x| Some(x) != v.first())
}

fn channel_model(
    ds: &ThermalDataset,
    refs: &[f64],
    search: &Search,
    sel: &Selection,
    static_rms: f64,
    opts: &FitOptions,
) -> Result<ChannelModel, ThermalError> {
    let name = &ds.channel_names[channel_of(ds, search.y)];
    let nonfinite = || ThermalError::NonFinite {
        what: format!("model of `{name}`"),
    };
    let cols = search.columns(&sel.specs).ok_or_else(nonfinite)?;
    let refs_cols: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let beta = BlockStats::new(&refs_cols, search.y, &search.blocks)
        .coefficients(None)
        .ok_or_else(nonfinite)?;
    let fitted: Vec<f64> = (0..search.y.len())
        .map(|i| search.y[i] - predict_row(&beta, &refs_cols, i))
        .collect();
    let heldout = heldout_residuals(&refs_cols, search.y, &search.blocks).ok_or_else(nonfinite)?;
    let terms = sel
        .specs
        .iter()
        .zip(beta.iter().skip(1))
        .map(|(s, &b)| term_of(ds, refs, s, b))
        .collect();
    let m = ChannelModel {
        channel: name.clone(),
        intercept_um: beta[0],
        terms,
        fit_rms_um: rms(&fitted),
        heldout_rms_um: rms(&heldout),
        static_heldout_rms_um: static_rms,
        noise_um: Some(crate::sensors::short_term_noise_of_moving(search.y))
            .filter(|v| v.is_finite())
            .unwrap_or(0.0),
        interval: {
            // Extrapolation, not interpolation, is what a prediction does: the interval is
            // taken from the residuals of the later blocks predicted forward in time from the
            // blocks before them, not from blocks held out between fitted ones (whose 95 %
            // quantile covered 5-29 % of the real run's last 40 %).
            let (fwd, fwd_blocks) = forward_residuals(
                &refs_cols,
                search.y,
                &search.blocks,
                search.blocks.0.len() / 2,
            )
            .ok_or_else(nonfinite)?;
            interval(&fwd, &fwd_blocks, opts.interval_level)
        },
    };
    check_model(&m).map(|_| m).ok_or_else(nonfinite)
}

fn channel_of(ds: &ThermalDataset, y: &[f64]) -> usize {
    ds.displacements_um
        .iter()
        .position(|d| std::ptr::eq(d.as_slice(), y))
        .unwrap_or(0)
}

pub(crate) fn term_of(ds: &ThermalDataset, refs: &[f64], s: &Spec, coefficient: f64) -> Term {
    let input = match s.src {
        // `Smoothed` is the diagnosis's alone (never in a fit's pool).
        Src::Sensor(i) | Src::Smoothed(i) => Input::Sensor {
            name: ds.sensor_names[i].clone(),
            reference_c: refs[i],
        },
        Src::Spindle(p) => Input::Spindle { exponent: p },
    };
    Term {
        input,
        tau_heat_s: s.tau_heat_s,
        tau_cool_s: s.tau_cool_s,
        coefficient,
    }
}

fn check_model(m: &ChannelModel) -> Option<()> {
    m.numbers().iter().all(|v| v.is_finite()).then_some(())
}

/// The interval's half-width from all held-out residuals, and its coverage block by block
/// with the half-width taken from the other blocks.
pub(crate) fn interval(heldout: &[f64], blocks: &Blocks, level: f64) -> Interval {
    let abs: Vec<f64> = heldout.iter().map(|r| r.abs()).collect();
    let mut covered = 0usize;
    for r in &blocks.0 {
        let others: Vec<f64> = abs
            .iter()
            .enumerate()
            .filter(|(i, _)| !r.contains(i))
            .map(|(_, v)| *v)
            .collect();
        let hw = quantile(others, level);
        covered += abs[r.clone()].iter().filter(|&&v| v <= hw).count();
    }
    Interval {
        level,
        half_width_um: quantile(abs.clone(), level),
        heldout_coverage: covered as f64 / abs.len().max(1) as f64,
    }
}

pub(crate) fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let pos = (q * (v.len() - 1) as f64).clamp(0.0, (v.len() - 1) as f64);
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

impl ThermalModel {
    /// Predicts every channel from the temperatures (and speed) of `ds`. Each lag starts at
    /// rest on the first sample's input; use [`ThermalModel::predict_after`] to carry the
    /// lags' state over from the samples before.
    pub fn predict(&self, ds: &ThermalDataset) -> Result<Prediction, ThermalError> {
        let (inputs, specs) = self.inputs_for(ds)?;
        let mut channels = vec![];
        for (m, specs) in self.channels.iter().zip(&specs) {
            let cols: Vec<_> = specs
                .iter()
                .map(|s| {
                    inputs
                        .column(s)
                        .ok_or_else(|| mismatch("spindle_rpm is needed by the model"))
                })
                .collect::<Result<_, _>>()?;
            let values: Vec<f64> = (0..ds.len())
                .map(|i| {
                    m.intercept_um
                        + m.terms
                            .iter()
                            .zip(&cols)
                            .map(|(t, c)| t.coefficient * c[i])
                            .sum::<f64>()
                })
                .collect();
            let hw = m.interval.half_width_um;
            channels.push(ChannelPrediction {
                channel: m.channel.clone(),
                lower_um: values.iter().map(|v| v - hw).collect(),
                upper_um: values.iter().map(|v| v + hw).collect(),
                values_um: values,
            });
        }
        let p = Prediction {
            time_s: ds.time_s.clone(),
            channels,
        };
        check_finite(&p)?;
        Ok(p)
    }

    /// Predicts `ds` with the lags run over `history` first (the samples just before it,
    /// with the same sensors; their displacements are not used).
    pub fn predict_after(
        &self,
        history: &ThermalDataset,
        ds: &ThermalDataset,
    ) -> Result<Prediction, ThermalError> {
        let joined = history.join_inputs(ds)?;
        let mut p = self.predict(&joined)?;
        let skip = history.len();
        p.time_s.drain(..skip);
        for c in &mut p.channels {
            c.values_um.drain(..skip);
            c.lower_um.drain(..skip);
            c.upper_um.drain(..skip);
        }
        Ok(p)
    }

    fn inputs_for(&self, ds: &ThermalDataset) -> Result<(Inputs, Vec<Vec<Spec>>), ThermalError> {
        let mut refs = vec![0.0; ds.sensor_names.len()];
        let mut specs = vec![];
        for m in &self.channels {
            let mut v = vec![];
            for t in &m.terms {
                let src = match &t.input {
                    Input::Sensor { name, reference_c } => {
                        let i = ds.sensor_index(name).ok_or_else(|| {
                            mismatch(&format!(
                                "sensor `{name}` of the model is not in the dataset"
                            ))
                        })?;
                        refs[i] = *reference_c;
                        Src::Sensor(i)
                    }
                    Input::Spindle { exponent } => Src::Spindle(*exponent),
                };
                v.push(Spec {
                    src,
                    tau_heat_s: t.tau_heat_s,
                    tau_cool_s: t.tau_cool_s,
                });
            }
            specs.push(v);
        }
        Ok((Inputs::new(ds, &refs), specs))
    }

    /// The model in physical terms, one block per channel.
    pub fn describe(&self) -> String {
        let mut s = String::new();
        for m in &self.channels {
            s += &format!(
                "{}: held-out RMS {:.3} µm (static all-temperature fit {:.3} µm), {:.0} % interval ±{:.3} µm (held-out coverage {:.1} %)\n",
                m.channel,
                m.heldout_rms_um,
                m.static_heldout_rms_um,
                100.0 * m.interval.level,
                m.interval.half_width_um,
                100.0 * m.interval.heldout_coverage
            );
            s += &noise_line(m);
            s += &format!("  constant {:+.3} µm\n", m.intercept_um);
            for t in &m.terms {
                s += &format!("  {}\n", t.describe());
            }
        }
        s
    }
}

fn mismatch(what: &str) -> ThermalError {
    ThermalError::Mismatch {
        what: what.to_string(),
    }
}

/// The held-out RMS against the displacement's short-term noise, and what it means when the
/// model leaves well above it (nothing for a model written before the noise was kept).
fn noise_line(m: &ChannelModel) -> String {
    if m.noise_um.is_nan() || m.noise_um <= 0.0 {
        return String::new();
    }
    let ratio = m.heldout_rms_um / m.noise_um;
    if !ratio.is_finite() {
        return String::new();
    }
    let mut s = format!(
        "  held out, {ratio:.1}× the displacement's short-term noise ({:.3} µm)",
        m.noise_um
    );
    if ratio > MISSED_NOISE_RATIO {
        s += ": the model misses an effect; `metrolog thermal diagnose` names what it can";
    }
    s + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(heldout_rms_um: f64, noise_um: f64) -> ChannelModel {
        ChannelModel {
            channel: "x_um".into(),
            intercept_um: 0.0,
            terms: vec![],
            fit_rms_um: heldout_rms_um,
            heldout_rms_um,
            static_heldout_rms_um: 1.0,
            interval: Interval {
                level: 0.95,
                half_width_um: 0.5,
                heldout_coverage: 0.9,
            },
            noise_um,
        }
    }

    /// The held-out RMS is put against the displacement's noise, with a word when the model
    /// leaves more than twice it; a model written before the noise was kept reads back as 0
    /// and says nothing of it.
    #[test]
    fn the_description_puts_the_heldout_rms_against_the_noise() {
        let near = noise_line(&channel(0.12, 0.1));
        assert_eq!(
            near,
            "  held out, 1.2× the displacement's short-term noise (0.100 µm)\n"
        );
        let far = noise_line(&channel(0.25, 0.1));
        assert!(
            far.starts_with("  held out, 2.5×") && far.contains("misses an effect"),
            "{far}"
        );
        assert_eq!(noise_line(&channel(0.1, 0.0)), "");
        assert_eq!(noise_line(&channel(1.0, 1e-320)), "");
        let mut old = serde_json::to_value(channel(0.2, 0.1)).expect("serialises");
        old.as_object_mut().expect("an object").remove("noise_um");
        let read: ChannelModel = serde_json::from_value(old).expect("an old model reads");
        assert_eq!(read.noise_um, 0.0);
    }
}
