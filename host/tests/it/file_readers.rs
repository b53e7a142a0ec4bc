//! Every reader of a file gonio is given (issue 30): `session.json`, `points.jsonl`,
//! `calibration.json`, a tile certificate, `gonio library import`'s exchange file and
//! `gonio fit`'s CSV, fed arbitrary bytes and real files (written by the simulator) with
//! bytes changed, cut, repeated: a result or an error, never a panic. The stable, quick
//! version of the fuzz targets in host/fuzz (docs/RELIABILITY.md, "The file readers
//! under fuzzing"), with the inputs the fuzzers found that made a reader panic.
use crate::common::in_process::{measure, ram_dir};
use host::instrument::calibration::TileCertificate;
use host::output::library::{ExchangeFile, Library, OpenMode, StockInfo, read_session_folder};
use host::output::{dataset, folder};
use proptest::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// The six readers, each from a file's bytes as its caller reads the file (the JSON
/// documents and the CSV with `read_to_string`: bytes that are not UTF-8 stop there).
fn session_json(bytes: &[u8]) {
    if let Ok(text) = std::str::from_utf8(bytes) {
        let _ = folder::parse_session(Path::new("session.json"), text);
    }
}

fn points_jsonl(bytes: &[u8]) {
    let path = Path::new("points.jsonl");
    if let Ok(file) = folder::lines_of(path, bytes) {
        let _ = folder::parse_points(path, &file);
    }
}

fn calibration_json(bytes: &[u8]) {
    if let Ok(text) = std::str::from_utf8(bytes) {
        let _ = folder::parse_calibration(Path::new("calibration.json"), text);
    }
}

fn tile_certificate(bytes: &[u8]) {
    let today = chrono::NaiveDate::from_ymd_opt(2026, 12, 4).expect("a date");
    let _ = TileCertificate::parse(Path::new("tile.json"), bytes, today);
}

fn library_import(bytes: &[u8]) {
    let mut input = bytes;
    let _ = ExchangeFile::read(&mut input, Path::new("exchange.jsonl"));
}

fn fit_csv(bytes: &[u8]) {
    // The whole reader `gonio fit` uses: UTF-8, then an `.astm` export or a CSV dialect.
    let _ = dataset::read_bytes(Path::new("sample.csv"), bytes);
}

const CERTIFICATE: &str = r#"{"tile": "PTFE #7", "certificate": "C-1", "issued": "2026-03-01", "valid_until": "2027-03-01",
 "radiance_factor": 0.98, "expanded_uncertainty": 0.0098, "coverage_factor": 2}"#;

/// Real files: a session of glossy paper G measured on the simulator with a tile
/// certificate, and the exchange file of a library holding it; measured once per run.
struct RealFiles {
    session: Vec<u8>,
    points: Vec<u8>,
    calibration: Vec<u8>,
    readings: Vec<u8>,
    astm: Vec<u8>,
    exchange: Vec<u8>,
}

fn real_files() -> &'static RealFiles {
    static FILES: OnceLock<RealFiles> = OnceLock::new();
    FILES.get_or_init(|| {
        let root = ram_dir("readers", "real");
        std::fs::create_dir_all(&root).unwrap();
        let tile = root.join("tile.json");
        std::fs::write(&tile, CERTIFICATE).unwrap();
        let dir = root.join("G");
        let (d, t) = (dir.to_str().unwrap(), tile.to_str().unwrap());
        measure(
            &[
                "--sim",
                "G",
                "--spots",
                "1",
                "--seed",
                "5",
                "--tile-certificate",
                t,
                "--out",
                d,
            ],
            None,
        )
        .expect("a simulated session");
        let read = |name: &str| std::fs::read(dir.join(name)).unwrap();
        let mut library = Library::open_file(&root.join("library.sqlite"), OpenMode::Add).unwrap();
        let stock = StockInfo {
            name: "G".into(),
            ..StockInfo::default()
        };
        let sheet = read_session_folder(&dir, Some("ream 7"), true).unwrap();
        library.add_sheets(&stock, &[sheet]).unwrap();
        let mut exchange = Vec::new();
        library
            .export(&mut exchange, &root.join("exchange.jsonl"))
            .unwrap();
        let files = RealFiles {
            session: read("session.json"),
            points: read("points.jsonl"),
            calibration: read("calibration.json"),
            readings: read("readings.csv"),
            astm: read("G.astm"),
            exchange,
        };
        let _ = std::fs::remove_dir_all(&root);
        files
    })
}

/// The real files read as they are (the mutations below start from a file that reads).
#[test]
fn the_real_files_read() {
    let files = real_files();
    let text = |b: &[u8]| String::from_utf8(b.to_vec()).unwrap();
    folder::parse_session(Path::new("session.json"), &text(&files.session)).unwrap();
    let path = Path::new("points.jsonl");
    let lines = folder::lines_of(path, &files.points).unwrap();
    assert!(!folder::parse_points(path, &lines).unwrap().is_empty());
    folder::parse_calibration(Path::new("calibration.json"), &text(&files.calibration)).unwrap();
    let today = chrono::NaiveDate::from_ymd_opt(2026, 12, 4).unwrap();
    TileCertificate::parse(Path::new("tile.json"), CERTIFICATE.as_bytes(), today).unwrap();
    let mut input = &files.exchange[..];
    let exchange = ExchangeFile::read(&mut input, Path::new("exchange.jsonl")).unwrap();
    assert!(exchange.records() > 0);
    assert!(
        !dataset::parse_csv(&text(&files.readings), "G")
            .unwrap()
            .is_empty()
    );
    let astm = dataset::read_bytes(Path::new("G.astm"), &files.astm).unwrap();
    assert!(astm.iter().all(|set| !set.observations.is_empty()));
}

/// One change to a file: a byte replaced, inserted or removed, a span cut out or
/// repeated, or a number put where a number was.
#[derive(Clone, Debug)]
enum Mutation {
    Replace(usize, u8),
    Insert(usize, u8),
    Remove(usize),
    Cut(usize, usize),
    Repeat(usize, usize, usize),
    Number(usize, &'static str),
}

/// Numbers a reader must refuse or take without panicking: huge, tiny, negative, not
/// finite in words, long.
const NUMBERS: &[&str] = &[
    "0",
    "-1",
    "-0",
    "1e308",
    "-1e308",
    "1e-320",
    "1e999",
    "NaN",
    "Infinity",
    "-Infinity",
    "18446744073709551615",
    "18446744073709551616",
    "4294967296",
    "-9223372036854775809",
    "9999999999999999999999999",
    "0.0000000000000000000000000001",
    "1.7976931348623157e308",
    "null",
    "\"\"",
    "[]",
    "{}",
    "true",
];

fn mutation() -> impl Strategy<Value = Mutation> {
    let at = any::<prop::sample::Index>();
    prop_oneof![
        (at.clone(), any::<u8>()).prop_map(|(i, b)| Mutation::Replace(i.index(usize::MAX), b)),
        (at.clone(), any::<u8>()).prop_map(|(i, b)| Mutation::Insert(i.index(usize::MAX), b)),
        at.clone()
            .prop_map(|i| Mutation::Remove(i.index(usize::MAX))),
        (at.clone(), 1usize..64).prop_map(|(i, n)| Mutation::Cut(i.index(usize::MAX), n)),
        (at.clone(), 1usize..256, 1usize..8).prop_map(|(i, n, k)| Mutation::Repeat(
            i.index(usize::MAX),
            n,
            k
        )),
        (at, prop::sample::select(NUMBERS))
            .prop_map(|(i, n)| Mutation::Number(i.index(usize::MAX), n)),
    ]
}

/// `bytes` with the mutations applied (positions taken modulo the length then).
fn mutated(bytes: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    for m in mutations {
        let len = b.len().max(1);
        match *m {
            Mutation::Replace(i, x) => {
                if !b.is_empty() {
                    b[i % len] = x;
                }
            }
            Mutation::Insert(i, x) => b.insert(i % (b.len() + 1), x),
            Mutation::Remove(i) => {
                if !b.is_empty() {
                    b.remove(i % len);
                }
            }
            Mutation::Cut(i, n) => {
                let start = i % len;
                let end = (start + n).min(b.len());
                if start < end {
                    b.drain(start..end);
                }
            }
            Mutation::Repeat(i, n, k) => {
                let start = i % len;
                let end = (start + n).min(b.len());
                if start < end {
                    let span = b[start..end].to_vec();
                    for _ in 0..k {
                        b.splice(end..end, span.iter().copied());
                    }
                }
            }
            Mutation::Number(i, number) => {
                // The number that starts at or after i, replaced whole.
                let Some(start) = (i % len..b.len()).find(|&k| b[k].is_ascii_digit()) else {
                    continue;
                };
                let start = if start > 0 && b[start - 1] == b'-' {
                    start - 1
                } else {
                    start
                };
                let end = (start + 1..b.len())
                    .find(|&k| !matches!(b[k], b'0'..=b'9' | b'.' | b'e' | b'E' | b'-' | b'+'))
                    .unwrap_or(b.len());
                b.splice(start..end, number.bytes());
            }
        }
    }
    b
}

fn changes() -> impl Strategy<Value = Vec<Mutation>> {
    prop::collection::vec(mutation(), 1..6)
}

/// Arbitrary bytes, mostly of the characters JSON and CSV are made of.
fn junk() -> impl Strategy<Value = Vec<u8>> {
    let structural = prop::sample::select(b"{}[]\",:0123456789.-eE \ntrufalsn\\".to_vec());
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..512),
        prop::collection::vec(structural, 0..512),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_read_or_are_refused(bytes in junk()) {
        session_json(&bytes);
        points_jsonl(&bytes);
        calibration_json(&bytes);
        tile_certificate(&bytes);
        library_import(&bytes);
        fit_csv(&bytes);
    }

    #[test]
    fn a_changed_session_json_reads_or_is_refused(m in changes()) {
        session_json(&mutated(&real_files().session, &m));
    }

    #[test]
    fn a_changed_points_jsonl_reads_or_is_refused(m in changes()) {
        points_jsonl(&mutated(&real_files().points, &m));
    }

    #[test]
    fn a_changed_calibration_json_reads_or_is_refused(m in changes()) {
        calibration_json(&mutated(&real_files().calibration, &m));
    }

    #[test]
    fn a_changed_tile_certificate_reads_or_is_refused(m in changes()) {
        tile_certificate(&mutated(CERTIFICATE.as_bytes(), &m));
    }

    #[test]
    fn a_changed_exchange_file_reads_or_is_refused(m in changes()) {
        library_import(&mutated(&real_files().exchange, &m));
    }

    #[test]
    fn a_changed_fit_csv_reads_or_is_refused(m in changes()) {
        fit_csv(&mutated(&real_files().readings, &m));
    }

    #[test]
    fn a_changed_astm_export_reads_or_is_refused(m in changes()) {
        fit_csv(&mutated(&real_files().astm, &m));
    }
}
