//! Checks shared by the cargo-fuzz targets (`protocol/fuzz`: `trajectory`, `mcap_reader`) and
//! the corpus replay test (`log/tests/fuzz_corpus.rs`): each panics when a parser breaks one of
//! its promises on the input. Not part of the API.

use std::path::Path;

/// The trajectory parser: never panics; what it accepts, [`crate::trajectory::write_trajectory`]
/// writes back to the same poses (values to the writer's 6 decimals).
pub fn trajectory(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(rows) = crate::trajectory::parse_trajectory(text) else {
        return;
    };
    let written = crate::trajectory::write_trajectory(&rows);
    let again = crate::trajectory::parse_trajectory(&written)
        .unwrap_or_else(|e| panic!("the writer's output does not parse: {e}\n{written}"));
    assert_eq!(again.len(), rows.len());
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 + 1e-12 * a.abs();
    for (a, b) in rows.iter().zip(&again) {
        assert_eq!(a.pose, b.pose);
        assert!(
            close(a.x_mm, b.x_mm) && close(a.y_mm, b.y_mm) && close(a.z_mm, b.z_mm),
            "{a:?} vs {b:?}"
        );
        assert_eq!(a.a_deg.is_some(), b.a_deg.is_some());
        assert!(close(a.a_deg.unwrap_or(0.0), b.a_deg.unwrap_or(0.0)));
        assert!(close(a.c_deg.unwrap_or(0.0), b.c_deg.unwrap_or(0.0)));
    }
}

/// The MCAP reader on a (possibly damaged) file: never panics, refuses exactly the files that
/// do not start with the MCAP magic, never fails on what is inside an MCAP file (damage is
/// reported in the summary), never claims more bytes than the file has.
pub fn mcap_file(path: &Path) {
    let mut messages = 0u64;
    let starts_mcap = std::fs::read(path)
        .map(|d| d.starts_with(mcap::MAGIC))
        .unwrap_or(false);
    let read = crate::reader::read_log(path, |item| {
        if let crate::reader::LogItem::Message { .. } = item {
            messages += 1;
        }
    });
    let summary = match read {
        Err(crate::LogError::NotMcap { .. }) if !starts_mcap => return,
        Err(e) => panic!("a readable file is an Err: {e}"),
        Ok(_) if !starts_mcap => panic!("a file without the MCAP magic was read"),
        Ok(s) => s,
    };
    assert_eq!(summary.messages, messages);
    assert!(
        summary.bytes_read <= summary.file_bytes,
        "{} of {} bytes read",
        summary.bytes_read,
        summary.file_bytes
    );
    let _ = crate::reader::read_run_metadata(path);
}
