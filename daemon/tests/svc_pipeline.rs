//! The pipeline on synthetic driver events: steady values at the programmed plateaus, status
//! counters, and the end of a run at program end.

use std::sync::{Arc, Mutex};

use detect::PoseEngine;
use drivers::{DriverEvent, HostClock, Instrument, Sample, SampleValues, Trigger};
use metrolog::acquire::counts::RunCounts;
use metrolog::acquire::pipeline::{Pipeline, PipelineConfig, Status, StopReason};
use metrolog::acquire::sink::{Closed, DetectOnly, EventSink};
use metrolog_log::DetectorSettings;
use metrolog_log::topics::PoseMsg;
use protocol::can::TriggerEvent;
use types::PoseStatus;

#[derive(Default)]
struct Seen {
    samples: usize,
    triggers: usize,
    ticks: usize,
    finished: bool,
}

/// The real pose engine, with a count of what went through it.
struct Counting(DetectOnly, Arc<Mutex<Seen>>);

impl EventSink for Counting {
    fn record(&mut self, ev: &DriverEvent, now_ns: u64) -> anyhow::Result<Vec<PoseMsg>> {
        match ev {
            DriverEvent::Sample(_) => self.1.lock().unwrap().samples += 1,
            DriverEvent::Trigger(_) => self.1.lock().unwrap().triggers += 1,
            _ => {}
        }
        self.0.record(ev, now_ns)
    }
    fn tick(&mut self, _: u64) -> anyhow::Result<()> {
        self.1.lock().unwrap().ticks += 1;
        Ok(())
    }
    fn finish(self: Box<Self>, now_ns: u64) -> anyhow::Result<Closed> {
        self.1.lock().unwrap().finished = true;
        Box::new(self.0).finish(now_ns)
    }
    fn counts(&self) -> &RunCounts {
        self.0.counts()
    }
}

/// Deterministic uniform noise in [-1, 1) (xorshift64).
struct Noise(u64);
impl Noise {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

fn li80(seq: u64, t_ns: u64, position_um: f64) -> DriverEvent {
    DriverEvent::Sample(Sample {
        instrument: Instrument::Interferometer,
        seq,
        device_t_us: t_ns / 1000,
        host_ns: t_ns,
        fitted_ns: t_ns,
        valid: true,
        values: SampleValues::Position {
            raw_nm: (position_um * 1e3) as i64,
            position_um,
            sig: 90,
            flags: 0,
        },
    })
}

fn psd(seq: u64, t_ns: u64, x_um: f64, y_um: f64) -> DriverEvent {
    DriverEvent::Sample(Sample {
        instrument: Instrument::Psd,
        seq,
        device_t_us: t_ns / 1000,
        host_ns: t_ns,
        fitted_ns: t_ns,
        valid: true,
        values: SampleValues::Psd {
            x_um,
            y_um,
            sum_pa: 1e6,
            head_c: 21.0,
        },
    })
}

fn trig(event: TriggerEvent, pose: u16, t_ns: u64) -> DriverEvent {
    DriverEvent::Trigger(Trigger {
        event,
        pose,
        nc_ms: (t_ns / 1_000_000) as u32,
        host_ns: t_ns,
    })
}

/// A program of `poses` plateaus, LI-80 and PSD at 1 kHz: pose k stands at 1000·k µm (PSD at
/// (k, -k) µm) with ±0.05 µm uniform noise, 0.3 s moves (linear ramps), 0.5 s dwells.
fn program(poses: u16) -> Vec<DriverEvent> {
    let mut ev = Vec::new();
    let mut noise = Noise(0x9E37_79B9_7F4A_7C15);
    let t0 = 1_000_000_000_000u64;
    let dt = 1_000_000u64; // 1 ms
    let mut t = t0;
    let mut seq = 0u64;
    let mut pos = 0.0f64;
    ev.push(trig(TriggerEvent::ProgramStart, 0, t));
    for k in 1..=poses {
        let target = 1000.0 * k as f64;
        ev.push(trig(TriggerEvent::MotionStart, k, t));
        let from = pos;
        for i in 0..300 {
            pos = from + (target - from) * (i + 1) as f64 / 300.0;
            ev.push(li80(seq, t, pos + 0.05 * noise.next()));
            ev.push(psd(seq, t, pos / 1000.0, -pos / 1000.0));
            seq += 1;
            t += dt;
        }
        ev.push(trig(TriggerEvent::ExactStop, k, t));
        for _ in 0..500 {
            ev.push(li80(seq, t, target + 0.05 * noise.next()));
            ev.push(psd(
                seq,
                t,
                k as f64 + 0.05 * noise.next(),
                -(k as f64) + 0.05 * noise.next(),
            ));
            seq += 1;
            t += dt;
        }
        ev.push(trig(TriggerEvent::DwellEnd, k, t));
    }
    ev.push(trig(TriggerEvent::ProgramEnd, 0, t));
    ev
}

fn pipeline(seen: &Arc<Mutex<Seen>>, stop_at_program_end: bool) -> Pipeline {
    let engine = PoseEngine::new(&DetectorSettings::default().with_samples(150)).unwrap();
    Pipeline::new(
        PipelineConfig {
            instruments: vec![
                Instrument::Interferometer,
                Instrument::Psd,
                Instrument::Trigger,
            ],
            stop_at_program_end,
            keep_poses: true,
            connect: None,
            disk_alarm: None,
            trajectory: Vec::new(),
            datum: None,
        },
        HostClock::new(),
        Box::new(Counting(DetectOnly::new(engine), seen.clone())),
    )
}

#[test]
fn steady_values_sit_on_the_programmed_plateaus() {
    let seen = Arc::new(Mutex::new(Seen::default()));
    let mut p = pipeline(&seen, false);
    let events = program(5);
    let n_events = events.len();
    for e in events {
        p.handle(e);
    }
    let out = p.finish(StopReason::Cancelled, 0).unwrap();
    let seen = seen.lock().unwrap();
    assert!(seen.finished);
    assert_eq!(seen.samples + seen.triggers, n_events);
    assert_eq!(seen.triggers, 5 * 3 + 2);
    for inst in [Instrument::Interferometer, Instrument::Psd] {
        let values: Vec<&PoseMsg> = out.poses.iter().filter(|v| v.instrument == inst).collect();
        assert_eq!(values.len(), 5, "{inst:?}: {values:?}");
        for (k, v) in values.iter().enumerate() {
            assert_eq!(v.pose, k as u32 + 1);
            assert_eq!(v.status, PoseStatus::Ok);
            assert_eq!(v.n, 150);
            // Uniform ±0.05 µm: σ = 0.05/√3, mean of 150 within 5σ/√150 = 0.012 µm.
            let tol = 0.012;
            let expected: Vec<(&str, f64)> = match inst {
                Instrument::Interferometer => vec![("position_um", 1000.0 * (k + 1) as f64)],
                _ => vec![("x_um", (k + 1) as f64), ("y_um", -((k + 1) as f64))],
            };
            for (ch, e) in expected {
                let m = v.mean[ch];
                assert!(
                    (m - e).abs() < tol,
                    "{inst:?} pose {} {ch}: {m} vs {e}",
                    v.pose
                );
            }
        }
    }
    let st = &out.status;
    // The pose engine runs a detector per instrument; the CapBall sent nothing, so its five
    // dwells are reported as device_away, never invented.
    assert_eq!(st.poses, 15);
    assert_eq!(st.poses_ok, 10);
    let cb: Vec<&PoseMsg> = out
        .poses
        .iter()
        .filter(|v| v.instrument == Instrument::Capball)
        .collect();
    assert_eq!(cb.len(), 5);
    assert!(
        cb.iter()
            .all(|v| v.status == PoseStatus::DeviceAway && v.n == 0)
    );
    assert_eq!(
        st.instruments[&Instrument::Interferometer].received,
        5 * 800
    );
    assert_eq!(st.instruments[&Instrument::Trigger].received, 17);
    assert_eq!(st.instruments[&Instrument::Psd].poses.get("ok"), Some(&5));
    assert_eq!(st.last_pose, 5);
}

#[test]
fn run_ends_at_program_end_when_configured() {
    let seen = Arc::new(Mutex::new(Seen::default()));
    let p = pipeline(&seen, true);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let out = rt.block_on(async move {
        let (tx, rx) = tokio::sync::mpsc::channel(1 << 16);
        for e in program(3) {
            tx.try_send(e).unwrap();
        }
        // Events after program end belong to no run of this program.
        tx.try_send(li80(999_999, 2_000_000_000_000, 0.0)).unwrap();
        let (ptx, prx) = tokio::sync::watch::channel(Status::default());
        let cancel = tokio_util::sync::CancellationToken::new();
        let out = p
            .run(
                rx,
                cancel,
                metrolog::acquire::service::Notifier::from_env(),
                ptx,
            )
            .await
            .unwrap();
        assert_eq!(prx.borrow().poses_ok, 6);
        drop(tx);
        out
    });
    assert_eq!(out.reason, StopReason::ProgramEnd);
    assert_eq!(out.status.poses_ok, 6);
    assert_eq!(
        out.status.instruments[&Instrument::Interferometer].received,
        3 * 800
    );
    let seen = seen.lock().unwrap();
    assert!(seen.finished);
}

#[test]
fn a_dwell_without_samples_is_reported_not_invented() {
    let seen = Arc::new(Mutex::new(Seen::default()));
    let mut p = pipeline(&seen, false);
    let t = 5_000_000_000u64;
    p.handle(trig(TriggerEvent::ProgramStart, 0, t));
    p.handle(trig(TriggerEvent::MotionStart, 1, t + 1));
    p.handle(trig(TriggerEvent::ExactStop, 1, t + 2));
    p.handle(trig(TriggerEvent::DwellEnd, 1, t + 500_000_000));
    let out = p.finish(StopReason::Cancelled, 0).unwrap();
    let li: Vec<_> = out
        .poses
        .iter()
        .filter(|v| v.instrument == Instrument::Interferometer)
        .collect();
    assert_eq!(li.len(), 1);
    assert_eq!(li[0].status, PoseStatus::DeviceAway);
    assert_eq!(li[0].n, 0);
    assert_eq!(out.status.poses_ok, 0);
}
