//! CapBall model tests: Jacobian against a numerical derivative, identification by simulation
//! with known truth, sensor-frame calibration, degenerate inputs.

// Parallel arrays indexed together read more plainly with an index.
#![allow(clippy::needless_range_loop)]

use geometry::capball::*;
use geometry::kinematics::Pose;
use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn truth() -> CapballErrors {
    CapballErrors {
        link: LinkErrors {
            ec0y_urad: 25.0,
            eb0z_urad: -40.0,
            ea0z_urad: 15.0,
            eb0a_urad: 60.0,
            ec0a_urad: -35.0,
            ea0c_urad: 20.0,
            eb0c_urad: -50.0,
            ey0c_um: 12.0,
        },
        setup: SetupErrors {
            ball_x_um: 30.0,
            ball_y_um: -20.0,
            ball_z_um: 10.0,
            tool_x_um: -15.0,
            tool_y_um: 8.0,
            tool_z_um: 40.0,
        },
    }
}

fn simulate(
    setup: &CapballSetup,
    poses: &[Pose],
    e: &CapballErrors,
    noise_um: f64,
    seed: u64,
) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, noise_um).unwrap();
    poses
        .iter()
        .map(|p| {
            let v = setup.volumetric_error_um(e, p);
            [
                v.x + n.sample(&mut rng),
                v.y + n.sample(&mut rng),
                v.z + n.sample(&mut rng),
            ]
        })
        .collect()
}

#[test]
fn analytic_jacobian_matches_numerical_derivative() {
    let s = CapballSetup::paper_default();
    for &(a, c) in &[
        (0.0, 0.0),
        (-30.0, 45.0),
        (-75.0, 200.0),
        (-90.0, 310.0),
        (20.0, 123.0),
    ] {
        let p = s.pose_for(a, c);
        let ja = s.jacobian(&p);
        let jn = s.jacobian_numeric(&p);
        let d = (ja - jn).abs().max();
        assert!(
            d < 1e-6,
            "pose a={a} c={c}: max |J_analytic − J_numeric| = {d}\n{ja}\n{jn}"
        );
    }
}

#[test]
fn pose_for_keeps_tool_on_ball() {
    let s = CapballSetup::paper_default();
    let p = s.pose_for(-45.0, 90.0);
    // A = −45° (tool relative to table, ISO 841), C = 90°: hand-worked with the table turned
    // by +45° about X and −90° about Z: ball (120, 80, 100) → Rz(−90): (80, −120, 100) →
    // Rx(+45°): (80, −120c − 100s, −120s + 100c) with c = s = √½.
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let expect = Vector3::new(80.0, -120.0 * h - 100.0 * h, -120.0 * h + 100.0 * h);
    let got = Vector3::new(p.x_mm, p.y_mm, p.z_mm);
    assert!((got - expect).norm() < 1e-9, "{got} vs {expect}");
    // And the error-free model reads zero there.
    let e = s.volumetric_error_um(&CapballErrors::default(), &p);
    assert!(e.norm() < 1e-9);
}

#[test]
fn identification_recovers_truth_within_its_uncertainty() {
    let s = CapballSetup::paper_default();
    let spec = TrajectorySpec::default();
    let poses = s.trajectory(&spec);
    assert_eq!(poses.len(), 807);
    let t = truth().to_vector();
    let mut z2 = Vec::new();
    for seed in 0..8 {
        let meas = simulate(&s, &poses, &truth(), 0.3, seed);
        let id = s.identify(&poses, &meas).unwrap();
        assert!(
            id.condition_number < 1e3,
            "condition {}",
            id.condition_number
        );
        assert!(
            (id.residual_sigma_um - 0.3).abs() < 0.03,
            "sigma {}",
            id.residual_sigma_um
        );
        for k in 0..N_PARAMS {
            let z = (id.params[k] - t[k]) / id.std_uncertainty[k];
            assert!(
                z.abs() < 4.5,
                "{}: {} vs {} (u = {})",
                PARAM_NAMES[k],
                id.params[k],
                t[k],
                id.std_uncertainty[k]
            );
            z2.push(z * z);
        }
    }
    let rms = (z2.iter().sum::<f64>() / z2.len() as f64).sqrt();
    // 112 normalised errors: their RMS is 1 within about ±0.2 when the covariance is right.
    assert!((rms - 1.0).abs() < 0.25, "RMS of normalised errors {rms}");
}

#[test]
fn validation_on_reversed_trajectory() {
    let s = CapballSetup::paper_default();
    let spec = TrajectorySpec::default();
    let id_poses = s.trajectory(&spec);
    let va_poses = s.trajectory(&spec.reversed_a());
    let id = s
        .identify(&id_poses, &simulate(&s, &id_poses, &truth(), 0.5, 1))
        .unwrap();
    let rms = s
        .validation_rms_um(&id, &va_poses, &simulate(&s, &va_poses, &truth(), 0.5, 2))
        .unwrap();
    for k in 0..3 {
        assert!((rms[k] - 0.5).abs() < 0.06, "validation rms {rms:?}");
        assert!(
            (id.residual_rms_um[k] - 0.5).abs() < 0.06,
            "identification rms {:?}",
            id.residual_rms_um
        );
    }
}

#[test]
fn degenerate_inputs_get_clear_errors() {
    let s = CapballSetup::paper_default();
    let poses = s.trajectory(&TrajectorySpec {
        n_poses: 4,
        ..Default::default()
    });
    let e = s.identify(&poses, &[[0.0; 3]; 4]).unwrap_err();
    assert!(matches!(e, CapballError::TooFewPoses { .. }), "{e}");
    let e = s.identify(&poses, &[[0.0; 3]; 3]).unwrap_err();
    assert!(matches!(e, CapballError::LengthMismatch { .. }));
    // A fixed: only C turns → A-axis and Z-related parameters are not excited.
    let flat: Vec<Pose> = (0..100).map(|i| s.pose_for(0.0, i as f64 * 3.6)).collect();
    let e = s.identify(&flat, &vec![[0.0; 3]; 100]).unwrap_err();
    assert!(matches!(e, CapballError::Singular { .. }), "{e}");
    let mut bad = vec![[0.0; 3]; 807];
    bad[10][1] = f64::NAN;
    let all = s.trajectory(&TrajectorySpec::default());
    assert_eq!(
        s.identify(&all, &bad).unwrap_err(),
        CapballError::NonFinite { index: 11 }
    );
    // Values in mm mistaken for µm are fine, but values in nm are not plausible.
    bad[10][1] = 25_000.0;
    assert!(matches!(
        s.identify(&all, &bad).unwrap_err(),
        CapballError::Implausible { .. }
    ));
}

#[test]
fn sensor_frame_calibration_recovers_gains_and_offsets() {
    // Sensor directions: slightly non-orthogonal, gains 1 %, −0.5 %, 0.3 %.
    let d = Matrix3::from_columns(&[
        Vector3::new(1.0, 0.002, -0.001) * 1.01,
        Vector3::new(-0.001, 1.0, 0.003) * 0.995,
        Vector3::new(0.0005, 0.0, 1.0) * 1.003,
    ]);
    let o = Vector3::new(12.0, -7.0, 3.0);
    let m = cube_points_um(200.0, 5);
    assert_eq!(m.len(), 125);
    let s: Vec<_> = m.iter().map(|mi| sensor_readings_um(&d, &o, mi)).collect();
    let f = calibrate_sensor_frame(&m, &s).unwrap();
    for k in 0..3 {
        assert!((f.gains[k] - d.column(k).norm()).abs() < 1e-9);
        assert!((f.offsets_um[k] - o[k]).abs() < 1e-6);
    }
    // Hand-worked cosine between sensors 1 and 2.
    let c12 = d.column(0).normalize().dot(&d.column(1).normalize()) * 1e6;
    assert!((f.non_orthogonality_urad[0] - c12).abs() < 1e-3);
    assert!((f.last_row[3] - 1.0).abs() < 1e-12 && f.last_row[0].abs() < 1e-12);
    assert!(f.residual_rms_um < 1e-9);
    assert!(calibrate_sensor_frame(&m[..3], &s[..3]).is_err());
}

#[test]
fn dataset_round_trip_and_unit_checks() {
    let s = CapballSetup::paper_default();
    let poses = s.trajectory(&TrajectorySpec {
        n_poses: 20,
        ..Default::default()
    });
    let recs: Vec<_> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| CapballRecord {
            run: 1,
            pose_index: i as u32 + 1,
            time_s: Some(i as f64),
            pose: *p,
            e_um: [1.0, 2.0, 3.0],
        })
        .collect();
    let text = write_dataset(&recs);
    let back = parse_dataset(&format!("# comment\n{text}")).unwrap();
    assert_eq!(back.len(), 20);
    assert!((back[7].pose.x_mm - poses[7].x_mm).abs() < 1e-5);
    let bad = text.replacen("ex_um", "ex_mm", 1);
    assert!(parse_dataset(&bad).unwrap_err().to_string().contains("µm"));
    let bad = text.replacen("1,2,", "1,x,", 1);
    assert!(parse_dataset(&bad).is_err());
    // A finite but absurd angle (10¹⁶⁰°) is refused where it is read: it used to reach the
    // identification and loop forever in the SVD.
    let mut rows: Vec<String> = text.lines().map(str::to_string).collect();
    let header: Vec<&str> = rows[0].split(',').collect();
    let c = header.iter().position(|h| *h == "c_deg").unwrap();
    let mut fields: Vec<String> = rows[1].split(',').map(str::to_string).collect();
    fields[c] = "1e160".into();
    rows[1] = fields.join(",");
    let e = parse_dataset(&rows.join("\n")).unwrap_err().to_string();
    assert!(
        e.contains("c_deg") && e.contains("outside the range"),
        "{e}"
    );
}

#[test]
fn forward_um_is_the_paper_default_model() {
    let t = truth();
    let s = CapballSetup::paper_default();
    let p = s.pose_for(-60.0, 30.0);
    let a = forward_um(&t.link, &t.setup, &p);
    let b = s.volumetric_error_um(&t, &p);
    assert_eq!(a, [b.x, b.y, b.z]);
    // Linear model and exact model agree to second order (errors of order 100 µrad · 200 mm).
    let lin = s.jacobian(&p) * nalgebra::SVector::<f64, 14>::from_column_slice(&t.to_vector());
    assert!((lin - b).norm() < 0.01, "{lin} vs {b}");
}

#[test]
fn jacobian_holds_for_a_tilted_a_axis_and_offset_pivots() {
    // A nutating table: A tilted 45° in the XZ plane, C offset from A; the screws must still
    // match the numerical derivative of the exact model.
    let toml = r#"
chain = "WCAYFXZT"
tool_offset_mm = [0.0, 0.0, 150.0]
[axes.A]
direction = [0.70710678, 0.0, 0.70710678]
pivot_mm = [10.0, -20.0, 30.0]
[axes.C]
direction = [0.0, 0.0, 1.0]
pivot_mm = [5.0, 15.0, -40.0]
"#;
    let cfg = geometry::kinematics::MachineConfig::from_toml(toml).unwrap();
    let s = CapballSetup::new(&cfg, Vector3::new(90.0, -60.0, 120.0)).unwrap();
    for &(a, c) in &[(0.0, 0.0), (-40.0, 100.0), (-120.0, 250.0)] {
        let p = s.pose_for(a, c);
        let d = (s.jacobian(&p) - s.jacobian_numeric(&p)).abs().max();
        assert!(d < 1e-6, "a={a} c={c}: {d}");
        let e0 = s.volumetric_error_um(&CapballErrors::default(), &p).norm();
        assert!(e0 < 1e-6, "error-free model reads {e0} µm");
    }
    let poses = s.trajectory(&TrajectorySpec::default());
    assert!(s.condition_number(&poses).is_finite());
}

#[test]
fn trajectory_csv_and_pose_value_join() {
    let s = CapballSetup::paper_default();
    let poses = s.trajectory(&TrajectorySpec {
        n_poses: 30,
        ..Default::default()
    });
    // The trajectory CSV's own round trip is tested in metrolog-log (`trajectory`).
    let back = poses.clone();
    let (p, m) = join_pose_values(&back, &[(3, [1.0, 2.0, 3.0]), (30, [0.0; 3])]).unwrap();
    assert_eq!(p[0], back[2]);
    assert_eq!(m[0], [1.0, 2.0, 3.0]);
    assert!(join_pose_values(&back, &[(31, [0.0; 3])]).is_err());
    assert!(join_pose_values(&back, &[(0, [0.0; 3])]).is_err());
}
