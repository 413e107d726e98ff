//! Decoder throughput on realistic streams: 10 000 frames per instrument with 1 % of the bytes
//! being inserted garbage (corrupting the frames they land in), fed in 4 KiB chunks as a port
//! read would deliver them. Throughput is reported in frames (elements) per second.
//! Target: ≥ 5 million frames/s on one core.
//!
//! Two groups: `decode` measures wall time, `decode_cpu` the CPU time of the benchmark thread
//! (`CLOCK_THREAD_CPUTIME_ID`), which stays meaningful when other processes load the machine.

use criterion::measurement::{Measurement, ValueFormatter, WallTime};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use protocol::{Decoded, StreamDecoder, cb3, li80, psd, slcan};
use std::hint::black_box;

const FRAMES: usize = 10_000;
const CHUNK: usize = 4096;

/// xorshift64*: a deterministic stream without a dev-dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

/// Inserts a random byte before 1 % of the bytes.
fn with_garbage(clean: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut out = Vec::with_capacity(clean.len() * 102 / 100);
    for &b in clean {
        if rng.next() % 100 < 1 {
            out.push(rng.next() as u8);
        }
        out.push(b);
    }
    out
}

fn li80_stream(rng: &mut Rng) -> Vec<u8> {
    let mut s = Vec::new();
    for i in 0..FRAMES {
        if i % 1000 == 999 {
            li80::encode_env(
                &li80::EnvFrame {
                    seq: i as u32,
                    t_us: i as u64 * 100,
                    air_c: 20.125,
                    air_pa: 101_325.4,
                    rh_pct: 45.2,
                    material_c: vec![20.01, 20.03],
                },
                &mut s,
            );
        } else {
            let f = li80::PosFrame {
                seq: 1_000_000 + i as u32,
                t_us: 12_345_678_901 + i as u64 * 100,
                raw_nm: (rng.next() % 2_000_000_000) as i64 - 1_000_000_000,
                sig: 87,
                flags: li80::PosFlags(0),
            };
            li80::encode_pos(&f, &mut s);
        }
    }
    s
}

fn cb3_stream(rng: &mut Rng) -> Vec<u8> {
    let mut s = Vec::new();
    for i in 0..FRAMES {
        let f = cb3::SampleFrame {
            seq: i as u16,
            t_us: i as u32 * 50,
            ch: [rng_code(rng), rng_code(rng), rng_code(rng)],
            flags: 0,
        };
        cb3::encode(&cb3::Frame::Sample(f), &mut s);
    }
    s
}

fn rng_code(rng: &mut Rng) -> i32 {
    (rng.next() % (1 << 24)) as i32 - (1 << 23)
}

fn psd_stream(rng: &mut Rng) -> Vec<u8> {
    let mut s = Vec::new();
    for i in 0..FRAMES {
        let d = psd::DataLine {
            seq: i as u32,
            t_us: 987_654_321 + i as u64 * 1000,
            x1_pa: 1_000_000 + rng.next() % 100_000,
            x2_pa: 1_000_000 + rng.next() % 100_000,
            y1_pa: 1_000_000 + rng.next() % 100_000,
            y2_pa: 1_000_000 + rng.next() % 100_000,
            head_mc: 21_345,
        };
        psd::encode_data(&d, &mut s);
    }
    s
}

fn slcan_stream(rng: &mut Rng) -> Vec<u8> {
    let mut s = Vec::new();
    for i in 0..FRAMES {
        let t = protocol::can::TriggerFrame {
            event: protocol::can::TriggerEvent::ExactStop,
            pose: i as u16,
            nc_ms: rng.next() as u32,
        };
        let f = slcan::CanFrame {
            id: protocol::can::DEFAULT_CAN_ID,
            extended: false,
            data: t.encode().to_vec(),
            timestamp_ms: Some((i % 60_000) as u16),
        };
        slcan::encode_frame(&f, &mut s);
    }
    s
}

fn run<D: StreamDecoder>(mut d: D, stream: &[u8]) -> (usize, usize) {
    let (mut frames, mut rejects) = (0usize, 0usize);
    for chunk in stream.chunks(CHUNK) {
        d.feed(chunk, |x| match x {
            Decoded::Frame(f) => {
                black_box(&f);
                frames += 1;
            }
            Decoded::Reject(_) => rejects += 1,
        });
    }
    (frames, rejects)
}

/// CPU time consumed by the calling thread, in nanoseconds.
struct ThreadCpuTime;

fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant Linux supports.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID) failed");
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

impl Measurement for ThreadCpuTime {
    type Intermediate = u64;
    type Value = u64;
    fn start(&self) -> u64 {
        thread_cpu_ns()
    }
    fn end(&self, start: u64) -> u64 {
        thread_cpu_ns() - start
    }
    fn add(&self, a: &u64, b: &u64) -> u64 {
        a + b
    }
    fn zero(&self) -> u64 {
        0
    }
    fn to_f64(&self, v: &u64) -> f64 {
        *v as f64
    }
    fn formatter(&self) -> &dyn ValueFormatter {
        // Values are nanoseconds, as for wall time: reuse its formatter.
        static WALL: WallTime = WallTime;
        WALL.formatter()
    }
}

fn streams() -> [(&'static str, Vec<u8>); 4] {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    [
        ("li80", with_garbage(&li80_stream(&mut rng), &mut rng)),
        ("cb3", with_garbage(&cb3_stream(&mut rng), &mut rng)),
        ("psd", with_garbage(&psd_stream(&mut rng), &mut rng)),
        ("slcan", with_garbage(&slcan_stream(&mut rng), &mut rng)),
    ]
}

fn decode_named(name: &str, stream: &[u8]) -> (usize, usize) {
    match name {
        "li80" => run(li80::Decoder::new(), stream),
        "cb3" => run(cb3::Decoder::new(), stream),
        "psd" => run(psd::Decoder::new(), stream),
        _ => run(slcan::Decoder::new(), stream),
    }
}

fn bench_cpu(c: &mut Criterion<ThreadCpuTime>) {
    let mut g = c.benchmark_group("decode_cpu");
    g.throughput(Throughput::Elements(FRAMES as u64));
    for (name, stream) in &streams() {
        g.bench_function(*name, |b| b.iter(|| decode_named(name, black_box(stream))));
    }
    g.finish();
}

fn bench(c: &mut Criterion) {
    let streams = streams();
    let mut g = c.benchmark_group("decode");
    g.throughput(Throughput::Elements(FRAMES as u64));
    for (name, stream) in &streams {
        let counts = decode_named(name, stream);
        eprintln!(
            "{name}: {} bytes, {} frames decoded, {} rejections (of {FRAMES} sent)",
            stream.len(),
            counts.0,
            counts.1
        );
        g.bench_function(*name, |b| b.iter(|| decode_named(name, black_box(stream))));
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_group! {
    name = benches_cpu;
    config = Criterion::default().with_measurement(ThreadCpuTime);
    targets = bench_cpu
}
criterion_main!(benches, benches_cpu);
