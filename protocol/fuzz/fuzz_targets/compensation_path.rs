//! A positioning CSV to the controller files (issue 27): the reader, a compensation table in
//! every dialect and mode, the files and the before/after verification. No panic; no NaN or
//! infinity, no path in a file name and no control character in a line of an accepted file's
//! output (`metrolog_analysis::fuzzcheck::compensation_path`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = metrolog_analysis::fuzzcheck::compensation_path(text);
    }
});
