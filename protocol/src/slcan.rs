//! SLCAN (Lawicel) text protocol (instruments.md §4): every message ends in `\r`; frames
//! `t<iii><l><dd…>` and `T<iiiiiiii><l><dd…>`, optional 4-hex-digit ms timestamp; `\r` = ack,
//! `\a` = nack.

/// A CAN frame as carried over SLCAN (also what the SocketCAN path produces).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CanFrame {
    pub id: u32,
    pub extended: bool,
    pub data: Vec<u8>,
    /// SLCAN millisecond timestamp (0-59999) when timestamps are on.
    pub timestamp_ms: Option<u16>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Message {
    Frame(CanFrame),
    /// `\r` on its own: the last command succeeded.
    Ack,
    /// `\a`: the last command failed.
    Nack,
    /// Another answer (version `V…`, serial `N…`, status `F…`, `z`/`Z` transmit acks).
    Other(String),
}

pub const MAX_LINE: usize = 64;

#[derive(Debug, Default)]
pub struct Decoder { /* private state */ }
impl Decoder {
    pub fn new() -> Self { todo!() }
}
impl crate::StreamDecoder for Decoder {
    type Frame = Message;
    fn feed<S: FnMut(crate::Decoded<Message>)>(&mut self, _bytes: &[u8], _sink: S) { todo!() }
    fn reset(&mut self) { todo!() }
}

/// `t`/`T` line with `\r` (and timestamp when present).
pub fn encode_frame(_f: &CanFrame, _out: &mut Vec<u8>) { todo!() }
