//! Wire formats of the instruments metrolog reads, as pure codecs: bytes in, frames and counted
//! rejections out. No I/O and no async here, so every decoder can be fed from a port, a file, a
//! fuzzer or a property test alike (the sans-IO shape of the `mcap` crate).
//!
//! One module per instrument of `docs/instruments.md`:
//! - [`li80`]: LI-80 laser interferometer, NMEA-style ASCII lines with XOR checksum;
//! - [`cb3`]: CB-3 CapBall ADC, COBS-framed binary payloads with CRC-16/CCITT-FALSE;
//! - [`psd`]: PSD-2 transimpedance board, SCPI commands and unchecked CSV data lines;
//! - [`can`]: CNC exact-stop trigger frames (CAN 2.0A payload) and [`slcan`] (Lawicel text).
//!
//! The host-side conversions are in [`edlen`] (refractive index of air) and [`convert`].
//!
//! # Data-sheet limits
//!
//! The numbers of `docs/instruments.md` are defined here and nowhere else in the workspace
//! (the daemon's config checks, the simulator and the analyses use these):
//! - rates: [`li80::RATE_HZ`] (1–10000 Hz), [`cb3::RATE_HZ`] (100–20000 Hz),
//!   [`psd::RATE_HZ`] (1–1000 Hz), and [`POWER_UP_RATE_HZ`] (10 Hz, every device);
//! - links: [`psd::BAUDS`], [`psd::DEFAULT_BAUD`], [`psd::LINE_BITS`],
//!   [`can::STANDARD_ID_MAX`], [`can::DEFAULT_CAN_ID`];
//! - sensor ranges: [`li80::SIG_MIN`], [`cb3::CODE_MAX`], [`cb3::CODE_FULL_SCALE`],
//!   [`cb3::VOLTS_FULL_SCALE`], [`convert::AIR_C_RANGE`], [`convert::AIR_PA_RANGE`],
//!   [`convert::RH_PCT_RANGE`], [`convert::MATERIAL_C_RANGE`], [`convert::PSD_LX_MM`],
//!   [`convert::PSD_LY_MM`], [`convert::CapBallPoly::NOMINAL`];
//! - material expansion coefficients α: [`convert::ALPHA_STEEL_UM_PER_M_K`] (the default of the
//!   measured axis, 11.7 µm/(m·K)), [`convert::HEAD_ALPHA_UM_PER_M_K`] (invar of the PSD head).
//!
//! ```
//! use protocol::{Decoded, RejectKind, StreamDecoder, li80};
//!
//! let mut dec = li80::Decoder::new();
//! let mut out = Vec::new();
//! // The port opened in the middle of a record; the next one arrives in two reads.
//! dec.feed(b"50,0*65\r\n$POS,1,2,3,", |d| out.push(d));
//! dec.feed(b"50,0*65\r\n", |d| out.push(d));
//! assert!(matches!(&out[0], Decoded::Reject(r) if r.kind == RejectKind::Malformed && r.bytes == 9));
//! assert!(matches!(&out[1], Decoded::Frame(li80::Line::Pos(p)) if p.seq == 1 && p.raw_nm == 3));
//! ```

pub mod can;
pub mod cb3;
pub mod convert;
pub mod edlen;
#[doc(hidden)]
pub mod fuzzcheck;
pub mod li80;
pub mod modbus;
pub mod psd;
pub mod reject;
pub mod slcan;
mod text;

pub use reject::{RejectKind, Rejection};

/// Rate every instrument streams at after power-up, until told otherwise (instruments.md,
/// introduction).
pub const POWER_UP_RATE_HZ: u32 = 10;

/// What a streaming decoder hands out for the bytes it was fed.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded<F> {
    /// A frame that passed every check of its format.
    Frame(F),
    /// Bytes that were discarded, and why. The decoder has already resynchronised.
    Reject(Rejection),
}

/// A streaming decoder: feed it chunks of any size, split anywhere; it calls `sink` for every
/// complete frame and every rejection, in stream order, and keeps a partial frame for the next
/// call. It never panics on any input and never loses a valid frame that follows garbage.
pub trait StreamDecoder {
    type Frame;
    fn feed<S: FnMut(Decoded<Self::Frame>)>(&mut self, bytes: &[u8], sink: S);
    /// Forget any partial frame (after a reconnect).
    fn reset(&mut self);
}
