//! A library whatever keeps it: the [`Store`] each back end implements (the SQLite file,
//! a PostgreSQL database), and [`Library`], an open one, with what is the same for both
//! built on the store's own operations: export, the contents after an audit entry, the
//! migration from one back end to another.
use super::audit::{self, AuditEntry};
use super::exchange::{ExchangeFile, ExchangeRecord};
use super::{LibraryError, Location, Result, SheetRecord, StockInfo};
use crate::analysis::evidence::{LibrarySheet, population};
use crate::analysis::specimen::SheetLay;
use serde::Serialize;
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// Whether opening may create the library.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OpenMode {
    /// Read or change an existing library; a missing one is [`LibraryError::Missing`].
    Existing,
    /// Create the library when missing (commands that add).
    Add,
}

/// A stock with its counts, for `list`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct StockSummary {
    /// Name.
    pub name: String,
    /// Manufacturer.
    pub manufacturer: Option<String>,
    /// Notes.
    pub notes: Option<String>,
    /// Sheets (sessions).
    pub sheets: usize,
    /// Spots over its sheets.
    pub spots: usize,
}

/// What `import` did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ImportCounts {
    /// Records (lines) read.
    pub records: usize,
    /// Sessions added.
    pub sessions_added: usize,
    /// Sessions skipped: already in the library (by SHA-256).
    pub sessions_skipped: usize,
    /// Stocks new to the library.
    pub stocks_added: usize,
}

/// What a removal removed.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Removed {
    /// Stocks removed (a stock goes with its last sheet: the library holds only what an
    /// export can carry).
    pub stocks: Vec<String>,
    /// Sessions removed (SHA-256).
    pub sessions: Vec<String>,
    /// Spots removed.
    pub spots: usize,
}

/// The library's sheets as one consistent state: read in one transaction, so a search
/// never weighs half of another process's add.
#[derive(Clone, Debug, Default)]
pub struct Contents {
    /// Every sheet with its session's SHA-256 and how it lay, ordered by stock name and
    /// SHA-256 (bytewise), as an export orders them.
    pub sheets: Vec<(String, LibrarySheet, SheetLay)>,
    /// The last audit entry of this state: [`Library::contents_at`] with it gives these
    /// sheets again. `None` when the trail is empty.
    pub last_entry: Option<i64>,
}

/// What a migration copied.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Migrated {
    /// Records (spots) copied.
    pub records: usize,
    /// Sessions copied.
    pub sessions: usize,
    /// Audit entries of the source copied.
    pub audit_entries: usize,
    /// Recorded validations copied.
    pub validations: usize,
    /// The SHA-256 of the export of both: equal, or the migration fails.
    pub export_sha256: String,
}

/// What a library keeps and how, one implementation per back end. Every change is one
/// transaction with its audit entries; reads that must agree with each other
/// ([`Store::contents`]) are one snapshot.
pub trait Store {
    /// Where it is.
    fn location(&self) -> &Location;
    /// Add sheets under one stock, all or none: a session already in the library (by
    /// SHA-256) refuses the whole add, naming the stock it is under.
    fn add_sheets(&mut self, stock: &StockInfo, sheets: &[SheetRecord]) -> Result<()>;
    /// The stock a session (by its SHA-256) is under, if it is in the library.
    fn stock_of_session(&self, sha256: &str) -> Result<Option<String>>;
    /// Every stock with its sheet and spot counts, by name.
    fn stocks(&self) -> Result<Vec<StockSummary>>;
    /// Remove a stock with all its sheets and spots.
    fn remove_stock(&mut self, name: &str) -> Result<Removed>;
    /// Remove one session, named by its SHA-256 or a prefix only it has; its stock goes
    /// with it when it was the stock's last sheet.
    fn remove_session(&mut self, sha256_prefix: &str) -> Result<Removed>;
    /// Every spot as an exchange record, ordered by stock name, session SHA-256 and spot
    /// index (bytewise), given to `each` as it is read. `each`'s error stops the reading.
    fn for_each_record(&self, each: &mut dyn FnMut(ExchangeRecord) -> Result<()>) -> Result<()>;
    /// Whether the session of SHA-256 `sha256` is in the library.
    fn has_session(&self, sha256: &str) -> Result<bool>;
    /// How many sheets (sessions) the library holds.
    fn sheet_count(&self) -> Result<usize>;
    /// Import a checked exchange file in one transaction: sessions already in the
    /// library (by SHA-256) are skipped.
    fn import(&mut self, file: &ExchangeFile) -> Result<ImportCounts>;
    /// Record the population `gonio forensic --library` validated from the contents of
    /// identity `identity`.
    fn record_validation(&mut self, identity: &str, population: &serde_json::Value) -> Result<()>;
    /// The population validated from the contents of identity `identity`, if recorded.
    fn validation_record(&self, identity: &str) -> Result<Option<serde_json::Value>>;
    /// Every recorded validation, by contents identity.
    fn validation_records(&self) -> Result<Vec<(String, serde_json::Value)>>;
    /// The library's sheets and the last audit entry, in one snapshot.
    fn contents(&self) -> Result<Contents>;
    /// The population last made from the contents of identity `identity` by this gonio,
    /// if still cached.
    fn cached_population(&self, identity: &str) -> Result<Option<serde_json::Value>>;
    /// Cache a population made from the contents of identity `identity`, in place of
    /// any cached before.
    fn cache_population(&mut self, identity: &str, population: &serde_json::Value) -> Result<()>;
    /// The audit trail, oldest first, given to `each`.
    fn history(&self, each: &mut dyn FnMut(AuditEntry) -> Result<()>) -> Result<()>;
    /// Take a whole library in one transaction (a migration into this empty one): the
    /// source's audit entries, its sessions and validations, and an entry saying so.
    fn receive(
        &mut self,
        file: &ExchangeFile,
        history: &[AuditEntry],
        validations: &[(String, serde_json::Value)],
        from: &Location,
    ) -> Result<()>;
}

/// An open library, of either back end.
pub struct Library {
    store: Box<dyn Store>,
}

impl std::fmt::Debug for Library {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Library")
            .field("location", self.store.location())
            .finish()
    }
}

impl std::ops::Deref for Library {
    type Target = dyn Store;
    fn deref(&self) -> &(dyn Store + 'static) {
        self.store.as_ref()
    }
}

impl std::ops::DerefMut for Library {
    fn deref_mut(&mut self) -> &mut (dyn Store + 'static) {
        self.store.as_mut()
    }
}

impl Library {
    /// Open the library at `location`. Checks before anything is written: a library that
    /// is not one (not SQLite, damaged, another program's, a newer gonio's) is refused and
    /// left as it is.
    pub fn open(location: &Location, mode: OpenMode) -> Result<Library> {
        let store: Box<dyn Store> = match location {
            Location::File(path) => Box::new(super::sqlite::SqliteLibrary::open(path, mode)?),
            Location::Postgres(url) => Box::new(super::postgres::PgLibrary::open(url, mode)?),
        };
        Ok(Library { store })
    }

    /// Open the SQLite file at `path` (see [`Library::open`]).
    pub fn open_file(path: &Path, mode: OpenMode) -> Result<Library> {
        Library::open(&Location::File(path.to_path_buf()), mode)
    }

    /// Every spot as an exchange record, in the order of [`Store::for_each_record`].
    pub fn records(&self) -> Result<Vec<ExchangeRecord>> {
        let mut out = Vec::new();
        self.for_each_record(&mut |record| {
            out.push(record);
            Ok(())
        })?;
        Ok(out)
    }

    /// Write every spot to `out` as JSON Lines (see [`ExchangeRecord`]), record by record
    /// as they are read; returns the number of records. `out_path` is only for messages.
    pub fn export(&self, out: &mut dyn Write, out_path: &Path) -> Result<usize> {
        let io = |source| LibraryError::Io {
            path: out_path.to_path_buf(),
            source,
        };
        let mut out = std::io::BufWriter::new(out);
        let mut records = 0;
        self.for_each_record(&mut |record| {
            serde_json::to_writer(&mut out, &record).map_err(|e| io(std::io::Error::other(e)))?;
            out.write_all(b"\n").map_err(io)?;
            records += 1;
            Ok(())
        })?;
        out.flush().map_err(io)?;
        Ok(records)
    }

    /// Every sheet (its stock, lot, instrument and spots) with its session SHA-256, ordered
    /// as [`Self::records`].
    pub fn sheets(&self) -> Result<Vec<(String, LibrarySheet)>> {
        Ok(self
            .contents()?
            .sheets
            .into_iter()
            .map(|(sha, sheet, _)| (sha, sheet))
            .collect())
    }

    /// How every sheet lay, as (session SHA-256, stock, lay).
    pub fn lays(&self) -> Result<Vec<(String, String, SheetLay)>> {
        Ok(self
            .contents()?
            .sheets
            .into_iter()
            .map(|(sha, sheet, lay)| (sha, sheet.stock, lay))
            .collect())
    }

    /// The audit trail, oldest first.
    pub fn audit_entries(&self) -> Result<Vec<AuditEntry>> {
        let mut out = Vec::new();
        self.history(&mut |entry| {
            out.push(entry);
            Ok(())
        })?;
        Ok(out)
    }

    /// The library's sheets as they were just after audit entry `entry`, recovered from
    /// today's contents and the trail alone (see [`audit`]), with their contents identity:
    /// the identity a search or comparison made then recorded. Fails when the trail and
    /// the contents disagree (a sheet changed since it was added, an add of a session the
    /// library neither holds nor removed later): the trail is then no evidence of the past.
    pub fn contents_at(&self, entry: i64) -> Result<Replayed> {
        let contents = self.contents()?;
        let last = contents.last_entry.unwrap_or(0);
        let at = self.store.location().to_string();
        if entry < 0 || entry > last {
            return Err(LibraryError::Invalid(format!(
                "{at}: no audit entry {entry}: its trail runs from 1 to {last}"
            )));
        }
        // Only the entries of the snapshot read: later ones are of changes it does not hold.
        let entries: Vec<AuditEntry> = self
            .audit_entries()?
            .into_iter()
            .filter(|e| e.entry <= last)
            .collect();
        let mut sheets: HashMap<String, LibrarySheet> = contents
            .sheets
            .into_iter()
            .map(|(sha, sheet, _)| (sha, sheet))
            .collect();
        // The sheets held today must be those their last add recorded.
        let mut last_add: HashMap<&str, &AuditEntry> = HashMap::new();
        for e in &entries {
            if let (Some(sha), "add" | "import") = (e.session_sha256.as_deref(), e.action.as_str())
            {
                last_add.insert(sha, e);
            }
        }
        let mut checked = 0;
        for (sha, e) in &last_add {
            let Some(sheet) = sheets.get(*sha) else {
                continue;
            };
            let recorded = e.detail["sheet_sha256"].as_str().unwrap_or("");
            if audit::sheet_digest(sheet) != recorded {
                return Err(LibraryError::Invalid(format!(
                    "{at}: session {sha} is not the sheet audit entry {} added (digest {recorded}): the library was changed outside gonio; its trail cannot recover the past",
                    e.entry
                )));
            }
            checked += 1;
        }
        for e in entries.iter().rev().filter(|e| e.entry > entry) {
            let Some(sha) = e.session_sha256.as_deref() else {
                continue;
            };
            match e.action.as_str() {
                "add" | "import" => {
                    let undone = sheets.remove(sha);
                    if undone.is_none() {
                        return Err(LibraryError::Invalid(format!(
                            "{at}: audit entry {} added session {sha}, which the library neither holds nor removed later",
                            e.entry
                        )));
                    }
                }
                "remove" => {
                    let sheet: LibrarySheet = serde_json::from_value(e.detail["sheet"].clone())
                        .map_err(|err| {
                            LibraryError::Invalid(format!(
                                "{at}: audit entry {} (remove of {sha}) does not hold the sheet removed: {err}",
                                e.entry
                            ))
                        })?;
                    sheets.insert(sha.to_string(), sheet);
                }
                _ => {}
            }
        }
        let mut sheets: Vec<(String, LibrarySheet)> = sheets.into_iter().collect();
        sheets.sort_by(|a, b| a.1.stock.cmp(&b.1.stock).then_with(|| a.0.cmp(&b.0)));
        let weighed: Vec<LibrarySheet> = sheets.iter().map(|(_, s)| s.clone()).collect();
        Ok(Replayed {
            entry,
            identity: population::contents_identity(&weighed),
            sheets,
            checked_against_trail: checked,
        })
    }
}

/// The contents after an audit entry, recovered from the trail.
#[derive(Clone, Debug)]
pub struct Replayed {
    /// The entry.
    pub entry: i64,
    /// Their contents identity (`evidence::population::contents_identity`).
    pub identity: String,
    /// The sheets, with their sessions' SHA-256, ordered as an export.
    pub sheets: Vec<(String, LibrarySheet)>,
    /// Sheets held today whose digest was checked against the entry that added them.
    pub checked_against_trail: usize,
}

/// Copy the whole of `from` into `to`, an empty library of any back end: every record,
/// the audit trail (each entry with its original number, time and who under `origin`)
/// and the recorded validations, in one transaction of `to`; then both exported and
/// compared byte for byte, the migration failing if they differ.
pub fn migrate(from: &Library, to: &mut Library) -> Result<Migrated> {
    let target = to.location().to_string();
    let copied = to.audit_entries()?;
    if to.sheet_count()? > 0 || copied.iter().any(|e| e.action != "create") {
        return Err(LibraryError::Invalid(format!(
            "{target}: not empty ({} sheets, {} audit entries): a migration goes into a new library only; nothing was copied",
            to.sheet_count()?,
            copied.len()
        )));
    }
    // Through a file of the exchange format: checked as an import checks it, and held on
    // disk, not in memory (a national collection's records are hundreds of megabytes).
    let mut spool = tempfile::tempfile().map_err(|source| LibraryError::Io {
        path: std::env::temp_dir(),
        source,
    })?;
    let label = Path::new("(the migration's copy)");
    let records = from.export(&mut spool, label)?;
    let io = |source| LibraryError::Io {
        path: label.to_path_buf(),
        source,
    };
    use std::io::Seek;
    spool.rewind().map_err(io)?;
    let file = ExchangeFile::read(&mut std::io::BufReader::new(&spool), label)?;
    let history = from.audit_entries()?;
    let validations = from.validation_records()?;
    to.receive(&file, &history, &validations, from.location())?;
    let (a, b) = (export_sha256(from)?, export_sha256(to)?);
    if a != b {
        return Err(LibraryError::Invalid(format!(
            "{target}: its export differs from {}'s after the migration (SHA-256 {b} against {a}): the copy is not faithful; remove it and report this",
            from.location()
        )));
    }
    Ok(Migrated {
        records,
        sessions: file.sessions.len(),
        audit_entries: history.len(),
        validations: validations.len(),
        export_sha256: a,
    })
}

/// The SHA-256 of a library's export, computed as it is written.
pub fn export_sha256(library: &Library) -> Result<String> {
    let mut hashing = population::Sha256Writer::default();
    library.export(&mut hashing, Path::new("(hash)"))?;
    Ok(hashing.hex())
}

/// What a removal by SHA-256 prefix found, as both back ends judge it.
pub(crate) fn one_session<T: Clone>(
    at: &Location,
    prefix: &str,
    matches: &[(T, String)],
) -> Result<(T, String)> {
    match matches {
        [one] => Ok(one.clone()),
        [] => Err(LibraryError::SessionPrefix {
            library: at.clone(),
            what: format!("no session {prefix}… in the library"),
        }),
        many => {
            let names: Vec<&str> = many.iter().map(|m| m.1.as_str()).collect();
            Err(LibraryError::SessionPrefix {
                library: at.clone(),
                what: format!(
                    "{} sessions begin with {prefix} ({}): give more of the SHA-256",
                    many.len(),
                    names.join(", ")
                ),
            })
        }
    }
}

/// A SHA-256 prefix as given to `remove --session`, lowercased, or why it is not one.
pub(crate) fn session_prefix(at: &Location, given: &str) -> Result<String> {
    let prefix = given.to_ascii_lowercase();
    if prefix.is_empty() || !prefix.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(LibraryError::SessionPrefix {
            library: at.clone(),
            what: format!("'{given}' is not a SHA-256 or a prefix of one (hex digits)"),
        });
    }
    Ok(prefix)
}

/// The checks of an add made before any back end is touched: the same as `import` and
/// `read_session_folder` make, so no caller of the API stores a spot the commands refuse.
pub(crate) fn check_add(stock: &StockInfo, sheets: &[SheetRecord]) -> Result<()> {
    super::check_text("stock name", &stock.name)?;
    if let Some(lot) = sheets.iter().find_map(|s| s.lot.as_deref()) {
        super::check_text("lot", lot)?;
    }
    for sheet in sheets {
        for (k, spot) in sheet.spots.iter().enumerate() {
            super::check_spot(spot).map_err(|e| {
                LibraryError::Invalid(format!("{}: spot {k}: {e}", sheet.session_path))
            })?;
        }
    }
    Ok(())
}

/// A stock's manufacturer or notes as given against the library's: the fields to fill
/// (the library has none), or the conflict (it has another).
pub(crate) fn stock_fields_to_fill(
    stock: &StockInfo,
    manufacturer: &Option<String>,
    notes: &Option<String>,
) -> Result<Vec<(&'static str, String)>> {
    let mut fill = Vec::new();
    for (field, existing, given) in [
        ("manufacturer", manufacturer, &stock.manufacturer),
        ("notes", notes, &stock.notes),
    ] {
        match (existing, given) {
            (Some(existing), Some(given)) if existing != given => {
                return Err(LibraryError::StockConflict {
                    stock: stock.name.clone(),
                    field,
                    existing: existing.clone(),
                    given: given.clone(),
                });
            }
            (None, Some(given)) => fill.push((field, given.clone())),
            _ => {}
        }
    }
    Ok(fill)
}

/// Where [`Store::cached_population`] keeps a population: under the gonio that made it
/// (another version may make it differently) and the contents it was made from.
pub(crate) fn population_cache_key(identity: &str) -> String {
    format!(
        "population-cache/gonio {}/{identity}",
        env!("CARGO_PKG_VERSION")
    )
}

/// The record kept of a validation: the population with when and by what.
pub(crate) fn validation_value(population: &serde_json::Value) -> serde_json::Value {
    serde_json::json!({
        "validated_at": super::now_utc(),
        "validated_by": format!("gonio {}", env!("CARGO_PKG_VERSION")),
        "population": population,
    })
}
