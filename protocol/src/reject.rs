//! Why a decoder discarded bytes. Every rejection is counted per instrument by the drivers.

/// The kind of a rejection; the counters of the drivers are keyed by it.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum RejectKind {
    /// The XOR checksum of an NMEA-style line did not match.
    BadChecksum,
    /// The CRC of a binary frame did not match.
    BadCrc,
    /// A line that does not have the shape of its record (no `*HH`, unparsable number, ...).
    Malformed,
    /// A record with the wrong number of fields.
    FieldCount,
    /// A record whose name or type byte is not in the data sheet.
    UnknownRecord,
    /// A line longer than any valid line; discarded up to the next line end.
    OverlongLine,
    /// A COBS frame that does not decode.
    Cobs,
    /// A binary frame of the wrong length for its type.
    BadLength,
    /// A polled device did not answer a request in time (Modbus RTU, instruments.md §5).
    Timeout,
    /// A polled device answered a request with an exception response (Modbus RTU).
    Exception,
}

impl RejectKind {
    pub const ALL: [RejectKind; 10] = [
        RejectKind::BadChecksum,
        RejectKind::BadCrc,
        RejectKind::Malformed,
        RejectKind::FieldCount,
        RejectKind::UnknownRecord,
        RejectKind::OverlongLine,
        RejectKind::Cobs,
        RejectKind::BadLength,
        RejectKind::Timeout,
        RejectKind::Exception,
    ];
    pub fn name(self) -> &'static str {
        match self {
            RejectKind::BadChecksum => "bad_checksum",
            RejectKind::BadCrc => "bad_crc",
            RejectKind::Malformed => "malformed",
            RejectKind::FieldCount => "field_count",
            RejectKind::UnknownRecord => "unknown_record",
            RejectKind::OverlongLine => "overlong_line",
            RejectKind::Cobs => "cobs",
            RejectKind::BadLength => "bad_length",
            RejectKind::Timeout => "timeout",
            RejectKind::Exception => "exception",
        }
    }
}

/// Bytes a decoder discarded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rejection {
    pub kind: RejectKind,
    /// How many bytes were discarded with it (including the terminator).
    pub bytes: usize,
}
