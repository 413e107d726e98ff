//! CNC exact-stop triggers from SLCAN (serial) or SocketCAN, decoded by the same code.
//!
//! Both transports turn what they receive into a [`protocol::slcan::CanFrame`] and hand it to
//! [`trigger_from_frame`]: frames with another identifier (or extended frames) are ignored,
//! frames with the configured identifier must carry a valid trigger payload
//! (instruments.md §4) or are counted as rejections. The SLCAN driver is here; the SocketCAN
//! transport (cargo feature `socketcan`) is `can_socket`, on the same [`trigger_path`].

use std::time::Duration;

use protocol::can::{TriggerError, TriggerFrame};
use protocol::slcan::{CanFrame, Decoder, Message};

use crate::sample_path::{FrameConverter, Reading, SamplePath};
use crate::serial_driver::{SerialDriver, SerialSession};
use crate::serial_link::Port;
use crate::stamper::SampleStamper;
use crate::{DriverError, EventSender, HostClock, Instrument, Trigger};

/// What the daemon configures for an SLCAN (serial) CAN adapter.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct SlcanConfig {
    pub port: String,
    pub can_id: u32,
}

/// What the daemon configures for a SocketCAN interface.
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

/// What a CAN frame means: nothing when it is not ours, else a trigger or a bad payload.
pub(crate) fn frame_reading(frame: &CanFrame, can_id: u32, host_ns: u64) -> Option<Reading> {
    match trigger_from_frame(frame, can_id, host_ns) {
        Ok(Some(t)) => Some(Reading::Trigger(t)),
        Ok(None) => None,
        Err(error) => Some(Reading::BadTrigger {
            can_id: frame.id,
            error,
            bytes: frame.data.len(),
        }),
    }
}

/// SLCAN messages to readings: data frames through [`trigger_from_frame`], acknowledgements
/// as answers.
pub(crate) struct SlcanFrames {
    port: String,
    can_id: u32,
}

const ACK: &str = "\r";
const NACK: &str = "\x07";

impl FrameConverter for SlcanFrames {
    type Decoder = Decoder;

    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }

    fn convert(&mut self, m: Message, host_ns: u64, out: &mut impl FnMut(Reading)) {
        match m {
            Message::Frame(f) => {
                if let Some(r) = frame_reading(&f, self.can_id, host_ns) {
                    out(r)
                }
            }
            Message::Ack => out(Reading::Answer(ACK.into())),
            Message::Nack => out(Reading::Answer(NACK.into())),
            Message::Other(o) => tracing::debug!(port = %self.port, "SLCAN says {o:?}"),
        }
    }
}

/// The SLCAN adapter's session: close, set 500 kbit/s, open.
struct SlcanDriver {
    can_id: u32,
}

impl SerialDriver for SlcanDriver {
    type Converter = SlcanFrames;

    fn baud(&self) -> u32 {
        115_200
    }
    fn idle_timeout(&self) -> Duration {
        // Triggers come when the machine moves; silence is normal. A vanished port still
        // shows as a read error.
        Duration::from_secs(24 * 3600)
    }
    fn coalesce(&self) -> Duration {
        // A few frames per pose: nothing to coalesce, and each frame's arrival time feeds the
        // NC clock fit that places the dwells.
        Duration::ZERO
    }
    async fn stop<P: Port>(
        &self,
        s: &mut SerialSession<'_, SlcanFrames, P>,
    ) -> Result<(), DriverError> {
        s.expect("C\r", |a| a == ACK || a == NACK).await.map(drop)
    }

    async fn setup<P: Port>(
        &self,
        s: &mut SerialSession<'_, SlcanFrames, P>,
    ) -> Result<String, DriverError> {
        // Close first: the channel may be open from an earlier run (a nack just means it was
        // closed already).
        s.expect("C\r", |a| a == ACK || a == NACK).await?;
        s.reset_decoder();
        s.expect("S6\r", |a| a == ACK).await?;
        s.start_accepting();
        s.expect("O\r", |a| a == ACK).await?;
        Ok(format!(
            "SLCAN adapter at 500 kbit/s, trigger id {:#05x}",
            self.can_id
        ))
    }
}

/// The sample path of triggers from `port` (an SLCAN port or a CAN interface).
pub(crate) fn trigger_path(
    port: &str,
    can_id: u32,
    clock: HostClock,
    tx: EventSender,
) -> SamplePath<SlcanFrames> {
    let frames = SlcanFrames {
        port: port.to_string(),
        can_id,
    };
    // Triggers carry no device sequence or clock to fit: the stamper stays unused.
    let stamper = SampleStamper::new(32, 32);
    SamplePath::new(frames, stamper, Instrument::Trigger, port, clock, tx)
}

/// Start the SLCAN trigger driver task. It runs until `cancel` fires, reconnecting with
/// backoff.
pub fn spawn_slcan(
    cfg: SlcanConfig,
    clock: HostClock,
    tx: EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let path = trigger_path(&cfg.port, cfg.can_id, clock, tx);
    let driver = SlcanDriver { can_id: cfg.can_id };
    crate::serial_driver::spawn(driver, path, cancel)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample_path::reject_kind;
    use protocol::RejectKind;
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
}
