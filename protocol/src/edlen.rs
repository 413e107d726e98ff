//! Refractive index of air: Edlén's equation as updated by Birch and Downs (1993, with the
//! 1994 correction), including the water-vapour term and a CO2 content of 450 ppm.

/// Vacuum wavelength of the LI-80, nm.
pub const LI80_VACUUM_WAVELENGTH_NM: f64 = 632.991;

/// `n` for vacuum wavelength `lambda_nm`, air temperature `t_c` °C, pressure `p_pa` Pa,
/// relative humidity `rh_pct` %, CO2 `co2_ppm`.
pub fn refractive_index(
    _lambda_nm: f64,
    _t_c: f64,
    _p_pa: f64,
    _rh_pct: f64,
    _co2_ppm: f64,
) -> f64 {
    todo!("Edlén / Birch-Downs: in progress")
}
