//! The reference library of measured paper stocks (issue 13): stocks, the sheets measured
//! of each (one per session folder) and their spots (the fitted σ°, ρs, ρd with
//! covariance), for `gonio library` and the forensic search; kept in one SQLite file of a
//! machine, or in a PostgreSQL database an institute shares (issue 29), with the same
//! schema rules, the same exchange format and an audit trail of every change.
//!
//! A session folder's identity is the SHA-256 of its `MANIFEST.sha256` file's bytes: the
//! manifest names every file of the finished folder with its own SHA-256, so two folders
//! have the same identity exactly when they hold the same files, wherever they are kept.
//! A session is in the library at most once.
//!
//! Never destructive on open: a file or database that is not a gonio library, is damaged,
//! belongs to another program or to a newer gonio is reported (where and what is wrong) and
//! left as it is; only [`OpenMode::Add`] creates a missing one. Every change is one
//! transaction with its audit entries; writers wait for each other, so two processes
//! adding at once both succeed.
//!
//! The exchange format (`export`/`import`) is JSON Lines, one [`ExchangeRecord`] per spot;
//! see `docs/LIBRARY.md`.
//!
//! In parts, over the types here: `location`, where a library is (and the `[library]`
//! setting); `store`, an open [`Library`] of either back end over the [`Store`] each
//! implements (`sqlite`, `postgres`); `audit`, the trail's entries; `exchange`, the
//! exchange file's records and their parser; `ingest`, a finished folder read (and
//! verified) into a [`SheetRecord`]. The back ends use the exchange records (export writes
//! them, import takes them); exchange and ingest use no other part.
mod audit;
mod exchange;
mod ingest;
mod location;
mod postgres;
mod sqlite;
mod store;
#[cfg(test)]
mod tests;
#[cfg(test)]
pub(crate) mod tests_postgres;
mod validate;

pub use audit::AuditEntry;
pub use exchange::{ExchangeFile, ExchangeRecord, RecordError};
pub use ingest::{read_session_folder, same_sheet_folders};
pub use location::{LibrarySetting, Location, SETTINGS_ENV, Settings, without_password};
pub use postgres::{CURATOR_ROLE, EXAMINER_ROLE};
pub use sqlite::default_path;
pub use store::{
    Contents, ImportCounts, Library, Migrated, OpenMode, Removed, Replayed, StockSummary, Store,
    export_sha256, migrate,
};
pub(crate) use validate::check_spot;
pub use validate::{MAX_RELATIVE_SD, MIN_RELATIVE_SD, SpotError};

use crate::analysis::evidence::Spot;
use std::path::PathBuf;
use thiserror::Error;

/// The schema this gonio writes and the newest it reads. Stored in SQLite three ways:
/// `meta`'s `schema_version`, `PRAGMA user_version` (readable without knowing the tables),
/// and implied by [`APPLICATION_ID`] being ours; in PostgreSQL in `gonio.meta`. An older
/// library is upgraded when opened (version 1 had no orientation and side of its sheets:
/// they become unknown; version 2 no audit trail: it begins at the upgrade).
pub const SCHEMA_VERSION: i64 = 3;

/// `PRAGMA application_id` of a gonio library: "goLB" in ASCII, so `file(1)` and any SQLite
/// tool can tell a gonio library from other SQLite files.
pub(crate) const APPLICATION_ID: i32 = 0x676F_4C42;

/// Why the library cannot do what was asked. Every variant names the library file or the
/// session folder concerned.
#[derive(Debug, Error)]
pub enum LibraryError {
    /// No library file or database (only commands that add create one).
    #[error(
        "{library}: no library here yet: nothing has been added (gonio library add … creates it)"
    )]
    Missing {
        /// The library.
        library: Location,
    },
    /// The file exists but is not an SQLite database.
    #[error("{path}: not a gonio library: {what}; left as it is")]
    NotSqlite {
        /// The file.
        path: PathBuf,
        /// What it is instead.
        what: String,
    },
    /// An SQLite database that is damaged (truncated, pages corrupt).
    #[error(
        "{path}: damaged library: {what}; left as it is (restore it from a backup or an export)"
    )]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What SQLite or the header check found.
        what: String,
    },
    /// A sound SQLite database of another program.
    #[error("{path}: not a gonio library ({what}); left as it is")]
    Foreign {
        /// The file.
        path: PathBuf,
        /// Why it is not ours.
        what: String,
    },
    /// A library written by a newer gonio.
    #[error(
        "{library}: written by a newer gonio (schema {found}); this gonio reads up to {SCHEMA_VERSION}: update gonio"
    )]
    Newer {
        /// The library.
        library: Location,
        /// Its schema version.
        found: i64,
    },
    /// PostgreSQL failed or refused (the server unreachable, a login refused, a
    /// transaction failed): what the server said.
    #[error("{library}: {what}")]
    Postgres {
        /// The library.
        library: Location,
        /// The server's message, with its detail and hint.
        what: String,
    },
    /// The database refused a change to a role without the right (an examiner adding or
    /// removing a stock): the role, the change, and who may make it.
    #[error("{library}: refused: {what}")]
    Denied {
        /// The library.
        library: Location,
        /// Why.
        what: String,
    },
    /// SQLite failed on a sound library (disk full, permissions, a lock held too long).
    #[error("{path}: {source}")]
    Sqlite {
        /// The library file.
        path: PathBuf,
        /// SQLite's error.
        source: rusqlite::Error,
    },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A session folder that does not verify, or whose `session.json` cannot be read.
    #[error("{dir}: not added: {what}")]
    BadSession {
        /// The folder.
        dir: PathBuf,
        /// Every problem, one per line.
        what: String,
    },
    /// A session whose result is flagged (`ok: false`).
    #[error(
        "{dir}: not added: its result is flagged ({flags}); a flagged sheet would weigh as evidence like a clean one. Measure it again, or add it anyway with --allow-flagged"
    )]
    Flagged {
        /// The folder.
        dir: PathBuf,
        /// Its flags.
        flags: String,
    },
    /// A folder of a sheet whose other folder (its sheet folder, or one of its spot
    /// folders) is in the library or in the same add: one sheet counts once.
    #[error(
        "{dir}: not added: it measured the same sheet as {other}, {where_}: a sheet counts once in the library (its spots are not sheets of their own). Add either the sheet folder or its spot folders, not both"
    )]
    SameSheet {
        /// The folder refused.
        dir: PathBuf,
        /// The other folder of the same sheet.
        other: String,
        /// Where the other one is: in the library under a stock, or given in this add.
        where_: String,
    },
    /// The session is already in the library.
    #[error(
        "{what}: already in the library under stock '{stock}' (session {sha256}); nothing was added"
    )]
    Duplicate {
        /// The folder or import line.
        what: String,
        /// Its identity.
        sha256: String,
        /// The stock it is under.
        stock: String,
    },
    /// A stock name, lot or other text that is not acceptable.
    #[error("{0}")]
    Invalid(String),
    /// No stock of that name.
    #[error("{library}: no stock '{name}' in the library")]
    UnknownStock {
        /// The library.
        library: Location,
        /// The name asked for.
        name: String,
    },
    /// No session, or more than one, matches the SHA-256 prefix.
    #[error("{library}: {what}")]
    SessionPrefix {
        /// The library.
        library: Location,
        /// What matched.
        what: String,
    },
    /// A stock's manufacturer or notes given differently from the library's.
    #[error(
        "stock '{stock}': {field} is '{existing}' in the library, not '{given}'; nothing was changed"
    )]
    StockConflict {
        /// The stock.
        stock: String,
        /// `manufacturer` or `notes`.
        field: &'static str,
        /// The library's.
        existing: String,
        /// The one given.
        given: String,
    },
    /// A line of an exchange file that is not a valid record.
    #[error("{path}:{line}: {what}; nothing was imported")]
    Import {
        /// The exchange file.
        path: PathBuf,
        /// Its line (1-based).
        line: usize,
        /// What is wrong.
        what: exchange::RecordError,
    },
}

/// Result of the library's operations.
pub type Result<T, E = LibraryError> = std::result::Result<T, E>;

/// A stock as given to [`Store::add_sheets`]: fields given as `None` are left as the
/// library has them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StockInfo {
    /// The stock's name (unique in the library).
    pub name: String,
    /// Its manufacturer.
    pub manufacturer: Option<String>,
    /// Free notes.
    pub notes: Option<String>,
}

/// One measured sheet (one session folder) as the library keeps it.
#[derive(Clone, Debug, PartialEq)]
pub struct SheetRecord {
    /// Lot or ream.
    pub lot: Option<String>,
    /// When it was measured: the start of the session's first run (local RFC 3339, as
    /// `session.json` records it).
    pub measured_at: Option<String>,
    /// The instrument's serial number.
    pub instrument_serial: String,
    /// The session folder's path as it was given to `add`.
    pub session_path: String,
    /// SHA-256 (hex) of the folder's `MANIFEST.sha256`: the session's identity.
    pub session_sha256: String,
    /// The sample name the session recorded.
    pub sample: String,
    /// How the sheet lay on the port (orientation, side), as its case recorded it; each
    /// unknown when not stated (and for every sheet of a library before schema 2).
    pub lay: crate::analysis::specimen::SheetLay,
    /// When it was added to a library (UTC RFC 3339); kept through export and import.
    pub(crate) added_at: String,
    /// Its spots, in order.
    pub spots: Vec<Spot>,
}

/// Now, UTC RFC 3339 with milliseconds: libraries are merged across labs and time zones.
pub(crate) fn now_utc() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

pub(crate) fn check_text(what: &str, value: &str) -> Result<()> {
    if value.trim().is_empty() || value.trim() != value || value.chars().any(char::is_control) {
        return Err(LibraryError::Invalid(format!(
            "{what} '{value}' must be non-empty, without leading or trailing spaces or control characters"
        )));
    }
    Ok(())
}

/// A session's SHA-256 as the library keeps it: 64 lowercase hex digits.
pub(crate) fn is_sha256_hex(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}
