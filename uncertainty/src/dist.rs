//! Probability distributions of input quantities (JCGM 101 §6.4) and their GUM standard
//! uncertainties (JCGM 100 §4.3).

use rand::Rng;
use rand_distr::{Distribution as _, StandardNormal};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, StudentsT};

use super::UncertaintyError;

/// Shape of a periodic drift over one period, normalised to the range −1…+1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriftShape {
    /// `sin(2π·phase)`: the arcsine (U-shaped) distribution when the phase is unknown.
    Sine,
    /// Symmetric triangle wave: uniform values when the phase is unknown.
    Triangle,
    /// Ramp from −1 to +1 over the period (a linear drift reset each period).
    Sawtooth,
}

impl DriftShape {
    /// The value at `phase` (in periods; any real number, only the fractional part counts).
    pub fn value(self, phase: f64) -> f64 {
        let f = phase - phase.floor();
        match self {
            DriftShape::Sine => (std::f64::consts::TAU * f).sin(),
            // Starts at 0 rising, like the sine, so both shapes share the phase convention.
            DriftShape::Triangle => {
                if f < 0.25 {
                    4.0 * f
                } else if f < 0.75 {
                    2.0 - 4.0 * f
                } else {
                    4.0 * f - 4.0
                }
            }
            DriftShape::Sawtooth => 2.0 * f - 1.0,
        }
    }

    /// Root mean square over one period (the standard deviation for a uniformly random phase).
    pub fn rms(self) -> f64 {
        match self {
            DriftShape::Sine => std::f64::consts::FRAC_1_SQRT_2,
            DriftShape::Triangle | DriftShape::Sawtooth => 1.0 / 3f64.sqrt(),
        }
    }
}

/// The state-of-knowledge distribution of one input quantity.
///
/// In budget files the variant is chosen by `distribution = "..."` and its fields sit beside it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "distribution", rename_all = "snake_case")]
pub enum Distribution {
    /// Gaussian with expectation `mean` and standard deviation `u` (JCGM 101 §6.4.7).
    Normal { mean: f64, u: f64 },
    /// Uniform on `mean ± half_width` (JCGM 101 §6.4.2).
    Rectangular { mean: f64, half_width: f64 },
    /// Symmetric triangular on `mean ± half_width` (JCGM 101 §6.4.5).
    Triangular { mean: f64, half_width: f64 },
    /// U-shaped (arcsine) on `mean ± half_width` (JCGM 101 §6.4.6), e.g. a cyclic temperature.
    Arcsine { mean: f64, half_width: f64 },
    /// Scaled and shifted Student t (JCGM 101 §6.4.9): `mean` = x̄, `scale` = s/√n, `dof` = n − 1.
    StudentT { mean: f64, scale: f64, dof: f64 },
    /// Symmetric trapezoid on `mean ± half_width`, top half-width `beta · half_width`
    /// (JCGM 101 §6.4.4).
    Trapezoidal {
        mean: f64,
        half_width: f64,
        beta: f64,
    },
    /// A periodic drift seen at an unknown time: `mean + amplitude · shape(phase)` with the phase
    /// uniform over one period.
    Drift {
        mean: f64,
        amplitude: f64,
        shape: DriftShape,
    },
    /// A value known exactly.
    Constant { value: f64 },
}

impl Distribution {
    /// Checks the parameters; `name` is used in the message.
    pub fn validate(&self, name: &str) -> Result<(), UncertaintyError> {
        let bad = |what: &str| {
            Err(UncertaintyError::BadDistribution {
                input: name.to_string(),
                reason: what.to_string(),
            })
        };
        let finite = |v: f64| v.is_finite();
        match *self {
            Distribution::Normal { mean, u } => {
                if !finite(mean) || !finite(u) || u < 0.0 {
                    return bad("normal needs a finite `mean` and `u` ≥ 0");
                }
            }
            Distribution::Rectangular { mean, half_width }
            | Distribution::Triangular { mean, half_width }
            | Distribution::Arcsine { mean, half_width } => {
                if !finite(mean) || !finite(half_width) || half_width < 0.0 {
                    return bad("needs a finite `mean` and `half_width` ≥ 0");
                }
            }
            Distribution::StudentT { mean, scale, dof } => {
                if !finite(mean) || !finite(scale) || scale < 0.0 {
                    return bad("student_t needs a finite `mean` and `scale` ≥ 0");
                }
                // JCGM 101 §6.4.9: the t distribution only has a finite variance for ν > 2.
                if dof.is_nan() || dof <= 2.0 {
                    return bad("student_t needs `dof` > 2 (its variance is infinite otherwise)");
                }
            }
            Distribution::Trapezoidal {
                mean,
                half_width,
                beta,
            } => {
                if !finite(mean) || !finite(half_width) || half_width < 0.0 {
                    return bad("trapezoidal needs a finite `mean` and `half_width` ≥ 0");
                }
                if !(0.0..=1.0).contains(&beta) {
                    return bad("trapezoidal needs 0 ≤ `beta` ≤ 1 (top to base width ratio)");
                }
            }
            Distribution::Drift {
                mean, amplitude, ..
            } => {
                if !finite(mean) || !finite(amplitude) {
                    return bad("drift needs a finite `mean` and `amplitude`");
                }
            }
            Distribution::Constant { value } => {
                if !finite(value) {
                    return bad("constant needs a finite `value`");
                }
            }
        }
        Ok(())
    }

    /// The estimate (expectation) of the quantity.
    pub fn mean(&self) -> f64 {
        match *self {
            Distribution::Normal { mean, .. }
            | Distribution::Rectangular { mean, .. }
            | Distribution::Triangular { mean, .. }
            | Distribution::Arcsine { mean, .. }
            | Distribution::StudentT { mean, .. }
            | Distribution::Trapezoidal { mean, .. }
            | Distribution::Drift { mean, .. } => mean,
            Distribution::Constant { value } => value,
        }
    }

    /// The standard uncertainty used by the GUM law of propagation.
    ///
    /// For the Student t this is `scale` (= s/√n, a Type A evaluation per JCGM 100 §4.2) with
    /// `dof` degrees of freedom, not the t distribution's standard deviation
    /// `scale·√(ν/(ν−2))` that Monte Carlo propagates (JCGM 101 §6.4.9.4 note).
    pub fn standard_uncertainty(&self) -> f64 {
        match *self {
            Distribution::Normal { u, .. } => u,
            Distribution::Rectangular { half_width, .. } => half_width / 3f64.sqrt(),
            Distribution::Triangular { half_width, .. } => half_width / 6f64.sqrt(),
            Distribution::Arcsine { half_width, .. } => half_width / 2f64.sqrt(),
            Distribution::StudentT { scale, .. } => scale,
            Distribution::Trapezoidal {
                half_width, beta, ..
            } => half_width * ((1.0 + beta * beta) / 6.0).sqrt(),
            Distribution::Drift {
                amplitude, shape, ..
            } => amplitude.abs() * shape.rms(),
            Distribution::Constant { .. } => 0.0,
        }
    }

    /// Degrees of freedom implied by the distribution itself (only the Student t has finite).
    pub fn implied_dof(&self) -> Option<f64> {
        match *self {
            Distribution::StudentT { dof, .. } => Some(dof),
            _ => None,
        }
    }

    /// True when the distribution is Gaussian (correlations can be imposed exactly).
    pub fn is_normal(&self) -> bool {
        matches!(self, Distribution::Normal { .. })
    }

    /// The quantile function (inverse CDF) at probability `p` in (0, 1).
    pub fn quantile(&self, p: f64) -> f64 {
        match *self {
            Distribution::Normal { mean, u } => mean + u * std_normal_quantile(p),
            Distribution::Rectangular { mean, half_width } => mean + half_width * (2.0 * p - 1.0),
            Distribution::Triangular { mean, half_width } => {
                if p < 0.5 {
                    mean - half_width + half_width * (2.0 * p).sqrt()
                } else {
                    mean + half_width - half_width * (2.0 * (1.0 - p)).sqrt()
                }
            }
            // F(x) = 1/2 + asin((x − μ)/a)/π.
            Distribution::Arcsine { mean, half_width } => {
                mean - half_width * (std::f64::consts::PI * p).cos()
            }
            Distribution::StudentT { mean, scale, dof } => {
                t_quantile(p, dof).map_or(f64::NAN, |t| mean + scale * t)
            }
            Distribution::Trapezoidal {
                mean,
                half_width,
                beta,
            } => mean + trapezoid_quantile(half_width, beta * half_width, p),
            Distribution::Drift {
                mean,
                amplitude,
                shape,
            } => mean + amplitude * shape.value(p),
            Distribution::Constant { value } => value,
        }
    }

    /// One random draw.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        match *self {
            Distribution::Normal { mean, u } => {
                let z: f64 = StandardNormal.sample(rng);
                mean + u * z
            }
            Distribution::StudentT { mean, scale, dof } => {
                // t = Z / √(χ²_ν/ν) (JCGM 101 §6.4.9.5).
                match rand_distr::StudentT::new(dof) {
                    Ok(t) => mean + scale * t.sample(rng),
                    Err(_) => f64::NAN,
                }
            }
            Distribution::Constant { value } => value,
            _ => self.quantile(open_unit(rng)),
        }
    }
}

/// A uniform draw in the open interval (0, 1), so that quantile functions stay finite.
pub(crate) fn open_unit<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    let bits = rng.next_u64() >> 11;
    (bits as f64 + 0.5) * (1.0 / (1u64 << 53) as f64)
}

/// Φ⁻¹(p) of the standard normal distribution.
pub fn std_normal_quantile(p: f64) -> f64 {
    // Φ⁻¹(p) = −√2 · erfc⁻¹(2p).
    -std::f64::consts::SQRT_2 * statrs::function::erf::erfc_inv(2.0 * p)
}

/// Φ(z) of the standard normal distribution.
pub fn std_normal_cdf(z: f64) -> f64 {
    0.5 * statrs::function::erf::erfc(-z / std::f64::consts::SQRT_2)
}

/// Quantile of a symmetric trapezoid centred on 0 with base half-width `a` and top half-width
/// `c`: density `h = 1/(a + c)` on the top, linear flanks.
fn trapezoid_quantile(a: f64, c: f64, p: f64) -> f64 {
    if a <= 0.0 {
        return 0.0;
    }
    let h = 1.0 / (a + c);
    let flank = h * (a - c) / 2.0; // probability in one flank
    if p < flank {
        -a + (2.0 * p * (a - c) / h).sqrt()
    } else if p <= 1.0 - flank {
        -c + (p - flank) / h
    } else {
        a - (2.0 * (1.0 - p) * (a - c) / h).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn moments(d: &Distribution, n: usize) -> (f64, f64) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let v: Vec<f64> = (0..n).map(|_| d.sample(&mut rng)).collect();
        let m = v.iter().sum::<f64>() / n as f64;
        let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
        (m, s)
    }

    #[test]
    fn sampled_moments_match_closed_forms() {
        // Closed forms from JCGM 101 §6.4: rectangular a/√3, triangular a/√6, arcsine a/√2,
        // trapezoid a·√((1+β²)/6), t: scale·√(ν/(ν−2)).
        let cases = [
            (Distribution::Normal { mean: 1.0, u: 2.0 }, 2.0),
            (
                Distribution::Rectangular {
                    mean: 0.0,
                    half_width: 3.0,
                },
                3.0 / 3f64.sqrt(),
            ),
            (
                Distribution::Triangular {
                    mean: 0.0,
                    half_width: 3.0,
                },
                3.0 / 6f64.sqrt(),
            ),
            (
                Distribution::Arcsine {
                    mean: 0.0,
                    half_width: 3.0,
                },
                3.0 / 2f64.sqrt(),
            ),
            (
                Distribution::Trapezoidal {
                    mean: 0.0,
                    half_width: 2.0,
                    beta: 0.5,
                },
                2.0 * (1.25f64 / 6.0).sqrt(),
            ),
            (
                Distribution::StudentT {
                    mean: 0.0,
                    scale: 1.0,
                    dof: 10.0,
                },
                (10.0f64 / 8.0).sqrt(),
            ),
            (
                Distribution::Drift {
                    mean: 0.0,
                    amplitude: 2.0,
                    shape: DriftShape::Triangle,
                },
                2.0 / 3f64.sqrt(),
            ),
        ];
        for (d, sd) in cases {
            let (m, s) = moments(&d, 400_000);
            assert!((m - d.mean()).abs() < 0.02 * sd.max(1.0), "{d:?} mean {m}");
            assert!((s - sd).abs() < 0.01 * sd, "{d:?} sd {s} vs {sd}");
        }
    }

    #[test]
    fn trapezoid_quantile_is_continuous_and_symmetric() {
        for &beta in &[0.0, 0.3, 1.0] {
            let d = Distribution::Trapezoidal {
                mean: 0.0,
                half_width: 1.0,
                beta,
            };
            assert!((d.quantile(0.5)).abs() < 1e-12);
            assert!((d.quantile(0.1) + d.quantile(0.9)).abs() < 1e-12);
            assert!(d.quantile(1e-12) > -1.0 - 1e-9 && d.quantile(1e-12) < -0.99);
        }
    }

    #[test]
    fn normal_quantile_known_values() {
        assert!((std_normal_quantile(0.975) - 1.959_963_985).abs() < 1e-8);
        assert!((std_normal_cdf(1.959_963_985) - 0.975).abs() < 1e-9);
    }
}

/// Above this many degrees of freedom the t quantile is taken from its expansion about the
/// normal one: statrs' `inverse_cdf` does not return for ν = 10⁸ (found by the `budget_path`
/// fuzz target).
const T_EXPANSION_DOF: f64 = 1e5;

/// The quantile at `p` of Student's t with `nu` degrees of freedom (`None`: `nu` not a positive
/// number). Beyond [`T_EXPANSION_DOF`] the Cornish–Fisher expansion
/// t = z + (z³ + z)/(4ν) + (5z⁵ + 16z³ + 3z)/(96ν²) (Abramowitz & Stegun 26.7.5), whose next
/// term is below 10⁻¹⁴ there.
pub fn t_quantile(p: f64, nu: f64) -> Option<f64> {
    if nu.is_nan() || nu <= 0.0 {
        return None;
    }
    if nu > T_EXPANSION_DOF {
        let z = std_normal_quantile(p);
        let (z3, z5) = (z.powi(3), z.powi(5));
        return Some(
            z + (z3 + z) / (4.0 * nu) + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * nu * nu),
        );
    }
    StudentsT::new(0.0, 1.0, nu).ok().map(|t| t.inverse_cdf(p))
}

#[cfg(test)]
mod t_quantile_tests {
    use super::*;

    /// Where the expansion takes over, statrs' t CDF (its regularised incomplete beta, not the
    /// inverse that hangs) gives back p from the expanded quantile to 10⁻¹⁰; far beyond, where
    /// statrs' inverse never returns, the quantile still comes and tends to the normal one.
    #[test]
    fn expansion_inverts_the_t_cdf_and_answers_beyond() {
        for p in [0.995, 0.975, 0.6, 0.01] {
            let nu = T_EXPANSION_DOF * 1.5;
            let t = t_quantile(p, nu).expect("a quantile");
            let cdf = StudentsT::new(0.0, 1.0, nu).map(|d| d.cdf(t)).expect("a t");
            assert!((cdf - p).abs() < 1e-10, "p {p}: cdf {cdf} at {t}");
            let z = std_normal_quantile(p);
            for big in [1e8, 1e20, f64::MAX] {
                let tb = t_quantile(p, big).expect("a quantile");
                assert!((tb - z).abs() <= (t - z).abs(), "p {p}, ν {big}: {tb}");
            }
        }
        assert_eq!(t_quantile(0.5, 0.0), None);
        assert_eq!(t_quantile(0.5, f64::NAN), None);
        assert!((t_quantile(0.995, 1e8).expect("a quantile") - 2.575_829_3).abs() < 1e-6);
    }
}
