//! The CapBall model `metrolog diagnose --write-model` writes (`CapballModel::from_diagnosis`)
//! reproduces what was measured: runs simulated with a cooling cycle and pose scatter are
//! diagnosed, the extended model is simulated over the same poses and times, and the two
//! datasets' baseline residuals (what the 14-parameter model leaves) are compared.

use diagnose::capball::{CapballRun, Options, diagnose};
use geometry::capball::{CapballSetup, TrajectorySpec};
use geometry::capball_effects::CyclicDrift;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use sim::CapballTruth;
use sim::scenario::CapballModel;

fn simulate(m: &CapballModel, spec: &TrajectorySpec, t0: f64, seed: u64) -> CapballRun {
    let setup = CapballSetup::paper_default();
    let poses = setup.trajectory(spec);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, m.pose_noise_um).expect("noise");
    let time_s: Vec<f64> = (0..poses.len()).map(|i| t0 + 0.75 * i as f64).collect();
    let e_um = poses
        .iter()
        .zip(&time_s)
        .map(|(p, &t)| {
            let c = sim::Coords {
                x_mm: p.x_mm,
                y_mm: p.y_mm,
                z_mm: p.z_mm,
                a_deg: p.a_deg,
                c_deg: p.c_deg,
            };
            m.error_um(&c, t).map(|v| v + noise.sample(&mut rng))
        })
        .collect();
    CapballRun::new(poses, time_s, e_um)
}

/// RMS per channel of what the 14 parameters identified on `id` leave on `id` and on `val`.
fn baseline_rms(id: &CapballRun, val: &CapballRun) -> ([f64; 3], [f64; 3]) {
    let setup = CapballSetup::paper_default();
    let ident = setup.identify(&id.poses, &id.e_um).expect("identify");
    let v = setup
        .validation_rms_um(&ident, &val.poses, &val.e_um)
        .expect("validation");
    (ident.residual_rms_um, v)
}

#[test]
fn extended_model_reproduces_the_residual_pattern() {
    let truth = CapballModel {
        cyclic_drift: Some(CyclicDrift {
            period_s: 1500.0,
            amplitude_um: [1.0, 1.0, 3.0],
            phase_rad: [0.3, 2.0, 4.0],
        }),
        pose_noise_um: 0.2,
        ..CapballModel::default()
    };
    let spec = TrajectorySpec {
        n_poses: 400,
        ..TrajectorySpec::default()
    };
    let id = simulate(&truth, &spec, 0.0, 1);
    let val = simulate(&truth, &spec.reversed_a(), 360.0, 2);
    let setup = CapballSetup::paper_default();
    let d = diagnose(
        &setup,
        &id,
        std::slice::from_ref(&val),
        None,
        &Options::default(),
    )
    .expect("diagnosis");
    let found = d.report.effects();
    assert_eq!(found, ["cyclic_drift"], "{:?}", d.report.findings);
    let model = CapballModel::from_diagnosis(&d);
    let c = model.cyclic_drift.as_ref().expect("cyclic drift written");
    assert!((c.period_s - 1500.0).abs() < 150.0, "{c:?}");
    // The written section is valid scenario TOML.
    let text = toml::to_string(&model).expect("toml");
    let back: CapballModel = toml::from_str(&text).expect("reads back");
    assert_eq!(back, model);
    // Re-simulated with the extended model (other noise): the baseline leaves the same
    // pattern — identification and validation residuals within 25 % per channel.
    let id2 = simulate(&model, &spec, 0.0, 3);
    let val2 = simulate(&model, &spec.reversed_a(), 360.0, 4);
    let (mi, mv) = baseline_rms(&id, &val);
    let (si, sv) = baseline_rms(&id2, &val2);
    println!("measured: identification {mi:.3?} validation {mv:.3?} µm");
    println!("extended model simulated: identification {si:.3?} validation {sv:.3?} µm");
    for k in 0..3 {
        assert!(
            (si[k] / mi[k] - 1.0).abs() < 0.25,
            "identification {k}: {si:?} vs {mi:?}"
        );
        assert!(
            (sv[k] / mv[k] - 1.0).abs() < 0.25,
            "validation {k}: {sv:?} vs {mv:?}"
        );
    }
    // The baseline model (14 parameters + white noise) does not: its validation residual is
    // the identification's.
    let plain = CapballModel {
        pose_noise_um: model.pose_noise_um,
        ..CapballModel::from_errors(&d.baseline.errors)
    };
    let id3 = simulate(&plain, &spec, 0.0, 5);
    let val3 = simulate(&plain, &spec.reversed_a(), 360.0, 6);
    let (_, bv) = baseline_rms(&id3, &val3);
    println!("baseline model simulated: validation {bv:.3?} µm");
    assert!(bv[2] < 0.5 * mv[2]);
}
