//! The thermal path without the diagnosis (issue 27): reader, ISO 230-3, the model fitted,
//! written as JSON, read back and predicting (`metrolog::fuzzcheck::thermal_fit_path`). The
//! fast half of `thermal_path`, whose diagnosis runs at 5–30 inputs a second; seeds and
//! findings in `corpus/thermal_path`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = metrolog::fuzzcheck::thermal_fit_path(text);
    }
});
