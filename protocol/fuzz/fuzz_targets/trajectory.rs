//! The one trajectory CSV parser (`metrolog_log::trajectory`): no panic, and what it accepts
//! writes back to the same poses (`metrolog_log::fuzzcheck::trajectory`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    metrolog_log::fuzzcheck::trajectory(data);
});
