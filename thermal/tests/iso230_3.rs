//! ISO 230-3 evaluations against a hand-worked example and a second implementation.

use proptest::prelude::*;
use thermal::iso230_3::{FiveProbes, etve, spindle_distortion};

#[test]
fn hand_worked_example() {
    // Probes 100 mm apart. After 1 h: X1 +4, X2 +9 µm; Y1 -2, Y2 -1 µm; Z -12 µm.
    // After 2 h: X1 +3, X2 +5; Y1 +1, Y2 -3; Z -20.
    let x1 = [0.0, 4.0, 3.0];
    let x2 = [1.0, 10.0, 6.0]; // starts at 1: only changes count
    let y1 = [0.0, -2.0, 1.0];
    let y2 = [0.0, -1.0, -3.0];
    let z = [0.0, -12.0, -20.0];
    let d = spindle_distortion(
        FiveProbes {
            x1_um: &x1,
            x2_um: &x2,
            y1_um: &y1,
            y2_um: &y2,
            z_um: &z,
        },
        100.0,
    )
    .unwrap();
    // B: (9 - 4) / 100 mm = 0.05 µm/mm = 50 µrad; then (5 - 3) / 100 = 20 µrad.
    assert_eq!(d.b_urad, vec![0.0, 50.0, 20.0]);
    // A: (-1 - (-2)) / 100 = 10 µrad; (-3 - 1) / 100 = -40 µrad.
    assert_eq!(d.a_urad, vec![0.0, 10.0, -40.0]);
    assert_eq!((d.max.x_um, d.max.y_um, d.max.z_um), (4.0, 2.0, 20.0));
    assert_eq!((d.max.a_urad, d.max.b_urad), (40.0, 50.0));
    // ETVE of Z: from 0 to -20 µm.
    assert_eq!(etve(&z).unwrap(), 20.0);
    assert_eq!(etve(&[5.0, -1.0, 2.0]).unwrap(), 6.0);
}

#[test]
fn bad_input_is_refused() {
    let ok = [0.0, 1.0];
    let p = FiveProbes {
        x1_um: &ok,
        x2_um: &ok,
        y1_um: &ok,
        y2_um: &ok,
        z_um: &[0.0],
    };
    assert!(spindle_distortion(p, 100.0).is_err());
    let p = FiveProbes {
        x1_um: &ok,
        x2_um: &ok,
        y1_um: &ok,
        y2_um: &ok,
        z_um: &ok,
    };
    assert!(spindle_distortion(p, 0.0).is_err());
    assert!(
        spindle_distortion(
            FiveProbes {
                x2_um: &[0.0, f64::NAN],
                ..p
            },
            100.0
        )
        .is_err()
    );
    assert!(etve(&[1.0]).is_err());
    assert!(etve(&[1.0, f64::INFINITY]).is_err());
}

/// A second, separately written evaluation: sorting for the range, rotating the mandrel's
/// two points into angles by atan (the small-angle form differs by under 1e-5 relative at these sizes).
fn second_etve(s: &[f64]) -> f64 {
    let mut v = s.to_vec();
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() - 1] - v[0]
}

fn second_tilt_urad(near: &[f64], far: &[f64], spacing_mm: f64) -> f64 {
    let mut worst: f64 = 0.0;
    for i in 0..near.len() {
        let dn = (near[i] - near[0]) * 1e-3; // mm
        let df = (far[i] - far[0]) * 1e-3;
        let angle = ((df - dn) / spacing_mm).atan() * 1e6;
        if angle.abs() > worst.abs() {
            worst = angle;
        }
    }
    worst.abs()
}

proptest! {
    #[test]
    fn agrees_with_a_second_implementation(
        v in proptest::collection::vec((-50.0f64..50.0, -50.0f64..50.0, -50.0f64..50.0, -50.0f64..50.0, -50.0f64..50.0), 2..40),
        spacing in 20.0f64..400.0,
    ) {
        let col = |k: usize| v.iter().map(|t| [t.0, t.1, t.2, t.3, t.4][k]).collect::<Vec<f64>>();
        let (x1, x2, y1, y2, z) = (col(0), col(1), col(2), col(3), col(4));
        let d = spindle_distortion(FiveProbes { x1_um: &x1, x2_um: &x2, y1_um: &y1, y2_um: &y2, z_um: &z }, spacing).unwrap();
        prop_assert!((d.max.b_urad - second_tilt_urad(&x1, &x2, spacing)).abs() < 1e-4 * (1.0 + d.max.b_urad));
        prop_assert!((d.max.a_urad - second_tilt_urad(&y1, &y2, spacing)).abs() < 1e-4 * (1.0 + d.max.a_urad));
        let zmax = z.iter().map(|q| (q - z[0]).abs()).fold(0.0, f64::max);
        prop_assert!((d.max.z_um - zmax).abs() < 1e-12);
        prop_assert!((etve(&z).unwrap() - second_etve(&z)).abs() < 1e-12);
    }
}
