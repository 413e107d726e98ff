//! PSD-2 transimpedance board (instruments.md §3): SCPI commands, answer lines, and unchecked
//! data lines `D,<seq>,<t_us>,<x1_pA>,<x2_pA>,<y1_pA>,<y2_pA>,<head_mC>\n`.
//!
//! Decoding rules (decisions where the data sheet is silent):
//! - Lines end in `\n`; one `\r` before it is dropped; an empty line is malformed.
//! - A line starting with `D,` is a data line: exactly 8 fields, else
//!   [`FieldCount`](crate::RejectKind::FieldCount); unsigned integers for `seq`, `t_us` and
//!   the currents (a `-` makes a current malformed), a signed `i32` for `head_mC`.
//! - Any other line is an answer if it is printable ASCII, except a line made only of
//!   digits, commas and minus signs: that is the tail of a data line cut when the port opened
//!   and is rejected as malformed. The one exception is `1`, the `*OPC?` answer, which is
//!   routed as an answer (a tail `1` cannot be told from it; the driver drops answers that
//!   arrive while no query is pending). `SYST:ERR?` answers contain `"`, `*IDN?` answers
//!   letters, so neither looks like a tail.

use std::io::Write as _;

use crate::text::{
    Fields, Piece, Splitter, field_count, parse_i32, parse_u32, printable_string, strip_cr,
};
use crate::{Decoded, RejectKind, Rejection};

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

/// Longest valid line, bytes, terminator excluded. A data line with every field at its type's
/// maximum is 129 bytes; the cap leaves room for that and for long answers.
pub const MAX_LINE: usize = 160;

/// Range of `CONF:RATE <hz>` the device accepts; outside it sets error −222 (instruments.md §3).
pub const RATE_MIN_HZ: u32 = 1;
pub const RATE_MAX_HZ: u32 = 1000;
/// [`RATE_MIN_HZ`]`..=`[`RATE_MAX_HZ`], for range checks.
pub const RATE_HZ: std::ops::RangeInclusive<u32> = RATE_MIN_HZ..=RATE_MAX_HZ;
/// Baud rate of the board's serial link at power-up (instruments.md §3).
pub const DEFAULT_BAUD: u32 = 921_600;
/// Baud rates the board's serial link can be set to.
pub const BAUDS: [u32; 8] = [
    9600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600,
];
/// Bits one data line takes on the wire: about 55 bytes of 10 bits (8N1), so that a link of
/// `baud` carries at most `baud / LINE_BITS` lines per second (instruments.md §3).
pub const LINE_BITS: u32 = 55 * 10;

#[derive(Debug, Default)]
pub struct Decoder {
    split: Splitter,
}
impl Decoder {
    pub fn new() -> Self {
        Self::default()
    }
}
impl crate::StreamDecoder for Decoder {
    type Frame = Line;
    fn feed<S: FnMut(Decoded<Line>)>(&mut self, bytes: &[u8], mut sink: S) {
        self.split
            .feed(bytes, MAX_LINE + 1, (b'\n', b'\n'), |p| match p {
                Piece::Line(raw, _) => {
                    let line = strip_cr(raw);
                    let n = raw.len() + 1;
                    sink(if line.len() > MAX_LINE {
                        reject(RejectKind::OverlongLine, n)
                    } else {
                        match decode_line(line) {
                            Ok(l) => Decoded::Frame(l),
                            Err(k) => reject(k, n),
                        }
                    });
                }
                Piece::Overlong(n, _) => sink(reject(RejectKind::OverlongLine, n + 1)),
            });
    }
    fn reset(&mut self) {
        self.split.reset();
    }
}

fn reject<F>(kind: RejectKind, bytes: usize) -> Decoded<F> {
    Decoded::Reject(Rejection { kind, bytes })
}

#[inline]
fn decode_line(line: &[u8]) -> Result<Line, RejectKind> {
    if line.starts_with(b"D,") {
        return parse_data(line).map(Line::Data);
    }
    if line != b"1"
        && line
            .iter()
            .all(|&b| b.is_ascii_digit() || b == b',' || b == b'-')
    {
        return Err(RejectKind::Malformed);
    }
    printable_string(line)
        .map(Line::Answer)
        .ok_or(RejectKind::Malformed)
}

#[inline]
fn parse_data(line: &[u8]) -> Result<DataLine, RejectKind> {
    if field_count(line) != 8 {
        return Err(RejectKind::FieldCount);
    }
    let mut f = Fields::new(line);
    f.skip();
    let m = RejectKind::Malformed;
    let seq = f.u32().ok_or(m)?;
    let t_us = f.u64().ok_or(m)?;
    let x1_pa = f.u64().ok_or(m)?;
    let x2_pa = f.u64().ok_or(m)?;
    let y1_pa = f.u64().ok_or(m)?;
    let y2_pa = f.u64().ok_or(m)?;
    let head_mc = f.i32().ok_or(m)?;
    Ok(DataLine {
        seq,
        t_us,
        x1_pa,
        x2_pa,
        y1_pa,
        y2_pa,
        head_mc,
    })
}

/// `D,...\n`, as the board writes it.
pub fn encode_data(d: &DataLine, out: &mut Vec<u8>) {
    let _ = writeln!(
        out,
        "D,{},{},{},{},{},{},{}",
        d.seq, d.t_us, d.x1_pa, d.x2_pa, d.y1_pa, d.y2_pa, d.head_mc
    );
}

/// Any line of the board (answers end in `\n` like data lines).
pub fn encode_line(l: &Line, out: &mut Vec<u8>) {
    match l {
        Line::Data(d) => encode_data(d, out),
        Line::Answer(s) => {
            out.extend_from_slice(s.as_bytes());
            out.push(b'\n');
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    Idn,
    Opc,
    ConfRate(u32),
    InitCont(bool),
    SystErr,
}
impl Command {
    /// The command line including its `\n`.
    pub fn to_line(&self) -> String {
        match self {
            Command::Idn => "*IDN?\n".into(),
            Command::Opc => "*OPC?\n".into(),
            Command::ConfRate(hz) => format!("CONF:RATE {hz}\n"),
            Command::InitCont(true) => "INIT:CONT ON\n".into(),
            Command::InitCont(false) => "INIT:CONT OFF\n".into(),
            Command::SystErr => "SYST:ERR?\n".into(),
        }
    }
    /// Parse a command line as the board does: keywords case-insensitive (SCPI), line end
    /// optional. `CONF:RATE` with any `u32` parses; the range check (−222) is the board's.
    /// `None`: not a command of the data sheet (the board sets a command error).
    pub fn parse(line: &str) -> Option<Command> {
        let l = line.strip_suffix('\n').unwrap_or(line);
        let l = l.strip_suffix('\r').unwrap_or(l).trim();
        let upper = l.to_ascii_uppercase();
        match upper.as_str() {
            "*IDN?" => Some(Command::Idn),
            "*OPC?" => Some(Command::Opc),
            "INIT:CONT ON" => Some(Command::InitCont(true)),
            "INIT:CONT OFF" => Some(Command::InitCont(false)),
            "SYST:ERR?" => Some(Command::SystErr),
            _ => upper
                .strip_prefix("CONF:RATE ")
                .and_then(|n| parse_u32(n.trim().as_bytes()))
                .map(Command::ConfRate),
        }
    }
}

/// `*IDN?` answer: `PSD-2,<serial>,<firmware>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Idn {
    pub serial: String,
    pub firmware: String,
}
impl Idn {
    pub fn parse(line: &str) -> Option<Idn> {
        let l = line.strip_suffix('\n').unwrap_or(line);
        let l = l.strip_suffix('\r').unwrap_or(l);
        let (serial, firmware) = l.strip_prefix("PSD-2,")?.split_once(',')?;
        Some(Idn {
            serial: serial.to_owned(),
            firmware: firmware.to_owned(),
        })
    }
    /// The answer line with its `\n`.
    pub fn to_line(&self) -> String {
        format!("PSD-2,{},{}\n", self.serial, self.firmware)
    }
}

/// `*OPC?` answer line.
pub const OPC_ANSWER: &str = "1\n";

/// `SYST:ERR?` answer: `<code>,"<text>"`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SystErr {
    pub code: i32,
    pub text: String,
}
impl SystErr {
    /// SCPI string: a `"` inside the text is doubled.
    pub fn parse(line: &str) -> Option<SystErr> {
        let l = line.strip_suffix('\n').unwrap_or(line);
        let l = l.strip_suffix('\r').unwrap_or(l);
        let (code, quoted) = l.split_once(',')?;
        let code = parse_i32(code.as_bytes())?;
        let inner = quoted.strip_prefix('"')?.strip_suffix('"')?;
        // Every `"` inside must be doubled.
        if inner.replace("\"\"", "").contains('"') {
            return None;
        }
        Some(SystErr {
            code,
            text: inner.replace("\"\"", "\""),
        })
    }
    /// The answer line with its `\n`.
    pub fn to_line(&self) -> String {
        format!("{},\"{}\"\n", self.code, self.text.replace('"', "\"\""))
    }
    pub fn no_error() -> SystErr {
        SystErr {
            code: 0,
            text: "No error".into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StreamDecoder;

    fn decode_all(bytes: &[u8]) -> Vec<Decoded<Line>> {
        let mut d = Decoder::new();
        let mut out = Vec::new();
        d.feed(bytes, |x| out.push(x));
        out
    }
    fn rej(kind: RejectKind, bytes: usize) -> Decoded<Line> {
        Decoded::Reject(Rejection { kind, bytes })
    }
    const DATA: &[u8] = b"D,42,1234567,1000,3000,2500,2500,21350\n";

    #[test]
    fn data_line() {
        let want = DataLine {
            seq: 42,
            t_us: 1234567,
            x1_pa: 1000,
            x2_pa: 3000,
            y1_pa: 2500,
            y2_pa: 2500,
            head_mc: 21350,
        };
        assert_eq!(decode_all(DATA), vec![Decoded::Frame(Line::Data(want))]);
        let mut enc = Vec::new();
        encode_data(&want, &mut enc);
        assert_eq!(enc, DATA);
        let neg = b"D,1,2,3,4,5,6,-1250\r\n";
        assert!(matches!(
            decode_all(neg)[0],
            Decoded::Frame(Line::Data(DataLine { head_mc: -1250, .. }))
        ));
    }

    #[test]
    fn rejections() {
        let l = b"D,1,2,3,4,5,6\n";
        assert_eq!(decode_all(l), vec![rej(RejectKind::FieldCount, l.len())]);
        let l = b"D,1,2,3,4,5,6,7,8\n";
        assert_eq!(decode_all(l), vec![rej(RejectKind::FieldCount, l.len())]);
        let l = b"D,1,2,-3,4,5,6,7\n";
        assert_eq!(decode_all(l), vec![rej(RejectKind::Malformed, l.len())]);
        let l = b"D,1,2,3.5,4,5,6,7\n";
        assert_eq!(decode_all(l), vec![rej(RejectKind::Malformed, l.len())]);
        let l = b"D,1,2,3,4,5,6,2147483648\n";
        assert_eq!(decode_all(l), vec![rej(RejectKind::Malformed, l.len())]);
        assert_eq!(decode_all(b"\n"), vec![rej(RejectKind::Malformed, 1)]);
        assert_eq!(
            decode_all(b"\xff\xfe\n"),
            vec![rej(RejectKind::Malformed, 3)]
        );
        // Tails of DATA when the port opens mid-line are all rejected.
        for cut in 1..DATA.len() {
            let tail = &DATA[cut..];
            assert_eq!(
                decode_all(tail),
                vec![rej(RejectKind::Malformed, tail.len())],
                "cut {cut}"
            );
        }
    }

    #[test]
    fn answers() {
        let got = decode_all(b"1\n0,\"No error\"\n-222,\"Data out of range\"\nPSD-2,77,1.4\n");
        let a = |s: &str| Decoded::Frame(Line::Answer(s.into()));
        assert_eq!(
            got,
            vec![
                a("1"),
                a("0,\"No error\""),
                a("-222,\"Data out of range\""),
                a("PSD-2,77,1.4")
            ]
        );
    }

    #[test]
    fn commands_and_syst_err() {
        for c in [
            Command::Idn,
            Command::Opc,
            Command::ConfRate(500),
            Command::InitCont(true),
            Command::InitCont(false),
            Command::SystErr,
        ] {
            assert_eq!(Command::parse(&c.to_line()), Some(c.clone()));
        }
        assert_eq!(Command::ConfRate(5).to_line(), "CONF:RATE 5\n");
        assert_eq!(
            Command::parse("init:cont on"),
            Some(Command::InitCont(true))
        );
        assert_eq!(Command::parse("CONF:RATE -5"), None);
        assert_eq!(Command::parse("FOO"), None);
        assert_eq!(
            SystErr::parse("-222,\"Data out of range\"\n"),
            Some(SystErr {
                code: -222,
                text: "Data out of range".into()
            })
        );
        assert_eq!(SystErr::no_error().to_line(), "0,\"No error\"\n");
        let q = SystErr {
            code: -100,
            text: "say \"hi\"".into(),
        };
        assert_eq!(q.to_line(), "-100,\"say \"\"hi\"\"\"\n");
        assert_eq!(SystErr::parse(&q.to_line()), Some(q));
        assert_eq!(SystErr::parse("0,No error"), None);
        let idn = Idn {
            serial: "4711".into(),
            firmware: "0.9".into(),
        };
        assert_eq!(idn.to_line(), "PSD-2,4711,0.9\n");
        assert_eq!(Idn::parse(&idn.to_line()), Some(idn));
        assert_eq!(Idn::parse("LI-80,1,2"), None);
        assert_eq!(SystErr::parse("0,\"a\"b\""), None);
    }
}
