//! The LI-80 driver over an in-memory port, the device played byte for byte from
//! instruments.md §1: the command sequence, streaming, a device error, a rejected line, a
//! gap, an unplug with reconnect, and a stop that keeps the samples sent before its answer.
//!
//! Time is tokio's paused clock on one thread: it only moves when both sides wait, so the
//! driver's answer timeouts and backoff never fire while the device has something to do.

use protocol::RejectKind;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use super::*;
use crate::serial_driver::run;
use crate::test_port::{Device, next_event, nmea, socket};
use crate::{Counters, DriverEvent, HostClock};

const PORT: &str = "/dev/metrolog-li80";

fn config() -> Li80Config {
    Li80Config {
        port: PORT.into(),
        rate_hz: 1000,
        alpha_um_per_m_k: 11.7,
    }
}

/// The device's side of the driver's setup (instruments.md §1), the `$ENV` record answering
/// `ENV?` being `env`. `stale` is what a device still streaming sends before its `OK`. The
/// datum is taken on the run's first connection only (`first`). The driver is configured at
/// `config().rate_hz`.
async fn answer_setup(dev: &mut Device, stale: &str, env: &str, first: bool) {
    answer_setup_at(dev, 1000, stale, env, first).await
}

/// [`answer_setup`] for a driver configured at `rate_hz`.
async fn answer_setup_at(dev: &mut Device, rate_hz: u32, stale: &str, env: &str, first: bool) {
    dev.expect("STREAM OFF\n").await;
    dev.send(stale).await;
    dev.send("OK\r\n").await;
    dev.expect("*IDN?\n").await;
    dev.send("LI-80,A1234,2.1.0\r\n").await;
    dev.expect(&format!("RATE {rate_hz}\n")).await;
    dev.send("OK\r\n").await;
    if first {
        dev.expect("DATUM\n").await;
        dev.send("OK\r\n").await;
    }
    dev.expect("ENV?\n").await;
    dev.send(&nmea(env)).await;
    dev.expect("STREAM ON\n").await;
    dev.send("OK\r\n").await;
}

/// The next event, which must be a sample.
async fn next_sample(rx: &mut mpsc::Receiver<DriverEvent>) -> Sample {
    match next_event(rx).await {
        DriverEvent::Sample(s) => s,
        ev => panic!("expected a sample, got {ev:?}"),
    }
}

/// The next event, which must be the `$ENV` sample of a setup; returns its refractive index.
async fn expect_environment(rx: &mut mpsc::Receiver<DriverEvent>, seq: u64) -> f64 {
    let s = next_sample(rx).await;
    assert_eq!(
        (s.instrument, s.seq, s.device_t_us),
        (Instrument::Interferometer, seq, 500)
    );
    assert!(s.valid);
    assert_eq!(
        s.fitted_ns, s.host_ns,
        "an `$ENV` sample keeps its arrival time"
    );
    let SampleValues::Environment {
        air_c,
        air_pa,
        rh_pct,
        material_c,
        n_air,
    } = s.values
    else {
        panic!("expected an environment sample, got {:?}", s.values)
    };
    assert_eq!((air_c, air_pa, rh_pct), (20.0, 101_325.0, 50.0));
    assert_eq!(material_c, [20.0]);
    // Standard air at 632.991 nm: n - 1 ≈ 2.7e-4.
    assert!((1.000_26..1.000_28).contains(&n_air), "n_air {n_air}");
    n_air
}

async fn expect_connected(rx: &mut mpsc::Receiver<DriverEvent>) {
    match next_event(rx).await {
        DriverEvent::Connected {
            instrument,
            port,
            identity,
        } => {
            assert_eq!(instrument, Instrument::Interferometer);
            assert_eq!(port, PORT);
            assert_eq!(identity, "LI-80,A1234,2.1.0");
        }
        ev => panic!("expected Connected, got {ev:?}"),
    }
}

/// A `$POS` sample with `seq`, `raw_nm`, `sig`, `flags` and validity as given, its position
/// air-compensated with `n_air` (the material at 20 °C: no thermal correction).
fn check_position(s: &Sample, n_air: f64, want: (u64, i64, u8, u32, bool)) {
    let (seq, raw, sig_want, flags_want, valid) = want;
    assert_eq!(
        (s.instrument, s.seq, s.valid),
        (Instrument::Interferometer, seq, valid)
    );
    let SampleValues::Position {
        raw_nm,
        position_um,
        sig,
        flags,
    } = s.values
    else {
        panic!("expected a position sample, got {:?}", s.values)
    };
    assert_eq!((raw_nm, sig, flags), (raw, sig_want, flags_want));
    assert_eq!(position_um, raw as f64 / n_air * 1e-3);
}

/// The host flags of a reading in datum epoch 1, not re-referenced.
const LOST_1: u32 = types::DATUM_NOT_RUNS | (1 << types::DATUM_EPOCH_SHIFT);

/// The next event, which must be a datum change to `epoch` (`referenced` or lost).
async fn expect_datum(rx: &mut mpsc::Receiver<DriverEvent>, epoch: u32, referenced: bool) {
    match next_event(rx).await {
        DriverEvent::Datum { change, .. } => {
            assert_eq!(
                (change.epoch, change.referenced),
                (epoch, referenced),
                "{change:?}"
            );
        }
        ev => panic!("expected a datum change, got {ev:?}"),
    }
}

#[tokio::test(start_paused = true)]
async fn li80_session_streaming_unplug_and_stop_over_an_in_memory_port() {
    let (tx, mut rx) = mpsc::channel(1024);
    let (socket, open) = socket();
    let cancel = CancellationToken::new();
    let (driver, path) = li80(&config(), HostClock::new(), tx);
    let mut dev = socket.plug();
    let task = tokio::spawn(run(driver, path, open, cancel.clone()));

    // A device left streaming by an earlier run: its lines before `OK` are no samples.
    let stale = nmea("POS,900,900000,12345,80,0") + &nmea("POS,901,901000,12346,80,0");
    answer_setup(&mut dev, &stale, "ENV,0,500,20.00,101325,50.0,20.00", true).await;
    let n_air = expect_environment(&mut rx, 0).await;
    expect_connected(&mut rx).await;

    // Streaming: samples in order, compensated; a weak beam is invalid.
    dev.send(&(nmea("POS,1,1000,632991,87,0") + &nmea("POS,2,2000,-1000,10,1")))
        .await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (1, 632_991, 87, 0, true),
    );
    check_position(&next_sample(&mut rx).await, n_air, (2, -1000, 10, 1, false));

    // A device fault is reported with its code and text.
    dev.send(&nmea("ERR,3,beam lost")).await;
    match next_event(&mut rx).await {
        DriverEvent::Error { error, port, .. } => {
            assert_eq!(port, PORT);
            assert!(
                matches!(&error, DriverError::DeviceReported { code: 3, text, .. } if text == "beam lost"),
                "{error:?}"
            );
        }
        ev => panic!("expected the device's error, got {ev:?}"),
    }

    // A line with a wrong checksum (0x65 is right for this body) is rejected, so sample 3 is
    // missing: a gap of one before sample 4.
    dev.send("$POS,3,3000,5,87,0*00\r\n").await;
    dev.send(&nmea("POS,4,4000,7,87,0")).await;
    check_position(&next_sample(&mut rx).await, n_air, (4, 7, 87, 0, true));

    // Unplugged: the driver reads end of file, reports it, and reconnects to the next device
    // plugged in, which it configures from scratch.
    let mut dev2 = socket.plug();
    drop(dev);
    match next_event(&mut rx).await {
        DriverEvent::Disconnected { reason, port, .. } => {
            assert_eq!(port, PORT);
            assert!(matches!(reason, DriverError::EndOfFile), "{reason:?}");
        }
        ev => panic!("expected Disconnected, got {ev:?}"),
    }
    // No `DATUM` this time: it would move the run's zero to wherever the axis stands. A new
    // datum epoch begins instead, and the operator is told.
    answer_setup(&mut dev2, "", "ENV,0,500,20.00,101325,50.0,20.00", false).await;
    expect_datum(&mut rx, 1, false).await;
    // The `$ENV` sequence starts afresh with the new session.
    expect_environment(&mut rx, 0).await;
    expect_connected(&mut rx).await;
    // The device restarted its count: no gap, no resync. Its zero is not the run's datum any
    // more: every reading is flagged and invalid (a pose of it is `datum_lost`, never ok).
    dev2.send(&nmea("POS,1,1000,100,90,0")).await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (1, 100, 90, LOST_1, false),
    );

    // Cancelled: the driver stops the stream, and what the device sent before its `OK` still
    // arrives.
    cancel.cancel();
    dev2.expect("STREAM OFF\n").await;
    dev2.send(&(nmea("POS,2,2000,200,90,0") + &nmea("POS,3,3000,300,90,0") + "OK\r\n"))
        .await;
    task.await.unwrap();
    let mut last_counters = None;
    let mut samples = Vec::new();
    while let Ok(ev) = rx.try_recv() {
        match ev {
            DriverEvent::Sample(s) => samples.push(s),
            DriverEvent::Counters { counters, .. } => last_counters = Some(counters),
            ev => panic!("unexpected event after the stop: {ev:?}"),
        }
    }
    assert_eq!(samples.len(), 2);
    check_position(&samples[0], n_air, (2, 200, 90, LOST_1, false));
    check_position(&samples[1], n_air, (3, 300, 90, LOST_1, false));

    let c = last_counters.expect("a last counters snapshot");
    let want = Counters {
        // 2 `$ENV`, 3 + 1 + 2 `$POS`
        samples: 8,
        // The low-signal sample, and the three after the reconnect (not the run's datum).
        invalid: 1 + 3,
        dropped: 0,
        gaps: 1,
        gap_samples: 1,
        resyncs: 0,
        device_errors: 1,
        disconnects: 1,
        reconnects: 1,
        // The answer lines of both setups (`ENV?` is answered by a record; no `DATUM` on the
        // reconnect) and of the stop.
        answers: 5 + 4 + 1,
        rejections: [(RejectKind::BadChecksum, 1)].into_iter().collect(),
        clock_drift_ppm: c.clock_drift_ppm,
    };
    assert_eq!(c, want);
}

/// A beam loss (the device's "datum lost" flag) begins epoch 1; the daemon's `Reference` at
/// the reference pose makes the driver send `DATUM` once the axis has stood the settle time,
/// and the readings after its `OK` are clean in epoch 1; a `Moving` before the settle time
/// cancels it; `LoseDatum` begins epoch 2.
#[tokio::test(start_paused = true)]
async fn li80_beam_loss_epoch_and_re_reference_over_an_in_memory_port() {
    let (tx, mut rx) = mpsc::channel(1024);
    let (socket, open) = socket();
    let cancel = CancellationToken::new();
    let (cmd_tx, cmd_rx) = mpsc::unbounded_channel();
    let (driver, mut path) = li80(&config(), HostClock::new(), tx);
    path.converter.commands = Some(cmd_rx);
    let mut dev = socket.plug();
    let task = tokio::spawn(run(driver, path, open, cancel.clone()));
    answer_setup(&mut dev, "", "ENV,0,500,20.00,101325,50.0,20.00", true).await;
    let n_air = expect_environment(&mut rx, 0).await;
    expect_connected(&mut rx).await;
    dev.send(&nmea("POS,1,1000,100,87,0")).await;
    check_position(&next_sample(&mut rx).await, n_air, (1, 100, 87, 0, true));
    // Beam lost: bit 1 from the device.
    dev.send(&nmea("POS,2,2000,150,87,2")).await;
    expect_datum(&mut rx, 1, false).await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (2, 150, 87, 2 | LOST_1, false),
    );
    // A reference pose whose dwell ends before the settle time: no DATUM.
    cmd_tx
        .send(Li80Command::Reference {
            pose: 7,
            settle: Duration::from_millis(200),
        })
        .unwrap();
    cmd_tx.send(Li80Command::Moving).unwrap();
    dev.send(&nmea("POS,3,3000,160,87,2")).await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (3, 160, 87, 2 | LOST_1, false),
    );
    tokio::time::sleep(Duration::from_millis(300)).await;
    dev.send(&nmea("POS,4,4000,170,87,2")).await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (4, 170, 87, 2 | LOST_1, false),
    );
    // The next one: DATUM after 200 ms standing.
    cmd_tx
        .send(Li80Command::Reference {
            pose: 13,
            settle: Duration::from_millis(200),
        })
        .unwrap();
    dev.send(&nmea("POS,5,5000,170,87,2")).await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (5, 170, 87, 2 | LOST_1, false),
    );
    tokio::time::sleep(Duration::from_millis(250)).await;
    dev.send(&nmea("POS,6,6000,170,87,2")).await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (6, 170, 87, 2 | LOST_1, false),
    );
    dev.expect("DATUM\n").await;
    dev.send("OK\r\n").await;
    expect_datum(&mut rx, 1, true).await;
    dev.send(&nmea("POS,7,7000,3,87,0")).await;
    let epoch_1 = 1 << types::DATUM_EPOCH_SHIFT;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (7, 3, 87, epoch_1, true),
    );
    // The service learns it started mid-program: epoch 2.
    cmd_tx
        .send(Li80Command::LoseDatum {
            reason: "test".into(),
        })
        .unwrap();
    dev.send(&nmea("POS,8,8000,4,87,0")).await;
    let lost_2 = types::DATUM_NOT_RUNS | (2 << types::DATUM_EPOCH_SHIFT);
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (8, 4, 87, epoch_1, true),
    );
    expect_datum(&mut rx, 2, false).await;
    dev.send(&nmea("POS,9,9000,5,87,0")).await;
    check_position(
        &next_sample(&mut rx).await,
        n_air,
        (9, 5, 87, lost_2, false),
    );
    cancel.cancel();
    dev.expect("STREAM OFF\n").await;
    dev.send("OK\r\n").await;
    task.await.unwrap();
}

/// Streams `secs` seconds of `$POS` lines at `rate_hz`, written `rate_hz / 1000` at a time
/// every millisecond (a USB serial adapter's frames), then stops the driver; returns the
/// samples in arrival order.
async fn stream_for(rate_hz: u32, secs: u32) -> Vec<Sample> {
    let (tx, mut rx) = mpsc::channel(1 << 20);
    let (socket, open) = socket();
    let cancel = CancellationToken::new();
    let cfg = Li80Config {
        rate_hz,
        ..config()
    };
    let (driver, path) = li80(&cfg, HostClock::new(), tx);
    let mut dev = socket.plug();
    let task = tokio::spawn(run(driver, path, open, cancel.clone()));
    let env = "ENV,0,500,20.00,101325,50.0,20.00";
    answer_setup_at(&mut dev, rate_hz, "", env, true).await;
    let per_ms = rate_hz / 1000;
    let mut seq = 0u32;
    for _ in 0..secs * 1000 {
        let mut chunk = String::new();
        for _ in 0..per_ms {
            seq += 1;
            let t_us = u64::from(seq) * 1_000_000 / u64::from(rate_hz);
            chunk += &nmea(&format!("POS,{seq},{t_us},{seq},80,0"));
        }
        dev.send(&chunk).await;
        tokio::time::sleep(std::time::Duration::from_millis(1)).await;
    }
    cancel.cancel();
    dev.expect("STREAM OFF\n").await;
    dev.send("OK\r\n").await;
    task.await.unwrap();
    let mut samples = Vec::new();
    while let Ok(ev) = rx.try_recv() {
        if let DriverEvent::Sample(s) = ev
            && matches!(s.values, SampleValues::Position { .. })
        {
            samples.push(s);
        }
    }
    samples
}

/// Read coalescing (docs/design.md, "Where the daemon's CPU goes"): at 1 kHz and at 5 kHz the
/// driver reads about once per coalescing tick (20 ms) plus a probe read every 100 ms,
/// 60-90 reads a second whatever the rate, not once per device write (1000 a second); every
/// sample arrives once, in order. A read is told by the arrival time it gives all its samples
/// (the host clock, which runs on while tokio's clock is paused).
#[tokio::test(start_paused = true)]
async fn a_stream_is_read_about_once_per_coalescing_tick_whatever_its_rate() {
    assert_eq!(crate::read_coalesce(), std::time::Duration::from_millis(20));
    for rate_hz in [1000, 5000] {
        let secs = 2;
        let samples = stream_for(rate_hz, secs).await;
        let seqs: Vec<u64> = samples.iter().map(|s| s.seq).collect();
        let want: Vec<u64> = (1..=u64::from(rate_hz * secs)).collect();
        assert!(seqs == want, "{rate_hz} Hz: samples lost or out of order");
        let mut reads = 0;
        for w in samples.windows(2) {
            reads += usize::from(w[1].host_ns != w[0].host_ns);
        }
        let per_s = reads as f64 / f64::from(secs);
        assert!(
            // 5 kHz sends about 4 kB a tick: a read of 3 KiB or more is read again at once.
            (50.0..=95.0).contains(&per_s),
            "{rate_hz} Hz: {per_s} reads a second"
        );
    }
}
