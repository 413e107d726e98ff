//! The uncertainty of ISO 230-2 results (positioning::iso230_uncertainty) against a hand
//! calculation written out here, term by term, for a small run (two targets 1000 mm apart,
//! three bidirectional cycles; the ISO 230-2 statistics of the same readings are worked by hand
//! in positioning_iso230.rs). No published worked example of ISO 230-2 Annex A or ISO/TR 230-9
//! was in reach; the budget's form is documented in the module and in docs/methods.md.

use positioning::iso230::evaluate;
use positioning::iso230_uncertainty::{self as unc, Known, Origin, Sensor, Setup};
use positioning::positioning_data::PositioningData;

const RUN: &str = "# axis: X
cycle,direction,index,target_mm,deviation_um
1,+,1,0,1
1,+,2,1000,4
1,-,2,1000,5
1,-,1,0,0
2,+,1,0,2
2,+,2,1000,4
2,-,2,1000,7
2,-,1,0,0
3,+,1,0,3
3,+,2,1000,4
3,-,2,1000,6
3,-,1,0,3
";

fn interferometer_setup() -> Setup {
    let a = |v: f64, n: &str| Some(Known::assumed(v, n));
    Setup {
        device_expanded_um_per_m: a(1.0, "certificate: U = 1 µm/m, k = 2"),
        air_compensation_ppm: a(0.5, "±0.5 ppm"),
        material_temp_accuracy_k: a(0.1, "±0.1 K"),
        material_temp_c: Some(Known::recorded(22.0, "material sensor")),
        alpha_um_per_m_k: a(11.7, "steel"),
        alpha_accuracy_um_per_m_k: a(1.0, "±1 µm/(m·K)"),
        misalignment_rad: a(1e-4, "beam walk < 0.1 mm/m"),
        dead_path_mm: a(100.0, "set-up sheet"),
        air_temp_range_k: Some(Known::recorded(0.5, "air sensor")),
        pressure_range_kpa: Some(Known::recorded(0.2, "barometer")),
        ..Setup::bare(Sensor::LaserInterferometer)
    }
}

fn result<'a>(b: &'a unc::Iso230Uncertainty, p: &str) -> &'a unc::ResultUncertainty {
    b.results.iter().find(|r| r.parameter == p).unwrap()
}

#[test]
fn interferometer_budget_by_hand() {
    let d = PositioningData::from_csv_str(RUN).unwrap();
    let b = unc::evaluate(&d, &evaluate(&d), &interferometer_setup());
    assert_eq!(b.length_mm, 1000.0);
    let r3 = 3f64.sqrt();
    // Scale terms over L = 1 m:
    let device = 1.0 / 2.0; // U/k
    let env = 0.5 / r3; // ±0.5 ppm rectangular
    let m_machine = 11.7 * 0.1 / r3; // α·L·δT/√3
    let e_machine = 2.0 * 1.0 / r3; // |22 − 20|·L·δα/√3
    let misalign = 1e6 * 1e-8 / 2.0 / (2.0 * r3); // L·θ²/2 one-sided, /(2√3)
    // Dead path 100 mm: Δn = 0.93e-6·0.5 K + 2.7e-6·0.2 kPa = 1.005e-6 → 0.1005 µm range.
    let dead = 1e5 * 1.005e-6 / (2.0 * r3);
    // E_VE from the run: pass offsets up (−0.5, 0, 0.5), down (−1, 0, 1): range 2 µm.
    let eve = 2.0 / (2.0 * r3);
    // E = 6 − 1 (target 2 down, s = 1; target 1 down, s = √3; n = 3): √(1/3 + 3/3).
    let samp_e = (1.0f64 / 3.0 + 1.0).sqrt();
    let u_e = [
        device, env, m_machine, e_machine, misalign, dead, eve, samp_e,
    ]
    .iter()
    .map(|x| x * x)
    .sum::<f64>()
    .sqrt();
    let e = result(&b, "E");
    assert_eq!(e.value_um, Some(5.0));
    assert!((e.u_um - u_e).abs() < 1e-9, "{} vs {u_e}", e.u_um);
    assert!((e.expanded_um - 2.0 * u_e).abs() < 1e-9);
    assert!((u_e - 1.946_915).abs() < 1e-5, "{u_e}");
    assert!(e.missing.is_empty());
    // B = |4 − 6| at target 2: E_VE and the two means (s↑ = 0, s↓ = 1, n = 3).
    let u_b = (eve * eve + 1.0 / 3.0).sqrt();
    assert!((result(&b, "B").u_um - u_b).abs() < 1e-9);
    // R = 4·s↓ = 4√3 at target 1: u(s) = s/√(2(n − 1)) = √3/2, times 4.
    let u_r = (eve * eve + (4.0 * r3 / 2.0f64).powi(2)).sqrt();
    let r = result(&b, "R");
    assert!((r.value_um.unwrap() - 4.0 * r3).abs() < 1e-12);
    assert!((r.u_um - u_r).abs() < 1e-9, "{} vs {u_r}", r.u_um);
    // The scale terms do not act on B and R.
    assert!(!r.contributions.iter().any(|c| c.0 == "u_DEVICE"));
}

#[test]
fn triangulation_without_temperatures_borrows_nothing() {
    let d = PositioningData::from_csv_str(RUN).unwrap();
    let setup = Setup::from_data(Sensor::Other("laser triangulation".into()), &d);
    let b = unc::evaluate(&d, &evaluate(&d), &setup);
    let c = |s: &str| b.contributors.iter().find(|c| c.symbol == s).unwrap();
    assert!(matches!(c("u_ENV").origin, Origin::NotApplicable(_)));
    assert!(matches!(c("u_DEADPATH").origin, Origin::NotApplicable(_)));
    for s in ["u_DEVICE", "u_M,MACHINE", "u_E,MACHINE", "u_MISALIGNMENT"] {
        assert!(matches!(c(s).origin, Origin::Missing(_)), "{s}");
        assert_eq!(c(s).u_um, None, "{s}");
    }
    let e = result(&b, "E");
    assert_eq!(
        e.missing,
        ["u_DEVICE", "u_M,MACHINE", "u_E,MACHINE", "u_MISALIGNMENT"]
    );
    // What is left: E_VE from the run and the sampling, a lower bound.
    let u = (1.0f64 / 3.0 + 4.0 / 3.0).sqrt();
    assert!((e.u_um - u).abs() < 1e-9, "{}", e.u_um);
}

#[test]
fn air_half_width_from_sensor_accuracies() {
    // ±0.1 K, ±0.1 kPa, ±5 %RH: 0.093, 0.27, 0.0425 ppm in quadrature = 0.28871 ppm.
    let h = unc::air_half_width_ppm(0.1, 0.1, 5.0);
    let want = (0.093f64.powi(2) + 0.27f64.powi(2) + 0.0425f64.powi(2)).sqrt();
    assert!(
        (h - want).abs() < 1e-12 && (h - 0.288_71).abs() < 1e-5,
        "{h}"
    );
}
