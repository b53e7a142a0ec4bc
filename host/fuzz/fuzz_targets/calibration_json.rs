//! Fuzz the reader of `calibration.json` (`host::output::folder::parse_calibration`, what
//! `read_calibration` does with the file's text), with arbitrary bytes: no panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    // read_calibration reads the file with read_to_string: bytes that are not UTF-8 never
    // reach the parser.
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = host::output::folder::parse_calibration(Path::new("calibration.json"), text);
});
