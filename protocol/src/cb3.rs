//! CB-3 CapBall ADC (instruments.md §2): ASCII commands, COBS-framed binary payloads ending in
//! `0x00`, each with a CRC-16/CCITT-FALSE over the payload before it.
//!
//! Decoding order for one `0x00`-terminated run, and the rejection each step gives:
//! empty run or COBS payload shorter than 3 bytes → [`BadLength`](crate::RejectKind::BadLength);
//! COBS error → [`Cobs`](crate::RejectKind::Cobs); CRC mismatch →
//! [`BadCrc`](crate::RejectKind::BadCrc); type byte not `0x01`/`0x7F` →
//! [`UnknownRecord`](crate::RejectKind::UnknownRecord); sample payload not 22 bytes →
//! `BadLength`; a channel code outside the 24-bit range (upper byte not the sign extension of
//! bit 23) or text that is not UTF-8 → [`Malformed`](crate::RejectKind::Malformed). The CRC is
//! checked before the type so that a corrupted type byte counts as corruption. Out-of-range
//! codes are rejected rather than masked: the data sheet promises sign-extended 24-bit codes,
//! and a frame that breaks it must not become a silently wrong value.

use crate::text::{Piece, Splitter};
use crate::{Decoded, RejectKind, Rejection};

/// Payload type byte of a sample frame.
pub const TYPE_SAMPLE: u8 = 0x01;
/// Payload type byte of a text frame.
pub const TYPE_TEXT: u8 = 0x7F;
/// Payload size of a sample frame: type 1 + seq 2 + t_us 4 + 3 × ch 4 + flags 1 + crc 2.
pub const SAMPLE_PAYLOAD_LEN: usize = 22;
/// Range of `RATE <hz>` the device accepts (instruments.md §2).
pub const RATE_MIN_HZ: u32 = 100;
pub const RATE_MAX_HZ: u32 = 20_000;
/// [`RATE_MIN_HZ`]`..=`[`RATE_MAX_HZ`], for range checks.
pub const RATE_HZ: std::ops::RangeInclusive<u32> = RATE_MIN_HZ..=RATE_MAX_HZ;
/// Full scale of the 24-bit codes: volts = code · 10.0 / 8388608.
pub const CODE_FULL_SCALE: f64 = 8_388_608.0;
pub const VOLTS_FULL_SCALE: f64 = 10.0;
/// Largest code a channel can carry (24-bit two's complement).
pub const CODE_MAX: i32 = 8_388_607;

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

/// Volts of a 24-bit code: code · 10.0 / 8388608.
///
/// Exact in f64: |code · 10| < 2^27 is an integer f64 holds exactly, and dividing by 2^23 only
/// changes the exponent. So every code has its own volts value and [`volts_code`] gives the
/// code back (the log stores codes and recomputes volts with this function,
/// docs/log-format.md).
#[inline]
pub fn code_volts(code: i32) -> f64 {
    f64::from(code) * VOLTS_FULL_SCALE / CODE_FULL_SCALE
}

/// The 24-bit code whose [`code_volts`] is `volts`, bit for bit; `None` for any other value
/// (between two codes, out of range, NaN, `-0.0`).
pub fn volts_code(volts: f64) -> Option<i32> {
    let c = volts * CODE_FULL_SCALE / VOLTS_FULL_SCALE;
    if !(c >= -CODE_FULL_SCALE && c <= CODE_MAX as f64) {
        return None;
    }
    let code = c as i32;
    (code_volts(code).to_bits() == volts.to_bits()).then_some(code)
}

impl SampleFrame {
    /// Volts of channel `i`: [`code_volts`].
    pub fn volts(&self) -> [f64; 3] {
        self.ch.map(code_volts)
    }
    /// Over-range flag of channel `i` (0-2).
    pub fn over_range(&self, i: usize) -> bool {
        i < 3 && self.flags & (1 << i) != 0
    }
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
pub struct Decoder {
    split: Splitter,
}
impl Decoder {
    pub fn new() -> Self {
        Self::default()
    }
}
impl crate::StreamDecoder for Decoder {
    type Frame = Frame;
    fn feed<S: FnMut(Decoded<Frame>)>(&mut self, bytes: &[u8], mut sink: S) {
        self.split.feed(bytes, MAX_FRAME, (0, 0), |p| match p {
            Piece::Line(run, _) => sink(match decode_run(run) {
                Ok(f) => Decoded::Frame(f),
                Err(kind) => Decoded::Reject(Rejection {
                    kind,
                    bytes: run.len() + 1,
                }),
            }),
            Piece::Overlong(n, _) => sink(Decoded::Reject(Rejection {
                kind: RejectKind::OverlongLine,
                bytes: n + 1,
            })),
        });
    }
    fn reset(&mut self) {
        self.split.reset();
    }
}

/// One COBS-encoded run without its `0x00`.
#[inline]
fn decode_run(run: &[u8]) -> Result<Frame, RejectKind> {
    if run.is_empty() {
        return Err(RejectKind::BadLength);
    }
    // The block-copying in-place decoder of the `cobs` crate on a stack copy: several times
    // faster than its byte-at-a-time state machine on the hot path.
    let mut buf = [0u8; MAX_FRAME];
    let buf = &mut buf[..run.len()];
    buf.copy_from_slice(run);
    let report = cobs::decode_in_place_report(buf).map_err(|_| RejectKind::Cobs)?;
    if report.parsed_size() != run.len() {
        return Err(RejectKind::Cobs);
    }
    decode_payload(&buf[..report.frame_size()])
}

/// A decoded payload (type byte to CRC).
pub fn decode_payload(p: &[u8]) -> Result<Frame, RejectKind> {
    let n = p.len();
    if n < 3 {
        return Err(RejectKind::BadLength);
    }
    let crc = u16::from_le_bytes([p[n - 2], p[n - 1]]);
    if crc16(&p[..n - 2]) != crc {
        return Err(RejectKind::BadCrc);
    }
    match p[0] {
        TYPE_SAMPLE => {
            if n != SAMPLE_PAYLOAD_LEN {
                return Err(RejectKind::BadLength);
            }
            let i32_at = |i: usize| i32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]]);
            let ch = [i32_at(7), i32_at(11), i32_at(15)];
            if ch.iter().any(|&c| !(-(1 << 23)..(1 << 23)).contains(&c)) {
                return Err(RejectKind::Malformed);
            }
            Ok(Frame::Sample(SampleFrame {
                seq: u16::from_le_bytes([p[1], p[2]]),
                t_us: u32::from_le_bytes([p[3], p[4], p[5], p[6]]),
                ch,
                flags: p[19],
            }))
        }
        TYPE_TEXT => std::str::from_utf8(&p[1..n - 2])
            .map(|s| Frame::Text(s.to_owned()))
            .map_err(|_| RejectKind::Malformed),
        _ => Err(RejectKind::UnknownRecord),
    }
}

/// The payload of a frame with its CRC, before COBS. Sample codes are written as given
/// (a code outside 24 bits makes a frame the decoder rejects, useful for fault injection).
pub fn encode_payload(f: &Frame, out: &mut Vec<u8>) {
    let start = out.len();
    match f {
        Frame::Sample(s) => {
            out.push(TYPE_SAMPLE);
            out.extend_from_slice(&s.seq.to_le_bytes());
            out.extend_from_slice(&s.t_us.to_le_bytes());
            for c in s.ch {
                out.extend_from_slice(&c.to_le_bytes());
            }
            out.push(s.flags);
        }
        Frame::Text(t) => {
            out.push(TYPE_TEXT);
            out.extend_from_slice(t.as_bytes());
        }
    }
    let crc = crc16(&out[start..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

/// Encode a frame: payload with CRC, COBS, trailing `0x00`.
pub fn encode(f: &Frame, out: &mut Vec<u8>) {
    let mut payload = Vec::with_capacity(32);
    encode_payload(f, &mut payload);
    encode_cobs(&payload, out);
}

/// COBS-encode any payload and append it with its `0x00` (for fault injection: a payload
/// with a bad CRC or unknown type).
pub fn encode_cobs(payload: &[u8], out: &mut Vec<u8>) {
    let start = out.len();
    out.resize(start + cobs::max_encoding_length(payload.len()), 0);
    let n = cobs::encode(payload, &mut out[start..]);
    out.truncate(start + n);
    out.push(0);
}

// Slice-by-16 tables: the sample CRC runs over 20 bytes per frame on the hot path.
const CCITT_FALSE: crc::Crc<u16, crc::Table<16>> =
    crc::Crc::<u16, crc::Table<16>>::new(&crc::CRC_16_IBM_3740);

/// CRC-16/CCITT-FALSE of `bytes`.
pub fn crc16(bytes: &[u8]) -> u16 {
    CCITT_FALSE.checksum(bytes)
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    Id,
    Rate(u32),
    Start,
    Stop,
}
impl Command {
    /// The command line including its `\n`.
    pub fn to_line(&self) -> String {
        match self {
            Command::Id => "ID?\n".into(),
            Command::Rate(hz) => format!("RATE {hz}\n"),
            Command::Start => "START\n".into(),
            Command::Stop => "STOP\n".into(),
        }
    }
    /// Parse a command line as the device does (line end optional). `RATE` with any `u32`
    /// parses; the range check (answer `ERR ...`) is the device's.
    pub fn parse(line: &str) -> Option<Command> {
        let l = line.strip_suffix('\n').unwrap_or(line);
        let l = l.strip_suffix('\r').unwrap_or(l);
        match l {
            "ID?" => Some(Command::Id),
            "START" => Some(Command::Start),
            "STOP" => Some(Command::Stop),
            _ => l
                .strip_prefix("RATE ")
                .and_then(|n| crate::text::parse_u32(n.as_bytes()))
                .map(Command::Rate),
        }
    }
}

/// A parsed text frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    Ok,
    Err(String),
    /// `CB-3,<serial>,<firmware>`
    Id {
        serial: String,
        firmware: String,
    },
    Other(String),
}
impl Answer {
    pub fn parse(text: &str) -> Answer {
        if text == "OK" {
            Answer::Ok
        } else if let Some(t) = text.strip_prefix("ERR ") {
            Answer::Err(t.to_owned())
        } else if let Some((serial, firmware)) =
            text.strip_prefix("CB-3,").and_then(|r| r.split_once(','))
        {
            Answer::Id {
                serial: serial.to_owned(),
                firmware: firmware.to_owned(),
            }
        } else {
            Answer::Other(text.to_owned())
        }
    }
    /// The text of the text frame.
    pub fn to_text(&self) -> String {
        match self {
            Answer::Ok => "OK".into(),
            Answer::Err(t) => format!("ERR {t}"),
            Answer::Id { serial, firmware } => format!("CB-3,{serial},{firmware}"),
            Answer::Other(t) => t.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StreamDecoder;

    fn decode_all(bytes: &[u8]) -> Vec<Decoded<Frame>> {
        let mut d = Decoder::new();
        let mut out = Vec::new();
        d.feed(bytes, |x| out.push(x));
        out
    }
    fn rej(kind: RejectKind, bytes: usize) -> Decoded<Frame> {
        Decoded::Reject(Rejection { kind, bytes })
    }

    #[test]
    fn crc_check_value() {
        // The catalogue check value of CRC-16/CCITT-FALSE (a.k.a. IBM-3740): "123456789" → 0x29B1.
        assert_eq!(crc16(b"123456789"), 0x29B1);
        assert_eq!(crc16(b""), 0xFFFF);
    }

    #[test]
    fn hand_worked_text_frame() {
        // Payload 7F 'O' 'K' F8 DC: CRC 0xDCF8 from Python's binascii.crc_hqx(b"\x7fOK", 0xFFFF)
        // (CRC-CCITT, init 0xFFFF, unreflected). No zero byte, so COBS is [6] + the 5 bytes.
        assert_eq!(crc16(&[0x7F, b'O', b'K']), 0xDCF8);
        let want = vec![0x06, 0x7F, b'O', b'K', 0xF8, 0xDC, 0x00];
        let mut enc = Vec::new();
        encode(&Frame::Text("OK".into()), &mut enc);
        assert_eq!(enc, want);
        assert_eq!(
            decode_all(&enc),
            vec![Decoded::Frame(Frame::Text("OK".into()))]
        );
    }

    #[test]
    fn sample_layout() {
        let s = SampleFrame {
            seq: 0x0102,
            t_us: 0x0304_0506,
            ch: [-1, 8_388_607, -8_388_608],
            flags: 5,
        };
        let mut p = Vec::new();
        encode_payload(&Frame::Sample(s), &mut p);
        assert_eq!(p.len(), SAMPLE_PAYLOAD_LEN);
        assert_eq!(&p[..7], &[0x01, 0x02, 0x01, 0x06, 0x05, 0x04, 0x03]);
        assert_eq!(&p[7..11], &[0xFF, 0xFF, 0xFF, 0xFF]);
        assert_eq!(&p[11..15], &[0xFF, 0xFF, 0x7F, 0x00]);
        assert_eq!(&p[15..19], &[0x00, 0x00, 0x80, 0xFF]);
        assert_eq!(p[19], 5);
        let mut enc = Vec::new();
        encode(&Frame::Sample(s), &mut enc);
        assert_eq!(enc.last(), Some(&0));
        assert!(!enc[..enc.len() - 1].contains(&0));
        assert_eq!(decode_all(&enc), vec![Decoded::Frame(Frame::Sample(s))]);
        let v = s.volts();
        assert_eq!(v[0], -10.0 / 8_388_608.0);
        assert_eq!(v[2], -10.0);
        assert!(s.over_range(0) && !s.over_range(1) && s.over_range(2) && !s.over_range(3));
    }

    /// Every 24-bit code → volts → the same code, and volts are exactly code · 10 / 2^23
    /// (checked with integer arithmetic: volts · 2^23 is an integer equal to code · 10).
    #[test]
    fn volts_and_codes_convert_exactly_both_ways() {
        for code in -(1 << 23)..(1 << 23) {
            let v = code_volts(code);
            assert_eq!(volts_code(v), Some(code), "code {code}");
            if code % 4099 == 0 || code.abs() >= CODE_MAX - 2 {
                let scaled = v * 8_388_608.0;
                assert_eq!(scaled.fract(), 0.0, "code {code}");
                assert_eq!(scaled as i64, i64::from(code) * 10, "code {code}");
            }
        }
        assert_eq!(code_volts(-(1 << 23)), -10.0);
        assert_eq!(code_volts(CODE_MAX), 10.0 - 10.0 / 8_388_608.0);
        let between = (code_volts(1) + code_volts(2)) / 2.0;
        for v in [
            between,
            -0.0,
            f64::NAN,
            10.0,
            -10.000_001,
            f64::INFINITY,
            1.0 / 3.0,
        ] {
            assert_eq!(volts_code(v), None, "{v}");
        }
    }

    #[test]
    fn rejections() {
        let s = SampleFrame {
            seq: 1,
            t_us: 2,
            ch: [3, 4, 5],
            flags: 0,
        };
        let mut p = Vec::new();
        encode_payload(&Frame::Sample(s), &mut p);
        // Bad CRC.
        let mut bad = p.clone();
        bad[5] ^= 0x10;
        let mut enc = Vec::new();
        encode_cobs(&bad, &mut enc);
        assert_eq!(decode_all(&enc), vec![rej(RejectKind::BadCrc, enc.len())]);
        // Wrong length with a good CRC.
        let mut short = p[..20].to_vec();
        let c = crc16(&short[..18]);
        short[18..20].copy_from_slice(&c.to_le_bytes());
        let mut enc = Vec::new();
        encode_cobs(&short, &mut enc);
        assert_eq!(
            decode_all(&enc),
            vec![rej(RejectKind::BadLength, enc.len())]
        );
        // Unknown type with a good CRC.
        let mut unk = vec![0x02, 1, 2, 3];
        let c = crc16(&unk);
        unk.extend_from_slice(&c.to_le_bytes());
        let mut enc = Vec::new();
        encode_cobs(&unk, &mut enc);
        assert_eq!(
            decode_all(&enc),
            vec![rej(RejectKind::UnknownRecord, enc.len())]
        );
        // Code outside 24 bits.
        let mut enc = Vec::new();
        encode(
            &Frame::Sample(SampleFrame {
                ch: [1 << 23, 0, 0],
                ..s
            }),
            &mut enc,
        );
        assert_eq!(
            decode_all(&enc),
            vec![rej(RejectKind::Malformed, enc.len())]
        );
        // Invalid UTF-8 text.
        let mut t = vec![0x7F, 0xFF, 0xFE];
        let c = crc16(&t);
        t.extend_from_slice(&c.to_le_bytes());
        let mut enc = Vec::new();
        encode_cobs(&t, &mut enc);
        assert_eq!(
            decode_all(&enc),
            vec![rej(RejectKind::Malformed, enc.len())]
        );
        // COBS error: code byte promises 9 bytes, 2 follow.
        assert_eq!(decode_all(&[9, 1, 2, 0]), vec![rej(RejectKind::Cobs, 4)]);
        // Empty run, too short.
        assert_eq!(decode_all(&[0]), vec![rej(RejectKind::BadLength, 1)]);
        assert_eq!(
            decode_all(&[3, 1, 2, 0]),
            vec![rej(RejectKind::BadLength, 4)]
        );
        // Over-long run, then a good frame.
        let mut stream = vec![1u8; 300];
        stream.push(0);
        let mut good = Vec::new();
        encode(&Frame::Sample(s), &mut good);
        stream.extend_from_slice(&good);
        assert_eq!(
            decode_all(&stream),
            vec![
                rej(RejectKind::OverlongLine, 301),
                Decoded::Frame(Frame::Sample(s))
            ]
        );
    }

    #[test]
    fn mid_frame_start_and_split() {
        let s = SampleFrame {
            seq: 9,
            t_us: 99,
            ch: [-300, 0, 77],
            flags: 0,
        };
        let mut enc = Vec::new();
        encode(&Frame::Sample(s), &mut enc);
        encode(&Frame::Sample(s), &mut enc);
        let one = enc.len() / 2;
        for cut in 1..one {
            let got = decode_all(&enc[cut..]);
            assert_eq!(got.len(), 2, "cut {cut}");
            assert!(
                matches!(got[0], Decoded::Reject(Rejection { bytes, .. }) if bytes == one - cut)
            );
            assert_eq!(got[1], Decoded::Frame(Frame::Sample(s)));
        }
        let mut d = Decoder::new();
        let mut out = Vec::new();
        for b in &enc {
            d.feed(std::slice::from_ref(b), |x| out.push(x));
        }
        assert_eq!(out, vec![Decoded::Frame(Frame::Sample(s)); 2]);
    }

    #[test]
    fn reset_forgets_partial_frame() {
        let s = SampleFrame {
            seq: 1,
            t_us: 2,
            ch: [3, 4, 5],
            flags: 0,
        };
        let mut enc = Vec::new();
        encode(&Frame::Sample(s), &mut enc);
        let mut d = Decoder::new();
        let mut out = Vec::new();
        d.feed(&enc[..10], |x| out.push(x));
        d.reset();
        d.feed(&enc, |x| out.push(x));
        assert_eq!(out, vec![Decoded::Frame(Frame::Sample(s))]);
    }

    #[test]
    fn commands_and_answers() {
        for c in [
            Command::Id,
            Command::Rate(20000),
            Command::Start,
            Command::Stop,
        ] {
            assert_eq!(Command::parse(&c.to_line()), Some(c.clone()));
        }
        assert_eq!(Command::Rate(100).to_line(), "RATE 100\n");
        assert_eq!(Command::parse("GO\n"), None);
        for a in [
            Answer::Ok,
            Answer::Err("rate out of range".into()),
            Answer::Id {
                serial: "42".into(),
                firmware: "1.0".into(),
            },
        ] {
            assert_eq!(Answer::parse(&a.to_text()), a);
        }
    }
}
