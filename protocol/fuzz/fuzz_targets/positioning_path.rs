//! The analysis path of a positioning CSV (issue 27): the reader, ISO 230-2 with drift
//! elimination and every standard, the text, CSV and HTML reports. No panic, and no NaN or
//! infinity in any output of a file the reader accepts (`metrolog_analysis::fuzzcheck`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = metrolog_analysis::fuzzcheck::positioning_path(text);
    }
});
