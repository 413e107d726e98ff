//! Speed target: analyze and diagnose a 100-cycle × 21-target run in under 1 s.

use criterion::{Criterion, criterion_group, criterion_main};
use diagnose::axis::{Options, diagnose};
use positioning::axis_model::{AxisModel, Effect};
use positioning::positioning_data::{PositioningData, simulate, standard_schedule};
use positioning::{drift, iso230};

fn run() -> PositioningData {
    let m = AxisModel {
        axis: "X".into(),
        targets_mm: (0..21).map(|i| 50.0 * i as f64 + (i % 5) as f64).collect(),
        systematic_up_um: (0..21).map(|i| (i as f64 * 0.6).sin() * 3.0).collect(),
        systematic_down_um: (0..21)
            .map(|i| (i as f64 * 0.6).sin() * 3.0 - 2.0)
            .collect(),
        noise_um: 0.4,
        effects: vec![
            Effect::ExponentialWarmup {
                amplitude_um: 4.0,
                tau_s: 5400.0,
            },
            Effect::CyclicDrift {
                period_s: 1500.0,
                amplitude_um: 1.5,
                phase_rad: 0.0,
            },
            Effect::LocalAnomaly {
                index: 7,
                std_ratio: 4.0,
            },
            Effect::Outliers {
                rate: 0.001,
                magnitude_um: 6.0,
            },
        ],
    };
    // 100 cycles × 21 targets × 2 directions, 6 s per reading: 7 h, as in the paper.
    simulate(&m, &standard_schedule(21, 100, 6.0), 1)
}

fn bench(c: &mut Criterion) {
    let data = run();
    let csv = data.to_csv_string();
    let mut g = c.benchmark_group("positioning_100x21");
    g.sample_size(20);
    g.bench_function("parse_csv", |b| {
        b.iter(|| PositioningData::from_csv_str(&csv).unwrap())
    });
    g.bench_function("analyze", |b| {
        b.iter(|| {
            let r = iso230::evaluate(&data);
            let d = drift::eliminate(&data, drift::default_reference_cycle(&data));
            (r, d)
        })
    });
    g.bench_function("diagnose", |b| {
        b.iter(|| diagnose(&data, &Options::default()).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
