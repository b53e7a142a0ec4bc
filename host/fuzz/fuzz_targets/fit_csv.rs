//! Fuzz the reader of `gonio fit`'s table (`host::output::dataset::read_bytes`, what
//! `read_file` does with the file's bytes: UTF-8, then gonio's `.astm` export or a CSV in
//! any of its dialects), with arbitrary bytes: no panic, and every data set read holds
//! readings.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = std::path::Path::new("sample.csv");
    if let Ok(sets) = host::output::dataset::read_bytes(path, data) {
        assert!(sets.iter().all(|s| !s.observations.is_empty()));
    }
});
