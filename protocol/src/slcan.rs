//! SLCAN (Lawicel) text protocol (instruments.md §4): every message ends in `\r`; frames
//! `t<iii><l><dd…>` and `T<iiiiiiii><l><dd…>`, optional 4-hex-digit ms timestamp; `\r` = ack,
//! `\a` = nack.
//!
//! Decoding rules: `\a` (0x07) is a message of its own with no `\r` after it, so it is a
//! boundary too; bytes of an unfinished message before a `\a` are rejected as malformed.
//! Frame lines are told apart from timestamped ones by their length against the DLC
//! (`t`: 5 + 2·DLC, or 9 + 2·DLC with a timestamp; `T`: 10 + 2·DLC or 14 + 2·DLC); any other
//! length, a DLC above 8, an identifier above 0x7FF (standard) or 0x1FFFFFFF (extended), a
//! timestamp above 59999 or a non-hex digit is malformed. Hex digits of either case are
//! accepted: the adapter is third-party (no checksum is at stake) and python-can's slcan
//! reader does the same. Other printable lines are [`Message::Other`]; non-printable ones
//! are malformed.

use std::io::Write as _;

use crate::text::{Piece, Splitter, hex_digit, printable_string};
use crate::{Decoded, RejectKind, Rejection};

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
/// SLCAN timestamps count milliseconds modulo 60000.
pub const TIMESTAMP_MODULUS_MS: u16 = 60_000;
const BEL: u8 = 0x07;

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
    type Frame = Message;
    fn feed<S: FnMut(Decoded<Message>)>(&mut self, bytes: &[u8], mut sink: S) {
        self.split.feed(bytes, MAX_LINE, (b'\r', BEL), |p| match p {
            Piece::Line(line, b'\r') => sink(match decode_line(line) {
                Ok(m) => Decoded::Frame(m),
                Err(kind) => Decoded::Reject(Rejection {
                    kind,
                    bytes: line.len() + 1,
                }),
            }),
            Piece::Line(line, _) => {
                if !line.is_empty() {
                    sink(Decoded::Reject(Rejection {
                        kind: RejectKind::Malformed,
                        bytes: line.len(),
                    }));
                }
                sink(Decoded::Frame(Message::Nack));
            }
            Piece::Overlong(n, b'\r') => sink(Decoded::Reject(Rejection {
                kind: RejectKind::OverlongLine,
                bytes: n + 1,
            })),
            Piece::Overlong(n, _) => {
                sink(Decoded::Reject(Rejection {
                    kind: RejectKind::OverlongLine,
                    bytes: n,
                }));
                sink(Decoded::Frame(Message::Nack));
            }
        });
    }
    fn reset(&mut self) {
        self.split.reset();
    }
}

#[inline]
fn hex_value(s: &[u8]) -> Option<u32> {
    let mut v = 0u32;
    for &b in s {
        v = (v << 4) | u32::from(hex_digit(b)?);
    }
    Some(v)
}

#[inline]
fn decode_line(line: &[u8]) -> Result<Message, RejectKind> {
    let Some(&first) = line.first() else {
        return Ok(Message::Ack);
    };
    let (extended, id_len, max_id) = match first {
        b't' => (false, 3, 0x7FF),
        b'T' => (true, 8, 0x1FFF_FFFF),
        _ => {
            return printable_string(line)
                .map(Message::Other)
                .ok_or(RejectKind::Malformed);
        }
    };
    let m = RejectKind::Malformed;
    let head = 1 + id_len + 1;
    if line.len() < head {
        return Err(m);
    }
    let id = hex_value(&line[1..1 + id_len])
        .filter(|&id| id <= max_id)
        .ok_or(m)?;
    let dlc = line[head - 1].wrapping_sub(b'0');
    if dlc > 8 {
        return Err(m);
    }
    let data_end = head + 2 * usize::from(dlc);
    let timestamp_ms = match line.len() - head {
        r if r == 2 * usize::from(dlc) => None,
        r if r == 2 * usize::from(dlc) + 4 => {
            let ts = hex_value(&line[data_end..]).ok_or(m)?;
            if ts >= u32::from(TIMESTAMP_MODULUS_MS) {
                return Err(m);
            }
            Some(ts as u16)
        }
        _ => return Err(m),
    };
    let mut data = Vec::with_capacity(usize::from(dlc));
    for pair in line[head..data_end].chunks_exact(2) {
        data.push(((hex_digit(pair[0]).ok_or(m)?) << 4) | hex_digit(pair[1]).ok_or(m)?);
    }
    Ok(Message::Frame(CanFrame {
        id,
        extended,
        data,
        timestamp_ms,
    }))
}

/// `t`/`T` line with `\r` (and timestamp when present). Hex upper-case. The caller keeps
/// `data` to at most 8 bytes and the identifier in range (more is written as given, which
/// the decoder rejects).
pub fn encode_frame(f: &CanFrame, out: &mut Vec<u8>) {
    if f.extended {
        let _ = write!(out, "T{:08X}{}", f.id, f.data.len());
    } else {
        let _ = write!(out, "t{:03X}{}", f.id, f.data.len());
    }
    for b in &f.data {
        let _ = write!(out, "{b:02X}");
    }
    if let Some(ts) = f.timestamp_ms {
        let _ = write!(out, "{ts:04X}");
    }
    out.push(b'\r');
}

/// Any adapter message as the adapter writes it.
pub fn encode_message(m: &Message, out: &mut Vec<u8>) {
    match m {
        Message::Frame(f) => encode_frame(f, out),
        Message::Ack => out.push(b'\r'),
        Message::Nack => out.push(BEL),
        Message::Other(s) => {
            out.extend_from_slice(s.as_bytes());
            out.push(b'\r');
        }
    }
}

/// Host → adapter commands the host uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `C`: close the channel.
    Close,
    /// `S<n>`: standard bit rate index (`S6` = 500 kbit/s).
    Bitrate(u8),
    /// `O`: open the channel.
    Open,
    /// `Z1` / `Z0`: timestamps on or off.
    Timestamps(bool),
}

/// Bit rate index of 500 kbit/s in the Lawicel `S<n>` command.
pub const BITRATE_500K: u8 = 6;

impl Command {
    /// The command with its `\r`.
    pub fn to_line(&self) -> String {
        match self {
            Command::Close => "C\r".into(),
            Command::Bitrate(n) => format!("S{n}\r"),
            Command::Open => "O\r".into(),
            Command::Timestamps(on) => format!("Z{}\r", u8::from(*on)),
        }
    }
    /// Parse one command (trailing `\r` optional), as an adapter does.
    pub fn parse(line: &str) -> Option<Command> {
        match line.strip_suffix('\r').unwrap_or(line) {
            "C" => Some(Command::Close),
            "O" => Some(Command::Open),
            "Z0" => Some(Command::Timestamps(false)),
            "Z1" => Some(Command::Timestamps(true)),
            l => match l.strip_prefix('S')?.as_bytes() {
                [d @ b'0'..=b'8'] => Some(Command::Bitrate(d - b'0')),
                _ => None,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StreamDecoder;

    fn decode_all(bytes: &[u8]) -> Vec<Decoded<Message>> {
        let mut d = Decoder::new();
        let mut out = Vec::new();
        d.feed(bytes, |x| out.push(x));
        out
    }
    fn rej(kind: RejectKind, bytes: usize) -> Decoded<Message> {
        Decoded::Reject(Rejection { kind, bytes })
    }
    fn frame(id: u32, extended: bool, data: &[u8], ts: Option<u16>) -> Decoded<Message> {
        Decoded::Frame(Message::Frame(CanFrame {
            id,
            extended,
            data: data.to_vec(),
            timestamp_ms: ts,
        }))
    }

    #[test]
    fn frames_with_and_without_timestamp() {
        let trig = [2, 0, 0x0C, 0x00, 0x10, 0x27, 0, 0];
        assert_eq!(
            decode_all(b"t181802000C0010270000\r"),
            vec![frame(0x181, false, &trig, None)]
        );
        assert_eq!(
            decode_all(b"t181802000C0010270000EA5F\r"),
            vec![frame(0x181, false, &trig, Some(59999))]
        );
        assert_eq!(decode_all(b"t1810\r"), vec![frame(0x181, false, &[], None)]);
        // DLC 0 with a timestamp: 4 extra digits.
        assert_eq!(
            decode_all(b"t18101234\r"),
            vec![frame(0x181, false, &[], Some(0x1234))]
        );
        assert_eq!(
            decode_all(b"T1FFFFFFF2abcd\r"),
            vec![frame(0x1FFF_FFFF, true, &[0xAB, 0xCD], None)]
        );
        let f = CanFrame {
            id: 0x181,
            extended: false,
            data: trig.to_vec(),
            timestamp_ms: Some(7),
        };
        let mut enc = Vec::new();
        encode_frame(&f, &mut enc);
        assert_eq!(enc, b"t181802000C00102700000007\r");
    }

    #[test]
    fn acks_and_others() {
        assert_eq!(
            decode_all(b"\r\x07V1013\rz\r"),
            vec![
                Decoded::Frame(Message::Ack),
                Decoded::Frame(Message::Nack),
                Decoded::Frame(Message::Other("V1013".into())),
                Decoded::Frame(Message::Other("z".into())),
            ]
        );
        // Partial message cut by a nack.
        assert_eq!(
            decode_all(b"t18\x07"),
            vec![rej(RejectKind::Malformed, 3), Decoded::Frame(Message::Nack)]
        );
    }

    #[test]
    fn rejections() {
        for (l, what) in [
            (&b"t1819\r"[..], "dlc 9"),
            (b"t8001\r", "id above 0x7FF"),
            (b"t1812AB\r", "short data"),
            (b"t1812ABCDE\r", "odd length"),
            (b"t1812ABCG\r", "bad hex"),
            (b"t181\r", "no dlc"),
            (b"t1810EA60\r", "timestamp 60000"),
            (b"T200000000\r", "extended id too big"),
            (b"\xff\r", "not printable"),
        ] {
            assert_eq!(
                decode_all(l),
                vec![rej(RejectKind::Malformed, l.len())],
                "{what}"
            );
        }
        let mut l = vec![b'V'; 100];
        l.push(b'\r');
        l.extend_from_slice(b"t1810\r");
        assert_eq!(
            decode_all(&l),
            vec![
                rej(RejectKind::OverlongLine, 101),
                frame(0x181, false, &[], None)
            ]
        );
    }

    #[test]
    fn commands() {
        for c in [
            Command::Close,
            Command::Bitrate(6),
            Command::Open,
            Command::Timestamps(true),
        ] {
            assert_eq!(Command::parse(&c.to_line()), Some(c));
        }
        assert_eq!(Command::Bitrate(BITRATE_500K).to_line(), "S6\r");
        assert_eq!(Command::parse("S9"), None);
        assert_eq!(Command::parse("X"), None);
    }
}
