//! Fuzz the reader of a tile certificate (`gonio measure --tile FILE`:
//! `host::instrument::calibration::TileCertificate::parse`, what `TileCertificate::read`
//! does with the file's bytes), with arbitrary bytes: no panic.
#![no_main]

use host::instrument::calibration::TileCertificate;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    // A fixed day inside the seed certificates' validity, so that the checks after the
    // dates' are reached too.
    let today = chrono::NaiveDate::from_ymd_opt(2026, 12, 4).expect("a date");
    let _ = TileCertificate::parse(Path::new("tile.json"), data, today);
});
