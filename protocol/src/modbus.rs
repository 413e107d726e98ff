//! Modbus RTU frames of the temperature module (instruments.md §5), sans I/O.
//!
//! The driver's transactions are made by `tokio-modbus`; this module is what the project
//! needs besides: the simulated module's slave side (parse a request, encode a response or
//! an exception), and the driver's classification of a transaction that `tokio-modbus` gave
//! up on (it drops a frame with a bad CRC byte by byte and then waits: the driver looks at the
//! bytes that did arrive to tell a bad CRC from silence). Every function takes any bytes and
//! never panics.

/// CRC-16/MODBUS (poly 0x8005 reflected, init 0xFFFF, no final XOR), sent low byte first.
pub const CRC: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_MODBUS);

/// Function 0x03, Read Holding Registers.
pub const READ_HOLDING: u8 = 0x03;
/// Function 0x04, Read Input Registers.
pub const READ_INPUT: u8 = 0x04;
/// Most registers one read may ask for (Modbus application protocol, 0x03/0x04).
pub const MAX_READ_REGISTERS: u16 = 125;
/// The longest RTU frame (Modbus over serial line, 2.5.1.1).
pub const MAX_FRAME_LEN: usize = 256;

/// Exception codes of the data sheet.
pub mod exception {
    pub const ILLEGAL_FUNCTION: u8 = 0x01;
    pub const ILLEGAL_DATA_ADDRESS: u8 = 0x02;
    pub const ILLEGAL_DATA_VALUE: u8 = 0x03;
    pub const DEVICE_FAILURE: u8 = 0x04;
    pub const DEVICE_BUSY: u8 = 0x06;
}

/// The CRC of `bytes`, as the two bytes that follow them on the wire.
pub fn crc_bytes(bytes: &[u8]) -> [u8; 2] {
    CRC.checksum(bytes).to_le_bytes()
}

/// `frame` with its CRC appended.
pub fn with_crc(mut frame: Vec<u8>) -> Vec<u8> {
    let c = crc_bytes(&frame);
    frame.extend_from_slice(&c);
    frame
}

/// Whether the last two bytes of `frame` are the CRC of the bytes before them.
pub fn crc_ok(frame: &[u8]) -> bool {
    frame.len() >= 3 && {
        let (body, crc) = frame.split_at(frame.len() - 2);
        crc_bytes(body) == [crc[0], crc[1]]
    }
}

/// A read request (0x03 / 0x04).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadRequest {
    pub unit: u8,
    pub function: u8,
    pub start: u16,
    pub count: u16,
}

impl ReadRequest {
    /// The request's 8 bytes, CRC included.
    pub fn encode(&self) -> Vec<u8> {
        let [sh, sl] = self.start.to_be_bytes();
        let [ch, cl] = self.count.to_be_bytes();
        with_crc(vec![self.unit, self.function, sh, sl, ch, cl])
    }
}

/// What the start of a slave's receive buffer holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RequestParse {
    /// Fewer bytes than a request has: wait for more (or for the 3.5-character gap).
    Incomplete,
    /// A request with a good CRC, `len` bytes long. `function` may be one this module does
    /// not support (answered with exception 01); its fields are then meaningless.
    Request { req: ReadRequest, len: usize },
    /// The first 8 bytes are not a request with a good CRC: drop a byte and look again.
    BadCrc,
}

/// Parse a request at the start of `buf`. Only the 8-byte requests (functions 0x01-0x06)
/// are recognised; anything else has a bad CRC as far as this module can tell.
pub fn parse_request(buf: &[u8]) -> RequestParse {
    if buf.len() < 8 {
        return RequestParse::Incomplete;
    }
    let f = &buf[..8];
    if !crc_ok(f) {
        return RequestParse::BadCrc;
    }
    RequestParse::Request {
        req: ReadRequest {
            unit: f[0],
            function: f[1],
            start: u16::from_be_bytes([f[2], f[3]]),
            count: u16::from_be_bytes([f[4], f[5]]),
        },
        len: 8,
    }
}

/// The response to a read: `unit`, `function`, byte count, the registers big-endian, CRC.
pub fn encode_read_response(unit: u8, function: u8, registers: &[u16]) -> Vec<u8> {
    let mut f = vec![unit, function, (registers.len() * 2).min(255) as u8];
    for r in registers {
        f.extend_from_slice(&r.to_be_bytes());
    }
    with_crc(f)
}

/// An exception response: `unit`, `function | 0x80`, `code`, CRC.
pub fn encode_exception(unit: u8, function: u8, code: u8) -> Vec<u8> {
    with_crc(vec![unit, function | 0x80, code])
}

/// What the bytes received for one read request are.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Response {
    /// The registers, the frame's CRC good.
    Registers(Vec<u16>),
    /// An exception response with its code.
    Exception(u8),
    /// A frame of the expected length whose CRC does not match.
    BadCrc,
    /// No byte at all.
    Nothing,
    /// Bytes, but too few for the frame they start (the rest did not come).
    Truncated,
    /// Bytes that are not an answer to this request: another unit or function, a byte count
    /// that is not twice the registers asked for, or bytes after the frame.
    Malformed,
}

/// Classify the bytes `buf` received after the read request `req`. Never panics.
pub fn parse_response(req: &ReadRequest, buf: &[u8]) -> Response {
    if buf.is_empty() {
        return Response::Nothing;
    }
    if buf[0] != req.unit {
        return Response::Malformed;
    }
    let Some(&function) = buf.get(1) else {
        return Response::Truncated;
    };
    let len = if function == req.function | 0x80 {
        5
    } else if function == req.function {
        match buf.get(2) {
            None => return Response::Truncated,
            Some(&n) if n as usize != 2 * req.count as usize => return Response::Malformed,
            Some(&n) => 5 + n as usize,
        }
    } else {
        return Response::Malformed;
    };
    if buf.len() < len {
        return Response::Truncated;
    }
    let frame = &buf[..len];
    if !crc_ok(frame) {
        return Response::BadCrc;
    }
    if buf.len() > len {
        return Response::Malformed;
    }
    if function & 0x80 != 0 {
        return Response::Exception(frame[2]);
    }
    Response::Registers(
        frame[3..len - 2]
            .chunks_exact(2)
            .map(|c| u16::from_be_bytes([c[0], c[1]]))
            .collect(),
    )
}

/// The silence that ends a frame (3.5 characters of 11 bits: 8N1 with start and stop bits
/// is 10, the specification counts 11) at `baud`, and the fixed 1750 µs above 19200 baud
/// (Modbus over serial line, 2.5.1.1).
pub fn frame_gap_us(baud: u32) -> u64 {
    if baud == 0 || baud > 19_200 {
        1750
    } else {
        (3.5 * 11.0 * 1e6 / baud as f64).ceil() as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_of_the_specifications_example() {
        // Modbus over serial line V1.02, 6.2.2: "02 07" has CRC 0x1241, sent 41 12.
        assert_eq!(crc_bytes(&[0x02, 0x07]), [0x41, 0x12]);
        // A read of 1 input register at 0 from unit 1, as every Modbus tool prints it.
        let r = ReadRequest {
            unit: 1,
            function: READ_INPUT,
            start: 0,
            count: 1,
        };
        assert_eq!(r.encode(), [0x01, 0x04, 0x00, 0x00, 0x00, 0x01, 0x31, 0xCA]);
        assert_eq!(
            parse_request(&r.encode()),
            RequestParse::Request { req: r, len: 8 }
        );
    }

    #[test]
    fn responses_are_classified() {
        let req = ReadRequest {
            unit: 7,
            function: READ_INPUT,
            start: 0,
            count: 2,
        };
        let ok = encode_read_response(7, READ_INPUT, &[0x00E1, 0x8000]);
        assert_eq!(
            parse_response(&req, &ok),
            Response::Registers(vec![0x00E1, 0x8000])
        );
        let mut bad = ok.clone();
        *bad.last_mut().unwrap() ^= 0x01;
        assert_eq!(parse_response(&req, &bad), Response::BadCrc);
        assert_eq!(parse_response(&req, &ok[..6]), Response::Truncated);
        assert_eq!(parse_response(&req, &[]), Response::Nothing);
        let ex = encode_exception(7, READ_INPUT, exception::ILLEGAL_DATA_ADDRESS);
        assert_eq!(parse_response(&req, &ex), Response::Exception(2));
        let other = encode_read_response(8, READ_INPUT, &[1, 2]);
        assert_eq!(parse_response(&req, &other), Response::Malformed);
        assert_eq!(frame_gap_us(9600), 4011);
        assert_eq!(frame_gap_us(115_200), 1750);
    }
}
