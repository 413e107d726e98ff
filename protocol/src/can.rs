//! CNC exact-stop trigger frames (instruments.md §4): CAN 2.0A, DLC 8, little-endian.

/// CNC trigger event names (instruments.md §4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "schemars", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum TriggerEvent {
    MotionStart = 1,
    ExactStop = 2,
    DwellEnd = 3,
    ProgramStart = 4,
    ProgramEnd = 5,
    FeedHold = 6,
}

impl TriggerEvent {
    pub const ALL: [TriggerEvent; 6] = [
        TriggerEvent::MotionStart,
        TriggerEvent::ExactStop,
        TriggerEvent::DwellEnd,
        TriggerEvent::ProgramStart,
        TriggerEvent::ProgramEnd,
        TriggerEvent::FeedHold,
    ];
    /// The event of byte 0, if the data sheet defines it.
    pub fn from_code(code: u8) -> Option<TriggerEvent> {
        Self::ALL.into_iter().find(|e| *e as u8 == code)
    }
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// The decoded payload of a trigger frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TriggerFrame {
    pub event: TriggerEvent,
    /// Row of the trajectory; 0 for program start and end.
    pub pose: u16,
    /// NC clock in ms, wraps.
    pub nc_ms: u32,
}

/// Default identifier of trigger frames.
pub const DEFAULT_CAN_ID: u32 = 0x181;
/// Largest identifier of a standard (CAN 2.0A, 11-bit) frame.
pub const STANDARD_ID_MAX: u32 = 0x7FF;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TriggerError {
    #[error("trigger frame has DLC {0}, expected 8")]
    BadDlc(usize),
    #[error("unknown trigger event code {0}")]
    UnknownEvent(u8),
    #[error("reserved byte 1 is {0:#04x}, expected 0")]
    Reserved(u8),
}

impl TriggerFrame {
    pub fn decode(data: &[u8]) -> Result<TriggerFrame, TriggerError> {
        let d: &[u8; 8] = data
            .try_into()
            .map_err(|_| TriggerError::BadDlc(data.len()))?;
        let event = TriggerEvent::from_code(d[0]).ok_or(TriggerError::UnknownEvent(d[0]))?;
        if d[1] != 0 {
            return Err(TriggerError::Reserved(d[1]));
        }
        Ok(TriggerFrame {
            event,
            pose: u16::from_le_bytes([d[2], d[3]]),
            nc_ms: u32::from_le_bytes([d[4], d[5], d[6], d[7]]),
        })
    }
    pub fn encode(&self) -> [u8; 8] {
        let p = self.pose.to_le_bytes();
        let t = self.nc_ms.to_le_bytes();
        [self.event.code(), 0, p[0], p[1], t[0], t[1], t[2], t[3]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_worked_layout() {
        // Exact stop at pose 12 (0x000C), NC clock 10000 ms (0x00002710).
        let bytes = [2, 0, 0x0C, 0x00, 0x10, 0x27, 0x00, 0x00];
        let f = TriggerFrame {
            event: TriggerEvent::ExactStop,
            pose: 12,
            nc_ms: 10_000,
        };
        assert_eq!(TriggerFrame::decode(&bytes), Ok(f));
        assert_eq!(f.encode(), bytes);
        for e in TriggerEvent::ALL {
            let f = TriggerFrame {
                event: e,
                pose: 0xFFFF,
                nc_ms: u32::MAX,
            };
            assert_eq!(TriggerFrame::decode(&f.encode()), Ok(f));
        }
    }

    #[test]
    fn errors() {
        assert_eq!(
            TriggerFrame::decode(&[2, 0, 0, 0]),
            Err(TriggerError::BadDlc(4))
        );
        assert_eq!(
            TriggerFrame::decode(&[7, 0, 0, 0, 0, 0, 0, 0]),
            Err(TriggerError::UnknownEvent(7))
        );
        assert_eq!(
            TriggerFrame::decode(&[0, 0, 0, 0, 0, 0, 0, 0]),
            Err(TriggerError::UnknownEvent(0))
        );
        assert_eq!(
            TriggerFrame::decode(&[1, 5, 0, 0, 0, 0, 0, 0]),
            Err(TriggerError::Reserved(5))
        );
    }
}
