//! The MCAP log reader on damaged files: the input is written to a file (the reader reads
//! files, in pieces) and read back (`metrolog_log::fuzzcheck::mcap_file`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // One file per fuzzing process, rewritten for every input (tmpfs when /dev/shm exists).
    let dir = if std::path::Path::new("/dev/shm").is_dir() {
        std::path::PathBuf::from("/dev/shm")
    } else {
        std::env::temp_dir()
    };
    let path = dir.join(format!("metrolog-fuzz-{}.mcap", std::process::id()));
    std::fs::write(&path, data).expect("cannot write the fuzz input file");
    metrolog_log::fuzzcheck::mcap_file(&path);
});
