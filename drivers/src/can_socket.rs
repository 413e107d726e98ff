//! CNC triggers from a SocketCAN interface (cargo feature `socketcan`, on by default).
//!
//! What is SocketCAN's here is thin: opening the interface and turning its frames into the
//! SLCAN path's [`CanFrame`] ([`from_socketcan`]). The loop — open, report, read, count,
//! reopen with backoff — reads any [`FrameSource`] and hands frames to the trigger path the
//! SLCAN driver uses ([`frame_reading`]), so the tests run it on an in-memory source.

use std::io;
use std::sync::Arc;
use std::time::Duration;

use protocol::slcan::CanFrame;
use tokio_util::sync::CancellationToken;

use crate::sample_path::SamplePath;
use crate::trigger::{SlcanFrames, SocketCanConfig, frame_reading, trigger_path};
use crate::{DriverError, EventSender, HostClock};

/// A SocketCAN frame as the SLCAN path sees it (`None` for remote and error frames).
pub fn from_socketcan(f: &socketcan::CanFrame) -> Option<CanFrame> {
    use socketcan::{EmbeddedFrame, Frame};
    match f {
        socketcan::CanFrame::Data(d) => Some(CanFrame {
            id: d.raw_id(),
            extended: d.is_extended(),
            data: d.data().to_vec(),
            timestamp_ms: None,
        }),
        _ => None,
    }
}

/// What one read of a CAN interface gives.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Received {
    /// A data frame.
    Data(CanFrame),
    /// An error frame of the bus: counted as a device error.
    BusError,
    /// A remote frame: not ours.
    Other,
}

impl Received {
    fn of(f: &socketcan::CanFrame) -> Received {
        match from_socketcan(f) {
            Some(cf) => Received::Data(cf),
            None if matches!(f, socketcan::CanFrame::Error(_)) => Received::BusError,
            None => Received::Other,
        }
    }
}

/// An open CAN interface, read one frame at a time.
pub(crate) trait FrameSource: Send {
    /// The next frame; cancel-safe.
    fn receive(&mut self) -> impl Future<Output = io::Result<Received>> + Send;
}

impl FrameSource for socketcan::tokio::CanSocket {
    async fn receive(&mut self) -> io::Result<Received> {
        self.read_frame().await.map(|f| Received::of(&f))
    }
}

/// Start the SocketCAN trigger driver task. It runs until `cancel` fires, reopening the
/// interface with backoff.
pub fn spawn_socketcan(
    cfg: SocketCanConfig,
    clock: HostClock,
    tx: EventSender,
    cancel: CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let path = trigger_path(&cfg.interface, cfg.can_id, clock, tx);
    let interface = cfg.interface.clone();
    let open = move || socketcan::tokio::CanSocket::open(&interface);
    tokio::spawn(run(path, cfg, open, cancel))
}

/// The trigger task on a CAN interface: open it with `open`, report it connected, hand every
/// frame down the trigger path; on a read error report the loss, back off (100 ms doubling to
/// 2 s) and open it again. A cancel while reading ends the task at once.
async fn run<S: FrameSource>(
    mut path: SamplePath<SlcanFrames>,
    cfg: SocketCanConfig,
    mut open: impl FnMut() -> io::Result<S> + Send,
    cancel: CancellationToken,
) {
    let mut backoff = Duration::from_millis(100);
    while !cancel.is_cancelled() {
        match open() {
            Err(e) => path.reporter.error(DriverError::CanInterface {
                interface: cfg.interface.clone(),
                cause: Arc::new(e),
            }),
            Ok(mut source) => {
                backoff = Duration::from_millis(100);
                let identity = format!("SocketCAN {}", cfg.interface);
                path.reporter.connected(identity, &path.stamper);
                path.reporter.accepting = true;
                loop {
                    let r = tokio::select! {
                        _ = cancel.cancelled() => return,
                        r = source.receive() => r,
                    };
                    match r {
                        Ok(f) => take(&mut path, f, cfg.can_id),
                        Err(e) => {
                            let reason = DriverError::ReadFailed { cause: e.into() };
                            path.reporter.disconnected(reason, &path.stamper);
                            break;
                        }
                    }
                }
            }
        }
        tokio::select! {
            _ = cancel.cancelled() => break,
            _ = tokio::time::sleep(backoff) => {}
        }
        backoff = (backoff * 2).min(Duration::from_secs(2));
    }
    path.tick(true);
}

/// One received frame down the trigger path; error frames are device errors.
fn take(path: &mut SamplePath<SlcanFrames>, f: Received, can_id: u32) {
    let host_ns = path.reporter.clock.now_ns();
    match f {
        Received::Data(cf) => {
            if let Some(r) = frame_reading(&cf, can_id, host_ns) {
                path.take_reading(r, host_ns)
            }
        }
        Received::BusError => path.reporter.counters.device_errors += 1,
        Received::Other => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_port::next_event;
    use crate::{DriverEvent, Instrument};
    use protocol::RejectKind;
    use protocol::can::TriggerEvent;
    use tokio::sync::mpsc;

    fn frame(id: u32, data: &[u8]) -> CanFrame {
        CanFrame {
            id,
            extended: false,
            data: data.to_vec(),
            timestamp_ms: None,
        }
    }

    #[test]
    fn socketcan_frames_take_the_slcan_path() {
        use socketcan::EmbeddedFrame;
        let id = socketcan::StandardId::new(0x181).unwrap();
        let sc = socketcan::CanFrame::new(id, &[4, 0, 0, 0, 0x10, 0, 0, 0]).unwrap();
        let cf = from_socketcan(&sc).unwrap();
        assert_eq!(cf, frame(0x181, &[4, 0, 0, 0, 0x10, 0, 0, 0]));
        let t = crate::trigger_from_frame(&cf, 0x181, 1).unwrap().unwrap();
        assert_eq!(
            (t.event, t.pose, t.nc_ms),
            (TriggerEvent::ProgramStart, 0, 16)
        );
        let ext = socketcan::ExtendedId::new(0x181).unwrap();
        let sc_ext = socketcan::CanFrame::new(ext, &[4, 0, 0, 0, 0x10, 0, 0, 0]).unwrap();
        assert!(from_socketcan(&sc_ext).unwrap().extended);
        let remote = socketcan::CanFrame::new_remote(id, 8).unwrap();
        assert_eq!(Received::of(&remote), Received::Other);
        // Through the shared path: counted as a trigger; a bad payload as a rejection.
        let (tx, mut rx) = mpsc::channel(4);
        let mut path = trigger_path("can0", 0x181, HostClock::new(), tx);
        path.reporter.accepting = true;
        take(&mut path, Received::of(&sc), 0x181);
        let bad = socketcan::CanFrame::new(id, &[1]).unwrap();
        take(&mut path, Received::of(&bad), 0x181);
        assert_eq!(path.reporter.counters.samples, 1);
        assert_eq!(
            path.reporter
                .counters
                .rejections
                .get(&RejectKind::BadLength),
            Some(&1)
        );
        assert!(matches!(rx.try_recv(), Ok(DriverEvent::Trigger(t)) if t.pose == 0));
    }

    /// An in-memory CAN interface: what the test sends is what it reads; `Err` is a read
    /// failure (the interface went down).
    struct Bus(mpsc::UnboundedReceiver<io::Result<Received>>);

    impl FrameSource for Bus {
        async fn receive(&mut self) -> io::Result<Received> {
            match self.0.recv().await {
                Some(r) => r,
                None => std::future::pending().await,
            }
        }
    }

    /// The loop over an in-memory interface: a missing interface is reported and retried,
    /// triggers and bus errors are counted, a read failure reopens it, cancel ends the task.
    /// Paused time: the backoff passes as soon as nothing else can run.
    #[tokio::test(start_paused = true)]
    async fn the_loop_opens_reads_counts_and_reopens() {
        let (tx, mut rx) = mpsc::channel(64);
        let cfg = SocketCanConfig {
            interface: "can7".into(),
            can_id: 0x181,
        };
        let path = trigger_path(&cfg.interface, cfg.can_id, HostClock::new(), tx);
        let (bus1_tx, bus1) = mpsc::unbounded_channel();
        let (bus2_tx, bus2) = mpsc::unbounded_channel();
        let mut opens = vec![
            Err(io::Error::new(io::ErrorKind::NotFound, "no such device")),
            Ok(Bus(bus1)),
            Ok(Bus(bus2)),
        ]
        .into_iter();
        let open = move || opens.next().expect("three opens");
        let cancel = CancellationToken::new();
        let task = tokio::spawn(run(path, cfg, open, cancel.clone()));

        match next_event(&mut rx).await {
            DriverEvent::Error { error, port, .. } => {
                assert_eq!(port, "can7");
                assert!(
                    matches!(&error, DriverError::CanInterface { interface, .. } if interface == "can7"),
                    "{error:?}"
                );
            }
            ev => panic!("expected the open error, got {ev:?}"),
        }
        let connected = |ev: DriverEvent| match ev {
            DriverEvent::Connected {
                instrument,
                identity,
                ..
            } => {
                assert_eq!(instrument, Instrument::Trigger);
                assert_eq!(identity, "SocketCAN can7");
            }
            ev => panic!("expected Connected, got {ev:?}"),
        };
        connected(next_event(&mut rx).await);

        // Exact stop of pose 3 at NC time 0x10 ms; another identifier is not ours; a bus
        // error frame is a device error.
        let stop = frame(0x181, &[2, 0, 3, 0, 0x10, 0, 0, 0]);
        bus1_tx
            .send(Ok(Received::Data(frame(0x182, &[2, 0, 9, 0, 0, 0, 0, 0]))))
            .unwrap();
        bus1_tx.send(Ok(Received::BusError)).unwrap();
        bus1_tx.send(Ok(Received::Data(stop.clone()))).unwrap();
        match next_event(&mut rx).await {
            DriverEvent::Trigger(t) => {
                assert_eq!(
                    (t.event, t.pose, t.nc_ms),
                    (TriggerEvent::ExactStop, 3, 0x10)
                )
            }
            ev => panic!("expected the trigger, got {ev:?}"),
        }

        // The interface fails: reported lost, reopened.
        bus1_tx
            .send(Err(io::Error::other("network is down")))
            .unwrap();
        match next_event(&mut rx).await {
            DriverEvent::Disconnected { reason, .. } => {
                assert!(
                    matches!(reason, DriverError::ReadFailed { .. }),
                    "{reason:?}"
                )
            }
            ev => panic!("expected Disconnected, got {ev:?}"),
        }
        connected(next_event(&mut rx).await);
        // A connection change sends the counters at once.
        match rx.recv().await {
            Some(DriverEvent::Counters { counters: c, .. }) => {
                assert_eq!((c.samples, c.device_errors), (1, 1));
                assert_eq!((c.disconnects, c.reconnects), (1, 1));
                assert!(c.rejections.is_empty());
            }
            ev => panic!("expected the counters, got {ev:?}"),
        }
        bus2_tx.send(Ok(Received::Data(stop))).unwrap();
        assert!(matches!(next_event(&mut rx).await, DriverEvent::Trigger(t) if t.pose == 3));

        // A cancel while reading ends the task at once, without a last counters snapshot
        // (as it always did; the serial drivers send one).
        cancel.cancel();
        task.await.unwrap();
        assert!(rx.try_recv().is_err());
    }
}
