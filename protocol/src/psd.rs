//! PSD-2 transimpedance board (instruments.md §3): SCPI commands, answer lines, and unchecked
//! data lines `D,<seq>,<t_us>,<x1_pA>,<x2_pA>,<y1_pA>,<y2_pA>,<head_mC>\n`.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataLine {
    pub seq: u32,
    pub t_us: u64,
    pub x1_pa: u64,
    pub x2_pa: u64,
    pub y1_pa: u64,
    pub y2_pa: u64,
    /// Head temperature in milli-degrees Celsius.
    pub head_mc: i32,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Line {
    Data(DataLine),
    /// Any line not starting with `D,`: the answer to a query.
    Answer(String),
}

pub const MAX_LINE: usize = 128;

#[derive(Debug, Default)]
pub struct Decoder { /* private state */ }
impl Decoder {
    pub fn new() -> Self { todo!() }
}
impl crate::StreamDecoder for Decoder {
    type Frame = Line;
    fn feed<S: FnMut(crate::Decoded<Line>)>(&mut self, _bytes: &[u8], _sink: S) { todo!() }
    fn reset(&mut self) { todo!() }
}

pub fn encode_data(_d: &DataLine, _out: &mut Vec<u8>) { todo!() }

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    Idn,
    Opc,
    ConfRate(u32),
    InitCont(bool),
    SystErr,
}
impl Command {
    pub fn to_line(&self) -> String { todo!() }
    pub fn parse(_line: &str) -> Option<Command> { todo!() }
}

/// `SYST:ERR?` answer: `<code>,"<text>"`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SystErr {
    pub code: i32,
    pub text: String,
}
impl SystErr {
    pub fn parse(_line: &str) -> Option<SystErr> { todo!() }
    pub fn to_line(&self) -> String { todo!() }
}
