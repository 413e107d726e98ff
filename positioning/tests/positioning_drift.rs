//! Thermal-drift elimination (Stejskal et al. 2017) against independent expectations.
#![allow(clippy::needless_range_loop)]

use positioning::axis_model::{AxisModel, Direction, Effect};
use positioning::drift::{coverage_factor, eliminate};
use positioning::positioning_data::{PositioningData, Reading, simulate, standard_schedule};

fn axis(m: usize, noise_um: f64, effects: Vec<Effect>) -> AxisModel {
    AxisModel {
        axis: "X".into(),
        targets_mm: (0..m).map(|i| 20.0 * i as f64).collect(),
        systematic_up_um: (0..m).map(|i| (i as f64).sin() * 2.0).collect(),
        systematic_down_um: (0..m).map(|i| (i as f64).sin() * 2.0 - 1.5).collect(),
        noise_um,
        effects,
    }
}

#[test]
fn student_t_widening_below_30_cycles() {
    // Closed form of the Student t quantile for 2 degrees of freedom: t = (2p−1)/√(2p(1−p)),
    // at p = Φ(2) = 0.977249868.
    let p: f64 = 0.977_249_868_051_820_8;
    let t2 = (2.0 * p - 1.0) / (2.0 * p * (1.0 - p)).sqrt();
    assert!(
        (coverage_factor(3) - t2).abs() < 1e-6,
        "{}",
        coverage_factor(3)
    );
    // 1 degree of freedom (Cauchy): t = tan(π(p − 1/2)).
    let t1 = (std::f64::consts::PI * (p - 0.5)).tan();
    assert!((coverage_factor(2) - t1).abs() < 1e-6);
    assert_eq!(coverage_factor(30), 2.0);
    assert!(coverage_factor(29) > 2.0 && coverage_factor(29) < coverage_factor(10));
}

#[test]
fn cycle_offsets_vanish_from_the_rebuilt_chart() {
    // Noise-free run whose every cycle is shifted by its own offset (a drift constant within a
    // cycle): the adjacent differences are the systematic differences exactly, their scatter is
    // zero, and the chart rebuilt from cycle 3 is the systematic curve plus cycle 3's offset.
    let m = axis(6, 0.0, vec![]);
    let offsets = [0.0, 1.5, 3.2, 4.0, 4.4];
    let mut readings = Vec::new();
    for (c, off) in offsets.iter().enumerate() {
        for (dir, sys) in [
            (Direction::Up, &m.systematic_up_um),
            (Direction::Down, &m.systematic_down_um),
        ] {
            for i in 0..6 {
                readings.push(Reading {
                    cycle: c + 1,
                    direction: dir,
                    index: i + 1,
                    target_mm: m.targets_mm[i],
                    deviation_um: sys[i] + off,
                    time_s: (c * 12 + i) as f64,
                    air_c: None,
                    material_c: None,
                });
            }
        }
    }
    let d = PositioningData {
        readings,
        has_times: true,
        material_compensation: true,
        ..Default::default()
    };
    let r = eliminate(&d, 3);
    for dd in &r.directions {
        let sys = if dd.direction == Direction::Up {
            &m.systematic_up_um
        } else {
            &m.systematic_down_um
        };
        for (p, s) in dd.chart.iter().zip(sys) {
            assert!((p.deviation_um.unwrap() - (s + 3.2)).abs() < 1e-9);
        }
        for p in &dd.pairs {
            assert!(p.s_diff_um.unwrap() < 1e-9);
            assert!((p.mean_diff_um.unwrap() - (sys[p.index - 1] - sys[p.index])).abs() < 1e-9);
        }
    }
}

#[test]
fn without_drift_a_difference_scatters_sqrt2_times_more() {
    // Eq. 7–10: s_b / s_a = √2 (their Monte Carlo: 1.4076).
    let m = axis(16, 0.5, vec![]);
    let d = simulate(&m, &standard_schedule(16, 100, 6.0), 11);
    let r = eliminate(&d, 50);
    for dd in &r.directions {
        let mean_s: f64 = dd.pairs.iter().map(|p| p.s_diff_um.unwrap()).sum::<f64>() / 15.0;
        assert!(
            (mean_s / 0.5 - 2f64.sqrt()).abs() < 0.05,
            "{}",
            mean_s / 0.5
        );
        let ratio = dd.mean_ratio.unwrap();
        assert!((ratio - 0.5f64.sqrt()).abs() < 0.04, "{ratio}");
    }
    assert!(r.anomalous_targets.is_empty());
    assert_eq!(r.k, 2.0);
}

#[test]
fn drift_inflates_the_classic_scatter_only() {
    // 7 h run with a 12 µm warm-up: the classic s grows, the drift-free scatter stays √2·σ.
    let m = axis(
        16,
        0.4,
        vec![Effect::ExponentialWarmup {
            amplitude_um: 12.0,
            tau_s: 7200.0,
        }],
    );
    let d = simulate(&m, &standard_schedule(16, 100, 7.0 * 3600.0 / 3200.0), 5);
    let r = eliminate(&d, 50);
    for dd in &r.directions {
        let mean_s: f64 = dd.pairs.iter().map(|p| p.s_diff_um.unwrap()).sum::<f64>() / 15.0;
        assert!(mean_s / 0.4 < 1.6, "{}", mean_s / 0.4);
        assert!(dd.mean_ratio.unwrap() > 3.0);
    }
}

#[test]
fn a_target_that_scatters_more_is_flagged() {
    for seed in 0..10 {
        let m = axis(
            16,
            0.3,
            vec![Effect::LocalAnomaly {
                index: 3,
                std_ratio: 4.0,
            }],
        );
        let d = simulate(&m, &standard_schedule(16, 30, 6.0), seed);
        assert_eq!(eliminate(&d, 10).anomalous_targets, vec![3], "seed {seed}");
        let m = axis(
            16,
            0.3,
            vec![Effect::LocalAnomaly {
                index: 16,
                std_ratio: 4.0,
            }],
        );
        let d = simulate(&m, &standard_schedule(16, 30, 6.0), seed);
        assert_eq!(eliminate(&d, 10).anomalous_targets, vec![16], "seed {seed}");
    }
    let mut false_alarms = 0;
    for seed in 0..40 {
        let m = axis(16, 0.3, vec![Effect::LinearDrift { rate_um_per_h: 5.0 }]);
        let d = simulate(&m, &standard_schedule(16, 20, 6.0), 100 + seed);
        false_alarms += !eliminate(&d, 10).anomalous_targets.is_empty() as usize;
    }
    assert!(false_alarms <= 2, "{false_alarms} false alarms in 40 runs");
}

#[test]
fn missing_reference_reading_is_substituted_and_said() {
    let m = axis(6, 0.3, vec![]);
    let mut d = simulate(&m, &standard_schedule(6, 8, 6.0), 1);
    d.readings
        .retain(|r| !(r.cycle == 4 && r.index == 1 && r.direction == Direction::Up));
    let r = eliminate(&d, 4);
    let up = &r.directions[0];
    assert_ne!(up.reference_cycle, Some(4));
    assert!(r.notes.iter().any(|n| n.contains("cycle 4")));
    assert!(up.chart.iter().all(|p| p.deviation_um.is_some()));
}
