//! The CapBall dataset reader (`docs/datasets.md`): a clear error or records, no panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = geometry::capball::parse_dataset(text);
    }
});
