//! CNC exact-stop triggers from SLCAN (serial) or SocketCAN, decoded by the same code.
//!
//! Both transports turn what they receive into a [`protocol::slcan::CanFrame`] and hand it to
//! [`trigger_from_frame`]: frames with another identifier (or extended frames) are ignored,
//! frames with the configured identifier must carry a valid trigger payload
//! (instruments.md §4) or are counted as rejections.

use std::time::Duration;

use protocol::can::{TriggerError, TriggerFrame};
use protocol::slcan::{CanFrame, Decoder, Message};
use protocol::{Decoded, RejectKind};

use crate::link::{Acq, Device, Handler, Link, SessionError};
use crate::{Instrument, Trigger};

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct SlcanConfig {
    pub port: String,
    pub can_id: u32,
}

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct SocketCanConfig {
    pub interface: String,
    pub can_id: u32,
}

/// The trigger carried by `frame`: `Ok(None)` when the frame is not ours (another identifier
/// or an extended frame), `Err` when it is ours but its payload is not a trigger.
pub fn trigger_from_frame(
    frame: &CanFrame,
    can_id: u32,
    host_ns: u64,
) -> Result<Option<Trigger>, TriggerError> {
    if frame.extended || frame.id != can_id {
        return Ok(None);
    }
    let t = TriggerFrame::decode(&frame.data)?;
    Ok(Some(Trigger {
        event: t.event,
        pose: t.pose,
        nc_ms: t.nc_ms,
        host_ns,
    }))
}

/// The rejection kind a bad trigger payload is counted under.
pub fn reject_kind(e: &TriggerError) -> RejectKind {
    match e {
        TriggerError::BadDlc(_) => RejectKind::BadLength,
        TriggerError::UnknownEvent(_) => RejectKind::UnknownRecord,
        TriggerError::Reserved(_) => RejectKind::Malformed,
    }
}

/// The one path every received CAN frame takes, whichever the transport.
fn handle_frame(acq: &mut Acq, frame: &CanFrame, can_id: u32, host_ns: u64) {
    if !acq.accepting {
        return;
    }
    match trigger_from_frame(frame, can_id, host_ns) {
        Ok(Some(t)) => acq.emit_trigger(t),
        Ok(None) => {}
        Err(e) => {
            tracing::warn!(port = %acq.port, id = frame.id, "bad trigger frame: {e}");
            acq.reject(reject_kind(&e), frame.data.len());
        }
    }
}

struct Slcan {
    cfg: SlcanConfig,
    acq: Acq,
}

const ACK: &str = "\r";
const NACK: &str = "\x07";

impl Handler for Slcan {
    type Dec = Decoder;

    fn on_item(&mut self, item: Decoded<Message>, host_ns: u64) -> Option<String> {
        match item {
            Decoded::Reject(r) => self.acq.reject(r.kind, r.bytes),
            Decoded::Frame(Message::Frame(f)) => {
                handle_frame(&mut self.acq, &f, self.cfg.can_id, host_ns)
            }
            Decoded::Frame(Message::Ack) => {
                self.acq.counters.answers += 1;
                return Some(ACK.into());
            }
            Decoded::Frame(Message::Nack) => {
                self.acq.counters.answers += 1;
                return Some(NACK.into());
            }
            Decoded::Frame(Message::Other(o)) => {
                tracing::debug!(port = %self.acq.port, "SLCAN says {o:?}")
            }
        }
        None
    }
}

impl Device for Slcan {
    fn acq(&mut self) -> &mut Acq {
        &mut self.acq
    }
    fn baud(&self) -> u32 {
        115_200
    }
    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }
    fn idle_timeout(&self) -> Duration {
        // Triggers come when the machine moves; silence is normal. A vanished port still
        // shows as a read error.
        Duration::from_secs(24 * 3600)
    }
    async fn stop(&mut self, link: &mut Link<Decoder>) -> Result<(), SessionError> {
        link.expect(self, "C\r", |a| a == ACK || a == NACK)
            .await
            .map(drop)
    }

    async fn setup(&mut self, link: &mut Link<Decoder>) -> Result<String, SessionError> {
        // Close first: the channel may be open from an earlier run (a nack just means it was
        // closed already).
        link.expect(self, "C\r", |a| a == ACK || a == NACK).await?;
        link.reset_decoder();
        link.expect(self, "S6\r", |a| a == ACK).await?;
        self.acq.accepting = true;
        link.expect(self, "O\r", |a| a == ACK).await?;
        Ok(format!(
            "SLCAN adapter at 500 kbit/s, trigger id {:#05x}",
            self.cfg.can_id
        ))
    }
}

pub fn spawn_slcan(
    cfg: SlcanConfig,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let acq = Acq::new(Instrument::Trigger, &cfg.port, 32, 32, clock, tx);
    tokio::spawn(crate::link::run(Slcan { cfg, acq }, cancel))
}

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

pub fn spawn_socketcan(
    cfg: SocketCanConfig,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut acq = Acq::new(Instrument::Trigger, &cfg.interface, 32, 32, clock, tx);
        let mut backoff = Duration::from_millis(100);
        while !cancel.is_cancelled() {
            match socketcan::tokio::CanSocket::open(&cfg.interface) {
                Err(e) => acq.error(format!("cannot open CAN interface {}: {e}", cfg.interface)),
                Ok(sock) => {
                    backoff = Duration::from_millis(100);
                    acq.connected(format!("SocketCAN {}", cfg.interface));
                    acq.accepting = true;
                    loop {
                        let r = tokio::select! {
                            _ = cancel.cancelled() => return,
                            r = sock.read_frame() => r,
                        };
                        match r {
                            Ok(f) => {
                                let host_ns = acq.clock.now_ns();
                                match from_socketcan(&f) {
                                    Some(cf) => handle_frame(&mut acq, &cf, cfg.can_id, host_ns),
                                    None if matches!(f, socketcan::CanFrame::Error(_)) => {
                                        acq.counters.device_errors += 1
                                    }
                                    None => {}
                                }
                            }
                            Err(e) => {
                                acq.disconnected(format!("read failed: {e}"));
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
        acq.tick(true);
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::can::TriggerEvent;

    fn frame(id: u32, extended: bool, data: Vec<u8>) -> CanFrame {
        CanFrame {
            id,
            extended,
            data,
            timestamp_ms: None,
        }
    }

    #[test]
    fn trigger_payload_by_hand() {
        // Exact stop (2), pose 0x0102 = 258, NC clock 0x04030201 ms, little-endian.
        let f = frame(0x181, false, vec![2, 0, 0x02, 0x01, 0x01, 0x02, 0x03, 0x04]);
        let t = trigger_from_frame(&f, 0x181, 7).unwrap().unwrap();
        assert_eq!(
            t,
            Trigger {
                event: TriggerEvent::ExactStop,
                pose: 258,
                nc_ms: 0x0403_0201,
                host_ns: 7
            }
        );
    }

    #[test]
    fn other_ids_and_extended_frames_are_not_ours() {
        let data = vec![2, 0, 1, 0, 0, 0, 0, 0];
        assert_eq!(
            trigger_from_frame(&frame(0x182, false, data.clone()), 0x181, 0),
            Ok(None)
        );
        assert_eq!(
            trigger_from_frame(&frame(0x181, true, data), 0x181, 0),
            Ok(None)
        );
    }

    #[test]
    fn bad_payloads_are_errors_with_their_kind() {
        let e = trigger_from_frame(&frame(0x181, false, vec![2, 0, 1]), 0x181, 0).unwrap_err();
        assert_eq!(reject_kind(&e), RejectKind::BadLength);
        let e = trigger_from_frame(&frame(0x181, false, vec![9, 0, 1, 0, 0, 0, 0, 0]), 0x181, 0)
            .unwrap_err();
        assert_eq!(reject_kind(&e), RejectKind::UnknownRecord);
        let e = trigger_from_frame(&frame(0x181, false, vec![1, 5, 1, 0, 0, 0, 0, 0]), 0x181, 0)
            .unwrap_err();
        assert_eq!(reject_kind(&e), RejectKind::Malformed);
    }

    #[test]
    fn socketcan_frames_take_the_slcan_path() {
        use socketcan::EmbeddedFrame;
        let id = socketcan::StandardId::new(0x181).unwrap();
        let sc = socketcan::CanFrame::new(id, &[4, 0, 0, 0, 0x10, 0, 0, 0]).unwrap();
        let cf = from_socketcan(&sc).unwrap();
        assert_eq!(cf, frame(0x181, false, vec![4, 0, 0, 0, 0x10, 0, 0, 0]));
        let t = trigger_from_frame(&cf, 0x181, 1).unwrap().unwrap();
        assert_eq!(
            (t.event, t.pose, t.nc_ms),
            (TriggerEvent::ProgramStart, 0, 16)
        );
        // Through the shared handler: counted as a trigger.
        let (tx, mut rx) = tokio::sync::mpsc::channel(4);
        let mut acq = Acq::new(
            Instrument::Trigger,
            "can0",
            32,
            32,
            crate::HostClock::new(),
            tx,
        );
        acq.accepting = true;
        handle_frame(&mut acq, &cf, 0x181, 1);
        handle_frame(&mut acq, &frame(0x181, false, vec![1]), 0x181, 2);
        assert_eq!(acq.counters.samples, 1);
        assert_eq!(
            acq.counters.rejections.get(&RejectKind::BadLength),
            Some(&1)
        );
        assert!(matches!(rx.try_recv(), Ok(crate::DriverEvent::Trigger(t)) if t.pose == 0));
    }
}
