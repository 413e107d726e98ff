//! The positioning dataset reader (`docs/datasets.md`): a clear error or a dataset, no panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(d) = positioning::positioning_data::PositioningData::from_csv_str(text) {
            // A declared unit relabels any text (a report) without panicking.
            let _ = d.units().relabel(text);
        }
    }
});
