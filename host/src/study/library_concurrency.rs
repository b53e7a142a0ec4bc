//! Many instruments adding and examiners searching one library at once (issue 29): W
//! writer threads add stocks (two sheets of two spots each, one add per stock) and now and
//! then a session another writer already added (which must be refused, never stored
//! twice); S searcher threads read the contents as a search does, and check that what they
//! read is one state the library was in: exactly the sessions the trail says were added up
//! to the state's last entry, every stock whole. At the end every add must be present
//! exactly once, with one entry in the trail.
//!
//! The test below runs it for seconds against the server CI
//! starts; `GONIO_TEST_POSTGRES=URL GONIO_PG_CONCURRENCY_SECONDS=60 cargo test -p host
//! --lib -- writers_and_searchers --nocapture` runs the minute.
use crate::analysis::evidence::Spot;
use crate::output::library::{Library, LibraryError, Location, OpenMode, SheetRecord, StockInfo};
use std::collections::{BTreeSet, HashMap};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// What the campaign saw.
#[derive(Clone, Debug, Default)]
pub struct Report {
    /// Adds committed (stocks of two sheets).
    pub adds: usize,
    /// Searches (reads of the contents) checked.
    pub searches: usize,
    /// Adds of a session already in the library, tried.
    pub duplicates_tried: usize,
    /// Of those, refused as duplicates.
    pub duplicates_refused: usize,
    /// Every inconsistency found (empty when all is well).
    pub inconsistent: Vec<String>,
    /// Sheets in the library at the end.
    pub sheets_at_end: usize,
    /// `add` entries in the trail at the end.
    pub add_entries_at_end: usize,
    /// Wall time of the campaign.
    pub seconds: f64,
}

/// A sheet of this campaign: its identity from the writer, the stock and the sheet's number.
fn sheet(writer: usize, stock: usize, k: usize) -> SheetRecord {
    let name = format!("writer {writer} stock {stock} sheet {k}");
    let spot = |j: usize| Spot {
        values: [
            Some(5.0 + writer as f64 * 0.01 + j as f64 * 0.1),
            Some(1.0 + stock as f64 * 1e-4),
            Some(0.8),
        ],
        covariance: [[1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-5]],
    };
    SheetRecord {
        lot: None,
        measured_at: None,
        instrument_serial: format!("SIM-{writer:04}"),
        session_path: name.clone(),
        session_sha256: crate::output::folder::manifest::sha256_hex(name.as_bytes()),
        sample: "PPC".into(),
        lay: Default::default(),
        added_at: crate::output::library::now_utc(),
        spots: (0..2).map(spot).collect(),
    }
}

/// Run the campaign on the library at `location` (existing) for `duration`.
pub fn run(
    location: &Location,
    writers: usize,
    searchers: usize,
    duration: Duration,
) -> Result<Report, LibraryError> {
    let started = Instant::now();
    let deadline = started + duration;
    let added: Mutex<Vec<String>> = Mutex::new(Vec::new());
    let report = Mutex::new(Report::default());
    std::thread::scope(|scope| -> Result<(), LibraryError> {
        let mut handles = Vec::new();
        for writer in 0..writers {
            let (added, report) = (&added, &report);
            handles.push(scope.spawn(move || -> Result<(), LibraryError> {
                let mut library = Library::open(location, OpenMode::Existing)?;
                let mut stock = 0;
                while Instant::now() < deadline {
                    let sheets = [sheet(writer, stock, 0), sheet(writer, stock, 1)];
                    let info = StockInfo {
                        name: format!("writer {writer} stock {stock}"),
                        ..Default::default()
                    };
                    library.add_sheets(&info, &sheets)?;
                    report.lock().expect("report").adds += 1;
                    added
                        .lock()
                        .expect("added")
                        .extend(sheets.iter().map(|s| s.session_path.clone()));
                    if stock % 5 == 4 {
                        // Another writer's sheet again, under this writer's stock.
                        let other = (writer + 1) % writers.max(1);
                        let again = sheet(other, 0, 0);
                        let known = added.lock().expect("added").contains(&again.session_path);
                        if known {
                            let refused = matches!(
                                library.add_sheets(&info, &[again]),
                                Err(LibraryError::Duplicate { .. })
                            );
                            let mut r = report.lock().expect("report");
                            r.duplicates_tried += 1;
                            r.duplicates_refused += usize::from(refused);
                        }
                    }
                    stock += 1;
                }
                Ok(())
            }));
        }
        for _ in 0..searchers {
            let report = &report;
            handles.push(scope.spawn(move || -> Result<(), LibraryError> {
                let library = Library::open(location, OpenMode::Existing)?;
                while Instant::now() < deadline {
                    let found = check_one_state(&library)?;
                    let mut r = report.lock().expect("report");
                    r.searches += 1;
                    r.inconsistent.extend(found);
                }
                Ok(())
            }));
        }
        for handle in handles {
            handle.join().expect("a campaign thread panicked")?;
        }
        Ok(())
    })?;
    let mut report = report.into_inner().expect("report");
    let library = Library::open(location, OpenMode::Existing)?;
    report.sheets_at_end = library.sheet_count()?;
    let trail = library.audit_entries()?;
    report.add_entries_at_end = trail.iter().filter(|e| e.action == "add").count();
    let expected = added.into_inner().expect("added").len();
    if report.sheets_at_end != expected || report.add_entries_at_end != expected {
        report.inconsistent.push(format!(
            "at the end: {} sheets and {} add entries, {expected} sheets added",
            report.sheets_at_end, report.add_entries_at_end
        ));
    }
    report.inconsistent.extend(check_one_state(&library)?);
    report.seconds = started.elapsed().as_secs_f64();
    Ok(report)
}

/// Read the contents once as a search does; what is inconsistent in them, if anything.
fn check_one_state(library: &Library) -> Result<Vec<String>, LibraryError> {
    let contents = library.contents()?;
    let mut found = Vec::new();
    let last = contents.last_entry.unwrap_or(0);
    let held: BTreeSet<&str> = contents
        .sheets
        .iter()
        .map(|(sha, _, _)| sha.as_str())
        .collect();
    if held.len() != contents.sheets.len() {
        found.push(format!("entry {last}: a session held twice"));
    }
    let mut per_stock: HashMap<&str, usize> = HashMap::new();
    for (_, sheet, _) in &contents.sheets {
        *per_stock.entry(sheet.stock.as_str()).or_default() += 1;
        if sheet.sheet.spots.len() != 2 {
            found.push(format!(
                "entry {last}: a sheet of {} spots",
                sheet.sheet.spots.len()
            ));
        }
    }
    for (stock, n) in per_stock {
        if n != 2 {
            found.push(format!(
                "entry {last}: stock '{stock}' with {n} sheets (half an add)"
            ));
        }
    }
    // Entries up to the state's last are committed and never change: the sessions they
    // added (less those removed; none here) are the state's sessions exactly.
    let trail = library.audit_entries()?;
    let by_trail: BTreeSet<&str> = trail
        .iter()
        .filter(|e| e.entry <= last && e.action == "add")
        .filter_map(|e| e.session_sha256.as_deref())
        .collect();
    if by_trail != held {
        found.push(format!(
            "entry {last}: {} sessions held, the trail added {} up to it",
            held.len(),
            by_trail.len()
        ));
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use crate::output::library::tests_postgres::{TestDatabase, server};

    #[test]
    fn writers_and_searchers_at_once_lose_nothing_and_read_one_state() {
        let Some(admin) = server() else { return };
        let db = TestDatabase::new(&admin);
        drop(
            crate::output::library::Library::open(
                &db.location(),
                crate::output::library::OpenMode::Add,
            )
            .expect("create"),
        );
        let seconds: f64 = std::env::var("GONIO_PG_CONCURRENCY_SECONDS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(8.0);
        let report = super::run(
            &db.location(),
            8,
            8,
            std::time::Duration::from_secs_f64(seconds),
        )
        .expect("the campaign");
        eprintln!("{report:?}");
        assert!(report.adds > 8 && report.searches > 8, "{report:?}");
        assert_eq!(
            report.duplicates_refused, report.duplicates_tried,
            "{report:?}"
        );
        assert!(report.inconsistent.is_empty(), "{report:?}");
    }
}
