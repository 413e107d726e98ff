//! Host-side conversions of instruments.md: LI-80 air and material compensation, CapBall
//! polynomial and sensor-to-machine transform, PSD position, gating, error map, head thermal
//! correction.
//!
//! Pure arithmetic on plain arrays (no linear-algebra crate: the protocol crate stays a leaf).

use crate::cb3::SampleFrame;
use crate::edlen;
use crate::li80::EnvFrame;
use crate::psd::DataLine;

/// Why a conversion could not produce a value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConvertError {
    /// an `$ENV` record without material temperature: the LI-80 needs at least one material sensor
    #[error(
        "an `$ENV` record without material temperature: the LI-80 needs at least one material sensor"
    )]
    NoMaterialSensor,
    /// {what} = {value} is outside {min}..{max}: check the sensor or the configuration
    #[error("{what} = {value} is outside {min}..{max}: check the sensor or the configuration")]
    OutOfRange {
        what: &'static str,
        value: f64,
        min: f64,
        max: f64,
    },
    /// PSD spot position ({x_um} µm, {y_um} µm) lies outside the error map: extend the map or
    /// re-centre the beam
    #[error(
        "PSD spot position ({x_um} µm, {y_um} µm) lies outside the error map: extend the map or re-centre the beam"
    )]
    OutsideMap { x_um: f64, y_um: f64 },
    /// error map needs at least 2×2 grid points with positive steps and nx·ny corrections
    #[error(
        "error map needs at least 2×2 grid points, positive finite steps and nx·ny = {expected} corrections, got {got}"
    )]
    BadMap { expected: usize, got: usize },
}

impl ConvertError {
    fn check(what: &'static str, value: f64, min: f64, max: f64) -> Result<f64, ConvertError> {
        if (min..=max).contains(&value) {
            Ok(value)
        } else {
            Err(ConvertError::OutOfRange {
                what,
                value,
                min,
                max,
            })
        }
    }
}

// ---------------------------------------------------------------------------------------------
// LI-80 (instruments.md §1, host-side compensation)

/// Reference temperature of dimensional metrology (ISO 1), °C.
pub const REFERENCE_TEMPERATURE_C: f64 = 20.0;

/// Expansion coefficient of steel instruments.md suggests, µm/(m·K).
pub const ALPHA_STEEL_UM_PER_M_K: f64 = 11.7;

/// The compensation state derived from one `$ENV` record, applied to every `$POS` until the
/// next one. Computing `n` once per second keeps the per-sample path to two multiplications.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Li80Compensation {
    /// Refractive index of air (Birch & Downs, 632.991 nm, 450 ppm CO2).
    pub n_air: f64,
    /// Mean of the material sensors, °C.
    pub material_c: f64,
    /// Expansion coefficient of the measured axis, µm/(m·K).
    pub alpha_um_per_m_k: f64,
}

/// Plausibility limits of the `$ENV` values, beyond which the Edlén equation is not used
/// (Birch & Downs fitted it for laboratory air; NIST quotes −40..100 °C, 10..140 kPa).
pub const AIR_C_RANGE: (f64, f64) = (-40.0, 100.0);
pub const AIR_PA_RANGE: (f64, f64) = (10_000.0, 140_000.0);
pub const RH_PCT_RANGE: (f64, f64) = (0.0, 100.0);
pub const MATERIAL_C_RANGE: (f64, f64) = (-40.0, 100.0);

impl Li80Compensation {
    /// From an `$ENV` record and the axis' expansion coefficient.
    pub fn from_env(env: &EnvFrame, alpha_um_per_m_k: f64) -> Result<Self, ConvertError> {
        let t = ConvertError::check(
            "air temperature °C",
            env.air_c,
            AIR_C_RANGE.0,
            AIR_C_RANGE.1,
        )?;
        let p = ConvertError::check(
            "air pressure Pa",
            env.air_pa,
            AIR_PA_RANGE.0,
            AIR_PA_RANGE.1,
        )?;
        let rh = ConvertError::check(
            "relative humidity %",
            env.rh_pct,
            RH_PCT_RANGE.0,
            RH_PCT_RANGE.1,
        )?;
        for &m in &env.material_c {
            ConvertError::check(
                "material temperature °C",
                m,
                MATERIAL_C_RANGE.0,
                MATERIAL_C_RANGE.1,
            )?;
        }
        let material_c = mean(&env.material_c).ok_or(ConvertError::NoMaterialSensor)?;
        Ok(Li80Compensation {
            n_air: edlen::li80_refractive_index(t, p, rh),
            material_c,
            alpha_um_per_m_k,
        })
    }

    /// `L20 = (raw/n)·(1 − α·(T_mat − 20 °C))`, nm.
    #[inline]
    pub fn length_at_20c_nm(&self, raw_nm: i64) -> f64 {
        length_at_20c_nm(
            air_corrected_nm(raw_nm as f64, self.n_air),
            self.alpha_um_per_m_k,
            self.material_c,
        )
    }
}

/// `L = raw/n`: the device counts fringes of the vacuum wavelength; in air each fringe is
/// shorter by the factor `n`.
#[inline]
pub fn air_corrected_nm(raw_nm: f64, n_air: f64) -> f64 {
    raw_nm / n_air
}

/// `L20 = L·(1 − α·(T_mat − 20 °C))` with α in µm/(m·K).
#[inline]
pub fn length_at_20c_nm(l_nm: f64, alpha_um_per_m_k: f64, material_c: f64) -> f64 {
    l_nm * (1.0 - alpha_um_per_m_k * 1e-6 * (material_c - REFERENCE_TEMPERATURE_C))
}

/// Arithmetic mean; `None` for no values.
pub fn mean(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        None
    } else {
        Some(values.iter().sum::<f64>() / values.len() as f64)
    }
}

// ---------------------------------------------------------------------------------------------
// CB-3 CapBall (instruments.md §2, host-side conversion)

/// Pre-calibration polynomial of one capacitive sensor: `d = c1·V + c2·V² + c3·V³`, µm.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CapBallPoly {
    /// `[c1, c2, c3]` in µm/V, µm/V², µm/V³.
    pub c: [f64; 3],
}

impl CapBallPoly {
    /// The data sheet's nominal sensor: `c1` = 10 µm/V, no non-linearity.
    pub const NOMINAL: CapBallPoly = CapBallPoly {
        c: [10.0, 0.0, 0.0],
    };

    /// Distance change, µm, for `volts`.
    #[inline]
    pub fn distance_um(&self, volts: f64) -> f64 {
        // Horner form of c1·V + c2·V² + c3·V³.
        volts * (self.c[0] + volts * (self.c[1] + volts * self.c[2]))
    }
}

/// The 4×4 homogeneous transform `T` of the cube calibration (row-major), `v = T·[d; 1]`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CapBallTransform {
    pub t: [[f64; 4]; 4],
}

impl CapBallTransform {
    pub const IDENTITY: CapBallTransform = CapBallTransform {
        t: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };

    /// The volumetric error in the machine frame, µm: the first three rows of `T·[d; 1]`.
    /// The fourth row is `[0 0 0 1]` for the affine least-squares fit `T = M·S⁺` and is not used.
    #[inline]
    pub fn apply(&self, d_um: [f64; 3]) -> [f64; 3] {
        let row = |r: &[f64; 4]| r[0] * d_um[0] + r[1] * d_um[1] + r[2] * d_um[2] + r[3];
        [row(&self.t[0]), row(&self.t[1]), row(&self.t[2])]
    }
}

/// The calibration of a CapBall: the polynomial of each sensor and the cube-calibration
/// transform. The CB-3 driver converts every sample with it, and a log stores it with the raw
/// codes so a reader recomputes the same values bit for bit (docs/log-format.md).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CapBallCalibration {
    pub poly: [CapBallPoly; 3],
    pub transform: CapBallTransform,
}

/// What one CB-3 sample converts to: volts, sensor distance changes (µm) and the
/// machine-frame error (µm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CapBallValues {
    pub volts: [f64; 3],
    pub d_um: [f64; 3],
    pub e_um: [f64; 3],
}

impl CapBallCalibration {
    /// Codes → volts → sensor distances → machine-frame volumetric error.
    #[inline]
    pub fn convert(&self, codes: [i32; 3]) -> CapBallValues {
        let volts = codes.map(crate::cb3::code_volts);
        let d_um: [f64; 3] = std::array::from_fn(|i| self.poly[i].distance_um(volts[i]));
        CapBallValues {
            volts,
            d_um,
            e_um: self.transform.apply(d_um),
        }
    }
}

/// Volts → sensor distances → machine-frame volumetric error, µm, for one CB-3 sample.
pub fn capball_volumetric_um(
    s: &SampleFrame,
    polys: &[CapBallPoly; 3],
    t: &CapBallTransform,
) -> [f64; 3] {
    let cal = CapBallCalibration {
        poly: *polys,
        transform: *t,
    };
    cal.convert(s.ch).e_um
}

// ---------------------------------------------------------------------------------------------
// PSD-2 (instruments.md §3, host-side conversion)

/// Active length of the duolateral diode along x and y, mm.
pub const PSD_LX_MM: f64 = 10.0;
pub const PSD_LY_MM: f64 = 10.0;

/// Head thermal correction constants: lever length, mm, and expansion of invar, µm/(m·K).
pub const HEAD_L0_MM: f64 = 193.0;
pub const HEAD_ALPHA_UM_PER_M_K: f64 = 1.7;

/// Spot position on the diode, µm, from the four photocurrents, or why it is invalid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PsdReading {
    Valid {
        x_um: f64,
        y_um: f64,
    },
    /// `x1 + x2` or `y1 + y2` is below the configured minimum: beam blocked or off the diode.
    LowIntensity {
        sum_x_pa: u64,
        sum_y_pa: u64,
    },
}

/// Duolateral PSD: `x = (Lx/2)·(x2 − x1)/(x2 + x1)`, same for y; gated on both sums being at
/// least `min_sum_pa` (and non-zero, so the division is defined).
pub fn psd_position(d: &DataLine, min_sum_pa: u64) -> PsdReading {
    let sum_x = d.x1_pa.saturating_add(d.x2_pa);
    let sum_y = d.y1_pa.saturating_add(d.y2_pa);
    if sum_x < min_sum_pa.max(1) || sum_y < min_sum_pa.max(1) {
        return PsdReading::LowIntensity {
            sum_x_pa: sum_x,
            sum_y_pa: sum_y,
        };
    }
    let ratio = |a: u64, b: u64, s: u64| (b as f64 - a as f64) / s as f64;
    PsdReading::Valid {
        x_um: PSD_LX_MM * 500.0 * ratio(d.x1_pa, d.x2_pa, sum_x),
        y_um: PSD_LY_MM * 500.0 * ratio(d.y1_pa, d.y2_pa, sum_y),
    }
}

/// Thermal elongation of the measuring head along the spindle axis, µm:
/// `Δl = l0·α·(T − T_ref)` with `l0` = 193 mm and `α` = 1.7 µm/(m·K) (invar).
#[inline]
pub fn head_thermal_um(head_mc: i32, t_ref_c: f64) -> f64 {
    HEAD_L0_MM * 1e-3 * HEAD_ALPHA_UM_PER_M_K * (f64::from(head_mc) * 1e-3 - t_ref_c)
}

/// What [`ErrorMap::correction_um`] does with a position outside the grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutsideMap {
    /// Use the nearest edge of the grid (the correction is extrapolated flat).
    Clamp,
    /// Refuse: [`ConvertError::OutsideMap`]. The default, since a flat extrapolation of a
    /// calibration is a silently wrong value.
    #[default]
    Error,
}

/// Calibrated PSD error map: a regular grid of `(dx, dy)` corrections, µm, interpolated
/// bilinearly. The corrected position is the measured position **plus** the correction.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorMap {
    /// Position of grid point (0, 0), µm.
    pub x0_um: f64,
    pub y0_um: f64,
    /// Grid steps, µm, > 0.
    pub dx_um: f64,
    pub dy_um: f64,
    /// Grid points along x and y, ≥ 2 each.
    pub nx: usize,
    pub ny: usize,
    /// Corrections, row-major by y: `corrections[iy * nx + ix]` at
    /// `(x0 + ix·dx, y0 + iy·dy)`.
    pub corrections_um: Vec<[f64; 2]>,
    pub outside: OutsideMap,
}

impl ErrorMap {
    /// Checks the shape of a map read from a configuration.
    pub fn validate(&self) -> Result<(), ConvertError> {
        let expected = self.nx.saturating_mul(self.ny);
        let ok = self.nx >= 2
            && self.ny >= 2
            && self.dx_um.is_finite()
            && self.dy_um.is_finite()
            && self.dx_um > 0.0
            && self.dy_um > 0.0
            && self.x0_um.is_finite()
            && self.y0_um.is_finite()
            && self.corrections_um.len() == expected;
        if ok {
            Ok(())
        } else {
            Err(ConvertError::BadMap {
                expected,
                got: self.corrections_um.len(),
            })
        }
    }

    /// Bilinearly interpolated correction at `(x_um, y_um)`.
    pub fn correction_um(&self, x_um: f64, y_um: f64) -> Result<[f64; 2], ConvertError> {
        self.validate()?;
        let outside = ConvertError::OutsideMap { x_um, y_um };
        // Fractional grid coordinates.
        let mut u = (x_um - self.x0_um) / self.dx_um;
        let mut v = (y_um - self.y0_um) / self.dy_um;
        let (umax, vmax) = ((self.nx - 1) as f64, (self.ny - 1) as f64);
        if !(u.is_finite() && v.is_finite()) {
            return Err(outside);
        }
        if !(0.0..=umax).contains(&u) || !(0.0..=vmax).contains(&v) {
            match self.outside {
                OutsideMap::Error => return Err(outside),
                OutsideMap::Clamp => {
                    u = u.clamp(0.0, umax);
                    v = v.clamp(0.0, vmax);
                }
            }
        }
        // Cell index; the last cell also takes the upper edge.
        let ix = (u.floor() as usize).min(self.nx - 2);
        let iy = (v.floor() as usize).min(self.ny - 2);
        let (fu, fv) = (u - ix as f64, v - iy as f64);
        let at = |i: usize, j: usize| self.corrections_um[j * self.nx + i];
        let (c00, c10, c01, c11) = (
            at(ix, iy),
            at(ix + 1, iy),
            at(ix, iy + 1),
            at(ix + 1, iy + 1),
        );
        let mut out = [0.0; 2];
        for k in 0..2 {
            out[k] = c00[k] * (1.0 - fu) * (1.0 - fv)
                + c10[k] * fu * (1.0 - fv)
                + c01[k] * (1.0 - fu) * fv
                + c11[k] * fu * fv;
        }
        Ok(out)
    }

    /// Measured position plus interpolated correction, µm.
    pub fn apply(&self, x_um: f64, y_um: f64) -> Result<[f64; 2], ConvertError> {
        let c = self.correction_um(x_um, y_um)?;
        Ok([x_um + c[0], y_um + c[1]])
    }
}
