//! Checks shared by the cargo-fuzz targets (`protocol/fuzz`) and the seed-corpus replay test:
//! each panics when a decoder breaks one of its promises on `data`. Not part of the API.

use crate::{Decoded, StreamDecoder, cb3, li80, psd, slcan};

fn run<D: StreamDecoder + Default>(chunks: &[&[u8]]) -> Vec<Decoded<D::Frame>> {
    let mut d = D::default();
    let mut out = Vec::new();
    for c in chunks {
        d.feed(c, |x| out.push(x));
    }
    out
}

/// Whole, split at a point taken from the data, and byte by byte: the same output. Rejections
/// never account for more bytes than were fed.
fn chunking<D>(data: &[u8]) -> Vec<Decoded<D::Frame>>
where
    D: StreamDecoder + Default,
    D::Frame: PartialEq + std::fmt::Debug,
{
    let whole = run::<D>(&[data]);
    let at = data
        .first()
        .map_or(0, |&b| usize::from(b) * data.len() / 256);
    let (a, b) = data.split_at(at);
    assert_eq!(run::<D>(&[a, b]), whole, "split at {at} changed the output");
    if data.len() <= 1024 {
        let bytes: Vec<&[u8]> = data.chunks(1).collect();
        assert_eq!(
            run::<D>(&bytes),
            whole,
            "byte-by-byte feeding changed the output"
        );
    }
    let rejected: usize = whole
        .iter()
        .map(|d| match d {
            Decoded::Reject(r) => r.bytes,
            Decoded::Frame(_) => 0,
        })
        .sum();
    assert!(
        rejected <= data.len(),
        "rejections account for {rejected} of {} bytes",
        data.len()
    );
    whole
}

fn frames<F>(out: Vec<Decoded<F>>) -> impl Iterator<Item = F> {
    out.into_iter().filter_map(|d| match d {
        Decoded::Frame(f) => Some(f),
        Decoded::Reject(_) => None,
    })
}

/// Every record re-encodes to a line that decodes to the same record.
pub fn li80(data: &[u8]) {
    for f in frames(chunking::<li80::Decoder>(data)) {
        let mut enc = Vec::new();
        li80::encode_line(&f, &mut enc);
        let again: Vec<_> = frames(run::<li80::Decoder>(&[&enc])).collect();
        assert_eq!(
            again,
            vec![f],
            "re-encoded {:?}",
            String::from_utf8_lossy(&enc)
        );
    }
}

/// Every frame re-encodes to a frame that decodes to itself, and its payload's CRC verifies.
pub fn cb3(data: &[u8]) {
    for f in frames(chunking::<cb3::Decoder>(data)) {
        let mut p = Vec::new();
        cb3::encode_payload(&f, &mut p);
        let n = p.len();
        assert_eq!(
            cb3::crc16(&p[..n - 2]),
            u16::from_le_bytes([p[n - 2], p[n - 1]])
        );
        if let cb3::Frame::Sample(s) = &f {
            assert!(s.ch.iter().all(|c| (-(1 << 23)..(1 << 23)).contains(c)));
        }
        let mut enc = Vec::new();
        cb3::encode(&f, &mut enc);
        let again: Vec<_> = frames(run::<cb3::Decoder>(&[&enc])).collect();
        assert_eq!(again, vec![f]);
    }
}

/// Every data line re-encodes and decodes to itself.
pub fn psd(data: &[u8]) {
    for f in frames(chunking::<psd::Decoder>(data)) {
        if let psd::Line::Data(d) = f {
            let mut enc = Vec::new();
            psd::encode_data(&d, &mut enc);
            let again: Vec<_> = frames(run::<psd::Decoder>(&[&enc])).collect();
            assert_eq!(again, vec![psd::Line::Data(d)]);
        }
    }
}

/// Every CAN frame is in range and re-encodes and decodes to itself.
pub fn slcan(data: &[u8]) {
    for f in frames(chunking::<slcan::Decoder>(data)) {
        if let slcan::Message::Frame(c) = f {
            assert!(c.data.len() <= 8);
            assert!(c.id <= if c.extended { 0x1FFF_FFFF } else { 0x7FF });
            assert!(
                c.timestamp_ms
                    .is_none_or(|t| t < slcan::TIMESTAMP_MODULUS_MS)
            );
            let mut enc = Vec::new();
            slcan::encode_frame(&c, &mut enc);
            let again: Vec<_> = frames(run::<slcan::Decoder>(&[&enc])).collect();
            assert_eq!(again, vec![slcan::Message::Frame(c)]);
        }
    }
}

/// The CAN trigger path: a payload decodes to a trigger or a typed error (never a panic), and
/// a decoded trigger re-encodes to the same 8 bytes; the payloads of the frames an SLCAN
/// stream carries take the same path (`drivers::trigger` hands both transports' frames to
/// [`crate::can::TriggerFrame::decode`]).
pub fn can(data: &[u8]) {
    let payload = &data[..data.len().min(16)];
    if let Ok(t) = crate::can::TriggerFrame::decode(payload) {
        assert_eq!(t.encode().as_slice(), payload);
    }
    for f in frames(run::<slcan::Decoder>(&[data])) {
        if let slcan::Message::Frame(c) = f
            && let Ok(t) = crate::can::TriggerFrame::decode(&c.data)
        {
            assert_eq!(t.encode().as_slice(), c.data.as_slice());
        }
    }
}
