//! Shared machinery of the byte-stream decoders: splitting at a boundary byte with a length
//! cap, and allocation-free number parsing for the hot path of the ASCII protocols.

/// One piece of the stream between two boundaries.
pub(crate) enum Piece<'a> {
    /// A complete piece (terminator excluded) and the terminator that ended it.
    Line(&'a [u8], u8),
    /// A piece longer than the cap: `usize` bytes were discarded before the terminator `u8`.
    Overlong(usize, u8),
}

/// Splits a byte stream at terminator bytes, keeping a partial piece between calls. Pieces
/// wholly inside one chunk are handed out without copying.
#[derive(Debug, Default)]
pub(crate) struct Splitter {
    buf: Vec<u8>,
    /// Set while discarding an over-long piece up to the next terminator.
    discarding: bool,
    discarded: usize,
}

impl Splitter {
    pub(crate) fn reset(&mut self) {
        self.buf.clear();
        self.discarding = false;
        self.discarded = 0;
    }

    /// Feed `bytes`; the bytes `term.0` and `term.1` (the same byte for one terminator) end a
    /// piece; pieces longer than `limit` bytes (terminator excluded) are reported as
    /// [`Piece::Overlong`].
    #[inline]
    pub(crate) fn feed(
        &mut self,
        bytes: &[u8],
        limit: usize,
        term: (u8, u8),
        mut on_piece: impl FnMut(Piece<'_>),
    ) {
        let mut rest = bytes;
        while !rest.is_empty() {
            match find2(rest, term.0, term.1) {
                Some(i) => {
                    let part = &rest[..i];
                    let term = rest[i];
                    rest = &rest[i + 1..];
                    if self.discarding {
                        let n = self.discarded + i;
                        self.discarding = false;
                        self.discarded = 0;
                        on_piece(Piece::Overlong(n, term));
                    } else if self.buf.is_empty() {
                        if part.len() > limit {
                            on_piece(Piece::Overlong(part.len(), term));
                        } else {
                            on_piece(Piece::Line(part, term));
                        }
                    } else if self.buf.len() + part.len() > limit {
                        let n = self.buf.len() + part.len();
                        self.buf.clear();
                        on_piece(Piece::Overlong(n, term));
                    } else {
                        self.buf.extend_from_slice(part);
                        on_piece(Piece::Line(&self.buf, term));
                        self.buf.clear();
                    }
                }
                None => {
                    if self.discarding {
                        self.discarded = self.discarded.saturating_add(rest.len());
                    } else if self.buf.len() + rest.len() > limit {
                        self.discarding = true;
                        self.discarded = self.buf.len() + rest.len();
                        self.buf.clear();
                    } else {
                        if self.buf.capacity() == 0 {
                            self.buf.reserve(limit);
                        }
                        self.buf.extend_from_slice(rest);
                    }
                    break;
                }
            }
        }
    }
}

const LO: u64 = 0x0101_0101_0101_0101;
const HI: u64 = 0x8080_8080_8080_8080;

/// Position of the first byte equal to `a` or `b`, eight bytes at a time (the SWAR zero-byte
/// test of Mycroft; a false positive can only follow a true match, so the lowest flagged byte
/// is exact).
#[inline]
pub(crate) fn find2(hay: &[u8], a: u8, b: u8) -> Option<usize> {
    let (sa, sb) = (LO * u64::from(a), LO * u64::from(b));
    let mut chunks = hay.chunks_exact(8);
    let mut base = 0;
    for c in &mut chunks {
        let x = u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]);
        let (xa, xb) = (x ^ sa, x ^ sb);
        let m = (xa.wrapping_sub(LO) & !xa & HI) | (xb.wrapping_sub(LO) & !xb & HI);
        if m != 0 {
            return Some(base + (m.trailing_zeros() / 8) as usize);
        }
        base += 8;
    }
    chunks
        .remainder()
        .iter()
        .position(|&x| x == a || x == b)
        .map(|i| base + i)
}

/// Unsigned decimal: one or more digits, nothing else (no sign, no spaces).
#[inline]
pub(crate) fn parse_u64(s: &[u8]) -> Option<u64> {
    if s.is_empty() || s.len() > 20 {
        return None;
    }
    let mut v: u64 = 0;
    for &b in s {
        let d = b.wrapping_sub(b'0');
        if d > 9 {
            return None;
        }
        v = v.checked_mul(10)?.checked_add(u64::from(d))?;
    }
    Some(v)
}

#[inline]
pub(crate) fn parse_u32(s: &[u8]) -> Option<u32> {
    if s.len() > 10 {
        return None;
    }
    u32::try_from(parse_u64(s)?).ok()
}

/// Signed decimal: optional `-`, then digits.
#[inline]
pub(crate) fn parse_i64(s: &[u8]) -> Option<i64> {
    match s.split_first() {
        Some((b'-', mag)) => {
            let m = parse_u64(mag)?;
            if m > i64::MAX as u64 + 1 {
                None
            } else {
                Some((m as i64).wrapping_neg())
            }
        }
        _ => i64::try_from(parse_u64(s)?).ok(),
    }
}

#[inline]
pub(crate) fn parse_i32(s: &[u8]) -> Option<i32> {
    i32::try_from(parse_i64(s)?).ok()
}

#[inline]
pub(crate) fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        b'a'..=b'f' => Some(b - b'a' + 10),
        _ => None,
    }
}

#[inline]
pub(crate) fn hex_digit_upper(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        _ => None,
    }
}

/// Plain decimal number as the data sheets define it: `-?[0-9]+(\.[0-9]+)?`; no exponent,
/// no `inf`/`NaN`, no `+`, no thousands separators.
pub(crate) fn parse_decimal(s: &[u8]) -> Option<f64> {
    let mag = s.strip_prefix(b"-").unwrap_or(s);
    let (int, frac) = match mag.iter().position(|&b| b == b'.') {
        Some(i) => (&mag[..i], Some(&mag[i + 1..])),
        None => (mag, None),
    };
    if int.is_empty() || !int.iter().all(u8::is_ascii_digit) {
        return None;
    }
    if frac.is_some_and(|f| f.is_empty() || !f.iter().all(u8::is_ascii_digit)) {
        return None;
    }
    std::str::from_utf8(s).ok()?.parse().ok()
}

/// Splits `s` at commas into `out`; returns the number of fields (which may exceed
/// `out.len()`, in which case the extra fields are not stored).
#[inline]
pub(crate) fn split_fields<'a, const N: usize>(s: &'a [u8], out: &mut [&'a [u8]; N]) -> usize {
    let mut n = 0;
    for f in s.split(|&b| b == b',') {
        if n < N {
            out[n] = f;
        }
        n += 1;
    }
    n
}

/// Number of comma-separated fields of `s` (a vectorisable count, no splitting).
#[inline]
pub(crate) fn field_count(s: &[u8]) -> usize {
    s.iter().filter(|&&b| b == b',').count() + 1
}

/// Parses comma-separated fields in one pass, each number up to the next `,` or the end. The
/// caller checks the field count first (so a failure here means a malformed field).
pub(crate) struct Fields<'a> {
    s: &'a [u8],
    i: usize,
}

impl<'a> Fields<'a> {
    #[inline]
    pub(crate) fn new(s: &'a [u8]) -> Self {
        Fields { s, i: 0 }
    }

    /// Consumes the field separator: `,` or the end of the input.
    #[inline]
    fn end_field(&mut self) -> Option<()> {
        match self.s.get(self.i) {
            None => Some(()),
            Some(b',') => {
                self.i += 1;
                Some(())
            }
            Some(_) => None,
        }
    }

    /// Skips a field whatever it holds.
    #[inline]
    pub(crate) fn skip(&mut self) {
        while self.i < self.s.len() && self.s[self.i] != b',' {
            self.i += 1;
        }
        if self.i < self.s.len() {
            self.i += 1;
        }
    }

    /// Unsigned decimal field (digits only).
    #[inline]
    pub(crate) fn u64(&mut self) -> Option<u64> {
        let start = self.i;
        let mut v: u64 = 0;
        while let Some(&b) = self.s.get(self.i) {
            let d = b.wrapping_sub(b'0');
            if d > 9 {
                break;
            }
            v = v.checked_mul(10)?.checked_add(u64::from(d))?;
            self.i += 1;
        }
        if self.i == start {
            return None;
        }
        self.end_field()?;
        Some(v)
    }

    #[inline]
    pub(crate) fn u32(&mut self) -> Option<u32> {
        u32::try_from(self.u64()?).ok()
    }

    /// Signed decimal field: optional `-`, digits.
    #[inline]
    pub(crate) fn i64(&mut self) -> Option<i64> {
        if self.s.get(self.i) == Some(&b'-') {
            self.i += 1;
            let m = self.u64()?;
            if m > i64::MAX as u64 + 1 {
                None
            } else {
                Some((m as i64).wrapping_neg())
            }
        } else {
            i64::try_from(self.u64()?).ok()
        }
    }

    #[inline]
    pub(crate) fn i32(&mut self) -> Option<i32> {
        i32::try_from(self.i64()?).ok()
    }

    /// Hexadecimal field, 1 to 8 digits of either case.
    #[inline]
    pub(crate) fn hex_u32(&mut self) -> Option<u32> {
        let start = self.i;
        let mut v = 0u32;
        while let Some(d) = self.s.get(self.i).and_then(|&b| hex_digit(b)) {
            if self.i - start == 8 {
                return None;
            }
            v = (v << 4) | u32::from(d);
            self.i += 1;
        }
        if self.i == start {
            return None;
        }
        self.end_field()?;
        Some(v)
    }
}

/// Printable ASCII (0x20-0x7E) only, and not empty.
#[inline]
pub(crate) fn printable(s: &[u8]) -> bool {
    !s.is_empty() && s.iter().all(|&b| (0x20..=0x7E).contains(&b))
}

/// The bytes as a `String`, when they are printable ASCII.
pub(crate) fn printable_string(s: &[u8]) -> Option<String> {
    if printable(s) {
        // Printable ASCII is valid UTF-8.
        std::str::from_utf8(s).ok().map(str::to_owned)
    } else {
        None
    }
}

/// Strips one trailing `\r` (lines may end in `\r\n`).
#[inline]
pub(crate) fn strip_cr(s: &[u8]) -> &[u8] {
    s.strip_suffix(b"\r").unwrap_or(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers() {
        assert_eq!(parse_u64(b"0"), Some(0));
        assert_eq!(parse_u64(b"18446744073709551615"), Some(u64::MAX));
        assert_eq!(parse_u64(b"18446744073709551616"), None);
        assert_eq!(parse_u64(b""), None);
        assert_eq!(parse_u64(b"+1"), None);
        assert_eq!(parse_u64(b"1 "), None);
        assert_eq!(parse_u32(b"4294967295"), Some(u32::MAX));
        assert_eq!(parse_u32(b"4294967296"), None);
        assert_eq!(parse_i64(b"-9223372036854775808"), Some(i64::MIN));
        assert_eq!(parse_i64(b"-9223372036854775809"), None);
        assert_eq!(parse_i64(b"9223372036854775807"), Some(i64::MAX));
        assert_eq!(parse_i64(b"9223372036854775808"), None);
        assert_eq!(parse_i64(b"-"), None);
        assert_eq!(parse_i64(b"--1"), None);
        assert_eq!(parse_i32(b"-2147483648"), Some(i32::MIN));
        assert_eq!(parse_i32(b"2147483648"), None);
    }

    #[test]
    fn fields_cursor() {
        let mut f = Fields::new(b"POS,4294967295,18446744073709551615,-9223372036854775808,1a,-5");
        f.skip();
        assert_eq!(f.u32(), Some(u32::MAX));
        assert_eq!(f.u64(), Some(u64::MAX));
        assert_eq!(f.i64(), Some(i64::MIN));
        assert_eq!(f.hex_u32(), Some(0x1A));
        assert_eq!(f.i32(), Some(-5));
        for (s, ok) in [
            (&b"12x"[..], false),
            (b"", false),
            (b"-", false),
            (b"1,", true),
            (b"+1", false),
        ] {
            assert_eq!(
                Fields::new(s).i64().is_some(),
                ok,
                "{:?}",
                std::str::from_utf8(s)
            );
        }
        assert_eq!(Fields::new(b"123456789").hex_u32(), None);
        assert_eq!(Fields::new(b"FFFFFFFF").hex_u32(), Some(u32::MAX));
        assert_eq!(Fields::new(b"1f").hex_u32(), Some(31));
        assert_eq!(Fields::new(b"G").hex_u32(), None);
        assert_eq!(Fields::new(b"4294967296").u32(), None);
        assert_eq!(field_count(b"a,b,,c"), 4);
        assert_eq!(field_count(b""), 1);
    }

    #[test]
    fn decimals() {
        assert_eq!(parse_decimal(b"20.125"), Some(20.125));
        assert_eq!(parse_decimal(b"-0.5"), Some(-0.5));
        assert_eq!(parse_decimal(b"101325"), Some(101325.0));
        for bad in [
            &b"1e5"[..],
            b"inf",
            b"NaN",
            b".5",
            b"5.",
            b"+1",
            b"1,5",
            b"",
            b"-",
            b"1.2.3",
        ] {
            assert_eq!(parse_decimal(bad), None, "{:?}", std::str::from_utf8(bad));
        }
    }

    fn pieces(chunks: &[&[u8]], limit: usize) -> Vec<(Vec<u8>, usize, u8)> {
        let mut s = Splitter::default();
        let mut out = Vec::new();
        for c in chunks {
            s.feed(c, limit, (b'\n', b'\n'), |p| match p {
                Piece::Line(l, t) => out.push((l.to_vec(), 0, t)),
                Piece::Overlong(n, t) => out.push((Vec::new(), n, t)),
            });
        }
        out
    }

    #[test]
    fn find2_matches_naive_search() {
        let hay: Vec<u8> = (0..200u32).map(|i| (i * 37 % 251) as u8).collect();
        for start in 0..40 {
            for (a, b) in [(0u8, 0u8), (b'\n', b'\n'), (7, 13), (200, 1), (0x80, 0xFF)] {
                let h = &hay[start..];
                let naive = h.iter().position(|&x| x == a || x == b);
                assert_eq!(find2(h, a, b), naive, "start {start}, {a} {b}");
            }
        }
        assert_eq!(find2(b"", 1, 2), None);
        assert_eq!(find2(&[0x81, 0x00, 0x01], 0x01, 0x01), Some(2));
        assert_eq!(find2(&[0xFF; 16], 0xFE, 0xFE), None);
    }

    #[test]
    fn splitter_keeps_partial_and_caps() {
        let got = pieces(&[b"ab", b"c\nde", b"f\n"], 4);
        assert_eq!(
            got,
            vec![(b"abc".to_vec(), 0, b'\n'), (b"def".to_vec(), 0, b'\n')]
        );
        // 6 bytes over two chunks with cap 4, then a good line.
        let got = pieces(&[b"abc", b"def", b"\nok\n"], 4);
        assert_eq!(got, vec![(vec![], 6, b'\n'), (b"ok".to_vec(), 0, b'\n')]);
        let got = pieces(&[b"abcdefgh\nxy\n"], 4);
        assert_eq!(got, vec![(vec![], 8, b'\n'), (b"xy".to_vec(), 0, b'\n')]);
        let got = pieces(&[b"ab", b"cdefgh\nxy\n"], 4);
        assert_eq!(got, vec![(vec![], 8, b'\n'), (b"xy".to_vec(), 0, b'\n')]);
    }
}
