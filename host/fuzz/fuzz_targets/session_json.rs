//! Fuzz the reader of `session.json` (`host::output::folder::parse_session`, what
//! `read_session` does with the file's text), with arbitrary bytes: no panic, and a
//! document read is one of this gonio's schemas.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    // read_session reads the file with read_to_string: bytes that are not UTF-8 never
    // reach the parser.
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = host::output::folder::parse_session(Path::new("session.json"), text);
});
