//! The simulated devices against their data sheet (instruments.md): exact answer bytes,
//! frames that decode with the protocol crate, rates, clock drift, power-up state.

mod common;

use std::time::{Duration, Instant};

use common::*;
use protocol::{Decoded, RejectKind, StreamDecoder};
use sim::Device;

fn decode<D: StreamDecoder>(mut d: D, bytes: &[u8]) -> (Vec<D::Frame>, Vec<RejectKind>) {
    let mut frames = Vec::new();
    let mut rejects = Vec::new();
    d.feed(bytes, |x| match x {
        Decoded::Frame(f) => frames.push(f),
        Decoded::Reject(r) => rejects.push(r.kind),
    });
    (frames, rejects)
}

/// Least-squares slope of y on x.
fn slope(pts: &[(f64, f64)]) -> f64 {
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
    sxy / sxx
}

#[test]
fn li80_answers_are_exact() {
    let env = Env::start(quick());
    let mut p = env.open(Device::Interferometer);
    let crlf = || ends_with(b"\r\n");
    assert_eq!(
        ask(&mut *p, "*IDN?\n", crlf()),
        b"LI-80,LI80-SIM-0001,2.4.1\r\n"
    );
    assert_eq!(
        ask(&mut *p, "RATE 0\n", crlf()),
        b"ERR 2 rate out of range\r\n"
    );
    assert_eq!(
        ask(&mut *p, "RATE 10001\n", crlf()),
        b"ERR 2 rate out of range\r\n"
    );
    assert_eq!(ask(&mut *p, "RATE 10000\r\n", crlf()), b"OK\r\n");
    assert_eq!(
        ask(&mut *p, "HELLO\n", crlf()),
        b"ERR 1 unknown command\r\n"
    );
    assert_eq!(ask(&mut *p, "DATUM\n", crlf()), b"OK\r\n");
    assert_eq!(ask(&mut *p, "STREAM OFF\n", crlf()), b"OK\r\n");
    let env_line = ask(&mut *p, "ENV?\n", crlf());
    let (frames, rejects) = decode(protocol::li80::Decoder::new(), &env_line);
    assert!(rejects.is_empty(), "{rejects:?}");
    match &frames[..] {
        [protocol::li80::Line::Env(e)] => {
            // The demo's environment at t = 0: means plus phase-0 sines.
            assert!((e.air_c - 20.3).abs() < 1e-9, "{e:?}");
            assert!((e.air_pa - 100_800.0).abs() < 1e-9);
            assert!((e.rh_pct - 45.0).abs() < 1e-9);
            assert_eq!(e.material_c.len(), 2);
        }
        other => panic!("expected one $ENV line, got {other:?}"),
    }
    // Nothing streams before STREAM ON (power-up state).
    assert!(read_for(&mut *p, Duration::from_millis(200)).is_empty());
}

#[test]
fn li80_streams_at_rate_with_env_and_configured_drift() {
    let mut sc = quick();
    // A drift large enough to measure against the host clock in 1.5 s.
    sc.interferometer.identity.clock_ppm = 5000.0;
    let env = Env::start(sc);
    let mut p = env.open(Device::Interferometer);
    ask(&mut *p, "RATE 2000\n", ends_with(b"\r\n"));
    send(&mut *p, "STREAM ON\n");
    let mut dec = protocol::li80::Decoder::new();
    let start = Instant::now();
    let mut pos = Vec::new();
    let mut envs = 0;
    let mut pts = Vec::new();
    let mut buf = [0u8; 8192];
    // 1.5 s of device time (3000 samples), however long a loaded machine takes to deliver it.
    while pos.len() < 3000 && start.elapsed() < Duration::from_secs(60) {
        let n = match p.read(&mut buf) {
            Ok(n) => n,
            Err(_) => continue,
        };
        let host_s = start.elapsed().as_secs_f64();
        dec.feed(&buf[..n], |x| match x {
            Decoded::Frame(protocol::li80::Line::Pos(f)) => {
                pts.push((host_s, f.t_us as f64 * 1e-6));
                pos.push(f);
            }
            Decoded::Frame(protocol::li80::Line::Env(_)) => envs += 1,
            Decoded::Frame(protocol::li80::Line::Answer(a)) => assert_eq!(a, "OK"),
            Decoded::Frame(other) => panic!("unexpected {other:?}"),
            Decoded::Reject(r) => panic!("rejected {r:?}"),
        });
    }
    // 1.5 s at 2 kHz.
    assert!(pos.len() >= 3000, "{} samples in 60 s", pos.len());
    for w in pos.windows(2) {
        assert_eq!(w[1].seq, w[0].seq + 1);
        // 500 µs apart on the device clock (± rounding).
        assert!((w[1].t_us - w[0].t_us).abs_diff(500) <= 4, "{:?}", w);
    }
    assert!((1..=3).contains(&envs), "{envs} $ENV lines in 1.5 s");
    // Arrival times carry batching and scheduling delays that only ever add: compare the
    // least-delayed samples of the first and the last 0.15 s (lower envelope), which a loaded
    // machine disturbs far less than a regression over all samples.
    let (h0, h1) = (pts[0].0, pts[pts.len() - 1].0);
    let least = |from: f64, to: f64| {
        pts.iter()
            .filter(|p| p.0 >= from && p.0 < to)
            .map(|p| (p.0 - p.1, p.1))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, dev_s)| pts.iter().find(|p| p.1 == dev_s).copied().unwrap())
            .unwrap()
    };
    let (a, b) = (least(h0, h0 + 0.15), least(h1 - 0.15, h1 + 1.0));
    let drift_ppm = ((b.1 - a.1) / (b.0 - a.0) - 1.0) * 1e6;
    eprintln!(
        "measured drift {drift_ppm:.0} ppm (regression over all: {:.0} ppm)",
        (slope(&pts) - 1.0) * 1e6
    );
    assert!(
        (drift_ppm - 5000.0).abs() < 600.0,
        "measured drift {drift_ppm} ppm"
    );
    assert!(pos.iter().all(|f| f.sig >= 25 && f.flags.0 == 0));
}

#[test]
fn cb3_answers_stream_and_wraps() {
    let mut sc = quick();
    sc.capball.identity.seq_start = 65_530;
    sc.capball.identity.clock_start_us = u32::MAX as u64 - 100_000;
    let env = Env::start(sc);
    let mut p = env.open(Device::Capball);
    let text = |bytes: &[u8]| {
        let (frames, rejects) = decode(protocol::cb3::Decoder::new(), bytes);
        assert!(rejects.is_empty(), "{rejects:?}");
        frames
    };
    let zero = || ends_with(b"\0");
    use protocol::cb3::Frame;
    assert_eq!(
        text(&ask(&mut *p, "ID?\n", zero())),
        vec![Frame::Text("CB-3,CB3-SIM-0042,1.7.0".into())]
    );
    assert_eq!(
        text(&ask(&mut *p, "RATE 99\n", zero())),
        vec![Frame::Text("ERR rate out of range".into())]
    );
    assert_eq!(
        text(&ask(&mut *p, "RATE 20001\n", zero())),
        vec![Frame::Text("ERR rate out of range".into())]
    );
    assert_eq!(
        text(&ask(&mut *p, "FOO\n", zero())),
        vec![Frame::Text("ERR unknown command".into())]
    );
    assert_eq!(
        text(&ask(&mut *p, "RATE 20000\n", zero())),
        vec![Frame::Text("OK".into())]
    );
    // The exact bytes of an answer: COBS of [0x7F, 'O', 'K', crc lo, crc hi] + 0x00.
    let ok = ask(&mut *p, "STOP\n", zero());
    let crc = protocol::cb3::crc16(&[0x7F, b'O', b'K']);
    let payload = [0x7F, b'O', b'K', (crc & 0xFF) as u8, (crc >> 8) as u8];
    let mut expect = cobs::encode_vec(&payload);
    expect.push(0);
    assert_eq!(ok, expect);
    let mut bytes = ask(&mut *p, "START\n", zero());
    bytes.extend(read_for(&mut *p, Duration::from_millis(1000)));
    let frames = text(&bytes);
    assert_eq!(frames[0], Frame::Text("OK".into()));
    let samples: Vec<_> = frames
        .iter()
        .filter_map(|f| match f {
            Frame::Sample(s) => Some(*s),
            _ => None,
        })
        .collect();
    // 20 kHz for about 1 s.
    assert!(
        (17_000..=21_000).contains(&samples.len()),
        "{} samples",
        samples.len()
    );
    assert_eq!(samples[0].seq, 65_530);
    let mut wrapped_seq = false;
    let mut wrapped_t = false;
    for w in samples.windows(2) {
        assert_eq!(w[1].seq, w[0].seq.wrapping_add(1));
        wrapped_seq |= w[1].seq < w[0].seq;
        wrapped_t |= w[1].t_us < w[0].t_us;
        let dt = w[1].t_us.wrapping_sub(w[0].t_us);
        assert!((48..=52).contains(&dt), "{dt} µs between samples");
    }
    assert!(wrapped_seq && wrapped_t);
    // At home the error is the setup offset; volts · 10 µm/V ≈ distance (polynomial ~linear).
    let v = samples[100].volts();
    assert!(v.iter().all(|v| v.abs() < 2.0), "{v:?}");
    assert!(samples.iter().all(|s| s.flags == 0));
}

#[test]
fn psd_scpi_errors_and_stream() {
    let env = Env::start(quick());
    let mut p = env.open(Device::Psd);
    let nl = || ends_with(b"\n");
    assert_eq!(
        ask(&mut *p, "*IDN?\n", nl()),
        b"PSD-2,PSD2-SIM-0007,3.1.2\n"
    );
    assert_eq!(ask(&mut *p, "*OPC?\n", nl()), b"1\n");
    send(&mut *p, "CONF:RATE 1001\n");
    send(&mut *p, "CONF:RATE 0\n");
    assert_eq!(
        ask(&mut *p, "SYST:ERR?\n", nl()),
        b"-222,\"Data out of range\"\n"
    );
    assert_eq!(
        ask(&mut *p, "SYST:ERR?\n", nl()),
        b"-222,\"Data out of range\"\n"
    );
    assert_eq!(ask(&mut *p, "SYST:ERR?\n", nl()), b"0,\"No error\"\n");
    send(&mut *p, "BOGUS\n");
    assert_eq!(
        ask(&mut *p, "SYST:ERR?\n", nl()),
        b"-113,\"Undefined header\"\n"
    );
    send(&mut *p, "CONF:RATE 1000\n");
    send(&mut *p, "INIT:CONT ON\n");
    let bytes = read_for(&mut *p, Duration::from_millis(1000));
    send(&mut *p, "INIT:CONT OFF\n");
    let (frames, rejects) = decode(protocol::psd::Decoder::new(), &bytes);
    assert!(rejects.is_empty(), "{rejects:?}");
    let data: Vec<_> = frames
        .iter()
        .filter_map(|f| match f {
            protocol::psd::Line::Data(d) => Some(*d),
            _ => None,
        })
        .collect();
    assert!((850..=1050).contains(&data.len()), "{} lines", data.len());
    // Spot at home (z = 0): the straightness polynomials' constants, 12 µm and −5 µm.
    let n = data.len() as f64;
    let x = data
        .iter()
        .map(|d| 5000.0 * (d.x2_pa as f64 - d.x1_pa as f64) / (d.x1_pa + d.x2_pa) as f64)
        .sum::<f64>()
        / n;
    let y = data
        .iter()
        .map(|d| 5000.0 * (d.y2_pa as f64 - d.y1_pa as f64) / (d.y1_pa + d.y2_pa) as f64)
        .sum::<f64>()
        / n;
    assert!((x - 12.0).abs() < 0.02, "x = {x}");
    assert!((y + 5.0).abs() < 0.02, "y = {y}");
    for d in &data {
        assert!((d.x1_pa + d.x2_pa).abs_diff(1_200_000) <= 1);
        assert!((21_000..22_000).contains(&d.head_mc), "{}", d.head_mc);
    }
}

#[test]
fn slcan_commands_and_trigger_sequence() {
    let mut sc = quick();
    sc.faults.missing_triggers = vec![sim::scenario::MissingTrigger {
        pose: 2,
        event: protocol::can::TriggerEvent::ExactStop,
    }];
    let env = Env::start(sc);
    let mut p = env.open(Device::Trigger);
    let cr = || ends_with(b"\r");
    assert_eq!(ask(&mut *p, "C\r", cr()), b"\r");
    assert_eq!(ask(&mut *p, "S6\r", cr()), b"\r");
    assert_eq!(ask(&mut *p, "V\r", cr()), b"V1013\r");
    assert_eq!(ask(&mut *p, "X\r", ends_with(b"\x07")), b"\x07");
    assert_eq!(ask(&mut *p, "Z1\r", cr()), b"\r");
    assert_eq!(ask(&mut *p, "O\r", cr()), b"\r");
    assert_eq!(
        ask(&mut *p, "S6\r", ends_with(b"\x07")),
        b"\x07",
        "bit rate while open"
    );
    env.sim().start_program();
    let dur = env.sim().program_duration_s();
    let bytes = read_for(&mut *p, Duration::from_secs_f64(dur + 0.5));
    env.rt.block_on(async {
        tokio::time::timeout(Duration::from_secs(2), env.sim().program_done())
            .await
            .unwrap()
    });
    let (msgs, rejects) = decode(protocol::slcan::Decoder::new(), &bytes);
    assert!(rejects.is_empty(), "{rejects:?}");
    let mut got = Vec::new();
    let mut last_nc: Option<u32> = None;
    for m in msgs {
        let protocol::slcan::Message::Frame(f) = m else {
            panic!("unexpected {m:?}")
        };
        assert_eq!((f.id, f.extended), (0x181, false));
        assert!(f.timestamp_ms.is_some_and(|t| t < 60_000));
        let t = protocol::can::TriggerFrame::decode(&f.data).unwrap();
        if let Some(prev) = last_nc {
            assert!(t.nc_ms.wrapping_sub(prev) < 2_000);
        }
        last_nc = Some(t.nc_ms);
        got.push((t.event as u8, t.pose));
    }
    // Program start, pose 1 (motion, stop, dwell end), pose 2 without its exact stop, end.
    assert_eq!(
        got,
        vec![(4, 0), (1, 1), (2, 1), (3, 1), (1, 2), (3, 2), (5, 0)]
    );
    let rec = env.sim().record();
    assert_eq!(
        rec.trigger
            .events
            .iter()
            .filter(|e| e.fate == sim::TriggerFate::Missing)
            .count(),
        1
    );
    assert_eq!(rec.truth.len(), 2);
}

#[test]
fn unplug_ends_reads_and_replug_restores_power_up_state() {
    let env = Env::start(quick());
    let link = env.sim().port(Device::Interferometer);
    let pts1 = std::fs::read_link(&link).unwrap();
    let mut p = env.open(Device::Interferometer);
    ask(&mut *p, "RATE 1000\n", ends_with(b"\r\n"));
    send(&mut *p, "STREAM ON\n");
    assert!(!read_for(&mut *p, Duration::from_millis(100)).is_empty());
    env.rt
        .block_on(env.sim().unplug(Device::Interferometer))
        .unwrap();
    assert!(!link.exists(), "link must vanish on unplug");
    // The host's reads end: EOF or an error, never a timeout forever.
    let mut buf = [0u8; 4096];
    let end = Instant::now() + Duration::from_secs(1);
    let mut ended = false;
    while Instant::now() < end {
        match p.read(&mut buf) {
            Ok(0) => {
                ended = true;
                break;
            }
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => {
                ended = true;
                break;
            }
        }
    }
    assert!(ended, "read after unplug neither returned EOF nor failed");
    drop(p);
    let pts2 = env
        .rt
        .block_on(env.sim().replug(Device::Interferometer))
        .unwrap();
    assert_eq!(std::fs::read_link(&link).unwrap(), pts2);
    let _ = pts1;
    let mut p = env.open(Device::Interferometer);
    // Power-up state: not streaming, 10 Hz.
    assert!(read_for(&mut *p, Duration::from_millis(150)).is_empty());
    send(&mut *p, "STREAM ON\n");
    let bytes = read_for(&mut *p, Duration::from_millis(1000));
    let (frames, _) = decode(protocol::li80::Decoder::new(), &bytes);
    let pos: Vec<_> = frames
        .iter()
        .filter_map(|f| match f {
            protocol::li80::Line::Pos(p) => Some(*p),
            _ => None,
        })
        .collect();
    assert!(
        (9..=12).contains(&pos.len()),
        "{} samples at 10 Hz",
        pos.len()
    );
    assert_eq!(pos[0].seq, 0, "sequence restarts at power-up");
    assert!(pos[0].t_us < 1_000_000, "clock restarts at power-up");
    let rec = env.sim().record();
    assert_eq!(rec.interferometer.faults.unplugs, 1);
    assert_eq!(rec.interferometer.power_ups, 2);
}

#[test]
fn host_close_and_reopen_is_seen_without_stale_data() {
    let env = Env::start(quick());
    let mut p = env.open(Device::Psd);
    send(&mut *p, "CONF:RATE 100\n");
    send(&mut *p, "INIT:CONT ON\n");
    assert!(!read_for(&mut *p, Duration::from_millis(100)).is_empty());
    drop(p);
    std::thread::sleep(Duration::from_millis(300));
    let mut p = env.open(Device::Psd);
    let bytes = read_for(&mut *p, Duration::from_millis(300));
    let (frames, _) = decode(protocol::psd::Decoder::new(), &bytes);
    assert!(
        frames.len() >= 20,
        "still streaming after the host reopened"
    );
    let rec = env.sim().record();
    assert!(rec.psd.faults.not_connected >= 20, "{:?}", rec.psd.faults);
}

/// CPU time of this process, s.
fn cpu_s() -> f64 {
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage writes into the struct we own.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

#[test]
fn idle_devices_with_open_ports_do_not_spin() {
    let env = Env::start(quick());
    // Every port opened at once and answered at once: a device that spins on a stale
    // readiness would starve the others (and burn a core).
    let mut ports: Vec<_> = Device::ALL.into_iter().map(|d| env.open(d)).collect();
    let mut li = ports.remove(0);
    assert_eq!(
        ask(&mut *li, "*IDN?\n", ends_with(b"\r\n")),
        b"LI-80,LI80-SIM-0001,2.4.1\r\n"
    );
    let c0 = cpu_s();
    std::thread::sleep(Duration::from_millis(1000));
    let used = cpu_s() - c0;
    // Four 2 ms timers cost a few per cent of a core; a spinning task costs 100 %.
    assert!(used < 0.4, "{used} s of CPU in 1 s idle");
    assert_eq!(
        ask(&mut *li, "*IDN?\n", ends_with(b"\r\n")),
        b"LI-80,LI80-SIM-0001,2.4.1\r\n"
    );
}

#[test]
fn program_starts_when_the_can_channel_opens() {
    let mut sc = quick();
    sc.program.start = sim::ProgramStart::OnCanOpen;
    sc.program.start_delay_s = 0.2;
    let env = Env::start(sc);
    let mut p = env.open(Device::Trigger);
    ask(&mut *p, "S6\r", ends_with(b"\r"));
    std::thread::sleep(Duration::from_millis(200));
    assert!(!env.sim().program_started());
    // Timed from before the open: the delay runs from the simulator's receipt of `O`, which a
    // loaded machine may deliver, and answer, late (the answer is no lower bound).
    let t = Instant::now();
    assert_eq!(ask(&mut *p, "O\r", ends_with(b"\r")), b"\r");
    assert!(env.sim().program_started());
    let bytes = read_until(&mut *p, Duration::from_secs(2), |b| !b.is_empty());
    // The program-start frame comes after the configured delay.
    assert!(
        t.elapsed() >= Duration::from_millis(195),
        "{:?}",
        t.elapsed()
    );
    assert!(
        bytes.starts_with(b"t1818040000"),
        "{:?}",
        String::from_utf8_lossy(&bytes)
    );
    let done = env.rt.block_on(async {
        tokio::time::timeout(Duration::from_secs(5), env.sim().program_done()).await
    });
    assert!(done.is_ok());
}

#[test]
fn program_starts_after_a_delay_without_any_host() {
    let mut sc = quick();
    sc.program.start = sim::ProgramStart::AfterDelay;
    sc.program.start_delay_s = 0.1;
    // The delay runs from the simulator's start: the clock is read before it.
    let t = Instant::now();
    let env = Env::start(sc);
    let dur = env.sim().program_duration_s();
    env.rt
        .block_on(async {
            tokio::time::timeout(Duration::from_secs(5), env.sim().program_done()).await
        })
        .unwrap();
    let took = t.elapsed().as_secs_f64();
    assert!(
        took >= dur + 0.1 - 0.01 && took < dur + 0.1 + 2.0,
        "{took} s for a {dur} s program"
    );
    let rec = env.sim().record();
    // No host had the adapter open: every event is accounted for as not delivered.
    assert_eq!(rec.trigger.events.len(), 2 + 3 * 2);
    assert!(
        rec.trigger
            .events
            .iter()
            .all(|e| e.fate == sim::TriggerFate::ChannelClosed)
    );
}

#[test]
fn device_states_and_waiting_until_all_stream() {
    let env = Env::start(quick());
    let all = [
        Device::Interferometer,
        Device::Capball,
        Device::Psd,
        Device::Trigger,
    ];
    for d in all {
        let st = env.sim().state(d);
        assert!(
            st.plugged && !st.active && st.power_ups == 1,
            "{d:?}: {st:?}"
        );
        assert_eq!(st.rate_hz, if d == Device::Trigger { 0 } else { 10 });
    }
    let mut li = env.open(Device::Interferometer);
    let mut cb = env.open(Device::Capball);
    let mut psd = env.open(Device::Psd);
    let mut tr = env.open(Device::Trigger);
    ask(&mut *li, "RATE 500\n", ends_with(b"\r\n"));
    send(&mut *li, "STREAM ON\n");
    send(&mut *cb, "START\n");
    send(&mut *psd, "INIT:CONT ON\n");
    let waited = env.rt.block_on(async {
        tokio::time::timeout(Duration::from_millis(300), env.sim().wait_active(&all)).await
    });
    assert!(waited.is_err(), "the CAN channel is still closed");
    send(&mut *tr, "O\r");
    let waited = env.rt.block_on(async {
        tokio::time::timeout(Duration::from_secs(2), env.sim().wait_active(&all)).await
    });
    assert!(waited.is_ok());
    let st = env.sim().state(Device::Interferometer);
    assert!(
        st.host_connected && st.active && st.rate_hz == 500,
        "{st:?}"
    );
    env.rt.block_on(env.sim().unplug(Device::Psd)).unwrap();
    assert!(!env.sim().state(Device::Psd).plugged);
}
