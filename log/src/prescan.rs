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
/// chunk before the footer or the first truncated record). A chunk cut off by the end of the
/// file is checked as far as the file goes: the `mcap` reader streams an uncompressed chunk's
/// records before it has the whole chunk when its CRC is zero. Leaves `file` at its start.
pub(crate) fn first_bad_chunk(file: &mut File, file_bytes: u64) -> std::io::Result<Option<u64>> {
    let mut pos = 8u64;
    let mut bad = None;
    while let Some(h) = read_at::<9>(file, pos, file_bytes)? {
        let (opcode, len) = (
            h[0],
            u64::from_le_bytes(h[1..].try_into().unwrap_or([0; 8])),
        );
        if opcode == FOOTER {
            break;
        }
        let end = (pos + 9).checked_add(len);
        if opcode == CHUNK
            && !uncompressed_chunk_fits(file, pos + 9, end.unwrap_or(u64::MAX), file_bytes)?
        {
            bad = Some(pos);
            break;
        }
        match end.filter(|e| *e <= file_bytes) {
            Some(e) => pos = e,
            None => break,
        }
    }
    file.seek(SeekFrom::Start(0))?;
    Ok(bad)
}

/// `N` bytes at `pos`, if the file holds them.
fn read_at<const N: usize>(
    file: &mut File,
    pos: u64,
    file_bytes: u64,
) -> std::io::Result<Option<[u8; N]>> {
    if pos.checked_add(N as u64).is_none_or(|e| e > file_bytes) {
        return Ok(None);
    }
    let mut b = [0u8; N];
    file.seek(SeekFrom::Start(pos))?;
    file.read_exact(&mut b)?;
    Ok(Some(b))
}

/// Whether a chunk body in `[start, end)` is compressed, or its inner records, as far as the
/// file holds them, all fit in its records. Body: start and end time, uncompressed size (u64
/// each), CRC (u32), compression (u32 length + bytes), records length (u64), records.
fn uncompressed_chunk_fits(
    file: &mut File,
    start: u64,
    end: u64,
    file_bytes: u64,
) -> std::io::Result<bool> {
    // Past the file's end the reader stops first; a header too short is its own error.
    let Some(c) = read_at::<4>(file, start + 28, file_bytes)? else {
        return Ok(true);
    };
    if u32::from_le_bytes(c) != 0 || start + 40 > end {
        return Ok(true);
    }
    let Some(r) = read_at::<8>(file, start + 32, file_bytes)? else {
        return Ok(true);
    };
    let mut p = start + 40;
    let Some(records_end) = p.checked_add(u64::from_le_bytes(r)).filter(|e| *e <= end) else {
        return Ok(true); // the reader checks the records length against the chunk itself
    };
    while p < records_end {
        if p.saturating_add(9) > records_end {
            return Ok(false);
        }
        let Some(h) = read_at::<9>(file, p, file_bytes)? else {
            return Ok(true);
        };
        let len = u64::from_le_bytes(h[1..].try_into().unwrap_or([0; 8]));
        match p.saturating_add(9).checked_add(len) {
            Some(next) if next <= records_end => p = next,
            _ => return Ok(false),
        }
    }
    Ok(true)
}
