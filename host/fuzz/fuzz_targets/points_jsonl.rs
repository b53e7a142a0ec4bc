//! Fuzz the reader of `points.jsonl` (`host::output::folder::lines_of`, then
//! `parse_points`, as `read_lines` and the resume and re-analysis read the file), with
//! arbitrary bytes: no panic, and the lines read are the file's whole lines.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("points.jsonl");
    let Ok(file) = host::output::folder::lines_of(path, data) else {
        return;
    };
    let newlines = data.iter().filter(|&&b| b == b'\n').count();
    assert_eq!(file.lines.len(), newlines);
    let _ = host::output::folder::parse_points(path, &file);
});
