//! LI-80 laser interferometer (instruments.md §1): ASCII commands, NMEA-style data lines
//! `$<body>*HH\r\n` with `HH` the XOR of the bytes between `$` and `*`, and plain answer lines.

/// `$POS,<seq>,<t_us>,<raw_nm>,<sig>,<flags>*HH`
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PosFrame {
    pub seq: u32,
    pub t_us: u64,
    /// Displacement since datum in nm, vacuum wavelength, not yet corrected for air.
    pub raw_nm: i64,
    /// Beam signal strength 0-100 %; below [`SIG_MIN`] the reading is invalid.
    pub sig: u8,
    pub flags: PosFlags,
}

/// Below this signal strength (%) a reading is invalid.
pub const SIG_MIN: u8 = 25;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PosFlags(pub u32);
impl PosFlags {
    pub const BEAM_LOW: u32 = 1 << 0;
    pub const DATUM_LOST: u32 = 1 << 1;
    pub const OVER_SPEED: u32 = 1 << 2;
    pub fn beam_low(self) -> bool { self.0 & Self::BEAM_LOW != 0 }
    pub fn datum_lost(self) -> bool { self.0 & Self::DATUM_LOST != 0 }
    pub fn over_speed(self) -> bool { self.0 & Self::OVER_SPEED != 0 }
}

impl PosFrame {
    /// A reading is valid when the signal is at least [`SIG_MIN`] and the datum is not lost.
    pub fn valid(&self) -> bool { todo!() }
}

/// `$ENV,<seq>,<t_us>,<air_c>,<air_pa>,<rh_pct>,<mat_c>[,<mat_c>[,<mat_c>]]*HH`
#[derive(Debug, Clone, PartialEq)]
pub struct EnvFrame {
    pub seq: u32,
    pub t_us: u64,
    pub air_c: f64,
    pub air_pa: f64,
    pub rh_pct: f64,
    /// One to three material temperatures, °C.
    pub material_c: Vec<f64>,
}

/// `$ERR,<code>,<text>*HH`: an asynchronous fault.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ErrFrame {
    pub code: u32,
    pub text: String,
}

/// One line from the LI-80.
#[derive(Debug, Clone, PartialEq)]
pub enum Line {
    Pos(PosFrame),
    Env(EnvFrame),
    Err(ErrFrame),
    /// A line not starting with `$`: the answer to a command (`OK`, `ERR <code> <text>`,
    /// the `*IDN?` string). Routed to whoever waits for an answer.
    Answer(String),
}

/// Streaming decoder of the LI-80 byte stream. Lines end in `\n` (a `\r` before it is
/// dropped); a line longer than [`MAX_LINE`] is rejected as over-long.
#[derive(Debug, Default)]
pub struct Decoder { /* private state */ }

/// Longest valid line, bytes, terminator excluded.
pub const MAX_LINE: usize = 128;

impl Decoder {
    pub fn new() -> Self { todo!() }
}

impl crate::StreamDecoder for Decoder {
    type Frame = Line;
    fn feed<S: FnMut(crate::Decoded<Line>)>(&mut self, _bytes: &[u8], _sink: S) { todo!() }
    fn reset(&mut self) { todo!() }
}

/// Encoders (used by the simulated device and the tests): complete lines with `*HH\r\n`.
pub fn encode_pos(_f: &PosFrame, _out: &mut Vec<u8>) { todo!() }
pub fn encode_env(_f: &EnvFrame, _out: &mut Vec<u8>) { todo!() }
pub fn encode_err(_f: &ErrFrame, _out: &mut Vec<u8>) { todo!() }

/// Host → device commands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    Idn,
    Rate(u32),
    Stream(bool),
    Datum,
    EnvQuery,
}
impl Command {
    /// The command line including its `\n`.
    pub fn to_line(&self) -> String { todo!() }
    /// Parse one command line as the device does (`\r\n` accepted). `Err(())` = unknown command.
    pub fn parse(_line: &str) -> Result<Command, UnknownCommand> { todo!() }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown command")]
pub struct UnknownCommand;

/// A parsed answer line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    Ok,
    Err { code: u32, text: String },
    /// `LI-80,<serial>,<firmware>`
    Idn { serial: String, firmware: String },
    Other(String),
}
impl Answer {
    pub fn parse(_line: &str) -> Answer { todo!() }
}
