//! The library's tests: storage, the exchange file's round trip and refusals.
use super::*;
use crate::analysis::specimen::{Orientation, SheetLay, Side};
use rand::{Rng, SeedableRng};
use rusqlite::Connection;
use std::path::Path;

pub(super) fn sheet(n: u64, spots: usize) -> SheetRecord {
    let spot = |k: usize| Spot {
        values: [
            Some(4.0 + (n % 100) as f64 * 0.1 + k as f64),
            if k == 1 { None } else { Some(0.1 + 0.2) },
            Some(0.8 + 1e-17 * k as f64),
        ],
        // Awkward numbers (thirds, tiny and large exponents) that must come back to the
        // bit, in a covariance that is a possible measurement (the library refuses others).
        covariance: [
            [1.0 / 3.0 * 1e-4, 2.5e-7, -1.0 / 3.0 * 1e-6],
            [2.5e-7, 1e-4, 7e-300],
            [-1.0 / 3.0 * 1e-6, 7e-300, 1e-5],
        ],
    };
    SheetRecord {
        lot: n.is_multiple_of(2).then(|| format!("ream {n}")),
        measured_at: Some(format!("2026-05-01T14:03:{:02}.000+02:00", n % 60)),
        instrument_serial: "SIM-0001".into(),
        session_path: format!("sessions/é-{n}"),
        session_sha256: crate::output::folder::manifest::sha256_hex(&n.to_le_bytes()),
        sample: "PPC".into(),
        lay: crate::analysis::specimen::SheetLay {
            orientation: [None, Some(Orientation::Md), Some(Orientation::Cd)][n as usize % 3],
            side: [None, Some(Side::Felt), Some(Side::Wire)][n as usize % 3],
        },
        added_at: format!("2026-06-01T00:00:{:02}.000Z", n % 60),
        spots: (0..spots).map(spot).collect(),
    }
}

pub(super) fn stock(name: &str) -> StockInfo {
    StockInfo {
        name: name.into(),
        manufacturer: Some("Acme «Papier»".into()),
        notes: None,
    }
}

pub(super) fn export_bytes(library: &Library) -> Vec<u8> {
    let mut out = Vec::new();
    library.export(&mut out, Path::new("test")).expect("export");
    out
}

/// A library file of a few stocks, sheets and spots.
fn filled(path: &Path) -> Library {
    filled_at(&Location::File(path.to_path_buf()))
}

/// A library of a few stocks, sheets and spots, at `location`.
pub(super) fn filled_at(location: &Location) -> Library {
    let mut library = Library::open(location, OpenMode::Add).expect("create");
    library
        .add_sheets(&stock("PPC"), &[sheet(1, 1), sheet(2, 3)])
        .expect("add");
    library
        .add_sheets(
            &StockInfo {
                name: "Bond 80 g/m²".into(),
                manufacturer: None,
                notes: Some("from a \"ream\"\nline two".into()),
            },
            &[sheet(3, 2)],
        )
        .expect("add");
    library
        .add_sheets(&stock("PPC"), &[sheet(4, 1)])
        .expect("add to an existing stock");
    library
}

#[test]
fn a_new_library_has_its_ids_and_schema_version() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("sub").join("library.sqlite");
    drop(Library::open_file(&path, OpenMode::Add).expect("create"));
    let conn = Connection::open(&path).expect("open");
    let id: i32 = conn
        .pragma_query_value(None, "application_id", |r| r.get(0))
        .expect("id");
    let user_version: i64 = conn
        .pragma_query_value(None, "user_version", |r| r.get(0))
        .expect("version");
    let schema_version: i64 = conn
        .query_row(
            "SELECT value FROM meta WHERE key = 'schema_version'",
            [],
            |r| r.get(0),
        )
        .expect("meta");
    assert_eq!((id, user_version, schema_version), (APPLICATION_ID, 3, 3));
    // Its trail begins with its making.
    let opened = Library::open_file(&path, OpenMode::Existing).expect("reopen");
    let trail = opened.audit_entries().expect("history");
    assert_eq!(trail.len(), 1, "{trail:?}");
    assert_eq!((trail[0].entry, trail[0].action.as_str()), (1, "create"));
    assert_eq!(trail[0].db_user, None, "a file has no roles");
    drop(opened);
    // Reopening finds it, empty.
    assert!(
        Library::open_file(&path, OpenMode::Existing)
            .expect("reopen")
            .stocks()
            .expect("stocks")
            .is_empty()
    );
}

#[test]
fn reading_a_missing_library_does_not_create_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("library.sqlite");
    let err = Library::open_file(&path, OpenMode::Existing).expect_err("missing");
    assert!(matches!(err, LibraryError::Missing { .. }), "{err}");
    assert!(err.to_string().contains("nothing has been added"), "{err}");
    assert!(!path.exists());
}

/// Every file beside the library (WAL, shared memory), for "left as it is".
fn folder_bytes(dir: &Path) -> Vec<(std::ffi::OsString, Vec<u8>)> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .expect("list")
        .map(|e| e.expect("entry"))
        .map(|e| (e.file_name(), std::fs::read(e.path()).expect("read")))
        .collect();
    files.sort();
    files
}

#[test]
fn a_library_of_a_newer_schema_is_refused_and_left_as_it_is() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("library.sqlite");
    drop(filled(&path));
    {
        let conn = Connection::open(&path).expect("open");
        conn.execute("UPDATE meta SET value = 4 WHERE key = 'schema_version'", [])
            .expect("update");
        conn.pragma_update(None, "user_version", 4)
            .expect("version");
    }
    let before = folder_bytes(dir.path());
    for mode in [OpenMode::Existing, OpenMode::Add] {
        let err = Library::open_file(&path, mode).expect_err("newer");
        assert!(matches!(err, LibraryError::Newer { found: 4, .. }), "{err}");
        assert!(
            err.to_string().contains(
                "written by a newer gonio (schema 4); this gonio reads up to 3: update gonio"
            ),
            "{err}"
        );
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
    }
    assert_eq!(folder_bytes(dir.path()), before);
}

#[test]
fn random_bytes_are_refused_and_left_as_they_are() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("library.sqlite");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
    for len in [1usize, 99, 100, 4096, 70_000] {
        let bytes: Vec<u8> = (0..len).map(|_| rng.random()).collect();
        std::fs::write(&path, &bytes).expect("write");
        for mode in [OpenMode::Existing, OpenMode::Add] {
            let err = Library::open_file(&path, mode).expect_err("not SQLite");
            assert!(
                matches!(err, LibraryError::NotSqlite { .. }),
                "{len} bytes: {err}"
            );
            assert!(
                err.to_string().starts_with(&path.display().to_string()),
                "{err}"
            );
        }
        assert_eq!(
            folder_bytes(dir.path()),
            vec![(path.file_name().expect("name").to_owned(), bytes)],
            "{len} bytes"
        );
    }
}

#[test]
fn a_truncated_or_damaged_library_is_refused_and_left_as_it_is() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("library.sqlite");
    {
        let mut library = filled(&path);
        // Enough sheets for the file to span many pages.
        let sheets: Vec<SheetRecord> = (100..400).map(|n| sheet(n, 2)).collect();
        library.add_sheets(&stock("many"), &sheets).expect("add");
    }
    let whole = std::fs::read(&path).expect("read");
    assert!(whole.len() > 8 * 4096, "{} bytes", whole.len());
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("truncated to half", whole[..whole.len() / 2].to_vec()),
        ("truncated to its first page", whole[..4096].to_vec()),
        ("truncated inside the header", whole[..50].to_vec()),
        ("a page overwritten", {
            let mut b = whole.clone();
            b[3 * 4096..4 * 4096].fill(0xA5);
            b
        }),
    ];
    for (what, bytes) in cases {
        std::fs::write(&path, &bytes).expect("write");
        for mode in [OpenMode::Existing, OpenMode::Add] {
            let err = Library::open_file(&path, mode).expect_err(what);
            assert!(matches!(err, LibraryError::Corrupt { .. }), "{what}: {err}");
            assert!(
                err.to_string().starts_with(&path.display().to_string()),
                "{err}"
            );
        }
        assert_eq!(
            folder_bytes(dir.path()),
            vec![(path.file_name().expect("name").to_owned(), bytes)],
            "{what}"
        );
    }
}

#[test]
fn an_sqlite_file_of_another_program_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("other.sqlite");
    Connection::open(&path)
        .expect("open")
        .execute_batch("CREATE TABLE t (x); INSERT INTO t VALUES (1);")
        .expect("create");
    let before = folder_bytes(dir.path());
    let err = Library::open_file(&path, OpenMode::Add).expect_err("foreign");
    assert!(matches!(err, LibraryError::Foreign { .. }), "{err}");
    assert_eq!(folder_bytes(dir.path()), before);
}

#[test]
fn the_same_session_twice_is_refused_naming_its_stock() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut library = filled(&dir.path().join("library.sqlite"));
    let before = export_bytes(&library);
    // Under another stock, and together with a new sheet: nothing of the add is kept.
    let err = library
        .add_sheets(&stock("Other"), &[sheet(50, 1), sheet(2, 1)])
        .expect_err("duplicate");
    assert!(
        matches!(&err, LibraryError::Duplicate { stock, .. } if stock == "PPC"),
        "{err}"
    );
    assert!(
        err.to_string()
            .contains("already in the library under stock 'PPC'"),
        "{err}"
    );
    assert_eq!(export_bytes(&library), before);
    assert!(
        library
            .stocks()
            .expect("stocks")
            .iter()
            .all(|s| s.name != "Other")
    );
}

#[test]
fn a_different_manufacturer_for_a_stock_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut library = filled(&dir.path().join("library.sqlite"));
    let err = library
        .add_sheets(
            &StockInfo {
                name: "PPC".into(),
                manufacturer: Some("Other".into()),
                notes: None,
            },
            &[sheet(60, 1)],
        )
        .expect_err("conflict");
    assert!(
        matches!(
            err,
            LibraryError::StockConflict {
                field: "manufacturer",
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn export_then_import_into_an_empty_library_then_export_is_byte_identical() {
    let dir = tempfile::tempdir().expect("temp dir");
    let first = filled(&dir.path().join("first.sqlite"));
    let exported = export_bytes(&first);
    assert_eq!(
        exported.iter().filter(|&&b| b == b'\n').count(),
        7,
        "one line per spot"
    );
    let mut second =
        Library::open_file(&dir.path().join("second.sqlite"), OpenMode::Add).expect("create");
    let counts = second
        .import(&ExchangeFile::read(&mut exported.as_slice(), Path::new("x.jsonl")).expect("read"))
        .expect("import");
    assert_eq!(
        counts,
        ImportCounts {
            records: 7,
            sessions_added: 4,
            sessions_skipped: 0,
            stocks_added: 2
        }
    );
    assert_eq!(
        String::from_utf8(export_bytes(&second)).expect("utf-8"),
        String::from_utf8(exported.clone()).expect("utf-8")
    );
    // Lossless: the sheets (every f64 bit, every None) are the ones added.
    assert_eq!(
        second.sheets().expect("sheets"),
        first.sheets().expect("sheets")
    );
    assert_eq!(
        second.stocks().expect("stocks"),
        first.stocks().expect("stocks")
    );
    // Again: every session is already present.
    let counts = second
        .import(&ExchangeFile::read(&mut exported.as_slice(), Path::new("x.jsonl")).expect("read"))
        .expect("import");
    assert_eq!(
        counts,
        ImportCounts {
            records: 7,
            sessions_added: 0,
            sessions_skipped: 4,
            stocks_added: 0
        }
    );
    assert_eq!(export_bytes(&second), exported);
}

#[test]
fn an_exchange_file_of_the_first_version_still_imports() {
    let dir = tempfile::tempdir().expect("temp dir");
    let exported =
        String::from_utf8(export_bytes(&filled(&dir.path().join("first.sqlite")))).expect("utf-8");
    // What gonio wrote before its documents carried `schema`: the key was `format`, and
    // no lay.
    let old = older_records(&exported, "format", crate::schema::LIBRARY_RECORD_V1);
    let mut second =
        Library::open_file(&dir.path().join("second.sqlite"), OpenMode::Add).expect("open");
    let counts = second
        .import(&ExchangeFile::read(&mut old.as_bytes(), Path::new("old.jsonl")).expect("read"))
        .expect("import");
    assert_eq!(counts.records, exported.lines().count());
    assert_eq!(
        String::from_utf8(export_bytes(&second)).expect("utf-8"),
        without_lay(&exported),
        "imported as the same records, of unknown lay"
    );
}

/// `exported` (current records) as a gonio of `schema` wrote them: its schema under `key`,
/// no orientation or side.
fn older_records(exported: &str, key: &str, schema: &str) -> String {
    exported
        .lines()
        .map(|line| {
            let mut v: serde_json::Value = serde_json::from_str(line).expect("a record");
            let o = v.as_object_mut().expect("an object");
            o.remove("schema");
            o.remove("orientation");
            o.remove("side");
            o.insert(key.into(), schema.into());
            format!("{v}\n")
        })
        .collect()
}

/// `exported` with every sheet's lay unknown (null), as this gonio writes such records.
fn without_lay(exported: &str) -> String {
    let mut out = exported.to_string();
    for lay in ["md", "cd", "felt", "wire"] {
        for key in ["orientation", "side"] {
            out = out.replace(&format!("\"{key}\":\"{lay}\""), &format!("\"{key}\":null"));
        }
    }
    out
}

#[test]
fn an_exchange_file_of_version_2_still_imports_with_the_lay_unknown() {
    let dir = tempfile::tempdir().expect("temp dir");
    let exported =
        String::from_utf8(export_bytes(&filled(&dir.path().join("first.sqlite")))).expect("utf-8");
    let old = older_records(&exported, "schema", crate::schema::LIBRARY_RECORD_V2);
    assert!(!old.contains("orientation") && old.contains("gonio-library/2"));
    let mut second =
        Library::open_file(&dir.path().join("second.sqlite"), OpenMode::Add).expect("open");
    let counts = second
        .import(&ExchangeFile::read(&mut old.as_bytes(), Path::new("old.jsonl")).expect("read"))
        .expect("import");
    assert_eq!((counts.records, counts.sessions_added), (7, 4));
    assert!(
        second
            .lays()
            .expect("lays")
            .iter()
            .all(|(_, _, lay)| *lay == SheetLay::default())
    );
    assert_eq!(
        String::from_utf8(export_bytes(&second)).expect("utf-8"),
        without_lay(&exported)
    );
    // A version 2 record that states a lay was not written by a gonio of version 2.
    let mut claimed: serde_json::Value =
        serde_json::from_str(old.lines().next().expect("a line")).expect("JSON");
    claimed["orientation"] = "md".into();
    let err = ExchangeFile::read(&mut format!("{claimed}\n").as_bytes(), Path::new("x.jsonl"))
        .expect_err("a lay in a version 2 record");
    assert!(
        err.to_string()
            .contains("x.jsonl:1: a record of 'gonio-library/2' with an orientation or side"),
        "{err}"
    );
}

#[test]
fn the_lay_goes_through_export_and_import_unchanged() {
    let dir = tempfile::tempdir().expect("temp dir");
    let first = filled(&dir.path().join("first.sqlite"));
    let exported = export_bytes(&first);
    let text = String::from_utf8(exported.clone()).expect("utf-8");
    // filled's sheets: 1 md felt, 2 cd wire, 3 unknown, 4 md felt.
    for said in [
        "\"orientation\":\"md\",\"side\":\"felt\"",
        "\"orientation\":\"cd\",\"side\":\"wire\"",
        "\"orientation\":null,\"side\":null",
    ] {
        assert!(text.contains(said), "{said} in {text}");
    }
    let mut second =
        Library::open_file(&dir.path().join("second.sqlite"), OpenMode::Add).expect("create");
    second
        .import(&ExchangeFile::read(&mut exported.as_slice(), Path::new("x.jsonl")).expect("read"))
        .expect("import");
    let sorted = |l: &Library| {
        let mut lays = l.lays().expect("lays");
        lays.sort_by(|a, b| a.0.cmp(&b.0));
        lays
    };
    assert_eq!(sorted(&second), sorted(&first));
    let expected: Vec<(String, SheetLay)> = (1..=4)
        .map(|n| (sheet(n, 1).session_sha256, sheet(n, 1).lay))
        .collect();
    for (sha, lay) in &expected {
        assert!(
            sorted(&second).iter().any(|(s, _, l)| s == sha && l == lay),
            "{sha}: {lay:?}"
        );
    }
    assert_eq!(export_bytes(&second), exported);
}

/// The tables of a schema version 1 library, as gonio wrote them before the lay.
const SCHEMA_V1: &str = "
CREATE TABLE meta (key TEXT PRIMARY KEY NOT NULL, value NOT NULL);
CREATE TABLE stocks (id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE, manufacturer TEXT, notes TEXT);
CREATE TABLE sheets (
    id INTEGER PRIMARY KEY,
    stock_id INTEGER NOT NULL REFERENCES stocks(id) ON DELETE CASCADE,
    lot TEXT, measured_at TEXT, instrument_serial TEXT NOT NULL, session_path TEXT NOT NULL,
    session_sha256 TEXT NOT NULL UNIQUE, sample TEXT NOT NULL, added_at TEXT NOT NULL
);
CREATE INDEX sheets_by_stock ON sheets(stock_id);
CREATE TABLE spots (
    sheet_id INTEGER NOT NULL REFERENCES sheets(id) ON DELETE CASCADE,
    spot_index INTEGER NOT NULL,
    sigma_deg REAL, rho_s REAL, rho_d REAL,
    c00 REAL NOT NULL, c01 REAL NOT NULL, c02 REAL NOT NULL,
    c10 REAL NOT NULL, c11 REAL NOT NULL, c12 REAL NOT NULL,
    c20 REAL NOT NULL, c21 REAL NOT NULL, c22 REAL NOT NULL,
    PRIMARY KEY (sheet_id, spot_index)
);
";

/// A schema version 1 library at `old` holding what `current` holds (its lays dropped),
/// with a cached population in `meta`, as a gonio before the lay left it.
fn version_1_copy(current: &Path, old: &Path) {
    let conn = Connection::open(old).expect("create");
    conn.execute_batch(SCHEMA_V1).expect("v1 tables");
    conn.execute(
        "ATTACH DATABASE ?1 AS cur",
        [current.to_str().expect("utf-8 path")],
    )
    .expect("attach");
    conn.execute_batch(
        "INSERT INTO meta SELECT key, value FROM cur.meta;
         UPDATE meta SET value = 1 WHERE key = 'schema_version';
         INSERT INTO meta VALUES ('population-cache/gonio 0/abc', '{\"kept\":true}');
         INSERT INTO stocks SELECT * FROM cur.stocks;
         INSERT INTO sheets SELECT id, stock_id, lot, measured_at, instrument_serial,
             session_path, session_sha256, sample, added_at FROM cur.sheets;
         INSERT INTO spots SELECT * FROM cur.spots;
         DETACH DATABASE cur;",
    )
    .expect("copy");
    conn.pragma_update(None, "application_id", APPLICATION_ID)
        .expect("id");
    conn.pragma_update(None, "user_version", 1)
        .expect("version");
}

#[test]
fn a_library_of_schema_1_is_upgraded_keeping_every_record() {
    let dir = tempfile::tempdir().expect("temp dir");
    let current = dir.path().join("current.sqlite");
    let exported = String::from_utf8(export_bytes(&filled(&current))).expect("utf-8");
    let old = dir.path().join("old.sqlite");
    version_1_copy(&current, &old);
    // Read first (search, list and export open an existing library): upgraded in place.
    let upgraded = Library::open_file(&old, OpenMode::Existing).expect("an older library opens");
    assert_eq!(
        String::from_utf8(export_bytes(&upgraded)).expect("utf-8"),
        without_lay(&exported),
        "every stock, sheet and spot kept, each sheet's lay unknown"
    );
    assert_eq!(upgraded.sheet_count().expect("count"), 4);
    assert_eq!(
        upgraded.stocks().expect("stocks"),
        Library::open_file(&current, OpenMode::Existing)
            .expect("open")
            .stocks()
            .expect("stocks")
    );
    assert_eq!(
        upgraded.cached_population("abc").expect("meta"),
        None,
        "another version's cache is not this one's"
    );
    drop(upgraded);
    let conn = Connection::open(&old).expect("open");
    let versions: (i64, String, String) = conn
        .query_row(
            "SELECT (SELECT value FROM meta WHERE key = 'schema_version'),
                    (SELECT value FROM meta WHERE key = 'upgraded_from_1'),
                    (SELECT value FROM meta WHERE key = 'population-cache/gonio 0/abc')",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
        )
        .expect("meta");
    let user_version: i64 = conn
        .pragma_query_value(None, "user_version", |r| r.get(0))
        .expect("version");
    assert_eq!((versions.0, user_version), (3, 3));
    assert!(
        versions.1.starts_with("to schema 3 by gonio "),
        "{}",
        versions.1
    );
    assert_eq!(versions.2, "{\"kept\":true}", "meta is kept too");
    drop(conn);
    // Opened again: nothing more to do; and it takes sheets with their lay now.
    let mut again = Library::open_file(&old, OpenMode::Add).expect("reopen");
    again
        .add_sheets(&stock("PPC"), &[sheet(5, 2)])
        .expect("add after the upgrade");
    assert!(
        again
            .lays()
            .expect("lays")
            .iter()
            .any(|(sha, _, lay)| *sha == sheet(5, 2).session_sha256 && *lay == sheet(5, 2).lay)
    );
    // The trail begins at the upgrade, which says how many sheets it found without one.
    let trail = again.audit_entries().expect("history");
    let actions: Vec<&str> = trail.iter().map(|e| e.action.as_str()).collect();
    assert_eq!(actions, ["upgrade", "add"], "{trail:?}");
    assert_eq!(trail[0].detail["from_schema"], 1);
    assert_eq!(trail[0].detail["sheets_before_the_trail"], 4);
    // Its contents before the add are recovered from the trail; the sheets before the
    // trail began are simply there from its start.
    assert_eq!(again.contents_at(1).expect("replay").sheets.len(), 4);
    assert_eq!(again.contents_at(2).expect("replay").sheets.len(), 5);
}

#[test]
fn a_library_of_schema_2_is_upgraded_and_its_trail_begins_there() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("library.sqlite");
    let exported = export_bytes(&filled(&path));
    {
        // Schema 2 is schema 3 without the trail.
        let conn = Connection::open(&path).expect("open");
        conn.execute_batch(
            "DROP TRIGGER audit_is_append_only_update; DROP TRIGGER audit_is_append_only_delete;
             DROP TABLE audit; UPDATE meta SET value = 2 WHERE key = 'schema_version';",
        )
        .expect("to schema 2");
        conn.pragma_update(None, "user_version", 2)
            .expect("version");
    }
    let library = Library::open_file(&path, OpenMode::Existing).expect("upgraded");
    assert_eq!(export_bytes(&library), exported, "every record kept");
    let trail = library.audit_entries().expect("history");
    assert_eq!(trail.len(), 1, "{trail:?}");
    assert_eq!(trail[0].action, "upgrade");
    assert_eq!(trail[0].detail["from_schema"], 2);
}

#[test]
fn the_trail_is_append_only_and_recovers_every_past_state() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("library.sqlite");
    let mut library = Library::open_file(&path, OpenMode::Add).expect("create");
    let identity = |l: &Library| {
        let sheets: Vec<_> = l
            .sheets()
            .expect("sheets")
            .into_iter()
            .map(|(_, s)| s)
            .collect();
        crate::analysis::evidence::population::contents_identity(&sheets)
    };
    // The identity after each change, by its last entry.
    let mut states = vec![(1, identity(&library))];
    let after = |l: &Library, states: &mut Vec<(i64, String)>| {
        let entry = l
            .contents()
            .expect("contents")
            .last_entry
            .expect("an entry");
        states.push((entry, identity(l)));
    };
    library
        .add_sheets(&stock("PPC"), &[sheet(1, 1), sheet(2, 3)])
        .expect("add");
    after(&library, &mut states);
    library
        .add_sheets(&stock("Bond"), &[sheet(3, 2)])
        .expect("add");
    after(&library, &mut states);
    library
        .remove_session(&sheet(1, 1).session_sha256[..10])
        .expect("remove");
    after(&library, &mut states);
    library
        .add_sheets(&stock("PPC"), &[sheet(1, 1)])
        .expect("add again");
    after(&library, &mut states);
    library.remove_stock("Bond").expect("remove a stock");
    after(&library, &mut states);
    library
        .record_validation("abc", &serde_json::json!({"x": 1}))
        .expect("validate");
    after(&library, &mut states);
    for (entry, expected) in &states {
        let replayed = library.contents_at(*entry).expect("replay");
        assert_eq!(&replayed.identity, expected, "after entry {entry}");
    }
    let actions: Vec<String> = library
        .audit_entries()
        .expect("history")
        .into_iter()
        .map(|e| e.action)
        .collect();
    assert_eq!(
        actions,
        [
            "create", "add", "add", "add", "remove", "add", "remove", "validate"
        ],
    );
    // The database refuses to change or delete an entry.
    let conn = Connection::open(&path).expect("open");
    for sql in [
        "UPDATE audit SET action = 'add' WHERE entry = 1",
        "DELETE FROM audit WHERE entry = 2",
    ] {
        let err = conn.execute(sql, []).expect_err(sql).to_string();
        assert!(err.contains("append-only"), "{sql}: {err}");
    }
    // A sheet changed behind gonio's back: the trail says it cannot vouch for the past.
    conn.execute("UPDATE spots SET rho_d = 0.5 WHERE spot_index = 0", [])
        .expect("tamper");
    drop(conn);
    let err = library.contents_at(2).expect_err("tampered").to_string();
    assert!(err.contains("changed outside gonio"), "{err}");
}

#[test]
fn a_bad_exchange_file_imports_nothing_and_names_the_line() {
    let dir = tempfile::tempdir().expect("temp dir");
    let exported = export_bytes(&filled(&dir.path().join("first.sqlite")));
    let text = String::from_utf8(exported).expect("utf-8");
    let lines: Vec<&str> = text.lines().collect();
    let cases = [
        (format!("{}\n{}\nnot json\n", lines[0], lines[1]), 3),
        (
            format!(
                "{}\n{}\n",
                lines[0],
                lines[1].replace(crate::schema::LIBRARY_RECORD, "gonio-library/9")
            ),
            2,
        ),
        // The second spot of the first sheet (stock "Bond…", two spots, lay unknown) saying
        // another lay than the first.
        (
            format!(
                "{}\n{}\n",
                lines[0],
                lines[1].replace("\"orientation\":null", "\"orientation\":\"md\"")
            ),
            2,
        ),
        // The second spot of the first sheet (stock "Bond…", two spots) missing.
        (
            lines
                .iter()
                .enumerate()
                .filter(|(k, _)| *k != 1)
                .map(|(_, l)| format!("{l}\n"))
                .collect(),
            0,
        ),
    ];
    for (bad, line) in cases {
        let err = ExchangeFile::read(&mut bad.as_bytes(), Path::new("x.jsonl")).expect_err("bad");
        assert!(matches!(err, LibraryError::Import { .. }), "{err}");
        if line > 0 {
            assert!(
                err.to_string().starts_with(&format!("x.jsonl:{line}:")),
                "{err}"
            );
        }
    }
}

#[test]
fn remove_by_stock_and_by_unique_session_prefix() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut library = filled(&dir.path().join("library.sqlite"));
    let sha = sheet(3, 2).session_sha256;
    let removed = library
        .remove_session(&sha[..10].to_uppercase())
        .expect("remove");
    assert_eq!(
        removed,
        Removed {
            stocks: vec!["Bond 80 g/m²".into()],
            sessions: vec![sha.clone()],
            spots: 2
        }
    );
    assert!(matches!(
        library.remove_session(&sha),
        Err(LibraryError::SessionPrefix { .. })
    ));
    assert!(matches!(
        library.remove_session("zz"),
        Err(LibraryError::SessionPrefix { .. })
    ));
    // The empty prefix would match every session: refused.
    assert!(library.remove_session("").is_err());
    let removed = library.remove_stock("PPC").expect("remove");
    assert_eq!((removed.sessions.len(), removed.spots), (3, 5));
    assert!(library.stocks().expect("stocks").is_empty());
    assert!(library.records().expect("records").is_empty());
    assert!(matches!(
        library.remove_stock("PPC"),
        Err(LibraryError::UnknownStock { .. })
    ));
}

#[test]
fn two_threads_adding_to_one_new_file_both_succeed() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("library.sqlite");
    let barrier = std::sync::Arc::new(std::sync::Barrier::new(2));
    let threads: Vec<_> = (0..2u64)
        .map(|t| {
            let (path, barrier) = (path.clone(), barrier.clone());
            std::thread::spawn(move || {
                barrier.wait();
                let mut library = Library::open_file(&path, OpenMode::Add).expect("open");
                for n in 0..25 {
                    library
                        .add_sheets(
                            &stock(&format!("stock {}", n % 3)),
                            &[sheet(1000 * (t + 1) + n, 1)],
                        )
                        .expect("add");
                }
            })
        })
        .collect();
    for t in threads {
        t.join().expect("thread");
    }
    let library = Library::open_file(&path, OpenMode::Existing).expect("open");
    assert_eq!(library.sheets().expect("sheets").len(), 50);
    assert_eq!(library.stocks().expect("stocks").len(), 3);
}

#[test]
fn the_default_path_follows_xdg() {
    // Only checks the shape: the environment is the process's, shared by other tests.
    if let Some(path) = default_path() {
        assert!(path.ends_with("gonio/library.sqlite"), "{}", path.display());
    }
}
