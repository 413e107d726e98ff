//! Writes the example inputs under `examples/models/` from the models themselves (run with
//! `cargo test -p metrolog-geometry --test models_examples -- --ignored`), and checks that the
//! committed examples still parse.

// Parallel arrays indexed together read more plainly with an index.
#![allow(clippy::needless_range_loop)]

use std::path::PathBuf;

use geometry::capball::*;
use geometry::psd_frame::*;
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/models")
}

#[test]
#[ignore = "writes example files"]
fn generate_examples() {
    let d = dir();
    std::fs::create_dir_all(&d).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let noise = Normal::new(0.0, 0.4).unwrap();
    // CapBall: identification (A one way) and validation (A reversed) runs.
    let s = CapballSetup::paper_default();
    let truth = CapballErrors {
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
    };
    for (name, spec) in [
        ("capball_identification.csv", TrajectorySpec::default()),
        (
            "capball_validation.csv",
            TrajectorySpec::default().reversed_a(),
        ),
    ] {
        let poses = s.trajectory(&spec);
        let recs: Vec<_> = poses
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let e = s.volumetric_error_um(&truth, p);
                CapballRecord {
                    run: 1,
                    pose_index: i as u32 + 1,
                    time_s: Some(i as f64 * 0.75),
                    pose: *p,
                    e_um: [
                        e.x + noise.sample(&mut rng),
                        e.y + noise.sample(&mut rng),
                        e.z + noise.sample(&mut rng),
                    ],
                }
            })
            .collect();
        std::fs::write(d.join(name), write_dataset(&recs)).unwrap();
    }
    std::fs::write(
        d.join("capball_truth.json"),
        serde_json::to_string_pretty(&truth).unwrap(),
    )
    .unwrap();
    // Sensor-frame cube.
    let dm = nalgebra::Matrix3::from_columns(&[
        Vector3::new(1.0, 0.002, -0.001) * 1.006,
        Vector3::new(-0.001, 1.0, 0.003) * 0.995,
        Vector3::new(0.0005, 0.0, 1.0) * 1.003,
    ]);
    let o = Vector3::new(12.0, -7.0, 3.0);
    let mut cube = String::from("mx_um,my_um,mz_um,s1_um,s2_um,s3_um\n");
    for m in cube_points_um(250.0, 5) {
        let r = sensor_readings_um(&dm, &o, &m);
        let n = Normal::new(0.0, 0.1).unwrap();
        cube.push_str(&format!(
            "{},{},{},{:.4},{:.4},{:.4}\n",
            m.x,
            m.y,
            m.z,
            r.x + n.sample(&mut rng),
            r.y + n.sample(&mut rng),
            r.z + n.sample(&mut rng)
        ));
    }
    std::fs::write(d.join("capball_cube.csv"), cube).unwrap();
    // PSD: reference run 0 and a warmed-up run 1 (a 10 µm/m scale change and tilted Z).
    let l = PsdLayout::paper();
    let zero = PsdErrors::default();
    let mut warm = derive_errors(&l, &simulate_readings(&l, &zero_like(&l))).unwrap();
    warm.exx_um = l.xs().iter().map(|x| 0.5 + 0.01 * x).collect();
    warm.eyy_um = l.ys().iter().map(|y| -0.3 + 0.008 * y).collect();
    warm.eb0z_urad = 6.0;
    warm.ea0z_urad = -4.0;
    warm.ezx_um = l
        .xs()
        .iter()
        .map(|x| 0.6 * (1.0 - ((x - 92.0) / 92.0).powi(2)) - 0.36)
        .collect();
    let _ = zero;
    let n = Normal::new(0.0, 0.15).unwrap();
    let mut noisy = |r: PsdReadings| {
        PsdReadings::from_vec(
            &l,
            &r.to_vec()
                .iter()
                .map(|v| v + n.sample(&mut rng))
                .collect::<Vec<_>>(),
        )
    };
    let r0 = noisy(simulate_readings(&l, &zero_like(&l)));
    let r1 = noisy(simulate_readings(&l, &warm));
    std::fs::write(
        d.join("psd_readings.csv"),
        write_readings_csv(&[(0, r0), (1, r1)]),
    )
    .unwrap();
}

fn zero_like(l: &PsdLayout) -> PsdErrors {
    PsdErrors {
        x_mm: l.xs(),
        y_mm: l.ys(),
        y_s1_mm: l.ys1(),
        z_mm: l.zs(),
        exx_um: vec![0.0; 11],
        eyy_um: vec![0.0; 11],
        eyx_um: vec![0.0; 11],
        ezx_um: vec![0.0; 11],
        exy_um: vec![0.0; 11],
        ezy_um: vec![0.0; 11],
        exz_um: vec![0.0; 11],
        eyz_um: vec![0.0; 11],
        eax_urad: vec![0.0; 11],
        eby_urad: vec![0.0; 7],
        ..Default::default()
    }
}

#[test]
fn committed_examples_parse() {
    let d = dir();
    let Ok(text) = std::fs::read_to_string(d.join("capball_identification.csv")) else {
        return;
    };
    let recs = parse_dataset(&text).unwrap();
    assert_eq!(recs.len(), 807);
    let psd = std::fs::read_to_string(d.join("psd_readings.csv")).unwrap();
    assert_eq!(
        parse_readings_csv(&PsdLayout::paper(), &psd).unwrap().len(),
        2
    );
}
