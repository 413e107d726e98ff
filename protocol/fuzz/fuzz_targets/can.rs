//! The CAN trigger payloads, alone and carried by SLCAN frames (`protocol::fuzzcheck::can`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    protocol::fuzzcheck::can(data);
});
