//! Every injected fault shows up on the wire as the data sheet's kind of damage, and the
//! record counts exactly what was injected.

mod common;

use std::collections::BTreeMap;
use std::time::Duration;

use common::*;
use protocol::{Decoded, RejectKind, StreamDecoder};
use sim::record::DeviceRecord;
use sim::scenario::{StreamFaults, Timed, Unplug};
use sim::{Device, Fate};

fn decode<D: StreamDecoder>(mut d: D, bytes: &[u8]) -> (Vec<D::Frame>, BTreeMap<RejectKind, u64>) {
    let mut frames = Vec::new();
    let mut rejects = BTreeMap::new();
    d.feed(bytes, |x| match x {
        Decoded::Frame(f) => frames.push(f),
        Decoded::Reject(r) => *rejects.entry(r.kind).or_insert(0) += 1,
    });
    (frames, rejects)
}

fn heavy() -> StreamFaults {
    StreamFaults {
        garbage_rate: 0.01,
        bad_checksum_rate: 0.01,
        truncated_rate: 0.01,
        drop_rate: 0.01,
        max_each: 0,
        mid_frame_on_open: false,
    }
}

/// Sequence numbers present on the wire, the count of missing ones, and the record's view.
fn check_counts(rec: &DeviceRecord, seqs: &[u64], rejected: u64, checksum_possible: bool) {
    let f = rec.faults;
    assert!(f.garbage > 0 && f.truncated > 0 && f.dropped > 0, "{f:?}");
    assert_eq!(f.bad_checksum > 0, checksum_possible, "{f:?}");
    // Every damaged line or frame is exactly one rejection at the host.
    assert_eq!(rejected, f.garbage + f.bad_checksum + f.truncated);
    // The samples that decode are exactly those sent intact.
    let sent: Vec<u64> = rec
        .samples
        .iter()
        .filter(|s| s.fate == Fate::Sent)
        .map(|s| s.seq)
        .collect();
    assert_eq!(seqs, &sent[..]);
    // The host sees a gap for every sample that did not arrive.
    let first = seqs[0];
    let last = *seqs.last().unwrap();
    let missing = (last - first + 1) - seqs.len() as u64;
    let lost_in_range = rec
        .samples
        .iter()
        .filter(|s| s.seq > first && s.seq < last && s.fate != Fate::Sent)
        .count() as u64;
    assert_eq!(missing, lost_in_range);
    assert_eq!(
        rec.samples.iter().filter(|s| s.garbage_before).count() as u64,
        f.garbage
    );
}

fn stream_for(
    p: &mut dyn serialport::SerialPort,
    start: &str,
    stop: &str,
    dur: Duration,
) -> Vec<u8> {
    send(p, start);
    let mut b = read_for(p, dur);
    send(p, stop);
    b.extend(drain(p, Duration::from_millis(200)));
    b
}

#[test]
fn li80_faults_are_rejected_and_counted() {
    let mut sc = quick();
    sc.faults.interferometer = heavy();
    let env = Env::start(sc);
    let mut p = env.open(Device::Interferometer);
    ask(&mut *p, "RATE 2000\n", ends_with(b"\r\n"));
    let bytes = stream_for(
        &mut *p,
        "STREAM ON\n",
        "STREAM OFF\n",
        Duration::from_millis(800),
    );
    let (frames, rejects) = decode(protocol::li80::Decoder::new(), &bytes);
    let seqs: Vec<u64> = frames
        .iter()
        .filter_map(|l| match l {
            protocol::li80::Line::Pos(f) => Some(f.seq as u64),
            _ => None,
        })
        .collect();
    let rec = env.sim().record();
    assert_eq!(
        rejects.get(&RejectKind::BadChecksum).copied().unwrap_or(0),
        rec.interferometer.faults.bad_checksum
    );
    check_counts(&rec.interferometer, &seqs, rejects.values().sum(), true);
}

#[test]
fn cb3_faults_are_rejected_and_counted() {
    let mut sc = quick();
    sc.faults.capball = heavy();
    let env = Env::start(sc);
    let mut p = env.open(Device::Capball);
    ask(&mut *p, "RATE 5000\n", ends_with(b"\0"));
    let bytes = stream_for(&mut *p, "START\n", "STOP\n", Duration::from_millis(500));
    let (frames, rejects) = decode(protocol::cb3::Decoder::new(), &bytes);
    let rec = env.sim().record();
    // Unwrap the 16-bit sequence against the record's first sequence number.
    let base = rec.capball.samples[0].seq;
    let mut seqs = Vec::new();
    let mut last = base.wrapping_sub(1);
    for f in &frames {
        if let protocol::cb3::Frame::Sample(s) = f {
            let step = s.seq.wrapping_sub(last as u16) as u64;
            last += step;
            seqs.push(last);
        }
    }
    // Random garbage and cut frames may fail the CRC too; corrupted samples fail nothing else.
    assert!(
        rejects.get(&RejectKind::BadCrc).copied().unwrap_or(0) >= rec.capball.faults.bad_checksum
    );
    check_counts(&rec.capball, &seqs, rejects.values().sum(), true);
}

#[test]
fn psd_faults_are_rejected_and_counted() {
    let mut sc = quick();
    sc.faults.psd = heavy();
    let env = Env::start(sc);
    let mut p = env.open(Device::Psd);
    send(&mut *p, "CONF:RATE 1000\n");
    let bytes = stream_for(
        &mut *p,
        "INIT:CONT ON\n",
        "INIT:CONT OFF\n",
        Duration::from_millis(1000),
    );
    let (frames, rejects) = decode(protocol::psd::Decoder::new(), &bytes);
    let seqs: Vec<u64> = frames
        .iter()
        .map(|l| match l {
            protocol::psd::Line::Data(d) => d.seq as u64,
            protocol::psd::Line::Answer(a) => panic!("garbage taken for an answer: {a:?}"),
        })
        .collect();
    let rec = env.sim().record();
    check_counts(&rec.psd, &seqs, rejects.values().sum(), false);
}

#[test]
fn beam_interruption_loses_the_datum_until_datum() {
    let mut sc = quick();
    sc.faults.beam_interruptions = vec![Timed {
        at_s: 0.2,
        duration_s: 0.2,
    }];
    let env = Env::start(sc);
    let mut p = env.open(Device::Interferometer);
    ask(&mut *p, "RATE 1000\n", ends_with(b"\r\n"));
    send(&mut *p, "STREAM ON\n");
    env.sim().start_program();
    let mut bytes = read_for(&mut *p, Duration::from_millis(700));
    send(&mut *p, "DATUM\n");
    bytes.extend(read_for(&mut *p, Duration::from_millis(200)));
    let (frames, rejects) = decode(protocol::li80::Decoder::new(), &bytes);
    assert!(rejects.is_empty(), "{rejects:?}");
    let mut phase = 0; // 0 fine, 1 beam low, 2 datum lost after the beam came back, 3 after DATUM
    let mut errs = 0;
    let mut counts = [0usize; 4];
    for l in &frames {
        match l {
            protocol::li80::Line::Err(e) => {
                assert_eq!((e.code, e.text.as_str()), (3, "beam lost"));
                errs += 1;
            }
            protocol::li80::Line::Answer(a) if a == "OK" && phase >= 1 => phase = 3,
            protocol::li80::Line::Pos(f) => {
                let low = f.sig < protocol::li80::SIG_MIN;
                assert_eq!(low, f.flags.beam_low(), "{f:?}");
                match phase {
                    0 if low => phase = 1,
                    1 if !low => phase = 2,
                    _ => {}
                }
                match phase {
                    0 | 3 => assert!(f.valid() && !f.flags.datum_lost(), "phase {phase}: {f:?}"),
                    1 => assert!(low && f.flags.datum_lost() && !f.valid()),
                    _ => assert!(!low && f.flags.datum_lost() && !f.valid()),
                }
                counts[phase] += 1;
            }
            _ => {}
        }
    }
    assert_eq!(errs, 1);
    // About 200 ms of interruption at 1 kHz; the rest on either side.
    assert!((180..=220).contains(&counts[1]), "{counts:?}");
    assert!(
        counts[0] > 100 && counts[2] > 100 && counts[3] > 100,
        "{counts:?}"
    );
    assert_eq!(
        env.sim().record().interferometer.faults.beam_interruptions,
        1
    );
}

#[test]
fn scheduled_unplug_and_replug() {
    let mut sc = quick();
    sc.faults.unplugs = vec![Unplug {
        device: Device::Psd,
        at_s: 0.2,
        duration_s: 0.3,
    }];
    let env = Env::start(sc);
    let link = env.sim().port(Device::Psd);
    let mut p = env.open(Device::Psd);
    send(&mut *p, "CONF:RATE 100\n");
    send(&mut *p, "INIT:CONT ON\n");
    // Reads end at the unplug (EOF or error), about 0.2 s in (timed from before the start: a
    // lower bound must not depend on when this thread runs again).
    let t = std::time::Instant::now();
    env.sim().start_program();
    let mut buf = [0u8; 4096];
    loop {
        match p.read(&mut buf) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => break,
        }
        assert!(t.elapsed() < Duration::from_secs(2), "no unplug seen");
    }
    assert!(t.elapsed() > Duration::from_millis(150));
    drop(p);
    std::thread::sleep(Duration::from_millis(500));
    assert!(link.exists(), "replugged at the same path");
    let mut p = env.open(Device::Psd);
    // Power-up state: not streaming.
    assert!(read_for(&mut *p, Duration::from_millis(200)).is_empty());
    assert_eq!(
        ask(&mut *p, "*IDN?\n", ends_with(b"\n")),
        b"PSD-2,PSD2-SIM-0007,3.1.2\n"
    );
    let rec = env.sim().record();
    assert_eq!((rec.psd.faults.unplugs, rec.psd.power_ups), (1, 2));
}

#[test]
fn full_rates_simultaneously_without_falling_behind() {
    let mut sc = quick();
    sc.faults = Default::default();
    let env = Env::start(sc);
    let mut li = env.open(Device::Interferometer);
    let mut cb = env.open(Device::Capball);
    let mut psd = env.open(Device::Psd);
    ask(&mut *li, "RATE 10000\n", ends_with(b"\r\n"));
    ask(&mut *cb, "RATE 20000\n", ends_with(b"\0"));
    send(&mut *psd, "CONF:RATE 1000\n");
    send(&mut *li, "STREAM ON\n");
    send(&mut *cb, "START\n");
    send(&mut *psd, "INIT:CONT ON\n");
    let d = Duration::from_millis(1500);
    let (a, b, c) = std::thread::scope(|s| {
        let a = s.spawn(|| read_for(&mut *li, d));
        let b = s.spawn(|| read_for(&mut *cb, d));
        let c = s.spawn(|| read_for(&mut *psd, d));
        (a.join().unwrap(), b.join().unwrap(), c.join().unwrap())
    });
    let (fa, ra) = decode(protocol::li80::Decoder::new(), &a);
    let (fb, rb) = decode(protocol::cb3::Decoder::new(), &b);
    let (fc, rc) = decode(protocol::psd::Decoder::new(), &c);
    assert!(ra.is_empty() && rb.is_empty() && rc.is_empty());
    let n = |len: usize, rate: f64| len as f64 / (rate * 1.5);
    let pos = fa
        .iter()
        .filter(|l| matches!(l, protocol::li80::Line::Pos(_)))
        .count();
    let smp = fb
        .iter()
        .filter(|f| matches!(f, protocol::cb3::Frame::Sample(_)))
        .count();
    let dat = fc
        .iter()
        .filter(|l| matches!(l, protocol::psd::Line::Data(_)))
        .count();
    // Everything due in the window arrived (minus the start-up and the last batch).
    assert!(n(pos, 10_000.0) > 0.9, "LI-80 {pos}");
    assert!(n(smp, 20_000.0) > 0.9, "CB-3 {smp}");
    assert!(n(dat, 1_000.0) > 0.9, "PSD-2 {dat}");
    let rec = env.sim().record();
    for r in [&rec.interferometer, &rec.capball, &rec.psd] {
        assert_eq!(r.faults.overflow, 0);
    }
}

#[test]
fn reopening_a_streaming_device_starts_mid_frame() {
    let mut sc = quick();
    sc.faults.psd.mid_frame_on_open = true;
    let env = Env::start(sc);
    let mut p = env.open(Device::Psd);
    send(&mut *p, "CONF:RATE 1000\n");
    send(&mut *p, "INIT:CONT ON\n");
    let first = read_for(&mut *p, Duration::from_millis(100));
    // A fresh host connection before streaming started: whole lines from the first byte.
    assert!(
        first.starts_with(b"D,"),
        "{:?}",
        String::from_utf8_lossy(&first[..20])
    );
    drop(p);
    std::thread::sleep(Duration::from_millis(100));
    let mut p = env.open(Device::Psd);
    let bytes = read_for(&mut *p, Duration::from_millis(100));
    assert!(
        !bytes.starts_with(b"D,"),
        "{:?}",
        String::from_utf8_lossy(&bytes[..20])
    );
    let (frames, rejects) = decode(protocol::psd::Decoder::new(), &bytes);
    // The tail of the missed line is rejected (or taken for an answer); whole lines follow.
    let answers = frames
        .iter()
        .filter(|f| !matches!(f, protocol::psd::Line::Data(_)))
        .count() as u64;
    assert_eq!(
        answers + rejects.values().sum::<u64>(),
        1,
        "{rejects:?} {:?}",
        &frames[..2]
    );
    assert_eq!(env.sim().record().psd.faults.partial_on_open, 1);
}
