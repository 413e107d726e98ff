//! Speed targets of the model code: identification of 14 parameters from 807 poses (< 5 ms)
//! and a 50×50×50 volumetric grid (< 100 ms).

// Parallel arrays indexed together read more plainly with an index.
#![allow(clippy::needless_range_loop)]

use criterion::{Criterion, criterion_group, criterion_main};
use geometry::capball::{CapballErrors, CapballSetup, LinkErrors, TrajectorySpec};
use geometry::kinematics::{Machine, MachineConfig};
use geometry::psd_frame::{PsdErrors, PsdLayout, derive_errors, simulate_readings};
use geometry::volumetric::{ComponentErrors, GridSpec, volumetric_grid};

fn capball(c: &mut Criterion) {
    let s = CapballSetup::paper_default();
    let poses = s.trajectory(&TrajectorySpec::default());
    let truth = CapballErrors {
        link: LinkErrors {
            ec0y_urad: 25.0,
            eb0a_urad: 60.0,
            ey0c_um: 12.0,
            ..Default::default()
        },
        ..Default::default()
    };
    let meas: Vec<[f64; 3]> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let e = s.volumetric_error_um(&truth, p);
            let n = ((i * 7919) % 13) as f64 * 0.05 - 0.3;
            [e.x + n, e.y - n, e.z + 0.5 * n]
        })
        .collect();
    c.bench_function("capball identify 14 params / 807 poses", |b| {
        b.iter(|| {
            s.identify(std::hint::black_box(&poses), std::hint::black_box(&meas))
                .unwrap()
        })
    });
}

fn volumetric(c: &mut Criterion) {
    let mut csv = String::from("error,position_mm,value\nEC0Y,,20\nEB0Z,,-10\nEA0Z,,5\n");
    for name in [
        "EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXY", "EYY", "EZY", "EAY", "EBY", "ECY", "EXZ",
        "EYZ", "EZZ", "EAZ", "EBZ", "ECZ",
    ] {
        for i in 0..=20 {
            let q = i as f64 * 25.0;
            csv.push_str(&format!("{name},{q},{}\n", (q / 90.0).sin() * 3.0));
        }
    }
    let e = ComponentErrors::from_csv(&csv).unwrap();
    let cfg = MachineConfig {
        chain: "WYFXZT".into(),
        tool_offset_mm: [0.0, 0.0, -100.0],
        axes: Default::default(),
    };
    let m = Machine::from_config(&cfg).unwrap();
    let g = GridSpec::parse("0:500:50,0:500:50,0:500:50").unwrap();
    c.bench_function("volumetric grid 50x50x50", |b| {
        b.iter(|| volumetric_grid(&m, &e, std::hint::black_box(&g)).unwrap())
    });
}

fn psd(c: &mut Criterion) {
    let l = PsdLayout::paper();
    let zero = derive_errors(
        &l,
        &simulate_readings(
            &l,
            &PsdErrors {
                eby_urad: vec![0.0; 7],
                ..Default::default()
            },
        ),
    )
    .unwrap();
    let r = simulate_readings(&l, &zero);
    c.bench_function("psd derive 13 errors", |b| {
        b.iter(|| derive_errors(&l, std::hint::black_box(&r)).unwrap())
    });
}

criterion_group!(benches, capball, volumetric, psd);
criterion_main!(benches);
