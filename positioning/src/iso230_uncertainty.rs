//! Uncertainty of the ISO 230-2 results (E, M, A, B, R) of a run, with the contributors
//! ISO 230-2:2014 Annex A and ISO/TR 230-9 name: the measuring device's calibration
//! (u_DEVICE), the compensation of the air's refractive index (u_ENV, interferometers only), the
//! material temperature (u_M,MACHINE) and expansion coefficient (u_E,MACHINE), the misalignment
//! (cosine error, u_MISALIGNMENT), the dead path, the environmental variation error E_VE
//! (u_EVE = E_VE/(2√3)) and the sampling of the run itself (means and estimators from n
//! readings).
//!
//! The text of Annex A was not in reach: the contributors are the ones the standard lists, each
//! combined by the GUM (JCGM 100) from the way it acts on a result, written down here:
//!
//! - **scale terms** (device, air compensation, material temperature, α, misalignment) make an
//!   error proportional to the distance from the datum; on a range of deviations over the
//!   travel (E, M, A) they act with the measured length L = the span of the targets
//!   (sensitivity 1 to the error ε·L); on B and R, differences at one target, they cancel;
//! - **dead path**: a change of the refractive index during the run acts on the optics-to-datum
//!   path as an offset that varies in time (rectangular over its range: u = e/(2√3));
//! - **E_VE**: measured (machine at rest over the test's duration) or estimated from the run as
//!   paper 000's drift elimination sees it: the common change of all targets of a pass, pass to
//!   pass (its range); it acts on every result;
//! - **sampling**: x̄ from n readings has u = s/√n, an estimator s has u(s) = s/√(2(n − 1)); a
//!   result takes those of the targets that make it (the extremes of E, M, A, the target of B
//!   and R).
//!
//! A contributor the run did not record is [`Origin::Missing`]: it has no value, the combined
//! uncertainty is then a lower bound, and the report must say so. A value the run did not
//! record but that was given (a data sheet, the operator) is [`Origin::Assumed`] and says
//! where it came from. Nothing is borrowed from another instrument: a laser-triangulation run
//! has no interferometer calibration and no air compensation.

use serde::Serialize;

use crate::iso230::{Iso230Report, TargetStats};
use crate::positioning_data::PositioningData;

/// ∂n/∂T of air, 1/K (Edlén, Birch and Downs, at 20 °C, 101.325 kPa, 50 %RH, 633 nm).
pub const DN_DT_PER_K: f64 = -0.93e-6;
/// ∂n/∂p of air, 1/kPa.
pub const DN_DP_PER_KPA: f64 = 2.7e-6;
/// ∂n/∂RH of air, 1/%.
pub const DN_DRH_PER_PCT: f64 = -0.0085e-6;

/// Coverage factor of the expanded uncertainties (ISO 230-2 Annex A: k = 2).
pub const K: f64 = 2.0;

/// What measured the positions.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Sensor {
    /// A laser interferometer: wavelength compensated for the air.
    LaserInterferometer,
    /// Anything else (laser triangulation, a linear scale, a probe), by name.
    Other(String),
}

/// Where a contributor's value comes from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "origin", content = "note")]
pub enum Origin {
    /// From the run's own records.
    Recorded(String),
    /// Not recorded by the run; the value given and where it came from.
    Assumed(String),
    /// Not recorded and not given: no value, the combined uncertainty is a lower bound.
    Missing(String),
    /// Does not apply to this sensor.
    NotApplicable(String),
}

/// One contributor: its standard uncertainty in µm at the measured length (scale terms) or as
/// it acts (offsets), `None` when missing or not applicable.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Contributor {
    /// ISO 230-2 / ISO/TR 230-9 symbol, e.g. `u_DEVICE`.
    pub symbol: String,
    pub description: String,
    pub u_um: Option<f64>,
    pub origin: Origin,
}

/// A value with its origin, as the caller knows it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Known {
    pub value: f64,
    /// `true`: from the run's records; `false`: given (data sheet, operator).
    pub recorded: bool,
    /// Where it came from, for the report.
    pub note: String,
}

impl Known {
    pub fn recorded(value: f64, note: &str) -> Known {
        Known {
            value,
            recorded: true,
            note: note.to_string(),
        }
    }
    pub fn assumed(value: f64, note: &str) -> Known {
        Known {
            value,
            recorded: false,
            note: note.to_string(),
        }
    }
    fn origin(&self) -> Origin {
        if self.recorded {
            Origin::Recorded(self.note.clone())
        } else {
            Origin::Assumed(self.note.clone())
        }
    }
}

/// What is known about the measurement beside the readings. Every field is optional: what is
/// `None` becomes a missing contributor (unless it does not apply to the sensor).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Setup {
    pub sensor: Sensor,
    /// Expanded (k = 2) calibration uncertainty of the device, µm per metre of length.
    pub device_expanded_um_per_m: Option<Known>,
    /// Half-width (±) of the air compensation's error, ppm (interferometer only), e.g. from the
    /// environment sensors' accuracies through the Edlén sensitivities, see [`air_half_width_ppm`].
    pub air_compensation_ppm: Option<Known>,
    /// Half-width (±) of the material temperature measurement's error, K.
    pub material_temp_accuracy_k: Option<Known>,
    /// Mean material temperature during the run, °C.
    pub material_temp_c: Option<Known>,
    /// Expansion coefficient used, µm/(m·K), and the half-width of its uncertainty.
    pub alpha_um_per_m_k: Option<Known>,
    pub alpha_accuracy_um_per_m_k: Option<Known>,
    /// Largest angle between the measuring direction and the axis, rad.
    pub misalignment_rad: Option<Known>,
    /// Optics to reflector at the datum, mm (interferometer only).
    pub dead_path_mm: Option<Known>,
    /// Ranges (max − min) of the air temperature (K) and pressure (kPa) during the run.
    pub air_temp_range_k: Option<Known>,
    pub pressure_range_kpa: Option<Known>,
    /// E_VE measured by a drift test (machine at rest, the test's duration), µm. Without it the
    /// run's own estimate is used ([`e_ve_from_run`]).
    pub e_ve_um: Option<Known>,
}

impl Setup {
    /// Nothing known but the sensor.
    pub fn bare(sensor: Sensor) -> Setup {
        Setup {
            sensor,
            device_expanded_um_per_m: None,
            air_compensation_ppm: None,
            material_temp_accuracy_k: None,
            material_temp_c: None,
            alpha_um_per_m_k: None,
            alpha_accuracy_um_per_m_k: None,
            misalignment_rad: None,
            dead_path_mm: None,
            air_temp_range_k: None,
            pressure_range_kpa: None,
            e_ve_um: None,
        }
    }

    /// [`Setup::bare`] with what the dataset itself records: the material temperature (mean of
    /// the readings' `material_c`), the air temperature's range, α (metadata).
    pub fn from_data(sensor: Sensor, data: &PositioningData) -> Setup {
        let mut s = Setup::bare(sensor);
        let mat: Vec<f64> = data.readings.iter().filter_map(|r| r.material_c).collect();
        if !mat.is_empty() {
            let mean = mat.iter().sum::<f64>() / mat.len() as f64;
            s.material_temp_c = Some(Known::recorded(mean, "mean of the material temperatures"));
        }
        let air: Vec<f64> = data.readings.iter().filter_map(|r| r.air_c).collect();
        if let Some(r) = range(&air) {
            s.air_temp_range_k = Some(Known::recorded(r, "range of the air temperatures"));
        }
        if let Some(a) = data.alpha_um_per_m_k {
            s.alpha_um_per_m_k = Some(Known::recorded(a, "metadata alpha_um_per_m_k"));
        }
        s
    }

    fn interferometer(&self) -> bool {
        self.sensor == Sensor::LaserInterferometer
    }
}

fn range(v: &[f64]) -> Option<f64> {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (hi >= lo).then_some(hi - lo)
}

/// Half-width (ppm) of the air compensation's error from the environment sensors'
/// half-widths (K, kPa, %RH) through the Edlén sensitivities, combined as independent
/// rectangular errors: √3·√Σ(cᵢ·aᵢ/√3)², i.e. the half-width of a rectangle of the same u.
pub fn air_half_width_ppm(air_k: f64, pressure_kpa: f64, humidity_pct: f64) -> f64 {
    let terms = [
        DN_DT_PER_K * air_k,
        DN_DP_PER_KPA * pressure_kpa,
        DN_DRH_PER_PCT * humidity_pct,
    ];
    terms.iter().map(|t| t * t).sum::<f64>().sqrt() * 1e6
}

/// E_VE estimated from the run, µm: per direction and pass, the mean over the targets of the
/// reading minus its target's mean in that direction (what the whole pass moved, the thermal
/// drift paper 000 eliminates); E_VE is the range of these over all passes. `None` with fewer
/// than two passes.
pub fn e_ve_from_run(data: &PositioningData) -> Option<f64> {
    let grid = data.grid();
    let mut offsets = Vec::new();
    for g in &grid {
        let means: Vec<Option<f64>> = g
            .iter()
            .map(|t| {
                let v: Vec<f64> = t.iter().flatten().copied().collect();
                (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
            })
            .collect();
        for c in 0..data.n_cycles() {
            let d: Vec<f64> = g
                .iter()
                .zip(&means)
                .filter_map(|(t, m)| Some(t.get(c).copied().flatten()? - (*m)?))
                .collect();
            if !d.is_empty() {
                offsets.push(d.iter().sum::<f64>() / d.len() as f64);
            }
        }
    }
    (offsets.len() >= 2).then(|| range(&offsets)).flatten()
}

/// The uncertainty of one ISO 230-2 result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ResultUncertainty {
    /// ISO 230-2 symbol: E, M, A, B, R.
    pub parameter: String,
    pub value_um: Option<f64>,
    /// (symbol, standard uncertainty in µm) of each contributor that acts on this result and
    /// has a value.
    pub contributions: Vec<(String, f64)>,
    /// Combined standard uncertainty of the known contributors, µm.
    pub u_um: f64,
    pub k: f64,
    /// U = k·u, µm.
    pub expanded_um: f64,
    /// Contributors acting on this result that are missing: U is then a lower bound.
    pub missing: Vec<String>,
}

/// The budget of a run: its contributors and the uncertainty of each result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Iso230Uncertainty {
    pub sensor: Sensor,
    /// Measured length L: the span of the targets, mm.
    pub length_mm: f64,
    pub contributors: Vec<Contributor>,
    pub results: Vec<ResultUncertainty>,
}

fn contributor(symbol: &str, description: &str, u: Option<f64>, origin: Origin) -> Contributor {
    Contributor {
        symbol: symbol.to_string(),
        description: description.to_string(),
        u_um: u,
        origin,
    }
}

/// A scale or offset contributor from one known value (`u = f(value)`), missing when unknown.
fn from_known(
    symbol: &str,
    description: &str,
    known: Option<&Known>,
    missing: &str,
    u: impl Fn(f64) -> f64,
) -> Contributor {
    match known {
        Some(k) => contributor(symbol, description, Some(u(k.value)), k.origin()),
        None => contributor(
            symbol,
            description,
            None,
            Origin::Missing(missing.to_string()),
        ),
    }
}

/// Two known values combined, with the origin of the less certain one (Assumed over Recorded).
fn from_two(
    symbol: &str,
    description: &str,
    a: Option<&Known>,
    b: Option<&Known>,
    missing: &str,
    u: impl Fn(f64, f64) -> f64,
) -> Contributor {
    match (a, b) {
        (Some(x), Some(y)) => {
            let origin = if x.recorded && y.recorded {
                Origin::Recorded(format!("{}; {}", x.note, y.note))
            } else {
                Origin::Assumed(format!("{}; {}", x.note, y.note))
            };
            contributor(symbol, description, Some(u(x.value, y.value)), origin)
        }
        _ => contributor(
            symbol,
            description,
            None,
            Origin::Missing(missing.to_string()),
        ),
    }
}

const RECT: f64 = 1.732_050_807_568_877_2; // √3

/// The scale contributors (they act on E, M, A with the measured length `l_m` in metres).
fn scale_contributors(s: &Setup, l_m: f64) -> Vec<Contributor> {
    let mut v = vec![from_known(
        "u_DEVICE",
        "calibration of the measuring device",
        s.device_expanded_um_per_m.as_ref(),
        "the device's calibration uncertainty is not recorded (calibration certificate)",
        |u_per_m| u_per_m * l_m / K,
    )];
    v.push(if s.interferometer() {
        from_known(
            "u_ENV",
            "compensation of the air's refractive index",
            s.air_compensation_ppm.as_ref(),
            "the accuracies of the air temperature, pressure and humidity sensors are not recorded",
            |ppm| ppm * l_m / RECT,
        )
    } else {
        contributor(
            "u_ENV",
            "compensation of the air's refractive index",
            None,
            Origin::NotApplicable("not an interferometer: no wavelength compensation".into()),
        )
    });
    let alpha = s.alpha_um_per_m_k.as_ref();
    v.push(from_two(
        "u_M,MACHINE",
        "material temperature measurement (normalisation to 20 °C)",
        alpha,
        s.material_temp_accuracy_k.as_ref(),
        "no material temperature accuracy or no α: the normalisation to 20 °C cannot be assessed",
        |a, acc| a * l_m * acc / RECT,
    ));
    let dt = s.material_temp_c.as_ref().map(|t| Known {
        value: (t.value - 20.0).abs(),
        ..t.clone()
    });
    v.push(from_two(
        "u_E,MACHINE",
        "expansion coefficient α of the axis (|T − 20 °C|·δα)",
        dt.as_ref(),
        s.alpha_accuracy_um_per_m_k.as_ref(),
        "no material temperature recorded or no uncertainty of α: the results are not \
         normalised to 20 °C with a known uncertainty",
        |dt, da| dt * l_m * da / RECT,
    ));
    v.push(from_known(
        "u_MISALIGNMENT",
        "cosine error, one-sided on [0, L·θ²/2], rectangular",
        s.misalignment_rad.as_ref(),
        "the alignment of the measuring direction to the axis is not recorded",
        |th| l_m * 1e6 * th * th / 2.0 / (2.0 * RECT),
    ));
    v
}

/// The offset contributors: dead path and E_VE (act on every result).
fn offset_contributors(s: &Setup, data: &PositioningData) -> Vec<Contributor> {
    let mut v = Vec::new();
    v.push(if s.interferometer() {
        let dn = match (s.air_temp_range_k.as_ref(), s.pressure_range_kpa.as_ref()) {
            (Some(t), Some(p)) => Some(Known {
                value: (DN_DT_PER_K * t.value).abs() + (DN_DP_PER_KPA * p.value).abs(),
                recorded: t.recorded && p.recorded,
                note: format!("{}; {}", t.note, p.note),
            }),
            _ => None,
        };
        from_two(
            "u_DEADPATH",
            "dead path: change of the air during the run over the optics-to-datum path",
            s.dead_path_mm.as_ref(),
            dn.as_ref(),
            "the dead path or the ranges of air temperature and pressure are not recorded",
            |dead_mm, dn| dead_mm * 1e3 * dn / (2.0 * RECT),
        )
    } else {
        contributor(
            "u_DEADPATH",
            "dead path",
            None,
            Origin::NotApplicable("not an interferometer".into()),
        )
    });
    let e_ve = s.e_ve_um.clone().or_else(|| {
        e_ve_from_run(data).map(|e| {
            Known::recorded(
                e,
                "estimated from the run: range of the passes' common drift (paper 000)",
            )
        })
    });
    v.push(from_known(
        "u_EVE",
        "environmental variation error E_VE, rectangular: E_VE/(2√3)",
        e_ve.as_ref(),
        "no drift test and fewer than two passes",
        |e| e / (2.0 * RECT),
    ));
    v
}

/// u of a mean and of an estimator from one direction at one target.
fn sampling(s: Option<f64>, n: usize) -> (f64, f64) {
    match s {
        Some(s) if n >= 2 => {
            let n = n as f64;
            (s / n.sqrt(), s / (2.0 * (n - 1.0)).sqrt())
        }
        _ => (0.0, 0.0),
    }
}

fn up(t: &TargetStats) -> (Option<f64>, Option<f64>, usize) {
    (t.mean_up_um, t.s_up_um, t.n_up)
}
fn down(t: &TargetStats) -> (Option<f64>, Option<f64>, usize) {
    (t.mean_down_um, t.s_down_um, t.n_down)
}

/// (mean, s, n) of one direction at one target.
type Sample = (f64, f64, usize);

/// The (mean, s, n) of the extreme values of `f` over both directions and all targets.
fn extremes(targets: &[TargetStats], f: &dyn Fn(f64, f64) -> f64) -> Option<(Sample, Sample)> {
    let all: Vec<Sample> = targets
        .iter()
        .flat_map(|t| [up(t), down(t)])
        .filter_map(|(m, s, n)| Some((m?, s.unwrap_or(0.0), n)))
        .collect();
    let key = |x: &Sample| f(x.0, x.1);
    let hi = all
        .iter()
        .copied()
        .max_by(|a, b| key(a).total_cmp(&key(b)))?;
    let lo = all
        .iter()
        .copied()
        .min_by(|a, b| key(a).total_cmp(&key(b)))?;
    Some((hi, lo))
}

/// Sampling u of E (range of means) and A (range of x̄ ± 2s).
fn sampling_e_a(targets: &[TargetStats]) -> (f64, f64) {
    let e = extremes(targets, &|m, _| m).map_or(0.0, |(hi, lo)| {
        let (a, b) = (sampling(Some(hi.1), hi.2), sampling(Some(lo.1), lo.2));
        (a.0 * a.0 + b.0 * b.0).sqrt()
    });
    let hi = extremes(targets, &|m, s| m + 2.0 * s).map(|x| x.0);
    let lo = extremes(targets, &|m, s| m - 2.0 * s).map(|x| x.1);
    let a = match (hi, lo) {
        (Some(h), Some(l)) => {
            let (a, b) = (sampling(Some(h.1), h.2), sampling(Some(l.1), l.2));
            (a.0.powi(2) + b.0.powi(2) + 4.0 * (a.1.powi(2) + b.1.powi(2))).sqrt()
        }
        _ => 0.0,
    };
    (e, a)
}

/// Sampling u of M (range of the bidirectional means).
fn sampling_m(targets: &[TargetStats]) -> f64 {
    let u_mean = |t: &TargetStats| {
        let (a, b) = (
            sampling(t.s_up_um, t.n_up).0,
            sampling(t.s_down_um, t.n_down).0,
        );
        0.5 * (a * a + b * b).sqrt()
    };
    let with: Vec<&TargetStats> = targets.iter().filter(|t| t.mean_um.is_some()).collect();
    let key = |t: &&TargetStats| t.mean_um.unwrap_or(0.0);
    let hi = with.iter().max_by(|a, b| key(a).total_cmp(&key(b)));
    let lo = with.iter().min_by(|a, b| key(a).total_cmp(&key(b)));
    match (hi, lo) {
        (Some(h), Some(l)) => (u_mean(h).powi(2) + u_mean(l).powi(2)).sqrt(),
        _ => 0.0,
    }
}

/// Sampling u of B (at the target of max |B_i|) and R (at the target of max R_i).
fn sampling_b_r(targets: &[TargetStats]) -> (f64, f64) {
    let by = |f: &dyn Fn(&TargetStats) -> Option<f64>| {
        targets
            .iter()
            .filter(|t| f(t).is_some())
            .max_by(|a, b| f(a).unwrap_or(0.0).total_cmp(&f(b).unwrap_or(0.0)))
    };
    let b = by(&|t| t.b_um.map(f64::abs)).map_or(0.0, |t| {
        let (a, b) = (
            sampling(t.s_up_um, t.n_up).0,
            sampling(t.s_down_um, t.n_down).0,
        );
        (a * a + b * b).sqrt()
    });
    let r = by(&|t| t.r_um).map_or(0.0, |t| {
        let (mu, su) = sampling(t.s_up_um, t.n_up);
        let (md, sd) = sampling(t.s_down_um, t.n_down);
        // The uncertainty of the form that gives R_i: 4s↑, 4s↓ or 2s↑ + 2s↓ + |B_i|.
        let (s_up, s_down) = (t.s_up_um.unwrap_or(0.0), t.s_down_um.unwrap_or(0.0));
        let bidirectional = 2.0 * s_up + 2.0 * s_down + t.b_um.map_or(0.0, f64::abs);
        if 4.0 * s_up >= bidirectional.max(4.0 * s_down) {
            4.0 * su
        } else if 4.0 * s_down >= bidirectional {
            4.0 * sd
        } else {
            (4.0 * su * su + 4.0 * sd * sd + mu * mu + md * md).sqrt()
        }
    });
    (b, r)
}

fn result(
    parameter: &str,
    value: Option<f64>,
    acting: &[&Contributor],
    sampling_u: f64,
) -> ResultUncertainty {
    let mut contributions: Vec<(String, f64)> = acting
        .iter()
        .filter_map(|c| Some((c.symbol.clone(), c.u_um?)))
        .collect();
    contributions.push(("u_SAMPLING".to_string(), sampling_u));
    let missing = acting
        .iter()
        .filter(|c| matches!(c.origin, Origin::Missing(_)))
        .map(|c| c.symbol.clone())
        .collect();
    let u = contributions.iter().map(|c| c.1 * c.1).sum::<f64>().sqrt();
    ResultUncertainty {
        parameter: parameter.to_string(),
        value_um: value,
        contributions,
        u_um: u,
        k: K,
        expanded_um: K * u,
        missing,
    }
}

/// The uncertainty budget of a run's ISO 230-2 results.
pub fn evaluate(data: &PositioningData, report: &Iso230Report, setup: &Setup) -> Iso230Uncertainty {
    let targets = data.targets_mm();
    let length_mm = range(&targets).unwrap_or(0.0);
    let scale = scale_contributors(setup, length_mm * 1e-3);
    let offset = offset_contributors(setup, data);
    let all: Vec<&Contributor> = scale.iter().chain(&offset).collect();
    let eve: Vec<&Contributor> = offset.iter().filter(|c| c.symbol == "u_EVE").collect();
    let (se, sa) = sampling_e_a(&report.targets);
    let sm = sampling_m(&report.targets);
    let (sb, sr) = sampling_b_r(&report.targets);
    let ax = &report.axis;
    let results = vec![
        result("E", ax.e, &all, se),
        result("M", ax.m, &all, sm),
        result("A", ax.a, &all, sa),
        result("B", ax.b, &eve, sb),
        result("R", ax.r, &eve, sr),
    ];
    Iso230Uncertainty {
        sensor: setup.sensor.clone(),
        length_mm,
        contributors: scale.into_iter().chain(offset).collect(),
        results,
    }
}

/// The contributors an operator can give when the run did not record them (`--assume
/// KEY=VALUE`): key, meaning with its unit, and the range a real value lies in.
pub const GIVEN_KEYS: &[(&str, &str, f64, f64)] = &[
    (
        "device_um_per_m",
        "expanded (k = 2) calibration uncertainty of the measuring device, µm/m (its certificate)",
        0.0,
        100.0,
    ),
    (
        "air_ppm",
        "half-width of the air compensation's error, ppm (interferometer)",
        0.0,
        100.0,
    ),
    (
        "material_c",
        "mean material temperature during the run, °C",
        -20.0,
        60.0,
    ),
    (
        "material_accuracy_k",
        "half-width of the material temperature measurement's error, K",
        0.0,
        10.0,
    ),
    (
        "alpha_um_per_m_k",
        "expansion coefficient of the axis, µm/(m·K)",
        -50.0,
        50.0,
    ),
    (
        "alpha_accuracy_um_per_m_k",
        "half-width of the uncertainty of α, µm/(m·K)",
        0.0,
        50.0,
    ),
    (
        "misalignment_mrad",
        "largest angle between the measuring direction and the axis, mrad",
        0.0,
        100.0,
    ),
    (
        "dead_path_mm",
        "optics to reflector at the datum, mm (interferometer)",
        0.0,
        100_000.0,
    ),
    (
        "air_range_k",
        "range (max − min) of the air temperature during the run, K",
        0.0,
        50.0,
    ),
    (
        "pressure_range_kpa",
        "range (max − min) of the air pressure during the run, kPa",
        0.0,
        50.0,
    ),
    (
        "e_ve_um",
        "E_VE measured by a drift test (machine at rest, the test's duration), µm",
        0.0,
        10_000.0,
    ),
];

/// Check a given contributor `key = value` against [`GIVEN_KEYS`]: the message says what to fix.
pub fn check_given(key: &str, value: f64) -> Result<(), String> {
    let Some((_, meaning, lo, hi)) = GIVEN_KEYS.iter().find(|g| g.0 == key) else {
        let keys: Vec<&str> = GIVEN_KEYS.iter().map(|g| g.0).collect();
        return Err(format!(
            "`{key}` is not a contributor; one of: {}",
            keys.join(", ")
        ));
    };
    if !(value.is_finite() && (*lo..=*hi).contains(&value)) {
        return Err(format!(
            "{key} = {value}: the {meaning} must lie in [{lo}, {hi}]"
        ));
    }
    Ok(())
}

impl Setup {
    /// Set a contributor the operator gives ([`GIVEN_KEYS`]; checked by [`check_given`]),
    /// marked assumed with `note` as its source. It replaces a recorded value of the same key.
    pub fn give(&mut self, key: &str, value: f64, note: &str) -> Result<(), String> {
        check_given(key, value)?;
        let k = Some(Known::assumed(value, note));
        match key {
            "device_um_per_m" => self.device_expanded_um_per_m = k,
            "air_ppm" => self.air_compensation_ppm = k,
            "material_c" => self.material_temp_c = k,
            "material_accuracy_k" => self.material_temp_accuracy_k = k,
            "alpha_um_per_m_k" => self.alpha_um_per_m_k = k,
            "alpha_accuracy_um_per_m_k" => self.alpha_accuracy_um_per_m_k = k,
            "misalignment_mrad" => self.misalignment_rad = Some(Known::assumed(value * 1e-3, note)),
            "dead_path_mm" => self.dead_path_mm = k,
            "air_range_k" => self.air_temp_range_k = k,
            "pressure_range_kpa" => self.pressure_range_kpa = k,
            _ => self.e_ve_um = k,
        }
        Ok(())
    }
}
