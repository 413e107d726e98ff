//! End to end through the wire: the host-side conversions of the protocol crate, applied to
//! the decoded frames, recover the scenario's true values at every pose; readings move during
//! a move and ring after the exact stop.

mod common;

use std::collections::HashMap;
use std::time::Duration;

use common::*;
use protocol::convert::{CapBallPoly, CapBallTransform, Li80Compensation, PsdReading};
use protocol::{Decoded, StreamDecoder};
use sim::scenario::PoseRow;
use sim::{Device, PoseTruth};

fn frames<D: StreamDecoder>(mut d: D, bytes: &[u8]) -> Vec<D::Frame> {
    let mut out = Vec::new();
    d.feed(bytes, |x| match x {
        Decoded::Frame(f) => out.push(f),
        Decoded::Reject(r) => panic!("rejected {r:?}"),
    });
    out
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}
fn std(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn host_conversions_recover_the_truth_at_every_pose() {
    let mut sc = quick();
    sc.time_scale = 1.0;
    sc.program.dwell_s = 0.4;
    // The conversions only: no per-visit scatter of the measuring loop (not in the per-pose
    // truth) and no cooling cycle moving during the window.
    sc.capball.truth.pose_noise_um = 0.0;
    sc.capball.truth.cyclic_drift = None;
    let row = |x: f64, y: f64, z: f64, a: f64, c: f64| PoseRow {
        pose: None,
        x_mm: x,
        y_mm: y,
        z_mm: z,
        a_deg: a,
        c_deg: c,
        move_s: None,
        dwell_s: None,
    };
    sc.program.poses = vec![
        row(101.871, 0.0, 0.0, 0.0, 0.0),
        row(399.05, 20.0, 150.0, -30.0, 90.0),
        row(198.544, -10.0, 300.0, -60.0, 270.0),
    ];
    let env = Env::start(sc.clone());
    let mut li = env.open(Device::Interferometer);
    let mut cb = env.open(Device::Capball);
    let mut psd = env.open(Device::Psd);
    ask(&mut *li, "RATE 1000\n", ends_with(b"\r\n"));
    ask(&mut *li, "DATUM\n", ends_with(b"\r\n"));
    ask(&mut *cb, "RATE 1000\n", ends_with(b"\0"));
    send(&mut *psd, "CONF:RATE 1000\n");
    send(&mut *li, "STREAM ON\n");
    send(&mut *cb, "START\n");
    send(&mut *psd, "INIT:CONT ON\n");
    env.sim().start_program();
    // Read all three ports while the program runs.
    let total = env.sim().program_duration_s() + 0.3;
    let (b_li, b_cb, b_psd) = std::thread::scope(|s| {
        let a = s.spawn(|| read_for(&mut *li, Duration::from_secs_f64(total)));
        let b = s.spawn(|| read_for(&mut *cb, Duration::from_secs_f64(total)));
        let c = s.spawn(|| read_for(&mut *psd, Duration::from_secs_f64(total)));
        (a.join().unwrap(), b.join().unwrap(), c.join().unwrap())
    });
    let rec = env.sim().record();
    let t_prog = rec.program_started_s.unwrap();
    // Program time of each sample, by sequence number, from the record.
    let when = |r: &sim::record::DeviceRecord| -> HashMap<u64, f64> {
        r.samples
            .iter()
            .map(|s| (s.seq, s.true_s - t_prog))
            .collect()
    };
    let (w_li, w_psd) = (when(&rec.interferometer), when(&rec.psd));
    // The CB-3 carries its sequence modulo 2^16 (the demo starts it near the wrap).
    let w_cb: HashMap<u16, f64> = rec
        .capball
        .samples
        .iter()
        .map(|s| (s.seq as u16, s.true_s - t_prog))
        .collect();
    let settle = sc.ringing.settle_s();
    let window = |t: &PoseTruth| (t.exact_stop_s + settle, t.dwell_end_s);

    // LI-80: (raw/n)·(1 − α(T − 20)) with the latest $ENV, minus the programmed displacement.
    let mut comp: Option<Li80Compensation> = None;
    let mut li_pts: Vec<(f64, f64)> = Vec::new();
    for l in frames(protocol::li80::Decoder::new(), &b_li) {
        match l {
            protocol::li80::Line::Env(e) => {
                comp = Some(Li80Compensation::from_env(&e, 11.7).unwrap())
            }
            protocol::li80::Line::Pos(p) => {
                let c = comp.expect("an $ENV line precedes the first $POS");
                li_pts.push((w_li[&(p.seq as u64)], c.length_at_20c_nm(p.raw_nm) / 1e3));
            }
            _ => {}
        }
    }
    let cb_t = CapBallTransform {
        t: sc.capball_transform(),
    };
    let polys = sc.capball.poly.map(|c| CapBallPoly { c });
    let mut cb_pts = Vec::new();
    for f in frames(protocol::cb3::Decoder::new(), &b_cb) {
        if let protocol::cb3::Frame::Sample(s) = f {
            let e = protocol::convert::capball_volumetric_um(&s, &polys, &cb_t);
            cb_pts.push((w_cb[&s.seq], e));
        }
    }
    let mut psd_pts = Vec::new();
    for l in frames(protocol::psd::Decoder::new(), &b_psd) {
        if let protocol::psd::Line::Data(d) = l {
            let PsdReading::Valid { x_um, y_um } = protocol::convert::psd_position(&d, 100_000)
            else {
                panic!("gated")
            };
            psd_pts.push((w_psd[&(d.seq as u64)], x_um, y_um));
        }
    }
    assert_eq!(rec.truth.len(), 3);
    eprintln!(
        "li {} ({:?}..{:?}), cb {}, psd {}, bytes {} {} {}",
        li_pts.len(),
        li_pts.first().map(|p| p.0),
        li_pts.last().map(|p| p.0),
        cb_pts.len(),
        psd_pts.len(),
        b_li.len(),
        b_cb.len(),
        b_psd.len()
    );
    for t in &rec.truth {
        let (a, b) = window(t);
        let li: Vec<f64> = li_pts
            .iter()
            .filter(|p| p.0 >= a && p.0 < b)
            .map(|p| p.1 - t.x_mm * 1e3)
            .collect();
        assert!(
            li.len() >= 150,
            "pose {}: {} LI-80 samples in the settled window",
            t.pose,
            li.len()
        );
        let dev = mean(&li);
        assert!(
            (dev - t.deviation_um).abs() < 0.03,
            "pose {}: measured {dev} µm, true {} µm",
            t.pose,
            t.deviation_um
        );
        for k in 0..3 {
            let v: Vec<f64> = cb_pts
                .iter()
                .filter(|p| p.0 >= a && p.0 < b)
                .map(|p| p.1[k])
                .collect();
            assert!(
                v.len() >= 150,
                "pose {}: {} CB-3 samples of {}",
                t.pose,
                v.len(),
                cb_pts.len()
            );
            assert!(
                (mean(&v) - t.capball_e_um[k]).abs() < 0.01,
                "pose {} e{k}: {} vs {}",
                t.pose,
                mean(&v),
                t.capball_e_um[k]
            );
        }
        let xs: Vec<f64> = psd_pts
            .iter()
            .filter(|p| p.0 >= a && p.0 < b)
            .map(|p| p.1)
            .collect();
        let ys: Vec<f64> = psd_pts
            .iter()
            .filter(|p| p.0 >= a && p.0 < b)
            .map(|p| p.2)
            .collect();
        assert!(
            (mean(&xs) - t.psd_x_um).abs() < 0.02,
            "pose {} psd x",
            t.pose
        );
        assert!(
            (mean(&ys) - t.psd_y_um).abs() < 0.02,
            "pose {} psd y",
            t.pose
        );
        // Ringing: the first 30 ms after the exact stop scatter far more than the settled part.
        let ring: Vec<f64> = li_pts
            .iter()
            .filter(|p| p.0 >= t.exact_stop_s && p.0 < t.exact_stop_s + 0.03)
            .map(|p| p.1)
            .collect();
        assert!(
            std(&ring) > 10.0 * std(&li),
            "pose {}: ringing std {} vs settled {}",
            t.pose,
            std(&ring),
            std(&li)
        );
        // Motion: the reading moves between the previous pose and this one.
        let mid = 0.5 * (t.motion_start_s + t.exact_stop_s);
        let moving: Vec<f64> = li_pts
            .iter()
            .filter(|p| (p.0 - mid).abs() < 0.005)
            .map(|p| p.1)
            .collect();
        let prev_x = if t.pose == 1 {
            0.0
        } else {
            rec.truth[t.pose as usize - 2].x_mm
        };
        let halfway = 0.5 * (prev_x + t.x_mm) * 1e3;
        assert!(
            moving
                .iter()
                .all(|m| (m - halfway).abs() < 0.2 * (t.x_mm - prev_x).abs() * 1e3 + 5.0)
        );
    }
}
