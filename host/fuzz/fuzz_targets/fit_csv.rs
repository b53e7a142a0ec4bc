//! Fuzz the reader of `gonio fit`'s CSV (`host::output::dataset::parse_csv`, what
//! `read_file` does with the file's text), with arbitrary bytes: no panic, and every data
//! set read holds readings.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // read_file reads the file with read_to_string: bytes that are not UTF-8 never reach
    // the parser.
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(sets) = host::output::dataset::parse_csv(text, "sample") {
        assert!(sets.iter().all(|s| !s.observations.is_empty()));
    }
});
