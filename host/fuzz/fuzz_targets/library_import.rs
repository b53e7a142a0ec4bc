//! Fuzz the reader of `gonio library import`'s exchange file (JSON Lines,
//! `host::output::library::ExchangeFile::read`), with arbitrary bytes: no panic.
#![no_main]

use host::output::library::ExchangeFile;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let mut input: &[u8] = data;
    if let Ok(file) = ExchangeFile::read(&mut input, Path::new("exchange.jsonl")) {
        let _ = file.records();
    }
});
