//! Cost of generating one sample of each device: the physics at the sample's instant plus the
//! wire encoding. The simulation must sustain LI-80 10 kHz + CB-3 20 kHz + PSD-2 1 kHz at once,
//! i.e. 31 000 samples/s: a budget of about 32 µs per sample on one core.

use std::hint::black_box;
use std::sync::Arc;

use criterion::{Criterion, criterion_group, criterion_main};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim::Scenario;
use sim::physics::{CachedCapballModel, CapballTruth, World};

fn world() -> World {
    let sc = Scenario::demo();
    let truth: Arc<dyn CapballTruth> = Arc::new(CachedCapballModel::new(sc.capball.truth.clone()));
    World::new(sc, truth, &mut ChaCha8Rng::seed_from_u64(1))
}

fn bench(c: &mut Criterion) {
    let w = world();
    let mid = |i: usize| {
        let p = w.schedule.poses[i];
        0.5 * (p.motion_start_s + p.dwell_end_s)
    };
    let mut out = Vec::with_capacity(64);
    c.bench_function("li80_sample", |b| {
        let mut k = 0u64;
        b.iter(|| {
            let s = mid((k % 36) as usize) + k as f64 * 1e-4;
            let ph = w.phase(Some(s));
            let t = s * w.scenario.time_scale;
            let (air_c, pa, rh, mat) = w.environment(t);
            let n = protocol::edlen::li80_refractive_index(air_c, pa, rh);
            let l20 = w.axis_length20_um(ph, t) + w.ringing_um(ph);
            let tm = mat.iter().sum::<f64>() / mat.len() as f64;
            let raw_nm = (n * l20 / (1.0 - 11.7e-6 * (tm - 20.0)) * 1e3).round() as i64;
            let f = protocol::li80::PosFrame {
                seq: k as u32,
                t_us: k * 100,
                raw_nm,
                sig: 86,
                flags: protocol::li80::PosFlags(0),
            };
            out.clear();
            protocol::li80::encode_pos(&f, &mut out);
            k += 1;
            black_box(&out);
        })
    });
    c.bench_function("cb3_sample", |b| {
        let mut k = 0u64;
        b.iter(|| {
            let s = mid(36 + (k % 20) as usize) + k as f64 * 5e-5;
            let ph = w.phase(Some(s));
            let e = w.capball_error_um(ph, s * w.scenario.time_scale);
            let d = w.capball_sensor_um(e);
            let mut ch = [0i32; 3];
            for i in 0..3 {
                let v = sim::physics::volts_for_um(&w.scenario.capball.poly[i], d[i]);
                ch[i] = (v * 838_860.8).round() as i32;
            }
            let f = protocol::cb3::Frame::Sample(protocol::cb3::SampleFrame {
                seq: k as u16,
                t_us: k as u32,
                ch,
                flags: 0,
            });
            out.clear();
            protocol::cb3::encode(&f, &mut out);
            k += 1;
            black_box(&out);
        })
    });
    c.bench_function("psd_sample", |b| {
        let mut k = 0u64;
        b.iter(|| {
            let s = mid(56 + (k % 9) as usize) + k as f64 * 1e-3;
            let ph = w.phase(Some(s));
            let (x, y) = w.psd_spot_um(&w.coords(ph));
            let split = |p: f64| {
                let r = p / 5000.0;
                (
                    (6e5 * (1.0 - r)).round() as u64,
                    (6e5 * (1.0 + r)).round() as u64,
                )
            };
            let (x1, x2) = split(x);
            let (y1, y2) = split(y);
            let d = protocol::psd::DataLine {
                seq: k as u32,
                t_us: k * 1000,
                x1_pa: x1,
                x2_pa: x2,
                y1_pa: y1,
                y2_pa: y2,
                head_mc: 21_500,
            };
            out.clear();
            protocol::psd::encode_data(&d, &mut out);
            k += 1;
            black_box(&out);
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
