//! The real drivers against scripted devices: the test plays the device on the far end of a
//! pty, writing bytes made with `protocol`'s encoders (and hand-made faulty ones), and checks
//! every value and every counter against what it wrote.

use std::collections::BTreeSet;
use std::time::Duration;

use drivers::{HostClock, SampleValues};
use hil::fake::{cb3_device, psd_device};
use hil::{Collected, FakeDevice, collect_until, finish};
use protocol::RejectKind;
use tokio_util::sync::CancellationToken;

/// Number of gaps (maximal runs) and of missing samples in `lost`.
fn gaps_of(lost: &BTreeSet<u64>) -> (u64, u64) {
    let mut runs = 0;
    let mut prev: Option<u64> = None;
    for &s in lost {
        if prev != Some(s.wrapping_sub(1)) {
            runs += 1;
        }
        prev = Some(s);
    }
    (runs, lost.len() as u64)
}

fn total_rejections(c: &drivers::Counters) -> u64 {
    c.rejections.values().sum()
}

// ---------------------------------------------------------------- CB-3

/// ch values of sample `i`: 24-bit codes, some negative.
fn cb3_codes(i: u64) -> [i32; 3] {
    let i = i as i32;
    [i * 37 - 100_000, -(i * 11), 8_388_607 - i * 5]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cb3_values_wraps_and_fault_counts() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("cb3");
    // 3000 samples at 20 kHz, seq starting at 64000 (wraps at 65536), t_us 100 ms before the
    // u32 wrap: both counters wrap during the run.
    const N: u64 = 3000;
    let seq0 = 64_000u64;
    let t0 = u32::MAX as u64 - 100_000;
    let dropped: BTreeSet<u64> = [500, 501, 502, 1700].into();
    let bad_crc: BTreeSet<u64> = [900].into();
    let truncated: BTreeSet<u64> = [1300].into();
    let over_range: BTreeSet<u64> = [200, 2500].into();
    let garbage_before: BTreeSet<u64> = [100, 2000].into();
    let mut chunks = Vec::new();
    let mut chunk = Vec::new();
    for i in 0..N {
        if garbage_before.contains(&i) {
            chunk.extend_from_slice(b"\x13\x37garbage!");
            chunk.push(0);
        }
        let f = protocol::cb3::SampleFrame {
            seq: ((seq0 + i) & 0xFFFF) as u16,
            t_us: ((t0 + i * 50) & 0xFFFF_FFFF) as u32,
            ch: cb3_codes(i),
            flags: if over_range.contains(&i) { 0b010 } else { 0 },
        };
        let frame = protocol::cb3::Frame::Sample(f);
        if dropped.contains(&i) {
        } else if bad_crc.contains(&i) {
            let mut payload = Vec::new();
            protocol::cb3::encode_payload(&frame, &mut payload);
            let n = payload.len();
            payload[n - 1] ^= 0x5A;
            protocol::cb3::encode_cobs(&payload, &mut chunk);
        } else if truncated.contains(&i) {
            let mut enc = Vec::new();
            protocol::cb3::encode(&frame, &mut enc);
            chunk.extend_from_slice(&enc[..10]);
            chunk.push(0);
        } else {
            protocol::cb3::encode(&frame, &mut chunk);
        }
        if chunk.len() > 900 {
            chunks.push(std::mem::take(&mut chunk));
        }
    }
    chunks.push(chunk);
    let dev =
        FakeDevice::start(&link, b'\n', cb3_device(), chunks, Duration::from_millis(2)).unwrap();

    let (tx, mut rx) = tokio::sync::mpsc::channel(100_000);
    let cancel = CancellationToken::new();
    let cfg = drivers::Cb3Config {
        port: link.display().to_string(),
        rate_hz: 20_000,
        poly: [[10.0, 0.0, 0.0], [10.0, 0.5, 0.0], [10.0, 0.0, 0.0]],
        transform: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };
    let task = drivers::spawn_cb3(cfg, HostClock::new(), tx, cancel.clone());
    let lost: BTreeSet<u64> = dropped
        .union(&bad_crc)
        .chain(truncated.iter())
        .copied()
        .collect();
    let expected = N - lost.len() as u64;
    let mut c = Collected::default();
    let ok = collect_until(&mut rx, &mut c, Duration::from_secs(120), |c| {
        c.samples.len() as u64 >= expected
    })
    .await;
    assert!(
        ok,
        "got {} of {expected} samples; errors {:?}",
        c.samples.len(),
        c.errors
    );
    tokio::time::sleep(Duration::from_millis(100)).await;
    finish(cancel, task, &mut rx, &mut c).await;
    drop(dev);

    assert_eq!(c.connected, vec!["CB-3,0042,1.3".to_string()]);
    // Every sample exactly once, in order, with its value.
    let sent: Vec<u64> = (0..N).filter(|i| !lost.contains(i)).collect();
    assert_eq!(c.samples.len(), sent.len());
    let first = &c.samples[0];
    for (s, &i) in c.samples.iter().zip(&sent) {
        assert_eq!(s.seq - first.seq, i, "unwrapped sequence");
        assert_eq!(
            s.device_t_us - first.device_t_us,
            i * 50,
            "unwrapped device clock"
        );
        let SampleValues::Capball {
            volts,
            d_um,
            e_um,
            flags,
        } = &s.values
        else {
            panic!("{s:?}")
        };
        let codes = cb3_codes(i);
        for k in 0..3 {
            let v = codes[k] as f64 * 10.0 / 8_388_608.0;
            assert!((volts[k] - v).abs() < 1e-12);
            let d = if k == 1 {
                10.0 * v + 0.5 * v * v
            } else {
                10.0 * v
            };
            assert!((d_um[k] - d).abs() < 1e-9 && (e_um[k] - d).abs() < 1e-9);
        }
        assert_eq!(s.valid, !over_range.contains(&i));
        assert_eq!(*flags != 0, over_range.contains(&i));
    }
    let k = c.counters.clone().expect("counters");
    let (gaps, gap_samples) = gaps_of(&lost);
    assert_eq!((k.gaps, k.gap_samples), (gaps, gap_samples), "{k:?}");
    assert_eq!(k.samples, sent.len() as u64);
    assert_eq!(k.invalid, over_range.len() as u64);
    assert_eq!(k.rejections.get(&RejectKind::BadCrc), Some(&1), "{k:?}");
    assert_eq!(
        total_rejections(&k),
        (garbage_before.len() + bad_crc.len() + truncated.len()) as u64,
        "{k:?}"
    );
    assert_eq!((k.dropped, k.resyncs, k.reconnects), (0, 0, 0));
}

// ---------------------------------------------------------------- PSD-2

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn psd_values_gating_and_bad_lines() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("psd2");
    const N: u64 = 600;
    let blocked: BTreeSet<u64> = (300..320).collect();
    let bad_field_count: BTreeSet<u64> = [50].into();
    let unparsable: BTreeSet<u64> = [450].into();
    let mut chunks = Vec::new();
    let mut chunk = Vec::new();
    let currents = |i: u64| -> [u64; 4] {
        if (300..320).contains(&i) {
            [10, 12, 9, 11]
        } else {
            [1000 + i, 3000 - i, 2000, 2000 + 2 * i]
        }
    };
    for i in 0..N {
        let [x1, x2, y1, y2] = currents(i);
        let d = protocol::psd::DataLine {
            seq: 4_294_967_000u32.wrapping_add(i as u32),
            t_us: 5_000_000 + i * 1000,
            x1_pa: x1,
            x2_pa: x2,
            y1_pa: y1,
            y2_pa: y2,
            head_mc: 21_500,
        };
        if bad_field_count.contains(&i) {
            chunk.extend_from_slice(format!("D,{},{},1,2,3\n", d.seq, d.t_us).as_bytes());
        } else if unparsable.contains(&i) {
            chunk.extend_from_slice(format!("D,{},{},1x,2,3,4,5\n", d.seq, d.t_us).as_bytes());
        } else {
            protocol::psd::encode_data(&d, &mut chunk);
        }
        if i % 5 == 4 {
            chunks.push(std::mem::take(&mut chunk));
        }
    }
    chunks.push(chunk);
    let dev =
        FakeDevice::start(&link, b'\n', psd_device(), chunks, Duration::from_millis(5)).unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(100_000);
    let cancel = CancellationToken::new();
    let cfg = drivers::PsdConfig {
        port: link.display().to_string(),
        baud: 921_600,
        rate_hz: 1000,
        min_sum_pa: 500.0,
        error_map: None,
        head: None,
    };
    let task = drivers::spawn_psd(cfg, HostClock::new(), tx, cancel.clone());
    let lost: BTreeSet<u64> = bad_field_count.union(&unparsable).copied().collect();
    let expected = N - lost.len() as u64;
    let mut c = Collected::default();
    let ok = collect_until(&mut rx, &mut c, Duration::from_secs(120), |c| {
        c.samples.len() as u64 >= expected
    })
    .await;
    assert!(
        ok,
        "got {} of {expected}; errors {:?}",
        c.samples.len(),
        c.errors
    );
    finish(cancel, task, &mut rx, &mut c).await;
    // The closing INIT:CONT OFF, *OPC? are the 9th and 10th commands: wait for them.
    let cmds = dev.wait_commands(10, Duration::from_secs(20));
    drop(dev);
    assert_eq!(
        cmds,
        [
            "INIT:CONT OFF",
            "*OPC?",
            "SYST:ERR?",
            "*IDN?",
            "CONF:RATE 1000",
            "SYST:ERR?",
            "INIT:CONT ON",
            "*OPC?",
            "INIT:CONT OFF",
            "*OPC?"
        ]
    );
    let sent: Vec<u64> = (0..N).filter(|i| !lost.contains(i)).collect();
    assert_eq!(c.samples.len(), sent.len());
    let s0 = c.samples[0].seq;
    for (s, &i) in c.samples.iter().zip(&sent) {
        assert_eq!(s.seq - s0, i, "sequence unwrapped across the u32 wrap");
        let SampleValues::Psd {
            x_um, y_um, head_c, ..
        } = s.values
        else {
            panic!()
        };
        let [x1, x2, y1, y2] = currents(i).map(|v| v as f64);
        assert_eq!(s.valid, !blocked.contains(&i));
        if s.valid {
            assert!((x_um - 5000.0 * (x2 - x1) / (x1 + x2)).abs() < 1e-9);
            assert!((y_um - 5000.0 * (y2 - y1) / (y1 + y2)).abs() < 1e-9);
        }
        assert!((head_c - 21.5).abs() < 1e-12);
    }
    let k = c.counters.unwrap();
    assert_eq!(k.invalid, blocked.len() as u64);
    assert_eq!((k.gaps, k.gap_samples), gaps_of(&lost));
    assert_eq!(total_rejections(&k), 2, "{k:?}");
    assert_eq!(k.rejections.get(&RejectKind::FieldCount), Some(&1), "{k:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn psd_rate_refused_is_reported_with_port_command_and_answer() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("psd2");
    let _dev =
        FakeDevice::start(&link, b'\n', psd_device(), vec![], Duration::from_millis(5)).unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(1000);
    let cancel = CancellationToken::new();
    let cfg = drivers::PsdConfig {
        port: link.display().to_string(),
        baud: 115_200,
        rate_hz: 5000,
        min_sum_pa: 500.0,
        error_map: None,
        head: None,
    };
    let task = drivers::spawn_psd(cfg, HostClock::new(), tx, cancel.clone());
    let mut c = Collected::default();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(10), |c| !c
            .errors
            .is_empty())
        .await
    );
    finish(cancel, task, &mut rx, &mut c).await;
    let e = &c.errors[0];
    assert!(
        e.contains(&link.display().to_string())
            && e.contains("CONF:RATE 5000")
            && e.contains("-222"),
        "{e}"
    );
    assert!(c.connected.is_empty() && c.samples.is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_device_gets_a_clear_error() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("cb3");
    let _dev = FakeDevice::start(
        &link,
        b'\n',
        Box::new(|_, _| None),
        vec![],
        Duration::from_millis(5),
    )
    .unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(1000);
    let cancel = CancellationToken::new();
    let cfg = drivers::Cb3Config {
        port: link.display().to_string(),
        rate_hz: 1000,
        poly: [[10.0, 0.0, 0.0]; 3],
        transform: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };
    let task = drivers::spawn_cb3(cfg, HostClock::new(), tx, cancel.clone());
    let mut c = Collected::default();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(10), |c| !c
            .errors
            .is_empty())
        .await
    );
    finish(cancel, task, &mut rx, &mut c).await;
    let e = &c.errors[0];
    assert!(
        e.contains(&link.display().to_string()) && e.contains("no answer to `STOP`"),
        "{e}"
    );
}

/// CB-3 script of `n` samples with seq and clock from 0 (a fresh power-up).
fn cb3_script(n: u64) -> Vec<Vec<u8>> {
    let mut chunks = Vec::new();
    let mut chunk = Vec::new();
    for i in 0..n {
        let f = protocol::cb3::SampleFrame {
            seq: i as u16,
            t_us: (i * 1000) as u32,
            ch: cb3_codes(i),
            flags: 0,
        };
        protocol::cb3::encode(&protocol::cb3::Frame::Sample(f), &mut chunk);
        if i % 10 == 9 {
            chunks.push(std::mem::take(&mut chunk));
        }
    }
    chunks.push(chunk);
    chunks
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replugged_device_is_reconfigured_and_its_restart_is_not_a_gap() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("cb3");
    let dev = FakeDevice::start(
        &link,
        b'\n',
        cb3_device(),
        cb3_script(400),
        Duration::from_millis(2),
    )
    .unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(100_000);
    let cancel = CancellationToken::new();
    let cfg = drivers::Cb3Config {
        port: link.display().to_string(),
        rate_hz: 1000,
        poly: [[10.0, 0.0, 0.0]; 3],
        transform: [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    };
    let task = drivers::spawn_cb3(cfg, HostClock::new(), tx, cancel.clone());
    let mut c = Collected::default();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(20), |c| c
            .samples
            .len()
            >= 400)
        .await
    );
    // Unplug: pty closed, link gone.
    dev.unplug();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(10), |c| !c
            .disconnected
            .is_empty())
        .await
    );
    tokio::time::sleep(Duration::from_millis(300)).await;
    // Plugged in again: a new pty behind the same link, sequence restarted at 0.
    let dev2 = FakeDevice::start(
        &link,
        b'\n',
        cb3_device(),
        cb3_script(300),
        Duration::from_millis(2),
    )
    .unwrap();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(20), |c| c
            .samples
            .len()
            >= 700)
        .await,
        "{} samples after replug; {:?}",
        c.samples.len(),
        c.errors
    );
    finish(cancel, task, &mut rx, &mut c).await;
    drop(dev2);
    assert_eq!(c.connected.len(), 2);
    assert_eq!(c.disconnected.len(), 1);
    assert_eq!(c.samples.len(), 700);
    for (k, s) in c.samples.iter().enumerate() {
        let i = if k < 400 { k } else { k - 400 } as u64;
        let SampleValues::Capball { volts, .. } = s.values else {
            panic!()
        };
        assert!((volts[0] - cb3_codes(i)[0] as f64 * 10.0 / 8_388_608.0).abs() < 1e-12);
    }
    let k = c.counters.unwrap();
    assert_eq!(
        (
            k.reconnects,
            k.disconnects,
            k.gaps,
            k.gap_samples,
            k.resyncs
        ),
        (1, 1, 0, 0, 0),
        "{k:?}"
    );
    assert_eq!(k.samples, 700);
}

// ---------------------------------------------------------------- LI-80

/// Compensated length at 20 °C, µm, computed here from the data sheet formula.
fn li80_expected_um(raw_nm: i64, env: &protocol::li80::EnvFrame, alpha: f64) -> f64 {
    let n = protocol::edlen::refractive_index(632.991, env.air_c, env.air_pa, env.rh_pct, 450.0);
    let t_mat = env.material_c.iter().sum::<f64>() / env.material_c.len() as f64;
    raw_nm as f64 / n / 1000.0 * (1.0 - alpha * 1e-6 * (t_mat - 20.0))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn li80_values_compensation_validity_and_fault_counts() {
    use protocol::li80::{ErrFrame, PosFlags, PosFrame, encode_err, encode_pos};
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("li80");
    const N: u64 = 2000;
    let dropped: BTreeSet<u64> = [100, 1500, 1501].into();
    let bad_checksum: BTreeSet<u64> = [400].into();
    let truncated: BTreeSet<u64> = [600].into();
    let garbage_before: BTreeSet<u64> = [700, 1900].into();
    let datum_lost: BTreeSet<u64> = (800..850).collect();
    let lost_from = 800;
    let beam_low: BTreeSet<u64> = (1200..1210).collect();
    let env_at = 1000u64;
    let env2 = protocol::li80::EnvFrame {
        seq: 1,
        t_us: 100_000,
        air_c: 24.0,
        air_pa: 101_000.0,
        rh_pct: 60.0,
        material_c: vec![25.0, 25.5, 26.0],
    };
    let raw = |i: u64| i as i64 * 123_457 - 50_000_000;
    let mut chunks = Vec::new();
    let mut chunk = Vec::new();
    for i in 0..N {
        if garbage_before.contains(&i) {
            chunk.extend_from_slice(b"#~%garbage\r\n");
        }
        if i == env_at {
            protocol::li80::encode_env(&env2, &mut chunk);
        }
        if i == 1300 {
            encode_err(
                &ErrFrame {
                    code: 3,
                    text: "beam lost".into(),
                },
                &mut chunk,
            );
        }
        let flags = if datum_lost.contains(&i) {
            PosFlags::DATUM_LOST | PosFlags::BEAM_LOW
        } else {
            0
        };
        let sig = if datum_lost.contains(&i) {
            5
        } else if beam_low.contains(&i) {
            20
        } else {
            90
        };
        let f = PosFrame {
            seq: i as u32,
            t_us: 7_000_000 + i * 100,
            raw_nm: raw(i),
            sig,
            flags: PosFlags(flags),
        };
        let mut line = Vec::new();
        encode_pos(&f, &mut line);
        if dropped.contains(&i) {
        } else if bad_checksum.contains(&i) {
            let n = line.len();
            // `*HH\r\n`: replace the checksum by a wrong one.
            let wrong = format!("{:02X}", protocol::li80::checksum(&line[1..n - 5]) ^ 0x21);
            line[n - 4..n - 2].copy_from_slice(wrong.as_bytes());
            chunk.extend_from_slice(&line);
        } else if truncated.contains(&i) {
            chunk.extend_from_slice(&line[..15]);
            chunk.extend_from_slice(b"\r\n");
        } else {
            chunk.extend_from_slice(&line);
        }
        if i % 20 == 19 {
            chunks.push(std::mem::take(&mut chunk));
        }
    }
    chunks.push(chunk);
    let dev = FakeDevice::start(
        &link,
        b'\n',
        hil::fake::li80_device(),
        chunks,
        Duration::from_millis(2),
    )
    .unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(100_000);
    let cancel = CancellationToken::new();
    let alpha = 11.7;
    let cfg = drivers::Li80Config {
        port: link.display().to_string(),
        rate_hz: 10_000,
        alpha_um_per_m_k: alpha,
    };
    let task = drivers::spawn_li80(cfg, HostClock::new(), tx, cancel.clone());
    let lost: BTreeSet<u64> = dropped
        .iter()
        .chain(&bad_checksum)
        .chain(&truncated)
        .copied()
        .collect();
    let expected = N - lost.len() as u64;
    let mut c = Collected::default();
    let ok = collect_until(&mut rx, &mut c, Duration::from_secs(120), |c| {
        c.stream().count() as u64 >= expected
    })
    .await;
    assert!(
        ok,
        "got {} of {expected}; errors {:?}",
        c.stream().count(),
        c.errors
    );
    tokio::time::sleep(Duration::from_millis(100)).await;
    finish(cancel, task, &mut rx, &mut c).await;
    // The closing STREAM OFF is the 7th command: wait for it, not for a fixed time.
    let cmds = dev.wait_commands(7, Duration::from_secs(20));
    drop(dev);
    assert_eq!(
        cmds,
        [
            "STREAM OFF",
            "*IDN?",
            "RATE 10000",
            "DATUM",
            "ENV?",
            "STREAM ON",
            "STREAM OFF"
        ]
    );
    assert_eq!(c.connected, ["LI-80,80123,2.4.1"]);
    // The `$ERR` line: counted and reported.
    assert_eq!(c.errors.len(), 1);
    assert!(c.errors[0].contains("beam lost") && c.errors[0].contains(&link.display().to_string()));

    let env1 = hil::fake::li80_env(0);
    let sent: Vec<u64> = (0..N).filter(|i| !lost.contains(i)).collect();
    let stream: Vec<_> = c.stream().collect();
    assert_eq!(stream.len(), sent.len());
    for (s, &i) in stream.iter().zip(&sent) {
        assert_eq!(s.seq, i);
        assert_eq!(s.device_t_us, 7_000_000 + i * 100);
        let SampleValues::Position {
            raw_nm,
            position_um,
            ..
        } = s.values
        else {
            panic!()
        };
        assert_eq!(raw_nm, raw(i));
        let env = if i < env_at { &env1 } else { &env2 };
        let want = li80_expected_um(raw(i), env, alpha);
        assert!(
            (position_um - want).abs() < 1e-9 * want.abs().max(1.0),
            "sample {i}: {position_um} vs {want}"
        );
        // From the first "datum lost" reading on, the readings are from another zero until
        // the host re-references (DATUM at a reference pose): invalid even where this device
        // clears its flag by itself (it should keep it until DATUM, instruments.md §1).
        assert_eq!(
            s.valid,
            i < lost_from && !beam_low.contains(&i),
            "sample {i}"
        );
    }
    // Two `$ENV` samples: the answer to `ENV?` and the one in the stream.
    let envs: Vec<_> = c
        .samples
        .iter()
        .filter(|s| matches!(s.values, SampleValues::Environment { .. }))
        .collect();
    assert_eq!(envs.len(), 2);
    let k = c.counters.unwrap();
    assert_eq!(k.samples, sent.len() as u64 + 2);
    assert_eq!((k.gaps, k.gap_samples), gaps_of(&lost), "{k:?}");
    assert_eq!(
        k.invalid,
        sent.iter().filter(|i| **i >= lost_from).count() as u64
    );
    // The loss began datum epoch 1, told once.
    let epochs: Vec<(u32, bool)> = c.datum.iter().map(|d| (d.epoch, d.referenced)).collect();
    assert_eq!(epochs, [(1, false)]);
    assert_eq!(k.device_errors, 1);
    assert_eq!(
        k.rejections.get(&RejectKind::BadChecksum),
        Some(&1),
        "{k:?}"
    );
    assert_eq!(
        total_rejections(&k),
        (garbage_before.len() + bad_checksum.len() + truncated.len()) as u64,
        "{k:?}"
    );
    assert_eq!((k.dropped, k.resyncs, k.reconnects), (0, 0, 0));
}
