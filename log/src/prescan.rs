//! A pass over the record headers of a file before the `mcap` reader sees it, for damage that
//! reader does not survive. In an uncompressed chunk, `mcap` 0.26's `LinearReader` subtracts
//! each inner record's length from what is left of the chunk without checking it
//! (`sans_io/linear_reader.rs`, `compressed_remaining -= …`): a record that claims to run past
//! its chunk's end panics in a debug build and wraps in a release build (found by the
//! `mcap_reader` fuzz target with overflow checks on; the input is kept in its corpus). The
//! reader is then fed the file only up to such a chunk.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};

const CHUNK: u8 = 0x06;
const FOOTER: u8 = 0x02;

/// Byte offset of the first uncompressed chunk whose records run past its end (None: no such
/// chunk before the footer or the first truncated record). Leaves `file` at its start.
pub(crate) fn first_bad_chunk(file: &mut File, file_bytes: u64) -> std::io::Result<Option<u64>> {
    let mut pos = 8u64;
    let mut bad = None;
    while let Some((opcode, len)) = header_at(file, pos, file_bytes)? {
        let Some(end) = (pos + 9).checked_add(len).filter(|e| *e <= file_bytes) else {
            break;
        };
        if opcode == FOOTER {
            break;
        }
        if opcode == CHUNK && !uncompressed_chunk_fits(file, pos + 9, end)? {
            bad = Some(pos);
            break;
        }
        pos = end;
    }
    file.seek(SeekFrom::Start(0))?;
    Ok(bad)
}

/// Opcode and length of the record at `pos`, if the file holds its header.
fn header_at(file: &mut File, pos: u64, file_bytes: u64) -> std::io::Result<Option<(u8, u64)>> {
    if pos.checked_add(9).is_none_or(|e| e > file_bytes) {
        return Ok(None);
    }
    let mut h = [0u8; 9];
    file.seek(SeekFrom::Start(pos))?;
    file.read_exact(&mut h)?;
    let len = u64::from_le_bytes(h[1..].try_into().unwrap_or([0; 8]));
    Ok(Some((h[0], len)))
}

fn u64_at(file: &mut File, pos: u64) -> std::io::Result<u64> {
    let mut b = [0u8; 8];
    file.seek(SeekFrom::Start(pos))?;
    file.read_exact(&mut b)?;
    Ok(u64::from_le_bytes(b))
}

/// Whether a chunk body in `[start, end)` is compressed, or its inner records all fit in it.
/// Body: start and end time, uncompressed size (u64 each), CRC (u32), compression (u32
/// length + bytes), records length (u64), records.
fn uncompressed_chunk_fits(file: &mut File, start: u64, end: u64) -> std::io::Result<bool> {
    if start + 32 > end {
        return Ok(true); // too short for its header: the reader reports that itself
    }
    let mut c = [0u8; 4];
    file.seek(SeekFrom::Start(start + 28))?;
    file.read_exact(&mut c)?;
    let compression_len = u64::from(u32::from_le_bytes(c));
    if compression_len != 0 {
        return Ok(true);
    }
    let records_at = start + 32;
    if records_at + 8 > end {
        return Ok(true);
    }
    let records_len = u64_at(file, records_at)?;
    let (mut p, records_end) = (records_at + 8, records_at + 8);
    let Some(records_end) = records_end.checked_add(records_len).filter(|e| *e <= end) else {
        return Ok(true); // the reader checks the records length against the chunk itself
    };
    while p < records_end {
        if p + 9 > records_end {
            return Ok(false);
        }
        let len = u64_at(file, p + 1)?;
        match (p + 9).checked_add(len) {
            Some(next) if next <= records_end => p = next,
            _ => return Ok(false),
        }
    }
    Ok(true)
}
