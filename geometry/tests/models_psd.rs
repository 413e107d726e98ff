//! PSD laser-frame model: exact round trip, noise propagation against the stated uncertainty,
//! and a cross-check against the rigid-body kinematics.

// Parallel arrays indexed together read more plainly with an index.
#![allow(clippy::needless_range_loop)]

use geometry::kinematics::{AxisName, ErrorSource, Machine, SmallDisplacement};
use geometry::psd_frame::*;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Remove mean and least-squares slope (the ISO 230-1 reference line).
fn deslope(p: &[f64], v: &[f64]) -> Vec<f64> {
    let n = p.len() as f64;
    let pm = p.iter().sum::<f64>() / n;
    let vm = v.iter().sum::<f64>() / n;
    let sxx: f64 = p.iter().map(|x| (x - pm).powi(2)).sum();
    let b = p
        .iter()
        .zip(v)
        .map(|(x, y)| (x - pm) * (y - vm))
        .sum::<f64>()
        / sxx;
    p.iter()
        .zip(v)
        .map(|(x, y)| y - vm - b * (x - pm))
        .collect()
}

fn truth(l: &PsdLayout) -> PsdErrors {
    let (xs, ys, ys1, zs) = (l.xs(), l.ys(), l.ys1(), l.zs());
    let f = |p: &[f64], a: f64, w: f64| {
        deslope(
            p,
            &p.iter()
                .map(|x| a * (x * w).sin() + 0.3 * a * (x * w * 2.3).cos())
                .collect::<Vec<_>>(),
        )
    };
    PsdErrors {
        exx_um: xs.iter().map(|x| 1.5 + 0.02 * x).collect(),
        eyy_um: ys.iter().map(|y| -0.8 + 0.015 * y).collect(),
        eyx_um: f(&xs, 1.2, 0.03),
        ezx_um: f(&xs, 2.0, 0.02),
        exy_um: f(&ys, 0.9, 0.04),
        ezy_um: f(&ys, 1.7, 0.025),
        exz_um: f(&zs, 2.5, 0.011),
        eyz_um: f(&zs, 1.1, 0.017),
        eax_urad: f(&xs, 8.0, 0.035),
        eby_urad: f(&ys1, 6.0, 0.05),
        ec0y_urad: 12.0,
        eb0z_urad: -9.0,
        ea0z_urad: 7.0,
        frame: FrameTerms {
            xy_rotation_urad: 4.0,
            x_tilt_urad: -3.0,
            y_tilt_urad: 2.0,
            z_offset_um: 0.7,
        },
        x_mm: xs,
        y_mm: ys,
        y_s1_mm: ys1,
        z_mm: zs,
    }
}

#[test]
fn exact_round_trip_through_the_field_model() {
    let l = PsdLayout::paper();
    let t = truth(&l);
    let r = simulate_readings(&l, &t);
    assert_eq!(r.s1.len(), 7);
    assert_eq!(r.to_vec().len(), 2 * 51);
    let d = derive_errors(&l, &r).unwrap();
    let (a, b) = (t.to_vec(), d.to_vec());
    assert_eq!(a.len(), b.len());
    for (k, name) in t.names().iter().enumerate() {
        assert!(
            (a[k] - b[k]).abs() < 1e-9,
            "{name}: truth {} derived {}",
            a[k],
            b[k]
        );
    }
}

#[test]
fn noise_propagates_as_stated_normalised_errors() {
    // Paper 003 §5: reading noise, doubled in variance by the reference subtraction.
    let l = PsdLayout::paper();
    let t = truth(&l);
    let sigma = 0.2;
    let u = derive_uncertainty(&l, sigma * 2f64.sqrt()).unwrap();
    let clean = simulate_readings(&l, &t);
    let zero = PsdReadings::from_vec(&l, &vec![0.0; 102]);
    let n = Normal::new(0.0, sigma).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let tv = t.to_vec();
    let mut z2 = 0.0;
    let mut count = 0usize;
    let mut worst: f64 = 0.0;
    for _ in 0..200 {
        let noisy = |base: &PsdReadings, rng: &mut ChaCha8Rng| {
            PsdReadings::from_vec(
                &l,
                &base
                    .to_vec()
                    .iter()
                    .map(|v| v + n.sample(rng))
                    .collect::<Vec<_>>(),
            )
        };
        let run = noisy(&clean, &mut rng);
        let reference = noisy(&zero, &mut rng);
        let d = derive_errors(&l, &run.minus(&reference).unwrap())
            .unwrap()
            .to_vec();
        for k in 0..tv.len() {
            if u[k] > 1e-12 {
                let z = (d[k] - tv[k]) / u[k];
                worst = worst.max(z.abs());
                z2 += z * z;
                count += 1;
            }
        }
    }
    let rms = (z2 / count as f64).sqrt();
    assert!(count > 15_000);
    assert!((rms - 1.0).abs() < 0.03, "RMS of normalised errors {rms}");
    assert!(worst < 5.5, "largest normalised error {worst}");
    // The uncertainty of the Z-squarenesses is the largest of the angular terms, as in paper
    // 003 Table 4 (EA0Z, EB0Z several µm over the volume against 0.4 µm for positioning).
    let names = t.names();
    let ui = |n: &str| u[names.iter().position(|x| x == n).unwrap()];
    assert!(ui("EB0Z_urad") > ui("EC0Y_urad"));
}

struct Rigid;
impl ErrorSource for Rigid {
    fn link(&self, a: AxisName) -> SmallDisplacement {
        let rot = match a {
            AxisName::Y => Vector3::new(0.0, 0.0, 30.0),
            AxisName::Z => Vector3::new(15.0, -20.0, 0.0),
            _ => Vector3::zeros(),
        };
        SmallDisplacement {
            rot_urad: rot,
            trans_um: Vector3::zeros(),
        }
    }
    fn motion(&self, a: AxisName, q: f64) -> SmallDisplacement {
        // Positioning 20 µm/m on X and −10 µm/m on Y; straightnesses symmetric about the
        // middle of the travel (no least-squares slope); a roll of X.
        let (rot, tr) = match a {
            AxisName::X => (
                Vector3::new(1e-3 * (q - 92.0).powi(2), 0.0, 0.0),
                Vector3::new(0.02 * q, 1e-4 * (q - 92.0).powi(2), 0.0),
            ),
            AxisName::Y => (
                Vector3::zeros(),
                Vector3::new(0.0, -0.01 * q, -2e-4 * (q - 83.5).powi(2)),
            ),
            _ => (Vector3::zeros(), Vector3::zeros()),
        };
        SmallDisplacement {
            rot_urad: rot,
            trans_um: tr,
        }
    }
}

#[test]
fn rigid_body_machine_cross_check() {
    // The paper's wbXYZt machine: bed carries X, X carries Y, Y carries Z and the PSD head.
    let m = Machine::from_chain("WFXYZT").unwrap();
    let l = PsdLayout::paper();
    let d = derive_errors(&l, &readings_from_machine(&l, &m, &Rigid)).unwrap();
    // Squarenesses as set in the chain (first order; second-order terms ~1e-4 µrad).
    assert!((d.ec0y_urad - 30.0).abs() < 0.01, "EC0Y {}", d.ec0y_urad);
    assert!((d.eb0z_urad + 20.0).abs() < 0.01, "EB0Z {}", d.eb0z_urad);
    // EA0Z: the Z direction is tilted 15 µrad about X. The roll of X adds to what the frame
    // sees: the Z travel at x_lo is tilted by EAX(x_lo) = 1e-3·92² = 8.464 µrad
    // (Ey = −EAX(x_lo)·z), and the mean roll over the X positions, 1e-3·18.4²·110/11 =
    // 3.3856 µrad, tilts the Y travel the same way (the gauge puts mean roll into the tilt):
    // 15 + 8.464 − 3.3856 = 20.0784 µrad, the squareness of the Z travel at x_lo to the mean Y.
    assert!((d.ea0z_urad - 20.0784).abs() < 0.01, "EA0Z {}", d.ea0z_urad);
    // Positioning scale: 20 µm/m over 184 mm = 3.68 µm; Y: −10 µm/m over 167 mm.
    let sx = d.exx_um[10] - d.exx_um[0];
    let sy = d.eyy_um[10] - d.eyy_um[0];
    assert!((sx - 3.68).abs() < 1e-3, "{sx}");
    assert!((sy + 1.67).abs() < 1e-3, "{sy}");
    // Straightness (least-squares line removed) and the roll of X.
    let xs = l.xs();
    let eyx = deslope(
        &xs,
        &xs.iter()
            .map(|x| 1e-4 * (x - 92.0).powi(2))
            .collect::<Vec<_>>(),
    );
    let eax = deslope(
        &xs,
        &xs.iter()
            .map(|x| 1e-3 * (x - 92.0).powi(2))
            .collect::<Vec<_>>(),
    );
    for i in 0..11 {
        assert!(
            (d.eyx_um[i] - eyx[i]).abs() < 1e-4,
            "EYX[{i}] {} vs {}",
            d.eyx_um[i],
            eyx[i]
        );
        assert!(
            (d.eax_urad[i] - eax[i]).abs() < 1e-3,
            "EAX[{i}] {} vs {}",
            d.eax_urad[i],
            eax[i]
        );
    }
    let ys = l.ys();
    let ezy = deslope(
        &ys,
        &ys.iter()
            .map(|y| -2e-4 * (y - 83.5).powi(2))
            .collect::<Vec<_>>(),
    );
    for i in 0..11 {
        assert!((d.ezy_um[i] - ezy[i]).abs() < 1e-4);
    }
    // In a wbXYZt machine the roll of Y has no in-plane lever arm: the twist between S1 and
    // S3 is zero (see psd_frame.md).
    assert!(d.eby_urad.iter().all(|v| v.abs() < 1e-6));
}

#[test]
fn degenerate_inputs() {
    let l = PsdLayout::paper();
    let mut r = simulate_readings(&l, &truth(&l));
    r.s3[4][1] = f64::NAN;
    assert_eq!(
        derive_errors(&l, &r).unwrap_err(),
        PsdError::NonFinite {
            segment: 3,
            point: 5
        }
    );
    r.s3.pop();
    assert!(matches!(
        derive_errors(&l, &r).unwrap_err(),
        PsdError::PointCount { segment: 3, .. }
    ));
    let bad = PsdLayout {
        x_hi: -1.0,
        ..PsdLayout::paper()
    };
    assert!(derive_errors(&bad, &r).is_err());
    // CSV round trip and missing points.
    let r = simulate_readings(&l, &truth(&l));
    let text = write_readings_csv(&[(0, r.clone()), (3, r.clone())]);
    let runs = parse_readings_csv(&l, &text).unwrap();
    assert_eq!(runs.len(), 2);
    assert!((runs[1].1.s5[3][1] - r.s5[3][1]).abs() < 1e-4);
    let cut: String = text
        .lines()
        .filter(|s| !s.starts_with("3,5,11,"))
        .map(|s| format!("{s}\n"))
        .collect();
    assert!(
        parse_readings_csv(&l, &cut)
            .unwrap_err()
            .to_string()
            .contains("segment 5 point 11")
    );
    assert!(parse_readings_csv(&l, "run,segment,point,r1_um,r2_um\n0,6,1,0,0\n").is_err());
}
