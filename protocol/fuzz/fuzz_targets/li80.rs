//! Feeds the input to the li80 decoder whole and split at a point taken from the input, and
//! checks the two outputs agree (plus the checks of `protocol::fuzzcheck`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    protocol::fuzzcheck::li80(data);
});
