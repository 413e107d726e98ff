//! Replays the cargo-fuzz seed corpus (`protocol/fuzz/corpus/<target>/`) and any findings kept
//! there through the fuzz checks, so CI re-runs them without nightly. Files named `valid_*`
//! must decode without a single rejection.
//!
//! The seed files are written by the encoders: `cargo test -p metrolog-protocol --test corpus
//! -- --ignored write_seed_corpus` regenerates them.

use protocol::{Decoded, StreamDecoder, cb3, fuzzcheck, li80, psd, slcan};
use std::path::PathBuf;

const TARGETS: [&str; 5] = ["li80", "cb3", "psd", "slcan", "can"];

fn corpus_dir(target: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/corpus")
        .join(target)
}

fn rejections<D: StreamDecoder + Default>(data: &[u8]) -> (usize, usize) {
    let (mut frames, mut rejects) = (0, 0);
    D::default().feed(data, |d| match d {
        Decoded::Frame(_) => frames += 1,
        Decoded::Reject(_) => rejects += 1,
    });
    (frames, rejects)
}

#[test]
fn replay_corpus() {
    for target in TARGETS {
        let dir = corpus_dir(target);
        let mut n = 0;
        for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.unwrap().path();
            let data = std::fs::read(&path).unwrap();
            match target {
                "li80" => fuzzcheck::li80(&data),
                "cb3" => fuzzcheck::cb3(&data),
                "psd" => fuzzcheck::psd(&data),
                "can" => fuzzcheck::can(&data),
                _ => fuzzcheck::slcan(&data),
            }
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if name.starts_with("valid_") && target != "can" {
                let (frames, rejects) = match target {
                    "li80" => rejections::<li80::Decoder>(&data),
                    "cb3" => rejections::<cb3::Decoder>(&data),
                    "psd" => rejections::<psd::Decoder>(&data),
                    _ => rejections::<slcan::Decoder>(&data),
                };
                assert!(
                    frames > 0 && rejects == 0,
                    "{target}/{name}: {frames} frames, {rejects} rejections"
                );
            }
            n += 1;
        }
        assert!(n >= 4, "{target}: only {n} corpus files");
    }
}

fn seeds() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    let mut out = Vec::new();

    // LI-80
    let pos = |seq, raw_nm, sig, flags| {
        let mut v = Vec::new();
        li80::encode_pos(
            &li80::PosFrame {
                seq,
                t_us: 1_000_000 + u64::from(seq) * 100,
                raw_nm,
                sig,
                flags: li80::PosFlags(flags),
            },
            &mut v,
        );
        v
    };
    let mut env = Vec::new();
    li80::encode_env(
        &li80::EnvFrame {
            seq: 3,
            t_us: 3_000_000,
            air_c: 20.125,
            air_pa: 101_325.4,
            rh_pct: 45.2,
            material_c: vec![20.01, 20.03, 19.98],
        },
        &mut env,
    );
    let mut err = Vec::new();
    li80::encode_err(
        &li80::ErrFrame {
            code: 3,
            text: "beam lost".into(),
        },
        &mut err,
    );
    out.push(("li80", "valid_pos", pos(1, 123_456, 87, 0)));
    out.push(("li80", "valid_env", env.clone()));
    out.push(("li80", "valid_err", err.clone()));
    out.push((
        "li80",
        "valid_answers",
        b"OK\r\nERR 2 rate out of range\r\nLI-80,SN1234,2.1.0\r\n".to_vec(),
    ));
    let mut stream = Vec::new();
    for i in 0..5 {
        stream.extend(pos(i, -1_000 * i64::from(i), 20 + 15 * i as u8, i));
    }
    stream.extend(&env);
    out.push(("li80", "valid_stream", stream.clone()));
    out.push(("li80", "mid_frame_start", stream[17..].to_vec()));
    let mut bad = pos(9, 5, 90, 0);
    let n = bad.len();
    bad[n - 3] = if bad[n - 3] == b'0' { b'1' } else { b'0' };
    bad.extend(b"\x00\xffnoise$POS,1\r\n$XYZ,1*5A\r\n");
    bad.extend(vec![b'A'; 200]);
    bad.extend(b"\n");
    bad.extend(pos(10, 6, 90, 2));
    out.push(("li80", "faults", bad));

    // CB-3
    let sample = |seq: u16, ch: [i32; 3], flags| {
        let mut v = Vec::new();
        cb3::encode(
            &cb3::Frame::Sample(cb3::SampleFrame {
                seq,
                t_us: u32::from(seq) * 50,
                ch,
                flags,
            }),
            &mut v,
        );
        v
    };
    let text = |t: &str| {
        let mut v = Vec::new();
        cb3::encode(&cb3::Frame::Text(t.into()), &mut v);
        v
    };
    out.push(("cb3", "valid_sample", sample(1, [1000, -1000, 0], 0)));
    out.push((
        "cb3",
        "valid_text",
        [
            text("OK"),
            text("CB-3,77,1.2"),
            text("ERR rate out of range"),
        ]
        .concat(),
    ));
    let mut stream = Vec::new();
    for i in 0..6u16 {
        stream.extend(sample(
            i,
            [8_388_607, -8_388_608, i32::from(i) * 256],
            (i % 8) as u8,
        ));
    }
    out.push(("cb3", "valid_stream", stream.clone()));
    out.push(("cb3", "mid_frame_start", stream[5..].to_vec()));
    let mut bad = sample(7, [1, 2, 3], 0);
    bad[4] ^= 0x40;
    bad.extend([0, 0, 9, 1, 2, 0]);
    bad.extend(vec![1u8; 300]);
    bad.push(0);
    bad.extend(sample(8, [1, 2, 3], 0));
    out.push(("cb3", "faults", bad));

    // PSD-2
    let data = |seq: u32, c: [u64; 4], head_mc| {
        let mut v = Vec::new();
        psd::encode_data(
            &psd::DataLine {
                seq,
                t_us: 500_000 + u64::from(seq) * 1000,
                x1_pa: c[0],
                x2_pa: c[1],
                y1_pa: c[2],
                y2_pa: c[3],
                head_mc,
            },
            &mut v,
        );
        v
    };
    out.push((
        "psd",
        "valid_data",
        data(1, [1_000_000, 1_200_000, 900_000, 950_000], 21_345),
    ));
    out.push((
        "psd",
        "valid_answers",
        b"1\n0,\"No error\"\n-222,\"Data out of range\"\nPSD-2,4711,0.9\n".to_vec(),
    ));
    let mut stream = Vec::new();
    for i in 0..6 {
        stream.extend(data(
            i,
            [u64::from(i) * 1000, 5000, 2500, 2500],
            -1250 + i as i32,
        ));
    }
    out.push(("psd", "valid_stream", stream.clone()));
    out.push(("psd", "mid_frame_start", stream[9..].to_vec()));
    out.push((
        "psd",
        "faults",
        b"D,1,2,3\nD,1,2,-3,4,5,6,7\nD,1,2,3,4,5,6,99999999999\n,5,6,7\n\xff\xfe\n".to_vec(),
    ));

    // SLCAN
    let can = |id, extended, data: &[u8], ts| {
        let mut v = Vec::new();
        slcan::encode_frame(
            &slcan::CanFrame {
                id,
                extended,
                data: data.to_vec(),
                timestamp_ms: ts,
            },
            &mut v,
        );
        v
    };
    out.push((
        "slcan",
        "valid_trigger",
        can(0x181, false, &[2, 0, 12, 0, 0x10, 0x27, 0, 0], None),
    ));
    out.push((
        "slcan",
        "valid_timestamped",
        can(0x181, false, &[1, 0, 13, 0, 0x20, 0x27, 0, 0], Some(59_999)),
    ));
    out.push(("slcan", "valid_acks", b"\r\x07V1013\rN0042\rz\r".to_vec()));
    out.push((
        "slcan",
        "valid_extended",
        can(0x1FFF_FFFF, true, &[0xAB, 0xCD], Some(0)),
    ));
    out.push((
        "slcan",
        "faults",
        b"t1819\rt8001\rt1812AB\rt18\x07T200000000\rt1810EA60\r".to_vec(),
    ));
    out
}

#[test]
#[ignore = "writes the seed corpus; run by hand after changing an encoder"]
fn write_seed_corpus() {
    for (target, name, data) in seeds() {
        let dir = corpus_dir(target);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join(name), data).unwrap();
    }
}

#[test]
fn seeds_are_in_the_corpus() {
    for (target, name, data) in seeds() {
        let path = corpus_dir(target).join(name);
        let kept = std::fs::read(&path)
            .unwrap_or_else(|e| panic!("{}: {e} (run write_seed_corpus)", path.display()));
        assert_eq!(
            kept,
            data,
            "{} is stale: run write_seed_corpus",
            path.display()
        );
    }
}
