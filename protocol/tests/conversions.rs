//! Conversions against independent expectations: published reference values where they exist,
//! an independent high-precision re-derivation (tests/reference/edlen_reference.py) where not,
//! and hand-worked examples.

// Reference values are quoted with all the digits their source gives.
#![allow(clippy::excessive_precision)]

use protocol::cb3::SampleFrame;
use protocol::convert::*;
use protocol::edlen::*;
use protocol::li80::EnvFrame;
use protocol::psd::DataLine;

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn saturation_vapour_pressure_matches_iapws_if97_verification_table() {
    // IAPWS-IF97 (Wagner et al., 2000), Table 35: computer-program verification values of the
    // saturation-pressure equation: 300 K → 0.353658941e-2 MPa, 500 K → 0.263889776e1 MPa,
    // 600 K → 0.123443146e2 MPa (nine significant digits).
    for (t_k, p_mpa) in [
        (300.0, 0.353_658_941e-2),
        (500.0, 0.263_889_776e1),
        (600.0, 0.123_443_146e2),
    ] {
        let got = saturation_vapour_pressure_pa(t_k - 273.15) / 1e6;
        assert!(close(got / p_mpa, 1.0, 2e-9), "{t_k} K: {got} vs {p_mpa}");
    }
    assert!(close(
        water_vapour_pressure_pa(26.85, 50.0),
        0.5 * 3_536.589_41,
        1e-4
    ));
}

#[test]
fn birch_downs_matches_independent_rederivation_15_to_30_c() {
    // 40-digit decimal re-derivation of Birch & Downs (1994) eqs. 1-3 with IAPWS-IF97 eq. 30,
    // tests/reference/edlen_reference.py (written separately, other language); 632.991 nm,
    // 450 ppm CO2. No published check values for the unmodified Birch & Downs equation with
    // this humidity conversion were found; see the NIST comparison below for a published one.
    let table = [
        (15.0, 101_325.0, 0.0, 1.000_276_528_981_100),
        (15.0, 101_325.0, 50.0, 1.000_276_219_011_475),
        (20.0, 101_325.0, 0.0, 1.000_271_799_082_706),
        (20.0, 101_325.0, 50.0, 1.000_271_373_998_313),
        (20.0, 99_000.0, 30.0, 1.000_265_304_830_126),
        (22.5, 100_500.0, 45.0, 1.000_266_853_039_292),
        (25.0, 101_325.0, 50.0, 1.000_266_651_816_699),
        (25.0, 102_000.0, 80.0, 1.000_268_087_060_999),
        (30.0, 101_325.0, 50.0, 1.000_262_035_649_523),
        (30.0, 98_000.0, 20.0, 1.000_253_871_987_053),
    ];
    for (t, p, rh, want) in table {
        let got = li80_refractive_index(t, p, rh);
        assert!(close(got, want, 1e-12), "({t}, {p}, {rh}): {got} vs {want}");
        assert_eq!(got, refractive_index(632.991, t, p, rh, 450.0));
    }
}

#[test]
fn nist_modified_edlen_matches_published_values() {
    // Values published in the README of the `ref_index` 1.0 package (PyPI), an implementation of
    // the NIST Engineering Metrology Toolbox's modified Edlén equation (Stone & Zimmerman,
    // appendix A-IV): edlen(wave=633.0, t, p=101325, rh).
    for (t, rh, want) in [
        (20.0, 20.0, 1.000_271_629_169_164_9),
        (20.0, 80.0, 1.000_271_119_763_522_6),
        (60.0, 80.0, 1.000_233_974_854_282_3),
    ] {
        let got = refractive_index_nist_modified(633.0, t, 101_325.0, rh, 450.0);
        assert!(close(got, want, 1e-11), "({t}, {rh}): {got} vs {want}");
    }
    // At 20 °C the unmodified water term differs only by the factor 292.75/293.15: < 1e-9.
    let bd = refractive_index(633.0, 20.0, 101_325.0, 80.0, 450.0);
    assert!(close(bd, 1.000_271_119_763_522_6, 1e-9));
}

#[test]
fn birch_downs_agrees_with_nist_ciddor_values() {
    // NIST EMT Ciddor calculator outputs (633 nm, 101325 Pa), as quoted in the tests of the
    // `ref_index` package: the two equations agree to about 1e-8 in laboratory air.
    for (t, rh, ciddor) in [
        (20.0, 50.0, 1.000_271_373),
        (20.0, 0.0, 1.000_271_8),
        (20.0, 100.0, 1.000_270_949),
        (26.7982, 50.0, 1.000_264_994),
    ] {
        let got = refractive_index(633.0, t, 101_325.0, rh, 450.0);
        assert!(
            close(got, ciddor, 2e-8),
            "({t}, {rh}): {got} vs Ciddor {ciddor}"
        );
    }
}

#[test]
fn co2_correction() {
    let at = |x| refractive_index(632.991, 20.0, 101_325.0, 0.0, x);
    // 450 ppm is Birch and Downs' standard air: no change at all.
    assert_eq!(
        at(450.0),
        refractive_index_f(632.991, 20.0, 101_325.0, 0.0, 450.0)
    );
    // 400 ppm: (n−1) scaled by 1/(1 + 0.5327·5e-5) = 1 − 2.6634e-5 → −7.239e-9 at n−1 = 2.71799e-4.
    let d = at(400.0) - at(450.0);
    assert!(
        close(
            d,
            -2.717_99e-4 * 0.5327 * 5e-5 / (1.0 + 0.5327 * 5e-5),
            1e-13
        ),
        "{d}"
    );
}

fn env(air_c: f64, air_pa: f64, rh_pct: f64, material_c: Vec<f64>) -> EnvFrame {
    EnvFrame {
        seq: 0,
        t_us: 0,
        air_c,
        air_pa,
        rh_pct,
        material_c,
    }
}

#[test]
fn li80_compensation_hand_worked() {
    // n at 20 °C, 101325 Pa, 50 % = 1.000271373998313 (table above). raw = 1 m:
    // L = 1e9/n = 999 728 699.6256 nm; material mean (20.5 + 21.5)/2 = 21 °C, steel:
    // L20 = L·(1 − 11.7e-6·1) = 999 717 002.7998 nm.
    let c =
        Li80Compensation::from_env(&env(20.0, 101_325.0, 50.0, vec![20.5, 21.5]), 11.7).unwrap();
    assert_eq!(c.material_c, 21.0);
    assert!(close(
        air_corrected_nm(1e9, c.n_air),
        999_728_699.625_6,
        1e-3
    ));
    assert!(close(
        c.length_at_20c_nm(1_000_000_000),
        999_717_002.799_8,
        1e-3
    ));
    // At 20 °C material the thermal factor is 1.
    assert_eq!(length_at_20c_nm(123.0, 11.7, 20.0), 123.0);
    assert!(close(
        length_at_20c_nm(1e6, 11.7, 25.0),
        1e6 * (1.0 - 58.5e-6),
        1e-9
    ));
}

#[test]
fn li80_compensation_rejects_implausible_env() {
    assert_eq!(
        Li80Compensation::from_env(&env(20.0, 101_325.0, 50.0, vec![]), 11.7),
        Err(ConvertError::NoMaterialSensor)
    );
    assert!(matches!(
        Li80Compensation::from_env(&env(20.0, 101_325.0, 150.0, vec![20.0]), 11.7),
        Err(ConvertError::OutOfRange {
            what: "relative humidity %",
            ..
        })
    ));
    assert!(matches!(
        Li80Compensation::from_env(&env(20.0, 1_013.25, 50.0, vec![20.0]), 11.7),
        Err(ConvertError::OutOfRange { .. })
    ));
    assert!(matches!(
        Li80Compensation::from_env(&env(20.0, 101_325.0, 50.0, vec![20.0, 500.0]), 11.7),
        Err(ConvertError::OutOfRange { .. })
    ));
}

#[test]
fn capball_hand_worked() {
    // d = 10·2 + 0.5·4 − 0.1·8 = 21.2 µm.
    let p = CapBallPoly {
        c: [10.0, 0.5, -0.1],
    };
    assert!(close(p.distance_um(2.0), 21.2, 1e-12));
    assert!(close(p.distance_um(-2.0), -20.0 + 2.0 + 0.8, 1e-12));
    // T: 90° about z, then translate by (1, 2, 3) µm: (x, y, z) → (−y + 1, x + 2, z + 3).
    let t = CapBallTransform {
        t: [
            [0.0, -1.0, 0.0, 1.0],
            [1.0, 0.0, 0.0, 2.0],
            [0.0, 0.0, 1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };
    assert_eq!(t.apply([10.0, 20.0, 30.0]), [-19.0, 12.0, 33.0]);
    assert_eq!(
        CapBallTransform::IDENTITY.apply([1.0, 2.0, 3.0]),
        [1.0, 2.0, 3.0]
    );
    // Codes 838861, −419430, 0 ≈ 1.0000 V, −0.5000 V, 0 V with the nominal 10 µm/V.
    let s = SampleFrame {
        seq: 0,
        t_us: 0,
        ch: [838_861, -419_430, 0],
        flags: 0,
    };
    let v = capball_volumetric_um(&s, &[CapBallPoly::NOMINAL; 3], &CapBallTransform::IDENTITY);
    assert!(close(v[0], 838_861.0 * 10.0 / 8_388_608.0 * 10.0, 1e-12));
    assert!(close(v[0], 10.0, 1e-5) && close(v[1], -5.0, 1e-5) && v[2] == 0.0);
}

fn data(x1: u64, x2: u64, y1: u64, y2: u64) -> DataLine {
    DataLine {
        seq: 0,
        t_us: 0,
        x1_pa: x1,
        x2_pa: x2,
        y1_pa: y1,
        y2_pa: y2,
        head_mc: 20_000,
    }
}

#[test]
fn psd_position_hand_worked() {
    // x = 5000 µm · (3000 − 1000)/4000 = 2500 µm; y = 5000 · (1000 − 3000)/4000 = −2500 µm.
    assert_eq!(
        psd_position(&data(1000, 3000, 3000, 1000), 100),
        PsdReading::Valid {
            x_um: 2500.0,
            y_um: -2500.0
        }
    );
    assert_eq!(
        psd_position(&data(500, 500, 0, 2000), 100),
        PsdReading::Valid {
            x_um: 0.0,
            y_um: 5000.0
        }
    );
    // Gating: y1 + y2 = 99 < 100.
    assert_eq!(
        psd_position(&data(1000, 3000, 49, 50), 100),
        PsdReading::LowIntensity {
            sum_x_pa: 4000,
            sum_y_pa: 99
        }
    );
    // All dark with a zero minimum is still invalid (no division by zero).
    assert!(matches!(
        psd_position(&data(0, 0, 0, 0), 0),
        PsdReading::LowIntensity { .. }
    ));
}

#[test]
fn head_thermal_hand_worked() {
    // 193 mm · 1.7 µm/(m·K) · (25 − 20) K = 0.193 · 1.7 · 5 = 1.6405 µm.
    assert!(close(head_thermal_um(25_000, 20.0), 1.6405, 1e-12));
    assert!(close(head_thermal_um(19_000, 20.0), -0.3281, 1e-12));
}

fn map(outside: OutsideMap) -> ErrorMap {
    // 3 × 2 grid, x at −1000, 0, 1000 µm; y at 0, 2000 µm.
    ErrorMap {
        x0_um: -1000.0,
        y0_um: 0.0,
        dx_um: 1000.0,
        dy_um: 2000.0,
        nx: 3,
        ny: 2,
        corrections_um: vec![
            [0.0, 0.0],
            [1.0, -1.0],
            [2.0, 0.0],
            [4.0, 0.0],
            [5.0, 1.0],
            [6.0, 2.0],
        ],
        outside,
    }
}

#[test]
fn error_map_bilinear_hand_worked() {
    let m = map(OutsideMap::Error);
    // Grid points exactly.
    assert_eq!(m.correction_um(0.0, 0.0).unwrap(), [1.0, -1.0]);
    assert_eq!(m.correction_um(1000.0, 2000.0).unwrap(), [6.0, 2.0]);
    // Cell centre of (−1000..0) × (0..2000): mean of 0, 1, 4, 5 = 2.5; of 0, −1, 0, 1 = 0.
    assert_eq!(m.correction_um(-500.0, 1000.0).unwrap(), [2.5, 0.0]);
    // (500, 500): u = 1.5, v = 0.25: x: (1·0.5 + 2·0.5)·0.75 + (5·0.5 + 6·0.5)·0.25 = 1.125 + 1.375 = 2.5;
    // y: (−1·0.5 + 0)·0.75 + (1·0.5 + 2·0.5)·0.25 = −0.375 + 0.375 = 0.
    assert_eq!(m.correction_um(500.0, 500.0).unwrap(), [2.5, 0.0]);
    assert_eq!(m.apply(500.0, 500.0).unwrap(), [502.5, 500.0]);
    assert_eq!(
        m.correction_um(1500.0, 0.0),
        Err(ConvertError::OutsideMap {
            x_um: 1500.0,
            y_um: 0.0
        })
    );
    assert!(m.correction_um(f64::NAN, 0.0).is_err());
    let c = map(OutsideMap::Clamp);
    assert_eq!(c.correction_um(1500.0, -10.0).unwrap(), [2.0, 0.0]);
    assert_eq!(c.correction_um(-5000.0, 9000.0).unwrap(), [4.0, 0.0]);
    let mut bad = map(OutsideMap::Error);
    bad.corrections_um.pop();
    assert_eq!(
        bad.validate(),
        Err(ConvertError::BadMap {
            expected: 6,
            got: 5
        })
    );
}
