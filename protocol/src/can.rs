//! CNC exact-stop trigger frames (instruments.md §4): CAN 2.0A, DLC 8, little-endian.

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TriggerEvent {
    MotionStart = 1,
    ExactStop = 2,
    DwellEnd = 3,
    ProgramStart = 4,
    ProgramEnd = 5,
    FeedHold = 6,
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
    pub fn decode(_data: &[u8]) -> Result<TriggerFrame, TriggerError> { todo!() }
    pub fn encode(&self) -> [u8; 8] { todo!() }
}
