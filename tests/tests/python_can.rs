//! An independent check of our SLCAN reading: python-can's own `slcan` interface (a peer
//! nobody here wrote) encodes the trigger frames; our SLCAN trigger driver decodes them.
//!
//! Which side is the adapter: python-can's `slcan` bus and our driver are both *host* sides
//! of an SLCAN adapter (both send `C`/`S6`/`O`). A real adapter relays frames between the CAN
//! bus and the host, and python-can's transmit lines `t<iii><l><dd…>\r` have exactly the form
//! an adapter delivers received frames in. So the test plays the adapter between two ptys:
//! it acknowledges our driver's `C`/`S6`/`O` with `\r`, and once our channel is open it
//! passes python-can's frame lines through byte for byte (dropping python-can's own host
//! commands, which a real adapter would execute, not forward). What our decoder reads is thus
//! python-can's encoding, and the payloads are packed in Python from the data sheet.

use std::os::fd::AsFd;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use drivers::HostClock;
use hil::{Collected, collect_until, finish, nonblocking, relay_write};
use protocol::RejectKind;
use tokio_util::sync::CancellationToken;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_can_slcan_frames_are_read_by_our_trigger_driver() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("slcan");
    let py_side = hil::pty().unwrap();
    let our_side = hil::pty().unwrap();
    hil::point_link(&link, &our_side.path).unwrap();
    nonblocking(&py_side.master);
    nonblocking(&our_side.master);
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let relay = std::thread::spawn(move || {
        let (mut from_py, mut from_us) = (Vec::new(), Vec::new());
        let mut pending: Vec<u8> = Vec::new();
        let mut open = false;
        let mut buf = [0u8; 4096];
        let mut our_commands = Vec::new();
        while !stop2.load(Ordering::Relaxed) {
            if let Ok(n) = nix::unistd::read(py_side.master.as_fd(), &mut buf) {
                for &b in &buf[..n] {
                    if b == b'\r' {
                        if matches!(from_py.first(), Some(b't' | b'T')) {
                            pending.extend_from_slice(&from_py);
                            pending.push(b'\r');
                        }
                        from_py.clear();
                    } else {
                        from_py.push(b);
                    }
                }
            }
            if let Ok(n) = nix::unistd::read(our_side.master.as_fd(), &mut buf) {
                for &b in &buf[..n] {
                    if b == b'\r' {
                        let cmd = String::from_utf8_lossy(&from_us).to_string();
                        match cmd.as_str() {
                            "O" => open = true,
                            "C" => open = false,
                            _ => {}
                        }
                        our_commands.push(cmd);
                        from_us.clear();
                        relay_write(&our_side.master, b"\r");
                    } else {
                        from_us.push(b);
                    }
                }
            }
            if open && !pending.is_empty() {
                relay_write(&our_side.master, &pending);
                pending.clear();
            }
            std::thread::sleep(Duration::from_micros(500));
        }
        our_commands
    });

    let (tx, mut rx) = tokio::sync::mpsc::channel(1000);
    let cancel = CancellationToken::new();
    let cfg = drivers::SlcanConfig {
        port: link.display().to_string(),
        can_id: 0x181,
    };
    let task = drivers::spawn_slcan(cfg, HostClock::new(), tx, cancel.clone());
    let mut c = Collected::default();
    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(10), |c| !c
            .connected
            .is_empty())
        .await,
        "{:?}",
        c.errors
    );

    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/python/slcan_peer.py");
    let py_path = py_side.path.clone();
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new("python3")
            .arg(script)
            .arg(&py_path)
            .output()
    })
    .await
    .unwrap()
    .expect("python3 must be installed (with python-can: pip install python-can)");
    assert!(
        out.status.success(),
        "python-can peer failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let sent = report["sent"].as_array().unwrap().clone();
    assert_eq!(sent.len(), 18);

    assert!(
        collect_until(&mut rx, &mut c, Duration::from_secs(10), |c| c
            .triggers
            .len()
            >= sent.len())
        .await
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    finish(cancel, task, &mut rx, &mut c).await;
    stop.store(true, Ordering::Relaxed);
    let ours = relay.join().unwrap();
    assert_eq!(&ours[..3], ["C", "S6", "O"]);

    assert_eq!(
        c.triggers.len(),
        sent.len(),
        "frames of other ids or extended frames must be ignored"
    );
    for (t, s) in c.triggers.iter().zip(&sent) {
        let event = serde_json::to_value(t.event).unwrap();
        let code = match event.as_str().unwrap() {
            "motion_start" => 1,
            "exact_stop" => 2,
            "dwell_end" => 3,
            "program_start" => 4,
            "program_end" => 5,
            "feed_hold" => 6,
            other => panic!("{other}"),
        };
        assert_eq!(code, s["event"].as_u64().unwrap());
        assert_eq!(t.pose as u64, s["pose"].as_u64().unwrap());
        assert_eq!(t.nc_ms as u64, s["nc_ms"].as_u64().unwrap());
    }
    let k = c.counters.unwrap();
    assert_eq!(k.samples, sent.len() as u64);
    assert_eq!(k.rejections.get(&RejectKind::BadLength), Some(&1), "{k:?}");
    assert_eq!(k.rejections.values().sum::<u64>(), 1);
}

/// The other direction: python-can's `slcan` interface as the host of our simulated adapter.
/// python-can sends its own open sequence (`C`, `S6`, `O`); the scenario starts the CNC program
/// when the channel opens; every trigger frame the simulation sent must reach python-can with
/// the payload of the data sheet (packed here by hand, little-endian).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_can_host_reads_the_simulated_slcan_adapter() {
    hil::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let mut sc = sim::Scenario::demo();
    sc.program.poses.truncate(3);
    sc.program.move_s = 0.05;
    sc.program.dwell_s = 0.1;
    sc.program.start = sim::ProgramStart::OnCanOpen;
    sc.program.start_delay_s = 0.3;
    let sim = sim::Sim::start(sc, dir.path()).unwrap();
    let port = sim.port(sim::Device::Trigger);
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/python/slcan_host.py");
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new("python3")
            .arg(script)
            .arg(&port)
            .arg("20")
            .output()
    })
    .await
    .unwrap()
    .expect("python3 must be installed (with python-can: pip install python-can)");
    assert!(
        out.status.success(),
        "python-can host failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let frames: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout).unwrap();
    let rec = sim.record();
    let sent: Vec<_> = rec
        .trigger
        .events
        .iter()
        .filter(|e| e.fate == sim::TriggerFate::Sent)
        .collect();
    assert_eq!(
        sent.len(),
        2 + 3 * 3,
        "program start, 3 poses × 3 events, program end"
    );
    assert_eq!(frames.len(), sent.len(), "{frames:?}");
    for (f, s) in frames.iter().zip(&sent) {
        assert_eq!(f["id"].as_u64(), Some(0x181));
        assert_eq!(f["extended"].as_bool(), Some(false));
        let mut want = vec![s.event as u8, 0];
        want.extend_from_slice(&s.pose.to_le_bytes());
        want.extend_from_slice(&s.nc_ms.to_le_bytes());
        let want: String = want.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(f["data"].as_str(), Some(want.as_str()));
    }
    sim.shutdown().await;
}
