//! The analysis path of a volumetric input as its command takes it (issue 27): reader, evaluation,
//! reports. No panic, and no NaN or infinity in an output of an accepted input
//! (`metrolog::fuzzcheck::volumetric_path`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = metrolog::fuzzcheck::volumetric_path(text);
    }
});
