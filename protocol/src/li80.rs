//! LI-80 laser interferometer (instruments.md §1): ASCII commands, NMEA-style data lines
//! `$<body>*HH\r\n` with `HH` the XOR of the bytes between `$` and `*`, and plain answer lines.
//!
//! Decoding rules (decisions where the data sheet is silent):
//! - Lines end in `\n`; one `\r` before it is dropped. An empty line is rejected as
//!   [`Malformed`](crate::RejectKind::Malformed) (the device never sends one; it appears when
//!   the port opens between `\r` and `\n`).
//! - The checksum must be two **upper-case** hex digits, as the data sheet says; `*5a` is
//!   rejected as malformed. The device is the only writer, so strictness costs nothing and
//!   keeps the simulator honest.
//! - A `$` starts a record even in the middle of a line: the bytes before the last `$` are
//!   rejected as malformed and the record after it is decoded, so a record that follows
//!   line noise without a line end is not lost.
//! - A line without `$` is an answer only if it is printable ASCII, starts with a letter,
//!   contains no `*`, and is not one or two hex digits. Otherwise it is the tail of a record
//!   cut when the port opened (such tails always end in `*HH`, or are the `HH`/`H` alone) and
//!   is rejected as malformed. The tail of an *answer* (`K` of `OK`) cannot be told from an
//!   answer; the driver drops answers that arrive while no command is pending.
//! - `$POS` has exactly 5 fields, `$ENV` 6 to 8, `$ERR` a code and a text (the text may
//!   contain commas); otherwise [`FieldCount`](crate::RejectKind::FieldCount). `sig` above
//!   100 is malformed; flags are 1-8 hex digits of either case; ENV numbers must be plain
//!   decimals (`-?d+(.d+)?`).

use std::io::Write as _;

use crate::text::{
    Fields, Piece, Splitter, field_count, hex_digit_upper, parse_decimal, parse_u32, parse_u64,
    printable, printable_string, split_fields, strip_cr,
};
use crate::{Decoded, RejectKind, Rejection};

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

/// Range of `RATE <hz>` the device accepts (instruments.md §1); outside it answers
/// `ERR 2 rate out of range`.
pub const RATE_MIN_HZ: u32 = 1;
pub const RATE_MAX_HZ: u32 = 10_000;
/// [`RATE_MIN_HZ`]`..=`[`RATE_MAX_HZ`], for range checks.
pub const RATE_HZ: std::ops::RangeInclusive<u32> = RATE_MIN_HZ..=RATE_MAX_HZ;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PosFlags(pub u32);
impl PosFlags {
    pub const BEAM_LOW: u32 = 1 << 0;
    pub const DATUM_LOST: u32 = 1 << 1;
    pub const OVER_SPEED: u32 = 1 << 2;
    pub fn beam_low(self) -> bool {
        self.0 & Self::BEAM_LOW != 0
    }
    pub fn datum_lost(self) -> bool {
        self.0 & Self::DATUM_LOST != 0
    }
    pub fn over_speed(self) -> bool {
        self.0 & Self::OVER_SPEED != 0
    }
}

impl PosFrame {
    /// A reading is valid when the signal is at least [`SIG_MIN`] and the datum is not lost.
    pub fn valid(&self) -> bool {
        self.sig >= SIG_MIN && !self.flags.datum_lost()
    }
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
pub struct Decoder {
    split: Splitter,
}

/// Longest valid line, bytes, terminator excluded.
pub const MAX_LINE: usize = 128;

impl Decoder {
    pub fn new() -> Self {
        Self::default()
    }
}

impl crate::StreamDecoder for Decoder {
    type Frame = Line;
    fn feed<S: FnMut(Decoded<Line>)>(&mut self, bytes: &[u8], mut sink: S) {
        // +1: the `\r` of `\r\n` is part of the piece the splitter sees.
        self.split
            .feed(bytes, MAX_LINE + 1, (b'\n', b'\n'), |p| match p {
                Piece::Line(line, _) => decode_line(line, &mut sink),
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

/// One line without its `\n`; every byte of it plus the `\n` is accounted for by exactly one
/// frame or rejection (two when a `$` follows garbage on the same line).
#[inline]
fn decode_line(raw: &[u8], sink: &mut impl FnMut(Decoded<Line>)) {
    let line = strip_cr(raw);
    if line.len() > MAX_LINE {
        sink(reject(RejectKind::OverlongLine, raw.len() + 1));
        return;
    }
    let cr = raw.len() - line.len();
    // The common case (one `$`, at the start) without a backward scan.
    let last_dollar = if line.first() == Some(&b'$') && !line[1..].contains(&b'$') {
        Some(0)
    } else {
        line.iter().rposition(|&b| b == b'$')
    };
    match last_dollar {
        Some(0) => sink(match parse_record(line) {
            Ok(l) => Decoded::Frame(l),
            Err(k) => reject(k, raw.len() + 1),
        }),
        Some(i) => {
            sink(reject(RejectKind::Malformed, i));
            sink(match parse_record(&line[i..]) {
                Ok(l) => Decoded::Frame(l),
                Err(k) => reject(k, line.len() - i + cr + 1),
            });
        }
        None => sink(match answer_line(line) {
            Some(s) => Decoded::Frame(Line::Answer(s)),
            None => reject(RejectKind::Malformed, raw.len() + 1),
        }),
    }
}

fn answer_line(line: &[u8]) -> Option<String> {
    let first = *line.first()?;
    if !first.is_ascii_alphabetic() || !printable(line) || line.contains(&b'*') {
        return None;
    }
    if line.len() <= 2 && line.iter().all(|&b| hex_digit_upper(b).is_some()) {
        return None;
    }
    printable_string(line)
}

/// XOR of the bytes strictly between `$` and `*`.
pub fn checksum(body: &[u8]) -> u8 {
    body.iter().fold(0, |a, &b| a ^ b)
}

/// A record line from `$` to the checksum, without line end.
fn parse_record(rec: &[u8]) -> Result<Line, RejectKind> {
    let n = rec.len();
    if n < 4 || rec[n - 3] != b'*' {
        return Err(RejectKind::Malformed);
    }
    let (hi, lo) = match (hex_digit_upper(rec[n - 2]), hex_digit_upper(rec[n - 1])) {
        (Some(h), Some(l)) => (h, l),
        _ => return Err(RejectKind::Malformed),
    };
    let body = &rec[1..n - 3];
    if checksum(body) != (hi << 4) | lo {
        return Err(RejectKind::BadChecksum);
    }
    let name_end = body.iter().position(|&b| b == b',').unwrap_or(body.len());
    match &body[..name_end] {
        b"POS" => parse_pos(body).map(Line::Pos),
        b"ENV" => parse_env(body).map(Line::Env),
        b"ERR" => parse_err(body).map(Line::Err),
        _ => Err(RejectKind::UnknownRecord),
    }
}

#[inline]
fn parse_pos(body: &[u8]) -> Result<PosFrame, RejectKind> {
    if field_count(body) != 6 {
        return Err(RejectKind::FieldCount);
    }
    let mut f = Fields::new(body);
    f.skip();
    let m = RejectKind::Malformed;
    let seq = f.u32().ok_or(m)?;
    let t_us = f.u64().ok_or(m)?;
    let raw_nm = f.i64().ok_or(m)?;
    let sig = f.u32().filter(|&s| s <= 100).ok_or(m)? as u8;
    let flags = PosFlags(f.hex_u32().ok_or(m)?);
    Ok(PosFrame {
        seq,
        t_us,
        raw_nm,
        sig,
        flags,
    })
}

fn parse_env(body: &[u8]) -> Result<EnvFrame, RejectKind> {
    let mut f: [&[u8]; 9] = [&[]; 9];
    let n = split_fields(body, &mut f);
    if !(7..=9).contains(&n) {
        return Err(RejectKind::FieldCount);
    }
    let m = RejectKind::Malformed;
    let mut material_c = Vec::with_capacity(n - 6);
    for field in &f[6..n] {
        material_c.push(parse_decimal(field).ok_or(m)?);
    }
    Ok(EnvFrame {
        seq: parse_u32(f[1]).ok_or(m)?,
        t_us: parse_u64(f[2]).ok_or(m)?,
        air_c: parse_decimal(f[3]).ok_or(m)?,
        air_pa: parse_decimal(f[4]).ok_or(m)?,
        rh_pct: parse_decimal(f[5]).ok_or(m)?,
        material_c,
    })
}

fn parse_err(body: &[u8]) -> Result<ErrFrame, RejectKind> {
    let mut parts = body.splitn(3, |&b| b == b',');
    let (_, code, text) = match (parts.next(), parts.next(), parts.next()) {
        (Some(a), Some(b), Some(c)) => (a, b, c),
        _ => return Err(RejectKind::FieldCount),
    };
    Ok(ErrFrame {
        code: parse_u32(code).ok_or(RejectKind::Malformed)?,
        text: if text.is_empty() {
            String::new()
        } else {
            printable_string(text).ok_or(RejectKind::Malformed)?
        },
    })
}

/// Appends `$<body>*HH\r\n`.
fn finish_record(start: usize, out: &mut Vec<u8>) {
    let sum = checksum(&out[start + 1..]);
    let _ = write!(out, "*{sum:02X}\r\n");
}

/// Encoders (used by the simulated device and the tests): complete lines with `*HH\r\n`.
/// Flags are written as upper-case hex without leading zeros.
pub fn encode_pos(f: &PosFrame, out: &mut Vec<u8>) {
    let start = out.len();
    let _ = write!(
        out,
        "$POS,{},{},{},{},{:X}",
        f.seq, f.t_us, f.raw_nm, f.sig, f.flags.0
    );
    finish_record(start, out);
}

/// Numbers are written in their shortest round-trip decimal form (Rust's `Display` for
/// `f64` never uses an exponent). They must be finite; a device with a resolution of 0.001
/// keeps the line well under [`MAX_LINE`].
pub fn encode_env(f: &EnvFrame, out: &mut Vec<u8>) {
    let start = out.len();
    let _ = write!(
        out,
        "$ENV,{},{},{},{},{}",
        f.seq, f.t_us, f.air_c, f.air_pa, f.rh_pct
    );
    for m in &f.material_c {
        let _ = write!(out, ",{m}");
    }
    finish_record(start, out);
}

pub fn encode_err(f: &ErrFrame, out: &mut Vec<u8>) {
    let start = out.len();
    let _ = write!(out, "$ERR,{},{}", f.code, f.text);
    finish_record(start, out);
}

/// Any line of the device, as the device writes it (answers end in `\r\n` too).
pub fn encode_line(l: &Line, out: &mut Vec<u8>) {
    match l {
        Line::Pos(f) => encode_pos(f, out),
        Line::Env(f) => encode_env(f, out),
        Line::Err(f) => encode_err(f, out),
        Line::Answer(s) => {
            out.extend_from_slice(s.as_bytes());
            out.extend_from_slice(b"\r\n");
        }
    }
}

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
    pub fn to_line(&self) -> String {
        match self {
            Command::Idn => "*IDN?\n".into(),
            Command::Rate(hz) => format!("RATE {hz}\n"),
            Command::Stream(true) => "STREAM ON\n".into(),
            Command::Stream(false) => "STREAM OFF\n".into(),
            Command::Datum => "DATUM\n".into(),
            Command::EnvQuery => "ENV?\n".into(),
        }
    }
    /// Parse one command line as the device does (`\n` or `\r\n` optional at the end).
    /// `RATE` with any `u32` parses: the range check (answer `ERR 2`) is the device's.
    pub fn parse(line: &str) -> Result<Command, UnknownCommand> {
        let l = line.strip_suffix('\n').unwrap_or(line);
        let l = l.strip_suffix('\r').unwrap_or(l);
        match l {
            "*IDN?" => Ok(Command::Idn),
            "STREAM ON" => Ok(Command::Stream(true)),
            "STREAM OFF" => Ok(Command::Stream(false)),
            "DATUM" => Ok(Command::Datum),
            "ENV?" => Ok(Command::EnvQuery),
            _ => l
                .strip_prefix("RATE ")
                .and_then(|n| parse_u32(n.as_bytes()))
                .map(Command::Rate)
                .ok_or(UnknownCommand),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown command")]
pub struct UnknownCommand;

/// A parsed answer line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    Ok,
    Err {
        code: u32,
        text: String,
    },
    /// `LI-80,<serial>,<firmware>`
    Idn {
        serial: String,
        firmware: String,
    },
    Other(String),
}
impl Answer {
    /// Parse an answer line (line end optional).
    pub fn parse(line: &str) -> Answer {
        let l = line.strip_suffix('\n').unwrap_or(line);
        let l = l.strip_suffix('\r').unwrap_or(l);
        if l == "OK" {
            return Answer::Ok;
        }
        if let Some(rest) = l.strip_prefix("ERR ") {
            let (code, text) = rest.split_once(' ').unwrap_or((rest, ""));
            if let Some(code) = parse_u32(code.as_bytes()) {
                return Answer::Err {
                    code,
                    text: text.to_owned(),
                };
            }
        }
        if let Some((serial, firmware)) = l.strip_prefix("LI-80,").and_then(|r| r.split_once(',')) {
            return Answer::Idn {
                serial: serial.to_owned(),
                firmware: firmware.to_owned(),
            };
        }
        Answer::Other(l.to_owned())
    }

    /// The answer line as the device writes it, with `\r\n`.
    pub fn to_line(&self) -> String {
        match self {
            Answer::Ok => "OK\r\n".into(),
            Answer::Err { code, text } => format!("ERR {code} {text}\r\n"),
            Answer::Idn { serial, firmware } => format!("LI-80,{serial},{firmware}\r\n"),
            Answer::Other(s) => format!("{s}\r\n"),
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

    // Checksums worked by hand: XOR of "POS,1,2,3,50,0".
    // P=0x50 O=0x4F S=0x53 ,=0x2C 1=0x31 ,  2=0x32 , 3=0x33 , 5=0x35 0=0x30 , 0=0x30
    // 50^4F=1F, ^53=4C, ^2C=60, ^31=51, ^2C=7D, ^32=4F, ^2C=63, ^33=50, ^2C=7C, ^35=49,
    // ^30=79, ^2C=55, ^30=65.
    const POS_LINE: &[u8] = b"$POS,1,2,3,50,0*65\r\n";

    #[test]
    fn decodes_hand_worked_pos() {
        let got = decode_all(POS_LINE);
        let want = PosFrame {
            seq: 1,
            t_us: 2,
            raw_nm: 3,
            sig: 50,
            flags: PosFlags(0),
        };
        assert_eq!(got, vec![Decoded::Frame(Line::Pos(want))]);
        let mut enc = Vec::new();
        encode_pos(&want, &mut enc);
        assert_eq!(enc, POS_LINE);
    }

    #[test]
    fn pos_fields() {
        let f = PosFrame {
            seq: u32::MAX,
            t_us: u64::MAX,
            raw_nm: i64::MIN,
            sig: 100,
            flags: PosFlags(0x7),
        };
        let mut enc = Vec::new();
        encode_pos(&f, &mut enc);
        assert!(
            enc.starts_with(b"$POS,4294967295,18446744073709551615,-9223372036854775808,100,7*")
        );
        assert_eq!(decode_all(&enc), vec![Decoded::Frame(Line::Pos(f))]);
        assert!(f.flags.beam_low() && f.flags.datum_lost() && f.flags.over_speed());
        assert!(!f.valid());
        let ok = PosFrame {
            sig: 25,
            flags: PosFlags(PosFlags::BEAM_LOW),
            ..f
        };
        assert!(ok.valid());
        assert!(!PosFrame { sig: 24, ..ok }.valid());
    }

    #[test]
    fn env_and_err() {
        let e = EnvFrame {
            seq: 7,
            t_us: 1_000_000,
            air_c: 20.125,
            air_pa: 101325.0,
            rh_pct: 45.5,
            material_c: vec![19.98, 20.02, -1.5],
        };
        let mut enc = Vec::new();
        encode_env(&e, &mut enc);
        assert!(enc.starts_with(b"$ENV,7,1000000,20.125,101325,45.5,19.98,20.02,-1.5*"));
        assert_eq!(decode_all(&enc), vec![Decoded::Frame(Line::Env(e))]);
        let r = ErrFrame {
            code: 3,
            text: "beam lost".into(),
        };
        let mut enc = Vec::new();
        encode_err(&r, &mut enc);
        assert_eq!(decode_all(&enc), vec![Decoded::Frame(Line::Err(r))]);
    }

    fn with_sum(body: &str) -> Vec<u8> {
        format!("${body}*{:02X}\r\n", checksum(body.as_bytes())).into_bytes()
    }

    #[test]
    fn rejections() {
        // Bad checksum: 0x65 expected.
        assert_eq!(
            decode_all(b"$POS,1,2,3,50,0*66\r\n"),
            vec![rej(RejectKind::BadChecksum, 20)]
        );
        // Lower-case checksum digits are rejected (data sheet: upper-case).
        // XOR of "POS,9,2,3,50,0" is 0x65 ^ '1' ^ '9' = 0x6D.
        assert_eq!(decode_all(b"$POS,9,2,3,50,0*6D\r\n").len(), 1);
        assert!(matches!(
            decode_all(b"$POS,9,2,3,50,0*6D\r\n")[0],
            Decoded::Frame(_)
        ));
        assert_eq!(
            decode_all(b"$POS,9,2,3,50,0*6d\r\n"),
            vec![rej(RejectKind::Malformed, 20)]
        );
        assert_eq!(
            decode_all(b"$POS,1,2,3,50,0\r\n"),
            vec![rej(RejectKind::Malformed, 17)]
        );
        let l = with_sum("POS,1,2,3,50");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::FieldCount, l.len())]);
        let l = with_sum("POS,1,2,3,50,0,0");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::FieldCount, l.len())]);
        let l = with_sum("POS,1,2,x,50,0");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::Malformed, l.len())]);
        let l = with_sum("POS,1,2,3,101,0");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::Malformed, l.len())]);
        let l = with_sum("POS,4294967296,2,3,50,0");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::Malformed, l.len())]);
        let l = with_sum("XYZ,1,2");
        assert_eq!(
            decode_all(&l),
            vec![rej(RejectKind::UnknownRecord, l.len())]
        );
        let l = with_sum("ENV,1,2,20,101325,50");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::FieldCount, l.len())]);
        let l = with_sum("ENV,1,2,20,101325,50,1,2,3,4");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::FieldCount, l.len())]);
        let l = with_sum("ENV,1,2,2e1,101325,50,20");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::Malformed, l.len())]);
        let l = with_sum("ERR,3");
        assert_eq!(decode_all(&l), vec![rej(RejectKind::FieldCount, l.len())]);
        assert_eq!(decode_all(b"\r\n"), vec![rej(RejectKind::Malformed, 2)]);
    }

    #[test]
    fn answers_and_mid_frame_tails() {
        let got = decode_all(b"OK\r\nERR 2 rate out of range\nLI-80,1234,1.0.2\r\n");
        assert_eq!(
            got,
            vec![
                Decoded::Frame(Line::Answer("OK".into())),
                Decoded::Frame(Line::Answer("ERR 2 rate out of range".into())),
                Decoded::Frame(Line::Answer("LI-80,1234,1.0.2".into())),
            ]
        );
        // Port opened in the middle of `$POS,1,2,3,50,0*65\r\n`: every tail is rejected.
        for cut in 1..POS_LINE.len() - 1 {
            let tail = &POS_LINE[cut..];
            let got = decode_all(tail);
            assert_eq!(
                got,
                vec![rej(RejectKind::Malformed, tail.len())],
                "cut at {cut}"
            );
        }
    }

    #[test]
    fn resync_at_dollar_and_overlong() {
        let mut s = b"\x01garbage".to_vec();
        s.extend_from_slice(POS_LINE);
        let got = decode_all(&s);
        assert_eq!(got[0], rej(RejectKind::Malformed, 8));
        assert!(matches!(got[1], Decoded::Frame(Line::Pos(_))));
        let mut s = vec![b'x'; 300];
        s.push(b'\n');
        s.extend_from_slice(POS_LINE);
        let got = decode_all(&s);
        assert_eq!(got[0], rej(RejectKind::OverlongLine, 301));
        assert!(matches!(got[1], Decoded::Frame(Line::Pos(_))));
        // Exactly MAX_LINE bytes plus \r\n is fine; one more is over-long.
        let mut s = vec![b'A'; MAX_LINE];
        s.extend_from_slice(b"\r\n");
        assert!(matches!(decode_all(&s)[0], Decoded::Frame(Line::Answer(_))));
        let mut s = vec![b'A'; MAX_LINE + 1];
        s.extend_from_slice(b"\r\n");
        assert_eq!(
            decode_all(&s),
            vec![rej(RejectKind::OverlongLine, MAX_LINE + 3)]
        );
    }

    #[test]
    fn reset_forgets_partial_line() {
        let mut d = Decoder::new();
        let mut out = Vec::new();
        d.feed(b"$POS,1,2", |x| out.push(x));
        d.reset();
        d.feed(POS_LINE, |x| out.push(x));
        assert_eq!(out, decode_all(POS_LINE));
        // Also while discarding an over-long line.
        let mut out = Vec::new();
        d.feed(&[b'x'; 500], |x| out.push(x));
        d.reset();
        d.feed(POS_LINE, |x| out.push(x));
        assert_eq!(out, decode_all(POS_LINE));
    }

    #[test]
    fn split_anywhere() {
        let mut d = Decoder::new();
        let mut out = Vec::new();
        for b in POS_LINE.iter().chain(POS_LINE) {
            d.feed(std::slice::from_ref(b), |x| out.push(x));
        }
        assert_eq!(out.len(), 2);
        assert_eq!(out[0], decode_all(POS_LINE)[0]);
    }

    #[test]
    fn commands_and_answers() {
        for c in [
            Command::Idn,
            Command::Rate(1000),
            Command::Stream(true),
            Command::Stream(false),
            Command::Datum,
            Command::EnvQuery,
        ] {
            assert_eq!(Command::parse(&c.to_line()), Ok(c.clone()));
        }
        assert_eq!(Command::Rate(10).to_line(), "RATE 10\n");
        assert_eq!(Command::parse("STREAM ON\r\n"), Ok(Command::Stream(true)));
        assert_eq!(Command::parse("RATE x\n"), Err(UnknownCommand));
        assert_eq!(Command::parse("FOO\n"), Err(UnknownCommand));
        assert_eq!(Answer::parse("OK\r\n"), Answer::Ok);
        assert_eq!(
            Answer::parse("ERR 2 rate out of range"),
            Answer::Err {
                code: 2,
                text: "rate out of range".into()
            }
        );
        assert_eq!(
            Answer::parse("LI-80,A123,2.1"),
            Answer::Idn {
                serial: "A123".into(),
                firmware: "2.1".into()
            }
        );
        assert_eq!(Answer::parse("what"), Answer::Other("what".into()));
        for a in [
            Answer::Ok,
            Answer::Err {
                code: 1,
                text: "unknown command".into(),
            },
            Answer::Idn {
                serial: "S1".into(),
                firmware: "F".into(),
            },
        ] {
            assert_eq!(Answer::parse(&a.to_line()), a);
        }
    }
}
