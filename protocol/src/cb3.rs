//! CB-3 CapBall ADC (instruments.md §2): ASCII commands, COBS-framed binary payloads ending in
//! `0x00`, each with a CRC-16/CCITT-FALSE over the payload before it.

/// Payload type `0x01`: `seq u16, t_us u32 (wraps), ch0..ch2 i32 (24-bit codes), flags u8, crc u16`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleFrame {
    pub seq: u16,
    pub t_us: u32,
    /// 24-bit signed ADC codes, sign-extended.
    pub ch: [i32; 3],
    /// Bits 0-2: over-range on channel 0-2.
    pub flags: u8,
}

impl SampleFrame {
    /// Volts of channel `i`: code · 10.0 / 8388608.
    pub fn volts(&self) -> [f64; 3] { todo!() }
}

/// One frame from the CB-3.
#[derive(Debug, Clone, PartialEq)]
pub enum Frame {
    Sample(SampleFrame),
    /// Type `0x7F`: the answer to a command (`OK`, `ERR <text>`, `CB-3,<serial>,<firmware>`).
    Text(String),
}

/// Largest encoded frame accepted before a `0x00`; longer runs are rejected as over-long.
pub const MAX_FRAME: usize = 256;

#[derive(Debug, Default)]
pub struct Decoder { /* private state */ }
impl Decoder {
    pub fn new() -> Self { todo!() }
}
impl crate::StreamDecoder for Decoder {
    type Frame = Frame;
    fn feed<S: FnMut(crate::Decoded<Frame>)>(&mut self, _bytes: &[u8], _sink: S) { todo!() }
    fn reset(&mut self) { todo!() }
}

/// Encode a frame: payload with CRC, COBS, trailing `0x00`.
pub fn encode(_f: &Frame, _out: &mut Vec<u8>) { todo!() }

/// CRC-16/CCITT-FALSE of `bytes`.
pub fn crc16(_bytes: &[u8]) -> u16 { todo!() }

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    Id,
    Rate(u32),
    Start,
    Stop,
}
impl Command {
    pub fn to_line(&self) -> String { todo!() }
    pub fn parse(_line: &str) -> Option<Command> { todo!() }
}
