//! Refractive index of air: Edlén's equation as updated by Birch and Downs (1993, with the
//! 1994 correction), including the water-vapour term and a CO2 content of 450 ppm.
//!
//! Equations (Birch & Downs, Metrologia 31 (1994) 315, eqs. 1-3; σ = 1/λ_vac in µm⁻¹,
//! `t` in °C, `p` and `f` in Pa):
//! - standard air (dry, 15 °C, 101 325 Pa, **450 ppm CO2**):
//!   `(n−1)_s·10⁸ = 8342.54 + 2406147/(130 − σ²) + 15998/(38.9 − σ²)`;
//! - temperature and pressure:
//!   `(n−1)_tp = p·(n−1)_s/96095.43 · [1 + 10⁻⁸(0.601 − 0.00972·t)·p]/(1 + 0.0036610·t)`;
//! - water vapour of partial pressure `f`: `n_tpf − n_tp = −f·(3.7345 − 0.0401·σ²)·10⁻¹⁰`.
//!
//! Birch and Downs give no humidity conversion; `f` = RH · p_sv(t) with the saturation vapour
//! pressure over water of IAPWS-IF97 (eq. 30), as the NIST Engineering Metrology Toolbox does
//! (Stone & Zimmerman, "Index of refraction of air", appendix A-I). The enhancement factor
//! (≈1.004) is ignored, as in the NIST Edlén calculation.
//!
//! CO2: Birch and Downs' standard air already contains 450 ppm, the value instruments.md
//! prescribes, so at 450 ppm no correction is applied. For another content `x` the refractivity
//! is scaled by `[1 + 0.5327·(x − 0.0004)] / [1 + 0.5327·(0.00045 − 0.0004)]` (mole fractions),
//! the CO2 dependence of Bönsch & Potulski (Metrologia 35 (1998) 133, eq. 7, there referred to
//! 400 ppm), re-referred to 450 ppm. This is the same 0.53·10⁻⁶/ppm slope Ciddor (1996) uses.
//!
//! The NIST calculator's "modified Edlén" multiplies the water term by `292.75/T` (T in K);
//! [`refractive_index_nist_modified`] implements it for comparison with NIST values. The two
//! differ by < 1·10⁻⁹ at 20 °C and by ≈3·10⁻⁸ at 30 °C, 50 % RH.

/// Vacuum wavelength of the LI-80, nm.
pub const LI80_VACUUM_WAVELENGTH_NM: f64 = 632.991;

/// CO2 content of the air the LI-80 compensation assumes (instruments.md §1), ppm.
pub const LI80_CO2_PPM: f64 = 450.0;

/// CO2 content of Birch and Downs' standard air, ppm.
pub const BIRCH_DOWNS_CO2_PPM: f64 = 450.0;

/// Saturation vapour pressure over liquid water, Pa, at `t_c` °C: IAPWS-IF97 eq. 30
/// (valid 0 °C to 373.946 °C; used as the NIST toolbox does).
pub fn saturation_vapour_pressure_pa(t_c: f64) -> f64 {
    const N: [f64; 10] = [
        0.116_705_214_527_67e4,
        -0.724_213_167_032_06e6,
        -0.170_738_469_400_92e2,
        0.120_208_247_024_70e5,
        -0.323_255_503_223_33e7,
        0.149_151_086_135_30e2,
        -0.482_326_573_615_91e4,
        0.405_113_405_420_57e6,
        -0.238_555_575_678_49,
        0.650_175_348_447_98e3,
    ];
    let t_k = t_c + 273.15;
    let th = t_k + N[8] / (t_k - N[9]);
    let a = th * th + N[0] * th + N[1];
    let b = N[2] * th * th + N[3] * th + N[4];
    let c = N[5] * th * th + N[6] * th + N[7];
    let x = 2.0 * c / (-b + (b * b - 4.0 * a * c).sqrt());
    1.0e6 * x.powi(4)
}

/// Partial pressure of water vapour, Pa, at relative humidity `rh_pct` % and `t_c` °C.
pub fn water_vapour_pressure_pa(t_c: f64, rh_pct: f64) -> f64 {
    rh_pct / 100.0 * saturation_vapour_pressure_pa(t_c)
}

/// Refractivity `(n−1)` of dry air at `t_c`, `p_pa`, CO2 `co2_ppm`; σ² in µm⁻².
fn dry_refractivity(sigma2: f64, t_c: f64, p_pa: f64, co2_ppm: f64) -> f64 {
    let n_s = 1e-8 * (8342.54 + 2_406_147.0 / (130.0 - sigma2) + 15_998.0 / (38.9 - sigma2));
    let co2 = (1.0 + 0.5327 * (co2_ppm * 1e-6 - 0.0004))
        / (1.0 + 0.5327 * (BIRCH_DOWNS_CO2_PPM * 1e-6 - 0.0004));
    p_pa * n_s * co2 / 96_095.43 * (1.0 + 1e-8 * (0.601 - 0.00972 * t_c) * p_pa)
        / (1.0 + 0.003_661_0 * t_c)
}

/// `n` for vacuum wavelength `lambda_nm`, air temperature `t_c` °C, pressure `p_pa` Pa,
/// relative humidity `rh_pct` %, CO2 `co2_ppm`.
pub fn refractive_index(lambda_nm: f64, t_c: f64, p_pa: f64, rh_pct: f64, co2_ppm: f64) -> f64 {
    let f = water_vapour_pressure_pa(t_c, rh_pct);
    refractive_index_f(lambda_nm, t_c, p_pa, f, co2_ppm)
}

/// As [`refractive_index`] with the water-vapour partial pressure `f_pa` given directly.
pub fn refractive_index_f(lambda_nm: f64, t_c: f64, p_pa: f64, f_pa: f64, co2_ppm: f64) -> f64 {
    let sigma = 1000.0 / lambda_nm;
    let s2 = sigma * sigma;
    1.0 + dry_refractivity(s2, t_c, p_pa, co2_ppm) - f_pa * (3.7345 - 0.0401 * s2) * 1e-10
}

/// The NIST Engineering Metrology Toolbox's "modified Edlén": Birch and Downs with the water
/// term scaled by `292.75/T`. For comparison with NIST values only.
pub fn refractive_index_nist_modified(
    lambda_nm: f64,
    t_c: f64,
    p_pa: f64,
    rh_pct: f64,
    co2_ppm: f64,
) -> f64 {
    let sigma = 1000.0 / lambda_nm;
    let s2 = sigma * sigma;
    let f = water_vapour_pressure_pa(t_c, rh_pct);
    1.0 + dry_refractivity(s2, t_c, p_pa, co2_ppm)
        - 292.75 / (t_c + 273.15) * f * (3.7345 - 0.0401 * s2) * 1e-10
}

/// Refractive index at the LI-80 wavelength and 450 ppm CO2, as instruments.md §1 prescribes.
pub fn li80_refractive_index(t_c: f64, p_pa: f64, rh_pct: f64) -> f64 {
    refractive_index(LI80_VACUUM_WAVELENGTH_NM, t_c, p_pa, rh_pct, LI80_CO2_PPM)
}
